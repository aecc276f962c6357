"""The motion-capture stand-in without a SITL: the truth's frame (SIM_STATE / HIL_STATE_QUATERNION -> local
NED), the latency, the noise, the refinement below the truth's grid, the message fields and the parameter sets
(the refinement's and the link clock's own tests: ``tests/firmware_bridge/test_truth_refine.py``)."""

from __future__ import annotations

import math
import time
from types import SimpleNamespace

import numpy as np
import pytest

from ddpc_codegen.testbed.mocap import (MAV_FRAME_LOCAL_NED, MocapConfig, MocapPose, MocapSampler, MocapStandIn,
                                        TruthBuffer, odometry_fields, vision_position_fields)
from ddpc_codegen.testbed.mocap_params import (ARDUPILOT_LAB, PX4_LAB, lab_params, px4_has_external_vision,
                                               transport_allowance_ms)
from firmware_bridge.truth import EARTH_RADIUS_M

LAT0, LON0, ALT0 = -35.363261, 149.165230, 584.09
_M_PER_DEG = math.radians(1.0) * EARTH_RADIUS_M


def sim_state(north: float, east: float, up: float, vn=0.0, ve=0.0, vd=0.0, roll=0.0, pitch=0.0, yaw=0.0,
              alt_grid: float = 0.0):
    """An ArduPilot SIM_STATE at (north, east, up) [m] from the test origin; ``alt_grid`` [m]: report the
    altitude truncated to that grid (the simulator's centimetres)."""
    lat = LAT0 + north / _M_PER_DEG
    lon = LON0 + east / (_M_PER_DEG * math.cos(math.radians(LAT0)))
    alt = ALT0 + up
    if alt_grid:
        alt = math.floor(round(alt / alt_grid, 9)) * alt_grid
    return SimpleNamespace(get_type=lambda: "SIM_STATE", lat=lat, lon=lon, lat_int=0, lon_int=0, alt=alt,
                           vn=vn, ve=ve, vd=vd, roll=roll, pitch=pitch, yaw=yaw)


def hil_state(north: float, east: float, up: float, q=(1.0, 0.0, 0.0, 0.0)):
    """A PX4 HIL_STATE_QUATERNION at (north, east, up) [m] (degE7, mm, cm/s), attitude ``q`` (w, x, y, z)."""
    lat = LAT0 + north / _M_PER_DEG
    lon = LON0 + east / (_M_PER_DEG * math.cos(math.radians(LAT0)))
    return SimpleNamespace(get_type=lambda: "HIL_STATE_QUATERNION", lat=int(round(lat * 1e7)), lon=int(round(lon * 1e7)),
                           alt=int((ALT0 + up) * 1e3), vx=0, vy=0, vz=0, attitude_quaternion=list(q))


def exact(**kw) -> MocapConfig:
    return MocapConfig(latency_s=kw.pop("latency_s", 0.0), pos_noise_m=0.0, att_noise_rad=0.0, vel_noise_mps=0.0, **kw)


def test_sim_state_becomes_local_ned_from_the_first_sample():
    s = MocapSampler(exact())
    s.feed(sim_state(0, 0, 0), 0.0)
    s.feed(sim_state(2.0, -1.0, 1.5, vn=0.3, ve=-0.2, vd=-0.1, roll=0.1, pitch=-0.2, yaw=2.0), 0.01)
    p = s.sample(0.01)
    # exact to the flat-earth model, within the message's grid (the altitude's centimetre cell: its middle)
    np.testing.assert_allclose(p.position[:2], [2.0, -1.0], atol=1e-6)
    assert -1.51 < p.position[2] <= -1.5
    np.testing.assert_allclose(p.velocity, [0.3, -0.2, -0.1], atol=1e-9)
    np.testing.assert_allclose(p.euler, [0.1, -0.2, 2.0], atol=1e-9)
    assert s.origin == pytest.approx((LAT0, LON0, ALT0))


