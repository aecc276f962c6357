"""Closed-loop simulation at 200 Hz: companion controller -> PX4-like FC (1 kHz) -> hybrid plant.

One control tick (dt = 5 ms, zero-order hold on the setpoint)::

    measured state (delayed, noisy)                                    ┐ companion computer
    r_nom = controller.nominal_reference(state)        stage (a)       │
    u     = reference_hook(ctx) or r_nom               steering slot   │
    u    += excitation[k]                              PRBS, data collection
    sp    = controller.track(u, state)                 stage (b)       ┘
    PX4: set_attitude_target(sp.q, sp.thrust); 5 x { attitude loop @250 Hz, rate loop @1 kHz,
         plant RK4 step of 1 ms with event location }

Logged per tick k (time-major arrays, see :class:`SimResult`): y[k] is the measurement the
tick-k decision was based on and u[k] the reference applied from t_k to t_k + dt, so u[k]
influences y[k+1], y[k+2], ... (a strictly proper closed loop).
"""

from __future__ import annotations

import math
import sys
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np

from ddpc_codegen.design.phases import ASCENT, DESCENT, GROUND, PHASE_NAMES
from ddpc_codegen.robot.controller import ControllerConfig, HeightLegAngleController, MeasuredState
from ddpc_codegen.robot.frames import euler_from_quat
from ddpc_codegen.design.data import IODataset, prbs
from ddpc_codegen.sim.flight_controller import PX4LikeFlightController
from ddpc_codegen.sim.params import PogoXParams, SensorNoise
from ddpc_codegen.sim.plant import STANCE, HybridEventError, PogoXPlant
from ddpc_codegen.sim.scenarios import FlyingScenario, Scenario, get_scenario

__all__ = ["simulate", "SimResult", "TickContext", "Push", "Excitation"]


# ----------------------------------------------------------------------------- inputs
@dataclass(frozen=True)
class Push:
    """An external force impulse: ``force`` (3,) [N, world] during [t, t + duration) [s],
    applied at ``point`` (3,) [m, body frame; default the COM, e.g. (0, 0, -0.3) on the leg]."""

    t: float
    force: tuple[float, float, float]
    duration: float = 0.1
    point: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class Excitation:
    """PRBS excitation added to the references for data collection.

    Attributes:
        amplitude: per-channel amplitude (m for z, rad for angles), scalar or (m,).
        min_hold: ticks each PRBS bit is held (4 ticks = 20 ms).
        seed: PRBS seed (None: derived from the simulation seed).
        aerial_only: hopping: excite only outside the ground phase (the ground phase keeps
            the spring leg's natural dynamics; its samples are replaced by artificial IO anyway).
    """

    amplitude: float | Sequence[float] = 0.03
    min_hold: int = 4
    seed: int | None = None
    aerial_only: bool = True

    def signal(self, n_ticks: int, m: int, seed: int) -> np.ndarray:
        """(n_ticks, m) PRBS."""
        amp = np.broadcast_to(np.asarray(self.amplitude, dtype=float), (m,))
        return prbs(n_ticks, m, amplitude=amp, min_hold=self.min_hold, seed=self.seed if self.seed is not None else seed)


def default_excitation(scenario: str) -> Excitation:
    """PRBS amplitudes that excite the loop visibly without saturating the thrust."""
    if scenario == "flying":
        return Excitation(amplitude=(0.05, 0.03), min_hold=4)
    return Excitation(amplitude=(0.01, 0.02, 0.02), min_hold=4)


