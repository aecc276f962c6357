"""Generated C solvers against the interpreted design layer (independent solvers, same QP)."""

import json
import socket
from pathlib import Path

import numpy as np
import osqp
import pytest
import scipy.sparse as sp
from scipy.optimize import nnls

from support.lti import random_lti
from ddpc_codegen import (DataError, IODataset, ManifestError, SteeringConfig, SteeringProblem, fit_predictor,
                          generate, load_solver)
from ddpc_codegen.cli.main import main as cli_main

pytestmark = pytest.mark.compiler

TI, TF, M, P = 10, 8, 2, 2


def _config(**kw):
    base = dict(t_ini=TI, t_f=TF, m=M, p=P, Q=[10.0, 4.0], R=[0.2, 0.1], R_mode="offset", lambda_sigma=50.0,
                u_min=[-1.5, -1.2], u_max=[1.5, 1.2], y_min=[-6.0, -6.0], y_max=[6.0, 6.0], du_max=[0.6, 0.8],
                name="cgtest")
    return SteeringConfig(**(base | kw))


@pytest.fixture(scope="module")
def plant():
    sys_ = random_lti(4, M, P, 5)
    rng = np.random.default_rng(5)
    u = rng.standard_normal((400, M))
    y, _ = sys_.simulate(u, rng.standard_normal(4))
    return sys_, IODataset(u, y, 0.005)


@pytest.fixture(scope="module")
def problem(plant):
    return SteeringProblem(fit_predictor(plant[1], TI, TF, "pem"), _config())


@pytest.fixture(scope="module")
def solvers(problem, tmp_path_factory):
    root = tmp_path_factory.mktemp("gen")
    return {b: load_solver(generate(problem, root / b, backend=b, name=f"cg_{b}")) for b in ("daqp", "osqp")}


def _draws(problem, plant, n, seed):
    """A closed-loop-like stream: sliding windows of a trajectory, alternating easy and aggressive targets."""
    sys_ = plant[0]
    rng = np.random.default_rng(seed)
    u = rng.uniform(-0.4, 0.4, (n + TI, M))
    y, _ = sys_.simulate(u, 0.3 * rng.standard_normal(4))
    out = []
    for k in range(n):
        scale = 0.05 if k % 3 else 4.0
        y_des = y[k + TI - 1] + scale * rng.standard_normal((TF, P))
        u_nom = np.tile(u[k + TI - 1], (TF, 1))
        out.append(problem.theta(u[k : k + TI], y[k : k + TI], y_des, u_nom))
    return out


def _kkt(problem, th, z, tol=1e-7):
    """Max KKT residual of z for the QP at theta: stationarity with sign-correct multipliers, feasibility."""
    q, l, u = problem.qp_vectors(th)
    A = problem.A
    Az = A @ z
    lo, hi = np.isclose(Az, l, atol=tol), np.isclose(Az, u, atol=tol)
    g = problem.P @ z + q
    # P z + q + A_hi' lam - A_lo' mu = 0 with lam, mu >= 0 (NNLS: sign-correct even when degenerate)
    B = np.hstack([A[hi].T, -A[lo].T])
    if B.shape[1]:
        _, res = nnls(B, -g, maxiter=5000)
    else:
        res = np.linalg.norm(g)
    primal_viol = max(0.0, (l - Az).max(), (Az - u).max())
    return res / max(1.0, np.linalg.norm(q)), primal_viol


def test_daqp_matches_exact_interpreted_over_200_draws(problem, plant, solvers):
    s = solvers["daqp"]
    s.reset()
    fast = active = 0
    for th in _draws(problem, plant, 220, 1):
        r = s.solve_theta(th)
        ref = problem.solve_theta(th, solver="exact")
        assert r.ok and ref.ok
        assert np.abs(r.u - ref.u).max() <= 1e-8
        np.testing.assert_allclose(r.y_pred, ref.y_pred, atol=1e-8)
        np.testing.assert_allclose(r.sigma, ref.sigma, atol=1e-8)
        res, primal = _kkt(problem, th, r.u.ravel())
        assert res <= 1e-8 and primal <= 1e-8
        fast += r.fast_path
        active += not r.fast_path
    assert fast >= 10 and active >= 100  # both regimes exercised


