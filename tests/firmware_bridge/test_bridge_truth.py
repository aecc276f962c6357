"""The SITL's true state (ArduPilot SIM_STATE, PX4 SIH HIL_STATE_QUATERNION) as the bridge logs it:
local ENU from lat / lon / alt, heights from the take-off point, NED -> ENU; the height refined below the
centimetres ArduCopter reports and placed on its clock through the link's bursts."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from firmware_bridge.truth import CLOCK_PARTNER, SimTruth

# ArduPilot's own flat-earth scale (AP_Math/location.h LOCATION_SCALING_FACTOR): metres per 1e-7 degree.
AP_SCALE = 0.011131884502145034
LAT0, LON0 = -353632610, 1491652300  # CMAC, degE7


def _sim_state(lat_e7: int, lon_e7: int, alt: float, v_ned=(0.0, 0.0, 0.0), rpy=(0.0, 0.0, 0.0), ints=True):
    """A SIM_STATE as it arrives: packed and parsed (float32 fields on the wire)."""
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    msg = mavlink.MAVLink_sim_state_message(
        1.0, 0.0, 0.0, 0.0, *rpy, 0.0, 0.0, -9.81, 0.0, 0.0, 0.0, lat_e7 * 1e-7, lon_e7 * 1e-7, alt, 0.0, 0.0,
        *v_ned, lat_e7 if ints else 0, lon_e7 if ints else 0)
    return mavlink.MAVLink(None).parse_char(bytearray(msg.pack(mav)))


def test_sim_state_becomes_local_enu_from_the_take_off_point():
    tr = SimTruth()
    assert not tr.present and tr.as_dict() is None
    tr.update(_sim_state(LAT0, LON0, 584.09), rx=1.0)
    tr.capture_ground()                                   # disarmed on the ground: heights from here
    np.testing.assert_allclose(tr.position, 0.0, atol=1e-9)
    # 2000e-7 deg north, -1500e-7 deg east (west), 1.25 m up; NED velocity, yaw 30 deg NED (east of north)
    tr.update(_sim_state(LAT0 + 2000, LON0 - 1500, 585.34, v_ned=(1.0, 2.0, -0.5), rpy=(0.1, 0.2, math.radians(30))),
              rx=1.005)
    north, east = 2000 * AP_SCALE, -1500 * AP_SCALE * math.cos(math.radians(LAT0 * 1e-7))
    np.testing.assert_allclose(tr.position, (east, north, 1.25), atol=2e-3)  # ArduPilot's scale vs WGS-84 radius
    np.testing.assert_allclose(tr.velocity, (2.0, 1.0, 0.5), atol=1e-6)
    np.testing.assert_allclose(tr.euler, (0.1, -0.2, math.radians(60)), atol=1e-6)
    assert tr.age(1.015) == pytest.approx(0.010) and tr.seq == 2
    # the take-off altitude refined inside the reported centimetre (truncated: the truth is above it)
    assert 584.09 <= tr.as_dict()["alt0_m"] < 584.10 and tr.as_dict()["source"] == "SIM_STATE"


def test_float_degrees_are_used_without_the_integer_extension_and_bad_samples_are_skipped():
    tr = SimTruth()
    tr.update(_sim_state(LAT0, LON0, 584.0, ints=False), rx=0.0)
    tr.update(_sim_state(LAT0 + 1000, LON0, 584.0, ints=False), rx=0.01)
    assert tr.position[1] == pytest.approx(1000 * AP_SCALE, abs=0.45)   # float32 degrees: ~0.4 m resolution
    bad = _sim_state(LAT0, LON0, float("nan"))
    tr.update(bad, rx=0.02)
    assert tr.seq == 2 and tr.rx == 0.01


def _hil_state(lat_e7: int, lon_e7: int, alt_mm: int, v_ned_cms=(0, 0, 0), q=(1.0, 0.0, 0.0, 0.0)):
    """A HIL_STATE_QUATERNION as PX4 SIH sends it (degE7, mm AMSL, cm/s NED, FRD -> NED quaternion)."""
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    msg = mavlink.MAVLink_hil_state_quaternion_message(0, q, 0.0, 0.0, 0.0, lat_e7, lon_e7, alt_mm, *v_ned_cms,
                                                       0, 0, 0, 0, 0)
    return mavlink.MAVLink(None).parse_char(bytearray(msg.pack(mav)))


def test_px4_sih_hil_state_quaternion_becomes_local_enu_from_the_take_off_point():
    from ddpc_codegen.robot.frames import quat_from_euler

    lat0, lon0 = 473977432, 85455942  # what the shared PX4 SIH reports (Zurich), degE7
    tr = SimTruth()
    tr.update(_hil_state(0, 0, 0), rx=0.5)               # before SIH has a position: zeros, skipped
    assert not tr.present
    tr.update(_hil_state(lat0, lon0, 489399), rx=1.0)
    tr.capture_ground()
    np.testing.assert_allclose(tr.position, 0.0, atol=1e-9)
    q = quat_from_euler(0.1, 0.2, math.radians(30))       # NED roll, pitch, yaw 30 deg (east of north)
    tr.update(_hil_state(lat0 + 1000, lon0 - 2000, 490649, v_ned_cms=(100, 200, -50), q=tuple(q)), rx=1.01)
    north = math.radians(1000e-7) * 6378137.0
    east = math.radians(-2000e-7) * 6378137.0 * math.cos(math.radians(lat0 * 1e-7))
    np.testing.assert_allclose(tr.position, (east, north, 1.25), atol=1e-6)
    np.testing.assert_allclose(tr.velocity, (2.0, 1.0, 0.5), atol=1e-9)
    np.testing.assert_allclose(tr.euler, (0.1, -0.2, math.radians(60)), atol=1e-6)
    assert tr.as_dict()["source"] == "HIL_STATE_QUATERNION" and tr.seq == 2


GROUND = 584.0437  # the true altitude where the vehicle stands [m AMSL]: inside a centimetre cell


def _climb(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """On the ground for 5 s, a 1 m cosine climb over 2 s, then a vertical wander: altitude [m AMSL], rate [m/s]."""
    s = np.clip(t - 5.0, 0.0, None)
    up = 0.5 - 0.5 * np.cos(np.pi * np.minimum(s, 2.0) / 2.0) + 0.3 * np.sin(2 * np.pi * s / 4.3) \
        + 0.2 * np.sin(2 * np.pi * s / 6.1)
    return GROUND + up, np.gradient(up, t)


def _cm_state(alt: float, vu: float) -> SimpleNamespace:
    """ArduCopter's SIM_STATE at ``alt`` [m AMSL] climbing at ``vu`` [m/s]: the altitude truncated to whole
    centimetres (as the simulator's Location reports it), the velocity exact."""
    return SimpleNamespace(get_type=lambda: "SIM_STATE", alt=math.floor(round(alt * 100.0, 6)) / 100.0, vd=-vu,
                           lat=LAT0 * 1e-7, lon=LON0 * 1e-7, lat_int=LAT0, lon_int=LON0, vn=0.0, ve=0.0, roll=0.0,
                           pitch=0.0, yaw=0.0)


def _lpos(boot_s: float) -> SimpleNamespace:
    return SimpleNamespace(get_type=lambda: "LOCAL_POSITION_NED", time_boot_ms=int(round(boot_s * 1e3)))


def test_the_true_height_is_refined_below_the_centimetres_sim_state_reports():
    """A hover's and a climb's height from SIM_STATE's truncated centimetres and its exact velocity: well under a
    millimetre from the true height, where the centimetres alone are ~5 mm off."""
    t = np.arange(0.0, 30.0, 0.02)
    alt, vu = _climb(t)
    tr = SimTruth()
    up = []
    for a, v, ti in zip(alt, vu, t):
        tr.update(_cm_state(a, v), rx=ti)
        up.append(tr.position[2])
    exact = alt - tr.alt0  # heights from the first sample's reported altitude (no ground captured)
    raw = np.array([_cm_state(a, 0.0).alt for a in alt]) - tr.alt0
    k = t > 6.0  # once the climb has crossed a cell edge
    assert np.sqrt(np.mean((raw[k] - exact[k]) ** 2)) > 0.004
    assert np.sqrt(np.mean((np.array(up)[k] - exact[k]) ** 2)) < 0.0005
    tr.capture_ground()  # where it is now, refined: the height's zero
    assert tr.position[2] == 0.0 and tr.alt0 == pytest.approx(alt[-1], abs=0.0005)


def test_the_truth_is_placed_on_arducopters_clock_through_the_links_bursts():
    """SIM_STATE and LOCAL_POSITION_NED leave ArduCopter's same loop and arrive in the same bursts, 0-20 ms late: the
    truth takes the loop's time on the bridge's clock (stamped on arrival a climb would be off by its speed times
    the burst, and the velocity's integral over the arrival gaps would break the refinement)."""
    t = np.arange(0.0, 30.0, 0.02)
    alt, vu = _climb(t)
    burst = np.repeat(np.random.default_rng(3).uniform(0.0, 0.02, len(t) // 4 + 1), 4)[:len(t)]
    tr = SimTruth.for_link("ardupilot", {"ATTITUDE_QUATERNION", "LOCAL_POSITION_NED"})
    assert tr.partner == CLOCK_PARTNER
    placed, up = [], []
    for a, v, ti, late in zip(alt, vu, t, burst):
        tr.update(_cm_state(a, v), rx=ti + late)      # held until its partner comes
        tr.update(_lpos(100.0 + ti), rx=ti + late + 1e-4)
        placed.append(tr.rx)
        up.append(tr.position[2])
    assert tr.seq == len(t) and tr.clock.paired == len(t)
    k = t > 6.0
    # its loop's time (less the link's quickest transit seen), whatever its burst
    assert burst[k].max() > 0.015 and np.abs(np.array(placed) - t)[k].max() < 0.004
    assert np.sqrt(np.mean((np.array(up)[k] - (alt - tr.alt0)[k]) ** 2)) < 0.0005
    # PX4 SIH sends its truth apart from the telemetry, and the bridge's ODOMETRY stream carries no time_boot_ms
    assert SimTruth.for_link("px4", {"LOCAL_POSITION_NED"}).clock is None
    assert SimTruth.for_link("ardupilot", {"ODOMETRY"}).partner == ""
    plain = SimTruth()
    plain.update(_lpos(1.0), rx=0.0)  # without a partner, any other message is no truth
    assert not plain.present
