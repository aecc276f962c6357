"""The simulated vehicle's position controller: PX4's cascaded multicopter position control
(``mc_pos_control``'s ``PositionControl``), with ArduCopter's gains and limits for its emulation, and
what the autopilot flies on it (:class:`PositionFlight`: HOLD, LAND, the link's position setpoints).

* position error -> velocity setpoint (P), plus the setpoint's velocity as feed-forward; the
  horizontal speed is limited keeping the position part first, the vertical one to the climb /
  descent limits;
* velocity error -> acceleration (P, I, D on the velocity's derivative), plus the setpoint's
  acceleration as feed-forward;
* acceleration -> thrust vector through the autopilot's hover-thrust estimate (the true one by
  default; a wrong one is a vehicle heavier or lighter than the autopilot believes, which the
  velocity integrator absorbs with a lag), tilt-limited, vertical thrust first, with PX4's
  anti-windup (vertical: stop integrating into a saturation; horizontal: tracking);
* thrust vector + yaw -> attitude quaternion and collective thrust for the flight controller.

Everything is world ENU (z up) and the true state, as the vehicle's own HOLD always used. A
:class:`PositionTarget` component that is NaN is not controlled (PX4's ``trajectory_setpoint``):
:func:`target_from_local_ned` reads SET_POSITION_TARGET_LOCAL_NED as PX4's MAVLink receiver does.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ddpc_codegen.robot.frames import enu_from_ned, quat_from_euler, wrap_pi, yaw_enu_from_ned
from ddpc_codegen.testbed.vehicle_config import MODE_HOLD, MODE_OFFBOARD

from firmware_bridge.link import mavlink

__all__ = ["PositionGains", "PX4_POSITION", "ARDUCOPTER_POSITION", "PositionTarget", "PositionController",
           "PositionFlight", "target_from_local_ned", "constrain_xy"]

_NAN3 = (math.nan, math.nan, math.nan)
_POS_IGNORE = (mavlink.POSITION_TARGET_TYPEMASK_X_IGNORE | mavlink.POSITION_TARGET_TYPEMASK_Y_IGNORE
               | mavlink.POSITION_TARGET_TYPEMASK_Z_IGNORE)
_VEL_IGNORE = (mavlink.POSITION_TARGET_TYPEMASK_VX_IGNORE | mavlink.POSITION_TARGET_TYPEMASK_VY_IGNORE
               | mavlink.POSITION_TARGET_TYPEMASK_VZ_IGNORE)
_ACC_IGNORE = (mavlink.POSITION_TARGET_TYPEMASK_AX_IGNORE | mavlink.POSITION_TARGET_TYPEMASK_AY_IGNORE
               | mavlink.POSITION_TARGET_TYPEMASK_AZ_IGNORE)
# PX4 low-passes the velocity derivative the D term acts on (MPC_VELD_LP) [Hz].
_VEL_DOT_LP_HZ = 5.0
# HOLD brakes until slower than this, then holds where it is [m/s].
_STOPPED = 0.1
# LAND: still (|vz| below this [m/s]) on the ground for this long [s] is landed.
_LANDED_VZ, _LANDED_FOR = 0.2, 0.5


@dataclass(frozen=True)
class PositionGains:
    """Gains [1/s, 1/s, 1/s^2, -] and limits [m/s, rad, normalized thrust] of the cascade.

    PX4 parameter names in the field comments; :data:`ARDUCOPTER_POSITION` maps ArduCopter's.
    """

    xy_p: float = 0.95          # MPC_XY_P
    z_p: float = 1.0            # MPC_Z_P
    xy_vel_p: float = 1.8       # MPC_XY_VEL_P_ACC
    xy_vel_i: float = 0.4       # MPC_XY_VEL_I_ACC
    xy_vel_d: float = 0.2       # MPC_XY_VEL_D_ACC
    z_vel_p: float = 4.0        # MPC_Z_VEL_P_ACC
    z_vel_i: float = 2.0        # MPC_Z_VEL_I_ACC
    z_vel_d: float = 0.0        # MPC_Z_VEL_D_ACC
    xy_vel_max: float = 12.0    # MPC_XY_VEL_MAX
    z_vel_max_up: float = 3.0   # MPC_Z_VEL_MAX_UP
    z_vel_max_dn: float = 1.5   # MPC_Z_VEL_MAX_DN
    tilt_max: float = math.radians(45.0)  # MPC_TILTMAX_AIR
    thr_min: float = 0.12       # MPC_THR_MIN
    thr_max: float = 1.0        # MPC_THR_MAX
    thr_xy_margin: float = 0.3  # MPC_THR_XY_MARG
    land_speed: float = 0.7     # MPC_LAND_SPEED


PX4_POSITION = PositionGains()
# ArduCopter (AC_PosControl defaults): PSC_POSXY_P 1, PSC_VELXY_P 2 / I 1 / D 0.5, PSC_POSZ_P 1,
# PSC_VELZ_P 5 (its acceleration loop's integrator, PSC_ACCZ_I, is the vertical I here); WPNAV_SPEED 5,
# WPNAV_SPEED_UP 2.5, WPNAV_SPEED_DN 1.5 m/s; ANGLE_MAX 30 deg; LAND_SPEED 0.5 m/s.
ARDUCOPTER_POSITION = PositionGains(xy_p=1.0, z_p=1.0, xy_vel_p=2.0, xy_vel_i=1.0, xy_vel_d=0.5, z_vel_p=5.0,
                                    z_vel_i=1.0, z_vel_d=0.0, xy_vel_max=5.0, z_vel_max_up=2.5, z_vel_max_dn=1.5,
                                    tilt_max=math.radians(30.0), land_speed=0.5)


@dataclass
class PositionTarget:
    """A position-control setpoint, world ENU: position [m], velocity [m/s], acceleration [m/s^2]
    (each (3,); NaN: not controlled / no feed-forward), yaw [rad, ENU] and yaw rate [rad/s] (NaN:
    not given; neither: keep the heading)."""

    position: np.ndarray = field(default_factory=lambda: np.array(_NAN3))
    velocity: np.ndarray = field(default_factory=lambda: np.array(_NAN3))
    acceleration: np.ndarray = field(default_factory=lambda: np.array(_NAN3))
    yaw: float = math.nan
    yaw_rate: float = math.nan


def target_from_local_ned(msg) -> PositionTarget:
    """SET_POSITION_TARGET_LOCAL_NED as PX4 reads it: a group (position, velocity, acceleration)
    with any of its ignore bits set is not used; yaw / yaw rate by their own bits; NED -> ENU.

    Raises ValueError (the reason, as PX4 logs it) for a frame other than MAV_FRAME_LOCAL_NED, a
    force setpoint, or a setpoint that controls nothing.
    """
    if msg.coordinate_frame != mavlink.MAV_FRAME_LOCAL_NED:
        raise ValueError(f"SET_POSITION_TARGET_LOCAL_NED coordinate frame {msg.coordinate_frame} unsupported")
    m = int(msg.type_mask)
    tgt = PositionTarget()
    if not m & _POS_IGNORE:
        tgt.position = np.array(enu_from_ned((msg.x, msg.y, msg.z)), dtype=float)
    if not m & _VEL_IGNORE:
        tgt.velocity = np.array(enu_from_ned((msg.vx, msg.vy, msg.vz)), dtype=float)
    if not m & _ACC_IGNORE:
        if m & mavlink.POSITION_TARGET_TYPEMASK_FORCE_SET:
            raise ValueError("SET_POSITION_TARGET_LOCAL_NED force not supported")
        tgt.acceleration = np.array(enu_from_ned((msg.afx, msg.afy, msg.afz)), dtype=float)
    if not m & mavlink.POSITION_TARGET_TYPEMASK_YAW_IGNORE and math.isfinite(msg.yaw):
        tgt.yaw = yaw_enu_from_ned(float(msg.yaw))
    if not m & mavlink.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE and math.isfinite(msg.yaw_rate):
        tgt.yaw_rate = -float(msg.yaw_rate)  # clockwise (NED) -> counter-clockwise (ENU)
    if not any(np.isfinite(v).any() for v in (tgt.position, tgt.velocity, tgt.acceleration)):
        raise ValueError("SET_POSITION_TARGET_LOCAL_NED controls nothing (all of position, velocity, "
                         "acceleration ignored or not finite)")
    return tgt


def _add_if_not_nan(setpoint: np.ndarray, addition: np.ndarray) -> np.ndarray:
    """PX4's addIfNotNan per component: NaN + a = a, s + NaN = s, s + a."""
    return np.where(np.isfinite(setpoint), setpoint + np.nan_to_num(addition), addition)