def test_rate_penalty_generated_equals_interpreted(problem, plant, tmp_path):
    # R_du, R_ddu, R_de and R_doffset only change P and the affine q map; the generated code must follow without special cases.
    prob = SteeringProblem(problem.predictor, _config(R_du=[5.0, 1.0], R_ddu=[0.0, 3.0], R_de=[2.0, 0.0],
                                                      R_doffset=[0.0, 4.0], name="cg_rdu"))
    s = load_solver(generate(prob, tmp_path / "rdu", backend="daqp"))
    assert s.manifest["weights"]["R_du"] == [[5.0, 0.0], [0.0, 1.0]]
    assert s.manifest["weights"]["R_ddu"] == [[0.0, 0.0], [0.0, 3.0]]
    assert s.manifest["weights"]["R_de"] == [[2.0, 0.0], [0.0, 0.0]]
    assert s.manifest["weights"]["R_doffset"] == [[0.0, 0.0], [0.0, 4.0]]
    for th in _draws(prob, plant, 40, 7):
        r, ref = s.solve_theta(th), prob.solve_theta(th, solver="exact")
        assert r.ok and ref.ok and np.abs(r.u - ref.u).max() <= 1e-8


def test_fast_path_is_kkt_with_empty_active_set(problem, plant, solvers):
    s = solvers["daqp"]
    n_fast = 0
    for th in _draws(problem, plant, 60, 2):
        r = s.solve_theta(th)
        if r.fast_path:
            n_fast += 1
            q, l, u = problem.qp_vectors(th)
            z = r.u.ravel()
            assert np.linalg.norm(problem.P @ z + q) <= 1e-9 * max(1.0, np.linalg.norm(q))
            assert problem.is_feasible(z, l, u, tol=1e-9)
            assert r.iterations == 0
    assert n_fast > 0


def test_osqp_backend_runs_interpreted_osqps_admm_then_refines_to_the_exact_optimum(problem, plant, solvers):
    """Same ADMM (same settings, same warm-start sequence: same iteration counts as osqp-python), then the
    active-set refinement: answers equal the exact optimum; an unrefined answer is still inside the bounds."""
    s = solvers["osqp"]
    st = s.manifest["settings"]
    s.reset()
    ref = osqp.OSQP()
    q0, l0, u0 = problem.qp_vectors(np.zeros(problem.n_theta))
    ref.setup(sp.triu(sp.csc_matrix(problem.P), format="csc"), q0, sp.csc_matrix(problem.A),
              np.maximum(np.r_[problem.lb_u, problem.lg0], -1e30), np.minimum(np.r_[problem.ub_u, problem.ug0], 1e30),
              verbose=False, eps_abs=st["eps"], eps_rel=st["eps"], max_iter=st["max_iter"], rho=st["rho"],
              adaptive_rho=False, polishing=False, warm_starting=True)
    n_qp = refined = same_iter = 0
    for th in _draws(problem, plant, 200, 3):
        r = s.solve_theta(th)
        if r.fast_path:
            continue  # the C path skipped the QP; the interpreted one keeps its warm start untouched too
        n_qp += 1
        q, l, u = problem.qp_vectors(th)
        ref.update(q=q, l=np.maximum(l, -1e30), u=np.minimum(u, 1e30))
        x = ref.solve(raise_error=False)
        same_iter += r.iterations == x.info.iter
        exact = problem.solve_theta(th, solver="exact")
        if r.ok:
            refined += r.info["refined"]
            tol = 1e-7 if r.info["refined"] else 5e-3
            assert np.abs(r.u - exact.u).max() <= tol
            assert r.info["max_violation"] <= s.feas_tol
        else:
            assert np.isnan(r.u).all()
            ref.warm_start(x=np.zeros(problem.n_u), y=np.zeros(problem.n_c))  # C dropped its warm start
    assert n_qp >= 50 and same_iter >= 0.9 * n_qp and refined >= 0.9 * n_qp


