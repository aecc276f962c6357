"""The DeePC reference (eq. DDPC) against an independent formulation: cvxpy, solved by Clarabel
(interior point), with its own Hankel matrices; non-trivial lambda_g and lambda_sigma and active
input and output bounds."""

import numpy as np
import pytest

from support.lti import random_lti
from ddpc_codegen import DeePCProblem, IODataset, SteeringConfig

TI, TF, M, P = 4, 6, 2, 2


@pytest.fixture(scope="module")
def plant():
    sys_ = random_lti(3, M, P, 4)
    rng = np.random.default_rng(4)
    u = rng.standard_normal((110, M))
    y, _ = sys_.simulate(u, rng.standard_normal(3))
    y = y + 0.02 * rng.standard_normal(y.shape)  # noisy data: lambda_g and lambda_sigma both matter
    return sys_, IODataset(u, y, 0.01)


def _cfg(lambda_sigma, mode="offset", R_ddu=None, R_de=None, R_doffset=None):
    return SteeringConfig(t_ini=TI, t_f=TF, m=M, p=P, Q=[[10.0, 1.0], [1.0, 4.0]], R=[0.5, 0.2], R_du=[0.3, 0.0],
                          R_ddu=R_ddu, R_de=R_de, R_doffset=R_doffset,
                          R_mode=mode, lambda_sigma=lambda_sigma, u_min=[-0.6, -0.5], u_max=[0.6, 0.5],
                          y_min=[-0.8, -1.0], y_max=[0.8, 1.0], du_max=[0.3, 0.25])


def _hankel(w, L):
    """(L*d, T-L+1) block Hankel written out column by column (not the package's sliding windows)."""
    return np.column_stack([w[j : j + L].reshape(-1) for j in range(w.shape[0] - L + 1)])


def _cvxpy_deepc(ds, c, lambda_g, u_ini, y_ini, y_des, u_nom):
    cp = pytest.importorskip("cvxpy")  # heavy (~1 s): imported where it is used, not while every worker collects
    Hu, Hy = _hankel(ds.u[0], TI + TF), _hankel(ds.y[0], TI + TF)
    Up, Uf, Yp, Yf = Hu[: M * TI], Hu[M * TI :], Hy[: P * TI], Hy[P * TI :]
    g = cp.Variable(Hu.shape[1])
    u, y, s = cp.Variable((TF, M)), cp.Variable((TF, P)), cp.Variable((TI, P))
    du = u - cp.vstack([u_ini[-1:], u[:-1]])
    ddu = du - cp.vstack([u_ini[-1:] - u_ini[-2:-1], du[:-1]])
    e = u - y[:, :M]  # input i against output i
    de = e - cp.vstack([u_ini[-1:] - y_ini[-1:, :M], e[:-1]])
    dnom = u_nom - np.vstack([2 * u_nom[:1] - u_nom[1:2], u_nom[:-1]])  # the first change extrapolated back
    offset = {"absolute": u, "offset": u - u_nom, "increment": du}[c.R_mode]
    cost = (sum(cp.quad_form(y[k] - y_des[k], c.Q) for k in range(TF))
            + sum(cp.quad_form(offset[k], c.R) + cp.quad_form(du[k], c.R_du) + cp.quad_form(ddu[k], c.R_ddu)
                  + cp.quad_form(de[k], c.R_de) + cp.quad_form(du[k] - dnom[k], c.R_doffset) for k in range(TF))
            + lambda_g * cp.sum_squares(g) + c.lambda_sigma * cp.sum_squares(s))
    # time-major stacking: Up @ g is u_ini.reshape(-1), i.e. row-major flattening of (TI, M)
    cons = [Up @ g == u_ini.reshape(-1), Yp @ g == cp.reshape(y_ini - s, (TI * P,), order="C"),
            Uf @ g == cp.reshape(u, (TF * M,), order="C"), Yf @ g == cp.reshape(y, (TF * P,), order="C"),
            u >= np.tile(c.u_min, (TF, 1)), u <= np.tile(c.u_max, (TF, 1)),
            y >= np.tile(c.y_min, (TF, 1)), y <= np.tile(c.y_max, (TF, 1)),
            cp.abs(du) <= np.tile(c.du_max, (TF, 1))]
    prob = cp.Problem(cp.Minimize(cost), cons)
    prob.solve(solver="CLARABEL", tol_gap_abs=1e-12, tol_gap_rel=1e-12, tol_feas=1e-12, max_iter=500)
    assert prob.status == "optimal", prob.status
    return u.value, y.value


