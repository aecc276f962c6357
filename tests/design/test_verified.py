"""No silent wrong answer (issue 12): every interpreted result is "solved" and inside all bounds
within BOUND_TOL, or a non-OK status with NaN u; extreme or NaN ticks leave no state behind;
configs that cannot be solved soundly are refused with messages naming key and value."""

import inspect

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from support.lti import random_lti
from ddpc_codegen import ConfigError, DataError, IODataset, SteeringConfig, SteeringProblem, fit_predictor
from ddpc_codegen.values.solve_result import BOUND_TOL

TI, TF, M, P = 6, 10, 2, 2
BOUNDS = dict(u_min=[-1.5, -1.2], u_max=[1.5, 1.2], y_min=[-6.0, -6.0], y_max=[6.0, 6.0], du_max=[0.6, 0.8])


@pytest.fixture(scope="module")
def setup():
    sys_ = random_lti(4, M, P, 11)
    rng = np.random.default_rng(11)
    u = rng.standard_normal((500, M))
    y, _ = sys_.simulate(u, rng.standard_normal(4))
    y += 1e-3 * rng.standard_normal(y.shape)
    ds = IODataset(u, y, 0.005)
    cfg = SteeringConfig(t_ini=TI, t_f=TF, m=M, p=P, Q=[10.0, 4.0], R=[0.2, 0.1], lambda_sigma=50.0,
                         R_mode="offset", **BOUNDS)
    return sys_, ds, SteeringProblem(fit_predictor(ds, TI, TF, "lsq", ridge=1e-6), cfg)


def _normal_theta(prob, sys_, seed):
    rng = np.random.default_rng(seed)
    u = rng.uniform(-1.4, 1.1, (TI, M)) * (0.2 if seed % 2 else 1.0)
    y, _ = sys_.simulate(u, 0.3 * rng.standard_normal(4))
    scale = 0.05 if seed % 2 else rng.uniform(0.5, 5.0)  # odd seeds: mostly no active bound (fast path)
    return prob.theta(u, y, scale * rng.standard_normal((TF, P)), 0.1 * rng.standard_normal((TF, M)))


def _assert_sound(prob, th, r):
    """Either solved and inside every bound (own units, BOUND_TOL relative) or non-OK with NaN."""
    if not r.ok:
        assert r.status != "solved" and np.all(np.isnan(r.u)), r
        return
    c, z = prob.config, r.u.ravel()
    tol = lambda b: BOUND_TOL * np.maximum(1.0, np.abs(b))  # noqa: E731
    assert np.all(np.isfinite(z)) and np.all(np.isfinite(r.y_pred))
    lo, hi = np.tile(c.u_min, TF), np.tile(c.u_max, TF)
    assert np.all(z >= lo - tol(lo)) and np.all(z <= hi + tol(hi))
    y = prob.predictor.Gy_w @ th[: prob.n_w] + prob.predictor.Gy_u @ z
    lo, hi = np.tile(c.y_min, TF), np.tile(c.y_max, TF)
    assert np.all(y >= lo - tol(lo)) and np.all(y <= hi + tol(hi))
    du = np.diff(np.r_[th[M * (TI - 1) : M * TI], z].reshape(-1, M), axis=0).ravel()
    dm = np.tile(c.du_max, TF)
    assert np.all(np.abs(du) <= dm + tol(dm))


OSQP_EPS = inspect.signature(SteeringProblem.solve_theta).parameters["eps"].default  # its eps_abs = eps_rel


def osqp_promise(prob, th, u):
    """How far an OSQP answer u (Tf, m) may lie from the optimum, in u (2-norm, so also per entry).

    OSQP stops when its dual residual r = P z + q + A'y has ||r||_inf <= eps_abs + eps_rel max(||P z||_inf,
    ||A'y||_inf, ||q||_inf), so (A'y = r - P z - q) ||r||_inf <= eps (1 + ||P z||_inf + ||q||_inf) / (1 - eps);
    on a Hessian P >= mu I
    an answer meeting its active bounds is then within sqrt(n_z) ||r||_inf / mu of the optimum z*, and
    u = B z within ||B||_2 of that (B = I without knots). Polished answers are far closer.
    """
    q, _, _ = prob.qp_vectors(th)
    z = prob.to_z(u.ravel())
    pz = prob.P @ z
    r = OSQP_EPS * (1.0 + np.abs(pz).max() + np.abs(q).max()) / (1.0 - OSQP_EPS)
    mu = np.linalg.eigvalsh(prob.P).min()
    b = 1.0 if prob.B is None else np.linalg.norm(prob.B, 2)
    return b * np.sqrt(prob.n_z) * r / mu