def test_bad_input_refused_before_c(solvers):
    s = solvers["daqp"]
    z = np.zeros
    with pytest.raises(DataError, match="u_ini contains NaN or inf; refusing to steer on it"):
        s.solve(np.full((TI, M), np.nan), z((TI, P)), z((TF, P)), z((TF, M)))
    with pytest.raises(DataError, match=r"y_des must be \(8, 2\) time-major or stacked \(16,\); got shape \(7, 2\)"):
        s.solve(z((TI, M)), z((TI, P)), z((7, P)), z((TF, M)))
    with pytest.raises(DataError, match="R_mode 'offset' needs u_nom"):
        s.solve(z((TI, M)), z((TI, P)), z((TF, P)))
    with pytest.raises(DataError, match=r"theta must have shape"):
        s.solve_theta(np.zeros(3))


@pytest.mark.parametrize("backend", ["daqp", "osqp"])
def test_infeasible_returns_status_never_garbage_and_recovers(problem, plant, solvers, backend):
    s = solvers[backend]
    u_ini = np.full((TI, M), 5.0)  # far outside the box with a rate bound: no feasible first step
    r = s.solve(u_ini, np.zeros((TI, P)), np.zeros((TF, P)), np.zeros((TF, M)))
    assert not r.ok and r.status in ("infeasible", "max_iter", "unverified") and np.isnan(r.u).all()
    assert np.isnan(r.y_pred).all()
    th = _draws(problem, plant, 3, 4)[1]
    ok = s.solve_theta(th)
    assert ok.ok and np.abs(ok.u - problem.solve_theta(th, solver="exact").u).max() <= (1e-8 if backend == "daqp" else 5e-3)


def test_regenerating_gives_identical_bytes(problem, tmp_path):
    for backend in ("daqp", "osqp"):
        a = generate(problem, tmp_path / f"a_{backend}", backend=backend, name="same", compile=False)
        b = generate(problem, tmp_path / f"b_{backend}", backend=backend, name="same", compile=False)
        fa = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
        fb = sorted(p.relative_to(b) for p in b.rglob("*") if p.is_file())
        assert fa == fb and len(fa) >= 6
        for rel in fa:
            assert (a / rel).read_bytes() == (b / rel).read_bytes(), rel


def test_manifest_contents_and_mismatch_refused(problem, plant, solvers, tmp_path):
    s = solvers["daqp"]
    man = s.manifest
    assert man["dims"] == {"m": M, "p": P, "t_ini": TI, "t_f": TF, "n_u": M * TF, "n_z": M * TF, "n_theta": problem.n_theta,
                           "n_g": problem.n_g, "n_y": P * TF, "n_sigma": P * TI}
    assert man["knots"] is None  # every sample free
    assert man["config_hash"] == problem.config.digest and man["predictor_hash"] == problem.predictor.digest
    assert man["bounds"]["u_max"] == [1.5, 1.2] and man["versions"]["casadi"] and man["compiler"]["flags"]
    assert "-march=native" not in man["compiler"]["flags"]
    load_solver(s.folder, config=problem.config, predictor_hash=problem.predictor.digest)
    other = _config(Q=[11.0, 4.0])
    with pytest.raises(ManifestError, match="was generated from a different configuration"):
        load_solver(s.folder, config=other)
    with pytest.raises(ManifestError, match="different predictor"):
        load_solver(s.folder, predictor_hash="0" * 64)


def test_tampered_or_missing_artifacts_refused(problem, tmp_path):
    # (the name of the solvers fixture: builds of one problem under one name share their compiled objects)
    out = generate(problem, tmp_path / "t", backend="daqp", name="cg_daqp")
    src = out / "cg_daqp_data.c"
    src.write_text(src.read_text() + "\n/* edited */\n")
    with pytest.raises(ManifestError, match="cg_daqp_data.c differs from the one the solver was built from"):
        load_solver(out)
    man = json.loads((out / "manifest.json").read_text())
    man["format_version"] = 99
    (out / "manifest.json").write_text(json.dumps(man))
    with pytest.raises(ManifestError, match="regenerate the solver"):
        load_solver(out)
    (out / "manifest.json").write_text("{not json")
    with pytest.raises(ManifestError, match="is not valid JSON"):
        load_solver(out)
    with pytest.raises(ManifestError, match="has no manifest.json"):
        load_solver(tmp_path)


