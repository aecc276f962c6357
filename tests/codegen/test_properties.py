"""No silent wrong answer from a generated solver (both backends): random and extreme parameter
sequences (entries up to 1e308, NaN / inf ticks between normal ones) give either "solved" inside every
bound within the stated tolerance, or a non-OK status with NaN -- and no tick leaves state behind."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ddpc_codegen import load_solver
from ddpc_codegen.codegen import vectors as test_vectors
from ddpc_codegen.values.solve_result import BOUND_TOL

pytestmark = pytest.mark.compiler

CASES = [("flying", "daqp"), ("flying", "osqp"), ("hopping", "daqp")]

normal = st.tuples(st.just("normal"), st.integers(0, 47), st.floats(0.0, 0.05))
extreme = st.tuples(st.just("extreme"), st.integers(0, 47), st.integers(6, 308), st.sampled_from([1.0, -1.0]),
                    st.floats(0.0, 1.0, exclude_max=True), st.booleans())
broken = st.tuples(st.just("nonfinite"), st.integers(0, 47), st.sampled_from([math.nan, math.inf, -math.inf]),
                   st.floats(0.0, 1.0, exclude_max=True))
sequences = st.lists(st.one_of(normal, normal, extreme, broken), min_size=1, max_size=8)


def _theta(tick, vec: test_vectors.Vectors, rng: np.random.Generator) -> np.ndarray:
    th = vec.theta[tick[1] % len(vec.theta)].copy()
    n = th.size
    if tick[0] == "normal":
        th += tick[2] * rng.standard_normal(n) * np.maximum(1e-3, np.abs(th))
    elif tick[0] == "extreme":
        _, _, exp, sign, where, block = tick
        i = int(where * n)
        sl = slice(i, min(n, i + 20)) if block else slice(i, i + 1)
        th[sl] = sign * 10.0 ** exp
    else:
        th[int(tick[3] * n)] = tick[2]
    return th


def _workspace(s) -> bytes:
    return bytes(s._ffi.buffer(s._ws))


@pytest.fixture(scope="module")
def instances(generated, problems):
    out = {}
    for key in CASES:
        s = load_solver(generated[key])
        vec = test_vectors.read(generated[key] / f"{key[0]}_{key[1]}_vectors.txt")
        out[key] = (s, problems[key[0]], vec, _workspace(s))
    return out


@pytest.mark.parametrize("key", CASES)
def test_every_answer_is_verified_or_nan_and_failures_leave_no_state(instances, key):
    s, problem, vec, post_init = instances[key]

    @settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
    @given(seq=sequences, seed=st.integers(0, 2**16))
    def run(seq, seed):
        rng = np.random.default_rng(seed)
        s.reset()
        for tick in seq:
            th = _theta(tick, vec, rng)
            r = s.solve_theta(th, raw=True)
            if r.status == "solved":
                assert np.all(np.isfinite(r.u))
                assert test_vectors.violation(problem, r.u.ravel(), th) <= BOUND_TOL
                assert r.info["max_violation"] <= BOUND_TOL
            else:
                assert np.isnan(r.u).all() and not r.fast_path
                assert _workspace(s) == post_init  # the warm start is dropped: back to post-init
            if tick[0] == "nonfinite":
                assert r.status == "nonfinite"
        # afterwards, a normal tick answers exactly like a fresh instance
        fresh = load_solver(s.folder)
        th = vec.theta[seed % len(vec.theta)]
        s.reset()
        a, b = s.solve_theta(th), fresh.solve_theta(th)
        assert a.status == b.status and np.array_equal(a.u, b.u, equal_nan=True)

    run()


@pytest.mark.parametrize("key", CASES)
def test_reset_restores_the_exact_post_init_workspace(instances, key):
    s, _, vec, post_init = instances[key]
    s.reset()
    for th in vec.theta[:12]:
        s.solve_theta(th)
    assert _workspace(s) != post_init  # the QP ticks left a warm start
    s.reset()
    assert _workspace(s) == post_init


def test_two_instances_used_alternately_are_independent(generated, problems):
    """Two workspaces of one solver, interleaved tick by tick on different streams, answer exactly as each
    does alone (bit for bit), for both backends."""
    for key in (("flying", "daqp"), ("flying", "osqp")):
        vec = test_vectors.read(generated[key] / f"{key[0]}_{key[1]}_vectors.txt")
        a, b = load_solver(generated[key]), load_solver(generated[key])
        fwd, bwd = vec.theta, vec.theta[::-1]
        mixed = [(a.solve_theta(x).u, b.solve_theta(y).u) for x, y in zip(fwd, bwd)]
        solo_a, solo_b = load_solver(generated[key]), load_solver(generated[key])
        alone_a = [solo_a.solve_theta(x).u for x in fwd]
        alone_b = [solo_b.solve_theta(y).u for y in bwd]
        for (ua, ub), va, vb in zip(mixed, alone_a, alone_b):
            assert np.array_equal(ua, va, equal_nan=True) and np.array_equal(ub, vb, equal_nan=True)
        ok = ~np.isnan(vec.u).any(axis=1)
        err = max(np.abs(u[0].ravel() - r).max() for u, r, k in zip(mixed, vec.u, ok) if k)
        assert err <= (1e-9 if key[1] == "daqp" else 1e-6)
