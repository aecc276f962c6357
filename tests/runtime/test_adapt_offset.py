"""The online output offset (``[adapt] offset``) in numpy: against the predictor's own data-unit matrices, clipped,
estimated whatever the verdict on G, installed only once verified (finite, within max_offset, better on the recent
window than the offset in use), applied by the interpreted twin, recorded by the loop; exact errors."""

from __future__ import annotations

import functools
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from ddpc_codegen.design.adaptation import AdaptiveProblem, adapter
from ddpc_codegen.values.config import SteeringConfig
from ddpc_codegen.design.data import IODataset
from ddpc_codegen.design.fit import fit_incremental
from ddpc_codegen.design.predictor import fit_predictor
from ddpc_codegen.design.problem import SteeringProblem
from ddpc_codegen.errors import ConfigError, DataError
from ddpc_codegen.runtime.adapt_loop import OnlineAdaptation
from ddpc_codegen.design.adapter import OFFSET_SPAN
from ddpc_codegen.values.adapt import AdaptSettings, Swapped, adapt_settings
from support.lti import random_lti

T_F = 4


def _problem(form: str = "absolute", bounds: dict | None = None) -> SteeringProblem:
    sys_ = random_lti(3, 2, 2, 4)
    rng = np.random.default_rng(4)
    u = rng.standard_normal((400, 2))
    y, _ = sys_.simulate(u, np.zeros(3))
    ds = IODataset(u, y + 1e-3 * rng.standard_normal(y.shape), 0.01)
    pred = fit_incremental(ds, 4, T_F, "lsq", ridge=1e-6) if form == "incremental" else \
        fit_predictor(ds, 3, T_F, "lsq", ridge=1e-6)
    cfg = SteeringConfig(t_ini=pred.t_ini, t_f=T_F, m=2, p=2, Q=[10.0, 1.0], R=[1.0, 1.0], R_mode="offset",
                         predictor={"method": "lsq"}, **(bounds or {}))
    return SteeringProblem(pred, cfg)


FORMS = ("absolute", "incremental")


@functools.cache
def problem(form: str) -> SteeringProblem:
    """The module's problem of ``form``, built on first use (not while every xdist worker collects)."""
    return _problem(form)


def _signal(seed: int, d: np.ndarray, T: int = 120) -> tuple[np.ndarray, np.ndarray]:
    """(u, y) of another system with the constant output disturbance d: an offset the fit has no term for."""
    rng = np.random.default_rng(seed)
    u = rng.standard_normal((T, 2))
    y, _ = random_lti(3, 2, 2, seed % 50 + 10).simulate(u, np.zeros(3))
    return u, y + d


def _reference_residuals(prob: SteeringProblem, u: np.ndarray, y: np.ndarray, k: int) -> np.ndarray:
    """y_f - [Gy_w Gy_u] [u_ini; y_ini; u_f] (data units) of the last k windows (k, p Tf), from the predictor's own
    data-unit matrices (not the update's scaled ring)."""
    pr = prob.predictor
    ti, tf = pr.t_ini, pr.t_f
    res = []
    for j in range(u.shape[0] - ti - tf + 1)[-k:]:
        z = np.concatenate([u[j : j + ti].ravel(), y[j : j + ti].ravel(), u[j + ti : j + ti + tf].ravel()])
        res.append(y[j + ti : j + ti + tf].ravel() - np.hstack([pr.Gy_w, pr.Gy_u]) @ z)
    return np.array(res)


def _reference_offset(prob: SteeringProblem, u: np.ndarray, y: np.ndarray, k: int) -> np.ndarray:
    """The mean of :func:`_reference_residuals` over the last k windows."""
    return _reference_residuals(prob, u, y, k).mean(axis=0)


def _feed(twin: AdaptiveProblem, u: np.ndarray, y: np.ndarray) -> None:
    for uk, yk in zip(u, y):
        twin.adapt_push(uk, yk)


@given(form=st.sampled_from(sorted(FORMS)), seed=st.integers(0, 10**6),
       d=st.lists(st.floats(-2.0, 2.0), min_size=2, max_size=2), window=st.integers(40, 90))