def test_build_works_without_network(problem, tmp_path, monkeypatch):
    def refuse(*a, **k):
        raise OSError("network access attempted during codegen")

    monkeypatch.setattr(socket.socket, "connect", refuse)
    monkeypatch.setattr(socket, "create_connection", refuse)
    for backend in ("daqp", "osqp"):
        out = generate(problem, tmp_path / backend, backend=backend, name=f"cg_{backend}")
        assert load_solver(out).solve_theta(np.zeros(problem.n_theta)).ok


def test_cli_codegen(plant, tmp_path, capsys):
    import dataclasses

    from firmware_bridge.preflight import PreflightError, check_solver_loop

    _, ds = plant
    # What a bridge tick log records about its loop goes into the manifest, and the bridge checks it.
    ds = dataclasses.replace(ds, metadata={**ds.metadata, "thrust_field": "climb_rate", "autopilot": "ardupilot"})
    ds.save(tmp_path / "d.npz")
    cfg = tmp_path / "c.toml"
    cfg.write_text(f"""
name = "clitest"
[horizon]
t_ini = {TI}
t_f = {TF}
[signals]
inputs = ["u0", "u1"]  # the dataset's channel names (codegen checks them)
outputs = ["y0", "y1"]
[cost]
Q = [10.0, 4.0]
R = [0.2, 0.1]
[bounds]
u_min = [-1.5, -1.2]
u_max = [1.5, 1.2]
[predictor]
method = "lsq"
[data]
dataset = "d.npz"
""")
    assert cli_main(["codegen", str(cfg), "--out", str(tmp_path / "gen"), "--quiet"]) == 0
    out = Path(capsys.readouterr().out.strip())
    assert out == tmp_path / "gen" / "clitest" and (out / "manifest.json").exists()
    man = load_solver(out, config=cfg).manifest
    assert man["backend"] == "daqp"
    assert man["dataset"]["thrust_field"] == "climb_rate" and man["dataset"]["autopilot"] == "ardupilot"
    assert check_solver_loop(man, "ardupilot", "climb_rate") is None
    # the recording's noise estimate is recorded; no limit in this config, so no warning
    assert len(man["dataset"]["output_noise"]) == 2 and man["dataset"]["noise_warning"] is None
    assert "came from ardupilot, this vehicle is px4" in check_solver_loop(man, "px4", "climb_rate")
    # a recording codegen flagged as noisier than the config was tuned for: the bridge repeats it
    noisy = {**man, "dataset": {**man["dataset"], "noise_warning": "WARNING: the recording is noisier"}}
    assert check_solver_loop(noisy, "ardupilot", "climb_rate") == "codegen said: WARNING: the recording is noisier"
    with pytest.raises(PreflightError, match="thrust was a climb rate .*d.npz.*reads it as a thrust"):
        check_solver_loop(man, "ardupilot", "thrust")
    (tmp_path / "d.npz").unlink()
    assert cli_main(["codegen", str(cfg), "--out", str(tmp_path / "gen"), "--quiet"]) == 2
    assert "dataset file" in capsys.readouterr().err


def test_missing_compiler_gives_clear_error(problem, tmp_path, monkeypatch):
    from ddpc_codegen import CodegenError

    monkeypatch.setenv("CC", str(tmp_path / "no-such-cc"))
    with pytest.raises(CodegenError, match="compiling solver 'nocc' failed .* Is a C compiler"):
        generate(problem, tmp_path / "x", backend="daqp", name="nocc")


def test_bad_names_and_backends(problem, tmp_path):
    from ddpc_codegen import CodegenError

    with pytest.raises(CodegenError, match="must start with a letter"):
        generate(problem, tmp_path / "x", name="1-bad name", compile=False)
    with pytest.raises(CodegenError, match="unknown backend 'cvx'"):
        generate(problem, tmp_path / "x", backend="cvx", compile=False)


