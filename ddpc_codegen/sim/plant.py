"""Hybrid rigid-body + pogo-leg + rotor dynamics of PogoX, with accurate event location.

Frames: world ENU (z up), body FLU; quaternion (w, x, y, z) body -> world. The leg points along
body -z from the COM; its foot is at r - L b3, b3 = R e3.

State vector (19,)::

    0:3 position r [m]   3:6 velocity v [m/s]   6:10 quaternion q   10:13 body rates w [rad/s]
    13 leg length L [m]  14 leg rate L' [m/s]   15:19 rotor speeds [rad/s]

Phases:

* AIR: m r'' = m g + R [0, 0, T] + F_ext, I w' = tau - w x I w. The (massless) leg sits at its
  rest length L0.
* STANCE: the foot is pinned at a ground point p (no slip, holonomic r = p + L b3). In minimal
  form (closed form, no linear solve): with body-frame external force F_b (gravity, drag,
  pushes, thrust) and spring force F_s = k (L0 - L) - c L' (+ bump stop beyond max compression)::

      L''                 = (F_bz + F_s)/m + L (wx^2 + wy^2)
      (Ixx + m L^2) ax    = tau'x + m L (-2 L' wx + L wz wy) - L F_by
      (Iyy + m L^2) ay    = tau'y - m L ( 2 L' wy + L wz wx) + L F_bx
      Izz az              = tau'z          (tau' = tau - w x I w)

  and r, v follow from the constraint (re-projected after every step).
* Touchdown (event: foot height reaches the ground, located to ~1e-12 s by Brent's method on
  the RK4 step): impact map = an impulse at the foot, perpendicular to the leg, that zeroes the
  foot's lateral velocity (no slip), plus the loss of the foot's axial momentum m_f v_axial
  (the foot stops, the leg is compliant axially). The foot mass is otherwise lumped into the body.
* Liftoff (event: leg force F_s returns to zero): smooth, no map; the unloaded massless leg then
  relaxes to L0 as c L' = k (L0 - L) (time constant c/k ~ 6 ms), which moves the foot only.

Rotors: thrust k_F w_i^2, drag torque k_M w_i^2, first-order lag w_i' = (w_cmd,i - w_i)/tau_m,
commands clipped to [w_idle, w_max]. X layout, PX4 numbering: 1 front-right (CCW), 2 back-left
(CCW), 3 front-left (CW), 4 back-right (CW).

Integration: fixed-step classical RK4 (1 ms) in plain Python floats (for a state this small,
cheaper than scipy's solve_ivp and its per-call overhead), with the inputs held over the step
(zero-order hold).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ddpc_codegen.robot.frames import matrix_from_quat
from ddpc_codegen.sim.params import PogoXParams

__all__ = ["AIR", "STANCE", "PogoXPlant", "PlantEvent", "HybridEventError", "rotor_geometry"]

AIR, STANCE = 0, 1
N_STATE = 19


class HybridEventError(RuntimeError):
    """The hybrid integration cannot advance: touchdown / liftoff keep re-triggering within one
    step (Zeno chattering of the foot on the ground), i.e. the robot is no longer hopping."""


@dataclass(frozen=True)
class PlantEvent:
    """A located hybrid event: kind is "touchdown" or "liftoff"; t in seconds."""

    kind: str
    t: float


def rotor_geometry(arm_length: float) -> tuple[tuple[float, ...], tuple[float, ...], tuple[float, ...]]:
    """Rotor x, y positions (body FLU) and yaw-torque signs for PX4's quad-X numbering."""
    d = arm_length / math.sqrt(2.0)
    xs = (d, -d, d, -d)
    ys = (-d, d, d, -d)
    # CCW rotors push the body clockwise (negative z in FLU).
    sign = (-1.0, -1.0, 1.0, 1.0)
    return xs, ys, sign


def event_root_finder():
    """scipy's ``brentq``, imported on the first contact event: importing scipy.optimize is slow, which
    a vehicle that never touches the ground (every flying run) need not pay. A real-time caller that will hop
    calls this once before its loop."""
    from scipy.optimize import brentq

    return brentq


