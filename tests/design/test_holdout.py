"""The held-out prediction check against LTI systems whose responses are known exactly."""

from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from support.lti import LTI, random_lti
from ddpc_codegen import IODataset, fit_predictor
from ddpc_codegen.design.holdout import hold_out_whole, holdout_check, holdout_figures, split_holdout

T_INI, T_F = 6, 12
CFG = SimpleNamespace(t_ini=T_INI, t_f=T_F, output_units=("m", "rad"))


def _fit(cfg, ds):
    return fit_predictor(ds, cfg.t_ini, cfg.t_f, "lsq")


def _data(sys_, n=(1200, 900), seed=0, noise=0.0):
    rng = np.random.default_rng(seed)
    us, ys = [], []
    for k in n:
        u = rng.standard_normal((k, sys_.B.shape[1]))
        y, _ = sys_.simulate(u, np.zeros(sys_.n))
        us.append(u)
        ys.append(y + noise * rng.standard_normal(y.shape))
    return IODataset(us, ys, 0.01, output_names=("z", "pitch"))


def test_an_exact_lti_system_is_predicted_exactly_on_held_out_data():
    sys_ = random_lti(4, 2, 2, 3)
    figs, lines, warnings = holdout_check(CFG, _data(sys_), _fit, 0.2)
    assert figs.windows >= 20 and figs.samples_held_out == 240 + 180
    assert max(figs.rmse) < 1e-8 and min(figs.fit_pct) > 99.9999
    assert min(figs.persistence_rmse) > 1e-2  # the outputs move: persistence is a real reference
    assert not warnings and "z [m]" in "\n".join(lines) and "pitch [rad]" in "\n".join(lines)


def test_the_figures_are_those_of_the_predictions_made_by_hand():
    sys_ = random_lti(3, 2, 2, 5)
    ds = _data(sys_, noise=1e-3)
    pred = _fit(CFG, ds)
    u, y = ds.trajectories()[1]
    figs = holdout_figures(pred, [(u, y)], stride=7)
    starts = range(T_INI, u.shape[0] - T_F + 1, 7)
    e = np.array([pred.predict(u[k - T_INI:k], y[k - T_INI:k], u[k:k + T_F])[0] - y[k:k + T_F] for k in starts])
    yt = np.array([y[k:k + T_F] for k in starts])
    np.testing.assert_allclose(figs.rmse, np.sqrt((e**2).mean(axis=(0, 1))), rtol=1e-12)
    np.testing.assert_allclose(figs.rmse_last, np.sqrt((e[:, -1] ** 2).mean(axis=0)), rtol=1e-12)
    fit = 100 * (1 - np.linalg.norm(e.reshape(-1, 2), axis=0) / np.linalg.norm((yt - yt.mean((0, 1))).reshape(-1, 2), axis=0))
    np.testing.assert_allclose(figs.fit_pct, fit, rtol=1e-12)
    assert figs.windows == len(starts)


def test_a_predictor_worse_than_holding_the_last_value_is_warned_about():
    sys_ = random_lti(4, 2, 2, 3)
    wrong = LTI(sys_.A, -sys_.B, sys_.C, -sys_.D)  # fitted on the mirrored system: every answer has the wrong sign
    _, lines, warnings = holdout_check(CFG, _data(sys_), lambda cfg, ds: _fit(cfg, _data(wrong, seed=1)), 0.2)
    assert warnings and all("worse than holding its last value" in w for w in warnings)


def test_data_too_short_for_a_held_out_part_skip_the_check_and_say_so():
    figs, lines, warnings = holdout_check(CFG, _data(random_lti(4, 2, 2, 3), n=(60, 50)), _fit, 0.2)
    assert figs is None and not warnings and "skipped" in lines[0]


def test_data_in_stretches_too_short_to_split_hold_out_whole_ones():
    # (a collect split by gaps: 10 stretches of 80 samples, none long enough to keep 20 % of it out)
    sys_ = random_lti(4, 2, 2, 3)
    figs, lines, warnings = holdout_check(CFG, _data(sys_, n=(80,) * 10), _fit, 0.2)
    assert figs is not None and figs.samples_held_out == 160 and figs.windows >= 20
    assert max(figs.rmse) < 1e-8 and not warnings and "2 whole stretches" in lines[0]


@settings(max_examples=60, deadline=None)
@given(lengths=st.lists(st.integers(1, 300), min_size=1, max_size=8), share=st.floats(0.05, 0.95),
       min_len=st.integers(1, 100))
def test_whole_stretches_held_out_keep_every_sample_once(lengths, share, min_len):
    rng = np.random.default_rng(0)
    ds = IODataset([rng.standard_normal((n, 1)) for n in lengths], [rng.standard_normal((n, 2)) for n in lengths], 0.01)
    fit_ds, held = hold_out_whole(ds, share, min_len)
    both = fit_ds.trajectories() + held
    key = lambda t: t[0][0, 0]  # noqa: E731  (each stretch's first input sample: distinct)
    assert sorted(map(key, both)) == sorted(map(key, ds.trajectories())) and len(both) == len(lengths)
    assert key(fit_ds.trajectories()[0]) == key(ds.trajectories()[0])  # the first stays in the fit
    assert all(u.shape[0] >= min_len for u, _ in held)
    assert sum(u.shape[0] for u, _ in fit_ds.trajectories()) >= 0.5 * sum(lengths)


@settings(max_examples=40, deadline=None)
@given(lengths=st.lists(st.integers(1, 400), min_size=1, max_size=4), share=st.floats(0.05, 0.95))
def test_split_keeps_every_sample_once_and_in_order(lengths, share):
    rng = np.random.default_rng(0)
    ds = IODataset([rng.standard_normal((n, 1)) for n in lengths], [rng.standard_normal((n, 2)) for n in lengths], 0.01)
    fit_ds, held = split_holdout(ds, share, min_part=30)
    fit_tr, k = fit_ds.trajectories(), 0
    for u, y in ds.trajectories():
        fu, fy = fit_tr.pop(0)
        if fu.shape[0] < u.shape[0]:  # split: the fit part then the held-out part, nothing else
            hu, hy = held[k]
            k += 1
            np.testing.assert_array_equal(np.vstack([fu, hu]), u)
            np.testing.assert_array_equal(np.vstack([fy, hy]), y)
            assert min(fu.shape[0], hu.shape[0]) >= 30
        else:
            np.testing.assert_array_equal(fu, u)
    assert k == len(held)


def test_a_share_outside_zero_one_is_refused():
    ds = _data(random_lti(4, 2, 2, 3))
    for bad in (0.0, 1.0, -0.1, float("nan")):
        with pytest.raises(ValueError, match="share"):
            split_holdout(ds, bad, 10)
