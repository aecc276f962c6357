"""Design side of online updates: the shipped fit statistic, the [adapt] settings, the QP model."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from ddpc_codegen.design.adaptation import fit_statistic, qp_model, write_fit_statistic
from ddpc_codegen.values.config import SteeringConfig
from ddpc_codegen.design.data import IODataset
from ddpc_codegen.design.fit import compose_increments, difference_dataset, fit_incremental
from ddpc_codegen.design.hankel import channel_stats
from ddpc_codegen.design.predictor import (FitLayout, _solve_r, _unscale, channel_scale, fit_predictor,
                                          hankel_r_factor)
from ddpc_codegen.design.problem import SteeringProblem
from ddpc_codegen.errors import ConfigError, DataError
from ddpc_codegen.design.adapter import solve_g, with_ridge
from ddpc_codegen.values.adapt import AdaptSettings, adapt_settings
from support.lti import random_lti


def _dataset(seed: int = 0, T: int = 500) -> IODataset:
    sys_ = random_lti(4, 2, 2, seed)
    rng = np.random.default_rng(seed)
    u = rng.standard_normal((T, 2)) * [0.3, 2.0]  # channels of different sizes: the scale matters
    y, _ = sys_.simulate(u, np.zeros(4))
    return IODataset(u, y + 1e-3 * rng.standard_normal(y.shape), 0.01)


def _problem(pred, R_mode="offset"):
    cfg = SteeringConfig(t_ini=pred.t_ini, t_f=pred.t_f, m=2, p=2, Q=[10.0, 3.0], R=[1.0, 0.5], R_mode=R_mode,
                         R_du=[0.2, 0.1], lambda_sigma=50.0, u_min=[-1.0] * 2, u_max=[1.0] * 2,
                         predictor={"method": pred.method})
    return SteeringProblem(pred, cfg)


@pytest.mark.parametrize("method", ["lsq", "pem"])
def test_fit_statistic_is_the_r_factor_of_the_scaled_hankel_data(method):
    ds = _dataset()
    pred = fit_predictor(ds, 4, 3, method, ridge=1e-6)
    R, lay = fit_statistic(pred)
    flay = FitLayout(2, 2, 4, 3, method)
    scale, _ = channel_scale(*channel_stats([np.hstack(t) for t in ds.trajectories()]), ds.input_names + ds.output_names)
    X = np.vstack([flay.data_rows((np.hstack([u, y]) / scale)[j : j + 7].reshape(1, -1))
                   for u, y in ds.trajectories() for j in range(u.shape[0] - 6)])
    assert R.shape == (lay.width, lay.width) == (flay.width, flay.width)
    np.testing.assert_allclose(R.T @ R, X.T @ X, rtol=1e-10, atol=1e-9)
    # and the predictor re-solved from it is the shipped one (scaled domain)
    G, _ = solve_g(with_ridge(R, lay.r, 1e-6), lay, 1.0, 1e-10)
    ref = _solve_r(hankel_r_factor(ds.trajectories(), flay, scale), flay, 1.0, 1e-6, 1e-10)["G"]
    assert np.abs(G - ref).max() <= 1e-9 * np.abs(ref).max()


def test_incremental_predictor_ships_the_increment_fit():
    ds = _dataset(2)
    pred = fit_incremental(ds, 5, 3, "lsq", ridge=1e-6)
    R, lay = fit_statistic(pred)
    inc = fit_predictor(difference_dataset(ds), 4, 3, "lsq", ridge=1e-6)
    assert (lay.t_ini, lay.method) == (4, "lsq")
    np.testing.assert_allclose(R.T @ R, inc.options["_r_factor"].T @ inc.options["_r_factor"], rtol=1e-12)


def test_hand_built_predictor_has_no_statistic():
    import dataclasses

    pred = fit_predictor(_dataset(), 4, 3, "lsq", ridge=1e-6)
    bare = dataclasses.replace(pred, options={k: v for k, v in pred.options.items() if k != "_r_factor"})
    with pytest.raises(DataError, match=r"^this predictor carries no R factor of its data"):
        fit_statistic(bare)


def test_written_statistic_and_its_manifest_entry(tmp_path):
    pred = fit_incremental(_dataset(), 5, 3, "lsq", ridge=1e-4)
    entry = write_fit_statistic(pred, tmp_path, "s1", AdaptSettings(forgetting=0.99))
    R = np.load(tmp_path / entry["file"])
    np.testing.assert_array_equal(R, fit_statistic(pred)[0])
    assert entry["shape"] == [R.shape[0], R.shape[1]] and entry["signal"] == "increments"
    assert entry["layout"]["t_ini"] == 4 and entry["adapt"]["forgetting"] == 0.99
    assert entry["channel_scale"] == pred.options["channel_scale"] and entry["ridge"] == 1e-4
    json.dumps(entry)  # JSON-able for the manifest


def _refitted(pred, lay, G):
    """The predictor of a fit-domain G by the fit's own conversion (``_unscale``, ``compose_increments``):
    the independent reference of the QP model's data-unit map."""
    scale = np.asarray(pred.options["channel_scale"], float)
    Gy, Gs = _unscale(G, scale, pred.m, pred.p, lay.t_ini, lay.t_f, lay.method)
    nw = (pred.m + pred.p) * lay.t_ini
    new = dataclasses.replace(pred, t_ini=lay.t_ini, Gy_w=Gy[:, :nw], Gy_u=Gy[:, nw:], Gs_w=Gs[:, :nw],
                              Gs_u=Gs[:, nw:])
    return compose_increments(new) if lay.t_ini != pred.t_ini else new