_tick = st.one_of(
    st.tuples(st.just("normal"), st.integers(0, 10**6)),
    st.tuples(st.just("extreme"), st.tuples(st.floats(15, 308), st.integers(0, 10**6), st.sampled_from([-1, 1]))),
    st.tuples(st.just("nan"), st.integers(0, 10**6)),
)


@pytest.mark.parametrize("solver", ["fast", "exact", "osqp"])
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(ticks=st.lists(_tick, min_size=2, max_size=6))
def test_every_answer_is_inside_the_bounds_or_nan(setup, solver, ticks):
    sys_, _, prob = setup
    for kind, arg in ticks:
        if kind == "normal":
            th = _normal_theta(prob, sys_, arg)
        elif kind == "extreme":
            (e, where, sign) = arg
            th = _normal_theta(prob, sys_, where)
            th[where % (prob.n_w + P * TF)] = sign * 10.0 ** e  # a u_ini, y_ini or y_des entry
        else:
            th = _normal_theta(prob, sys_, arg)
            th[arg % prob.n_theta] = np.nan
        _assert_sound(prob, th, prob.solve_theta(th, solver=solver))
    # No state left behind: a normal tick after the sequence equals the same tick on a fresh problem.
    th = _normal_theta(prob, sys_, 7)
    fresh = SteeringProblem(prob.predictor, prob.config).solve_theta(th, solver=solver)
    again = prob.solve_theta(th, solver=solver)
    assert again.status == fresh.status
    if fresh.ok:
        # two answers each within the solver's promise of the optimum differ by at most twice it
        atol = 2 * osqp_promise(prob, th, fresh.u) if solver == "osqp" else 1e-9
        np.testing.assert_allclose(again.u, fresh.u, atol=atol, rtol=0)
    prob.reset()  # and reset() is the post-construction state: the same answer to round-off
    np.testing.assert_allclose(prob.solve_theta(th, solver=solver).u, fresh.u, atol=1e-12, equal_nan=True)


def test_extreme_and_nan_ticks_are_refused_with_nan(setup):
    sys_, _, prob = setup
    th = _normal_theta(prob, sys_, 1)
    for v, status in ((1e308, "nonfinite_parameters"), (np.nan, "nonfinite_parameters")):
        t = th.copy()
        t[prob.n_w - 1] = v  # last y_ini entry
        for solver in ("fast", "exact", "osqp"):
            r = prob.solve_theta(t, solver=solver)
            assert r.status == status and np.all(np.isnan(r.u))
    with pytest.raises(DataError, match="y_ini contains NaN or inf"):
        prob.solve(np.zeros((TI, M)), np.full((TI, P), np.inf), np.zeros((TF, P)), np.zeros((TF, M)))


def test_a_violating_answer_is_not_solved(setup):
    sys_, _, prob = setup
    th, r = next((t, r) for t in (_normal_theta(prob, sys_, k) for k in range(1, 40, 2))
                 if (r := prob.solve_theta(t, solver="fast")).fast_path)
    z = r.u.ravel().copy()
    assert prob.check(z, th) == "solved"
    z[0] = prob.config.u_max[0] + 2 * BOUND_TOL * max(1.0, abs(prob.config.u_max[0]))
    assert prob.check(z, th) == "out_of_bounds"
    z[0] = np.nan
    assert prob.check(z, th) == "nonfinite"
    r = prob.result(z, th, prob.check(z, th))
    assert r.status == "nonfinite" and np.all(np.isnan(r.u))


@pytest.mark.parametrize("mode", ["offset", "absolute", "increment"])
def test_semidefinite_hessian_is_refused_naming_R(setup, mode):
    _, _, prob = setup
    cfg = prob.config.replace(R=[0.0, 0.0], R_mode=mode)
    with pytest.raises(ConfigError) as e:
        SteeringProblem(prob.predictor, cfg)
    msg = str(e.value)
    assert "[cost] R = [0.0, 0.0]" in msg and f"R_mode {mode!r}" in msg and "not strictly convex" in msg
    # A rate penalty makes it definite again (D is invertible).
    SteeringProblem(prob.predictor, cfg.replace(R_du=[0.1, 0.1]))


