"""The SITL's true state (ArduPilot SIM_STATE, PX4 SIH HIL_STATE_QUATERNION) as the bridge logs it:
local ENU from lat / lon / alt, heights from the take-off point, NED -> ENU."""

from __future__ import annotations

import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from firmware_bridge.truth import SimTruth

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
    assert tr.as_dict()["alt0_m"] == pytest.approx(584.09) and tr.as_dict()["source"] == "SIM_STATE"


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
