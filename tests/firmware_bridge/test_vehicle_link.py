"""The loop's vehicle side (firmware_bridge/vehicle_link.py), built on a link without a socket: heartbeats to
status, telemetry with the vehicle clock, reboots, refusals, parameters, link loss, the preflight's wait."""

from __future__ import annotations

import math

import pytest

from firmware_bridge.bridge_config import NoVehicleError
from firmware_bridge.link import mavlink
from part_fakes import FakeLink, ack, from_vehicle, heartbeat, telemetry, vehicle


def test_a_heartbeat_says_armed_offboard_and_the_mode_once_changed():
    v = vehicle()
    v.on_message(heartbeat(armed=False, offboard=False), 1.0)
    assert v.status.seen and not v.status.armed and v.status.autopilot == mavlink.MAV_AUTOPILOT_PX4
    v.on_message(heartbeat(), 1.2)
    assert v.status.armed and v.status.offboard and v.status.mode_name == "OFFBOARD" and v.status.last_hb == 1.2
    said = [e for _, e in v.events.events]
    assert said[0].startswith("vehicle heartbeat: sysid 1") and said[1] == "vehicle OFFBOARD, armed=True"
    assert v.heard(1.6) and not v.heard(1.8)


def test_telemetry_sets_the_vehicle_clock_and_a_reboot_asks_for_the_streams_again():
    reboots = []
    v = vehicle(on_reboot=lambda: reboots.append(1))
    for t in (9.985, 9.99, 9.995, 10.0, 10.005):  # the stamps are used once five advanced on the time line
        for m in telemetry(t):
            v.on_message(m, 100.0 + t + 0.002)
    assert v.telem.has_data and v.telem.seq_total == 10
    assert v.t_offset == pytest.approx(100.002) and v.vehicle_now(120.0, lockstep=False) == pytest.approx(19.998)
    assert v.vehicle_now(120.0, lockstep=True) == pytest.approx(10.005)  # lock-step: the newest stamp
    v.on_message(heartbeat(), 110.006)
    v.on_message(heartbeat(), 111.0)  # the vehicle was silent past the link timeout (it rebooted) ...
    for k in range(5):                # ... and its clock restarted: five samples agree on the new time line
        for m in telemetry(0.2 + 0.005 * k):
            v.on_message(m, 111.0 + 0.005 * k)
    # The streams were asked for when the heartbeat came back; the reboot needs no second request.
    assert v.counts["reboots"] == 1 and reboots == [1] and v.counts["stream_requests"] == 1
    assert v.pending(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL)
    assert v.telem.att.seq == 1 and v.telem.newest_stamp() == pytest.approx(0.22)
    assert v.telem.rejected["stamp"] == 8  # the four samples per stream before the fifth were not used


def _flying(v, t0: float = 10.0, n: int = 20, rx0: float = 100.0) -> float:
    """Heartbeat, then ``n`` regular samples at 200 Hz from vehicle time ``t0``; returns the next vehicle time."""
    v.on_message(heartbeat(), rx0)
    for k in range(n):
        for m in telemetry(t0 + 0.005 * k):
            v.on_message(m, rx0 + 0.005 * k)
    return t0 + 0.005 * n


def test_one_stamp_back_or_60_s_ahead_is_dropped_and_no_reboot():
    v = vehicle()
    t = _flying(v)
    for k, stamp in enumerate((t + 60.0, 0.2, t + 60.0, 3.0, t + 0.005)):   # forged stamps, one good one
        for m in telemetry(stamp):
            v.on_message(m, 100.1 + 0.005 * k)
    assert v.counts["reboots"] == 0 and v.counts["stream_requests"] == 0
    assert v.telem.rejected["stamp"] == 8 and v.telem.newest_stamp() == pytest.approx(t + 0.005)


def test_a_steady_60_s_jump_without_heartbeat_evidence_stays_dropped_with_one_event():
    v = vehicle()
    t = _flying(v)
    for k in range(600):  # every sample 60 s ahead of the vehicle's clock, for 3 s
        for m in telemetry(t + 60.0 + 0.005 * k):
            v.on_message(m, 100.1 + 0.005 * k)
        if k % 100 == 0:
            v.on_message(heartbeat(), 100.1 + 0.005 * k)  # the heartbeat goes on as before
    assert v.counts["reboots"] == 0 and v.counts["stream_requests"] == 0
    assert v.telem.rejected["stamp"] == 1200 and v.telem.newest_stamp() == pytest.approx(t - 0.005)
    said = [e for _, e in v.events.events if "time line" in e]
    assert len(said) == 1 and "without a reboot's heartbeat evidence" in said[0]


