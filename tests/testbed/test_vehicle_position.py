"""The simulated vehicle's position controller: its parts alone (MAVLink reading, the horizontal speed
limit, hover, tilt, yaw) and flown on the vehicle's physics in-process against an independent linear
model of the cascade (a z step, a z ramp with and without velocity feed-forward, the limits, a wrong
hover-thrust estimate, HOLD braking)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from support.bridge_helpers import free_port

from ddpc_codegen.robot.frames import euler_from_quat
from ddpc_codegen.testbed.vehicle import MODE_HOLD, MODE_LAND, MODE_OFFBOARD, SimVehicle, VehicleConfig
from ddpc_codegen.testbed.vehicle_position import (
    ARDUCOPTER_POSITION,
    PX4_POSITION,
    PositionController,
    PositionTarget,
    constrain_xy,
    target_from_local_ned,
)
from firmware_bridge.link import mavlink

M = mavlink
NAN3 = np.full(3, np.nan)
DT = 0.005


# ------------------------------------------------------------------ the parts alone
def _msg(type_mask: int, frame: int = M.MAV_FRAME_LOCAL_NED, pos=(1.0, 2.0, -3.0), vel=(0.1, 0.2, -0.3),
         acc=(0.5, 0.6, -0.7), yaw=0.0, yaw_rate=0.4):
    return M.MAVLink_set_position_target_local_ned_message(0, 1, 1, frame, type_mask, *pos, *vel, *acc, yaw, yaw_rate)


def test_type_mask_groups_and_ned_to_enu_as_px4_reads_them():
    all_on = target_from_local_ned(_msg(0))
    assert all_on.position.tolist() == [2.0, 1.0, 3.0] and all_on.velocity.tolist() == [0.2, 0.1, 0.3]
    assert all_on.acceleration.tolist() == [0.6, 0.5, 0.7]
    assert all_on.yaw == pytest.approx(math.pi / 2) and all_on.yaw_rate == pytest.approx(-0.4)  # north = ENU 90 deg
    # one ignore bit drops its whole group (PX4); yaw and yaw rate by their own bits
    t = target_from_local_ned(_msg(M.POSITION_TARGET_TYPEMASK_VZ_IGNORE | M.POSITION_TARGET_TYPEMASK_AX_IGNORE
                                   | M.POSITION_TARGET_TYPEMASK_YAW_IGNORE))
    assert np.isfinite(t.position).all() and np.isnan(t.velocity).all() and np.isnan(t.acceleration).all()
    assert math.isnan(t.yaw) and t.yaw_rate == pytest.approx(-0.4)
    only_vel = target_from_local_ned(_msg(0b1101_1100_0111))
    assert np.isnan(only_vel.position).all() and only_vel.velocity.tolist() == [0.2, 0.1, 0.3]
    assert math.isnan(only_vel.yaw) and math.isnan(only_vel.yaw_rate)


@pytest.mark.parametrize("msg, why", [
    (_msg(0, frame=M.MAV_FRAME_BODY_NED), "coordinate frame 8 unsupported"),
    (_msg(M.POSITION_TARGET_TYPEMASK_FORCE_SET), "force not supported"),
    (_msg(0b0000_0001_1111_1111), "controls nothing"),
    (_msg(0b0000_0001_1111_1000, pos=(math.nan,) * 3), "controls nothing"),
])
def test_what_px4_refuses(msg, why):
    with pytest.raises(ValueError, match=why):
        target_from_local_ned(msg)


def test_horizontal_speed_limit_gives_up_the_feed_forward_first():
    v0, ff = np.array([3.0, 0.0]), np.array([0.0, 6.0])
    assert constrain_xy(v0, ff, 10.0) == pytest.approx([3.0, 6.0])  # within the limit: the sum
    out = constrain_xy(v0, ff, 5.0)
    assert np.linalg.norm(out) == pytest.approx(5.0) and out[0] == pytest.approx(3.0)  # position part kept
    assert constrain_xy(np.array([8.0, 6.0]), ff, 5.0) == pytest.approx([4.0, 3.0])  # position part alone too big
    assert constrain_xy(np.zeros(2), np.array([0.0, 9.0]), 5.0) == pytest.approx([0.0, 5.0])


def test_on_target_at_rest_it_hovers_level_on_its_hover_thrust():
    c = PositionController(PX4_POSITION, 0.8, DT, tilt_max=math.radians(35))
    q, thrust = c.update(PositionTarget(position=np.array([1.0, 2.0, 3.0]), yaw=0.3),
                         np.array([1.0, 2.0, 3.0]), np.zeros(3), 0.0)
    roll, pitch, yaw = euler_from_quat(q)
    assert thrust == pytest.approx(0.8) and roll == pytest.approx(0.0) and pitch == pytest.approx(0.0)
    assert yaw == pytest.approx(0.3)


def test_far_away_it_tilts_at_most_its_limit_toward_the_target_keeping_height():
    c = PositionController(PX4_POSITION, 0.8, DT, tilt_max=math.radians(35))
    q, thrust = c.update(PositionTarget(position=np.array([0.0, 50.0, 1.0]), yaw=0.0), np.array([0.0, 0.0, 1.0]),
                         np.zeros(3), 0.0)
    roll, pitch, _ = euler_from_quat(q)
    assert roll == pytest.approx(-math.radians(35)) and pitch == pytest.approx(0.0, abs=1e-9)  # left: roll < 0 (FLU)
    assert thrust * math.cos(math.radians(35)) == pytest.approx(0.8)  # vertical thrust first: height held


def test_yaw_rate_turns_the_heading_and_a_pause_restarts_the_integrator():
    c = PositionController(PX4_POSITION, 0.8, DT)
    tgt = PositionTarget(velocity=np.array([0.0, 0.0, 0.5]), yaw_rate=1.0)
    for k in range(200):
        c.update(tgt, np.zeros(3), np.zeros(3), k * DT, yaw=0.2)
    assert c.yaw_sp == pytest.approx(0.2 + 200 * DT) and c.vel_int[2] > 0.0  # from the heading it started at
    c.update(tgt, np.zeros(3), np.zeros(3), 5.0, yaw=-1.0)  # not run for a while: starts afresh
    assert c.yaw_sp == pytest.approx(-1.0 + DT) and c.vel_int[2] == pytest.approx(2.0 * 0.5 * DT)


# ------------------------------------------------------------------ flown on the physics
def _vehicle(**kw) -> SimVehicle:
    return SimVehicle(VehicleConfig(url=f"udpout:127.0.0.1:{free_port()}", noise=False, **kw))


def _fly(veh: SimVehicle, seconds: float, target) -> np.ndarray:
    """OFFBOARD on ``target(t, p0)`` (a PositionTarget) for ``seconds``: rows (t, true position, velocity)."""
    ap, p0 = veh.autopilot, veh.plant.state[0:3].copy()
    rows = []
    for _ in range(int(round(seconds / veh.dt))):
        ap.flight.link, ap.sp_kind, ap.last_sp_time = target(veh.t, p0), "position", veh.t
        if ap.mode != MODE_OFFBOARD:
            ap.set_mode(MODE_OFFBOARD)
        veh._tick_start(0.0)
        veh._advance()
        veh.k += 1
        rows.append([veh.t, *veh.plant.state[0:6]])
    return np.array(rows)


def _linear_cascade(gains_p: float, vel_p: float, vel_i: float, ref, t: np.ndarray, ff=None) -> np.ndarray:
    """Independent reference: the ideal cascade on a double integrator (no actuator, no saturation),
    P on position, PI on velocity, Euler at 1 ms; the position at the times t."""
    h, x, v, i, out = 1e-3, 0.0, 0.0, 0.0, []
    for tk in np.arange(0.0, t[-1] + h / 2, h):
        e = gains_p * (ref(tk) - x) + (ff(tk) if ff else 0.0) - v
        a = vel_p * e + i
        i += vel_i * e * h
        v += a * h
        x += v * h
        out.append(x)
    return np.interp(t, np.arange(len(out)) * h, out)


def _step(t: float, t0: float = 0.2, size: float = 0.5) -> float:
    return size if t >= t0 else 0.0


def test_a_z_step_follows_the_linear_cascade_and_settles():
    veh = _vehicle()
    g = PX4_POSITION
    f = _fly(veh, 10.0, lambda t, p0: PositionTarget(position=p0 + [0.0, 0.0, _step(t)]))
    z = f[:, 3] - f[0, 3]
    ref = _linear_cascade(g.z_p, g.z_vel_p, g.z_vel_i, _step, f[:, 0])
    assert np.max(np.abs(z - ref)) < 0.03  # the motors' and attitude loop's lag only
    i1 = np.searchsorted(f[:, 0], 1.2)
    assert 0.15 < z[i1] < 0.35  # first-order-ish: well under way a second (tau ~ 1 / MPC_Z_P) after the step
    assert abs(z[-1] - 0.5) < 0.01 and np.max(z) < 0.55  # settled, little overshoot
    assert np.max(np.abs(f[:, 1:3] - f[0, 1:3])) < 0.01  # x, y held


def _ramp(t: float, v: float = 1.0, t0: float = 0.5) -> float:
    return v * max(t - t0, 0.0)


@pytest.mark.parametrize("ff", [False, True])
def test_a_z_ramp_lags_by_v_over_kp_without_velocity_feed_forward_and_hardly_with_it(ff):
    veh = _vehicle()
    g = PX4_POSITION

    def target(t, p0):
        vel = np.array([0.0, 0.0, 1.0 if t >= 0.5 else 0.0]) if ff else NAN3
        return PositionTarget(position=p0 + [0.0, 0.0, _ramp(t)], velocity=vel)

    f = _fly(veh, 9.0, target)
    z = f[:, 3] - f[0, 3]
    lag = np.array([_ramp(t) for t in f[:, 0]]) - z
    late = f[:, 0] >= 6.0
    ref = _linear_cascade(g.z_p, g.z_vel_p, g.z_vel_i, _ramp, f[:, 0], (lambda t: float(t >= 0.5)) if ff else None)
    # (the feed-forward's 1 m/s step asks 4 m/s^2 at the ramp's start: the thrust saturates a moment)
    assert np.max(np.abs(z - ref)) < (0.1 if ff else 0.05) and np.max(np.abs(z - ref)[late]) < 0.03
    if ff:
        assert abs(np.mean(lag[late])) < 0.03
    else:
        assert 0.85 * (1.0 / g.z_p) < np.mean(lag[late]) < 1.02 * (1.0 / g.z_p)


def _vel_sp(veh: SimVehicle, target):
    """``target`` that also records the controller's velocity setpoint of the tick before."""
    out: list[np.ndarray] = []

    def f(t, p0):
        out.append(veh.autopilot.flight.ctl.vel_sp.copy())
        return target(t, p0)

    return f, out


