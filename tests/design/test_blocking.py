"""Knots over the horizon (design.blocking) and the blocked steering QP, against independent references:
np.interp for the basis, and cvxpy (Clarabel) on the uncondensed problem in the full u with u in range(B)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from support.lti import random_lti
from ddpc_codegen import ConfigError, IODataset, SteeringConfig, SteeringProblem, fit_predictor
from ddpc_codegen.design.blocking import distinct_rows, knot_basis
from ddpc_codegen.values.config_values import knot_positions

TI, TF, M, P = 6, 24, 2, 2


@given(t_f=st.integers(2, 300), data=st.data())
@settings(max_examples=60, deadline=None)
def test_knot_count_gives_strictly_increasing_indices_over_the_horizon(t_f, data):
    k = data.draw(st.integers(2, t_f))
    pos = knot_positions(k, t_f)
    assert len(pos) == k and pos[0] == 0 and pos[-1] == t_f - 1
    assert all(b > a for a, b in zip(pos, pos[1:]))


def test_knot_count_is_dense_first():
    assert knot_positions(10, 100) == (0, 1, 5, 11, 20, 31, 44, 60, 78, 99)
    assert knot_positions(5, 5) == (0, 1, 2, 3, 4)


@pytest.mark.parametrize("knots, msg", [
    (1, "must be between 2 and t_f = 24 knots; got 1"),
    (25, "must be between 2 and t_f = 24 knots; got 25"),
    ([0, 5, 5, 23], r"sample indices must increase strictly from 0 to t_f - 1 = 23; got \[0, 5, 5, 23\]"),
    ([1, 23], r"sample indices must increase strictly from 0 to t_f - 1 = 23; got \[1, 23\]"),
    ([0, 22], r"sample indices must increase strictly from 0 to t_f - 1 = 23; got \[0, 22\]"),
    ("8", "must be a number of knots or a list of sample indices; got '8'"),
    (True, "must be a number of knots or a list of sample indices; got True"),
])
def test_bad_knots_are_config_errors(knots, msg):
    with pytest.raises(ConfigError, match=r"^<config>: \[horizon\] knots " + msg + "$"):
        SteeringConfig(t_ini=TI, t_f=TF, m=M, p=P, Q=[1.0, 1.0], R=[1.0, 1.0], knots=knots)


def test_knots_from_toml_and_in_the_digest(tmp_path):
    base = SteeringConfig(t_ini=TI, t_f=TF, m=M, p=P, Q=[1.0, 1.0], R=[1.0, 1.0])
    assert base.knots is None and "knots" not in base.to_dict()  # configs without knots keep their digest
    blocked = base.replace(knots=6)
    assert blocked.knots == knot_positions(6, TF) and blocked.digest != base.digest
    f = tmp_path / "c.toml"
    f.write_text('[horizon]\nt_ini = 6\nt_f = 24\nknots = [0, 2, 23]\n[signals]\ninputs = ["a", "b"]\n'
                 'outputs = ["c", "d"]\n[cost]\nQ = [1.0, 1.0]\nR = [1.0, 1.0]\n')
    assert SteeringConfig.from_toml(f).knots == (0, 2, 23)


@given(st.lists(st.integers(1, 9), min_size=1, max_size=6), st.integers(1, 3), st.data())
@settings(max_examples=40, deadline=None)
def test_basis_interpolates_linearly_between_knots(gaps, m, data):
    pos = tuple(np.concatenate([[0], np.cumsum(gaps)]).astype(int))
    t_f = pos[-1] + 1
    v = np.array(data.draw(st.lists(st.floats(-5, 5), min_size=m * len(pos), max_size=m * len(pos))))
    u = (knot_basis(pos, t_f, m) @ v).reshape(t_f, m)
    ref = np.column_stack([np.interp(np.arange(t_f), pos, v.reshape(-1, m)[:, i]) for i in range(m)])
    np.testing.assert_allclose(u, ref, atol=1e-12)


def test_distinct_rows_keeps_the_first_of_equal_rows_and_drops_zero_rows():
    A = np.array([[1.0, -1.0], [1.0 + 1e-15, -1.0], [0.0, 0.0], [1.0, -1.0], [2.0, 0.0]])
    rhs = np.array([0.0, 0.0, 0.0, 1.0, 0.0])
    assert distinct_rows(A, rhs).tolist() == [0, 3, 4]


# ---------------------------------------------------------------------------------------- the blocked QP
@pytest.fixture(scope="module")
def plant():
    sys_ = random_lti(4, M, P, 11)
    rng = np.random.default_rng(11)
    u = rng.standard_normal((500, M))
    y, _ = sys_.simulate(u, rng.standard_normal(4))
    return sys_, fit_predictor(IODataset(u, y, 0.005), TI, TF, "pem")


def _cfg(mode="offset", **kw):
    b = dict(u_min=[-1.5, -1.2], u_max=[1.5, 1.2], y_min=[-6.0, -6.0], y_max=[6.0, 6.0], du_max=[0.3, 0.4])
    return SteeringConfig(t_ini=TI, t_f=TF, m=M, p=P, R_mode=mode, Q=[10.0, 4.0], R=[0.2, 0.1], lambda_sigma=50.0,
                          **(b | kw))


def _params(sys_, rng, scale):
    u = rng.uniform(-0.4, 0.4, (TI, M))
    y, _ = sys_.simulate(u, 0.3 * rng.standard_normal(4))
    return u, y + 0.01 * rng.standard_normal(y.shape), scale * rng.standard_normal((TF, P)), 0.3 * rng.standard_normal((TF, M))


def _cvxpy_in_range(prob: SteeringProblem, u_ini, y_ini, y_des, u_nom) -> np.ndarray:
    """The uncondensed problem in the full u (n_u), every bound on every tick, with u = B v (Clarabel)."""
    import cvxpy as cp  # heavy (~1 s): imported by the worker that runs this, not by every one that collects

    c, pr = prob.config, prob.predictor
    u, v = cp.Variable(M * TF), cp.Variable(prob.n_z)
    w = np.r_[np.ravel(u_ini), np.ravel(y_ini)]
    y, s = pr.Gy_w @ w + pr.Gy_u @ u, pr.Gs_w @ w + pr.Gs_u @ u
    du = cp.hstack([u[:M] - np.ravel(u_ini)[-M:], u[M:] - u[:-M]])
    ru = {"absolute": u, "offset": u - np.ravel(u_nom), "increment": du}[c.R_mode]
    Qb, Rb, Rd = (np.kron(np.eye(TF), X) for X in (c.Q, c.R, c.R_du))
    J = (cp.quad_form(y - np.ravel(y_des), Qb) + c.lambda_sigma * cp.sum_squares(s) + cp.quad_form(ru, Rb)
         + cp.quad_form(du, Rd))
    cons = [u == prob.B @ v, u >= np.tile(c.u_min, TF), u <= np.tile(c.u_max, TF), y >= np.tile(c.y_min, TF),
            y <= np.tile(c.y_max, TF), cp.abs(du) <= np.tile(c.du_max, TF)]
    cp.Problem(cp.Minimize(J), cons).solve(solver="CLARABEL", tol_gap_abs=1e-11, tol_gap_rel=1e-11, tol_feas=1e-11)
    return u.value


@pytest.mark.parametrize("mode, knots", [("offset", 6), ("increment", [0, 3, 9, 23]), ("absolute", 24)])
def test_blocked_qp_equals_clarabel_on_u_in_range_of_b(plant, mode, knots):
    sys_, pred = plant
    prob = SteeringProblem(pred, _cfg(mode, knots=knots, R_du=[1.0, 0.5]))
    assert prob.n_z == M * len(prob.config.knots)
    rng = np.random.default_rng(4)
    active = 0
    for k in range(12):
        args = _params(sys_, rng, 0.1 if k % 2 else 4.0)
        res = prob.solve(*args, solver="exact")
        assert res.ok
        ref = _cvxpy_in_range(prob, *args)
        assert np.abs(res.u.ravel() - ref).max() <= 1e-5
        fast = prob.solve(*args, solver="fast")
        assert np.abs(fast.u - res.u).max() <= 1e-9
        active += not fast.fast_path
    assert 0 < active < 12  # both kinds of tick were exercised


def test_blocked_rate_rows_are_one_per_segment(plant):
    _, pred = plant
    prob = SteeringProblem(pred, _cfg(knots=[0, 3, 9, 23], y_min=None, y_max=None))
    assert prob.n_z == 8 and prob.lb_u.tolist() == [-1.5, -1.2] * 4
    assert prob.general_kinds == ("du",) * (M * 4)  # the first increment and one slope per segment, per channel


def test_blocked_rows_accept_exactly_what_the_whole_horizon_check_accepts(plant):
    # The QP's own rows (box at the knots, one rate row per segment) against check(), which verifies u = B z
    # tick by tick: the same answer for perturbed answers on both sides of the bounds.
    sys_, pred = plant
    prob = SteeringProblem(pred, _cfg(knots=[0, 3, 9, 23]))
    rng = np.random.default_rng(2)
    seen = set()
    for k in range(200):
        th = prob.theta(*_params(sys_, rng, 0.1 if k % 2 else 4.0))
        z = prob.solve_theta(th, solver="exact").u
        z = prob.to_z(z) + rng.choice([1e-3, 1e-1]) * rng.standard_normal(prob.n_z)
        ok = prob.check(z, th) == "solved"
        assert prob.is_feasible(z, *prob.qp_vectors(th)[1:]) == ok
        seen.add(ok)
    assert seen == {True, False}


def test_knots_at_every_sample_are_todays_problem(plant):
    sys_, pred = plant
    plain = SteeringProblem(pred, _cfg(R_du=[1.0, 0.5]))
    eye = SteeringProblem(pred, _cfg(R_du=[1.0, 0.5], knots=TF))
    np.testing.assert_array_equal(eye.B, np.eye(M * TF))
    for key in ("P", "A_g", "F_q", "F_g", "q0", "lg0", "ug0", "K", "k0", "lb_u", "ub_u"):
        np.testing.assert_array_equal(getattr(eye, key), getattr(plain, key), err_msg=key)
    args = _params(sys_, np.random.default_rng(8), 4.0)
    np.testing.assert_array_equal(eye.solve(*args, solver="exact").u, plain.solve(*args, solver="exact").u)