def test_equal_bounds_and_duplicate_names_are_refused():
    kw = dict(t_ini=2, t_f=2, m=2, p=1, Q=[1.0], R=[1.0, 1.0])
    with pytest.raises(ConfigError, match=r"\[bounds\] u_min/u_max channel 1: lower 0.2 >= upper 0.2"):
        SteeringConfig(u_min=[0.0, 0.2], u_max=[1.0, 0.2], **kw)
    with pytest.raises(ConfigError, match=r"\[signals\] inputs/outputs channel names must be unique; \['z'\]"):
        SteeringConfig(input_names=("z", "a"), output_names=("z",), **kw)
    with pytest.raises(ConfigError, match=r"\[signals\] input_units must be a list of 2 strings; got 'm'"):
        SteeringConfig(input_units="m", **kw)


def test_unknown_solver_is_refused_before_anything_else(setup):
    _, _, prob = setup
    with pytest.raises(ConfigError, match=r"unknown solver 'daqp'; choose one of \['osqp', 'exact', 'fast'\]"):
        prob.solve(None, None, None, solver="daqp")


_weights = st.sampled_from([0.0, 1e-12, 1e-6, 0.1, 1e3])


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(r=st.tuples(_weights, _weights), r_du=st.tuples(_weights, _weights),
       mode=st.sampled_from(["absolute", "offset", "increment"]), seed=st.integers(0, 10**6))
def test_any_weights_are_refused_or_solved_soundly(setup, r, r_du, mode, seed):
    sys_, _, prob = setup
    cfg = prob.config.replace(R=list(r), R_du=list(r_du), R_mode=mode)
    try:
        p = SteeringProblem(prob.predictor, cfg)
    except ConfigError as e:
        assert "[cost] R = " in str(e) and "not strictly convex" in str(e)
        assert min(r) + min(r_du) < 1e-3  # only nearly semidefinite weights are refused
        return
    rng = np.random.default_rng(seed)
    th = p.theta(rng.uniform(-0.5, 0.5, (TI, M)), 0.5 * rng.standard_normal((TI, P)), 3 * rng.standard_normal((TF, P)),
                 0.1 * rng.standard_normal((TF, M)))[: p.n_theta]
    for solver in ("fast", "exact", "osqp"):
        _assert_sound(p, th, p.solve_theta(th, solver=solver))


_value = st.recursive(
    st.one_of(st.none(), st.booleans(), st.integers(-10**20, 10**20), st.floats(allow_nan=True), st.text(max_size=5)),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=4), inner, max_size=2), max_leaves=6)
_KEYS = [("horizon", "t_ini"), ("horizon", "t_f"), ("horizon", "dt"), ("signals", "inputs"), ("signals", "outputs"),
         ("signals", "input_units"), ("cost", "Q"), ("cost", "R"), ("cost", "R_mode"), ("cost", "R_du"),
         ("cost", "lambda_sigma"), ("bounds", "u_min"), ("bounds", "du_max"), ("predictor", "method"),
         ("predictor", "ridge"), ("codegen", "backend"), ("codegen", "max_iter"), ("codegen", "eps"),
         ("data", "dataset"), ("", "name"), ("artificial_io", "t_a")]


@settings(max_examples=100, deadline=None)
@given(edits=st.lists(st.tuples(st.sampled_from(_KEYS), _value), min_size=1, max_size=3))
def test_any_config_value_is_accepted_or_a_config_error(edits):
    raw = {"name": "fz", "horizon": {"t_ini": 2, "t_f": 2}, "signals": {"inputs": ["a", "b"], "outputs": ["c"]},
           "cost": {"Q": [1.0], "R": [1.0, 1.0]}}
    for (sec, key), v in edits:
        (raw if not sec else raw.setdefault(sec, {}))[key] = v
    try:
        SteeringConfig.from_dict(raw, source="fz.toml")
    except ConfigError as e:
        assert "fz.toml" in str(e)


def test_the_osqp_promise_still_tells_a_state_left_behind(setup):
    # the "no state left behind" tolerance must stay far below the change a left-over answer would make:
    # the previous tick's answer differs from this tick's by orders of magnitude more than it
    sys_, _, prob = setup
    prev = SteeringProblem(prob.predictor, prob.config).solve_theta(_normal_theta(prob, sys_, 4), solver="osqp")
    th = _normal_theta(prob, sys_, 7)
    r = SteeringProblem(prob.predictor, prob.config).solve_theta(th, solver="osqp")
    tol = 2 * osqp_promise(prob, th, r.u)
    assert r.ok and prev.ok and 0.0 < tol < 1e-2 * np.abs(r.u - prev.u).max()
