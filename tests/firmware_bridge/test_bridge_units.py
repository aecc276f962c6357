"""Units of the bridge: autopilot profiles, frames, connection strings, the link's receive path
(loopback sockets and a pty), command retries, tick statistics."""

from __future__ import annotations

import math
import os
import socket
import time

import numpy as np
import pytest

from ddpc_codegen.robot.frames import euler_from_quat, quat_from_euler, quat_ned_frd_from_enu_flu, rotate_inverse
from firmware_bridge.bridge import gap_statistics
from firmware_bridge.link import CommandTracker, MavLink, mavlink, parse_url
from firmware_bridge.profiles import (
    ARDUCOPTER_MODES,
    ArduPilotProfile,
    PX4Profile,
    make_profile,
    px4_custom_mode,
    px4_decode,
    px4_mode_name,
)
from firmware_bridge.telemetry import TelemetryState, TrajectoryFrame


# ----------------------------------------------------------------------------- profiles
def test_px4_mode_encoding_round_trips_and_offboard_is_main_mode_6():
    assert px4_custom_mode(6) == 6 << 16
    assert px4_decode(px4_custom_mode(4, 3)) == (4, 3)
    assert px4_mode_name(px4_custom_mode(4, 6)) == "AUTO.LAND"
    p = PX4Profile()
    assert p.offboard_command() == (1.0, 6.0, 0.0)
    assert p.decode(1 | 128, px4_custom_mode(6)) .offboard and p.decode(1 | 128, px4_custom_mode(6)).armed
    assert not p.decode(1, px4_custom_mode(6)).armed
    assert not p.decode(1 | 128, px4_custom_mode(4, 3)).offboard
    assert p.thrust_field(0.73, 1.0, 0.5) == 0.73       # normalized thrust as is


def test_ardupilot_guided_modes_and_both_thrust_semantics():
    p = make_profile("ardupilot")
    assert p.offboard_command() == (1.0, 20.0, 0.0)       # GUIDED_NOGPS
    assert p.decode(129, ARDUCOPTER_MODES["GUIDED"]).offboard
    assert p.decode(129, ARDUCOPTER_MODES["GUIDED_NOGPS"]).offboard
    assert not p.decode(129, ARDUCOPTER_MODES["LOITER"]).offboard
    # Default GUID_OPTIONS = 0: thrust is a climb rate, 0.5 holds height.
    assert p.climb_rate_thrust and p.hover_field(0.7) == 0.5
    assert p.thrust_field(0.9, 1.0, 1.0) == 0.5
    up = p.thrust_field(0.9, 1.5, 1.0)                     # 0.5 m low -> climb 0.75 m/s
    assert up == pytest.approx(0.5 + 0.5 * 0.75 / 2.5)
    assert p.field_to_climb_rate(up) == pytest.approx(0.75)
    assert p.field_to_climb_rate(p.thrust_field(0.9, 0.0, 1.0)) == pytest.approx(-1.5)  # saturates at descent speed
    # ArduCopter's reading of the field (GCS_MAVLink_Copter.cpp, handle_message_set_attitude_target):
    # 0.5 holds, above it (f - 0.5) * 2 * WPNAV_SPEED_UP, below (0.5 - f) * 2 * -WPNAV_SPEED_DN, clipped to [0, 1].
    r = ArduPilotProfile(speed_up=2.0, speed_down=1.0)
    for f, vz in ((0.5, 0.0), (0.75, 0.5 * 2.0), (1.0, 2.0), (0.25, -0.5 * 1.0), (0.0, -1.0), (1.4, 2.0), (-0.2, -1.0)):
        assert r.field_to_climb_rate(f) == pytest.approx(vz)
    for vz in (-1.0, -0.3, 0.0, 0.4, 2.0):  # the encoding is its inverse inside the speed limits
        assert r.field_to_climb_rate(r.climb_rate_to_field(vz)) == pytest.approx(vz)
    # GUID_OPTIONS bit 3: the field is a thrust, like PX4.
    q = ArduPilotProfile(guid_options=8)
    assert not q.climb_rate_thrust and q.thrust_field(0.61, 2.0, 1.0) == 0.61
    with pytest.raises(ValueError):
        make_profile("betaflight")