# ----------------------------------------------------------------------------- hook context
@dataclass
class TickContext:
    """What the reference hook sees at control tick k.

    Attributes:
        k: tick index; t: time [s]; dt: control period [s].
        scenario: "flying" or "hopping".
        r_nom: (m,) nominal references from stage (a).
        y: (p,) measured outputs now.
        y_des: (p,) desired outputs now.
        phase: phase label (FLYING / DESCENT / GROUND / ASCENT, see :data:`PHASE_NAMES`).
        state: the measured :class:`MeasuredState`.
        u_log: (k, m) references applied at ticks 0..k-1 (read-only view).
        y_log: (k+1, p) measured outputs at ticks 0..k (the last row is ``y``).
        phase_log: (k+1,) phase labels at ticks 0..k.
        input_names / output_names: channel names.
    """

    k: int
    t: float
    dt: float
    scenario: str
    r_nom: np.ndarray
    y: np.ndarray
    y_des: np.ndarray
    phase: int
    state: MeasuredState
    u_log: np.ndarray
    y_log: np.ndarray
    phase_log: np.ndarray
    input_names: tuple[str, ...]
    output_names: tuple[str, ...]
    _controller: HeightLegAngleController = field(repr=False)

    @property
    def phase_name(self) -> str:
        return PHASE_NAMES[int(self.phase)]

    def desired(self, t: float | np.ndarray) -> np.ndarray:
        """Desired outputs at arbitrary time(s) t [s]: (p,) or (n, p)."""
        return self._controller.desired_outputs(t)

    def desired_ahead(self, n: int, start: int = 0) -> np.ndarray:
        """(n, p) desired outputs at ticks k+start, ..., k+start+n-1."""
        ts = self.t + self.dt * (start + np.arange(n))
        return np.atleast_2d(self._controller.desired_outputs(ts))

    def phases_ahead(self, n: int, start: int = 0) -> np.ndarray:
        """(n,) predicted phase labels at ticks k+start, ..., k+start+n-1 (nominal hop cycle)."""
        ts = self.t + self.dt * (start + np.arange(n))
        return self._controller.predict(ts)[1]


ReferenceHook = Callable[[TickContext], "np.ndarray | Sequence[float] | None"]