def test_absurd_positions_and_velocities_are_dropped_and_counted():
    v = vehicle()
    t = _flying(v)
    tel = v.telem
    forged = [mavlink.MAVLink_local_position_ned_message(0, 1e30, 0.0, -1.0, 0.0, 0.0, 0.0),
              mavlink.MAVLink_local_position_ned_message(0, 0.0, 0.0, -1.0, 1e30, 0.0, 0.0),
              mavlink.MAVLink_local_position_ned_message(0, 0.0, 0.0, -40.0, 0.0, 0.0, 0.0),   # 39 m in 5 ms
              mavlink.MAVLink_local_position_ned_message(0, 0.0, 0.0, -1.0, 0.0, 0.0, 30.0)]   # 30 m/s in 5 ms
    for k, m in enumerate(forged):
        m.time_boot_ms = int(round((t + 0.005 * k) * 1000))
        v.on_message(from_vehicle(m), 100.1 + 0.005 * k)
    assert dict(tel.rejected) == {"position_bounds": 1, "velocity_bounds": 1, "position_jump": 1, "velocity_jump": 1}
    assert tel.dropped == 4 and tel.position[2] == pytest.approx(1.0) and not tel.velocity.any()
    assert v.counts["telemetry_rejected"] is tel.rejected
    # A real climb is followed: 0.5 m in 0.1 s after the last accepted sample.
    m = mavlink.MAVLink_local_position_ned_message(int(round((t + 0.1) * 1000)), 0.0, 0.0, -1.5, 0.0, 0.0, -5.0)
    v.on_message(from_vehicle(m), 100.2)
    assert tel.position[2] == pytest.approx(1.5) and tel.velocity[2] == pytest.approx(5.0)


def test_an_arming_refusal_is_reported_with_the_autopilots_words():
    v = vehicle()
    v.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, (1.0,), "ARM")
    v.on_message(from_vehicle(mavlink.MAVLink_statustext_message(3, b"Arm: gyros inconsistent")), 1.0)
    v.on_message(ack(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, mavlink.MAV_RESULT_TEMPORARILY_REJECTED), 1.0)
    assert v.arming.refusals == ["arming refused (MAV_RESULT_TEMPORARILY_REJECTED): Arm: gyros inconsistent"]
    assert not v.pending(mavlink.MAV_CMD_COMPONENT_ARM_DISARM)


def test_parameters_are_decoded_and_the_offboard_loss_timeout_kept():
    v = vehicle()
    v.on_message(from_vehicle(mavlink.MAVLink_param_value_message(b"COM_OF_LOSS_T", 0.3,
                                                                  mavlink.MAV_PARAM_TYPE_REAL32, 2, 0)), 1.0)
    assert v.params["COM_OF_LOSS_T"] == pytest.approx(0.3) and v.profile.offboard_loss_timeout == pytest.approx(0.3)


def test_the_preflight_asks_for_the_parameters_and_flies_on_without_unanswered_optional_ones():
    # (the e2e tests' fake vehicle answers them: this is the 3 s wait that a silent autopilot costs)
    link = FakeLink()
    v = vehicle(link)
    v.on_message(heartbeat(), 1.0)
    link.inbox.append((from_vehicle(mavlink.MAVLink_param_value_message(b"MPC_THR_HOVER", 0.42,
                                                                        mavlink.MAV_PARAM_TYPE_REAL32, 2, 0)), 1.1))
    info = v.preflight(None, False, stopped=lambda: False, timeout=0.05)
    asked = {m.param_id for m in link.sent if m.get_type() == "PARAM_REQUEST_READ"}
    assert asked == {"MPC_THR_HOVER", "COM_OF_LOSS_T"}
    assert info.hover_thrust == pytest.approx(0.42) and "COM_OF_LOSS_T" not in info.params
    assert v.events.events[-1][1] == "parameters not answered within 0.05 s: COM_OF_LOSS_T (not needed)"


def test_a_silent_vehicle_loses_the_link_then_is_lost():
    v = vehicle()
    v.on_message(heartbeat(), 1.0)
    assert not v.watch(1.2, lost_after=3.0) and not v.link_lost
    assert not v.watch(1.6, lost_after=3.0) and v.link_lost and v.counts["link_losses"] == 1
    assert v.watch(4.5, lost_after=3.0) and v.counts["link_losses"] == 1
    v.on_message(heartbeat(), 4.6)  # back: said, and the streams asked for again
    assert v.events.events[-1][1] == "vehicle heartbeat back: link restored, re-requesting streams"
    assert not v.watch(4.7, lost_after=3.0) and not v.link_lost


def test_no_heartbeat_within_the_wait_is_no_vehicle():
    link = FakeLink()
    v = vehicle(link)
    with pytest.raises(NoVehicleError, match="no heartbeat from system 1 on fake within 0.05 s"):
        v.wait_for_heartbeat(0.05, stopped=lambda: False)
    assert link.heartbeats >= 1  # ours went out meanwhile (a udpin vehicle learns our address from it)
    link.inbox.append((heartbeat(), 5.0))
    v.wait_for_heartbeat(1.0, stopped=lambda: False)
    assert v.status.seen


def test_housekeeping_sends_our_heartbeat_and_retries_commands():
    link = FakeLink()
    v = vehicle(link)
    v.command(mavlink.MAV_CMD_DO_SET_MODE, (1.0, 6.0, 0.0), "DO_SET_MODE OFFBOARD")
    v.housekeeping(10.0, heartbeat=True)
    v.housekeeping(10.1, heartbeat=False)
    assert link.heartbeats == 1 and link.commands == [(mavlink.MAV_CMD_DO_SET_MODE, (1.0, 6.0, 0.0))]
    assert math.isinf(v.t_offset)
