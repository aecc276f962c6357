"""The loop's record (firmware_bridge/report.py :class:`FlightRecorder`) and its trigger
(firmware_bridge/clock.py :class:`TickTrigger`), built alone: a row per tick from the typed reference,
the statistics the summary reports; lock-step ticks, gaps and holes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ddpc_codegen.robot.state import MeasuredState
from firmware_bridge.clock import TickTrigger
from firmware_bridge.plausibility import TIMELINE_SAMPLES
from firmware_bridge.reference_stage import TickReference
from firmware_bridge.report import FlightRecorder
from firmware_bridge.telemetry import TelemetryState
from firmware_bridge.ticklog import REASONS, TICK_FIELDS, column_frames
from firmware_bridge.truth import SimTruth
from part_fakes import line, telemetry

DT = 0.005


def _row(rec: FlightRecorder, k: int, reason: str = "steered", u_st=True) -> None:
    y = np.array([1.0 + 0.001 * k, 0.0])
    ref = TickReference(np.array([1.0, 0.0]), y, np.array([1.01, 0.0]), reason,
                        u_steered=np.array([1.01, 0.0]) if u_st else None, solve_us=42.0, adapt=2)
    state = MeasuredState(t=k * DT, position=np.array([0.0, 0.0, y[0]]), velocity=np.zeros(3), euler=np.zeros(3),
                          body_rates=np.zeros(3))
    rec.record(ref, np.array([1.005, 0.0]), state, now=10.0 + k * DT, t_sent=10.0 + k * DT + 1e-4,
               t_vehicle=k * DT, t_traj=k * DT, age=0.002, q=(1.0, 0.0, 0.0, 0.0), thrust=0.5, field=0.5, event=True,
               engaged=True, fresh=True, sent=True, gap=False, n_new=2, latency=300.0, gate=0, armed=True,
               offboard=True, y_des=np.array([1.0, 0.0]), phase=0, backdate=0, contact=None, truth=SimTruth())


def test_a_row_holds_the_typed_reference_and_the_applied_one():
    rec = FlightRecorder(2, 2, DT, t0=10.0, lockstep=False, capacity=2)
    for k in range(20):  # grows past its capacity
        _row(rec, k, u_st=k % 2 == 0)
    v = rec.rows.view()
    assert rec.n == 20 and np.allclose(v["u"][:, 0], 1.005) and np.allclose(v["r_nom"][:, 0], 1.0)
    assert np.isnan(v["u_steered"][1, 0]) and v["u_steered"][0, 0] == 1.01 and np.all(v["adapt"] == 2)
    assert np.all(v["reason"] == REASONS.index("steered")) and np.allclose(v["compute_us"], 100.0)
    assert v["valid"].all() and np.all(v["contact"] == -1) and np.isnan(v["truth_position"]).all()
    assert math.isclose(v["t_wall"][3], 3 * DT)


def test_statistics_count_reasons_fallbacks_and_missed_ticks():
    rec = FlightRecorder(2, 2, DT, t0=10.0, lockstep=True)
    for k in range(10):
        _row(rec, k, reason="steered" if k < 7 else "solver_failed")
    send = np.r_[np.arange(5) * DT, 7 * DT + np.arange(5) * DT]  # two ticks missed
    s = rec.statistics(send, settle=0.0)
    assert s["ticks"] == 10 and s["reasons"] == {"steered": 7, "solver_failed": 3}
    assert s["fallbacks"] == 3 and s["missed_ticks"] == 2 and s["event_ticks"] == 10
    assert s["rmse_samples"] == 10 and s["rmse_z_measured"] > 0


def test_lockstep_ticks_on_every_pair_of_samples_and_bridges_short_gaps():
    tr = TickTrigger(DT, lockstep=True, max_gap_fill=3)
    tel = TelemetryState()
    assert tr.due(0.0, tel) == ""
    for m in line(1.0):  # a time line the vehicle's: five samples advanced on it
        tel.update(m, 0.0)
    assert tr.due(0.0, tel) == "event"
    age, t, n_new = tr.timing(0.0, tel)
    assert (age, t, n_new) == (0.0, 1.0, 2 * TIMELINE_SAMPLES) and tr.gap(t, tel) == (False, 0, False)
    assert tr.due(0.0, tel) == ""  # used
    for stamp, want in ((1.005, (False, 0, False)), (1.02, (True, 2, False)), (1.2, (True, 0, True))):
        for m in telemetry(stamp):
            tel.update(m, 0.0)
        assert tr.gap(stamp, tel) == want
    assert tr.gaps == 2


def test_real_time_ticks_on_the_grid_from_the_first_complete_telemetry():
    tr = TickTrigger(DT, lockstep=False, max_gap_fill=3)
    tel = TelemetryState()
    for m in line(1.0):
        tel.update(m, 5.0)
    assert tr.due(5.0, tel) == "grid" and tr.wake_in(5.0) == 0.0
    tr.done("grid", 5.001)
    assert tr.due(5.002, tel) == "" and abs(tr.wake_in(5.002) - 0.003) < 1e-9
    age, t, _ = tr.timing(5.006, tel)
    assert abs(age - 0.006) < 1e-9 and t == DT


def test_statistics_score_every_tick_of_the_trajectory_and_say_the_engaged_share():
    """A stall's blend (not active) is flown and scored; the take-off's approach (its clock at 0) is not."""
    rec = FlightRecorder(2, 2, DT, t0=10.0, lockstep=True)
    plan = ["takeoff"] * 2 + ["blend"] * 3 + ["steered"] * 5
    for k, reason in enumerate(plan):
        err = {"takeoff": 0.5, "blend": 0.1, "steered": 0.0}[reason]
        y = np.array([1.0 + err, 0.0])
        ref = TickReference(np.array([1.0, 0.0]), y, np.array([1.0, 0.0]), reason)
        state = MeasuredState(t=0.0, position=np.array([0.0, 0.0, y[0]]), velocity=np.zeros(3), euler=np.zeros(3),
                              body_rates=np.zeros(3))
        rec.record(ref, np.array([1.0, 0.0]), state, now=10.0 + k * DT, t_sent=10.0 + k * DT, t_vehicle=k * DT,
                   t_traj=0.0 if reason == "takeoff" else (k - 1) * DT, age=0.002, q=(1.0, 0.0, 0.0, 0.0), thrust=0.5,
                   field=0.5, event=True, engaged=reason == "steered", fresh=True, sent=True, gap=False, n_new=2,
                   latency=300.0, gate=0, armed=True, offboard=True, y_des=np.array([1.0, 0.0]), phase=0, backdate=0,
                   contact=None, truth=SimTruth())
    s = rec.statistics(np.arange(10) * DT, settle=0.0)
    assert s["rmse_samples"] == 8  # the blend's 3 ticks and the 5 steered ones
    assert s["rmse_z_measured"] == pytest.approx(math.sqrt(3 * 0.1**2 / 8))
    assert s["engaged_share"] == pytest.approx(5 / 8)
    assert rec.statistics(np.arange(10) * DT, settle=1.0)["engaged_share"] is None  # nothing scored


def test_the_columns_with_a_frame_say_which():
    """The measured state is in the bridge's trajectory frame (start frame: turned by the start heading), the
    truth in world ENU: never both just "ENU"."""
    start, world = column_frames("start"), column_frames("world")
    for cols in (start, world):
        assert cols["truth_position"].startswith("[m] world ENU") and "not the trajectory frame" in cols["truth_position"]
        assert set(cols) >= {"position", "velocity", "euler", "estimate_position", "truth_velocity", "mocap_position"}
    assert "the bridge's start frame" in start["position"] and "from the start heading" in start["euler"]
    assert "the autopilot's local ENU frame" in world["position"] and "from east" in world["euler"]
    assert set(start) <= set(TICK_FIELDS)