# ----------------------------------------------------------------------------- frames
def _telemetry(kind: str, q_ned, rates_frd, p_ned, v_ned, ms: int = 1234):
    mav = mavlink.MAVLink(None, 1, 1)
    roll, pitch, yaw = euler_from_quat(q_ned)
    if kind == "ATTITUDE":
        att = mav.attitude_encode(ms, roll, pitch, yaw, *rates_frd)
    elif kind == "ATTITUDE_QUATERNION":
        att = mav.attitude_quaternion_encode(ms, *q_ned, *rates_frd, (0, 0, 0, 0))
    else:
        nan = [math.nan] * 21
        att = mav.odometry_encode(ms * 1000, 1, 12, *p_ned, list(q_ned), *rotate_inverse(q_ned, v_ned), *rates_frd,
                                  nan, nan, 0, 0, 0)
    pos = att if kind == "ODOMETRY" else mav.local_position_ned_encode(ms, *p_ned, *v_ned)
    parser = mavlink.MAVLink(None)
    return [parser.parse_buffer(m.pack(mav))[0] for m in ((att,) if kind == "ODOMETRY" else (att, pos))]


@pytest.mark.parametrize("kind", ["ATTITUDE", "ATTITUDE_QUATERNION", "ODOMETRY"])
def test_every_telemetry_stream_gives_the_same_enu_flu_state(kind):
    rng = np.random.default_rng(3)
    for _ in range(5):
        e_enu = rng.uniform([-0.5, -0.5, -3.0], [0.5, 0.5, 3.0])
        q_ned = quat_ned_frd_from_enu_flu(quat_from_euler(*e_enu))
        p_enu, v_enu, w_flu = rng.normal(size=3), rng.normal(size=3), rng.normal(size=3)
        p_ned = (p_enu[1], p_enu[0], -p_enu[2])
        v_ned = (v_enu[1], v_enu[0], -v_enu[2])
        w_frd = (w_flu[0], -w_flu[1], -w_flu[2])
        tel = TelemetryState("ODOMETRY" if kind == "ODOMETRY" else kind,
                             "ODOMETRY" if kind == "ODOMETRY" else "LOCAL_POSITION_NED")
        for m in _telemetry(kind, q_ned, w_frd, p_ned, v_ned):
            assert tel.update(m, rx=1.0)
        np.testing.assert_allclose(tel.euler, e_enu, atol=2e-6)
        np.testing.assert_allclose(tel.position, p_enu, atol=1e-6)
        np.testing.assert_allclose(tel.velocity, v_enu, atol=2e-6)
        np.testing.assert_allclose(tel.rates, w_flu, atol=1e-6)
        assert tel.att.stamp == tel.pos.stamp == pytest.approx(1.234)


@pytest.mark.parametrize("kind", ["ATTITUDE", "ATTITUDE_QUATERNION", "ODOMETRY"])
@pytest.mark.parametrize("bad", ["nan_attitude", "nan_position", "inf_rate", "zero_quaternion"])
def test_telemetry_with_a_nonfinite_field_is_dropped_and_counted(kind, bad):
    """Issue 28: a NaN quaternion or position never reaches the state (frames, setpoints): the sample is
    dropped and counted, the last good one stays (and ages)."""
    q_good = quat_ned_frd_from_enu_flu(quat_from_euler(0.1, -0.2, 0.3))
    p_good, v, w = (1.0, 2.0, -3.0), (0.1, 0.2, 0.3), (0.0, 0.1, 0.0)
    tel = TelemetryState("ODOMETRY" if kind == "ODOMETRY" else kind,
                         "ODOMETRY" if kind == "ODOMETRY" else "LOCAL_POSITION_NED")
    for m in _telemetry(kind, q_good, w, p_good, v):
        assert tel.update(m, rx=1.0)
    before = (tel.euler.copy(), tel.position.copy(), tel.att.seq, tel.pos.seq)
    nan = math.nan
    q = {"nan_attitude": (nan, 0.0, 0.0, 1.0), "zero_quaternion": (0.0, 0.0, 0.0, 0.0)}.get(bad, q_good)
    if kind == "ATTITUDE" and bad == "zero_quaternion":
        q = (nan, nan, nan, nan)  # no quaternion in ATTITUDE: its Euler angles come out NaN
    p = (nan, 0.0, 0.0) if bad == "nan_position" else p_good
    rates = (math.inf, 0.0, 0.0) if bad == "inf_rate" else w
    with np.errstate(invalid="ignore"):
        msgs = _telemetry(kind, q, rates, p, v, ms=1300)
    used = [tel.update(m, rx=2.0) for m in msgs]
    assert tel.dropped >= 1 and not all(used)
    assert np.all(np.isfinite(tel.euler)) and np.all(np.isfinite(tel.position)) and np.all(np.isfinite(tel.rates))
    if not used[0]:  # the attitude sample was the bad one: the state still holds the last good attitude
        np.testing.assert_array_equal(tel.euler, before[0])
        assert tel.att.seq == before[2]
    if not used[-1]:
        np.testing.assert_array_equal(tel.position, before[1])
        assert tel.pos.seq == before[3]


