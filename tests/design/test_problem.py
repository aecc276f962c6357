import casadi as ca
import numpy as np
import pytest

from support.lti import random_lti
from ddpc_codegen import (ConfigError, DataError, DeePCProblem, IODataset, SteeringConfig,
                          SteeringProblem, fit_predictor)

TI, TF, M, P = 6, 10, 2, 2


@pytest.fixture(scope="module")
def plant():
    sys_ = random_lti(4, M, P, 11)
    rng = np.random.default_rng(11)
    u = rng.standard_normal((500, M))
    y, _ = sys_.simulate(u, rng.standard_normal(4))
    return sys_, IODataset(u, y, 0.005)


def _cfg(mode="offset", bounds=True, **kw):
    b = dict(u_min=[-1.5, -1.2], u_max=[1.5, 1.2], y_min=[-6.0, -6.0], y_max=[6.0, 6.0], du_max=[0.6, 0.8]) if bounds else {}
    base = dict(Q=[10.0, 4.0], R=[0.2, 0.1], lambda_sigma=50.0)
    return SteeringConfig(t_ini=TI, t_f=TF, m=M, p=P, R_mode=mode, **(base | b | kw))


def _params(sys_, rng, scale=1.0):
    u = rng.uniform(-0.4, 0.4, (TI, M))  # inside the u box, so the rate bound is feasible
    y, _ = sys_.simulate(u, 0.3 * rng.standard_normal(4))
    y += 0.01 * rng.standard_normal(y.shape)  # a slightly noisy y_ini makes sigma matter
    return u, y, scale * rng.standard_normal((TF, P)), 0.3 * rng.standard_normal((TF, M))


def _solve_direct(prob: SteeringProblem, u_ini, y_ini, y_des, u_nom):
    """DDPC-Flying as written: variables (u, y, sigma), [y; sigma] = G [w; u], solved by qpOASES."""
    c, pr = prob.config, prob.predictor
    nu, ny, ns = M * TF, P * TF, P * TI
    u, y, s = ca.SX.sym("u", nu), ca.SX.sym("y", ny), ca.SX.sym("s", ns)
    w = np.concatenate([np.ravel(u_ini), np.ravel(y_ini)])
    e = y - np.ravel(y_des)
    J = ca.mtimes([e.T, np.kron(np.eye(TF), c.Q), e]) + c.lambda_sigma * ca.dot(s, s)
    D = np.eye(nu) - np.eye(nu, k=-M)
    d0 = np.r_[np.ravel(u_ini)[-M:], np.zeros(nu - M)]
    ru = {"absolute": u, "offset": u - np.ravel(u_nom), "increment": ca.mtimes(D, u) - d0}[c.R_mode]
    J += ca.mtimes([ru.T, np.kron(np.eye(TF), c.R), ru])
    du = ca.mtimes(D, u) - d0
    J += ca.mtimes([du.T, np.kron(np.eye(TF), c.R_du), du])
    # changes of the offset u - u_nom written out, the nominal's change before the horizon as its first one
    un = np.ravel(u_nom)
    dn = np.r_[un[M : 2 * M] - un[:M], un[M:] - un[:-M]]
    J += ca.mtimes([(du - dn).T, np.kron(np.eye(TF), c.R_doffset), du - dn])
    # second differences written out: u_k - 2 u_(k-1) + u_(k-2), the earlier ones from u_ini
    ext = ca.vertcat(np.ravel(u_ini)[-2 * M :], u)
    ddu = ext[2 * M :] - 2 * ext[M:-M] + ext[: -2 * M]
    J += ca.mtimes([ddu.T, np.kron(np.eye(TF), c.R_ddu), ddu])
    # changes of the tracking error e_k = u_k - y_k (input i against output i), the first from the last applied pair
    e = ca.vertcat(np.ravel(u_ini)[-M:] - np.ravel(y_ini)[-P:][:M], u - y)  # M == P here
    de = e[M:] - e[:-M]
    J += ca.mtimes([de.T, np.kron(np.eye(TF), c.R_de), de])
    g = ca.vertcat(y - pr.Gy_w @ w - ca.mtimes(pr.Gy_u, u), s - pr.Gs_w @ w - ca.mtimes(pr.Gs_u, u),
                   u, y, ca.mtimes(D, u) - d0)
    lb = np.r_[np.zeros(ny + ns), np.tile(c.u_min, TF), np.tile(c.y_min, TF), -np.tile(c.du_max, TF)]
    ub = np.r_[np.zeros(ny + ns), np.tile(c.u_max, TF), np.tile(c.y_max, TF), np.tile(c.du_max, TF)]
    x = ca.vertcat(u, y, s)
    solver = ca.qpsol("direct", "qpoases", {"x": x, "f": J, "g": g}, {"printLevel": "none", "error_on_fail": True})
    return np.array(solver(lbg=lb, ubg=ub)["x"]).ravel()[:nu]