# ----------------------------------------------------------------------------- result
@dataclass
class SimResult:
    """Time-major logs of one closed-loop run (N control ticks).

    Attributes:
        scenario: "flying" / "hopping"; dt: control period [s].
        t: (N,) tick times [s].
        state: (N, 19) true plant state at the tick (see :mod:`ddpc_codegen.sim.plant`).
        u: (N, m) references actually applied (after hook and excitation).
        r_nom: (N, m) nominal references (stage a).
        excitation: (N, m) the PRBS part of u (zeros if none).
        y: (N, p) measured outputs (delayed, noisy); y_true: (N, p) true outputs at t.
        y_des: (N, p) desired outputs.
        phase: (N,) int8 phase labels (controller's estimate); contact: (N,) true contact.
        setpoint_q: (N, 4) attitude setpoints (w, x, y, z) ENU/FLU; setpoint_thrust: (N,) normalized;
        setpoint_euler: (N, 3) commanded roll, pitch, yaw.
        touchdowns, liftoffs: event times [s] located by the plant.
        extras: scenario-specific logs (flying: "x_des", "z_des" of the ellipse).
        crashed: True if the robot was lost (tilt > 70 deg, body near the ground, NaN state, or the
            hybrid integration stuck in foot chattering); crash_reason says which, and when.
    """

    scenario: str
    dt: float
    t: np.ndarray
    state: np.ndarray
    u: np.ndarray
    r_nom: np.ndarray
    excitation: np.ndarray
    y: np.ndarray
    y_true: np.ndarray
    y_des: np.ndarray
    phase: np.ndarray
    contact: np.ndarray
    setpoint_q: np.ndarray
    setpoint_thrust: np.ndarray
    setpoint_euler: np.ndarray
    touchdowns: np.ndarray
    liftoffs: np.ndarray
    input_names: tuple[str, ...]
    output_names: tuple[str, ...]
    input_units: tuple[str, ...]
    output_units: tuple[str, ...]
    params: PogoXParams
    config: ControllerConfig
    scenario_obj: Any
    seed: int
    crashed: bool = False
    crash_reason: str = ""
    n_bottom_outs: int = 0
    wall_time: float = 0.0
    extras: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def n(self) -> int:
        return int(self.t.shape[0])

    @property
    def position(self) -> np.ndarray:
        """(N, 3) true position [m]."""
        return self.state[:, 0:3]

    @property
    def velocity(self) -> np.ndarray:
        """(N, 3) true velocity [m/s]."""
        return self.state[:, 3:6]

    @property
    def euler(self) -> np.ndarray:
        """(N, 3) true roll, pitch, yaw [rad]."""
        return np.array([euler_from_quat(q) for q in self.state[:, 6:10]])

    def metrics(self) -> dict[str, Any]:
        """Tracking metrics (see :mod:`ddpc_codegen.sim.metrics`)."""
        from ddpc_codegen.sim.metrics import compute_metrics

        return compute_metrics(self)

    def to_dataset(self, split: str = "auto", *, t_min: float | None = None, metadata: dict | None = None) -> IODataset:
        """The IO data (u applied, y measured) as an :class:`IODataset` with phase labels.

        Args:
            split: "none" (one trajectory), "hops" (hopping: apex-to-apex segments, each with
                descent / ground / ascent -- what artificial-IO generation needs), "aerial"
                (hopping: liftoff-to-touchdown segments only), "auto" (flying: none, hopping: hops).
            t_min: drop samples (flying) / segments (hopping) starting before this time [s]
                (default: the scenario's settle time / settle hops).
        """
        if split == "auto":
            split = "none" if self.scenario == "flying" else "hops"
        n = self.n
        if t_min is None:
            if self.scenario == "flying":
                t_min = getattr(self.scenario_obj, "settle_time", 0.0)
            else:
                t_min = 0.0
        segments: list[tuple[int, int]] = []
        if split == "none":
            k0 = int(np.searchsorted(self.t, t_min - 1e-12))
            segments = [(k0, n)]
        elif split == "hops":
            ph = self.phase
            # Apexes: ascent -> descent transitions (and the release at rest at k = 0).
            apex = [0] + [k for k in range(1, n) if ph[k - 1] == ASCENT and ph[k] == DESCENT]
            for a, b in zip(apex[:-1], apex[1:]):
                if self.t[a] >= t_min - 1e-12 and np.any(ph[a:b] == GROUND):
                    segments.append((a, b))
        elif split == "aerial":
            ground = self.phase == GROUND
            k = 0
            while k < n:
                if ground[k]:
                    k += 1
                    continue
                j = k
                while j < n and not ground[j]:
                    j += 1
                # Only complete aerial phases (ending in a touchdown) unless it is the last one.
                if self.t[k] >= t_min - 1e-12 and j - k >= 2:
                    segments.append((k, j))
                k = j
        else:
            raise ValueError(f"split must be 'auto', 'none', 'hops' or 'aerial'; got {split!r}")
        if not segments:
            from ddpc_codegen.errors import DataError

            raise DataError(
                f"no {split!r} segments in this {self.scenario} run of {self.t[-1] if n else 0:.2f} s "
                f"(t_min={t_min}); simulate longer"
            )
        meta = {
            "source": "ddpc_codegen.sim",
            "scenario": self.scenario,
            "split": split,
            "seed": self.seed,
            "segments_ticks": [[int(a), int(b)] for a, b in segments],
            "controller_model_mass": self.config.model_mass,
            "true_mass": self.params.mass,
            "phase_labels": {str(k): v for k, v in PHASE_NAMES.items()},
        }
        meta.update(metadata or {})
        return IODataset(
            [self.u[a:b] for a, b in segments],
            [self.y[a:b] for a, b in segments],
            self.dt,
            input_names=self.input_names,
            output_names=self.output_names,
            input_units=self.input_units,
            output_units=self.output_units,
            phases=[self.phase[a:b] for a, b in segments],
            metadata=meta,
        )


# ----------------------------------------------------------------------------- simulate
def _as_pushes(pushes: Sequence[Push | tuple] | None) -> list[Push]:
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


