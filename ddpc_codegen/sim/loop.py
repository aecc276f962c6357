"""Closed-loop simulation at 200 Hz: companion controller -> PX4-like FC (1 kHz) -> hybrid plant.

One control tick (dt = 5 ms, zero-order hold on the setpoint)::

    measured state (delayed, noisy)                                    ┐ companion computer
    r_nom = controller.nominal_reference(state)        stage (a)       │
    u     = reference_hook(ctx) or r_nom               steering slot   │
    u    += excitation[k]                              PRBS, data collection
    sp    = controller.track(u, state)                 stage (b)       ┘
    stepper.advance((sp.q, sp.thrust))                 PX4 + plant, see :mod:`.stepper`:
         5 x { attitude loop @250 Hz, rate loop @1 kHz, plant RK4 step of 1 ms with event location }

Logged per tick k (time-major arrays, see :class:`SimResult`): y[k] is the measurement the
tick-k decision was based on and u[k] the reference applied from t_k to t_k + dt, so u[k]
influences y[k+1], y[k+2], ... (a strictly proper closed loop).
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field, fields
from typing import Any, Callable, Sequence

import numpy as np

from ddpc_codegen.design.data import prbs
from ddpc_codegen.values.phases import GROUND, PHASE_NAMES
from ddpc_codegen.robot.controller import HeightLegAngleController
from ddpc_codegen.robot.state import AttitudeTarget, MeasuredState
from ddpc_codegen.robot.frames import euler_from_quat
from ddpc_codegen.sim.params import PogoXParams, SensorNoise
from ddpc_codegen.sim.plant import STANCE
from ddpc_codegen.sim.run_result import SimResult
from ddpc_codegen.sim.scenarios import FlyingScenario, Scenario, get_scenario
from ddpc_codegen.sim.stepper import Push, Stepper

__all__ = ["simulate", "SimResult", "TickContext", "Push", "Excitation"]


# ----------------------------------------------------------------------------- inputs
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


# ----------------------------------------------------------------------------- simulate
def excitation_signal(
    excitation: Excitation | np.ndarray | bool | None, n_ticks: int, m: int, seed: int, scenario: str
) -> tuple[np.ndarray, bool]:
    """The (n_ticks, m) signal added to the references, and whether it stops in the ground phase.

    ``excitation``: an :class:`Excitation` (its PRBS, seeded with ``seed + 7919`` unless it
    has a seed), True (the scenario's :func:`default_excitation`), an (>= n_ticks, m) array
    added as is, or None / False (zeros).
    """
    if excitation is True:
        excitation = default_excitation(scenario)
    if isinstance(excitation, Excitation):
        return excitation.signal(n_ticks, m, seed=seed + 7919), excitation.aerial_only
    if excitation is None or excitation is False:
        return np.zeros((n_ticks, m)), True
    arr = np.asarray(excitation, dtype=float)
    if arr.ndim == 1 and m == 1:
        arr = arr[:, None]
    if arr.ndim != 2 or arr.shape[1] != m or arr.shape[0] < n_ticks:
        raise ValueError(f"excitation array must be ({n_ticks}, {m}); got {arr.shape}")
    return arr[:n_ticks].copy(), True


@dataclass
class _TickLogs:
    """Preallocated per-tick logs; field names and shapes are :class:`SimResult`'s."""

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

    @classmethod
    def allocate(cls, n: int, m: int, p: int, n_state: int) -> "_TickLogs":
        z = np.zeros
        return cls(t=z(n), state=z((n, n_state)), u=z((n, m)), r_nom=z((n, m)), excitation=z((n, m)),
                   y=z((n, p)), y_true=z((n, p)), y_des=z((n, p)), phase=z(n, dtype=np.int8),
                   contact=z(n, dtype=bool), setpoint_q=z((n, 4)), setpoint_thrust=z(n), setpoint_euler=z((n, 3)))

    def head(self, k: int) -> dict[str, np.ndarray]:
        """The first k rows of every log, by field name."""
        return {f.name: getattr(self, f.name)[:k] for f in fields(self)}


def _hook_references(
    hook: ReferenceHook, k: int, t: float, dt: float, scenario: str, r_nom: np.ndarray, meas: MeasuredState,
    ctrl: HeightLegAngleController, logs: _TickLogs,
) -> np.ndarray | None:
    """The hook's references u (m,) for tick k (None: keep r_nom), with read-only log views."""
    u_view, y_view, ph_view = logs.u[:k], logs.y[: k + 1], logs.phase[: k + 1]
    for v in (u_view, y_view, ph_view):
        v.flags.writeable = False
    ctx = TickContext(
        k=k, t=t, dt=dt, scenario=scenario, r_nom=r_nom.copy(), y=logs.y[k].copy(),
        y_des=ctrl.y_des.copy(), phase=int(logs.phase[k]), state=meas,
        u_log=u_view, y_log=y_view, phase_log=ph_view,
        input_names=ctrl.input_names, output_names=ctrl.output_names, _controller=ctrl,
    )
    out = hook(ctx)
    if out is None:
        return None
    u = np.asarray(out, dtype=float).reshape(ctrl.m)
    if not np.all(np.isfinite(u)):
        raise ValueError(f"reference_hook returned non-finite references {u} at tick {k}")
    return u


def _companion_tick(
    k: int, t: float, dt: float, scenario: str, meas: MeasuredState, ctrl: HeightLegAngleController,
    logs: _TickLogs, excitation: np.ndarray, aerial_only: bool, hook: ReferenceHook | None,
) -> AttitudeTarget:
    """The companion computer's tick k: stage (a), steering hook, excitation, stage (b).
    Logs y, phase, u, r_nom and the excitation part of row k; returns the setpoint."""
    r_nom = ctrl.nominal_reference(meas)
    logs.y[k] = ctrl.outputs(meas)
    logs.phase[k] = phase = ctrl.phase
    u = r_nom
    if hook is not None:
        u_hook = _hook_references(hook, k, t, dt, scenario, r_nom, meas, ctrl, logs)
        if u_hook is not None:
            u = u_hook
    e = excitation[k]
    if aerial_only and phase == GROUND:
        e = np.zeros(ctrl.m)  # the ground phase keeps the spring leg's natural dynamics
    u = u + e
    sp = ctrl.track(u, meas)
    logs.u[k], logs.r_nom[k], logs.excitation[k] = u, r_nom, e
    return sp


def _log_truth(k: int, t: float, stepper: Stepper, ctrl: HeightLegAngleController, sp: AttitudeTarget,
               logs: _TickLogs) -> None:
    """Row k of the true state, true outputs, desired outputs, contact and setpoint logs."""
    s_true = stepper.plant.state
    logs.t[k] = t
    logs.state[k] = s_true
    logs.y_des[k] = ctrl.y_des
    e_true = euler_from_quat(s_true[6:10])
    logs.y_true[k] = (s_true[2], e_true[1]) if ctrl.m == 2 else (s_true[2], e_true[0], e_true[1])
    logs.contact[k] = stepper.plant.mode == STANCE
    logs.setpoint_q[k] = sp.q
    logs.setpoint_thrust[k] = sp.thrust
    logs.setpoint_euler[k] = sp.euler


@dataclass
class _Run:
    """How a run ended: ticks simulated, lost or not and why."""

    ticks: int = 0
    crashed: bool = False
    crash_reason: str = ""


def _run_ticks(
    stepper: Stepper, ctrl: HeightLegAngleController, scenario: str, dt: float, n_ticks: int,
    logs: _TickLogs, excitation: np.ndarray, aerial_only: bool, hook: ReferenceHook | None,
    stop_on_crash: bool, bar: Any, changes: Sequence[tuple[float, Callable[[Stepper], None]]] = (),
) -> _Run:
    """The closed loop, tick by tick, until n_ticks or the robot is lost."""
    run = _Run()
    pending = sorted(changes, key=lambda c: c[0])
    for k in range(n_ticks):
        t = k * dt
        while pending and pending[0][0] <= t:
            pending.pop(0)[1](stepper)
        meas = stepper.measure(t)
        sp = _companion_tick(k, t, dt, scenario, meas, ctrl, logs, excitation, aerial_only, hook)
        _log_truth(k, t, stepper, ctrl, sp, logs)
        stepper.advance((sp.q, sp.thrust))
        run.ticks = k + 1
        if bar is not None and (k % 50 == 0 or k == n_ticks - 1):
            bar.update(k + 1 - bar.n)
        if stepper.stuck:
            run.crashed, run.crash_reason = True, run.crash_reason or stepper.stuck
            break  # the plant cannot go on, whatever stop_on_crash says
        lost = stepper.lost()
        if lost and not run.crashed:
            run.crashed, run.crash_reason = True, f"{lost} at t={stepper.plant.t:.3f} s"
        if lost and stop_on_crash:
            break
    return run


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
    changes: Sequence[tuple[float, Callable[[Stepper], None]]] | None = None,
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
        changes: (t [s], fn(stepper)) pairs: fn changes the vehicle at the first tick at or after t (e.g. a
            payload: ``stepper.plant._m += 0.3``; a thrust drop: ``stepper.plant._kf *= 0.85``).
    """
    t_wall = time.perf_counter()
    params = params or PogoXParams()
    sc = get_scenario(scenario)
    ctrl = sc.make_controller(params)
    dt = params.control_dt
    n_ticks = int(round(duration / dt))
    if n_ticks <= 0:
        raise ValueError(f"duration must be > 0; got {duration}")
    excitation_array, aerial_only = excitation_signal(excitation, n_ticks, ctrl.m, seed, sc.name)
    x0, y0, z0 = sc.initial_position(params)
    stepper = Stepper(params, [x0, y0, z0], noise=noise, seed=seed, pushes=pushes)
    ctrl.reset(0.0, z0 if sc.name == "hopping" else None)
    logs = _TickLogs.allocate(n_ticks, ctrl.m, ctrl.p, stepper.plant.state.shape[0])
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=n_ticks, file=sys.stderr, desc=f"simulate {sc.name}", unit="tick", leave=False)
    try:
        run = _run_ticks(stepper, ctrl, sc.name, dt, n_ticks, logs, excitation_array, aerial_only,
                         reference_hook, stop_on_crash, bar, changes or ())
    finally:
        if bar is not None:
            bar.close()
    out = logs.head(run.ticks)
    extras: dict[str, np.ndarray] = {}
    if isinstance(sc, FlyingScenario):
        d = sc.ellipse.sample(out["t"])
        extras["x_des"] = np.asarray(d["x"])
        extras["z_des"] = np.asarray(d["z"])
    return SimResult(
        scenario=sc.name, dt=dt, **out,
        touchdowns=np.array(stepper.touchdowns), liftoffs=np.array(stepper.liftoffs),
        input_names=ctrl.input_names, output_names=ctrl.output_names,
        input_units=ctrl.input_units, output_units=ctrl.output_units,
        params=params, config=ctrl.config, scenario_obj=sc, seed=seed,
        crashed=run.crashed, crash_reason=run.crash_reason, n_bottom_outs=stepper.plant.n_bottom_outs,
        wall_time=time.perf_counter() - t_wall, extras=extras,
    )
