"""The generated artificial-IO completion against the interpreted ArtificialIO.complete (an independent
solver of the same problem: SVD filter factors + CasADi's daqp vs dual-form Cholesky + DAQP in C)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from support.lti import random_lti
from ddpc_codegen import (CodegenError, DataError, IODataset, ManifestError, SteeringConfig, SteeringProblem,
                          fit_predictor, generate, load_solver)
from ddpc_codegen.codegen import OnlineCompletion
from ddpc_codegen.design.artificial_io import ArtificialIO
from ddpc_codegen.values.solve_result import BOUND_TOL
from ddpc_codegen.experiments.pipeline import default_config

pytestmark = pytest.mark.compiler

TI, TF, M, P, DEPTH, SIGMA = 8, 6, 2, 2, 24, 1e-2
U_MIN, U_MAX, Y_MIN, Y_MAX = [-1.0, -0.8], [1.0, 0.8], [-2.5, -3.0], [2.5, 3.0]


def _cfg(**kw) -> SteeringConfig:
    base = dict(t_ini=TI, t_f=TF, m=M, p=P, Q=[10.0, 4.0], R=[0.2, 0.1], R_mode="offset", lambda_sigma=50.0,
                u_min=U_MIN, u_max=U_MAX, y_min=Y_MIN, y_max=Y_MAX, du_max=[0.6, 0.8], name="artio")
    return SteeringConfig(**(base | kw))


@pytest.fixture(scope="module")
def plant():
    sys_ = random_lti(4, M, P, 7)
    rng = np.random.default_rng(7)
    us, ys = [], []
    for _ in range(4):
        u = 0.5 * rng.standard_normal((150, M))
        y, _ = sys_.simulate(u, rng.standard_normal(4))
        us.append(u)
        ys.append(y + 0.3 + 1e-3 * rng.standard_normal(y.shape))  # affine, slightly noisy: full-rank basis
    return sys_, IODataset(us, ys, 0.005)


@pytest.fixture(scope="module")
def art(plant):
    return ArtificialIO(plant[1], DEPTH, u_min=U_MIN, u_max=U_MAX, y_min=Y_MIN, y_max=Y_MAX)


@pytest.fixture(scope="module")
def problem(plant):
    return SteeringProblem(fit_predictor(plant[1], TI, TF, "lsq"), _cfg())


@pytest.fixture(scope="module")
def folders(problem, art, tmp_path_factory):
    root = tmp_path_factory.mktemp("artio")
    oc = OnlineCompletion(art, SIGMA, 0, 3)
    return {b: generate(problem, root / b, backend=b, name=f"artio_{b}", artificial_io=oc) for b in ("daqp", "osqp")}


@pytest.fixture(scope="module")
def completers(folders):
    return {b: load_solver(f).artificial_io for b, f in folders.items()}


def _window(plant, L: int, scale: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    sys_ = plant[0]
    rng = np.random.default_rng(seed)
    u = scale * rng.standard_normal((L, M))
    y, _ = sys_.simulate(u, scale * rng.standard_normal(4))
    return u, y + 0.3


def _kkt_fill(art, u, y, miss, got) -> np.ndarray:
    """The bounded optimum re-solved exactly at the active set ``got`` ends with (KKT system, numpy):
    CasADi's daqp stops at its own primal tolerance (~1e-9 apart), the exact solution does not."""
    L, d = len(u), M + P
    mask = np.broadcast_to(np.asarray(miss).reshape(L, -1), (L, d)).reshape(-1)
    B, b = art.basis[: L * d], np.hstack([u, y]).reshape(-1)[~mask]
    BK, BF = B[~mask], B[mask]
    lo, hi = np.tile(art.lo, L)[mask], np.tile(art.hi, L)[mask]
    fill = np.hstack([got.u, got.y]).reshape(-1)[mask]
    act = (np.abs(fill - lo) < 1e-7) | (np.abs(fill - hi) < 1e-7)
    bound = np.where(np.abs(fill - lo) < 1e-7, lo, hi)[act]
    lam, r, na = art.n_columns * SIGMA**2, B.shape[1], int(act.sum())
    kkt = np.block([[2 * (lam * np.eye(r) + BK.T @ BK), BF[act].T], [BF[act], np.zeros((na, na))]])
    z = np.linalg.solve(kkt, np.r_[2 * BK.T @ b, bound])[:r]
    return BF @ z


