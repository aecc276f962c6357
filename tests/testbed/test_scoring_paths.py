"""One run, scored in-process (scenario_metrics on the SimResult) and over-the-link style from its tick
log (sitl_demo.flight_figures, bridge_demo.truth_rmse): the same numbers, because one function scores both."""

from __future__ import annotations

import numpy as np
import pytest

from ddpc_codegen.values.prefilter import PrefilterModel
from ddpc_codegen.experiments.evaluate import scenario_metrics
from ddpc_codegen.experiments.policy_hook import PolicyHook
from ddpc_codegen.runtime.baselines import PrefilterPolicy
from ddpc_codegen.sim import FlyingScenario, simulate
from ddpc_codegen.testbed.bridge_demo import truth_rmse
from ddpc_codegen.testbed.sitl_flight import flight_figures
from firmware_bridge.gate import GATE_FLAGS
from firmware_bridge.ticklog import TickRecorder, reason_code


@pytest.fixture(scope="module")
def scored(tmp_path_factory):
    """A 5 s noisy flying run steered by a prefilter (a moving offset), its tick log and truth log."""
    pol = PrefilterPolicy(PrefilterModel((1.0, 1.0), (0.0, 0.0), (20, 0), 0.005))
    res = simulate("flying", 5.0, reference_hook=PolicyHook(pol, "flying"), seed=4, noise=True)
    rec = TickRecorder(2, 2, capacity=res.n)
    steered = (np.arange(res.n) % 3 != 0) & ~((np.arange(res.n) >= 300) & (np.arange(res.n) < 310))
    for k in range(res.n):
        i = rec.new_row()
        a = rec.arrays
        a["t_traj"][i] = a["t_vehicle"][i] = res.t[k]
        a["y"][i], a["y_des"][i], a["u"][i], a["r_nom"][i] = res.y[k], res.y_des[k], res.u[k], res.r_nom[k]
        a["sp_thrust"][i] = res.setpoint_thrust[k]
        a["truth_position"][i, 2] = res.y_true[k, 0]
        a["reason"][i] = reason_code("stale" if 300 <= k < 310 else "steered" if steered[k] else "prefilter")
        a["gate"][i] = GATE_FLAGS["stall"] if k == 310 else 0  # one stall, resumed after 10 stale ticks
        if k in (400, 700):  # two guard saturations (each after a clamped streak)
            a["gate"][i] |= GATE_FLAGS["guard_saturated"] | GATE_FLAGS["guard_clamped"]
        a["solve_us"][i] = 10.0 + k % 100 if steered[k] else np.nan  # the solver's call, on the steered ticks
        a["active"][i] = a["event"][i] = True
    tmp = tmp_path_factory.mktemp("scoring")
    log = rec.to_log(dt=res.dt, input_names=("z_ref", "pitch_ref"), output_names=("z", "pitch")).save(tmp / "run.npz")
    np.savez(tmp / "truth.npz", t=res.t, state=res.state)
    return res, log, tmp / "truth.npz", steered