def _as_noise(noise: SensorNoise | bool | None) -> SensorNoise | None:
    if noise is None or noise is False:
        return None
    if noise is True:
        return SensorNoise()
    if isinstance(noise, SensorNoise):
        return noise
    raise TypeError(f"noise must be a SensorNoise, True/False or None; got {noise!r}")


def simulate(
    scenario: str | Scenario = "flying",
    duration: float = 30.0,
    *,
    params: PogoXParams | None = None,
    seed: int = 0,
    reference_hook: ReferenceHook | None = None,
    excitation: Excitation | np.ndarray | bool | None = None,
    noise: SensorNoise | bool | None = None,
    pushes: Sequence[Push | tuple] | None = None,
    progress: bool = False,
    stop_on_crash: bool = True,
) -> SimResult:
    """Run the closed loop for ``duration`` seconds and return the logs.

    Args:
        scenario: "flying", "hopping" or a :class:`FlyingScenario` / :class:`HoppingScenario`.
        duration: simulated time [s] (N = round(duration / control_dt) ticks).
        params: true robot parameters (default :class:`PogoXParams`, controller mass 200 g low).
        seed: seeds the sensor noise and (unless given) the PRBS; runs are deterministic.
        reference_hook: called once per tick with a :class:`TickContext`; returns the references
            u (m,) fed to stage (b), or None to use r_nom.
        excitation: PRBS on the references: an :class:`Excitation`, an (N, m) array added as is,
            True (the scenario's default amplitudes) or None.
        noise: sensor noise (:class:`SensorNoise`, True for the defaults, None/False for none).
            The measurement delay ``params.meas_delay`` applies either way.
        pushes: :class:`Push` objects or tuples (t, force(3), duration[, point(3)]).
        progress: tqdm progress bar on stderr.
        stop_on_crash: end the run early when the robot is lost (``SimResult.crashed``).
    """
    t_wall = time.perf_counter()
    params = params or PogoXParams()
    sc = get_scenario(scenario)
    ctrl = sc.make_controller(params)
    m, p = ctrl.m, ctrl.p
    dt = params.control_dt
    h = params.physics_dt
    nsub = params.substeps
    n_ticks = int(round(duration / dt))
    if n_ticks <= 0:
        raise ValueError(f"duration must be > 0; got {duration}")
    rng = np.random.default_rng(seed)
    noise_p = _as_noise(noise)

    # Excitation signal.
    exc = np.zeros((n_ticks, m))
    aerial_only = True
    if excitation is True:
        excitation = default_excitation(sc.name)
    if isinstance(excitation, Excitation):
        exc = excitation.signal(n_ticks, m, seed=seed + 7919)
        aerial_only = excitation.aerial_only
    elif excitation is not None and excitation is not False:
        arr = np.asarray(excitation, dtype=float)
        if arr.ndim == 1 and m == 1:
            arr = arr[:, None]
        if arr.ndim != 2 or arr.shape[1] != m or arr.shape[0] < n_ticks:
            raise ValueError(f"excitation array must be ({n_ticks}, {m}); got {arr.shape}")
        exc = arr[:n_ticks].copy()

    # Plant and inner loops.
    plant = PogoXPlant(params)
    x0, y0, z0 = sc.initial_position(params)
    plant.reset([x0, y0, z0])
    fc = PX4LikeFlightController(params)
    ctrl.reset(0.0, z0 if sc.name == "hopping" else None)
    att_every = max(1, int(round(params.fc.rate_hz / params.fc.att_hz)))
    rate_every = max(1, int(round(1.0 / (params.fc.rate_hz * h))))
    pushes_l = _as_pushes(pushes)

    # Delayed measurements: ring of (t, state list, mode) per physics step.
    d_steps = int(round(params.meas_delay / h))
    buf: deque = deque(maxlen=d_steps + 1)
    buf.append((0.0, plant.state.tolist(), plant.mode))

    # Logs.
    T = np.zeros(n_ticks)
    S = np.zeros((n_ticks, plant.state.shape[0]))
    U = np.zeros((n_ticks, m))
    RN = np.zeros((n_ticks, m))
    EX = np.zeros((n_ticks, m))
    Y = np.zeros((n_ticks, p))
    YT = np.zeros((n_ticks, p))
    YD = np.zeros((n_ticks, p))
    PH = np.zeros(n_ticks, dtype=np.int8)
    CT = np.zeros(n_ticks, dtype=bool)
    QS = np.zeros((n_ticks, 4))
    TS = np.zeros(n_ticks)
    ES = np.zeros((n_ticks, 3))
    touchdowns: list[float] = []
    liftoffs: list[float] = []
    crashed = False
    crash_reason = ""
    stuck = ""

    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=n_ticks, file=sys.stderr, desc=f"simulate {sc.name}", unit="tick", leave=False)

    step_count = 0
    k_done = 0
    for k in range(n_ticks):
        t = k * dt
        # ---- measurement (delayed, noisy)
        tm, sm, mode_m = buf[0]
        pos = np.array(sm[0:3])
        vel = np.array(sm[3:6])
        eul = euler_from_quat(sm[6:10])
        rates = np.array(sm[10:13])
        if noise_p is not None:
            pos = pos + rng.normal(0.0, noise_p.position, 3)
            vel = vel + rng.normal(0.0, noise_p.velocity, 3)
            eul = eul + rng.normal(0.0, noise_p.angle, 3)
            rates = rates + rng.normal(0.0, noise_p.rate, 3)
        meas = MeasuredState(t=t, position=pos, velocity=vel, euler=eul, body_rates=rates, contact=mode_m == STANCE)

        # ---- companion computer
        r_nom = ctrl.nominal_reference(meas)
        y_meas = ctrl.outputs(meas)
        phase = ctrl.phase
        Y[k] = y_meas
        PH[k] = phase
        u = r_nom
        if reference_hook is not None:
            u_view, y_view, ph_view = U[:k], Y[: k + 1], PH[: k + 1]
            for v in (u_view, y_view, ph_view):
                v.flags.writeable = False
            ctx = TickContext(
                k=k, t=t, dt=dt, scenario=sc.name, r_nom=r_nom.copy(), y=y_meas.copy(),
                y_des=ctrl.y_des.copy(), phase=int(phase), state=meas,
                u_log=u_view, y_log=y_view, phase_log=ph_view,
                input_names=ctrl.input_names, output_names=ctrl.output_names, _controller=ctrl,
            )
            out = reference_hook(ctx)
            if out is not None:
                u = np.asarray(out, dtype=float).reshape(m)
                if not np.all(np.isfinite(u)):
                    raise ValueError(f"reference_hook returned non-finite references {u} at tick {k}")
        e = exc[k]
        if aerial_only and phase == GROUND:
            e = np.zeros(m)
        u = u + e
        sp = ctrl.track(u, meas)
        fc.set_attitude_target(sp.q, sp.thrust)

        # ---- log (true state at the tick)
        s_true = plant.state
        T[k] = t
        S[k] = s_true
        U[k] = u
        RN[k] = r_nom
        EX[k] = e
        YD[k] = ctrl.y_des
        e_true = euler_from_quat(s_true[6:10])
        YT[k] = (s_true[2], e_true[1]) if m == 2 else (s_true[2], e_true[0], e_true[1])
        CT[k] = plant.mode == STANCE
        QS[k] = sp.q
        TS[k] = sp.thrust
        ES[k] = sp.euler

        # ---- flight controller + physics, 1 kHz
        for _ in range(nsub):
            s = plant.state
            if step_count % att_every == 0:
                fc.attitude_update(s[6:10])
            if step_count % rate_every == 0:
                cmd = fc.rate_update(s[10:13], h * rate_every)
            ext = _external(pushes_l, plant.t, s) if pushes_l else (0.0,) * 6
            try:
                events = plant.step(h, cmd, ext)
            except HybridEventError as exc:
                stuck = str(exc)
                break
            for ev in events:
                (touchdowns if ev.kind == "touchdown" else liftoffs).append(ev.t)
            step_count += 1
            buf.append((plant.t, plant.state.tolist(), plant.mode))
        k_done = k + 1
        if bar is not None and (k % 50 == 0 or k == n_ticks - 1):
            bar.update(k + 1 - bar.n)
        if stuck:
            crashed, crash_reason = True, crash_reason or stuck
            break  # the plant cannot go on, whatever stop_on_crash says
        lost = _lost(plant)
        if lost and not crashed:
            crashed = True
            crash_reason = f"{lost} at t={plant.t:.3f} s"
        if lost and stop_on_crash:
            break
    if bar is not None:
        bar.close()

    sl = slice(0, k_done)
    extras: dict[str, np.ndarray] = {}
    if isinstance(sc, FlyingScenario):
        d = sc.ellipse.sample(T[sl])
        extras["x_des"] = np.asarray(d["x"])
        extras["z_des"] = np.asarray(d["z"])
    return SimResult(
        scenario=sc.name,
        dt=dt,
        t=T[sl],
        state=S[sl],
        u=U[sl],
        r_nom=RN[sl],
        excitation=EX[sl],
        y=Y[sl],
        y_true=YT[sl],
        y_des=YD[sl],
        phase=PH[sl],
        contact=CT[sl],
        setpoint_q=QS[sl],
        setpoint_thrust=TS[sl],
        setpoint_euler=ES[sl],
        touchdowns=np.array(touchdowns),
        liftoffs=np.array(liftoffs),
        input_names=ctrl.input_names,
        output_names=ctrl.output_names,
        input_units=ctrl.input_units,
        output_units=ctrl.output_units,
        params=params,
        config=ctrl.config,
        scenario_obj=sc,
        seed=seed,
        crashed=crashed,
        crash_reason=crash_reason,
        n_bottom_outs=plant.n_bottom_outs,
        wall_time=time.perf_counter() - t_wall,
        extras=extras,
    )