def _check_equal(art, gen, u, y, miss, replace_known):
    ref = art.complete(u, y, miss, replace_known=replace_known, noise_level=SIGMA)
    got = gen.complete(u, y, miss, replace_known=replace_known, noise_level=SIGMA)
    assert got.bounded == ref.bounded
    assert (got.status == "solved") == (ref.status == "solved"), (got.status, ref.status)
    # unbounded fills: <= 1e-9. Bounded QP: both active-set solvers end at round-off of an ill-conditioned
    # KKT system (cond ~1e8 here), measured ~1e-9 apart: 1e-8, and the generated fill is also compared
    # with the exact optimum at its active set
    tol = 1e-8 if got.bounded else 1e-9
    np.testing.assert_allclose(got.u, ref.u, rtol=0, atol=tol)
    np.testing.assert_allclose(got.y, ref.y, rtol=0, atol=tol)
    if got.bounded and got.status == "solved":
        exact = _kkt_fill(art, u, y, miss, got)
        mask = np.broadcast_to(np.asarray(miss).reshape(len(u), -1), (len(u), M + P)).reshape(-1)
        np.testing.assert_allclose(np.hstack([got.u, got.y]).reshape(-1)[mask], exact, rtol=0, atol=1e-8)
    assert got.residual == pytest.approx(ref.residual, abs=tol)
    if got.status == "solved":  # the verified-result rule: a solved fill is within every bound
        W, mask = np.hstack([got.u, got.y]), np.broadcast_to(np.asarray(miss).reshape(len(u), -1), (len(u), M + P))
        lo, hi = np.r_[U_MIN, Y_MIN], np.r_[U_MAX, Y_MAX]
        tol = BOUND_TOL * np.maximum(1.0, np.abs(np.r_[lo, hi]))
        assert np.all(W[mask] >= np.broadcast_to(lo - tol[: M + P], W.shape)[mask])
        assert np.all(W[mask] <= np.broadcast_to(hi + tol[M + P :], W.shape)[mask])
    return got


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(L=st.integers(2, DEPTH), start=st.integers(0, DEPTH), run=st.integers(1, 12),
       scale=st.sampled_from([0.2, 0.6, 1.5]), replace_known=st.booleans(), seed=st.integers(0, 10_000),
       backend=st.sampled_from(["daqp", "osqp"]))
def test_generated_completion_equals_interpreted_on_ground_runs(plant, art, completers, L, start, run, scale,
                                                                replace_known, seed, backend):
    u, y = _window(plant, L, scale, seed)
    miss = np.zeros(L, dtype=bool)
    miss[min(start, L - 1) : min(start, L - 1) + run] = True
    _check_equal(art, completers[backend], u, y, miss, replace_known)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(L=st.integers(2, DEPTH), density=st.floats(0.05, 0.9), scale=st.sampled_from([0.3, 1.5]),
       replace_known=st.booleans(), seed=st.integers(0, 10_000))
def test_generated_completion_equals_interpreted_on_entry_masks(plant, art, completers, L, density, scale,
                                                                replace_known, seed):
    u, y = _window(plant, L, scale, seed)
    miss = np.random.default_rng(seed + 1).random((L, M + P)) < density
    _check_equal(art, completers["daqp"], u, y, miss, replace_known)



@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(L=st.integers(1, DEPTH), scale=st.sampled_from([0.2, 0.6, 1.5]), replace_known=st.booleans(),
       noisy=st.booleans(), seed=st.integers(0, 10_000), backend=st.sampled_from(["daqp", "osqp"]))
