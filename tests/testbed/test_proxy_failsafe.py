"""The repeated failsafe measurement's statistics (:func:`ddpc_codegen.testbed.proxy_failsafe.compare`) on given
trial times, against Welch's interval computed by hand, and the proxy's last setpoint out per trial from a tick log."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ddpc_codegen.testbed.proxy_failsafe import TARGET_S, _last_out, compare

scipy_stats = pytest.importorskip("scipy.stats")


def _welch(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """Welch's 95 % interval of mean(a) - mean(b), from its closed form."""
    va, vb = a.var(ddof=1) / len(a), b.var(ddof=1) / len(b)
    dof = (va + vb) ** 2 / (va ** 2 / (len(a) - 1) + vb ** 2 / (len(b) - 1))
    h = scipy_stats.t.ppf(0.975, dof) * math.sqrt(va + vb)
    d = a.mean() - b.mean()
    return d - h, d + h


def test_each_arms_figures_and_the_welch_interval_of_the_difference():
    direct = [1.06, 1.11, 1.08, 1.03, 1.09, 1.07]
    proxy = [1.05, 1.12, 1.10, 1.04, 1.07]
    s = compare(direct, proxy)
    assert s["direct"]["n"] == 6 and s["proxy"]["n"] == 5
    assert s["direct"]["mean_s"] == pytest.approx(np.mean(direct)) and s["direct"]["median_s"] == pytest.approx(1.075)
    assert s["proxy"]["median_s"] == pytest.approx(1.07) and s["proxy"]["max_s"] == pytest.approx(1.12)
    assert s["direct"]["std_s"] == pytest.approx(np.std(direct, ddof=1))
    assert s["mean_diff_s"] == pytest.approx(np.mean(proxy) - np.mean(direct))
    assert s["ci95_s"] == pytest.approx(list(_welch(np.array(proxy), np.array(direct))))
    assert s["ci95_s"][0] < s["mean_diff_s"] < s["ci95_s"][1] and 0.0 < s["p_value"] <= 1.0


def test_the_verdict_says_whether_the_interval_lies_within_the_target_outside_it_or_across_it():
    rng = np.random.default_rng(3)
    base = 1.06 + 0.005 * rng.standard_normal(30)
    assert compare(base, base[::-1] + 0.002)["verdict"] == "within target"
    assert compare(base, base + 0.1)["verdict"] == "target missed"
    assert compare(base, base - 0.1)["verdict"] == "target missed"
    wide = 1.06 + 0.05 * rng.standard_normal(4)
    assert compare(wide, wide[::-1] + 0.02)["verdict"] == "unresolved"
    assert TARGET_S == pytest.approx(0.03)  # one 50 Hz app period + 10 ms


def test_trials_without_a_failsafe_are_left_out_and_too_few_give_no_interval():
    s = compare([1.0, None, float("nan"), 1.1], [1.05])
    assert s["direct"]["n"] == 2 and s["direct"]["mean_s"] == pytest.approx(1.05)
    assert s["proxy"]["std_s"] is None and s["ci95_s"] is None and s["verdict"] == "too few trials"
    empty = compare([], [])
    assert empty["direct"]["mean_s"] is None and empty["mean_diff_s"] is None


def test_the_proxys_last_setpoint_out_is_found_per_trial_in_one_tick_log(tmp_path):
    ticks = tmp_path / "ticks.npz"
    t = np.concatenate([100.0 + 0.02 * np.arange(50), 110.0 + 0.02 * np.arange(50)])
    np.savez(ticks, rows=np.array([(v + 3e-4,) for v in t], dtype=[("t", "<f8")]))
    trials = [{"t_last": 100.98}, {"t_last": 110.98}, {"t_last": 120.0}]
    out = _last_out(ticks, trials)
    assert out[0] == pytest.approx(3e-4) and out[1] == pytest.approx(3e-4) and out[2] is None
    assert _last_out(tmp_path / "none.npz", trials) == [None, None, None]
