"""Closed-loop evaluation on the simulator: one run with or without steering (the shared per-tick
policy driven by :class:`~ddpc_codegen.experiments.policy_hook.PolicyHook`), its metrics, and the
held-out prediction check. Setups (data -> predictor -> solver) come from :mod:`.pipeline`.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from ddpc_codegen.design.adaptation import AdaptiveProblem
from ddpc_codegen.values.phases import GROUND
from ddpc_codegen.design.problem import SteeringProblem
from ddpc_codegen.values.solve_result import SteeringResult
from ddpc_codegen.errors import DataError
from ddpc_codegen.experiments.pipeline import SteeringSetup
from ddpc_codegen.experiments.policy_hook import PolicyHook
from ddpc_codegen.flight_metrics import flight_metrics
from ddpc_codegen.runtime.adapt_loop import OnlineAdaptation
from ddpc_codegen.runtime.hopping import HoppingWindow
from ddpc_codegen.runtime.policy import SteeringPolicy
from ddpc_codegen.runtime.steerer import ReferenceSteerer
from ddpc_codegen.sim import PogoXParams, Push, SensorNoise, SimResult, simulate
from ddpc_codegen.sim.scenarios import HoppingScenario, Scenario
from ddpc_codegen.stats import percentiles
from ddpc_codegen.runtime.loader import load_solver

__all__ = ["InterpretedSolver", "RunResult", "run", "scenario_metrics", "offset_step",
           "prediction_check"]


# ----------------------------------------------------------------------------- solvers
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
    Both: offset_step_rms = per reference, the rms tick-to-tick change of the steering offset u - r_nom
    (reference units per tick; flying after the settle time, hopping over the aerial ticks after the
    settle hops; 0 when nothing steers); thrust_limit_share = the fraction of those ticks on which the
    controller's normalized thrust setpoint is clamped at 0 or 1.
    """
    m = res.metrics()
    out: dict[str, Any] = {"crashed": bool(res.crashed), "duration": m["duration"]}
    if res.scenario == "flying":
        f = flight_metrics(res.t, res.y_true, res.y_des, settle=float(getattr(res.scenario_obj, "settle_time", 0.0)),
                           u=res.u, r_nom=res.r_nom, thrust=res.setpoint_thrust, empty=float("nan"))
        out.update(rmse_z=f["rmse"][0], rmse_pitch=f["rmse"][1], rmse_x=m.get("rmse_x", float("nan")),
                   mean_z_error=f["mean_error"][0])
    else:
        settle = int(getattr(res.scenario_obj, "settle_hops", 0))
        t_scored = res.touchdowns[settle] if len(res.touchdowns) > settle else np.inf
        f = flight_metrics(res.t, res.y_true, res.y_des, settle=t_scored, active=res.phase != GROUND, u=res.u,
                           r_nom=res.r_nom, thrust=res.setpoint_thrust, empty=float("nan"))
    out["offset_step_rms"] = f["offset_step_rms"]
    out["thrust_limit_share"] = f["thrust_limit_share"]
    if res.scenario == "flying":
        return out
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