def _agrees_with_direct(prob: SteeringProblem, sys_, seed: int, draws: int, direct: bool = True) -> None:
    """``draws`` parameter draws (small and large y_des in turn): each solves, and (``direct``) equals the
    uncondensed QP written out to 1e-6."""
    rng = np.random.default_rng(seed)
    for k in range(draws):
        args = _params(sys_, rng, scale=0.1 if k % 2 else 4.0)
        res = prob.solve(*args, solver="exact")
        assert res.ok
        if direct:
            assert np.abs(res.u.ravel() - _solve_direct(prob, *args)).max() <= 1e-6


@pytest.mark.parametrize("mode", ["offset", "absolute", "increment"])
def test_condensed_equals_direct_ddpc_flying(plant, mode):
    sys_, ds = plant
    prob = SteeringProblem(fit_predictor(ds, TI, TF, "pem"), _cfg(mode))
    rng = np.random.default_rng(5)
    n_active = 0
    for k in range(20):
        args = _params(sys_, rng, scale=0.1 if k % 2 else 4.0)
        res = prob.solve(*args, solver="exact")
        assert res.ok
        ref = _solve_direct(prob, *args)
        assert np.abs(res.u.ravel() - ref).max() <= 1e-6
        th = prob.theta(*args)
        _, l, ub = prob.qp_vectors(th)
        Az = prob.A @ res.u.ravel()  # [I; A_g] z
        n_active += bool(np.any(np.isclose(Az, l, atol=1e-8) | np.isclose(Az, ub, atol=1e-8)))
    assert 5 <= n_active < 20  # both active and inactive bound draws were exercised


@pytest.mark.parametrize("mode, extra", [("offset", {}), ("increment", {"R_du": [1.0, 0.0]}),
                                         ("absolute", {"knots": [0, 2, 5, TF - 1]})])
def test_second_difference_penalty_equals_direct_and_smooths(plant, mode, extra):
    """R_ddu adds ||u_k - 2 u_(k-1) + u_(k-2)||^2 (the first two against u_ini): equal to the uncondensed QP
    written out, and (knots included) the penalized bending is smaller than without it (an optimum trades the
    rest of the cost for it, it never buys more bending)."""
    sys_, ds = plant
    pred = fit_predictor(ds, TI, TF, "pem")
    prob = SteeringProblem(pred, _cfg(mode, R_ddu=[5.0, 2.0], **extra))
    plain = SteeringProblem(pred, _cfg(mode, **extra))
    _agrees_with_direct(prob, sys_, 23, 8, direct="knots" not in extra)
    args = _params(sys_, np.random.default_rng(2), scale=0.1)
    bend = lambda r: np.sum(np.diff(np.vstack([args[0][-2:], r.u]), 2, axis=0) ** 2 * [5.0, 2.0])  # noqa: E731
    assert bend(prob.solve(*args, solver="exact")) < 0.95 * bend(plain.solve(*args, solver="exact"))


@pytest.mark.parametrize("mode", ["offset", "absolute"])
def test_rate_penalty_on_top_of_any_mode_equals_direct(plant, mode):
    # R_du adds ||du||^2_R_du to the mode's penalty; checked against the uncondensed QP.
    sys_, ds = plant
    prob = SteeringProblem(fit_predictor(ds, TI, TF, "pem"), _cfg(mode, R_du=[3.0, 0.5]))
    plain = SteeringProblem(prob.predictor, _cfg(mode))
    _agrees_with_direct(prob, sys_, 17, 10)
    # The penalty does what it says: smaller steps than without it (same parameters).
    args = _params(sys_, np.random.default_rng(1), scale=0.1)
    du = lambda r: np.diff(np.vstack([args[0][-1:], r.u]), axis=0)  # noqa: E731
    assert np.linalg.norm(du(prob.solve(*args, solver="exact"))) < np.linalg.norm(du(plain.solve(*args, solver="exact")))


@pytest.mark.parametrize("mode", ["offset", "increment"])
def test_tracking_error_rate_penalty_equals_direct_and_calms_the_error_changes(plant, mode):
    """R_de adds ||Δ(u_i - y_i)||^2 (the first change against the last applied pair): equal to the uncondensed QP
    written out, and the penalized changes are smaller than without it."""
    sys_, ds = plant
    prob = SteeringProblem(fit_predictor(ds, TI, TF, "pem"), _cfg(mode, R_de=[4.0, 1.0]))
    plain = SteeringProblem(prob.predictor, _cfg(mode))
    _agrees_with_direct(prob, sys_, 29, 8)
    args = _params(sys_, np.random.default_rng(3), scale=0.1)

    def changes(r) -> float:
        e = np.vstack([args[0][-1:] - args[1][-1:], r.u - r.y_pred])
        return float(np.sum(np.diff(e, axis=0) ** 2 * [4.0, 1.0]))
    assert changes(prob.solve(*args, solver="exact")) < 0.95 * changes(plain.solve(*args, solver="exact"))