def test_generated_completion_equals_interpreted_on_windows_without_missing_samples(
        plant, art, completers, L, scale, replace_known, noisy, seed, backend):
    """The denoised windows (nothing missing): the generated operator solves them with the leading block of
    a Cholesky factor computed at generation; the same fit and residual as the interpreted one."""
    u, y = _window(plant, L, scale, seed)
    if noisy:
        y = y + np.random.default_rng(seed).normal(0.0, SIGMA, y.shape)
    got = _check_equal(art, completers[backend], u, y, np.zeros(L, dtype=bool), replace_known)
    assert got.status == "solved" and not got.bounded

def test_active_bounds_are_solved_by_the_bounded_qp(plant, art, completers):
    bounded = 0
    for seed in range(40):
        u, y = _window(plant, 20, 1.5, seed)
        miss = np.zeros(20, dtype=bool)
        miss[6:14] = True
        bounded += _check_equal(art, completers["daqp"], u, y, miss, False).bounded
    assert bounded >= 5  # the case the test is for occurs (large windows leave the u bounds)


def test_noise_level_and_window_checks(plant, completers):
    gen = completers["daqp"]
    assert (gen.depth, gen.m, gen.p, gen.noise_level) == (DEPTH, M, P, SIGMA)
    u, y = _window(plant, 10, 0.3, 1)
    with pytest.raises(DataError, match="compiled for noise_level"):
        gen.complete(u, y, np.zeros(10, bool), noise_level=0.0)
    with pytest.raises(DataError, match="depth"):
        gen.complete(*_window(plant, DEPTH + 1, 0.3, 1), np.zeros(DEPTH + 1, bool))
    y[2, 0] = np.nan
    with pytest.raises(DataError, match="NaN"):
        gen.complete(u, y, np.zeros(10, bool))
    miss = np.zeros(10, bool)
    miss[2] = True
    assert gen.complete(u, y, miss).status == "solved"  # NaN where the sample is missing is fine


def test_manifest_records_the_completion_and_the_binary_is_the_authority(folders, art):
    folder = folders["daqp"]
    man = json.loads((folder / "manifest.json").read_text())
    entry = man["artificial_io"]
    assert (entry["depth"], entry["rank"], entry["m"], entry["p"]) == (DEPTH, art.rank, M, P)
    assert entry["lambda"] == art.n_columns * SIGMA**2 and entry["noise_level"] == SIGMA
    assert entry["lo"] == U_MIN + Y_MIN and entry["t_d_online"] == 0 and entry["min_ascent"] == 3
    for key, val in (("noise_level", 2e-2), ("rank", art.rank - 1), ("hi", U_MAX + [9.0, 3.0])):
        edited = json.loads(json.dumps(man))
        edited["artificial_io"][key] = val
        (folder / "manifest.json").write_text(json.dumps(edited))
        try:
            with pytest.raises(ManifestError, match=f"artificial_io.{key}"):
                load_solver(folder)
        finally:
            (folder / "manifest.json").write_text(json.dumps(man))
    assert load_solver(folder).artificial_io is not None


def test_zero_noise_level_is_refused_at_codegen(problem, art, tmp_path):
    with pytest.raises(CodegenError, match="noise level > 0"):
        generate(problem, tmp_path / "z", name="artio_zero", artificial_io=OnlineCompletion(art, 0.0))
    assert not (tmp_path / "z" / "manifest.json").exists()


def test_a_flying_solver_has_no_completion(problem, tmp_path):
    assert load_solver(generate(problem, tmp_path / "f", name="artio_none")).artificial_io is None


@pytest.fixture(scope="module")
def hop_log(tmp_path_factory):
    """A short raw hopping log (25 s, ~30 hops) with phase labels, as the simulator records it."""
    from ddpc_codegen.experiments.pipeline import CollectSpec, collect

    res = collect("hopping", CollectSpec(duration=25.0, seed=2, amplitude=(0.01, 0.02, 0.02)))
    path = tmp_path_factory.mktemp("hoplog") / "hop_raw.npz"
    res.to_dataset("none").save(path)
    return path