def test_climb_and_descent_speeds_are_limited():
    veh = _vehicle()
    g = PX4_POSITION
    tgt, vsp = _vel_sp(veh, lambda t, p0: PositionTarget(position=p0 + [0.0, 0.0, 10.0]))
    up = _fly(veh, 5.0, tgt)
    assert max(v[2] for v in vsp) == pytest.approx(g.z_vel_max_up)
    assert 2.7 < np.max(up[:, 6]) <= g.z_vel_max_up + 0.03  # the thrust saturates: it cannot overshoot
    tgt, vsp = _vel_sp(veh, lambda t, p0: PositionTarget(position=p0 - [0.0, 0.0, 6.0]))
    down = _fly(veh, 4.0, tgt)
    assert min(v[2] for v in vsp) == pytest.approx(-g.z_vel_max_dn)
    assert -1.2 * g.z_vel_max_dn < np.min(down[:, 6]) < -g.z_vel_max_dn  # the PI's overshoot


def test_arducopter_limits_its_speed_and_lean_angle_and_holds_height():
    veh = _vehicle(autopilot="ardupilot")
    tilts = []

    def target(t, p0):
        s = veh.plant.state
        r, p, _ = euler_from_quat(s[6:10])
        tilts.append(math.degrees(math.acos(math.cos(r) * math.cos(p))))
        return PositionTarget(position=p0 + [20.0, 0.0, 0.0])

    tgt, vsp = _vel_sp(veh, target)
    f = _fly(veh, 8.0, tgt)
    vmax = ARDUCOPTER_POSITION.xy_vel_max
    assert max(np.linalg.norm(v[:2]) for v in vsp) == pytest.approx(vmax)
    assert vmax < np.max(np.linalg.norm(f[:, 4:6], axis=1)) < 1.2 * vmax  # the PI's overshoot
    assert 25.0 < max(tilts) <= 30.0 + 1.0
    assert np.max(np.abs(f[:, 3] - f[0, 3])) < 0.15