@settings(max_examples=12, deadline=None)
def test_the_staged_offset_is_the_mean_residual_of_the_recent_window_in_data_units(form, seed, d, window):
    prob = problem(form)
    # every G refused (the gain check, or for the incremental form, which has none, the excitation check)
    st_ = AdaptSettings(enabled=True, window=window, offset=True, max_gain_change=0.0, min_excitation=1.0,
                        max_offset=1e6)
    twin = AdaptiveProblem(prob, st_)
    u, y = _signal(seed, np.array(d))
    _feed(twin, u, y)
    assert twin.adapt_resolve() in ("gain", "excitation")  # the offset is estimated whatever the verdict on G
    res = _reference_residuals(prob, u, y, window)
    want = res.mean(axis=0)
    got = twin.adapter.offset_estimate
    assert np.abs(got - want).max() <= 1e-9 * max(1.0, np.abs(want).max())
    # its verification: the window's sum of |residual - offset| (over each output's scale) below the one in use's
    w = 1.0 / np.tile(np.asarray(prob.predictor.options["channel_scale"])[2:], T_F)
    c = twin.adapt_counts()
    for key, off in (("offset_error_candidate", got), ("offset_error_current", 0.0)):
        assert c[key] == pytest.approx(np.sum(np.abs(res - off) * w), rel=1e-9)
    verified = c["offset_error_candidate"] < c["offset_error_current"]
    assert twin.adapt_swap() == Swapped(g=False, offset=verified)  # no G; the offset only once verified
    assert np.array_equal(twin.adapt_offset(), got if verified else np.zeros_like(got))
    assert twin.adapt_counts()["offset_swaps"] == int(verified) == 1 - twin.adapt_counts()["offset_rejected"]
    assert twin.adapt_counts()["offset_norm"] == pytest.approx(np.linalg.norm(got) if verified else 0.0, rel=1e-12)


def test_after_a_g_swap_the_offset_in_use_is_the_new_gs():
    prob = problem("absolute")
    twin = AdaptiveProblem(prob, AdaptSettings(enabled=True, window=60, offset=True, forgetting=0.95, max_change=1.0,
                                               min_excitation=1e-6, max_gain_change=1e6))
    u, y = _signal(3, np.array([0.3, -0.2]), T=300)
    _feed(twin, u, y)
    assert twin.adapt_resolve() == "accepted"
    G_new = twin.adapter.pending
    assert twin.adapt_swap() == Swapped(g=True, offset=True)
    np.testing.assert_array_equal(twin.adapter.G, G_new)
    np.testing.assert_allclose(twin.adapt_offset(), twin.adapter.offset_of(G_new), rtol=0, atol=1e-12)
    assert np.abs(twin.adapt_offset() - _reference_offset(prob, u, y, 60)).max() > 1e-3  # not the shipped G's


@pytest.mark.parametrize("max_offset, clipped", [(0.05, [0.05, 0.05]), ((10.0, 0.01), [None, 0.01]),
                                                 (10.0, [None, None])])
def test_the_offset_is_clipped_per_output_and_counted(max_offset, clipped):
    prob = problem("absolute")
    st_ = AdaptSettings(enabled=True, window=50, offset=True, max_gain_change=0.0, max_offset=max_offset)
    twin = AdaptiveProblem(prob, st_)
    u, y = _signal(1, np.array([1.0, -1.0]))
    _feed(twin, u, y)
    twin.adapt_resolve()
    raw = _reference_offset(prob, u, y, 50).reshape(T_F, 2)
    got = twin.adapter.offset_estimate.reshape(T_F, 2)
    for j, lim in enumerate(clipped):
        want = raw[:, j] if lim is None else np.clip(raw[:, j], -lim, lim)
        np.testing.assert_allclose(got[:, j], want, rtol=0, atol=1e-9)
    assert twin.adapt_counts()["offset_clipped"] == int(any(c is not None for c in clipped))
    assert np.abs(raw).min() > 0.05  # every entry was beyond the tight bounds