def test_cli_builds_a_hopping_artifact_with_its_completion_from_a_raw_log(hop_log, tmp_path, capsys):
    from ddpc_codegen.cli.main import main as cli_main
    from ddpc_codegen.design.hopping_data import ArtificialIOSpec

    assert cli_main(["codegen", str(default_config("hopping")), "--dataset", str(hop_log), "--out", str(tmp_path),
                     "--quiet"]) == 0
    solver = load_solver(tmp_path / "hopping")
    gen = solver.artificial_io
    spec = ArtificialIOSpec(**SteeringConfig.from_toml(default_config("hopping")).artificial_io)
    assert gen.noise_level == spec.noise_level_online and (gen.m, gen.p) == (3, 3)
    assert (gen.t_d_online, gen.min_ascent) == (spec.t_d_online, spec.min_ascent)
    assert gen.window_settings()["refit_residual"] == spec.refit_residual == 6.5e-3  # manifest -> runtime window
    # the online window of a recorded hop: ground phase + the first ascent samples
    from ddpc_codegen.values.phases import ground_runs

    raw = IODataset.load(hop_log)
    ph = raw.phases[0]
    g0, g1 = ground_runs(ph)[2]
    miss = np.zeros(g1 + 12 - g0, dtype=bool)
    miss[: g1 - g0] = True
    c = gen.complete(raw.u[0][g0 : g1 + 12], raw.y[0][g0 : g1 + 12], miss, replace_known=True)
    assert c.status == "solved" and c.u.shape == (len(miss), 3) and np.all(np.isfinite(c.y))


def test_cli_refuses_a_hopping_config_without_phase_labels(hop_log, tmp_path, capsys):
    from ddpc_codegen.cli.main import main as cli_main

    raw = IODataset.load(hop_log)
    IODataset(list(raw.u), list(raw.y), raw.dt, input_names=raw.input_names, output_names=raw.output_names,
              input_units=raw.input_units, output_units=raw.output_units).save(tmp_path / "nophase.npz")
    assert cli_main(["codegen", str(default_config("hopping")), "--dataset", str(tmp_path / "nophase.npz"),
                     "--out", str(tmp_path)]) != 0
    assert "has no phase labels" in capsys.readouterr().err and not (tmp_path / "hopping").exists()


def test_the_standalone_example_calls_the_completion_from_c(folders, tmp_path):
    from ddpc_codegen.codegen import standalone

    if standalone.tool("make") is None:
        pytest.skip("no make")
    for backend in ("daqp", "osqp"):  # osqp: DAQP bundled for the completion, both libraries link
        folder = standalone.relocated_copy(folders[backend], tmp_path / backend)
        run = standalone.run_example(standalone.make_example(folder), standalone.vectors_file(folder))
        assert run.returncode == 0 and run.mismatches == 0
        assert f"artio_{backend}: artificial IO over {TI} samples: solved" in run.output


def test_the_runtime_hopping_window_runs_on_the_generated_completion(plant, art, completers):
    from ddpc_codegen.values.phases import ASCENT, DESCENT, GROUND
    from ddpc_codegen.runtime.hopping import HoppingWindow

    u, y = _window(plant, 120, 0.3, 4)
    ph = np.resize(np.r_[[DESCENT] * 30, [GROUND] * 8, [ASCENT] * 30], 120)
    wins = [HoppingWindow(op, TI, 0, 3, SIGMA) for op in (completers["daqp"], art)]
    filled = 0
    for k in range(TI, 120):
        a, b = (w.window(u[:k], y[:k], ph[:k]) for w in wins)
        assert type(a) is type(b)
        if isinstance(a, tuple):
            filled += 1
            np.testing.assert_allclose(np.hstack(a), np.hstack(b), rtol=0, atol=1e-8)
        else:
            assert a == b
    assert filled >= 8 and wins[0].counts == wins[1].counts
