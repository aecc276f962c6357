"""The simulated robot below the companion computer: plant + PX4-like flight controller +
measurement model, advanced one 5 ms control tick at a time.

Both closed loops use it: :func:`ddpc_codegen.sim.simulate` (the companion controller in the
same process) and the simulated MAVLink vehicle ``ddpc-vehicle`` (the companion controller on
the other side of a link). One tick::

    stepper.measure(t)                  delayed (params.meas_delay), noisy state -> MeasuredState
    stepper.advance((q, thrust))        SET_ATTITUDE_TARGET, then `substeps` x {
                                           attitude loop every att_every steps (250 Hz),
                                           rate loop every rate_every steps (1 kHz),
                                           pushes -> external wrench, plant RK4 step (1 ms) }

A stuck hybrid integration (:class:`HybridEventError`, foot chattering) ends the stepping:
:attr:`Stepper.stuck` says why and :meth:`Stepper.advance` does nothing from then on.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from ddpc_codegen.robot.state import MeasuredState
from ddpc_codegen.robot.frames import euler_from_quat, matrix_from_quat
from ddpc_codegen.sim.flight_controller import PX4LikeFlightController
from ddpc_codegen.sim.params import PogoXParams, SensorNoise
from ddpc_codegen.sim.plant import STANCE, HybridEventError, PogoXPlant

__all__ = ["Push", "Stepper", "as_pushes", "as_noise", "external_wrench", "lost_reason"]


@dataclass(frozen=True)
class Push:
    """An external force impulse: ``force`` (3,) [N, world] during [t, t + duration) [s],
    applied at ``point`` (3,) [m, body frame; default the COM, e.g. (0, 0, -0.3) on the leg]."""

    t: float
    force: tuple[float, float, float]
    duration: float = 0.1
    point: tuple[float, float, float] = (0.0, 0.0, 0.0)


def as_pushes(pushes: Sequence[Push | tuple] | None) -> list[Push]:
    """:class:`Push` objects from Push objects or tuples (t, force(3), duration[, point(3)])."""
    out = []
    for p in pushes or ():
        if isinstance(p, Push):
            out.append(p)
        else:
            t, f, *rest = p
            dur = rest[0] if rest else 0.1
            pt = tuple(rest[1]) if len(rest) > 1 else (0.0, 0.0, 0.0)
            out.append(Push(float(t), tuple(float(v) for v in f), float(dur), pt))
    return out


def as_noise(noise: SensorNoise | bool | None) -> SensorNoise | None:
    """A :class:`SensorNoise` from True (defaults), False / None (no noise) or itself."""
    if noise is None or noise is False:
        return None
    if noise is True:
        return SensorNoise()
    if isinstance(noise, SensorNoise):
        return noise
    raise TypeError(f"noise must be a SensorNoise, True/False or None; got {noise!r}")


def external_wrench(pushes: list[Push], t: float, s: Sequence[float]) -> tuple[float, ...]:
    """(fx, fy, fz [N, world], tx, ty, tz [N m, body]) of the pushes active at time t [s] on
    a body with state s (19,) (only the quaternion s[6:10] is used, for off-COM points)."""
    fx = fy = fz = 0.0
    tx = ty = tz = 0.0
    for p in pushes:
        if p.t <= t < p.t + p.duration:
            fx += p.force[0]
            fy += p.force[1]
            fz += p.force[2]
            if any(p.point):
                R = matrix_from_quat(s[6:10])
                # Force in the body frame (R^T f), torque = point x f_body.
                fb = [R[0][i] * p.force[0] + R[1][i] * p.force[1] + R[2][i] * p.force[2] for i in range(3)]
                px, py, pz = p.point
                tx += py * fb[2] - pz * fb[1]
                ty += pz * fb[0] - px * fb[2]
                tz += px * fb[1] - py * fb[0]
    return (fx, fy, fz, tx, ty, tz)


def lost_reason(state: np.ndarray) -> str:
    """Why the robot with plant state (19,) is lost ("" while it is not): non-finite state, tilt
    above 70 deg, or the body below 0.1 m."""
    s = state
    if not np.all(np.isfinite(s)):
        return "non-finite state"
    qx, qy = s[7], s[8]
    b3z = 1.0 - 2.0 * (qx * qx + qy * qy)
    if b3z < math.cos(math.radians(70.0)):
        return "tilt above 70 deg"
    if s[2] < 0.1:
        return "body below 0.1 m"
    return ""


class Stepper:
    """Plant + flight controller + measurement delay + sensor noise (see the module docstring).

    Args:
        params: the true robot (:class:`PogoXParams`).
        position: (3,) start position [m, ENU]; quaternion: (4,) start attitude (w, x, y, z).
        noise: sensor noise (:class:`SensorNoise`, True for the defaults, None/False for none).
        seed: seeds the noise generator (normal draws in the order position, velocity, angle, rate).
        pushes: :class:`Push` objects or tuples, in plant time [s].
        history: keep this many extra physics steps of measurement history [s] (for
            :meth:`measure` of samples older than now; 0: only what the delay needs).
    """

    def __init__(
        self,
        params: PogoXParams,
        position: Sequence[float],
        *,
        quaternion: Sequence[float] = (1.0, 0.0, 0.0, 0.0),
        noise: SensorNoise | bool | None = None,
        seed: int = 0,
        pushes: Sequence[Push | tuple] | None = None,
        history: float = 0.0,
    ) -> None:
        self.params = params
        self.h = params.physics_dt
        self.substeps = params.substeps
        self.plant = PogoXPlant(params)
        self.plant.reset(position, quaternion=quaternion)
        self.fc = PX4LikeFlightController(params)
        self.att_every = max(1, int(round(params.fc.rate_hz / params.fc.att_hz)))
        self.rate_every = max(1, int(round(1.0 / (params.fc.rate_hz * self.h))))
        self.noise = as_noise(noise)
        self.rng = np.random.default_rng(seed)
        self.pushes = as_pushes(pushes)
        # Delayed measurements: ring of (t, state list, mode), one per physics step; entry
        # -(delay_steps + 1) is the state params.meas_delay ago.
        self.delay_steps = int(round(params.meas_delay / self.h))
        self._buf: deque = deque(maxlen=self.delay_steps + int(round(history / self.h)) + 1)
        self._buf.append((0.0, self.plant.state.tolist(), self.plant.mode))
        self._cmd: list[float] = [params.hover_omega] * 4
        self.step_count = 0
        self.touchdowns: list[float] = []
        self.liftoffs: list[float] = []
        self.stuck = ""

    # ------------------------------------------------------------------ measurement
    def measure(self, t: float, age: float = 0.0) -> MeasuredState:
        """The companion's view at time t [s]: the state ``meas_delay`` before t, plus noise.

        age: the sample is this much older than the newest physics step [s] (whole steps,
        at most the ``history`` asked for; the oldest kept state before that).
        """
        back = self.delay_steps + (int(round(age / self.h)) if age > 0.0 else 0)
        _tm, sm, mode_m = self._buf[max(0, len(self._buf) - 1 - back)]
        pos = np.array(sm[0:3])
        vel = np.array(sm[3:6])
        eul = euler_from_quat(sm[6:10])
        rates = np.array(sm[10:13])
        n = self.noise
        if n is not None:
            rng = self.rng
            pos = pos + rng.normal(0.0, n.position, 3)
            vel = vel + rng.normal(0.0, n.velocity, 3)
            eul = eul + rng.normal(0.0, n.angle, 3)
            rates = rates + rng.normal(0.0, n.rate, 3)
        return MeasuredState(t=t, position=pos, velocity=vel, euler=eul, body_rates=rates, contact=mode_m == STANCE)

    # ------------------------------------------------------------------ stepping
    def set_setpoint(self, q: Sequence[float], thrust: float) -> None:
        """SET_ATTITUDE_TARGET: attitude (w, x, y, z) body FLU -> world ENU, normalized thrust [0, 1]."""
        self.fc.set_attitude_target(q, thrust)

    def advance(
        self,
        setpoint: tuple[Sequence[float], float] | None = None,
        before_substep: Callable[[int], None] | None = None,
    ) -> None:
        """Simulate one control tick (``substeps`` physics steps).

        Args:
            setpoint: (q (4,), thrust) applied before the first step (None: keep the current one).
            before_substep: called with the step index j before step j (a setpoint that arrives
                mid-tick takes effect at the next 1 ms step, as on PX4's 1 kHz rate loop).
        """
        if setpoint is not None:
            self.fc.set_attitude_target(*setpoint)
        for j in range(self.substeps):
            if self.stuck:
                return  # the plant cannot go on
            if before_substep is not None:
                before_substep(j)
            self.substep()

    def substep(self) -> None:
        """One physics step: inner loops at their rates, pushes, plant RK4 with event location."""
        plant, fc = self.plant, self.fc
        s = plant.state
        if self.step_count % self.att_every == 0:
            fc.attitude_update(s[6:10])
        if self.step_count % self.rate_every == 0:
            self._cmd = fc.rate_update(s[10:13], self.h * self.rate_every)
        ext = external_wrench(self.pushes, plant.t, s) if self.pushes else (0.0,) * 6
        try:
            events = plant.step(self.h, self._cmd, ext)
        except HybridEventError as err:
            self.stuck = str(err)
            return
        for ev in events:
            (self.touchdowns if ev.kind == "touchdown" else self.liftoffs).append(ev.t)
        self.step_count += 1
        self._buf.append((plant.t, plant.state.tolist(), plant.mode))

    def lost(self) -> str:
        """Why the robot is lost now ("" while it is not), see :func:`lost_reason`."""
        return lost_reason(self.plant.state)