def constrain_xy(v0: np.ndarray, v1: np.ndarray, vmax: float) -> np.ndarray:
    """PX4's ControlMath::constrainXY: v0 + v1 limited to norm vmax, giving up v1 (the feed-forward)
    before v0 (the position part). Arrays (2,)."""
    s = v0 + v1
    if np.linalg.norm(s) <= vmax:
        return s
    n0 = float(np.linalg.norm(v0))
    if n0 >= vmax:
        return v0 / n0 * vmax
    if np.linalg.norm(v1 - v0) < 1e-3:
        return v0 / max(n0, 1e-9) * vmax
    n1 = float(np.linalg.norm(v1))
    if n0 < 1e-3:
        return v1 / n1 * vmax
    u1 = v1 / n1
    m = float(u1 @ v0)
    c = float(v0 @ v0) - vmax * vmax
    return v0 + u1 * (-m + math.sqrt(m * m - c))


def _limit_tilt(body_z: np.ndarray, tilt_max: float) -> np.ndarray:
    """Unit thrust direction (3,) tilted at most ``tilt_max`` from up, keeping its azimuth."""
    if math.acos(max(-1.0, min(1.0, float(body_z[2])))) <= tilt_max:
        return body_z
    h = body_z[:2]
    n = float(np.linalg.norm(h))
    d = h / n if n > 1e-9 else np.zeros(2)
    return np.array([d[0] * math.sin(tilt_max), d[1] * math.sin(tilt_max), math.cos(tilt_max)])