def offset_step(metrics: dict[str, Any], channel: int = 0) -> float | None:
    """``offset_step_rms`` of one reference (default 0, z_ref) from a metrics dict (scenario_metrics,
    a summary block); None when not recorded (e.g. a summary written before the metric existed)."""
    v = metrics.get("offset_step_rms") or []
    return v[channel] if channel < len(v) else None


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
    completion: str = "auto",
    adapt: bool = False,
    changes: Sequence[tuple[float, Any]] | None = None,
) -> RunResult:
    """Simulate one run of ``scenario`` (a name or a scenario object, e.g. another trajectory),
    steered through ``setup`` or not.

    Args:
        steer: False = the baseline (the model-based controller alone).
        interpreted: True / "fast" / "exact" / "osqp": solve in Python (SteeringProblem) instead of
            the generated C solver (used anyway when the setup has none).
        completion: hopping's online artificial IO: "generated" (the solver artifact's compiled
            completion), "interpreted" (``setup.art``), "auto" (generated when the generated solver
            steers and carries one).
        adapt: online predictor updates with the config's ``[adapt]`` settings: a fresh instance of the
            generated solver (built with ``[adapt] enabled``) or the interpreted twin
            (:class:`~ddpc_codegen.design.adaptation.AdaptiveProblem`); the summary's ``adaptation``.
        changes: (t, fn(stepper)) vehicle changes during the run (see :func:`~ddpc_codegen.sim.loop.simulate`).
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
        method = interpreted if isinstance(interpreted, str) else "fast"
        if adapt:
            solver = _adaptive_solver(setup, bool(interpreted), method)
        elif interpreted or setup.solver is None:
            solver = InterpretedSolver(setup.problem, method)
        else:
            solver = setup.solver
            solver.reset()
        steerer = ReferenceSteerer.for_solver(solver)
        window = None
        if scenario == "hopping":
            window = HoppingWindow(_completer(setup, solver, completion), cfg.t_ini, **setup.art_spec.window_settings())
        # the simulator never loses a sample: no gap filling
        policy = SteeringPolicy(steerer, max_gap_fill=0,
                                adaptation=OnlineAdaptation(solver, seed=seed) if adapt else None)
        hook = PolicyHook(policy, scenario, window=window, g_eff=_g_eff(params) if scenario == "hopping" else None,
                          dt=cfg.dt)
    t0 = time.perf_counter()
    res = simulate(sim_scenario, duration, params=params, seed=seed, reference_hook=hook, noise=noise,
                   pushes=pushes, progress=progress, changes=changes)
    wall = time.perf_counter() - t0
    met = scenario_metrics(res)
    met["wall_s"] = round(wall, 2)
    st = None
    if steerer is not None:
        st = steerer.summary()
        st["hook"] = dict(hook.counts)
        st["solver_us"] = percentiles(hook.solver_us)
        st["solver"] = ("interpreted" if isinstance(steerer.solver, (InterpretedSolver, AdaptiveProblem))
                        else f"generated:{steerer.solver.backend}")
        if hook.policy.adaptation is not None:
            st["adaptation"] = hook.policy.adaptation.summary()
        if hook.window is not None:
            art = hook.window.art
            st["artificial_io"] = {**hook.window.counts, **{f"op_{k}": v for k, v in art.counts.items()},
                                   "completion": "interpreted" if art is setup.art else "generated"}
    return RunResult(res, met, st, label)


def _adaptive_solver(setup: SteeringSetup, interpreted: bool, method: str):
    """A fresh adaptive solver of the setup: its own instance (the setup's solver stays as generated)."""
    settings = dataclasses.replace(setup.config.adapt, enabled=True)
    if interpreted or setup.solver_path is None:
        return AdaptiveProblem(setup.problem, settings, method)

    solver = load_solver(setup.solver_path)
    if solver.adaptation is None:
        raise DataError(f"{setup.solver_path}: generated without [adapt] enabled; set it in the config to adapt "
                        "the generated solver")
    return solver


def _completer(setup: SteeringSetup, solver, completion: str):
    """The online artificial-IO operator of a hopping run (see :func:`run`, ``completion``)."""
    generated = getattr(setup.solver, "artificial_io", None)
    if completion not in ("auto", "generated", "interpreted"):
        raise DataError(f"completion must be 'auto', 'generated' or 'interpreted'; got {completion!r}")
    if completion == "generated" or (completion == "auto" and solver is setup.solver and generated is not None):
        if generated is None:
            raise DataError("completion='generated' needs a generated hopping solver with its artificial-IO completion "
                            "(setup.solver.artificial_io); regenerate it with build_setup")
        return generated
    if setup.art is None:
        raise DataError("a hopping setup needs its artificial-IO operator")
    return setup.art


# ----------------------------------------------------------------------------- checks
def prediction_check(setup: SteeringSetup, held_out: SimResult, *, stride: int = 5) -> dict[str, list[float]]:
    """Multi-step prediction error of the setup's predictor on a held-out run (RMSE per output).

    Windows are taken as in the loop (hopping: ground filled with artificial IO, horizons that
    stay in the air). Returns {"rmse": [per output], "windows": n} against the measured outputs.
    """
    pr = setup.predictor
    Ti, Tf = pr.t_ini, pr.t_f
    u, y, ph = held_out.u, held_out.y, held_out.phase
    win = HoppingWindow(setup.art, Ti, **setup.art_spec.window_settings()) if setup.art is not None else None
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