def test_hil_state_quaternion_becomes_local_ned():
    s = MocapSampler(exact())
    s.feed(hil_state(0, 0, 0), 0.0)
    yaw = math.radians(30.0)
    s.feed(hil_state(1.0, 0.5, 0.8, q=(math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2))), 0.01)
    p = s.sample(0.01)
    np.testing.assert_allclose(p.position, [1.0, 0.5, -0.8], atol=0.02)  # degE7 and mm on the wire
    np.testing.assert_allclose(p.euler, [0.0, 0.0, yaw], atol=1e-9)


def test_latency_delays_the_pose_by_the_configured_time():
    s = MocapSampler(exact(latency_s=0.020))
    for k in range(201):  # climbing at 0.337 m/s, a sample each 5 ms, on the simulator's centimetre grid
        t = 0.005 * k
        s.feed(sim_state(0, 0, 0.337 * t, vd=-0.337, alt_grid=0.01), t)
    p = s.sample(1.0)
    assert p.t == pytest.approx(0.98)
    # 20 ms late = 6.7 mm lower; the grid leaves < 1 mm (each sample moves 1.7 mm across the cell edges)
    assert -p.position[2] == pytest.approx(0.337 * 0.98, abs=1e-3)


def test_a_gap_in_the_truth_sends_nothing_and_short_ones_extrapolate():
    s = MocapSampler(exact(max_extrapolation_s=0.05))
    s.feed(sim_state(0, 0, 0), 0.0)
    s.feed(sim_state(0, 0, 0.01, vd=-1.0), 0.01)
    climb = s.sample(0.01).position[2] - s.sample(0.04).position[2]
    assert climb == pytest.approx(0.03, abs=1e-9)  # along the newest velocity
    assert s.sample(0.2) is None
    assert MocapSampler(exact()).sample(1.0) is None


def test_noise_has_the_configured_spread_and_the_seed_repeats_it():
    cfg = MocapConfig(latency_s=0.0, pos_noise_m=0.0005, att_noise_rad=0.002, seed=3)
    draws = []
    for _ in range(2):
        s = MocapSampler(cfg)
        s.feed(sim_state(0, 0, 0), 0.0)
        s.feed(sim_state(0, 0, 0), 0.005)
        draws.append(np.array([np.r_[p.position, p.euler] for p in (s.sample(0.005) for _ in range(4000))]))
    np.testing.assert_array_equal(draws[0], draws[1])
    std = draws[0].std(axis=0)
    np.testing.assert_allclose(std[:3], 0.0005, rtol=0.06)
    np.testing.assert_allclose(std[3:], 0.002, rtol=0.06)
    assert abs(draws[0][:, 2].mean() + 0.005) < 3e-5  # unbiased around the centimetre cell's middle (standing still)


def test_the_centimetre_altitude_is_refined_with_the_velocity():
    """ArduPilot's SIM_STATE truncates the altitude to centimetres: a hover's millimetres of motion cross
    the cell edges, and the velocity integral between them gives the height to well under a millimetre."""
    s = MocapSampler(exact())
    t = np.arange(0.0, 10.0, 0.005)
    up = 0.5 + 0.004 * np.sin(2 * np.pi * 0.7 * t) + 0.003 * np.sin(2 * np.pi * 1.9 * t + 1.0)
    vu = 0.004 * 2 * np.pi * 0.7 * np.cos(2 * np.pi * 0.7 * t) + 0.003 * 2 * np.pi * 1.9 * np.cos(2 * np.pi * 1.9 * t + 1.0)
    s.feed(sim_state(0, 0, 0), -0.005)
    err, raw = [], []
    for ti, u, v in zip(t, up, vu):
        msg = sim_state(0, 0, u, vd=-v, alt_grid=0.01)
        s.feed(msg, ti)
        if ti > 2.0:
            err.append(-s.sample(ti).position[2] - u)
            raw.append(msg.alt - ALT0 - u)
    assert np.sqrt(np.mean(np.square(raw))) > 0.004  # what the message alone gives: ~cm steps
    assert np.sqrt(np.mean(np.square(err))) < 0.0005


