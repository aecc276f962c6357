"""PogoX "height and leg angle controller" -- the companion-computer side.

This is the model-based controller of the paper (section "Flying Dynamics and Controller",
"Hopping Control Design"): a PD on height that outputs the total thrust using the
controller's *model* mass, and leg angles (= body roll/pitch) from a horizontal PD (flying)
or Raibert foot placement (hopping). It sends PX4 what PX4's SET_ATTITUDE_TARGET carries:
an attitude quaternion and a normalized collective thrust in [0, 1].

It imports nothing from :mod:`ddpc_codegen.sim`: the same code runs in the simulator and, through
the MAVLink bridge, on the robot's companion computer. It works from a :class:`MeasuredState`.

Two stages, so that reference steering can be inserted between them::

    desired trajectory + measured state --(a) nominal_reference()--> r_nom (m,)
    r_nom --[steering layer may replace it by u]--> u (m,)
    u + measured state --(b) track()--> AttitudeTarget (quaternion + normalized thrust)

The closed loop seen by the steering layer has input u (the references) and output y:

=========  ==============================  ===========================  ============
mode       u (inputs, m)                   y (outputs, p)               units
=========  ==============================  ===========================  ============
flying     [z_ref, pitch_ref]              [z, pitch]                   m, rad
hopping    [z_ref, roll_ref, pitch_ref]    [z, roll, pitch]             m, rad, rad
=========  ==============================  ===========================  ============

Frames. Everything here is z-up: world ENU (x east, y north, z up), body FLU (x forward,
y left, z up; the leg points along body -z). Euler angles are intrinsic Z-Y-X
(yaw psi, pitch theta, roll phi), R = Rz(psi) Ry(theta) Rx(phi), body -> world. Positive pitch
tilts the thrust axis towards +x; positive roll tilts it towards -y. Quaternions are (w, x, y, z),
body -> world. PX4 works in NED / FRD: :func:`~ddpc_codegen.robot.frames.quat_ned_frd_from_enu_flu` gives
q_NED_FRD = q_(ENU->NED) * q_ENU_FLU * q_(FRD->FLU) (the MAVROS convention), so roll keeps its
sign while pitch and the world yaw change sign/offset (yaw_NED = pi/2 - yaw_ENU). Normalized
thrust is frame independent (PX4 sets thrust_body = [0, 0, -thrust] in FRD).

Why the tracking stage is what it is (deliberately, the paper's model-based controller):

* Height: total thrust T = m_model (g + a_ff + kp (z_ref - z) + kd (v_ref - vz)) / (cos(phi_ref)
  cos(theta_ref)). No integrator, so a wrong model mass leaves a real steady height error --
  the model-to-real gap reference steering is meant to remove.
* v_ref is a low-pass filtered difference of the *applied* reference u (a linear filter of u),
  so the loop from u to y stays LTI; flying uses ``ref_velocity_gain = 0`` (D on the
  measurement only) so that PRBS steps on z_ref do not kick the thrust into saturation.
* a_ff is a constant: 0 when flying, -g_eff = -(1 - thrust_fraction) g when hopping (the
  robot hops in a "reduced gravity": a constant share of the model weight is carried by thrust,
  which also keeps attitude authority in the air). While the leg extends in stance (contact and
  vz > 0) a constant ``stance_boost`` is added: thrust along the leg does work there and replaces
  the leg-damping and touchdown losses (the role of the energy controller in the original PogoX).
* Normalized thrust = T / max_thrust, with ``max_thrust`` the controller's model of the
  collective thrust at normalized thrust 1 (see the flight controller's mapping).
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from ddpc_codegen.values.phases import ASCENT, DESCENT, FLYING, GROUND, PHASE_NAMES
from ddpc_codegen.robot.controller_config import ControllerConfig
from ddpc_codegen.robot.frames import quat_from_euler
from ddpc_codegen.robot.hop_cycle import spring_mass_stance, stance_height
from ddpc_codegen.robot.signals import OUTPUTS, REFERENCES
from ddpc_codegen.robot.state import AttitudeTarget, MeasuredState
from ddpc_codegen.robot.trajectory import EllipseTrajectory, Trajectory

__all__ = [
    "MeasuredState",
    "AttitudeTarget",
    "ControllerConfig",
    "HeightLegAngleController",
]

# ----------------------------------------------------------------------------- controller
class HeightLegAngleController:
    """Model-based height and leg angle controller with a steerable reference interface.

    Call once per control tick, in this order::

        r_nom = ctl.nominal_reference(state)   # stage (a); also updates the desired outputs
        u = steer(r_nom) or r_nom              # optional reference steering
        sp = ctl.track(u, state)               # stage (b) -> AttitudeTarget

    Stage (a), flying: z_ref = z of the ellipse; pitch_ref = atan((x'' + kp_xy (x_d - x) +
    kd_xy (x'_d - x')) / g) (the horizontal PD with the ellipse's acceleration as feedforward).
    Stage (a), hopping: in the air z_ref follows a ballistic arc of the reduced gravity g_eff,
    started at the measured liftoff (time, height) with the speed that reaches ``apex_height``;
    the leg angles place the foot Raibert-style, offset = v T_st/2 + K (v - v_d) + K_i sum_hops(v_avg
    - v_d); in stance the references are the measured outputs (the spring's natural dynamics).
    The desired outputs y_des equal r_nom at the current tick and are available ahead of time
    through :meth:`desired_outputs` / :meth:`predict`.

    Args:
        config: :class:`ControllerConfig`.
        trajectory: flying only, the desired path (any :class:`~ddpc_codegen.robot.trajectory.Trajectory`;
            default :class:`EllipseTrajectory`).
    """

    def __init__(self, config: ControllerConfig, trajectory: Trajectory | None = None) -> None:
        self.config = config
        self.trajectory = trajectory if (trajectory is not None or config.mode != "flying") else EllipseTrajectory()
        self.mode = config.mode
        self.input_names: tuple[str, ...] = REFERENCES[self.mode]
        self.output_names: tuple[str, ...] = OUTPUTS[self.mode]
        self.input_units = ("m",) + ("rad",) * (len(self.input_names) - 1)
        self.output_units = ("m",) + ("rad",) * (len(self.output_names) - 1)
        self.reset()

    # --------------------------------------------------------------- bookkeeping
    @property
    def m(self) -> int:
        """Number of references (closed-loop inputs)."""
        return len(self.input_names)

    @property
    def phase_name(self) -> str:
        return PHASE_NAMES[self.phase]

    @property
    def p(self) -> int:
        return len(self.output_names)

    def reset(self, t0: float = 0.0, z0: float | None = None) -> None:
        """Forget the filter and hop state. Hopping: the robot is released at rest at (t0, z0)."""
        c = self.config
        self._u_prev: float | None = None
        self._v_ref = 0.0
        self._contact_prev = False
        self.y_des = np.zeros(self.p)
        self.phase = FLYING if self.mode == "flying" else DESCENT
        self._pd_correction = 0.0  # flying: x-PD part of the pitch command, held for look-ahead
        self._pd_correction_y = 0.0
        self._yaw_des = 0.0  # flying: the path's heading now [rad, trajectory frame]
        self._t_now = -math.inf
        if self.mode == "hopping":
            apex0 = c.initial_apex if c.initial_apex is not None else c.apex_height
            if z0 is not None:
                apex0 = z0
            g = c.g_eff
            # The first arc is a release from rest: a virtual liftoff whose apex is (t0, apex0).
            v = math.sqrt(2.0 * g * max(apex0 - c.leg_length, 0.0))
            self._arc_t0 = t0 - v / g
            self._arc_z0 = apex0 - 0.5 * v * v / g
            self._arc_v0 = v
            self._in_stance = False
            self._t_touchdown = -math.inf
            self._hold_angles = np.zeros(2)  # roll, pitch reference of the current aerial phase
            self._v_int = np.zeros(2)  # integral of the per-hop velocity error
            self._td_xy: np.ndarray | None = None
            self._td_t = -math.inf
            self.n_touchdowns = 0
            self.n_liftoffs = 0

    # --------------------------------------------------------------- outputs
    def outputs(self, state: MeasuredState) -> np.ndarray:
        """Closed-loop outputs y (p,) from a measured state: [z, pitch] or [z, roll, pitch]."""
        if self.mode == "flying":
            return np.array([state.position[2], state.euler[1]])
        return np.array([state.position[2], state.euler[0], state.euler[1]])

    # --------------------------------------------------------------- stage (a)
    def nominal_reference(self, state: MeasuredState) -> np.ndarray:
        """Stage (a): desired trajectory + measured state -> nominal references r_nom (m,).

        Also updates ``self.y_des`` (desired outputs now) and ``self.phase``.
        """
        self._t_now = float(state.t)
        if self.mode == "flying":
            return self._nominal_flying(state)
        return self._nominal_hopping(state)

    def _nominal_flying(self, s: MeasuredState) -> np.ndarray:
        c = self.config
        d = self.trajectory.sample(s.t)
        # Horizontal PD + the path's acceleration, turned into the commanded heading's frame (yaw 0:
        # x forward, y left), so pitch tilts along the heading and roll across it.
        yaw = float(d["yaw"])
        cy, sy = math.cos(yaw), math.sin(yaw)
        ex = c.kp_xy * (float(d["x"]) - s.position[0]) + c.kd_xy * (float(d["vx"]) - s.velocity[0])
        ey = c.kp_xy * (float(d["y"]) - s.position[1]) + c.kd_xy * (float(d["vy"]) - s.velocity[1])
        corr = cy * ex + sy * ey
        ax = cy * float(d["ax"]) + sy * float(d["ay"])
        self._pd_correction = corr
        self._pd_correction_y = -sy * ex + cy * ey - sy * float(d["ax"]) + cy * float(d["ay"])
        self._yaw_des = yaw
        pitch = self._clip_tilt(math.atan2(ax + corr, c.g))
        r = np.array([float(d["z"]), pitch])
        self.y_des = r.copy()
        self.phase = FLYING
        return r

    def _arc(self, t: np.ndarray | float) -> np.ndarray:
        tau = np.asarray(t, dtype=float) - self._arc_t0
        return self._arc_z0 + self._arc_v0 * tau - 0.5 * self.config.g_eff * tau * tau

    def _start_arc(self, t: float, z: float) -> None:
        c = self.config
        g = c.g_eff
        self._arc_t0 = t
        self._arc_z0 = z
        self._arc_v0 = math.sqrt(2.0 * g * max(c.apex_height - z, 0.0))

    def _nominal_hopping(self, s: MeasuredState) -> np.ndarray:
        c = self.config
        if s.contact and not self._in_stance:
            self._in_stance = True
            self._t_touchdown = s.t
            self.n_touchdowns += 1
            # S2S-style integral: adapt the nominal foot placement once per step, on the
            # average velocity of the last cycle (touchdown to touchdown).
            xy = np.asarray(s.position[:2], dtype=float)
            if c.velocity_integral_gain > 0.0 and self._td_xy is not None and s.t > self._td_t + 1e-6:
                v_avg = (xy - self._td_xy) / (s.t - self._td_t)
                err = v_avg - np.asarray(c.target_velocity, dtype=float)
                self._v_int = np.clip(self._v_int + err, -5.0, 5.0)
            self._td_xy, self._td_t = xy, s.t
        elif not s.contact and self._in_stance:
            self._in_stance = False
            self.n_liftoffs += 1
            self._start_arc(s.t, float(s.position[2]))
        if self._in_stance:
            # Ground phase: desired = measured keeps the spring leg's natural dynamics.
            r = np.array([s.position[2], s.euler[0], s.euler[1]])
            self.phase = GROUND
        else:
            roll, pitch = self._leg_angles(s)
            self._hold_angles = np.array([roll, pitch])
            r = np.array([float(self._arc(s.t)), roll, pitch])
            self.phase = ASCENT if s.t < self._arc_t0 + self._arc_v0 / c.g_eff else DESCENT
        self.y_des = r.copy()
        return r

    def _leg_angles(self, s: MeasuredState) -> tuple[float, float]:
        """Raibert foot placement: foot offset = v T_st / 2 + K (v - v_d) + K_i sum(v - v_d)."""
        c = self.config
        v = np.asarray(s.velocity[:2], dtype=float)
        vd = np.asarray(c.target_velocity, dtype=float)
        t_st = self.nominal_stance_time()
        off = v * (0.5 * t_st) + c.raibert_gain * (v - vd) + c.velocity_integral_gain * c.raibert_gain * self._v_int
        lim = c.leg_length * math.sin(c.max_tilt)
        fx, fy = (float(np.clip(o, -lim, lim)) for o in off)
        # Foot relative to COM = -L b3, b3 = (cos(roll) sin(pitch), -sin(roll), cos(roll) cos(pitch)).
        roll = math.asin(fy / c.leg_length)
        pitch = -math.asin(fx / (c.leg_length * math.cos(roll)))
        return self._clip_tilt(roll), self._clip_tilt(pitch)

    def nominal_stance_time(self) -> float:
        """Stance duration of the model's vertical spring-mass at the target apex [s]."""
        c = self.config
        g = c.g_eff
        v_td = math.sqrt(2.0 * g * max(c.apex_height - c.leg_length, 0.0))
        return spring_mass_stance(v_td, c.model_mass, c.leg_stiffness, g)[0]

    def _clip_tilt(self, a: float) -> float:
        m = self.config.max_tilt
        return m if a > m else (-m if a < -m else a)

    # --------------------------------------------------------------- look-ahead
    def desired_outputs(self, t: np.ndarray | float) -> np.ndarray:
        """Desired outputs y_des at arbitrary (future) times t: (p,) for a scalar, (n, p) for an array.

        Flying: z from the ellipse, pitch = atan((x'' feedforward + current x-PD term) / g), so at
        the current tick it equals the nominal pitch reference. Hopping: the current ballistic arc
        (reduced gravity) until its predicted touchdown, then the model's nominal spring-mass
        stance and the next nominal arc, periodically; angles held at the current aerial command
        (the current measured ones during stance).
        """
        return self.predict(t)[0]

    def predict(self, t: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """(y_des, phase labels) at times t; see :meth:`desired_outputs`."""
        scalar = np.ndim(t) == 0
        ts = np.atleast_1d(np.asarray(t, dtype=float))
        n = ts.shape[0]
        c = self.config
        if self.mode == "flying":
            d = self.trajectory.sample(ts)
            y = np.empty((n, 2))
            y[:, 0] = d["z"]
            a_fwd = np.cos(d["yaw"]) * d["ax"] + np.sin(d["yaw"]) * d["ay"]
            y[:, 1] = np.clip(np.arctan2(a_fwd + self._pd_correction, c.g), -c.max_tilt, c.max_tilt)
            ph = np.full(n, FLYING, dtype=np.int8)
        else:
            y, ph = self._predict_hopping(ts)
        if scalar:
            return y[0], ph[0]
        return y, ph

    def _predict_hopping(self, ts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        c = self.config
        g = c.g_eff
        L0 = c.leg_length
        n = ts.shape[0]
        y = np.empty((n, 3))
        y[:, 1:] = self.y_des[1:] if self._in_stance else self._hold_angles
        ph = np.empty(n, dtype=np.int8)
        v_nom = math.sqrt(2.0 * g * max(c.apex_height - L0, 0.0))
        t_st, z_off = spring_mass_stance(v_nom, c.model_mass, c.leg_stiffness, g)
        w = math.sqrt(c.leg_stiffness / c.model_mass)
        t_air = 2.0 * v_nom / g
        period = t_st + t_air
        now = self._t_now
        if self._in_stance:
            # The current stance, assumed nominal from the measured touchdown, then nominal hops
            # starting with an arc.
            cur_end = max(self._t_touchdown + t_st, now)
            first_is_stance = False
        else:
            z0, v0 = self._arc_z0, self._arc_v0
            cur_end = self._arc_t0 + (v0 + math.sqrt(max(v0 * v0 + 2.0 * g * (z0 - L0), 0.0))) / g
            first_is_stance = True
        for i, t in enumerate(ts):
            if t <= now + 1e-9:
                y[i, 0] = self.y_des[0]
                ph[i] = self.phase
            elif t < cur_end:
                if self._in_stance:
                    y[i, 0] = stance_height(t - self._t_touchdown, L0, v_nom, w, z_off)
                    ph[i] = GROUND
                else:
                    tau = t - self._arc_t0
                    y[i, 0] = self._arc_z0 + self._arc_v0 * tau - 0.5 * g * tau * tau
                    ph[i] = ASCENT if tau < self._arc_v0 / g else DESCENT
            else:
                tc = (t - cur_end) % period
                if not first_is_stance:
                    tc = (tc + t_st) % period  # the cycle below starts with the stance
                if tc < t_st:
                    y[i, 0] = stance_height(tc, L0, v_nom, w, z_off)
                    ph[i] = GROUND
                else:
                    tau = tc - t_st
                    y[i, 0] = L0 + v_nom * tau - 0.5 * g * tau * tau
                    ph[i] = ASCENT if tau < v_nom / g else DESCENT
        return y, ph

    # --------------------------------------------------------------- stage (b)
    def track(self, u: Sequence[float], state: MeasuredState) -> AttitudeTarget:
        """Stage (b): references u (m,) + measured state -> attitude quaternion + normalized thrust.

        Call exactly once per tick (it advances the reference-derivative filter).
        """
        c = self.config
        u = np.asarray(u, dtype=float)
        z_ref = float(u[0])
        if self._u_prev is None or state.contact != self._contact_prev:
            # Bumpless transfer at touchdown/liftoff: the reference switches between the arc and
            # the measured height, a jump that must not kick the thrust (within a phase the
            # filter below is a plain linear filter of u).
            raw = float(state.velocity[2])
            self._v_ref = raw
        else:
            raw = (z_ref - self._u_prev) / c.dt
        self._u_prev = z_ref
        self._contact_prev = state.contact
        a = c.dt / (c.ref_velocity_tau + c.dt)
        self._v_ref += a * (raw - self._v_ref)
        gain = c.ref_velocity_gain
        if gain is None:
            gain = 0.0 if self.mode == "flying" else 1.0
        if self.mode == "flying":
            a_ff = 0.0
            roll = self._clip_tilt(-math.atan2(self._pd_correction_y, c.g))
            pitch = self._clip_tilt(float(u[1]))
        else:
            a_ff = -c.g_eff
            if state.contact and state.velocity[2] > 0.0:
                # Energy injection while the leg extends (replaces the spring/impact losses).
                a_ff += c.stance_boost
            roll = self._clip_tilt(float(u[1]))
            pitch = self._clip_tilt(float(u[2]))
        acc = c.g + a_ff + c.kp_z * (z_ref - state.position[2]) + c.kd_z * (gain * self._v_ref - state.velocity[2])
        tilt = max(math.cos(roll) * math.cos(pitch), math.cos(c.max_tilt))
        thrust_n = max(c.model_mass * acc / tilt, 0.0)
        thrust = min(thrust_n / c.max_thrust, 1.0)
        yaw = self._yaw_des if self.mode == "flying" else 0.0
        euler = np.array([roll, pitch, yaw])
        return AttitudeTarget(
            q=quat_from_euler(roll, pitch, yaw),
            thrust=thrust,
            thrust_newton=thrust * c.max_thrust,
            euler=euler,
        )

    def step(self, state: MeasuredState) -> AttitudeTarget:
        """Both stages without steering (the unsteered model-based controller)."""
        return self.track(self.nominal_reference(state), state)

