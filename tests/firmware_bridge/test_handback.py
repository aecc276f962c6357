"""Issue 46 item 4: hand-backs and resumes never jump. The parts built alone with a fake clock (no sockets): a
stall of the bridge's own clock while the vehicle drifted resumes with every applied-reference step within the
rate bound, from what the vehicle was last sent (never from a nominal re-anchored to the measured outputs);
the pause is one stall and no link event; a clamp at the step guard is a clamp (its reason, the solver's
proposal in the tick log), not a fallback."""

from __future__ import annotations

import math

import numpy as np
import pytest

from firmware_bridge.clock import TickTrigger
from firmware_bridge.engagement import Engagement
from firmware_bridge.events import EventLog
from firmware_bridge.gate import GATE_FLAGS, SetpointGate
from firmware_bridge.reference_stage import TickReference
from firmware_bridge.report import FlightRecorder
from firmware_bridge.telemetry import TelemetryState
from firmware_bridge.tick_gate import TickGate
from firmware_bridge.ticklog import FALLBACK_REASONS, REASONS
from part_fakes import heartbeat, line, telemetry, vehicle

DT = 0.005
RATE = np.array([0.001, 0.002])  # per tick: the gate's bound (the solver's du_max)
R_NOM = np.array([1.0, 0.0])     # hover: the path's nominal reference does not move


def _loop(events: EventLog):
    gate = TickGate(SetpointGate(np.array([0.0, -0.5]), np.array([3.0, 0.5]), RATE.copy()), events,
                    max_step=np.array([0.05, 0.05]), max_tilt=math.radians(20.0), thrust_min=0.1, thrust_max=0.9,
                    hover_thrust=0.5, max_age=0.05, guard_hold=0.0)
    # the bridge caps the blend at the gate's rate bound (firmware_bridge.bridge._engagement)
    eng = Engagement(events, blend_rates=tuple(np.minimum((0.5, 0.5), RATE / DT)), max_age=0.05)
    return gate, eng


def _tick(gate: TickGate, eng: Engagement, now: float, y: np.ndarray, steer: np.ndarray) -> tuple[np.ndarray, str]:
    """One tick of the bridge's order: stall check, edges, nominal (+ blend), the mode's reference, the gate."""
    if gate.stalled(now):
        eng.stalled()
    eng.update(True, now, y, float(y[0]), "OFFBOARD")
    r, hold = eng.reference(R_NOM.copy(), y, now, DT, heard=True, engaged=True, fresh=True)
    ref = TickReference(r, y, r if hold else r + steer, hold or "steered")  # steered: a 3 cm correction
    u, _flags = gate.reference(ref, edge=eng.edge)
    eng.applied(u)
    return u, eng.edge


def test_a_stall_while_the_vehicle_drifted_resumes_within_the_rate_bound_from_what_it_was_sent():
    events = EventLog(t0=0.0)
    gate, eng = _loop(events)
    steer = np.array([0.03, 0.01])
    y = R_NOM.copy()
    applied, now = [], 0.0
    for _ in range(200):  # engaged and steered: the correction builds up at the rate bound
        applied.append(_tick(gate, eng, now, y, steer)[0])
        now += DT
    assert np.allclose(applied[-1], R_NOM + steer)
    # The bridge's process is stopped for 4 s; the vehicle, on its last setpoint, drifted 0.3 m meanwhile.
    now += 4.0
    y = R_NOM + np.array([0.3, 0.05])
    edges = []
    for _ in range(400):
        u, edge = _tick(gate, eng, now, y, np.zeros(2))
        applied.append(u)
        edges.append(edge)
        now += DT
    assert edges[0] == "resume" and edges.count("resume") == 1
    steps = np.abs(np.diff(np.array(applied), axis=0))
    assert np.all(steps <= RATE + 1e-12), steps.max(axis=0)  # the nominal does not move: the bound is the rate
    assert np.allclose(applied[-1], R_NOM)  # handed back to the nominal reference, at the rate bound
    assert gate.stalls == [{"t": 5.0, "gap_s": 4.005}]
    assert [e for _, e in events.events if e.startswith("resumed")] == [
        "resumed after a stall of the bridge: trajectory continues at t = 5.000 s, same frame"]


def test_the_tick_that_sees_a_stall_runs_at_the_wall_clocks_grid_time():
    """ArduCopter SITL, 4 s SIGSTOP of the bridge: the tick that saw the stall ran at its missed deadline's time and
    the next one 4 s later, so the resume was re-anchored before the trajectory clock jumped and the path's 0.5 m
    jump passed the gate as the path's own motion. The late tick takes the newest grid point: one jump, there."""
    tr, tel = TickTrigger(DT, lockstep=False, max_gap_fill=3), TelemetryState()
    for m in line(1.0):
        tel.update(m, 5.0)
    assert tr.due(5.0, tel) == "grid"
    tr.done("grid", 5.001)
    assert tr.due(9.0025, tel) == "grid"  # stopped from 5.001 to 9.0025
    _age, t, _n = tr.timing(9.0025, tel)
    assert t == pytest.approx(4.0) and tr.clock.skipped == 799  # grid points 1..799 passed over, 800 runs now
    tr.done("grid", 9.003)
    assert tr.due(9.004, tel) == "" and tr.timing(9.005, tel)[1] == pytest.approx(4.005)


