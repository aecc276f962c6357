"""Beyond the ellipse (:mod:`ddpc_codegen.testbed.sitl_conditions`): the non-repeating steps file, the
per-round figures and the printed target lines (no SITL needed), and against the real SITLs (skipped
without them): each unseen change is a parameter the SITL accepts and echoes, and the ground truth
arrives as the bridge asks for it (PX4 SIH: HIL_STATE_QUATERNION, ArduCopter: SIM_STATE)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ddpc_codegen.robot.trajectory_files import load_trajectory
from ddpc_codegen.testbed import sitl as h
from ddpc_codegen.testbed.sitl_conditions import (CONDITIONS, METHODS, steered_estimator_rms, summarize_rounds,
                                                  write_steps_trajectory)
from ddpc_codegen.testbed.sitl_demo import format_condition, main


def test_the_steps_file_is_a_non_repeating_3d_path_with_height_steps(tmp_path):
    tr = load_trajectory(write_steps_trajectory(tmp_path / "steps.csv", seed=0))
    assert tr.y is not None and tr.start_position() == (0.0, 0.0, 1.0)
    t = np.arange(0.0, 22.0, 0.005)
    d = tr.sample(t)
    levels = [float(tr.sample(ts + 1.5)["z"]) for ts in (4.0, 8.0, 12.0, 16.0)]
    steps = np.abs(np.diff([1.0, *levels]))
    assert np.all((steps >= 0.15 - 1e-6) & (steps <= 0.3 + 1e-6)), steps
    assert np.ptp(d["x"]) > 1.1 and np.ptp(d["y"]) > 0.45         # it moves in x and y
    # Each step's ramp stays under both SITL configs' z rate bound (ArduCopter 1 m/s, PX4 1.2 m/s).
    assert np.max(np.abs(d["vz"])) < 1.0
    # No repetition: the 11 s and 7.3 s horizontal periods and the steps never line up.
    assert np.max(np.abs(tr.sample(t[t < 8.0] + 11.0)["y"] - d["y"][t < 8.0])) > 0.1
    other = load_trajectory(write_steps_trajectory(tmp_path / "other.csv", seed=1))
    assert not np.allclose(other.sample(t)["z"], d["z"])


def _flight(v: float, est: float | None = 0.01) -> dict:
    return {"rmse_z": v, "rmse_z_truth": v + 0.001, "thrust_step_rms": 0.002, "max_ref_step": 0.004,
            "max_offset_step": 0.003, "fallbacks": 0, "estimator_rms": est}


def test_rounds_are_averaged_per_method_and_ilc_is_none_off_the_ellipse():
    r1 = {m: _flight(v) for m, v in zip(METHODS, (0.10, 0.06, 0.04, 0.01))}
    r2 = {m: _flight(v, est=0.02) for m, v in zip(METHODS, (0.12, 0.08, 0.05, 0.02))}
    s = summarize_rounds([r1, r2])
    assert s["rmse_z"] == {"passthrough": pytest.approx(0.11), "ctrl_ff": pytest.approx(0.07),
                           "prefilter": pytest.approx(0.045), "steered": pytest.approx(0.015), "ilc": None}
    assert s["rmse_z_truth"]["steered"] == pytest.approx(0.016) and s["rmse_z_truth"]["ilc"] is None
    # the estimator's error per method, in that method's own flights (the target compares like with like)
    assert s["estimator_rms"] == {m: pytest.approx(math.sqrt((0.01**2 + 0.02**2) / 2)) for m in METHODS}
    r2["ctrl_ff"]["estimator_rms"] = None
    assert summarize_rounds([r1, r2])["estimator_rms"]["ctrl_ff"] is None
    r1["steered"]["estimator_rms"] = 0.03
    assert steered_estimator_rms(summarize_rounds([r1, r2])) == pytest.approx(math.sqrt((0.03**2 + 0.02**2) / 2))
    assert steered_estimator_rms({"estimator_rms": 0.007}) == 0.007  # a report from before: one figure
    assert s["rounds"] == [r1, r2]
    # the constant part of the estimator's error per flight, RMS over the rounds; None when a flight has none
    assert s["estimator_bias_rms"]["steered"] is None  # these flights predate the figure
    r1["steered"]["estimator_bias"], r2["steered"]["estimator_bias"] = 0.003, -0.004
    assert summarize_rounds([r1, r2])["estimator_bias_rms"]["steered"] == pytest.approx(math.sqrt((9e-6 + 16e-6) / 2))
    r2["steered"]["rmse_z_truth"] = None  # a flight without truth: no mean for that method
    assert summarize_rounds([r1, r2])["rmse_z_truth"]["steered"] is None


def test_the_solve_time_of_the_rounds_is_the_worst_flight_s():
    r1 = {m: _flight(0.01) for m in METHODS}
    r2 = {m: _flight(0.01) for m in METHODS}
    r1["steered"]["solve_us_p99"], r2["steered"]["solve_us_p99"] = 300.0, 700.0
    s = summarize_rounds([r1, r2])
    assert s["solve_us_p99"]["steered"] == 700.0  # a latency target holds in every flight, not on average
    assert s["solve_us_p99"]["passthrough"] is None  # nothing solved (or a report from before the figure)
    assert s["stalls"]["steered"] is None  # flights from before the bridge's stalls were counted
    r1["steered"].update(stalls=1, stale_ticks=30)
    r2["steered"].update(stalls=0, stale_ticks=0)
    s = summarize_rounds([r1, r2])
    assert s["stalls"]["steered"] == 0.5 and s["stale_ticks"]["steered"] == 15.0  # mean of the rounds, as fallbacks
    assert s["guard_saturations"]["steered"] is None  # flights from before the saturations were counted


def test_condition_lines_state_the_target_on_the_true_height():
    c = {"rmse_z": {"passthrough": 0.1, "ctrl_ff": 0.05, "prefilter": 0.04, "ilc": None, "steered": 0.01},
         "rmse_z_truth": {"passthrough": 0.1, "ctrl_ff": 0.05, "prefilter": 0.04, "ilc": None, "steered": 0.016},
         "estimator_rms": {"steered": 0.008}, "max_ref_step": {"steered": 0.3}, "max_offset_step": {"steered": 0.005},
         "thrust_step_rms": {"passthrough": 0.002, "steered": 0.003}}
    assert format_condition("px4", "heavy", c).splitlines() == [
        "[sitl-demo] px4 heavy EKF height rmse: passthrough 100.0, ctrl ff 50.0, prefilter 40.0, ilc -, steered 10.0 mm",
        "[sitl-demo] px4 heavy true height rmse: passthrough 100.0, ctrl ff 50.0, prefilter 40.0, ilc -, steered 16.0 mm",
        "[sitl-demo] px4 heavy target >= 2x the best simple method (2.50x); estimator error in the steered flights 8.0 mm "
        "(steered 2.00x of it); largest reference step 300.0 mm per tick (of the correction u - r_nom 5.0); thrust step 1.5x "
        "passthrough's"]
    c.update(stalls={"steered": 2.0}, stale_ticks={"steered": 40.0})
    assert format_condition("px4", "heavy", c).endswith("; bridge stalls 2, stale ticks 40")
    c["guard_saturations"] = {"steered": 0.5}
    assert format_condition("px4", "heavy", c).endswith("; bridge stalls 2, stale ticks 40, guard saturations 0.5")
    assert format_condition("px4", "wind", {"skipped": CONDITIONS["px4"]["wind"]}) == (
        "[sitl-demo] px4 wind: PX4 SIH in this build has no wind parameter (no SIH_WIND_*): not flown")
    c["ilc"] = None
    c["rmse_z_truth"]["ilc"] = 0.03
    assert "target >= 10x passthrough (6.2x)" in format_condition("ardupilot", "ellipse", c)


def test_demo_tools_write_the_steps_file_and_refuse_bad_rounds(tmp_path, capsys):
    assert main(["--write-steps", str(tmp_path / "s.csv")]) == 0
    assert load_trajectory(tmp_path / "s.csv").duration == pytest.approx(22.0)
    with pytest.raises(SystemExit):
        main(["--rounds", "0", "--autopilot", "px4"])
    assert "--rounds must be >= 1; got 0" in capsys.readouterr().err


@pytest.mark.sitl
@pytest.mark.parametrize("autopilot", ["px4", "ardupilot"])
def test_unseen_changes_are_sitl_parameters_and_the_truth_arrives(autopilot):
    why = h.missing_reason(autopilot)
    if why:
        pytest.skip(why)
    res = h.run_isolated("sitl.isolated_funcs:sitl_conditions_and_truth", {"autopilot": autopilot}, timeout=240)
    for name, spec in CONDITIONS[autopilot].items():
        if not isinstance(spec, str):
            assert res["echoed"][name] == [pytest.approx(spec[0]), pytest.approx(spec[1])], name
    assert "did not confirm ['NO_SUCH_PARAM_X'] within 3 s" in res["refused"]
    assert res["truth_samples"] >= 20 and res["source"] == {"px4": "HIL_STATE_QUATERNION", "ardupilot": "SIM_STATE"}[
        autopilot]
    assert np.all(np.abs(res["truth_position"]) < 0.5)  # standing on the ground where it was captured
    assert all(0.0 <= dt < 2.0 for dt in res["second_link_s"])  # set and echoed over the second link (sitl-adapt)


def test_the_pipeline_refuses_unknown_conditions_before_starting_a_sitl(tmp_path):
    from ddpc_codegen.testbed.sitl_demo import run_pipeline

    with pytest.raises(ValueError, match=r"^unknown condition\(s\) \['rain'\]; choose from \['heavy', 'motor', "
                                         r"'steps', 'wind'\]$"):
        run_pipeline("px4", str(tmp_path / "x"), conditions=["heavy", "rain"])
    with pytest.raises(ValueError, match=r"^conditions need the baselines \(the prefilter is fitted there\)$"):
        run_pipeline("px4", str(tmp_path / "x"), conditions=["heavy"], baselines=False)
    assert not (tmp_path / "x").exists()
