"""The loop's engagement (firmware_bridge/engagement.py :class:`Engagement`), built alone: edges and the
trajectory clock, the take-off ramp, the bumpless blend, staleness and the resume after it."""

from __future__ import annotations

import numpy as np

from firmware_bridge.engagement import Engagement
from firmware_bridge.events import EventLog

DT = 0.005


def _eng(**kw) -> Engagement:
    return Engagement(EventLog(t0=0.0), describe=lambda: "steer; frame", **kw)


def test_the_first_engagement_starts_the_trajectory_clock_and_later_ones_continue_it():
    e = _eng()
    y = np.array([1.0, 0.0])
    assert e.update(False, 3.0, y, 1.0, "POSCTL") == "" and e.trajectory_time(3.0) == 0.0
    assert e.update(True, 4.0, y, 1.0, "OFFBOARD") == "first" and e.flown and e.activations == 1
    assert e.trajectory_time(6.5) == 2.5 and e.update(True, 4.005, y, 1.0, "OFFBOARD") == ""
    assert e.update(False, 7.0, y, 1.0, "POSCTL") == "lost"
    assert e.update(True, 9.0, y, 1.0, "OFFBOARD") == "again" and e.trajectory_time(9.0) == 5.0
    said = [w for _, w in e.events.events]
    assert said == ["engaged (OFFBOARD, armed): trajectory starts, steer; frame",
                    "disengaged: vehicle no longer armed + off-board (or link lost)",
                    "re-engaged (OFFBOARD): trajectory continues at t = 5.000 s, same frame"]


def test_why_the_nominal_reference_passes():
    e = _eng()
    r, y = np.array([1.0, 0.0]), np.array([1.0, 0.0])
    assert e.reference(r, y, 0.0, DT, heard=False, engaged=False, fresh=True)[1] == "no_heartbeat"
    assert e.reference(r, y, 0.0, DT, heard=True, engaged=False, fresh=True)[1] == "inactive"
    assert e.reference(r, y, 0.0, DT, heard=True, engaged=True, fresh=False)[1] == "stale"
    assert e.reference(r, y, 0.0, DT, heard=True, engaged=True, fresh=True)[1] == ""


def test_the_take_off_ramp_holds_the_trajectory_clock_until_the_start_height_is_held():
    e = _eng(takeoff=True, start_height=lambda: 1.0, climb_rate=1.0, tolerance=0.05, timeout=5.0)
    y = np.array([0.0, 0.0])
    assert e.update(True, 0.0, y, 0.0, "OFFBOARD") == "first" and e.approach is not None
    t, heights = 0.0, []
    while e.approach is not None and t < 10.0:
        z_ref, why = e.reference(np.array([1.0, 0.0]), np.array([min(t, 1.0), 0.0]), t, DT, heard=True, engaged=True,
                                 fresh=True)
        assert why == "takeoff"
        heights.append(z_ref[0])
        e.update(True, t, y, 0.0, "OFFBOARD")
        t += DT
    assert np.all(np.diff(heights) >= 0) and heights[-1] == 1.0 and np.diff(heights).max() <= DT + 1e-12
    assert e.approach_result["held"] and e.trajectory_time(t) <= 2 * DT + 1e-9  # the clock waited at the start
    assert e.events.events[-1][1] == "at the trajectory's start height: trajectory starts"


def test_an_engagement_blends_from_the_measured_outputs():
    e = _eng(blend_rates=(0.5, 1.0))
    e.update(True, 0.0, np.array([0.8, 0.0]), 0.8, "OFFBOARD")
    r, why = e.reference(np.array([1.0, 0.0]), np.array([0.8, 0.0]), 0.0, DT, heard=True, engaged=True, fresh=True)
    assert why == "blend" and r[0] == 0.8 + 0.5 * DT


def test_stale_telemetry_goes_quiet_after_the_limit_and_resumes_from_the_reference_last_applied():
    e = _eng(blend_rates=(0.5, 1.0), max_age=0.05, stale_action="hold", stale_stream_limit=1.0)
    e.update(True, 0.0, np.array([1.0, 0.0]), 1.0, "OFFBOARD")
    e.applied(np.array([1.1, 0.0]))
    assert e.telemetry(1.0, 0.01, True)
    assert e.telemetry(2.0, 0.2, False) and e.telemetry(2.9, 1.1, False)
    assert not e.telemetry(3.01, 1.2, False)  # past the stream limit: quiet
    assert e.telemetry(3.5, 0.01, True) and e.resume_pending
    assert e.update(True, 3.5, np.array([1.2, 0.0]), 1.2, "OFFBOARD") == "resume" and not e.resume_pending
    # what the vehicle flew on meanwhile, not the measured outputs (1.2) plus an offset: no step of its drift
    assert np.allclose(e.blend.current, [1.1, 0.0])
    said = [w for _, w in e.events.events]
    assert said[-3:] == ["telemetry stale (age 200.0 ms > 50 ms): fallback 'hold'", "telemetry fresh again after 1.500 s",
                         "resumed after stale telemetry: trajectory continues at t = 3.500 s, same frame"]


def test_a_stall_resumes_only_once_flying():
    e = _eng()
    e.stalled()
    assert not e.resume_pending
    e.update(True, 0.0, np.zeros(2), 1.0, "OFFBOARD")
    e.stalled()
    assert e.update(True, 1.0, np.zeros(2), 1.0, "OFFBOARD") == "resume"