def attitude_from_thrust(thr: np.ndarray, yaw: float) -> np.ndarray:
    """Attitude (w, x, y, z) body FLU -> world ENU whose body z is along ``thr`` (3,) at heading ``yaw``."""
    n = float(np.linalg.norm(thr))
    b = thr / n if n > 1e-9 else np.array([0.0, 0.0, 1.0])
    cy, sy = math.cos(yaw), math.sin(yaw)
    bf, bl = cy * b[0] + sy * b[1], -sy * b[0] + cy * b[1]  # heading frame: forward, left
    pitch = math.atan2(bf, b[2])
    roll = math.atan2(-bl * math.cos(pitch), b[2])
    return quat_from_euler(roll, pitch, yaw)


class PositionController:
    """The cascade (see the module docstring), one :meth:`update` per control tick.

    Args:
        gains: gains and limits (:data:`PX4_POSITION`, :data:`ARDUCOPTER_POSITION`).
        hover_thrust: the autopilot's hover-thrust estimate [normalized thrust].
        dt: control period [s]; g: gravity [m/s^2].
        tilt_max: the flight controller's own tilt limit [rad] (the smaller one applies).
    """

    def __init__(self, gains: PositionGains, hover_thrust: float, dt: float, g: float = 9.81,
                 tilt_max: float = math.pi) -> None:
        self.gains, self.hover_thrust, self.dt, self.g = gains, float(hover_thrust), float(dt), float(g)
        self.tilt_max = min(gains.tilt_max, tilt_max)
        gn = gains
        self._kp = np.array([gn.xy_p, gn.xy_p, gn.z_p])
        self._kv = np.array([gn.xy_vel_p, gn.xy_vel_p, gn.z_vel_p])
        self._ki = np.array([gn.xy_vel_i, gn.xy_vel_i, gn.z_vel_i])
        self._kd = np.array([gn.xy_vel_d, gn.xy_vel_d, gn.z_vel_d])
        self.vel_int = np.zeros(3)
        self.vel_dot = np.zeros(3)
        self._vel_prev: np.ndarray | None = None
        self._t_last = -math.inf
        self.yaw_sp = 0.0
        # The last tick's setpoints (ENU): velocity, acceleration, thrust vector.
        self.vel_sp, self.acc_sp, self.thr_sp = np.zeros(3), np.zeros(3), np.zeros(3)

    def reset(self, yaw: float) -> None:
        """Start afresh (integrator, derivative) holding heading ``yaw`` [rad, ENU]."""
        self.vel_int[:] = 0.0
        self.vel_dot[:] = 0.0
        self._vel_prev = None
        self.yaw_sp = float(yaw)

    def update(self, target: PositionTarget, pos: np.ndarray, vel: np.ndarray, t: float,
               yaw: float = 0.0) -> tuple[np.ndarray, float]:
        """One control step at time t [s] from the state (position, velocity (3,), heading ``yaw``
        [rad], ENU): (attitude quaternion body FLU -> world ENU, normalized collective thrust).
        A controller that did not run on the previous tick restarts (:meth:`reset`) first."""
        if t - self._t_last > 1.5 * self.dt:
            self.reset(yaw)
        self._t_last = t
        self._yaw_step(target)
        vel = np.asarray(vel, dtype=float)
        if self._vel_prev is not None:
            a = min(1.0, 2.0 * math.pi * _VEL_DOT_LP_HZ * self.dt)
            self.vel_dot += a * ((vel - self._vel_prev) / self.dt - self.vel_dot)
        self._vel_prev = vel.copy()
        self.vel_sp = self._velocity_setpoint(target, np.asarray(pos, dtype=float))
        vel_err = self.vel_sp - vel
        acc_fb = vel_err * self._kv + self.vel_int - self.vel_dot * self._kd
        self.acc_sp = np.nan_to_num(_add_if_not_nan(target.acceleration, acc_fb))
        self.thr_sp = self._thrust(self.acc_sp, vel_err)
        return attitude_from_thrust(self.thr_sp, self.yaw_sp), float(np.linalg.norm(self.thr_sp))

    def _yaw_step(self, target: PositionTarget) -> None:
        if math.isfinite(target.yaw):
            self.yaw_sp = target.yaw
        elif math.isfinite(target.yaw_rate):
            self.yaw_sp = wrap_pi(self.yaw_sp + target.yaw_rate * self.dt)

    def _velocity_setpoint(self, target: PositionTarget, pos: np.ndarray) -> np.ndarray:
        g = self.gains
        vel_pos = (target.position - pos) * self._kp
        vel_sp = _add_if_not_nan(target.velocity, vel_pos)
        if np.isfinite(vel_sp[:2]).all():
            v0 = np.nan_to_num(vel_pos[:2])
            vel_sp[:2] = constrain_xy(v0, vel_sp[:2] - v0, g.xy_vel_max)
        if math.isfinite(vel_sp[2]):
            vel_sp[2] = min(max(vel_sp[2], -g.z_vel_max_dn), g.z_vel_max_up)
        return vel_sp

    def _thrust(self, acc_sp: np.ndarray, vel_err: np.ndarray) -> np.ndarray:
        """Acceleration -> thrust vector [normalized], saturated vertical first; integrates the velocity error."""
        g, hov, gn = self.g, self.hover_thrust, self.gains
        body_z = np.array([acc_sp[0], acc_sp[1], g + acc_sp[2]])
        n = float(np.linalg.norm(body_z))
        body_z = _limit_tilt(body_z / n if n > 1e-9 else np.array([0.0, 0.0, 1.0]), self.tilt_max)
        collective = max((g + acc_sp[2]) * hov / g / body_z[2], gn.thr_min)
        thr = body_z * collective
        ve = np.nan_to_num(vel_err)
        if (thr[2] <= gn.thr_min and ve[2] <= 0.0) or (thr[2] >= gn.thr_max and ve[2] >= 0.0):
            ve[2] = 0.0  # do not integrate further into a saturation
        nxy = float(np.linalg.norm(thr[:2]))
        alloc = min(nxy, gn.thr_xy_margin)
        thr[2] = min(thr[2], math.sqrt(gn.thr_max ** 2 - alloc ** 2))
        rem = gn.thr_max ** 2 - thr[2] ** 2
        max_xy = math.sqrt(rem) if rem > 0.0 else 0.0
        if nxy > max_xy:
            thr[:2] *= max_xy / nxy
        # Tracking anti-windup: a saturated horizontal output pulls the integrator back.
        acc_made = thr[:2] * (g / hov)
        acc_lim = acc_made if acc_sp[:2] @ acc_sp[:2] > acc_made @ acc_made else acc_sp[:2]
        ve[:2] -= (2.0 / gn.xy_vel_p) * (acc_sp[:2] - acc_lim)
        self.vel_int += ve * self._ki * self.dt
        self.vel_int[2] = min(max(self.vel_int[2], -g), g)
        return thr


