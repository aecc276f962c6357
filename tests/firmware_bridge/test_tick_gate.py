"""The tick's last gate (firmware_bridge/tick_gate.py), built alone: the guard clamp of a refused steered
step, guard saturation on the control clock, stalls of the loop's clock, tilt / thrust clamps, a non-finite
setpoint, and the events at the start of each streak."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np

from ddpc_codegen.robot.frames import euler_from_quat
from firmware_bridge.events import EventLog
from firmware_bridge.gate import GATE_FLAGS, SetpointGate
from firmware_bridge.reference_stage import TickReference
from firmware_bridge.tick_gate import TickGate

LO, HI = np.array([0.2, -0.5]), np.array([3.0, 0.5])


def _gate(**kw) -> TickGate:
    kw = {"max_step": np.array([0.05, 0.05]), "max_tilt": math.radians(20.0), "thrust_min": 0.1, "thrust_max": 0.9,
          "hover_thrust": 0.5, "max_age": 0.05, "guard_hold": 0.1, **kw}
    return TickGate(SetpointGate(LO, HI, np.array([1.0, 1.0])), EventLog(t0=0.0), **kw)


def _ref(u, r_nom=(1.0, 0.0), candidate=None, reason="steered") -> TickReference:
    return TickReference(np.array(r_nom), np.array([1.0, 0.0]), np.array(u), reason,
                         candidate=None if candidate is None else np.array(candidate))


def test_a_refused_step_is_clamped_to_the_guard_and_saturates_after_the_hold():
    g = _gate()
    u, flags = g.reference(_ref([1.0, 0.0], candidate=[1.3, -0.2], reason="step_too_large"))
    assert np.allclose(u, [1.05, -0.05]) and flags & GATE_FLAGS["guard_clamped"]
    sat = [g.saturated(flags, 10.0 + 0.01 * k, 0.01 * k) for k in range(12)]
    assert sat.index(GATE_FLAGS["guard_saturated"]) == 10 and sum(map(bool, sat)) == 1  # 0.1 s held
    assert g.guard_saturations == [{"t": 10.1, "held_s": 0.1}] and g.gate.counts["guard_saturated"] == 1
    assert g.saturated(0, 11.0, 1.0) == 0 and math.isnan(g.clamped_since)  # a clean tick ends the streak


def test_a_gap_of_the_loops_clock_is_a_stall_and_lockstep_has_none():
    g = _gate()
    assert not g.stalled(1.0) and not g.stalled(1.005)
    assert g.stalled(1.2) and g.stalls == [{"t": 1.2, "gap_s": 0.195}]
    assert g.events.events[-1][1].startswith("bridge stalled: no tick for 0.195 s")
    assert not _gate(max_age=None).stalled(5.0)


def test_tilt_and_thrust_are_clamped_and_counted():
    g = _gate()
    sp = SimpleNamespace(euler=(0.0, math.radians(35.0), 0.3), q=(1.0, 0.0, 0.0, 0.0), thrust=1.4)
    q, thrust = g.clamp(sp)
    assert thrust == 0.9 and g.counts == {"tilt_clamped": 1, "thrust_clamped": 1}
    roll, pitch, yaw = euler_from_quat(q)
    assert abs(pitch - math.radians(20.0)) < 1e-9 and abs(roll) < 1e-12 and abs(yaw - 0.3) < 1e-9
    q, thrust = g.clamp(SimpleNamespace(euler=(0.0, 0.0, 0.0), q=(1.0, 0.0, 0.0, 0.0), thrust=float("nan")))
    assert thrust == 0.5 and q == (1.0, 0.0, 0.0, 0.0) and g.counts["thrust_clamped"] == 2


def test_a_non_finite_setpoint_is_never_sent():
    g = _gate()
    level = ((1.0, 0.0, 0.0, 0.0), 0.5, 0.5)
    assert g.setpoint((1.0, 0.0, 0.0, 0.0), 0.6, 0.6, lambda: level) == ((1.0, 0.0, 0.0, 0.0), 0.6, 0.6, 0)
    out = g.setpoint((float("nan"), 0.0, 0.0, 0.0), 0.6, 0.6, lambda: level)
    assert out == (*level, GATE_FLAGS["nonfinite_setpoint"]) and g.gate.counts["nonfinite_setpoint"] == 1


def test_events_say_each_streak_once():
    g = _gate()
    u, r = np.array([1.0, 0.0]), np.array([1.0, 0.0])
    notes = ["contact signal refused: test"]
    for _ in range(3):
        g.report(u, r, "solver_infeasible", GATE_FLAGS["rate_limited"], notes, dropped=0)
    g.report(u, r, "steered", 0, [], dropped=2)
    said = [w for _, w in g.events.events]
    assert said == ["gate: rate_limited (reference [1.0, 0.0], nominal [1.0, 0.0])",
                    "fallback: solver_infeasible (reference rate-limited back to the nominal one)",
                    "contact signal refused: test",
                    "telemetry with a non-finite field (or a non-unit quaternion) dropped; counted in summary "
                    "telemetry_dropped"]
    assert notes == []  # drained