def test_the_twin_steers_toward_y_des_minus_the_offset():
    prob = problem("absolute")
    twin = AdaptiveProblem(prob, AdaptSettings(enabled=True, window=50, offset=True, max_gain_change=0.0))
    u, y = _signal(2, np.array([0.5, 0.1]))
    _feed(twin, u, y)
    twin.adapt_resolve()
    twin.adapt_swap()
    b = twin.adapt_offset().reshape(T_F, 2)
    rng = np.random.default_rng(0)
    u_ini, y_ini, y_des = rng.standard_normal((3, 2)), rng.standard_normal((3, 2)), rng.standard_normal((T_F, 2))
    u_nom = rng.standard_normal((T_F, 2))
    got = twin.solve(u_ini, y_ini, y_des, u_nom)
    want = prob.solve(u_ini, y_ini, y_des - b, u_nom, solver="fast")  # no G swapped: the shipped QP
    np.testing.assert_allclose(got.u, want.u, rtol=0, atol=1e-12)
    th = prob.theta(u_ini, y_ini, y_des, u_nom)
    np.testing.assert_allclose(twin.solve_theta(th).u, want.u, rtol=0, atol=1e-12)
    assert np.abs(got.u - prob.solve(u_ini, y_ini, y_des, u_nom, solver="fast").u).max() > 1e-3


def test_without_offset_nothing_is_staged_and_the_loop_records_the_norm():
    prob = problem("absolute")
    u, y = _signal(5, np.array([0.5, 0.1]), T=200)
    norms = {}
    for on in (False, True):
        twin = AdaptiveProblem(prob, AdaptSettings(enabled=True, window=50, offset=on, max_gain_change=0.0,
                                                   period_ticks=60))
        loop = OnlineAdaptation(twin)
        for uk, yk in zip(u, y):
            loop.tick(uk, yk, True)
        ev = loop.summary()["events"]
        assert len(ev) == 3 and all(e[1] == "gain" and not e[2] for e in ev)
        norms[on] = [e[3] for e in ev]
        assert loop.offset_norm == norms[on][-1] == twin.adapt_counts()["offset_norm"]
        # an estimate not better than the offset in use is kept out (counted)
        c = twin.adapt_counts()
        assert c["offset_swaps"] == sum(e[7] for e in ev) == (3 - c["offset_rejected"] if on else 0)
        assert c["offset_swaps"] >= (1 if on else 0)
    assert norms[False] == [0.0] * 3 and norms[True][-1] > 0.1


def test_offset_with_output_bounds_is_refused():
    prob = _problem(bounds={"y_min": [-1.0, -np.inf], "y_max": [1.0, np.inf]})
    with pytest.raises(ConfigError, match=r"^\[adapt\] offset = true cannot be combined with finite output bounds "
                                          r"\(\[bounds\] y_min / y_max\): the estimated output offset would shift "
                                          r"them as well; drop the output bounds or set offset = false$"):
        adapter(prob, AdaptSettings(enabled=True, offset=True))
    adapter(prob, AdaptSettings(enabled=True))  # without the offset the bounded problem adapts


@pytest.mark.parametrize("value", [0.0, -1.0, [0.1, 0.2, 0.3], "x", True, [0.1, float("nan")]])
def test_a_bad_max_offset_is_refused_by_the_update(value):
    with pytest.raises(DataError, match=r"^\[adapt\] max_offset must be one number > 0 or 2 of them \(one per "
                                        rf"output\); got {__import__('re').escape(repr(value))}$"):
        adapter(problem("absolute"), AdaptSettings(enabled=True, offset=True, max_offset=value))


@pytest.mark.parametrize("table, message", [
    ({"offset": 1}, r"^c.toml: \[adapt\] offset must be true or false; got 1$"),
    ({"max_offset": 0}, r"^c.toml: \[adapt\] max_offset must be a number > 0 or a list of 2 of them \(output "
                        r"units\); got 0$"),
    ({"max_offset": [0.1]}, r"^c.toml: \[adapt\] max_offset must be a number > 0 or a list of 2 of them \(output "
                            r"units\); got \[0.1\]$"),
    ({"max_offset": [0.1, True]}, r"^c.toml: \[adapt\] max_offset must be a number > 0 or a list of 2 of them "
                                  r"\(output units\); got \[0.1, True\]$"),
])
def test_adapt_table_errors_for_the_offset_keys(table, message):
    with pytest.raises(ConfigError, match=message):
        adapt_settings(table, "c.toml", p=2)


def test_adapt_table_accepts_the_offset_keys():
    assert adapt_settings({"offset": True, "max_offset": [0.1, 2]}, "c.toml", p=2) == AdaptSettings(
        offset=True, max_offset=(0.1, 2.0))
    assert adapt_settings({"max_offset": float("inf")}).max_offset == float("inf")