@pytest.mark.parametrize("extra", [{}, {"R_du": [1.0, 0.0]}, {"knots": [0, 3, TF - 1]}])
def test_offset_rate_penalty_equals_direct_and_lets_the_references_follow_the_nominal_ramp(plant, extra):
    """R_doffset adds ||Δ(u - u_nom)||^2 (the nominal's change before the horizon taken as its first): equal to
    the uncondensed QP written out, and on a nominal ramp it leaves u closer to the ramp's own increments than
    R_du of the same weight (which charges the ramp itself)."""
    sys_, ds = plant
    pred = fit_predictor(ds, TI, TF, "pem")
    prob = SteeringProblem(pred, _cfg("offset", R_doffset=[30.0, 10.0], **extra))
    _agrees_with_direct(prob, sys_, 31, 8, direct="knots" not in extra)
    u_ini, y_ini, y_des, _ = _params(sys_, np.random.default_rng(4), scale=0.1)
    ramp = u_ini[-1] + 0.04 * np.arange(1, TF + 1)[:, None] * [1.0, -1.0]  # inside the rate bound
    rate = SteeringProblem(pred, _cfg("offset", **(extra | {"R_du": np.add(extra.get("R_du", 0.0), [30.0, 10.0])})))
    # the offset's changes, the first from 0 (the ramp extended back one step is u_ini[-1])
    off = lambda r: np.abs(np.diff(np.vstack([np.zeros((1, M)), r.u - ramp]), axis=0)).sum()  # noqa: E731
    assert off(prob.solve(u_ini, y_ini, y_des, ramp, solver="exact")) < off(rate.solve(u_ini, y_ini, y_des, ramp, solver="exact"))


def test_fast_path_is_exact_and_kkt_holds(plant):
    sys_, ds = plant
    prob = SteeringProblem(fit_predictor(ds, TI, TF, "pem"), _cfg())
    rng = np.random.default_rng(9)
    fast = 0
    for k in range(40):
        args = _params(sys_, rng, scale=0.1 if k % 2 else 4.0)
        th = prob.theta(*args)
        r = prob.solve_theta(th, solver="fast")
        ex = prob.solve_theta(th, solver="exact")
        assert np.abs(r.u - ex.u).max() <= 1e-9
        if r.fast_path:
            fast += 1
            q, l, ub = prob.qp_vectors(th)
            z = r.u.ravel()
            assert np.linalg.norm(prob.P @ z + q) <= 1e-9 * max(1.0, np.linalg.norm(q))  # stationarity, no multipliers
            assert np.all(prob.A @ z >= l - 1e-9) and np.all(prob.A @ z <= ub + 1e-9)
    assert 0 < fast < 40


def test_osqp_interpreted_matches_exact(plant):
    sys_, ds = plant
    prob = SteeringProblem(fit_predictor(ds, TI, TF, "pem"), _cfg("increment"))
    rng = np.random.default_rng(3)
    for k in range(10):
        args = _params(sys_, rng, scale=3.0)
        a = prob.solve(*args, solver="osqp", eps=1e-9)
        b = prob.solve(*args, solver="exact")
        assert a.ok and np.abs(a.u - b.u).max() <= 1e-5
        assert a.iterations > 0 and a.solve_time > 0


def test_qp_matrices_are_constant_and_vectors_affine(plant):
    _, ds = plant
    prob = SteeringProblem(fit_predictor(ds, TI, TF, "pem"), _cfg())
    rng = np.random.default_rng(0)
    th = rng.standard_normal(prob.n_theta)
    q, l, u = (np.array(v).ravel() for v in prob.param_map(th))
    qn, ln, un = prob.qp_vectors(th)
    np.testing.assert_allclose(q, qn, atol=1e-9)
    np.testing.assert_allclose(l, ln[prob.n_u :], atol=1e-9)
    np.testing.assert_allclose(u, un[prob.n_u :], atol=1e-9)
    np.testing.assert_array_equal(ln[: prob.n_u], np.tile([-1.5, -1.2], TF))
    assert prob.P.shape == (M * TF, M * TF) and np.allclose(prob.P, prob.P.T)
    assert prob.A.shape == (2 * M * TF + P * TF, M * TF)  # u box, y box, du box rows
    assert prob.A_g.shape == (M * TF + P * TF, M * TF)
    assert prob.n_theta == (M + P) * TI + P * TF + M * TF


