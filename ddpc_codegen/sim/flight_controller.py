"""A PX4-like multicopter flight controller in offboard attitude mode.

It takes exactly what PX4 takes from MAVLink SET_ATTITUDE_TARGET (body rates ignored): an
attitude quaternion and a normalized collective thrust in [0, 1]. Internally (PX4's
mc_att_control + mc_rate_control + control allocator, simplified):

1. tilt limit: the setpoint's tilt is clamped to ``tilt_max`` keeping its direction;
2. attitude P (250 Hz), quaternion error with PX4's sign convention:
   q_e = q^-1 q_sp, rate_sp = 2 sign(q_e,w) att_p * q_e,xyz, clamped to ``rate_max``;
3. body-rate PID (1 kHz): angular acceleration command = P e + I int(e) - D d(w)/dt (D on the
   low-pass filtered measured rate, anti-windup clamp, integration frozen while the motors
   saturate), torque = I_body * command;
4. allocation for the quad-X: per-rotor thrusts from (collective, torque); roll/pitch get
   priority over collective thrust, yaw is sacrificed first (PX4's desaturation logic, simplified);
   rotor speed commands w_i = sqrt(T_i / k_F) (thrust-linear outputs, THR_MDL_FAC = 1).

Normalized thrust -> newtons: T = thrust * max_thrust, max_thrust = 4 k_F w_max^2 =
thrust_to_weight * m g (see :mod:`ddpc_codegen.sim.params`). The frame here is ENU/FLU like the
rest of the simulator; PX4 proper works in NED/FRD (see :mod:`ddpc_codegen.robot.frames`).

The controller uses the *true* attitude and rates (PX4's own estimator is assumed good); the
companion computer sees a delayed, noisy state (see :mod:`ddpc_codegen.sim.stepper`).
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from ddpc_codegen.robot.frames import quat_multiply
from ddpc_codegen.sim.params import PogoXParams
from ddpc_codegen.sim.plant import rotor_geometry

__all__ = ["PX4LikeFlightController", "normalized_thrust_to_newton", "newton_to_normalized_thrust"]


def normalized_thrust_to_newton(thrust: float, params: PogoXParams) -> float:
    """Collective thrust [N] for a normalized thrust in [0, 1] (thrust-linear mapping)."""
    return min(max(float(thrust), 0.0), 1.0) * params.max_thrust


def newton_to_normalized_thrust(force: float, params: PogoXParams) -> float:
    """Inverse of :func:`normalized_thrust_to_newton`, clipped to [0, 1]."""
    return min(max(float(force) / params.max_thrust, 0.0), 1.0)


def _clamp(x: float, lo: float, hi: float) -> float:
    return lo if x < lo else (hi if x > hi else x)


class PX4LikeFlightController:
    """Cascaded attitude (P) -> body-rate (PID) -> allocation, PX4 style.

    Usage per physics step: ``attitude_update(q)`` at ``att_hz`` and ``rate_update(w, dt)`` at
    ``rate_hz`` (the simulation loop schedules them); the setpoint is changed with
    :meth:`set_attitude_target` whenever an offboard message arrives.
    """

    def __init__(self, params: PogoXParams) -> None:
        self.params = params
        self.gains = params.fc
        xs, ys, sg = rotor_geometry(params.arm_length)
        self._xs, self._ys, self._sg = xs, ys, sg
        self._km_ratio = params.k_m_ratio
        self._kf = params.k_f
        self._tmin = params.k_f * params.omega_idle**2
        self._tmax = params.k_f * params.omega_max**2
        self._inertia = params.inertia
        self.reset()

    def reset(self) -> None:
        self.q_sp = np.array([1.0, 0.0, 0.0, 0.0])
        self.thrust_sp = 0.0
        self.rate_sp = [0.0, 0.0, 0.0]
        self._integ = [0.0, 0.0, 0.0]
        self._w_filt: list[float] | None = None
        self._dw = [0.0, 0.0, 0.0]
        self._saturated = False
        self.last_rotor_cmd = [0.0] * 4

    # ------------------------------------------------------------------ offboard input
    def set_attitude_target(self, q: Sequence[float], thrust: float) -> None:
        """SET_ATTITUDE_TARGET: quaternion (w, x, y, z) body->world and normalized thrust [0, 1]."""
        q = np.asarray(q, dtype=float)
        n = float(np.linalg.norm(q))
        if not math.isfinite(n) or n < 1e-6:
            return  # PX4 rejects invalid quaternions; keep the previous setpoint
        q = q / n
        self.q_sp = self._limit_tilt(q)
        self.thrust_sp = _clamp(float(thrust), 0.0, 1.0) if math.isfinite(thrust) else 0.0

    def _limit_tilt(self, q: np.ndarray) -> np.ndarray:
        w, x, y, z = q
        # Thrust axis b3 = R e3 of the setpoint.
        b3 = (2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y))
        tilt = math.acos(_clamp(b3[2], -1.0, 1.0))
        tmax = self.gains.tilt_max
        if tilt <= tmax:
            return q
        # Rotate the thrust axis back to the cone keeping its azimuth and the setpoint's yaw.
        yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
        az = math.atan2(b3[1], b3[0])
        bx, by, bz = math.sin(tmax) * math.cos(az), math.sin(tmax) * math.sin(az), math.cos(tmax)
        # Rotation from e3 to b3_lim about axis e3 x b = (-by, bx, 0).
        s = math.sqrt(bx * bx + by * by)
        ang = math.atan2(s, bz)
        ax, ay = (-by / s, bx / s) if s > 1e-12 else (1.0, 0.0)
        q_tilt = np.array([math.cos(ang / 2), ax * math.sin(ang / 2), ay * math.sin(ang / 2), 0.0])
        q_yaw_in_tilt = np.array([math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)])
        out = quat_multiply(q_tilt, q_yaw_in_tilt)
        return out / np.linalg.norm(out)

    # ------------------------------------------------------------------ loops
    def attitude_update(self, q: Sequence[float]) -> list[float]:
        """Attitude P loop: measured quaternion -> body-rate setpoint [rad/s] (stored and returned)."""
        qw, qx, qy, qz = q
        sw, sx, sy, sz = self.q_sp
        # q_e = conj(q) * q_sp
        ew = qw * sw + qx * sx + qy * sy + qz * sz
        ex = qw * sx - qx * sw - qy * sz + qz * sy
        ey = qw * sy + qx * sz - qy * sw - qz * sx
        ez = qw * sz - qx * sy + qy * sx - qz * sw
        sgn = 2.0 if ew >= 0.0 else -2.0
        kp = self.gains.att_p
        rmax = self.gains.rate_max
        self.rate_sp = [
            _clamp(sgn * ex * kp[0], -rmax[0], rmax[0]),
            _clamp(sgn * ey * kp[1], -rmax[1], rmax[1]),
            _clamp(sgn * ez * kp[2], -rmax[2], rmax[2]),
        ]
        return self.rate_sp

    def rate_update(self, w: Sequence[float], dt: float) -> list[float]:
        """Body-rate PID + allocation: measured rates [rad/s] -> rotor speed commands (4,) [rad/s]."""
        gn = self.gains
        if self._w_filt is None:
            self._w_filt = [float(v) for v in w]
        a = dt / (dt + 1.0 / (2.0 * math.pi * gn.d_cutoff_hz))
        acc = [0.0, 0.0, 0.0]
        lim = gn.rate_i_limit
        for i in range(3):
            wf_old = self._w_filt[i]
            wf = wf_old + a * (w[i] - wf_old)
            self._w_filt[i] = wf
            dw = (wf - wf_old) / dt
            e = self.rate_sp[i] - w[i]
            if not self._saturated:
                self._integ[i] = _clamp(self._integ[i] + gn.rate_i[i] * e * dt, -lim, lim)
            acc[i] = gn.rate_p[i] * e + self._integ[i] - gn.rate_d[i] * dw
        I = self._inertia
        tau = (I[0] * acc[0], I[1] * acc[1], I[2] * acc[2])
        collective = self.thrust_sp * 4.0 * self._tmax
        thrusts = self._allocate(collective, tau)
        kf = self._kf
        cmd = [math.sqrt(t / kf) for t in thrusts]
        self.last_rotor_cmd = cmd
        return cmd

    def _allocate(self, collective: float, tau: Sequence[float]) -> list[float]:
        """Per-rotor thrusts [N] for (collective [N], body torque [N m]), with desaturation."""
        xs, ys, sg = self._xs, self._ys, self._sg
        d = abs(xs[0])
        # Inverse of the X mixer: tau_x = sum y_i T_i, tau_y = -sum x_i T_i, tau_z = k sum s_i T_i.
        rp = [(tau[0] * ys[i] / (4 * d * d)) - (tau[1] * xs[i] / (4 * d * d)) for i in range(4)]
        yw = [tau[2] * sg[i] / (4.0 * self._km_ratio) for i in range(4)]
        tmin, tmax = self._tmin, self._tmax
        span = tmax - tmin
        saturated = False
        lo, hi = min(rp), max(rp)
        if hi - lo > span:  # not even roll/pitch fit: scale them down
            sc = span / (hi - lo)
            rp = [v * sc for v in rp]
            lo, hi = lo * sc, hi * sc
            saturated = True
        c = collective / 4.0
        c_lo, c_hi = tmin - lo, tmax - hi
        if c < c_lo or c > c_hi:
            saturated = True
            c = _clamp(c, c_lo, c_hi)
        # Yaw gets whatever room is left.
        k = 1.0
        for i in range(4):
            base = c + rp[i]
            if yw[i] > 0 and base + yw[i] > tmax:
                k = min(k, (tmax - base) / yw[i])
            elif yw[i] < 0 and base + yw[i] < tmin:
                k = min(k, (tmin - base) / yw[i])
        if k < 1.0:
            saturated = True
            k = max(k, 0.0)
        self._saturated = saturated
        return [_clamp(c + rp[i] + k * yw[i], tmin, tmax) for i in range(4)]