# (the frame math itself is tested against scipy in tests/robot/test_frames.py)


# ----------------------------------------------------------------------------- link
def test_trajectory_frame_start_maps_heading_and_start_point():
    from ddpc_codegen.robot.controller import MeasuredState

    yaw0 = math.radians(60.0)
    fr = TrajectoryFrame("start", anchor=(0.5, 0.0))
    fr.capture(np.array([3.0, -2.0, 1.0]), yaw0)
    c, s = math.cos(yaw0), math.sin(yaw0)
    # 0.4 m ahead and 0.1 m left of the captured point, moving forward at 1 m/s, turned 10 deg further.
    pos = np.array([3.0 + 0.4 * c - 0.1 * s, -2.0 + 0.4 * s + 0.1 * c, 1.3])
    st = MeasuredState(0.0, pos, np.array([c, s, -0.2]), np.array([0.05, -0.1, yaw0 + math.radians(10)]), np.zeros(3))
    fr.to_trajectory(st)
    np.testing.assert_allclose(st.position, [0.9, 0.1, 1.3], atol=1e-12)
    np.testing.assert_allclose(st.velocity, [1.0, 0.0, -0.2], atol=1e-12)
    np.testing.assert_allclose(st.euler, [0.05, -0.1, math.radians(10)], atol=1e-12)
    # A setpoint in the trajectory frame keeps its roll and pitch and gains the heading.
    e = euler_from_quat(fr.to_world(quat_from_euler(0.1, -0.2, 0.0)))
    np.testing.assert_allclose(e, [0.1, -0.2, yaw0], atol=1e-12)
    assert "heading 60.0 deg" in fr.describe()