@pytest.mark.parametrize("form, method, R_mode, knots", [
    ("absolute", "lsq", "offset", None), ("absolute", "pem", "increment", [0, 2, 5]),
    ("incremental", "lsq", "absolute", None), ("incremental", "lsq", "offset", [0, 3, 5])])
def test_qp_model_rebuilds_the_qp_casadi_forms_for_another_g(form, method, R_mode, knots):
    """P, F_q, the output rows of A_g and F_g, and K rebuilt from a perturbed G equal those of the
    SteeringProblem CasADi forms from the predictor of that G (knots, output bounds and rate rows included)."""
    ds = _dataset(4)
    pred = fit_incremental(ds, 5, 6, "lsq", ridge=1e-6) if form == "incremental" else \
        fit_predictor(ds, 4, 6, method, ridge=1e-6)
    # R_doffset (offset mode only) is G-free: it must land in the fixed parts
    cfg = SteeringConfig(t_ini=pred.t_ini, t_f=6, m=2, p=2, Q=[10.0, 3.0], R=[1.0, 0.5], R_mode=R_mode,
                         R_du=[0.2, 0.1], R_doffset=[0.5, 0.0] if R_mode == "offset" else None, lambda_sigma=50.0, u_min=[-1.0] * 2, u_max=[1.0] * 2, y_min=[-5.0, -np.inf],
                         y_max=[5.0, 3.0], du_max=[0.3, 0.5], knots=knots, predictor={"method": pred.method})
    prob = SteeringProblem(pred, cfg)
    model = qp_model(prob)
    R, lay = fit_statistic(pred)
    G0, _ = solve_g(with_ridge(R, lay.r, 1e-6), lay, 1.0, 1e-10)
    np.testing.assert_allclose(model.rebuild(G0).P, prob.P, rtol=1e-9, atol=1e-9 * np.abs(prob.P).max())
    G1 = G0 * (1.0 + 0.1 * np.random.default_rng(3).standard_normal(G0.shape))
    ref = SteeringProblem(_refitted(pred, lay, G1), cfg)
    got = model.rebuild(G1)
    for key in ("P", "F_q", "A_g", "F_g", "K"):
        want = getattr(ref, key)
        assert np.abs(getattr(got, key) - want).max() <= 1e-9 * max(1.0, np.abs(want).max()), key


def test_qp_model_refuses_the_tracking_error_rate_penalty():
    """R_de couples u with the predicted y: the rebuild does not model it, so adaptation refuses it up front."""
    pred = fit_predictor(_dataset(5), 4, 3, "lsq", ridge=1e-6)
    prob = SteeringProblem(pred, _problem(pred).config.replace(R_de=[1.0, 0.0], source="c.toml"))
    with pytest.raises(ConfigError, match=r"^c.toml: \[cost\] R_de with \[adapt\]"):
        qp_model(prob)


def test_qp_model_refuses_a_candidate_whose_hessian_is_not_positive_definite():
    pred = fit_predictor(_dataset(5), 4, 3, "lsq", ridge=1e-6)
    prob = _problem(pred)
    model = dataclasses.replace(qp_model(prob), P_fixed=-1e6 * np.eye(prob.n_z))
    R, lay = fit_statistic(pred)
    assert model.rebuild(solve_g(with_ridge(R, lay.r, 1e-6), lay, 1.0, 1e-10)[0]) == "hessian"
    assert qp_model(prob).rebuild(np.full_like(solve_g(with_ridge(R, lay.r, 1e-6), lay, 1.0, 1e-10)[0], np.inf)) == "nonfinite"


def test_adapt_settings_defaults_and_values():
    assert adapt_settings(None) == AdaptSettings()
    s = adapt_settings({"enabled": True, "forgetting": 0.995, "period_ticks": 100, "dither": 0.01, "window": 120,
                        "min_improvement": 0.1})
    assert (s.enabled, s.forgetting, s.period_ticks, s.dither, s.window, s.min_improvement) == \
        (True, 0.995, 100, 0.01, 120, 0.1)


@pytest.mark.parametrize("table, message", [
    ({"forget": 0.9}, r"^c.toml: \[adapt\] unknown key\(s\) \['forget'\]; allowed: \['dither', 'enabled', "
                      r"'forgetting', 'max_change', 'max_gain_change', 'max_offset', 'min_excitation', 'min_improvement', "
                      r"'offset', 'period_ticks', 'window'\]$"),
    ({"min_improvement": 1.5}, r"^c.toml: \[adapt\] min_improvement must be in \[0, 1\]; got 1.5$"),
    ({"min_improvement": -0.1}, r"^c.toml: \[adapt\] min_improvement must be in \[0, 1\]; got -0.1$"),
    ({"max_gain_change": -1.0}, r"^c.toml: \[adapt\] max_gain_change must be > 0; got -1.0$"),
    ({"max_gain_change": float("nan")}, r"^c.toml: \[adapt\] max_gain_change must be > 0; got nan$"),
    ({"forgetting": 0.0}, r"^c.toml: \[adapt\] forgetting must be in \(0, 1\]; got 0.0$"),
    ({"forgetting": 1.01}, r"^c.toml: \[adapt\] forgetting must be in \(0, 1\]; got 1.01$"),
    ({"dither": -0.1}, r"^c.toml: \[adapt\] dither must be >= 0; got -0.1$"),
    ({"period_ticks": 0}, r"^c.toml: \[adapt\] period_ticks must be an integer >= 1; got 0$"),
    ({"window": 2.5}, r"^c.toml: \[adapt\] window must be an integer >= 1; got 2.5$"),
    ({"enabled": "yes"}, r"^c.toml: \[adapt\] enabled must be true or false; got 'yes'$"),
])
def test_adapt_settings_errors_name_key_and_value(table, message):
    with pytest.raises(ConfigError, match=message):
        adapt_settings(table, "c.toml")