@pytest.mark.parametrize("bounds", [dict(y_min=[-6.0, -np.inf], y_max=[np.inf, 6.0]),   # one-sided rows
                                    dict(y_min=[-np.inf] * P, y_max=[np.inf] * P, du_max=[np.inf, 0.8])])
def test_the_qp_data_are_the_cost_and_bounds_evaluated_with_one_sided_and_missing_bounds(plant, bounds):
    """P, q and the bound maps against the cost and constraints evaluated directly: a quadratic
    J(z) = J(0) + q'z + z'Pz/2 exactly, and l_g, u_g (+-inf where a side is unbounded) at random theta."""
    _, ds = plant
    prob = SteeringProblem(fit_predictor(ds, TI, TF, "pem"), _cfg(R_du=[2.0, 1.0], **bounds))
    assert np.all(np.isfinite(prob.F_q)) and np.all(np.isfinite(prob.F_g)) and np.all(np.isfinite(prob.P))
    rng = np.random.default_rng(3)
    for _ in range(3):
        th, z = rng.standard_normal(prob.n_theta), rng.standard_normal(prob.n_z)
        j = lambda v: float(prob._cost_fn(v, th))  # noqa: E731
        q = prob.qp_vectors(th)[0]
        assert j(z) - j(np.zeros(prob.n_z)) == pytest.approx(q @ z + 0.5 * z @ prob.P @ z, rel=1e-9, abs=1e-9)
        _, l_g, u_g = (np.array(v).ravel() for v in prob.param_map(th))
        _, ln, un = prob.qp_vectors(th)
        np.testing.assert_allclose(ln[prob.n_z :], l_g, rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(un[prob.n_z :], u_g, rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize("extra", [{}, {"R_du": [2.0, 1.0]}])
def test_deepc_matches_condensed_on_exact_data(plant, extra):
    sys_, full = plant
    ds = IODataset(full.u[0][:220], full.y[0][:220], full.dt)  # DeePC is dense in g: keep it small
    cfg = _cfg("increment", lambda_sigma=1e8, **extra)
    prob = SteeringProblem(fit_predictor(ds, TI, TF, "lsq"), cfg)
    deepc = DeePCProblem(ds, cfg, lambda_g=1e-6)
    rng = np.random.default_rng(21)
    for k in range(6):
        u_ini = 0.3 * rng.standard_normal((TI, M))
        y_ini, _ = sys_.simulate(u_ini, rng.standard_normal(4))  # exact, noise-free window
        y_des = (0.5 if k % 2 else 2.5) * rng.standard_normal((TF, P))
        a = prob.solve(u_ini, y_ini, y_des, solver="exact")
        b = deepc.solve(u_ini, y_ini, y_des)
        assert b.ok
        assert np.abs(a.u - b.u).max() <= 1e-5


def test_errors(plant):
    _, ds = plant
    pred = fit_predictor(ds, TI, TF, "pem")
    with pytest.raises(ConfigError, match="t_f=12 but the predictor was fitted with t_f=10"):
        SteeringProblem(pred, SteeringConfig(t_ini=TI, t_f=12, m=M, p=P, Q=[1, 1], R=[1, 1]))
    with pytest.raises(ConfigError, match="not strictly convex"):
        SteeringProblem(pred, _cfg(R=[0.0, 1.0], Q=[0.0, 0.0], lambda_sigma=0.0))
    prob = SteeringProblem(pred, _cfg())
    z = np.zeros
    with pytest.raises(DataError, match=r"y_des must be \(10, 2\) time-major or stacked \(20,\); got shape \(9, 2\)"):
        prob.solve(z((TI, M)), z((TI, P)), z((9, P)), z((TF, M)))
    with pytest.raises(DataError, match="u_ini contains NaN or inf; refusing to steer on it"):
        prob.solve(np.full((TI, M), np.nan), z((TI, P)), z((TF, P)), z((TF, M)))
    with pytest.raises(DataError, match="R_mode 'offset' needs u_nom"):
        prob.solve(z((TI, M)), z((TI, P)), z((TF, P)))
    with pytest.raises(ConfigError, match="unknown solver 'cvx'"):
        prob.solve(z((TI, M)), z((TI, P)), z((TF, P)), z((TF, M)), solver="cvx")


def test_infeasible_bounds_report_status_not_garbage(plant):
    _, ds = plant
    prob = SteeringProblem(fit_predictor(ds, TI, TF, "pem"), _cfg(du_max=[1e-3, 1e-3]))
    # u_ini ends far outside the box: the rate bound makes the box unreachable -> infeasible
    u_ini = np.full((TI, M), 5.0)
    for solver in ("exact", "osqp"):
        r = prob.solve(u_ini, np.zeros((TI, P)), np.zeros((TF, P)), np.zeros((TF, M)), solver=solver)
        assert not r.ok and r.status != "solved"
        assert np.all(np.isnan(r.u))