def test_trajectory_frame_world_is_the_identity():
    from ddpc_codegen.robot.controller import MeasuredState

    fr = TrajectoryFrame("world", anchor=(0.5, 0.0))
    fr.capture(np.array([3.0, -2.0, 1.0]), 1.0)  # ignored
    st = MeasuredState(0.0, np.array([1.0, 2.0, 3.0]), np.array([0.1, 0.2, 0.3]), np.array([0.0, 0.0, 1.0]), np.zeros(3))
    fr.to_trajectory(st)
    np.testing.assert_array_equal(st.position, [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(fr.to_world([1.0, 0.0, 0.0, 0.0]), [1.0, 0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="frame must be 'start' or 'world'; got 'body'"):
        TrajectoryFrame("body")


def test_connection_strings():
    assert parse_url("udpin:127.0.0.1:14540").kind == "udpin"
    assert parse_url("udp:127.0.0.1:14540").kind == "udpin"
    ep = parse_url("udpout:localhost:14550")
    assert (ep.kind, ep.host, ep.port) == ("udpout", "localhost", 14550)
    assert parse_url("tcp:127.0.0.1:5760").kind == "tcp"
    assert parse_url("/dev/ttyACM0:57600").baud == 57600
    assert parse_url("/dev/ttyACM0,115200").device == "/dev/ttyACM0"
    assert parse_url("/dev/ttyAMA0", baud=460800).baud == 460800
    for bad in ("udpin:14540", "bogus", "tcpin:0.0.0.0:5760"):
        with pytest.raises(ValueError):
            parse_url(bad)


def _pair():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    rx = MavLink(f"udpin:127.0.0.1:{port}", target_system=1, target_component=1)
    tx = MavLink(f"udpout:127.0.0.1:{port}", source_system=1, source_component=1, target_system=None)
    return rx, tx, port


def _pin(rx: MavLink, tx: MavLink) -> None:
    """The vehicle's first heartbeat pins the udpin link's peer (nothing else from it counts before)."""
    tx.send_heartbeat(2, 12, 129, 0, 4)
    assert [m.get_type() for m, _ in _drain_until(rx, 1)] == ["HEARTBEAT"]
    assert rx.peer == tx.local_address()


def _drain_until(link: MavLink, n: int, timeout: float = 5.0):
    got, t_end = [], time.monotonic() + timeout
    while len(got) < n and time.monotonic() < t_end:
        link.wait(0.05)
        got += link.drain()
    return got


def _wait_for_kernel_stamps(tries: int = 50) -> None:
    """Linux turns receive time stamping on for the whole stack lazily (a static key flipped from a
    work queue after the first SO_TIMESTAMPNS socket appears); until then datagrams are stamped
    when read. Wait, with plain sockets (not the code under test), until a datagram is stamped at
    arrival."""
    import struct

    so_ts = getattr(socket, "SO_TIMESTAMPNS", 35)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as a, socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as b:
        a.bind(("127.0.0.1", 0))
        a.setsockopt(socket.SOL_SOCKET, so_ts, 1)
        for _ in range(tries):
            b.sendto(b"probe", a.getsockname())
            time.sleep(0.05)
            _, anc, _, _ = a.recvmsg(64, 64)
            stamps = [struct.unpack("qq", d[:16]) for lvl, typ, d in anc if typ == so_ts]
            if stamps and time.time() - (stamps[0][0] + stamps[0][1] * 1e-9) > 0.025:
                return
    pytest.skip("the kernel does not stamp datagrams at arrival here")


def test_drain_returns_everything_pending_in_order_with_kernel_receive_times():
    rx, tx, _ = _pair()
    try:
        _wait_for_kernel_stamps()
        _pin(rx, tx)
        for k in range(50):
            tx.send(tx.mav.local_position_ned_encode(k, 0, 0, -float(k), 0, 0, 0))
        t_sent = time.monotonic()
        time.sleep(0.2)
        got = _drain_until(rx, 50)
        assert [m.time_boot_ms for m, _ in got] == list(range(50))
        # Receive times are when the kernel got the datagrams (about t_sent), not when draining ran
        # (>= t_sent + 0.2 s); the margin absorbs the realtime -> monotonic conversion on a busy machine.
        assert got[-1][1] <= t_sent + 0.1
        assert all(a[1] <= b[1] for a, b in zip(got, got[1:]))
    finally:
        rx.close()
        tx.close()


def test_garbage_and_other_systems_are_dropped_and_replies_stay_pinned():
    rx, tx, port = _pair()
    other = MavLink(f"udpout:127.0.0.1:{port}", source_system=7, source_component=1, target_system=None)
    raw = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        _pin(rx, tx)
        peer = rx.peer
        raw.sendto(b"\xfe\x09\x00garbage", ("127.0.0.1", port))          # truncated MAVLink 1 start + junk
        tx.transport.write(b"\xfd\x40\x00\x00")                          # a truncated packet from the vehicle
        other.send_heartbeat(2, 12, 129, 0, 4)                            # another system
        tx.send(tx.mav.local_position_ned_encode(5, 0, 0, -1, 0, 0, 0))  # must survive the junk before it
        got = _drain_until(rx, 1)
        assert [m.get_type() for m, _ in got] == ["LOCAL_POSITION_NED"]
        # Junk and the other system came from other addresses: dropped unparsed; the truncated packet is the vehicle's.
        assert rx.stats["foreign_packets"] == 2 and rx.stats["bad_data"] >= 1
        assert rx.peer == peer
        rx.send_heartbeat()
        tx.wait(1.0)
        assert [m.get_type() for m, _ in tx.drain()] == ["HEARTBEAT"]
    finally:
        for link in (rx, tx, other):
            link.close()
        raw.close()


def test_target_system_zero_locks_onto_the_first_autopilot():
    rx, tx, port = _pair()
    gcs = MavLink(f"udpout:127.0.0.1:{port}", source_system=255, source_component=190, target_system=None)
    rx.target_system, rx.target_component = 0, 0
    try:
        gcs.send_heartbeat(6, 8, 0, 0, 4)                   # a ground station: autopilot INVALID
        tx.send_heartbeat(2, 12, 129, 0, 4)
        got = _drain_until(rx, 1)
        assert rx.target_system == 1 and rx.target_component == 1
        assert [m.get_srcSystem() for m, _ in got] == [1]
    finally:
        for link in (rx, tx, gcs):
            link.close()


def test_serial_transport_over_a_pty():
    master, slave = os.openpty()
    try:
        link = MavLink(os.ttyname(slave) + ":115200", source_system=1, source_component=191)
        mav = mavlink.MAVLink(None, 1, 1)
        os.write(master, b"line noise" + mav.heartbeat_encode(2, 12, 129, 0, 4).pack(mav))
        got = _drain_until(link, 1)
        assert [m.get_type() for m, _ in got] == ["HEARTBEAT"]
        link.send_heartbeat()
        time.sleep(0.05)
        data = os.read(master, 1000)
        assert mavlink.MAVLink(None).parse_buffer(data)[0].get_srcComponent() == 191
        link.close()
    finally:
        os.close(master)
        os.close(slave)


def test_tcp_link_reconnects_after_the_peer_goes_away():
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(1)
    port = srv.getsockname()[1]
    link = MavLink(f"tcp:127.0.0.1:{port}", reconnect_interval=0.05)
    try:
        conn, _ = srv.accept()
        conn.close()                                       # the peer drops the connection
        t_end = time.monotonic() + 5
        while link.is_open and time.monotonic() < t_end:
            link.wait(0.05)
            link.drain()
        assert not link.is_open and link.stats["link_errors"] == 1
        t_end = time.monotonic() + 5
        while not link.poll() and time.monotonic() < t_end:
            time.sleep(0.02)
        conn2, _ = srv.accept()
        assert link.is_open and link.stats["reconnects"] == 1
        mav = mavlink.MAVLink(None, 1, 1)
        conn2.sendall(mav.heartbeat_encode(2, 12, 129, 0, 4).pack(mav))
        assert len(_drain_until(link, 1)) == 1
        conn2.close()
    finally:
        link.close()
        srv.close()


def test_command_tracker_retries_until_acked_and_serializes_same_command():
    rx, tx, _ = _pair()
    try:
        tx.send_heartbeat(2, 12, 129, 0, 4)
        _drain_until(rx, 1)
        tr = CommandTracker(rx, timeout=0.05, max_tries=3)
        a = tr.submit(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, (31.0, 5000.0), "att")
        b = tr.submit(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, (32.0, 5000.0), "pos")
        t = time.monotonic()
        tr.poll(t)
        tr.poll(t + 0.06)                                   # no ACK yet: resent with confirmation 1
        cmds = [m for m, _ in _drain_until(tx, 2)]
        assert [(m.param1, m.confirmation) for m in cmds] == [(31.0, 0), (31.0, 1)]   # b waits for a
        tr.on_ack(tx.mav.command_ack_encode(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0))
        assert a.done and a.accepted and not b.done
        tr.poll(time.monotonic())
        assert [m.param1 for m, _ in _drain_until(tx, 1)] == [32.0]
        for k in range(3):
            tr.poll(time.monotonic() + 0.1 * (k + 1))
        assert b.done and b.timed_out
    finally:
        rx.close()
        tx.close()


def test_gap_statistics_counts_missed_ticks_not_jitter():
    t = np.arange(0, 1, 0.005)
    assert gap_statistics(t, 0.005)["missed_ticks"] == 0
    jit = t + np.random.default_rng(0).uniform(-0.0012, 0.0012, t.size)   # gaps up to 7.4 ms
    assert gap_statistics(np.sort(jit), 0.005)["missed_ticks"] == 0
    holes = np.delete(t, [50, 100, 101, 102])
    s = gap_statistics(holes, 0.005)
    assert s["missed_ticks"] == 4 and s["max_gap_ms"] == pytest.approx(20.0)
    assert s["rate_hz"] == pytest.approx(195 / 0.995, rel=1e-6)  # intervals / span