def test_truth_buffer_interpolates_and_wraps_the_yaw():
    b = TruthBuffer()
    z = np.zeros(3)
    b.add(MocapPose(0.0, np.array([0.0, 0.0, 0.0]), z, np.array([0.0, 0.0, math.pi - 0.1])))
    b.add(MocapPose(0.1, np.array([1.0, 0.0, -1.0]), z, np.array([0.0, 0.0, -math.pi + 0.1])))
    p = b.at(0.05)
    np.testing.assert_allclose(p.position, [0.5, 0.0, -0.5])
    assert abs(abs(p.euler[2]) - math.pi) < 1e-9  # across ±pi, not through 0
    assert b.at(-0.01) is None


def test_message_fields_carry_ned_and_the_configured_noise():
    cfg = MocapConfig(pos_noise_m=0.001, att_noise_rad=0.01)
    pose = MocapPose(1.0, np.array([1.0, 2.0, -3.0]), np.array([0.5, 0.0, 0.0]), np.array([0.0, 0.0, math.pi / 2]))
    v = vision_position_fields(pose, 1_000_000, cfg)
    assert (v["x"], v["y"], v["z"], v["yaw"]) == (1.0, 2.0, -3.0, math.pi / 2) and v["usec"] == 1_000_000
    assert v["covariance"][0] == v["covariance"][6] == v["covariance"][11] == pytest.approx(1e-6)
    assert v["covariance"][20] == pytest.approx(1e-4) and v["covariance"][1] == 0.0
    o = odometry_fields(pose, 5, cfg, MAV_FRAME_LOCAL_NED)
    # heading east: the northward velocity is to the body's left (-y in FRD)
    np.testing.assert_allclose([o["vx"], o["vy"], o["vz"]], [0.0, -0.5, 0.0], atol=1e-12)
    assert o["frame_id"] == MAV_FRAME_LOCAL_NED and o["child_frame_id"] == 12
    np.testing.assert_allclose(o["q"], [math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4)])


def test_parameter_sets_follow_the_stream():
    cfg = MocapConfig(latency_s=0.008, pos_noise_m=0.0005)
    ap, px4 = lab_params("ardupilot", cfg), lab_params("px4", cfg)
    assert set(ARDUPILOT_LAB) <= set(ap) and set(PX4_LAB) <= set(px4)
    assert ap["VISO_DELAY_MS"] == 8 - 5 and px4["EKF2_EV_DELAY"] == 8  # EKF3 takes 5 ms (half its step) itself
    assert lab_params("ardupilot", MocapConfig(latency_s=0.002))["VISO_DELAY_MS"] == 0
    assert ap["EK3_SRC1_POSZ"] == 6 and ap["GPS1_TYPE"] == 0 and ap["EK3_SRC1_VELZ"] == 0
    assert px4["EKF2_HGT_REF"] == 3 and px4["EKF2_GPS_CTRL"] == 0 and px4["EKF2_BARO_CTRL"] == 0
    assert ap["VISO_POS_M_NSE"] == px4["EKF2_EVP_NOISE"] == 0.01  # the EKFs' floor, not 0.5 mm
    odo = lab_params("ardupilot", MocapConfig(message="odometry"))
    assert odo["EK3_SRC1_VELXY"] == odo["EK3_SRC1_VELZ"] == 6
    assert lab_params("px4", MocapConfig(message="odometry"))["EKF2_EV_CTRL"] == 15
    with pytest.raises(ValueError, match="unknown autopilot"):
        lab_params("inav")


def test_the_stand_ins_arducopter_link_declares_no_transmit_time():
    """ArduPilot dates a pose by its arrival minus its bytes' transmit time at the port's declared baud: the SITL's
    TCP link takes ~0.1 ms, so the stand-in's port (SERIAL1) must declare a baud that makes that allowance 0, even
    with a queue behind the pose; SERIAL1's default 57600 dated each pose ~30 ms early (the EKF ran ahead)."""
    baud = lab_params("ardupilot")["SERIAL1_BAUD"]
    assert transport_allowance_ms(baud, queued_bytes=2000) == 0.0
    assert transport_allowance_ms(57) > 20.0 and transport_allowance_ms(921, 1000) > 10.0
    assert "SERIAL1_BAUD" not in lab_params("px4")