def test_the_first_engagement_starts_at_the_take_offs_reference_not_at_what_inactive_ticks_computed():
    """ArduCopter SITL: disarmed, the inactive ticks computed the path's start (0.9 m) -- never sent, the vehicle
    got the idle ground setpoint; at the engagement the take-off's ramp starts at the measured height, but the
    envelope's rate clamp held the applied reference at 0.75 m and it came down at the gate's rate bound plus
    the ramp's, 8.5 mm per tick, for 70 ticks: 0.68 thrust on the ground. It starts on the ramp."""
    gate = TickGate(SetpointGate(np.array([0.0, -0.5]), np.array([3.0, 0.5]), RATE.copy()), EventLog(t0=0.0),
                    max_step=None, max_tilt=0.5, thrust_min=0.1, thrust_max=0.9, hover_thrust=0.5, max_age=0.05,
                    guard_hold=0.0, ref_rate=np.array([30.0, 100.0]), period=DT)
    start = np.array([0.9, 0.0])
    for _ in range(5):
        gate.reference(TickReference(start, np.zeros(2), start, "inactive"))
    ramp = np.array([0.0025, 0.0])
    u, flags = gate.reference(TickReference(ramp, np.zeros(2), ramp, "takeoff"), edge="first")
    assert np.allclose(u, ramp) and flags == 0
    u, _ = gate.reference(TickReference(2 * ramp, np.zeros(2), 2 * ramp, "takeoff"))
    assert np.allclose(u, 2 * ramp)


def test_a_bridge_pause_is_one_stall_and_no_link_event():
    """The bridge read nothing for 4 s while the vehicle went on sending: no link loss, no restore."""
    v = vehicle(link_timeout=0.5)
    gate, _eng = _loop(v.events)
    rx = 100.0
    for k in range(100):
        if k % 50 == 0:
            v.on_message(heartbeat(), rx)
        for m in telemetry(10.0 + 0.005 * k):
            v.on_message(m, rx)
        gate.stalled(rx)
        v.watch(rx, 10.0)
        rx += DT
    # paused between its read and its clock: the first tick after the pause sees the old messages only ...
    now = rx + 4.0
    assert gate.stalled(now)
    v.bridge_paused(now, gate.stalls[-1]["gap_s"])
    assert v.heard(now) and not v.watch(now, 10.0)
    # ... then the backlog and the vehicle's heartbeats (several in one read) arrive
    for k in range(8):
        v.on_message(heartbeat(), now + 0.001 * k)
        for m in telemetry(14.5 + 0.005 * k):
            v.on_message(m, now + 0.001 * k)
        v.watch(now + 0.001 * k, 10.0)
    said = [e for _, e in v.events.events]
    assert sum(e.startswith("bridge stalled") for e in said) == 1
    assert not [e for e in said if "link" in e or "silent" in e], said
    assert v.counts["link_losses"] == 0 and v.counts["stream_requests"] == 0


def test_a_real_silence_is_still_a_link_loss_and_restored_once():
    v = vehicle(link_timeout=0.5)
    v.on_message(heartbeat(), 100.0)
    assert not v.watch(100.4, 10.0) and not v.link_lost
    v.watch(100.6, 10.0)
    assert v.link_lost and v.counts["link_losses"] == 1
    for k in range(4):  # four heartbeats in one read
        v.on_message(heartbeat(), 101.0 + 0.001 * k)
    said = [e for _, e in v.events.events]
    assert sum("link restored" in e for e in said) == 1


def test_a_guard_clamp_is_a_clamp_with_the_proposal_not_a_fallback():
    events = EventLog(t0=0.0)
    gate, _eng = _loop(events)
    gate.gate.rate = None  # the guard alone here
    rec = FlightRecorder(2, 2, DT, 0.0, lockstep=False, capacity=16)
    proposal = np.array([1.4, -0.2])
    ref = TickReference(R_NOM.copy(), R_NOM.copy(), R_NOM.copy(), "step_too_large", candidate=proposal)
    for _ in range(3):
        u, flags = gate.reference(ref)
        gate.report(u, ref.r_nom, ref.reason, flags, [], dropped=0)
    assert np.allclose(u, [1.05, -0.05]) and flags & GATE_FLAGS["guard_clamped"]
    said = [e for _, e in events.events]
    assert said == ["guard: steered correction clamped at the [0.05, 0.05] guard (solver proposed [1.4, -0.2], "
                    "applied [1.05, -0.05], nominal [1.0, 0.0])"]  # once per streak, and no "fallback:"
    assert "guard_clamped" in REASONS and "guard_clamped" not in FALLBACK_REASONS
    _record(rec, ref, u, flags)
    t = rec.rows.arrays
    assert REASONS[t["reason"][0]] == "guard_clamped" and np.allclose(t["u_proposed"][0], proposal)
    plain = TickReference(R_NOM.copy(), R_NOM.copy(), R_NOM.copy(), "steered", u_steered=R_NOM.copy())
    _record(rec, plain, R_NOM, 0)
    assert REASONS[t["reason"][1]] == "steered" and np.all(np.isnan(t["u_proposed"][1]))


def _record(rec: FlightRecorder, ref: TickReference, u: np.ndarray, gate: int) -> None:
    from types import SimpleNamespace

    from firmware_bridge.truth import SimTruth

    state = SimpleNamespace(position=np.zeros(3), velocity=np.zeros(3), euler=np.zeros(3), body_rates=np.zeros(3))
    rec.record(ref, u, state, now=1.0, t_sent=1.0001, t_vehicle=1.0, t_traj=0.5, age=0.001, q=(1.0, 0.0, 0.0, 0.0),
               thrust=0.5, field=0.5, event=True, engaged=True, fresh=True, sent=True, gap=False, n_new=2,
               latency=100.0, gate=gate, armed=True, offboard=True, y_des=np.zeros(2), phase=0, backdate=0,
               contact=None, truth=SimTruth())