def _external(pushes: list[Push], t: float, s: np.ndarray) -> tuple[float, ...]:
    fx = fy = fz = 0.0
    tx = ty = tz = 0.0
    for p in pushes:
        if p.t <= t < p.t + p.duration:
            fx += p.force[0]
            fy += p.force[1]
            fz += p.force[2]
            if any(p.point):
                qw, qx, qy, qz = s[6:10]
                # Force in the body frame (R^T f), torque = point x f_body.
                R = (
                    (1 - 2 * (qy * qy + qz * qz), 2 * (qx * qy - qw * qz), 2 * (qx * qz + qw * qy)),
                    (2 * (qx * qy + qw * qz), 1 - 2 * (qx * qx + qz * qz), 2 * (qy * qz - qw * qx)),
                    (2 * (qx * qz - qw * qy), 2 * (qy * qz + qw * qx), 1 - 2 * (qx * qx + qy * qy)),
                )
                fb = [R[0][i] * p.force[0] + R[1][i] * p.force[1] + R[2][i] * p.force[2] for i in range(3)]
                px, py, pz = p.point
                tx += py * fb[2] - pz * fb[1]
                ty += pz * fb[0] - px * fb[2]
                tz += px * fb[1] - py * fb[0]
    return (fx, fy, fz, tx, ty, tz)


def _lost(plant: PogoXPlant) -> str:
    """Why the robot is lost ("" while it is not)."""
    s = plant.state
    if not np.all(np.isfinite(s)):
        return "non-finite state"
    qx, qy = s[7], s[8]
    b3z = 1.0 - 2.0 * (qx * qx + qy * qy)
    if b3z < math.cos(math.radians(70.0)):
        return "tilt above 70 deg"
    if s[2] < 0.1:
        return "body below 0.1 m"
    return ""