class PogoXPlant:
    """The true robot. ``step(h, rotor_cmd, ext)`` advances by h seconds and returns events.

    Args:
        params: :class:`PogoXParams`.
        ground_height: z of the (flat) ground [m].
    """

    def __init__(self, params: PogoXParams, ground_height: float = 0.0) -> None:
        self.params = params
        self.ground = float(ground_height)
        p = params
        self._m = p.mass
        self._ixx, self._iyy, self._izz = p.inertia
        self._kf = p.k_f
        self._km = p.k_f * p.k_m_ratio
        self._xs, self._ys, self._sg = rotor_geometry(p.arm_length)
        self._tau_m = p.motor_tau
        self._drag = p.drag
        self._g = p.g
        self._L0 = p.leg_rest_length
        self._k = p.leg_stiffness
        self._c = p.leg_damping
        self._cmax = p.leg_max_compression
        self._kb = p.bump_stiffness_factor * p.leg_stiffness
        self._mf = p.foot_mass
        # Relaxation rate of the unloaded leg in the air; too fast for the step -> snap to L0.
        self._relax = p.leg_stiffness / p.leg_damping if p.leg_damping > 0 else math.inf
        self._snap = self._relax * p.physics_dt > 2.0
        if self._snap:
            self._relax = 0.0
        self.state = np.zeros(N_STATE)
        self.mode = AIR
        self.foot = np.zeros(3)
        self.t = 0.0
        self.n_bottom_outs = 0
        self._bottomed = False
        self.reset([0.0, 0.0, 1.0])

    # ------------------------------------------------------------------ setup
    def reset(
        self,
        position: Sequence[float],
        velocity: Sequence[float] = (0.0, 0.0, 0.0),
        quaternion: Sequence[float] = (1.0, 0.0, 0.0, 0.0),
        rates: Sequence[float] = (0.0, 0.0, 0.0),
        rotor_speeds: Sequence[float] | float | None = None,
        t: float = 0.0,
    ) -> None:
        """Start in the air (rotors at hover speed of the true mass unless given)."""
        q = np.asarray(quaternion, dtype=float)
        q = q / np.linalg.norm(q)
        if rotor_speeds is None:
            rotor_speeds = self.params.hover_omega
        w = np.broadcast_to(np.asarray(rotor_speeds, dtype=float), (4,))
        s = np.concatenate([position, velocity, q, rates, [self._L0, 0.0], w]).astype(float)
        self.state = s
        self.mode = AIR
        self.t = float(t)
        self.n_bottom_outs = 0
        self._bottomed = False
        if self._touchdown_fn(list(s)) < 0.0:
            raise ValueError(
                f"initial foot height {self._touchdown_fn(list(s)):.3f} m is below the ground; "
                "start higher (body z > leg rest length)"
            )

    # ------------------------------------------------------------------ dynamics
    def _deriv(self, s: list[float], cmd: Sequence[float], ext: Sequence[float], stance: bool) -> list[float]:
        px, py, pz, vx, vy, vz, qw, qx, qy, qz, wx, wy, wz, L, Ld, r1, r2, r3, r4 = s
        kf = self._kf
        T1, T2, T3, T4 = kf * r1 * r1, kf * r2 * r2, kf * r3 * r3, kf * r4 * r4
        T = T1 + T2 + T3 + T4
        xs, ys, sg = self._xs, self._ys, self._sg
        tx = ys[0] * T1 + ys[1] * T2 + ys[2] * T3 + ys[3] * T4 + ext[3]
        ty = -(xs[0] * T1 + xs[1] * T2 + xs[2] * T3 + xs[3] * T4) + ext[4]
        tz = (self._km / kf) * (sg[0] * T1 + sg[1] * T2 + sg[2] * T3 + sg[3] * T4) + ext[5]
        # Rotation matrix body -> world, written out (= robot.frames.matrix_from_quat): this runs
        # 4x per RK4 step, and a call plus tuple unpacking would cost ~10 % of the simulation.
        xx, yy, zz = qx * qx, qy * qy, qz * qz
        xy, xz, yz = qx * qy, qx * qz, qy * qz
        wxq, wyq, wzq = qw * qx, qw * qy, qw * qz
        R00 = 1.0 - 2.0 * (yy + zz)
        R01 = 2.0 * (xy - wzq)
        R02 = 2.0 * (xz + wyq)
        R10 = 2.0 * (xy + wzq)
        R11 = 1.0 - 2.0 * (xx + zz)
        R12 = 2.0 * (yz - wxq)
        R20 = 2.0 * (xz - wyq)
        R21 = 2.0 * (yz + wxq)
        R22 = 1.0 - 2.0 * (xx + yy)
        m = self._m
        d = self._drag
        Fx = -d * vx + ext[0]
        Fy = -d * vy + ext[1]
        Fz = -d * vz + ext[2] - m * self._g
        ixx, iyy, izz = self._ixx, self._iyy, self._izz
        # tau' = tau - w x I w
        tpx = tx - (wy * izz * wz - wz * iyy * wy)
        tpy = ty - (wz * ixx * wx - wx * izz * wz)
        tpz = tz - (wx * iyy * wy - wy * ixx * wx)
        if not stance:
            ax = (Fx + T * R02) / m
            ay = (Fy + T * R12) / m
            az = (Fz + T * R22) / m
            alx, aly, alz = tpx / ixx, tpy / iyy, tpz / izz
            # Unloaded massless leg: c L' = k (L0 - L) brings it back to rest length.
            dL = self._relax * (self._L0 - L)
            ddL = 0.0
        else:
            # External force in the body frame (R^T F) plus thrust along body z.
            Fbx = R00 * Fx + R10 * Fy + R20 * Fz
            Fby = R01 * Fx + R11 * Fy + R21 * Fz
            Fbz = R02 * Fx + R12 * Fy + R22 * Fz + T
            comp = self._L0 - L
            Fs = self._k * comp - self._c * Ld
            if comp > self._cmax:
                Fs += self._kb * (comp - self._cmax)
            mL = m * L
            ddL = (Fbz + Fs) / m + L * (wx * wx + wy * wy)
            alx = (tpx + mL * (-2.0 * Ld * wx + L * wz * wy) - L * Fby) / (ixx + mL * L)
            aly = (tpy - mL * (2.0 * Ld * wy + L * wz * wx) + L * Fbx) / (iyy + mL * L)
            alz = tpz / izz
            # COM acceleration in the body frame from the constraint r = p + L b3.
            abx = 2.0 * Ld * wy + L * (aly + wz * wx)
            aby = -2.0 * Ld * wx + L * (-alx + wz * wy)
            abz = ddL - L * (wx * wx + wy * wy)
            ax = R00 * abx + R01 * aby + R02 * abz
            ay = R10 * abx + R11 * aby + R12 * abz
            az = R20 * abx + R21 * aby + R22 * abz
            dL = Ld
        qdw = -0.5 * (qx * wx + qy * wy + qz * wz)
        qdx = 0.5 * (qw * wx + qy * wz - qz * wy)
        qdy = 0.5 * (qw * wy - qx * wz + qz * wx)
        qdz = 0.5 * (qw * wz + qx * wy - qy * wx)
        it = 1.0 / self._tau_m
        return [
            vx, vy, vz, ax, ay, az, qdw, qdx, qdy, qdz, alx, aly, alz, dL, ddL,
            (cmd[0] - r1) * it, (cmd[1] - r2) * it, (cmd[2] - r3) * it, (cmd[3] - r4) * it,
        ]

    def _rk4(self, s: list[float], h: float, cmd: Sequence[float], ext: Sequence[float], stance: bool) -> list[float]:
        f = self._deriv
        k1 = f(s, cmd, ext, stance)
        hh = 0.5 * h
        k2 = f([a + hh * b for a, b in zip(s, k1)], cmd, ext, stance)
        k3 = f([a + hh * b for a, b in zip(s, k2)], cmd, ext, stance)
        k4 = f([a + h * b for a, b in zip(s, k3)], cmd, ext, stance)
        h6 = h / 6.0
        out = [a + h6 * (b + 2.0 * (c + d) + e) for a, b, c, d, e in zip(s, k1, k2, k3, k4)]
        # Renormalize the quaternion (RK4 drifts off the unit sphere slowly).
        n = 1.0 / math.sqrt(out[6] ** 2 + out[7] ** 2 + out[8] ** 2 + out[9] ** 2)
        out[6] *= n
        out[7] *= n
        out[8] *= n
        out[9] *= n
        if stance:
            self._project(out)
        return out

    def _project(self, s: list[float]) -> None:
        """Put r, v back on the stance constraint r = p + L b3 (removes integration drift)."""
        qw, qx, qy, qz = s[6], s[7], s[8], s[9]
        # R = matrix_from_quat(q), written out like the one in _deriv (every stance RK4 step).
        R00 = 1.0 - 2.0 * (qy * qy + qz * qz)
        R10 = 2.0 * (qx * qy + qw * qz)
        R20 = 2.0 * (qx * qz - qw * qy)
        R01 = 2.0 * (qx * qy - qw * qz)
        R11 = 1.0 - 2.0 * (qx * qx + qz * qz)
        R21 = 2.0 * (qy * qz + qw * qx)
        R02 = 2.0 * (qx * qz + qw * qy)
        R12 = 2.0 * (qy * qz - qw * qx)
        R22 = 1.0 - 2.0 * (qx * qx + qy * qy)
        L, Ld, wx, wy = s[13], s[14], s[10], s[11]
        f = self.foot
        s[0] = f[0] + L * R02
        s[1] = f[1] + L * R12
        s[2] = f[2] + L * R22
        # v = L' b3 + L R (w x e3), w x e3 = (wy, -wx, 0)
        s[3] = Ld * R02 + L * (wy * R00 - wx * R01)
        s[4] = Ld * R12 + L * (wy * R10 - wx * R11)
        s[5] = Ld * R22 + L * (wy * R20 - wx * R21)

    # ------------------------------------------------------------------ events
    def _touchdown_fn(self, s: Sequence[float]) -> float:
        """Foot height above the ground (air phase), foot at r - L b3."""
        qx, qy = s[7], s[8]
        b3z = 1.0 - 2.0 * (qx * qx + qy * qy)
        return s[2] - s[13] * b3z - self.ground

    def _liftoff_fn(self, s: Sequence[float]) -> float:
        """Spring-damper leg force (stance); liftoff when it returns to zero."""
        return self._k * (self._L0 - s[13]) - self._c * s[14]

    def _touchdown_map(self, s: list[float]) -> list[float]:
        s = list(s)
        qw, qx, qy, qz = s[6], s[7], s[8], s[9]
        R = matrix_from_quat((qw, qx, qy, qz))
        v = (s[3], s[4], s[5])
        vb = [R[0][i] * v[0] + R[1][i] * v[1] + R[2][i] * v[2] for i in range(3)]
        wx, wy = s[10], s[11]
        L0, m = s[13], self._m
        # Foot velocity in body frame: v_b + w x (0, 0, -L0).
        vfx = vb[0] - L0 * wy
        vfy = vb[1] + L0 * wx
        # No-slip impulse perpendicular to the leg zeroes the foot's lateral velocity.
        jx = -vfx / (1.0 / m + L0 * L0 / self._iyy)
        jy = -vfy / (1.0 / m + L0 * L0 / self._ixx)
        vb[0] += jx / m
        vb[1] += jy / m
        s[10] = wx + L0 * jy / self._ixx
        s[11] = wy - L0 * jx / self._iyy
        # The foot stops: its (lumped) share of the axial momentum is lost.
        vb[2] *= 1.0 - self._mf / m
        for i in range(3):
            s[3 + i] = R[i][0] * vb[0] + R[i][1] * vb[1] + R[i][2] * vb[2]
        s[14] = vb[2]
        self.foot = np.array([s[0] - L0 * R[0][2], s[1] - L0 * R[1][2], s[2] - L0 * R[2][2]])
        self.foot[2] = self.ground
        return s

    def _liftoff_map(self, s: list[float]) -> list[float]:
        s = list(s)
        if self._snap:
            s[13] = self._L0
        s[14] = 0.0
        return s

    # ------------------------------------------------------------------ stepping
    def step(self, h: float, rotor_cmd: Sequence[float], ext: Sequence[float] = (0.0,) * 6) -> list[PlantEvent]:
        """Advance by h seconds with rotor speed commands held constant.

        Args:
            h: step [s].
            rotor_cmd: (4,) rotor speed commands [rad/s] (clipped to idle..max).
            ext: (6,) external force (world, N) and torque (body, N m) on the body.
        Returns:
            the hybrid events located inside the step (usually none).
        """
        wmin, wmax = self.params.omega_idle, self.params.omega_max
        cmd = [min(max(float(c), wmin), wmax) for c in rotor_cmd]
        ext = [float(e) for e in ext]
        events: list[PlantEvent] = []
        s = self.state.tolist()
        remaining = float(h)
        t = self.t
        for _ in range(8):  # more than a few events in one ms would be a bug (chattering)
            stance = self.mode == STANCE
            s1 = self._rk4(s, remaining, cmd, ext, stance)
            fn = self._liftoff_fn if stance else self._touchdown_fn
            g0, g1 = fn(s), fn(s1)
            if g1 > 0.0 or (g0 <= 0.0 and g1 > g0):
                # No crossing (or still leaving the switching surface right after an event).
                s = s1
                break
            if g0 > 0.0:
                theta = event_root_finder()(
                    lambda tau: fn(self._rk4(s, tau, cmd, ext, stance)),
                    0.0, remaining, xtol=1e-14, rtol=1e-14, maxiter=200,
                )
            else:
                theta = 0.0  # on the surface and moving the wrong way: switch at once
            se = self._rk4(s, theta, cmd, ext, stance) if theta > 0.0 else list(s)
            t_ev = t + theta
            if stance:
                s = self._liftoff_map(se)
                self.mode = AIR
                events.append(PlantEvent("liftoff", t_ev))
            else:
                s = self._touchdown_map(se)
                self.mode = STANCE
                events.append(PlantEvent("touchdown", t_ev))
            t = t_ev
            remaining = remaining - theta
            if remaining <= 1e-15:
                break
        else:
            raise HybridEventError(f"too many hybrid events within one step at t={self.t:.6f} s "
                                   f"({len(events)} touchdowns / liftoffs): the foot is chattering on the ground")
        self.state = np.array(s)
        self.t += h
        if self.mode == STANCE:
            bottomed = self._L0 - s[13] > self._cmax
            if bottomed and not self._bottomed:
                self.n_bottom_outs += 1
            self._bottomed = bottomed
        return events

    # ------------------------------------------------------------------ views
    @property
    def position(self) -> np.ndarray:
        return self.state[0:3].copy()

    @property
    def velocity(self) -> np.ndarray:
        return self.state[3:6].copy()

    @property
    def quaternion(self) -> np.ndarray:
        return self.state[6:10].copy()

    @property
    def rates(self) -> np.ndarray:
        return self.state[10:13].copy()

    @property
    def contact(self) -> bool:
        return self.mode == STANCE

    @property
    def leg_length(self) -> float:
        return float(self.state[13])

    def rotor_thrusts(self) -> np.ndarray:
        return self._kf * self.state[15:19] ** 2

    def foot_position(self) -> np.ndarray:
        if self.mode == STANCE:
            return self.foot.copy()
        R = np.array(matrix_from_quat(self.state[6:10]))
        return self.state[0:3] - self.state[13] * R[:, 2]

    def leg_force(self) -> float:
        """Axial leg force [N] (0 in the air)."""
        if self.mode != STANCE:
            return 0.0
        comp = self._L0 - self.state[13]
        f = self._k * comp - self._c * self.state[14]
        if comp > self._cmax:
            f += self._kb * (comp - self._cmax)
        return float(f)

    def energy(self) -> float:
        """Mechanical energy [J]: kinetic (translation + rotation) + gravity + leg spring."""
        s = self.state
        v = s[3:6]
        w = s[10:13]
        I = np.array(self.params.inertia)
        e = 0.5 * self._m * float(v @ v) + 0.5 * float(w @ (I * w)) + self._m * self._g * float(s[2])
        if self.mode == STANCE:
            comp = self._L0 - s[13]
            e += 0.5 * self._k * comp * comp
            if comp > self._cmax:
                e += 0.5 * self._kb * (comp - self._cmax) ** 2
        return e