class PositionFlight:
    """What the autopilot flies on its position controller: HOLD (brake, then hold where it stopped),
    LAND (this horizontal position, down at the land speed) and OFFBOARD's position setpoints.

    Args:
        controller: the cascade; start: position (3,) [m, ENU] and heading [rad, ENU] HOLD starts with.
    """

    def __init__(self, controller: PositionController, start: tuple[np.ndarray, float]) -> None:
        self.ctl = controller
        self.ctl.reset(float(start[1]))
        self.own = PositionTarget(position=np.array(start[0], dtype=float), velocity=np.zeros(3), yaw=float(start[1]))
        self.link: PositionTarget | None = None  # the link's newest position setpoint
        self._landed_since: float | None = None

    def hold(self, yaw: float) -> None:
        """HOLD from here: brake (velocity 0); :meth:`step` fixes the position once stopped."""
        self.own = PositionTarget(velocity=np.zeros(3), yaw=yaw)

    def land(self, pos: np.ndarray, yaw: float) -> None:
        """LAND from ``pos`` (3,) [m, ENU]: hold its horizontal position, descend at the land speed."""
        self.own = PositionTarget(position=np.array([pos[0], pos[1], math.nan]),
                                  velocity=np.array([math.nan, math.nan, -self.ctl.gains.land_speed]), yaw=yaw)
        self._landed_since = None

    def landed(self, in_contact: bool, vz: float, t: float) -> bool:
        """LAND's touchdown: foot down and still for a moment, at vehicle time t [s]."""
        if not (in_contact and abs(vz) < _LANDED_VZ):
            self._landed_since = None
            return False
        if self._landed_since is None:
            self._landed_since = t
        return t - self._landed_since > _LANDED_FOR

    def step(self, mode: str, state: np.ndarray, t: float, yaw: float) -> tuple[np.ndarray, float]:
        """One tick in ``mode`` (MODE_*) from the true state (19,) at time t [s], heading ``yaw``:
        (attitude quaternion body FLU -> world ENU, normalized thrust in [0, 1])."""
        target = self.link if mode == MODE_OFFBOARD and self.link is not None else self.own
        pos, vel = state[0:3], state[3:6]
        if mode == MODE_HOLD and not np.isfinite(target.position).all() and np.linalg.norm(vel) < _STOPPED:
            target.position = np.array(pos, dtype=float)  # stopped: hold here
        q, thrust = self.ctl.update(target, pos, vel, t, yaw)
        return q, min(max(thrust, 0.0), 1.0)