def _agrees_with_cvxpy(plant, c, lambda_g: float, seed: int) -> tuple[int, int]:
    """DeePCProblem against the cvxpy model on 3 draws (y_des beyond the y bounds); (draws with an active
    u bound, with an active y bound)."""
    sys_, ds = plant
    deepc = DeePCProblem(ds, c, lambda_g=lambda_g)
    rng = np.random.default_rng(seed)
    active_u = active_y = 0
    for k in range(3):
        u_ini = rng.uniform(-0.3, 0.3, (TI, M))
        y_ini, _ = sys_.simulate(u_ini, 0.3 * rng.standard_normal(3))
        y_des = 2.0 * np.sin(np.arange(TF)[:, None] / 2.0 + rng.uniform(0, 6, P))  # beyond y bounds
        u_nom = 0.1 * rng.standard_normal((TF, M))
        r = deepc.solve(u_ini, y_ini, y_des, u_nom)
        assert r.ok, r.status
        u_ref, y_ref = _cvxpy_deepc(ds, c, lambda_g, u_ini, y_ini, y_des, u_nom)
        assert np.abs(r.u - u_ref).max() <= 1e-6
        assert np.abs(r.y_pred - y_ref).max() <= 1e-6
        active_u += np.any(np.isclose(np.abs(r.u), c.u_max, atol=1e-8))
        active_y += np.any(np.isclose(np.abs(r.y_pred), c.y_max, atol=1e-8))
    return active_u, active_y


@pytest.mark.parametrize("lambda_g", [1e-2, 1.0])
@pytest.mark.parametrize("lambda_sigma", [1e3, 1e6])
def test_deepc_equals_cvxpy_clarabel_with_active_bounds(plant, lambda_g, lambda_sigma):
    active_u, active_y = _agrees_with_cvxpy(plant, _cfg(lambda_sigma), lambda_g, int(lambda_g * 10 + np.log10(lambda_sigma)))
    assert active_u and active_y  # input and output bounds were both active


def test_deepc_with_a_second_difference_penalty_equals_cvxpy(plant):
    """R_ddu written out for cvxpy (Δ²u from u_ini's last two samples on) against DeePCProblem's matrices."""
    _agrees_with_cvxpy(plant, _cfg(1e3, R_ddu=[2.0, 0.4]), 1e-2, 3)


def test_deepc_with_a_tracking_error_rate_penalty_equals_cvxpy(plant):
    """R_de written out for cvxpy (changes of u - y, the first from u_ini[-1] - y_ini[-1]) against DeePCProblem."""
    _agrees_with_cvxpy(plant, _cfg(1e3, R_de=[3.0, 0.5]), 1e-2, 5)


def test_deepc_with_an_offset_rate_penalty_equals_cvxpy(plant):
    """R_doffset written out for cvxpy (changes of u - u_nom, the nominal's first change extrapolated back)."""
    _agrees_with_cvxpy(plant, _cfg(1e3, R_doffset=[2.0, 0.5]), 1e-2, 7)


def test_deepc_failed_status_gives_nan_never_a_guess(plant):
    sys_, ds = plant
    c = _cfg(1e3).replace(du_max=[1e-3, 1e-3])
    deepc = DeePCProblem(ds, c, lambda_g=1e-2)
    # u_ini ends far outside the box and the rate bound cannot bring it back: infeasible
    r = deepc.solve(np.full((TI, M), 5.0), np.zeros((TI, P)), np.zeros((TF, P)), np.zeros((TF, M)))
    assert r.status != "solved" and not r.ok
    assert np.all(np.isnan(r.u)) and np.all(np.isnan(r.y_pred)) and np.all(np.isnan(r.info["g"]))


@pytest.mark.parametrize("lambda_g, lambda_sigma", [(1e-9, 1e9), (1e-9, 1e3), (1e3, 1e9)])
def test_extreme_weights_give_a_verified_answer_or_nan(plant, lambda_g, lambda_sigma):
    # lambda_sigma = 1e9, lambda_g = 1e-9 made qpOASES fail while a finite u was returned
    sys_, ds = plant
    c = _cfg(lambda_sigma)
    deepc = DeePCProblem(ds, c, lambda_g=lambda_g)
    rng = np.random.default_rng(2)
    for _ in range(3):
        u_ini = rng.uniform(-0.3, 0.3, (TI, M))
        y_ini, _ = sys_.simulate(u_ini, 0.3 * rng.standard_normal(3))
        r = deepc.solve(u_ini, y_ini, 2.0 * rng.standard_normal((TF, P)), np.zeros((TF, M)))
        if not r.ok:
            assert np.all(np.isnan(r.u)) and "." not in r.status
            continue
        tol = 1e-8 * np.maximum(1.0, np.abs(c.u_max))
        assert np.all(np.abs(r.u) <= c.u_max + tol) and np.all(np.abs(r.y_pred) <= c.y_max + 1e-8)
        du = np.diff(np.vstack([u_ini[-1:], r.u]), axis=0)
        assert np.all(np.abs(du) <= c.du_max + 1e-8)
