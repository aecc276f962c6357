"""Honest baselines: reference steering against what a control engineer tries first.

All identified from the same recorded PRBS data the steering predictor is built from
(``SteeringSetup.raw``), all run through the simulator's per-tick ``reference_hook`` behind the
steering policy's interface (:mod:`ddpc_codegen.runtime.baselines`):

* ``passthrough``: the model-based controller alone.
* ``ctrl_ff``: the controller with its own feed-forward of the trajectory's velocity (flying; the
  hopping controller always has it, so there it equals passthrough).
* ``prefilter``: per-channel gain + offset + lead (:func:`~ddpc_codegen.design.baselines.fit_prefilter`).
* ``ilc``: P-type ILC with the prefilter's lead, gain 1/g and a zero-phase Q-filter, learned over
  repeated runs of the periodic case (flying: the ellipse, indexed by trajectory time; hopping:
  the hops, indexed by time since liftoff and averaged over the hops of a run); its last
  iteration is then frozen and flown on every other condition ("the next, different trajectory").
* ``ddpc``: the steering of :mod:`ddpc_codegen.experiments.pipeline` (generated C solver).

Conditions (flying / hopping): the paper's case (ellipse / apex 0.7 m), a non-repeating one
(seeded random smooth x-z path / a random apex target per hop), sensor noise on the paper's case
(the simulator's default :class:`~ddpc_codegen.sim.SensorNoise`; ILC's table learned noise-free),
pushes, and a -300 g mass error the data never saw (the data were recorded at -200 g).
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from ddpc_codegen.design.baselines import (ILC_CUTOFF_HZ, error_on_grid, fit_prefilter, ilc_step,
                                           iterations_to_settle)
from ddpc_codegen.values.prefilter import PrefilterModel
from ddpc_codegen.values.phases import GROUND
from ddpc_codegen.design.hopping_data import split_hopping
from ddpc_codegen.experiments.pipeline import ROOT, SteeringSetup
from ddpc_codegen.experiments.evaluate import RunResult, offset_step, run, scenario_metrics
from ddpc_codegen.experiments.policy_hook import PolicyHook
from ddpc_codegen.robot.hop_targets import ApexSchedule, ScheduledHoppingController
from ddpc_codegen.robot.trajectory import RandomSmoothTrajectory
from ddpc_codegen.runtime.baselines import FeedforwardPolicy, PassthroughPolicy, PrefilterPolicy
from ddpc_codegen.sim import FlyingScenario, PogoXParams, Push, SimResult, simulate
from ddpc_codegen.sim.metrics import hop_apexes
from ddpc_codegen.sim.scenarios import HoppingScenario

__all__ = ["ApexSchedule", "ScheduledHoppingScenario", "fit_scenario_prefilter", "learn_ilc", "ILCResult",
           "conditions", "evaluate_baselines", "reuse_from_summary", "format_baselines", "METHODS", "SMOOTH_HZ",
           "ILC_ITERATIONS", "SIMPLE", "controller_ff_scenario"]

METHODS = ("passthrough", "ctrl_ff", "prefilter", "ilc", "ddpc")
SIMPLE = ("passthrough", "ctrl_ff", "prefilter", "ilc")  # what an engineer tries before steering
# Prefilter fit: low-pass cut-off of u and y before the static fit (the flying PRBS is fast against
# the 0.5 s height loop; hopping's aerial segments are 0.3 s long, so a higher cut-off).
SMOOTH_HZ = {"flying": 1.0, "hopping": 2.0}


# ----------------------------------------------------------------------------- scenarios
@dataclass(frozen=True)
class ScheduledHoppingScenario(HoppingScenario):
    """Hopping with a new random apex target per hop (:class:`ApexSchedule`)."""

    schedule: ApexSchedule = field(default_factory=ApexSchedule)
    name: str = "hopping"

    def make_controller(self, params: PogoXParams) -> ScheduledHoppingController:
        return ScheduledHoppingController(self.controller_config(params), self.schedule)


def conditions(scenario: str) -> dict[str, dict[str, Any]]:
    """name -> {"scenario": object, "params", "pushes", "noise", "periodic": the ILC's own case?}."""
    if scenario == "flying":
        base: Any = FlyingScenario()
        nonrep: Any = FlyingScenario(ellipse=RandomSmoothTrajectory(seed=7))
        pushes = [Push(12.0, (0.0, 0.0, -10.0), 0.2), Push(20.0, (8.0, 0.0, 0.0), 0.1, (0.0, 0.0, -0.3))]
        names = ("ellipse (periodic)", "random smooth path")
    else:
        base = HoppingScenario()
        nonrep = ScheduledHoppingScenario(schedule=ApexSchedule(seed=7))
        pushes = [Push(8.1, (3.0, 0.0, -8.0), 0.1), Push(14.2, (0.0, 3.0, 0.0), 0.1, (0.0, 0.0, -0.3))]
        names = ("apex 0.7 m (periodic)", "random apex per hop")
    plain = {"params": PogoXParams(), "pushes": None, "noise": False, "periodic": False}
    return {
        names[0]: {**plain, "scenario": base, "periodic": True},
        names[1]: {**plain, "scenario": nonrep},
        # The periodic case with noisy measurements: ILC's table (learned noise-free) is a fixed
        # correction, the steering a feedback on the noisy outputs.
        "sensor noise": {**plain, "scenario": base, "noise": True},
        "push": {**plain, "scenario": base, "pushes": pushes},
        "mass -300 g": {**plain, "scenario": base, "params": PogoXParams(controller_mass_error=-0.3)},
    }


def _policy_run(policy: Any, sc: Any, duration: float, params: PogoXParams, pushes, seed: int,
                noise: bool = False) -> SimResult:
    policy.reset()
    return simulate(sc, duration, params=params, seed=seed, reference_hook=PolicyHook(policy, sc.name),
                    pushes=pushes, noise=noise or None)


# ----------------------------------------------------------------------------- metrics
def _metric(res: SimResult) -> dict[str, float]:
    """Flying: rmse_z, rmse_pitch. Hopping: apex_error_mean_abs against each hop's own target, rmse_pitch,
    vx_error_mean_abs. Both: offset_step_rms (the offset u - r_nom's tick-to-tick jitter, :func:`scenario_metrics`)."""
    if res.crashed:
        return {"crashed": True}
    m = scenario_metrics(res)
    if res.scenario == "flying":
        return {"rmse_z": m["rmse_z"], "rmse_pitch": m["rmse_pitch"], "mean_z_error": m["mean_z_error"],
                "offset_step_rms": m["offset_step_rms"]}
    out = {"apex_error_mean_abs": m["apex_error_mean_abs"], "rmse_pitch": m["rmse_pitch"],
           "vx_error_mean_abs": m["vx_error_mean_abs"], "offset_step_rms": m["offset_step_rms"]}
    sc = res.scenario_obj
    if isinstance(sc, ScheduledHoppingScenario):
        out["apex_error_mean_abs"] = _scheduled_apex_error(res, sc.schedule, sc.settle_hops)
    return out


def _scheduled_apex_error(res: SimResult, schedule: ApexSchedule, settle: int) -> float:
    """Mean |apex - target of that hop| over hops after ``settle``; hop j = the arc after liftoff j."""
    ta, za = hop_apexes(res)
    lo = np.asarray(res.liftoffs)
    errs = []
    for t, z in zip(ta, za):
        j = int(np.searchsorted(lo, t))  # liftoffs before this apex
        if j >= 1 + settle:
            errs.append(abs(z - schedule.apex(j)))
    return float(np.mean(errs)) if errs else float("nan")


def _key(scenario: str) -> str:
    return "rmse_z" if scenario == "flying" else "apex_error_mean_abs"


# ----------------------------------------------------------------------------- identification
def fit_scenario_prefilter(setup: SteeringSetup) -> PrefilterModel:
    """The prefilter from the setup's recorded PRBS data (hopping: its aerial segments)."""
    raw = setup.raw if setup.raw is not None else setup.dataset
    data = split_hopping(raw)[0] if setup.scenario == "hopping" and raw.phases is not None else raw
    lead = 200 if setup.scenario == "flying" else 60
    return fit_prefilter(data, max_lead=lead, smooth_hz=SMOOTH_HZ[setup.scenario])


@dataclass
class ILCResult:
    """The learned table, the periodic-case metric per iteration (0 = before learning) and the
    iteration the metric settled at (first within 10 % of the best)."""

    policy: FeedforwardPolicy
    metric: list[float]
    iterations: int
    wall_s: float


def _ilc_error(res: SimResult, clock: str, n: int, settle_hops: int) -> tuple[np.ndarray, np.ndarray]:
    """(error (n, p) on the table's clock, mask (n,) where it was observed); measured y - y_des."""
    e = res.y - res.y_des
    if clock == "trajectory":  # tick k of the run is tick k of the trajectory
        return error_on_grid(np.arange(res.n) * res.dt, e, n, res.dt)
    # Hopping: average the aerial error over the scored hops, indexed by ticks since liftoff.
    acc, cnt = np.zeros((n, e.shape[1])), np.zeros(n)
    ground = res.phase == GROUND
    lifts = np.flatnonzero(ground[:-1] & ~ground[1:]) + 1
    for k0 in lifts[settle_hops:]:
        j = 0
        while k0 + j < res.n and j < n and not ground[k0 + j]:
            acc[j] += e[k0 + j]
            cnt[j] += 1
            j += 1
    mask = cnt > 0
    acc[mask] /= cnt[mask, None]
    return acc, mask


def learn_ilc(setup: SteeringSetup, prefilter: PrefilterModel, *, duration: float, iterations: int = 8,
              gain_scale: float = 1.0, cutoff_hz: float = ILC_CUTOFF_HZ, seed: int = 0,
              quiet: bool = True) -> ILCResult:
    """P-type ILC on repeated runs of the periodic case (fresh simulation per iteration).

    The law is :func:`~ddpc_codegen.design.baselines.ilc_step` (lead d_i and gain gain_scale / g_i
    from the prefilter; the SITL demo flies the same one). Flying: the table spans
    the run (trajectory time); hopping: 0.6 s after liftoff, the mean error over the hops of the run.
    """
    t0 = time.perf_counter()
    sc_name = setup.scenario
    cond = next(iter(conditions(sc_name).values()))
    sc, params = cond["scenario"], cond["params"]
    clock = "trajectory" if sc_name == "flying" else "liftoff"
    dt = params.control_dt
    n = int(round(duration / dt)) if clock == "trajectory" else int(round(0.6 / dt))
    m = prefilter.m
    pol = FeedforwardPolicy(np.zeros((n, m)), dt, clock)
    metric: list[float] = []
    for it in range(iterations + 1):
        res = _policy_run(pol, sc, duration, params, None, seed)
        metric.append(float(_metric(res).get(_key(sc_name), np.nan)))
        if not quiet:
            print(f"[{sc_name}] ilc iteration {it}: {_key(sc_name)} = {metric[-1] * 1e3:.2f} mm", file=sys.stderr)
        if it == iterations:
            break
        err, mask = _ilc_error(res, clock, n, int(getattr(sc, "settle_hops", 0)))
        pol = FeedforwardPolicy(ilc_step(pol.delta, err, prefilter, dt=dt, mask=mask, gain_scale=gain_scale,
                                         cutoff_hz=cutoff_hz), dt, clock)
    return ILCResult(pol, metric, iterations_to_settle(metric), round(time.perf_counter() - t0, 1))


# ----------------------------------------------------------------------------- evaluation
ILC_ITERATIONS = {"flying": 4, "hopping": 6}


def reuse_from_summary(summary: dict[str, Any]) -> dict[str, dict[str, dict[str, dict]]]:
    """Passthrough and DDPC metrics the demo has already computed, keyed like :func:`conditions`.

    The demo's main runs (the periodic case) and its robustness "sensor noise", "push" and "mass
    -300 g" runs are the same simulations as these conditions (noise-free runs do not depend on the
    seed, the noisy ones use the same seed 3; the pushes and masses are the same, a test checks it),
    so they are not run twice.
    """
    out: dict[str, Any] = {}
    for sc in ("flying", "hopping"):
        if sc not in summary:
            continue
        names = list(conditions(sc))
        blocks = {names[0]: summary[sc]}
        for cond in names[2:]:
            blk = summary.get("robustness", {}).get(sc, {}).get(cond)
            if blk and "error" not in blk:
                blocks[cond] = blk
        out[sc] = {}
        for cond, blk in blocks.items():
            pt = {"crashed": True} if blk["crashed"]["baseline"] else dict(blk["baseline"])
            dd = {"crashed": True} if blk["crashed"]["steered"] else dict(blk["steered"])
            dd["fallbacks"] = int(blk["fallbacks"])
            out[sc][cond] = {"passthrough": pt, "ddpc": dd}
    return out


def _condition_row(sc_name: str, c: dict, setup: SteeringSetup, policies: dict, reused: dict, dur: float,
                   seed: int, interpreted: bool | str) -> dict[str, Any]:
    row: dict[str, Any] = {}
    for meth in METHODS:
        if meth in reused:
            row[meth] = reused[meth]
        elif meth == "ctrl_ff":
            row[meth] = _controller_ff_metric(sc_name, c, row, dur, seed)
        elif meth == "ddpc":
            r: RunResult = run(setup, c["scenario"], dur, params=c["params"], pushes=c["pushes"], seed=seed,
                               interpreted=interpreted, noise=c["noise"] or None)
            row[meth] = _metric(r.sim)
            row[meth]["fallbacks"] = int((r.steering or {}).get("fallbacks", 0))
        else:
            row[meth] = _metric(_policy_run(policies[meth], c["scenario"], dur, c["params"], c["pushes"], seed,
                                            c["noise"]))
    row["ilc_learned_here"] = bool(c["periodic"])
    return row


def controller_ff_scenario(scenario: Any) -> Any:
    """The same scenario with the model-based controller's own feed-forward on: the D term acts on
    the filtered derivative of the reference (ref_velocity_gain 1), i.e. the trajectory's velocity
    is fed forward. Flying runs without it by default (D on the measurement: the loop from u to y
    stays LTI); hopping's controller always has it."""
    return replace(scenario, controller={**scenario.controller, "ref_velocity_gain": 1.0})


def _controller_ff_metric(sc_name: str, c: dict, row: dict, dur: float, seed: int) -> dict[str, Any]:
    """ctrl_ff: passthrough with the controller's own feed-forward (hopping: that is its passthrough)."""
    if sc_name == "hopping":
        return {**row["passthrough"], "same_as_passthrough": True}
    return _metric(_policy_run(PassthroughPolicy(), controller_ff_scenario(c["scenario"]), dur, c["params"],
                               c["pushes"], seed, c["noise"]))


def evaluate_baselines(setups: dict[str, SteeringSetup], *, durations: dict[str, float],
                       ilc_iterations: dict[str, int] | None = None, reuse: dict | None = None,
                       interpreted: bool | str = False, seed: int = 3, quiet: bool = False,
                       out_dir: str | Path | None = None) -> dict[str, Any]:
    """Every condition x method per scenario; the summary.json ``baselines`` section (SI units).

    ``reuse``: {scenario: {condition: {method: metrics}}} already computed (:func:`reuse_from_summary`).
    ``out_dir``: also write ``prefilter_<scenario>.json`` and ``ilc_<scenario>.npz`` there (what
    :meth:`PrefilterPolicy.load` / :meth:`FeedforwardPolicy.load` read, e.g. on the bridge).
    """
    out: dict[str, Any] = {}
    iters = {**ILC_ITERATIONS, **(ilc_iterations or {})}
    for sc_name, setup in setups.items():
        t0 = time.perf_counter()
        dur = durations[sc_name]
        pf = fit_scenario_prefilter(setup)
        if not quiet:
            print(f"[{sc_name}] baselines: prefilter gain {np.round(pf.gain, 3).tolist()}, offset "
                  f"{np.round(pf.offset, 4).tolist()}, lead {list(pf.lead)} ticks", file=sys.stderr)
        ilc = learn_ilc(setup, pf, duration=dur, iterations=iters[sc_name], seed=seed, quiet=quiet)
        policies = {"passthrough": PassthroughPolicy(), "prefilter": PrefilterPolicy(pf), "ilc": ilc.policy}
        files = []
        if out_dir is not None:
            Path(out_dir).mkdir(parents=True, exist_ok=True)
            files = [pf.save(Path(out_dir) / f"prefilter_{sc_name}.json"),
                     ilc.policy.save(Path(out_dir) / f"ilc_{sc_name}.npz")]
            files = [str(f.resolve().relative_to(ROOT)) if f.resolve().is_relative_to(ROOT) else str(f) for f in files]
        rows: dict[str, Any] = {}
        for cname, c in conditions(sc_name).items():
            reused = (reuse or {}).get(sc_name, {}).get(cname, {})
            rows[cname] = row = _condition_row(sc_name, c, setup, policies, reused, dur, seed, interpreted)
            row["reused"] = sorted(reused)
            if not quiet:
                k = _key(sc_name)
                print(f"[{sc_name}] baselines, {cname}: " + ", ".join(
                    f"{mm} {row[mm].get(k, float('nan')) * 1e3:.2f}" for mm in METHODS) + " mm", file=sys.stderr)
        out[sc_name] = {
            "metric": _key(sc_name),
            "prefilter": pf.to_dict(),
            "ilc": {"iterations_run": iters[sc_name], "iterations_to_settle": ilc.iterations,
                    "metric_per_iteration": ilc.metric, "learned_on": next(iter(rows)), "wall_s": ilc.wall_s,
                    "law": "P-type, per channel lead d and gain 1/g from the prefilter, zero-phase 2nd-order "
                           "Butterworth Q-filter at 1 Hz"},
            "conditions": rows,
            "duration_s": dur,
            "files": files,
            "wall_s": round(time.perf_counter() - t0, 1),
        }
    return out


def format_baselines(b: dict[str, Any]) -> str:
    """The baselines table: key metric per condition and method [mm], and the best of passthrough,
    the controller's own feed-forward, prefilter and ILC divided by DDPC's (> 1: steering is better)."""
    head = ("scenario", "condition", "metric", *METHODS, "best simple / ddpc")
    rows = []
    for sc, blk in b.items():
        label = "RMSE z [mm]" if blk["metric"] == "rmse_z" else "mean |apex err| [mm]"
        for cname, row in blk["conditions"].items():
            vals = {mm: row[mm].get(blk["metric"]) for mm in METHODS}
            cells = []
            for mm in METHODS:
                v = vals[mm]
                txt = "crash" if row[mm].get("crashed") else ("-" if v is None or not np.isfinite(v) else f"{v * 1e3:.2f}")
                if mm == "ilc" and not row["ilc_learned_here"]:
                    txt += "*"
                cells.append(txt)
            simple = [vals[mm] for mm in SIMPLE
                      if vals[mm] is not None and np.isfinite(vals[mm]) and not row[mm].get("crashed")]
            d = vals["ddpc"]
            ratio = f"{min(simple) / d:.1f}x" if simple and d and np.isfinite(d) else "-"
            rows.append((sc, cname, label, *cells, ratio))
    w = [max(len(h), *(len(r[i]) for r in rows)) for i, h in enumerate(head)]
    line = lambda r: "| " + " | ".join(c.rjust(w[i]) if i > 2 else c.ljust(w[i]) for i, c in enumerate(r)) + " |"  # noqa: E731
    sep = "|" + "|".join(("-" * (w[i] + 1) + ":") if i > 2 else ("-" * (w[i] + 2)) for i in range(len(head))) + "|"
    notes = ["* ILC's last iteration learned on the periodic case, flown unchanged here"]
    for sc, blk in b.items():
        il = blk.get("ilc")
        if il:
            per = ", ".join(f"{v * 1e3:.2f}" for v in il["metric_per_iteration"])
            notes.append(f"ILC {sc}: {per} mm per iteration (0 = unmodified; within 10 % of the best at "
                         f"iteration {il['iterations_to_settle']}; the last one is flown)")
        if blk["metric"] != "rmse_z":  # hopping: the velocity a height correction must not spoil
            for cname, row in blk["conditions"].items():
                vx = [f"{mm} " + (f"{row[mm]['vx_error_mean_abs'] * 1e3:.1f}" if "vx_error_mean_abs" in row[mm] else "-")
                      for mm in METHODS if mm != "ctrl_ff"]
                step = [f"{mm} " + ("-" if (v := offset_step(row[mm])) is None else f"{v * 1e3:.2f}")
                        for mm in METHODS if mm != "ctrl_ff"]
                notes.append(f"mean |vx err| [mm/s] {sc}, {cname}: " + ", ".join(vx)
                             + "; z_ref offset step rms [mm]: " + ", ".join(step))
    return "\n".join([line(head), sep] + [line(r) for r in rows] + notes)
