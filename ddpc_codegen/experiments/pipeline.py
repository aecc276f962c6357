"""Reference steering in the simulated loop: collect -> predictor -> generated solver -> runs -> metrics.

The pipeline of the paper's evaluation, on :mod:`ddpc_codegen.sim`:

* **Flying** (DDPC-Flying). PRBS-excited closed-loop data on a *training* ellipse (other size,
  centre and period than the test ellipse: the data describe the loop, not the task); predictor
  fitted on it; steering QP generated as C and loaded; the test ellipse flown without and with
  steering.
* **Hopping** (DDPC-Hopping). PRBS on the references in the aerial phase only; the Hankel of
  the artificial-IO QP from aerial segments only; every hop's ground phase replaced by artificial
  IO (:mod:`ddpc_codegen.design.artificial_io`) and the hops joined into the mosaic H_G the predictor is fitted
  on; online the ground part of u_ini / y_ini is filled the same way; steering in the air only.

Timing (the steerer's convention, checked against the simulator's logs): the simulator logs
y[k] = the measurement tick k decided on and u[k] = the reference applied from t_k on, so u[k]
first shows in y[k+1]. At tick k the hook pushes the pair (u[k-1], y[k-1]) into the steerer's
ring buffer, so u_ini = u[k-Tini:k], y_ini = y[k-Tini:k], exactly the Hankel columns' pairing,
and the horizon is ticks k..k+Tf-1 (y_des = ``ctx.desired_ahead(Tf)``). The newest measurement
y[k] is then not used by the decision at tick k (it is predicted): one tick of information
latency, the price of a window that matches the data pairing without re-indexing the data.

Predictor choice (measured; numbers in ``configs/*.toml`` and the report):

* Training data are recorded without sensor noise (the paper's motion capture is far more precise
  than the simulator's pessimistic default noise). On such data the SPC least-squares predictor
  (``lsq``) is exact to 1e-5 m over 15 steps, but its gains on y_ini reach ~1e4 and the loop goes
  unstable as soon as the measurements are noisy; a ridge of 1e-2 brings the gain to ~3 at
  0.9 mm (clean) / 1.6 mm (noisy) 15-step error. The paper's ``pem`` at slack_weight = 1 is
  biased (3 mm over 15 steps on the same data).
* Recording *with* noise instead regularises the fit by itself but biases it (errors in
  variables): on hopping the 25-step height prediction is pulled ~20 mm toward the training
  hops' height. So: clean data, ``lsq`` with a ridge.
* The constant offset of the loop (gravity against a wrong model mass: the IO map is affine)
  needs no extra handling: a constant is an uncontrollable but observable mode, so it is part of
  the state the Tini window determines, and the linear predictor reproduces it (a mass error the
  data never saw is still steered out, see the robustness runs).
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from ddpc_codegen.design.config import SteeringConfig
from ddpc_codegen.design.phases import ASCENT, DESCENT, GROUND
from ddpc_codegen.design.data import IODataset
from ddpc_codegen.errors import DataError
from ddpc_codegen.design.artificial_io import ArtificialIO, HoppingWindow, ground_runs, stitch_hops
from ddpc_codegen.design.predictor import Predictor, fit_predictor
from ddpc_codegen.design.problem import SteeringProblem
from ddpc_codegen.design.result import SteeringResult
from ddpc_codegen.stats import percentiles
from ddpc_codegen.sim import Excitation, FlyingScenario, PogoXParams, Push, SensorNoise, SimResult, TickContext, simulate
from ddpc_codegen.sim.scenarios import EllipseTrajectory, HoppingScenario, Scenario
from ddpc_codegen.runtime.policy import SteeringPolicy
from ddpc_codegen.runtime.steerer import ReferenceSteerer

__all__ = [
    "ROOT",
    "CollectSpec",
    "ArtificialIOSpec",
    "SteeringSetup",
    "InterpretedSolver",
    "SteeringHook",
    "RunResult",
    "collect",
    "split_hopping",
    "build_setup",
    "run",
    "scenario_metrics",
    "prediction_check",
    "default_config",
]

ROOT = Path(__file__).resolve().parents[2]  # the repository (configs/, generated/, reports/)
_SCENARIOS = ("flying", "hopping")

# The ellipse the flying data are recorded on: not the test ellipse (centre (0, 1.2), radii (1, 0.3), 10 s).
TRAIN_ELLIPSE = EllipseTrajectory(center=(0.0, 1.0), radii=(0.6, 0.2), period=7.0)


def default_config(scenario: str) -> Path:
    """configs/<scenario>.toml of the repository."""
    return ROOT / "configs" / f"{scenario}.toml"


def _say(progress: bool, msg: str) -> None:
    if progress:
        print(msg, file=sys.stderr, flush=True)


# ----------------------------------------------------------------------------- data collection
@dataclass(frozen=True)
class CollectSpec:
    """How training data are recorded on the simulator.

    Attributes:
        duration: simulated seconds (flying: 90 s = 17 400 samples after the settle time;
            hopping: 120 s = ~145 hops).
        seed: PRBS and noise seed (the evaluation runs use other seeds).
        noise: record with sensor noise (default no; see the module docstring).
        amplitude: PRBS amplitude per reference channel (m, rad); None = the simulator's defaults.
        min_hold: PRBS bit length [ticks].
        mass_error: controller model mass minus true mass [kg] during the recording.
    """

    duration: float = 90.0
    seed: int = 1
    noise: bool = False
    amplitude: tuple[float, ...] | None = None
    min_hold: int = 4
    mass_error: float = -0.2

    @classmethod
    def default(cls, scenario: str) -> "CollectSpec":
        if scenario == "flying":
            return cls(duration=90.0, amplitude=(0.05, 0.03))
        return cls(duration=120.0, amplitude=(0.01, 0.02, 0.02))


def collect(scenario: str, spec: CollectSpec | None = None, *, progress: bool = False) -> SimResult:
    """Record PRBS-excited closed-loop data (flying: on :data:`TRAIN_ELLIPSE`; hopping: aerial PRBS)."""
    if scenario not in _SCENARIOS:
        raise DataError(f"unknown scenario {scenario!r}; choose one of {list(_SCENARIOS)}")
    spec = spec or CollectSpec.default(scenario)
    sc = FlyingScenario(ellipse=TRAIN_ELLIPSE) if scenario == "flying" else HoppingScenario()
    amp = spec.amplitude if spec.amplitude is not None else (0.05, 0.03) if scenario == "flying" else (0.01, 0.02, 0.02)
    res = simulate(sc, spec.duration, params=PogoXParams(controller_mass_error=spec.mass_error), seed=spec.seed,
                   excitation=Excitation(amplitude=tuple(amp), min_hold=spec.min_hold, aerial_only=True),
                   noise=spec.noise or None, progress=progress)
    if res.crashed:
        raise DataError(f"the robot was lost while collecting {scenario} data ({res.crash_reason}); "
                        "lower the PRBS amplitude")
    return res


def split_hopping(raw: IODataset) -> tuple[IODataset, IODataset]:
    """(aerial segments, apex-to-apex hops) of hopping logs with phase labels.

    Aerial segments run from a liftoff to the next touchdown (complete ones only, plus the
    release arc); hops from one apex (ascent -> descent switch) to the next, each with one
    ground phase.
    """
    if raw.phases is None:
        raise DataError("hopping data need phase labels (descent / ground / ascent)")
    au, ay, ap, hu, hy, hp = [], [], [], [], [], []
    for (u, y), ph in zip(raw.trajectories(), raw.phases):
        runs = ground_runs(ph)
        starts = [0] + [b for _, b in runs]
        ends = [a for a, _ in runs] + [len(ph)]
        for a, b in zip(starts, ends):
            if b - a >= 2 and b < len(ph):  # complete aerial phases (ending in a touchdown)
                au.append(u[a:b]); ay.append(y[a:b]); ap.append(ph[a:b])
        apex = [k for k in range(1, len(ph)) if ph[k - 1] == ASCENT and ph[k] == DESCENT]
        for a, b in zip(apex[:-1], apex[1:]):
            if np.any(ph[a:b] == GROUND):
                hu.append(u[a:b]); hy.append(y[a:b]); hp.append(ph[a:b])
    kw = dict(input_names=raw.input_names, output_names=raw.output_names, input_units=raw.input_units,
              output_units=raw.output_units, metadata=raw.metadata)
    if not au or not hu:
        raise DataError("no complete aerial phase or hop in the hopping data; record longer")
    return IODataset(au, ay, raw.dt, phases=ap, **kw), IODataset(hu, hy, raw.dt, phases=hp, **kw)


# ----------------------------------------------------------------------------- setup
@dataclass(frozen=True)
class ArtificialIOSpec:
    """Artificial ground-phase IO settings (hopping; see :mod:`ddpc_codegen.design.artificial_io`); the config's
    ``[artificial_io]`` table sets any of them (validated by :class:`SteeringConfig`).

    Attributes:
        t_d, t_a: real descent / ascent samples around each recorded ground phase that the offline
            stitching (the mosaic H_G) is conditioned on (exact least-norm, ``noise_level``).
        t_d_online: descent samples the online fill is conditioned on (0: the ascent alone; a
            descent context makes the fill atypical and noise-sensitive online).
        min_ascent: ascent samples needed before steering starts (fewer leave the aerial state
            at liftoff under-determined: on noise-free windows the 25-step height prediction
            error is ~9 cm with 1-4 samples, ~4 mm with 5-9 and ~2 mm with 10-14).
        ground_margin: extra samples of depth beyond the longest recorded ground phase.
        noise_level: sigma of the offline completion [m / rad] (0 = exact: clean recordings).
        noise_level_online: sigma of the online completion (measurements are noisy online).
    """

    t_d: int = 10
    t_a: int = 20
    t_d_online: int = 0
    min_ascent: int = 10
    ground_margin: int = 10
    noise_level: float = 0.0
    noise_level_online: float = 1e-3


@dataclass
class SteeringSetup:
    """Everything a steered run needs.

    problem: interpreted SteeringProblem; solver: the generated C solver (None if not compiled);
    dataset: the predictor's data (flying: the PRBS run; hopping: the stitched hops H_G);
    art: hopping's completion operator; info: provenance (PE summary, held-out prediction error, timings);
    raw: the recorded data as collected (hopping: with ground phases; what the baselines are fitted on).
    """

    scenario: str
    config: SteeringConfig
    predictor: Predictor
    problem: SteeringProblem
    dataset: IODataset
    solver: Any = None
    solver_path: Path | None = None
    art: ArtificialIO | None = None
    art_spec: ArtificialIOSpec = field(default_factory=ArtificialIOSpec)
    info: dict = field(default_factory=dict)
    raw: IODataset | None = None


def _fit(cfg: SteeringConfig, ds: IODataset) -> Predictor:
    opts = {k: v for k, v in cfg.predictor.items() if k != "method"}
    return fit_predictor(ds, cfg.t_ini, cfg.t_f, cfg.predictor["method"], **opts)


def build_setup(
    scenario: str,
    *,
    config: SteeringConfig | str | Path | None = None,
    raw: IODataset | SimResult | None = None,
    collect_spec: CollectSpec | None = None,
    art_spec: ArtificialIOSpec | None = None,
    generate_dir: str | Path | None = "generated",
    solver_name: str | None = None,
    backend: str | None = None,
    save_data: bool = True,
    progress: bool = False,
    fit: Callable[[SteeringConfig, IODataset], Predictor] | None = None,
) -> SteeringSetup:
    """Data -> predictor -> steering problem -> generated, compiled, loaded solver.

    Args:
        scenario: "flying" or "hopping".
        config: SteeringConfig or TOML path (default configs/<scenario>.toml).
        raw: recorded data (an IODataset with phase labels for hopping, or a SimResult);
            None records new data with ``collect_spec``.
        generate_dir: root of the generated solver folder (``<dir>/<solver_name>``); None = do
            not generate (interpreted runs only).
        solver_name: default ``steer_<scenario>``.
        fit: fits the predictor from (config, dataset) (default: ``fit_predictor`` with the config's
            [predictor] options); a sweep passes a cached one.
        save_data: write the recorded data (flying: the config's [data] dataset; hopping: the raw
            log next to it as ``hopping_raw.npz`` and the stitched hops as the [data] dataset).
    """
    t_start = time.perf_counter()
    cfg = config if isinstance(config, SteeringConfig) else SteeringConfig.from_toml(config or default_config(scenario))
    info: dict[str, Any] = {"config": cfg.source}
    if raw is None:
        _say(progress, f"[{scenario}] collecting PRBS-excited data on the simulator ...")
        raw = collect(scenario, collect_spec, progress=progress)
    if isinstance(raw, SimResult):
        raw = raw.to_dataset("none", t_min=getattr(raw.scenario_obj, "settle_time", 0.0) if scenario == "flying" else 0.0)
    info["raw_samples"] = raw.n_samples
    art = None
    art_spec = art_spec or ArtificialIOSpec(**cfg.artificial_io)
    if scenario == "flying":
        ds = raw
        if save_data and cfg.dataset:
            ds.save(cfg.dataset)
    else:
        aerial, hops = split_hopping(raw)
        g_max = max(b - a for ph in hops.phases for a, b in ground_runs(ph))
        depth = art_spec.t_d + g_max + art_spec.ground_margin + max(art_spec.t_a, cfg.t_ini)
        _say(progress, f"[hopping] artificial IO: Hankel of {aerial.n_trajectories} aerial segments, depth {depth}")
        art = ArtificialIO(aerial, depth, noise_level=art_spec.noise_level,
                           u_min=cfg.u_min, u_max=cfg.u_max, y_min=cfg.y_min, y_max=cfg.y_max)
        ds, rep = stitch_hops(hops, art, art_spec.t_d, art_spec.t_a, progress=progress)
        info["artificial_io"] = {"depth": depth, "rank": art.rank, "aerial_segments": aerial.n_trajectories,
                                 "aerial_columns": art.n_columns, **rep}
        if save_data and cfg.dataset:
            raw.save(Path(cfg.dataset).with_name("hopping_raw.npz"))
            ds.save(cfg.dataset)
    _say(progress, f"[{scenario}] fitting the {cfg.predictor['method']} predictor on {ds.n_trajectories} "
                   f"trajectories, {ds.n_samples} samples ...")
    pred = (fit or _fit)(cfg, ds)
    info["excitation"] = pred.excitation().summary()
    info["predictor"] = {"method": pred.method, "rank": pred.rank, "columns": pred.n_columns,
                         **{k: v for k, v in pred.options.items() if not k.startswith("_")}}
    prob = SteeringProblem(pred, cfg)
    setup = SteeringSetup(scenario, cfg, pred, prob, ds, art=art, art_spec=art_spec, info=info, raw=raw)
    if generate_dir is not None:
        from ddpc_codegen.codegen import generate
        from ddpc_codegen.runtime.loader import load_solver

        name = solver_name or f"steer_{scenario}"
        t0 = time.perf_counter()
        _say(progress, f"[{scenario}] generating + compiling the C solver generated/{name} ...")
        path = generate(prob, Path(generate_dir) / name, backend=backend, name=name)
        setup.solver = load_solver(path)
        setup.solver_path = Path(path)
        info["codegen_s"] = round(time.perf_counter() - t0, 2)
        info["backend"] = setup.solver.backend
    info["setup_s"] = round(time.perf_counter() - t_start, 2)
    return setup


# ----------------------------------------------------------------------------- solvers and hook
class InterpretedSolver:
    """A SteeringProblem behind the generated solver's API (``solve(u_ini, y_ini, y_des, u_nom)``).

    method: "fast" (unconstrained optimum if feasible, else CasADi's daqp: the generated daqp
    solver's algorithm, interpreted), "exact" (always the active-set solve) or "osqp".
    """

    def __init__(self, problem: SteeringProblem, method: str = "fast") -> None:
        self.problem = problem
        self.config = problem.config
        self.has_nominal = problem.has_nominal
        self.method = method

    def solve(self, u_ini, y_ini, y_des, u_nom=None) -> SteeringResult:
        return self.problem.solve(u_ini, y_ini, y_des, u_nom, solver=self.method)


class SteeringHook:
    """The :class:`SteeringPolicy` as the simulator's per-tick ``reference_hook``.

    Flying: y_des over the horizon is ``ctx.desired_ahead(Tf)`` (z of the ellipse, the pitch of
    the horizontal PD with its current correction held); u_nom is y_des with row 0 = r_nom.
    Hopping: no steering on the ground (r_nom = measured outputs keeps the spring's natural
    dynamics); in the air, a window whose ground part is filled with artificial IO, and the
    desired arc continued ballistically past the predicted touchdown (the aerial predictor knows
    nothing of the ground, so the horizon is scored against the arc the aerial dynamics should
    fly; the leg angles are held as the controller does).

    Counts (``counts``): ticks, ground, no_window:<reason>, filled (hopping).
    """

    def __init__(self, steerer: ReferenceSteerer, scenario: str, *, window: HoppingWindow | None = None,
                 g_eff: float | None = None) -> None:
        self.steerer = steerer
        self.policy = SteeringPolicy(steerer, max_gap_fill=0)  # the simulator never loses a sample
        self.scenario = scenario
        self.window = window
        self.g_eff = g_eff
        self.counts: dict[str, int] = {}
        self.solver_us: list[float] = []  # the solver's own timer (C for a generated solver)
        self._v_arc: float | None = None

    def _count(self, key: str) -> None:
        self.counts[key] = self.counts.get(key, 0) + 1

    def __call__(self, ctx: TickContext) -> np.ndarray | None:
        pol = self.policy
        self._count("ticks")
        if self.scenario == "flying":
            return self._decide(ctx, ctx.desired_ahead(pol.t_f))
        # ---- hopping
        if ctx.phase == GROUND:
            self._count("ground")
            pol.observe(ctx.r_nom, ctx.y)
            return None
        if self.window is not None:
            w = self.window.window(ctx.u_log, ctx.y_log[:-1], ctx.phase_log[:-1])
            if isinstance(w, str):
                self._count(f"no_window:{w}")
                pol.observe(ctx.r_nom, ctx.y)
                return None
            if w is not None:
                pol.steerer.set_window(*w)
                self._count("filled")
            else:
                # A clean aerial window: the real samples (a fitted window of an earlier tick may
                # still sit in the ring buffer otherwise).
                Ti = pol.steerer.t_ini
                pol.steerer.set_window(ctx.u_log[-Ti:], ctx.y_log[-Ti - 1 : -1])
        return self._decide(ctx, self._arc_horizon(ctx))

    def _decide(self, ctx: TickContext, y_des: np.ndarray) -> np.ndarray:
        out = self.policy.decide(ctx.y, ctx.r_nom, y_des)
        if out.result is not None and np.isfinite(out.result.solve_time) and out.result.solve_time > 0:
            self.solver_us.append(out.result.solve_time * 1e6)
        return out.u

    def _arc_horizon(self, ctx: TickContext) -> np.ndarray:
        """(Tf, p) desired outputs with z continued on the current ballistic arc after touchdown."""
        n = self.policy.t_f
        yd = np.array(ctx.desired_ahead(n), dtype=float)
        ph = np.asarray(ctx.phases_ahead(n))
        g = self.g_eff
        air = np.flatnonzero(ph != GROUND)
        # The aerial samples before the first predicted ground sample define the arc.
        first_ground = int(np.argmax(ph == GROUND)) if np.any(ph == GROUND) else n
        if g is None or first_ground >= n:
            if first_ground >= n and len(air) >= 2:
                self._v_arc = (yd[1, 0] - yd[0, 0]) / ctx.dt + 0.5 * (g or 0.0) * ctx.dt
            return yd
        tau = ctx.dt * np.arange(n)
        z0 = yd[0, 0]
        if first_ground >= 2:
            v = float(np.mean((yd[1:first_ground, 0] - z0 + 0.5 * g * tau[1:first_ground] ** 2) / tau[1:first_ground]))
        elif self._v_arc is not None:
            v = self._v_arc - g * ctx.dt
        else:
            v = 0.0
        self._v_arc = v
        yd[first_ground:, 0] = z0 + v * tau[first_ground:] - 0.5 * g * tau[first_ground:] ** 2
        # Leg angles: held at the current aerial command (what the controller does in the air).
        yd[first_ground:, 1:] = yd[0, 1:]
        return yd


# ----------------------------------------------------------------------------- runs
@dataclass
class RunResult:
    """One simulated run: the SimResult, its summary metrics, and the steering statistics (or None)."""

    sim: SimResult
    metrics: dict
    steering: dict | None = None
    label: str = ""


def scenario_metrics(res: SimResult) -> dict[str, Any]:
    """The report's metrics of a run (SI units, radians).

    Flying: rmse_z, rmse_pitch (after the settle time), plus rmse_x and mean_z_error.
    Hopping (after the settle hops): apex_error_mean_abs = mean |apex - target| [m],
    apex_error_mean_signed = mean (apex - target), rmse_pitch / rmse_roll / rmse_z over the aerial phase,
    vx_error_mean_abs = mean |per-hop average vx - target| [m/s] (touchdown to touchdown).
    """
    m = res.metrics()
    out: dict[str, Any] = {"crashed": bool(res.crashed), "duration": m["duration"]}
    if res.scenario == "flying":
        out.update(rmse_z=m["rmse_z"], rmse_pitch=m["rmse_pitch"], rmse_x=m.get("rmse_x", float("nan")),
                   mean_z_error=m["mean_z_error"])
        return out
    settle = int(getattr(res.scenario_obj, "settle_hops", 0))
    ap = np.asarray(m["apex_errors"][settle:], dtype=float)
    td = res.touchdowns
    vx = []
    for a, b in zip(td[:-1], td[1:]):
        ia, ib = int(np.searchsorted(res.t, a)), int(np.searchsorted(res.t, b))
        if ib < res.n and ib > ia:
            vx.append((res.state[ib, 0] - res.state[ia, 0]) / (res.t[ib] - res.t[ia]) - res.config.target_velocity[0])
    vx = np.asarray(vx[settle:])
    out.update(
        apex_error_mean_abs=float(np.mean(np.abs(ap))) if ap.size else float("nan"),
        apex_error_mean_signed=float(np.mean(ap)) if ap.size else float("nan"),
        apex_error_max_abs=float(np.max(np.abs(ap))) if ap.size else float("nan"),
        rmse_pitch=m["rmse_pitch_aerial"],
        rmse_roll=m["rmse_roll_aerial"],
        rmse_z=m["rmse_z_aerial"],
        vx_error_mean_abs=float(np.mean(np.abs(vx))) if vx.size else float("nan"),
        n_hops=int(m["n_hops_scored"]),
    )
    return out


def _g_eff(res_params: PogoXParams) -> float:
    sc = HoppingScenario()
    return sc.controller_config(res_params).g_eff


def run(
    setup: SteeringSetup | None,
    scenario: str | Scenario,
    duration: float,
    *,
    steer: bool = True,
    interpreted: bool | str = False,
    params: PogoXParams | None = None,
    noise: SensorNoise | bool | None = None,
    pushes: Sequence[Push] | None = None,
    seed: int = 0,
    progress: bool = False,
    label: str = "",
) -> RunResult:
    """Simulate one run of ``scenario`` (a name or a scenario object, e.g. another trajectory),
    steered through ``setup`` or not.

    Args:
        steer: False = the baseline (the model-based controller alone).
        interpreted: True / "fast" / "exact" / "osqp": solve in Python (SteeringProblem) instead of
            the generated C solver (used anyway when the setup has none).
    The simulator never gets an exception from the steering: solver failures are fallbacks
    (counted by the steerer); a simulator error ends the run as crashed.
    """
    params = params or PogoXParams()
    sim_scenario, scenario = scenario, scenario if isinstance(scenario, str) else scenario.name
    hook = None
    steerer = None
    if steer:
        if setup is None:
            raise DataError("a steered run needs a SteeringSetup")
        cfg = setup.config
        if interpreted or setup.solver is None:
            solver = InterpretedSolver(setup.problem, interpreted if isinstance(interpreted, str) else "fast")
        else:
            solver = setup.solver
            solver.reset()
        steerer = ReferenceSteerer.for_solver(solver)
        window = None
        if scenario == "hopping":
            if setup.art is None:
                raise DataError("a hopping setup needs its artificial-IO operator")
            window = HoppingWindow(setup.art, cfg.t_ini, setup.art_spec.t_d_online, setup.art_spec.min_ascent,
                                   setup.art_spec.noise_level_online)
        hook = SteeringHook(steerer, scenario, window=window,
                            g_eff=_g_eff(params) if scenario == "hopping" else None)
    t0 = time.perf_counter()
    res = simulate(sim_scenario, duration, params=params, seed=seed, reference_hook=hook, noise=noise,
                   pushes=pushes, progress=progress)
    wall = time.perf_counter() - t0
    met = scenario_metrics(res)
    met["wall_s"] = round(wall, 2)
    st = None
    if steerer is not None:
        st = steerer.summary()
        st["hook"] = dict(hook.counts)
        st["solver_us"] = percentiles(hook.solver_us)
        st["solver"] = "interpreted" if isinstance(steerer.solver, InterpretedSolver) else f"generated:{steerer.solver.backend}"
        if hook.window is not None:
            st["artificial_io"] = dict(hook.window.counts)
    return RunResult(res, met, st, label)


# ----------------------------------------------------------------------------- checks
def prediction_check(setup: SteeringSetup, held_out: SimResult, *, stride: int = 5) -> dict[str, list[float]]:
    """Multi-step prediction error of the setup's predictor on a held-out run (RMSE per output).

    Windows are taken as in the loop (hopping: ground filled with artificial IO, horizons that
    stay in the air). Returns {"rmse": [per output], "windows": n} against the measured outputs.
    """
    pr = setup.predictor
    Ti, Tf = pr.t_ini, pr.t_f
    u, y, ph = held_out.u, held_out.y, held_out.phase
    win = HoppingWindow(setup.art, Ti, setup.art_spec.t_d_online, setup.art_spec.min_ascent,
                        setup.art_spec.noise_level_online) if setup.art is not None else None
    errs = []
    for k in range(max(Ti, 200), held_out.n - Tf, stride):
        if win is not None:
            if np.any(ph[k : k + Tf] == GROUND):
                continue
            w = win.window(u[:k], y[:k], ph[:k])
            if isinstance(w, str):
                continue
            ui, yi = w if w is not None else (u[k - Ti : k], y[k - Ti : k])
        else:
            ui, yi = u[k - Ti : k], y[k - Ti : k]
        yp, _ = pr.predict(ui, yi, u[k : k + Tf])
        errs.append(yp - y[k : k + Tf])
    e = np.asarray(errs)
    return {"rmse": np.sqrt(np.mean(e**2, axis=(0, 1))).tolist() if e.size else [], "windows": int(len(errs))}