def test_the_same_run_scores_the_same_in_process_and_from_its_tick_log(scored):
    res, log, truth, steered = scored
    settle = FlyingScenario().settle_time
    sm = scenario_metrics(res)
    ff = flight_figures(log, settle=settle)
    tr = truth_rmse(log, truth, settle=settle)
    np.testing.assert_array_equal(res.y_true[:, 0], res.state[:, 2])  # the truth log's z is the scored z
    # Exactly equal: the same arrays through the same function.
    assert ff["rmse_z_truth"] == tr["rmse_z"] == sm["rmse_z"] == res.metrics()["rmse_z"]
    assert ff["rmse_z"] == tr["rmse_z_telemetry"]
    # And each figure is its definition (independent numpy on the SimResult).
    on = res.t >= settle
    assert ff["ticks"] == tr["samples"] == int(on.sum())
    assert sm["rmse_z"] == pytest.approx(np.sqrt(np.mean((res.y_true[on, 0] - res.y_des[on, 0]) ** 2)), rel=1e-12)
    assert ff["rmse_z"] == pytest.approx(np.sqrt(np.mean((res.y[on, 0] - res.y_des[on, 0]) ** 2)), rel=1e-12)
    assert ff["rmse_z"] != sm["rmse_z"]  # noisy telemetry against the truth: two different figures
    assert ff["estimator_rms"] == pytest.approx(np.sqrt(np.mean((res.y[on, 0] - res.y_true[on, 0]) ** 2)), rel=1e-12)
    off = res.u[on, 0] - res.r_nom[on, 0]
    assert ff["max_offset_step"] == pytest.approx(np.abs(np.diff(off)).max(), rel=1e-12) and ff["max_offset_step"] > 0
    assert ff["max_ref_step"] == pytest.approx(np.abs(np.diff(res.u[on, 0])).max(), rel=1e-12)
    rate = lambda x: np.sqrt(np.mean(np.diff(x) ** 2))  # noqa: E731
    assert ff["ref_rate_ratio"] == pytest.approx(rate(res.u[on, 0]) / rate(res.y_des[on, 0]), rel=1e-12)
    assert ff["thrust_step_rms"] == pytest.approx(np.sqrt(np.mean(np.diff(res.setpoint_thrust[on]) ** 2)), rel=1e-12)
    assert ff["engaged_fraction"] == pytest.approx(steered[on].mean(), rel=1e-12)
    solved = (10.0 + np.arange(res.n) % 100)[steered]  # every solver call of the flight, warm-up included
    assert ff["solve_us_p99"] == pytest.approx(np.percentile(solved, 99), rel=1e-12)
    assert ff["stalls"] == 1 and ff["stale_ticks"] == 10  # counted from the trajectory's start, settle or not
    assert ff["guard_saturations"] == 2
    # the ellipse's height never holds still for 0.5 s: every scored tick is near a change of the path's height
    assert ff["rmse_z_truth_changing"] == pytest.approx(ff["rmse_z_truth"], rel=1e-12) and ff["rmse_z_truth_steady"] is None


def test_flight_figures_count_every_tick_of_the_flown_trajectory(tmp_path):
    """A stall's bumpless blend is logged not active but flown: scored, and the engaged share says how much of
    the trajectory was engaged; the take-off's approach (trajectory clock at 0) and the ticks before are not."""
    rec = TickRecorder(2, 2, capacity=64)
    plan = ["inactive"] * 4 + ["takeoff"] * 6 + ["steered"] * 10 + ["blend"] * 10 + ["steered"] * 20
    t = 0.0
    for k, reason in enumerate(plan):
        i = rec.new_row()
        a = rec.arrays
        err = {"inactive": 1.0, "takeoff": 0.4, "steered": 0.01, "blend": 0.1}[reason]
        if reason not in ("inactive", "takeoff"):
            t += 0.005
        a["t_traj"][i] = np.nan if reason == "inactive" else t
        a["t_vehicle"][i] = 0.005 * k
        a["y_des"][i], a["y"][i], a["u"][i], a["r_nom"][i] = (1.0, 0.0), (1.0 + err, 0.0), (1.0, 0.0), (1.0, 0.0)
        a["truth_position"][i] = (0.0, 0.0, 1.0 + 2 * err)
        a["estimate_position"][i] = (0.0, 0.0, 1.0 + err)
        a["reason"][i] = reason_code(reason)
        a["active"][i] = a["event"][i] = reason == "steered"
    log = rec.to_log(dt=0.005, input_names=("z_ref", "pitch_ref"), output_names=("z", "pitch")).save(tmp_path / "l.npz")
    ff = flight_figures(log, settle=0.0)
    assert ff["ticks"] == 40 and ff["engaged_share"] == pytest.approx(30 / 40)
    assert ff["rmse_z"] == pytest.approx(np.sqrt((30 * 0.01**2 + 10 * 0.1**2) / 40), rel=1e-12)
    assert ff["rmse_z_truth"] == pytest.approx(2 * ff["rmse_z"], rel=1e-12)
    assert ff["engaged_fraction"] == pytest.approx(30 / 40)  # the steered share of the same ticks
    assert ff["ekf_rms"] == pytest.approx(ff["estimator_rms"], rel=1e-12)  # measured on the autopilot's estimate
    # the bridge demo's truth log scores the same ticks
    state = np.zeros((len(plan), 12))
    state[:, 2] = rec.arrays["truth_position"][: len(plan), 2]
    np.savez(tmp_path / "truth.npz", t=0.005 * np.arange(len(plan)), state=state)
    assert truth_rmse(log, tmp_path / "truth.npz", settle=0.0)["rmse_z"] == pytest.approx(ff["rmse_z_truth"], rel=1e-12)