def test_regenerating_in_place_loads_the_new_binary(problem, tmp_path):
    """A rebuilt solver in the same folder must not be served by the library already loaded."""
    out = tmp_path / "same"
    a = load_solver(generate(problem, out, backend="daqp", name="cg_daqp"))
    th = np.zeros(problem.n_theta)
    th[problem.n_w : problem.n_w + P * TF] = 50.0  # a far target: the u bound is active
    ua = a.solve_theta(th).u.max()
    tighter = SteeringProblem(problem.predictor, problem.config.replace(u_max=[0.5, 0.5]))
    b = load_solver(generate(tighter, out, backend="daqp", name="cg_daqp"))
    ub = b.solve_theta(th).u.max()
    assert ua > 0.5 + 1e-6 and ub <= 0.5 + 1e-9
    assert a.manifest["module"] != b.manifest["module"]


def test_missing_daqp_source_cache_names_the_fix(problem, tmp_path, monkeypatch):
    from ddpc_codegen import CodegenError

    monkeypatch.setenv("DDPC_CODEGEN_CACHE", str(tmp_path / "empty-cache"))
    with pytest.raises(CodegenError, match=r"DAQP 0.11.0 C sources are not in the cache .*run `make install` once"):
        generate(problem, tmp_path / "x", backend="daqp", name="nocache", compile=False)


def test_templates_render_strictly():
    """A name a rendered branch reads and the context lacks is an error (StrictUndefined), and so is a value no
    branch of the template (or of what it includes) ever reads."""
    from ddpc_codegen import CodegenError
    from ddpc_codegen.codegen.render import placeholders, render

    names = placeholders("qp.h.in")
    ctx = {k: "x" for k in names}
    assert "int x_qp_init(x_workspace *ws);" in render("qp.h.in", **ctx)
    with pytest.raises(CodegenError, match=r"template qp.h.in: missing value \('name' is undefined\)"):
        render("qp.h.in", **{k: v for k, v in ctx.items() if k != "name"})
    with pytest.raises(CodegenError, match=r"unused values \['typo'\]"):
        render("qp.h.in", typo=1, **ctx)
    # names read only inside an include or a branch not taken count as used, and are required once taken
    assert {"n_uu", "daqp_words"} <= placeholders("solver.h.in")
    with pytest.raises(CodegenError, match=r"template cffi_glue.c.in: missing value \('adapt' is undefined\)"):
        render("cffi_glue.c.in", name="x")


def test_noise_warning_names_the_channels_and_the_limit(tmp_path):
    """A recording noisier than the config's [data] max_output_noise is flagged (codegen prints it and the
    manifest keeps it): a predictor fitted on it can steer worse than none with every QP solved."""
    from ddpc_codegen.cli.codegen import noise_warning

    f = tmp_path / "c.toml"
    f.write_text("""
[horizon]
t_ini = 4
t_f = 3
[signals]
inputs = ["a"]
outputs = ["z", "pitch"]
output_units = ["m", "rad"]
[cost]
Q = [1.0, 1.0]
R = [0.1]
[data]
max_output_noise = [5e-4, 1e-3]
""")
    cfg = SteeringConfig.from_toml(f)
    assert noise_warning(cfg, np.array([4e-4, 9e-4])) is None
    w = noise_warning(cfg, np.array([2e-3, 9e-4]))
    assert w and "z 2 mm, pitch 0.9 mrad" in w and "max_output_noise z 0.5 mm, pitch 1 mrad" in w
    assert noise_warning(cfg.replace(max_output_noise=None), np.array([1.0, 1.0])) is None


def test_predict_is_the_interpreted_predictors_and_the_plants_response_to_any_references(problem, plant, solvers):
    """``GeneratedSolver.predict`` under references the solver did not choose (what the loop applied): the
    interpreted predictor's answer, and the LTI plant's exact response within the fit's own error."""
    sys_ = plant[0]
    rng = np.random.default_rng(11)
    for _ in range(5):
        u = rng.uniform(-0.4, 0.4, (TI + TF, M))
        y, _ = sys_.simulate(u, 0.3 * rng.standard_normal(4))
        ref = problem.predictor.predict(u[:TI], y[:TI], u[TI:])[0]
        for s in solvers.values():
            got = s.predict(u[:TI], y[:TI], u[TI:])
            np.testing.assert_allclose(got, ref, atol=1e-9)
            assert np.abs(got - y[TI:]).max() <= 1e-2 * np.abs(y[TI:]).max()