def _own_signal(seed: int, d=(0.0, 0.0), T: int = 300) -> tuple[np.ndarray, np.ndarray]:
    """(u, y) of the system the predictors were fitted on, with the constant output disturbance d."""
    rng = np.random.default_rng(seed)
    u = rng.standard_normal((T, 2))
    y, _ = random_lti(3, 2, 2, 4).simulate(u, np.zeros(3))
    return u, y + 1e-3 * rng.standard_normal(y.shape) + np.asarray(d)


def _probe_twin(form: str) -> AdaptiveProblem:
    return AdaptiveProblem(problem(form), AdaptSettings(enabled=True, window=60, offset=True))


def _absurd(y: np.ndarray, probe: str, seed: int) -> np.ndarray:
    """y with the probe's samples: 1 % outliers of 1e7, or its last 20 samples at 1e300."""
    y = y.copy()
    if probe == "outliers":
        idx = np.random.default_rng(seed).choice(y.shape[0], y.shape[0] // 100, replace=False)
        y[idx] += 1e7
    else:
        y[-20:] = 1e300
    return y


def test_the_default_max_offset_is_finite_from_the_fit_data():
    ad = _probe_twin("absolute").adapter
    scale_y = np.asarray(problem("absolute").predictor.options["channel_scale"])[2:]
    np.testing.assert_allclose(ad.max_offset, OFFSET_SPAN * scale_y, rtol=1e-12)
    inc = _probe_twin("incremental").adapter  # increments accumulate over the horizon: Tf of their scale
    scale_dy = np.asarray(problem("incremental").predictor.options["channel_scale"])[2:]
    np.testing.assert_allclose(inc.max_offset, OFFSET_SPAN * T_F * scale_dy, rtol=1e-12)
    assert np.all(np.isfinite(inc.max_offset))


def test_a_genuine_offset_change_is_installed():
    """A constant output disturbance (the absolute form: the incremental one is offset-free by construction)."""
    twin = _probe_twin("absolute")
    u, y = _own_signal(1, d=(0.3, -0.2))
    _feed(twin, u, y)
    twin.adapt_resolve()
    done = twin.adapt_swap()
    assert done.offset and twin.adapt_counts()["offset_rejected"] == 0
    if not done.g:  # the shipped G's mean residual (y_ini carries d too: not d itself)
        np.testing.assert_allclose(twin.adapt_offset(), _reference_offset(problem("absolute"), u, y, 60), atol=1e-9)
    assert np.abs(twin.adapt_offset()).max() > 0.05


@pytest.mark.parametrize("form", sorted(FORMS))
@pytest.mark.parametrize("probe", ["outliers", "1e300"])
def test_absurd_columns_install_no_offset(form, probe):
    """1 % outliers drag the mean far (clipped to the finite max_offset), 1e300 samples make it absurd: the
    estimate predicts the window worse than the offset in use (or is not finite), so nothing is installed --
    from scratch and after a genuine offset, which stays in use; the twin still steers."""
    for first in (False, True) if form == "absolute" else (False,):
        twin = _probe_twin(form)
        if first:
            u0, y0 = _own_signal(2, d=(0.3, -0.2))
            _feed(twin, u0, y0)
            twin.adapt_resolve()
            assert twin.adapt_swap().offset
        before = twin.adapt_offset()
        u, y = _own_signal(3, d=(0.3, -0.2) if first else (0.0, 0.0))
        _feed(twin, u, _absurd(y, probe, 3))
        twin.adapt_resolve()
        done = twin.adapt_swap()
        assert not done.offset and np.array_equal(twin.adapt_offset(), before), (first, twin.adapt_counts())
        assert twin.adapt_counts()["offset_rejected"] == 1
        est = twin.adapter.offset_estimate
        assert est is None or np.all(np.abs(est) <= np.tile(twin.adapter.max_offset, T_F))
        rng = np.random.default_rng(0)
        r = twin.solve(rng.standard_normal((problem(form).predictor.t_ini, 2)) * 0.1,
                       rng.standard_normal((problem(form).predictor.t_ini, 2)) * 0.1,
                       np.zeros((T_F, 2)), np.zeros((T_F, 2)))
        assert r.status == "solved"
