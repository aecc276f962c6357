"""What the loop asks of the vehicle on its own (firmware_bridge/mode_requests.py), on a link without a
socket: the off-board mode once the setpoints stream, arming and its give-up, LAND on stale telemetry, the
hand-back at exit; and the setpoint stream's times (firmware_bridge/setpoints.py)."""

from __future__ import annotations

import time

from firmware_bridge.link import mavlink
from firmware_bridge.mode_requests import ModeRequests
from firmware_bridge.setpoints import SetpointStream
from part_fakes import FakeLink, ack, heartbeat, line, telemetry, vehicle

Q = (1.0, 0.0, 0.0, 0.0)


def _parts(**flags):
    link = FakeLink()
    v = vehicle(link)
    stream = SetpointStream(v, lockstep=False)
    flags = {"arm": False, "offboard": True, "land": False, **flags}
    return link, v, stream, ModeRequests(v, stream, **flags)


def test_offboard_is_requested_once_setpoints_stream_and_never_after_an_engagement():
    link, v, stream, modes = _parts()
    v.on_message(heartbeat(offboard=False), 0.0)
    now = time.monotonic()
    assert modes.supervise(now, engaged_before=False) is None and not v.pending(mavlink.MAV_CMD_DO_SET_MODE)
    assert stream.send(Q, 0.5, 0) and stream.streaming(time.monotonic()) and stream.send_times
    modes.supervise(time.monotonic(), engaged_before=False)
    assert v.pending(mavlink.MAV_CMD_DO_SET_MODE) and modes.offboard_attempts == 1
    assert v.events.events[-1][1].startswith("requesting OFFBOARD after")
    _, v2, stream2, modes2 = _parts()
    v2.on_message(heartbeat(offboard=False), 0.0)
    stream2.send(Q, 0.5, 0)
    modes2.supervise(time.monotonic(), engaged_before=True)  # the pilot took it away: not pulled back
    assert not v2.pending(mavlink.MAV_CMD_DO_SET_MODE)


def test_arming_waits_for_telemetry_retries_and_gives_up():
    _, v, _, modes = _parts(arm=True, offboard=False)
    v.on_message(heartbeat(armed=False, offboard=False), 0.0)
    assert modes.supervise(1.0, False) is None and not v.pending(mavlink.MAV_CMD_COMPONENT_ARM_DISARM)
    for m in line(0.1):
        v.on_message(m, 1.0)
    modes.supervise(1.0, False)
    assert v.pending(mavlink.MAV_CMD_COMPONENT_ARM_DISARM) and v.arming.attempts == 1
    v.on_message(ack(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, mavlink.MAV_RESULT_FAILED), 1.1)
    modes.supervise(2.0, False)
    assert v.arming.attempts == 1  # the retry interval (2 s) has not passed
    modes.supervise(3.1, False)
    assert v.arming.attempts == 2
    assert "could not arm: 2 attempts" in modes.supervise(1.0 + v.arming.timeout + 1.0, False)


def test_stale_telemetry_asks_for_land_once():
    _, v, _, modes = _parts()
    modes.land_on_stale()
    modes.land_on_stale()
    assert len(v.tracker.queues[mavlink.MAV_CMD_DO_SET_MODE]) == 1
    assert v.events.events[-1][1] == "stale telemetry: requesting AUTO.LAND"


def test_the_hand_back_asks_for_hold_and_repeats_the_last_setpoint_until_acknowledged():
    link, v, stream, modes = _parts()
    v.on_message(heartbeat(), 0.0)
    stream.send(Q, 0.5, 0)
    n_sent = len(link.sent)
    link.inbox.append((ack(mavlink.MAV_CMD_DO_SET_MODE), 0.0))
    t0 = time.monotonic()
    modes.hand_back(period=0.0)
    assert time.monotonic() - t0 < 1.0 and v.events.events[-1][1] == "exit: requesting AUTO.LOITER"
    assert len(link.sent) >= n_sent  # the last setpoint repeated while waiting (never a new one)
    assert all(m is stream.last_msg for m in link.sent[n_sent:])


def test_the_stream_length_counts_in_vehicle_time_in_lockstep():
    _, v, _, _ = _parts()
    for m in line(5.0):
        v.on_message(m, 1.0)
    stream = SetpointStream(v, lockstep=True)
    stream.send(Q, 0.5, 5000)
    for m in telemetry(5.75):
        v.on_message(m, 1.2)  # 0.75 s of vehicle time in 0.2 s: a lock-step simulator under 4x real time
    assert abs(stream.streamed(time.monotonic()) - 0.75) < 1e-9 and stream.send_stamps == [5.0]