def test_config_is_checked():
    with pytest.raises(ValueError):
        MocapConfig(rate_hz=0)
    with pytest.raises(ValueError):
        MocapConfig(latency_s=-0.001)
    with pytest.raises(ValueError):
        MocapConfig(message="vicon")


def test_px4_build_without_external_vision_is_recognised(tmp_path):
    (tmp_path / "bin").mkdir()
    (tmp_path / "bin" / "px4").write_bytes(b"\x00EKF2_GPS_CTRL\x00EKF2_HGT_REF\x00")
    assert not px4_has_external_vision(tmp_path)
    (tmp_path / "bin" / "px4").write_bytes(b"\x00EKF2_EV_CTRL\x00EKF2_HGT_REF\x00")
    assert px4_has_external_vision(tmp_path)


class _FakeLink:
    """A MAVLink connection that hands out a SIM_STATE each 5 ms (hovering at 1 m) and records what is sent."""

    def __init__(self):
        self.target_system, self.target_component = 1, 1
        self.sent: list[tuple[str, dict]] = []
        self.t0 = time.monotonic()
        self.n = 0
        self.mav = SimpleNamespace(**{name: self._recorder(name) for name in (
            "heartbeat_send", "command_long_send", "set_gps_global_origin_send", "vision_position_estimate_send",
            "odometry_send")})

    def _recorder(self, name):
        def send(*args, **kw):
            self.sent.append((name, kw or {"args": args}))
        return send

    def recv_match(self, type=None, blocking=True, timeout=None):
        due = self.t0 + 0.005 * self.n
        wait = due - time.monotonic()
        if timeout is not None and wait > timeout:
            time.sleep(max(0.0, timeout))
            return None
        time.sleep(max(0.0, wait))
        self.n += 1
        return sim_state(0.0, 0.0, 1.0 if self.n > 1 else 0.0)


def test_stand_in_sends_at_its_rate_with_the_origin_and_the_stream_request():
    link = _FakeLink()
    m = MocapStandIn(link, "ardupilot", MocapConfig(rate_hz=100.0, latency_s=0.005, seed=0))
    m.start()
    time.sleep(1.0)
    m.stop()
    names = [n for n, _ in link.sent]
    poses = [kw for n, kw in link.sent if n == "vision_position_estimate_send"]
    assert not m.stats.errors and m.stats.truth > 100
    # 100 Hz for 1 s (a few at the start wait for the truth's latency; a loaded machine skips late ones)
    assert 50 <= len(poses) <= 101
    assert -1.01 < poses[-1]["z"] < -0.99
    assert "set_gps_global_origin_send" in names and names.count("heartbeat_send") >= 1
    asked = [kw["args"] for n, kw in link.sent if n == "command_long_send"]
    assert asked and asked[0][2] == 511 and asked[0][4] == 108  # SET_MESSAGE_INTERVAL of SIM_STATE
    origin = next(kw["args"] for n, kw in link.sent if n == "set_gps_global_origin_send")
    assert origin[3] == 584000  # whole metres (ArduPilot reads a centimetre-height origin back a centimetre low)
    assert not MocapStandIn(_FakeLink(), "px4").set_origin


def test_stand_in_forwards_the_same_poses_to_the_companion():
    link, companion = _FakeLink(), _FakeLink()
    m = MocapStandIn(link, "px4", MocapConfig(rate_hz=100.0, seed=0), forward=companion)
    m.start()
    time.sleep(0.5)
    m.stop()
    sent = [kw for n, kw in link.sent if n == "vision_position_estimate_send"]
    fwd = [kw for n, kw in companion.sent if n == "vision_position_estimate_send"]
    assert not m.stats.errors and len(sent) > 10 and fwd == sent  # the same poses, stamps and noise
    assert all(n == "vision_position_estimate_send" for n, _ in companion.sent)  # nothing else: no admin traffic