def test_a_heavier_vehicle_than_believed_sags_then_the_integrator_recovers():
    veh = _vehicle(hover_thrust=0.7)  # the truth is 0.8
    f = _fly(veh, 10.0, lambda t, p0: PositionTarget(position=p0.copy()))
    dz = f[:, 3] - f[0, 3]
    assert np.min(dz) < -0.1 and abs(dz[-1]) < 0.01  # the integrator's slow pole (tau ~ 2 s)
    assert veh.autopilot.flight.ctl.vel_int[2] == pytest.approx(9.81 * (0.8 / 0.7 - 1.0), rel=0.05)


def test_hold_brakes_and_holds_where_it_stopped():
    veh = _vehicle()
    _fly(veh, 2.0, lambda t, p0: PositionTarget(velocity=np.array([1.5, 0.0, 0.0])))
    x_entry = veh.plant.state[0]
    veh.autopilot.set_mode(MODE_HOLD)
    xs = []
    for _ in range(800):
        veh._tick_start(0.0)
        veh._advance()
        veh.k += 1
        xs.append(veh.plant.state[0])
    hold = veh.autopilot.flight.own.position
    assert hold[0] > x_entry + 0.3  # where it stopped, not where HOLD began
    # the integrator learnt the drag at 1.5 m/s: it creeps back over seconds (as PX4's, MPC_XY_VEL_I_ACC)
    assert abs(xs[-1] - hold[0]) < 0.08 and abs(veh.plant.state[3]) < 0.03


def test_land_descends_at_the_land_speed_over_where_it_began_and_disarms_on_the_ground():
    veh = _vehicle()
    xy0 = veh.plant.state[0:2].copy()
    veh.autopilot.set_mode(MODE_LAND)
    vz = []
    for _ in range(1000):
        if not veh.armed:
            break
        veh._tick_start(0.0)
        veh._advance()
        veh.k += 1
        vz.append(veh.plant.state[5])
    assert not veh.armed and veh.events[-1][1] == "disarmed (landed)" and veh.autopilot.body.in_contact()
    assert min(vz) == pytest.approx(-PX4_POSITION.land_speed, abs=0.1)
    assert np.linalg.norm(veh.plant.state[0:2] - xy0) < 0.02
