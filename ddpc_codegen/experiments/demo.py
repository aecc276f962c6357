"""``make demo``: the project's main job, end to end on the simulator.

For flying (the paper's sagittal ellipse) and periodic hopping, under the paper's -200 g model
mass error: record PRBS-excited data, fit the predictor (hopping: artificial ground-phase IO and
the mosaic H_G), generate and compile the steering solver, run the scenario without and with
steering (the generated C solver in the loop), then the robustness runs (sensor noise, pushes,
mass errors the data never saw). Prints a table, writes ``reports/summary.json`` and PNG figures.

    python -m ddpc_codegen.experiments.demo                 # what `make demo` runs
    ddpc-codegen demo --interpreted             # same, steering solved in Python (for comparison)
    ddpc-codegen evaluate --scenario hopping --noise --mass-error -0.3 --push 6,3,0,-10,0.1
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import platform
import sys
import time
from pathlib import Path
from typing import Any

from ddpc_codegen.values.config import SteeringConfig
from ddpc_codegen.errors import ConfigError, DDPCError
from ddpc_codegen.experiments.demo_figures import demo_figures
from ddpc_codegen.experiments.evaluate import RunResult, offset_step, prediction_check, run
from ddpc_codegen.experiments.report_file import update_report
from ddpc_codegen.experiments.pipeline import ROOT, CollectSpec, SteeringSetup, build_setup, default_config, say
from ddpc_codegen.sim import PogoXParams, Push
from ddpc_codegen.experiments.baselines_eval import evaluate_baselines, reuse_from_summary
from ddpc_codegen.experiments.baselines_eval import format_baselines

__all__ = ["run_demo", "format_table", "summary_block", "main", "register", "DURATIONS", "ROBUSTNESS"]

DURATIONS = {"flying": 30.0, "hopping": 20.0}  # evaluation runs [s] (flying: 3 s settle + 2.7 laps)

# Robustness conditions: name -> run keyword arguments (same seed for baseline and steered).
ROBUSTNESS: dict[str, dict[str, dict[str, Any]]] = {
    "flying": {
        "sensor noise": {"noise": True},
        # 10 N down on the body for 0.2 s, then 8 N forward on the leg (0.3 m below the COM) for 0.1 s.
        # (A 20 N / 0.2 s shove saturates the thrust while steering; the linear predictor does not
        # know the limit, and the steered pitch error then exceeds the baseline's.)
        "push": {"pushes": [Push(12.0, (0.0, 0.0, -10.0), 0.2), Push(20.0, (8.0, 0.0, 0.0), 0.1, (0.0, 0.0, -0.3))]},
        "mass -100 g": {"params": PogoXParams(controller_mass_error=-0.1)},
        "mass -300 g": {"params": PogoXParams(controller_mass_error=-0.3)},
    },
    "hopping": {
        "sensor noise": {"noise": True},
        # 8 N down + 3 N forward on the body in the air, then 3 N sideways on the leg.
        "push": {"pushes": [Push(8.1, (3.0, 0.0, -8.0), 0.1), Push(14.2, (0.0, 3.0, 0.0), 0.1, (0.0, 0.0, -0.3))]},
        "mass -100 g": {"params": PogoXParams(controller_mass_error=-0.1)},
        "mass -300 g": {"params": PogoXParams(controller_mass_error=-0.3)},
    },
}


def _num(x: Any) -> float | None:
    return None if x is None or (isinstance(x, float) and not math.isfinite(x)) else float(x)


# ----------------------------------------------------------------------------- summary
def summary_block(scenario: str, baseline: RunResult, steered: RunResult) -> dict[str, Any]:
    """The stable per-scenario block of reports/summary.json (SI units, radians, µs)."""
    keys = ("rmse_z", "rmse_pitch") if scenario == "flying" else ("apex_error_mean_abs", "rmse_pitch", "vx_error_mean_abs")
    extra = ("rmse_x", "mean_z_error") if scenario == "flying" else ("rmse_z", "rmse_roll", "apex_error_mean_signed", "apex_error_max_abs", "n_hops")
    pick = lambda m: {**{k: (int(m[k]) if k == "n_hops" and k in m else _num(m.get(k))) for k in keys + extra},  # noqa: E731
                      "offset_step_rms": [_num(v) for v in m.get("offset_step_rms") or []],
                      "thrust_limit_share": _num(m.get("thrust_limit_share"))}
    st = steered.steering or {}
    reasons = st.get("fallback_reasons", {})
    solver_failures = sum(v for k, v in reasons.items() if k.startswith(("solver_", "exception", "nonfinite_solution")))
    return {
        "baseline": pick(baseline.metrics),
        "steered": pick(steered.metrics),
        "solve_us": {"median": _num(st.get("solve_us", {}).get("p50")), "p99": _num(st.get("solve_us", {}).get("p99")),
                     "solver_median": _num(st.get("solver_us", {}).get("p50")),
                     "solver_p99": _num(st.get("solver_us", {}).get("p99"))},
        "fallbacks": int(st.get("fallbacks", 0)),
        "fallback_reasons": dict(reasons),
        "solver_failures": int(solver_failures),
        "steered_ticks": int(st.get("steered", 0)),
        "solver": st.get("solver"),
        "crashed": {"baseline": bool(baseline.metrics.get("crashed")), "steered": bool(steered.metrics.get("crashed"))},
    }


def _fmt(v: float | None, scale: float, digits: int = 1) -> str:
    return "-" if v is None or not math.isfinite(v) else f"{v * scale:.{digits}f}"


def format_table(summary: dict[str, Any]) -> str:
    """The main table (mm, mrad, mm/s, µs)."""
    head = ("scenario", "run", "RMSE z [mm]", "RMSE pitch [mrad]", "RMSE roll [mrad]", "mean |apex err| [mm]",
            "mean |vx err| [mm/s]", "solve med / p99 [us]", "fallbacks")
    rows = []
    for sc in ("flying", "hopping"):
        if sc not in summary:
            continue
        b = summary[sc]
        for run_name in ("baseline", "steered"):
            m = b[run_name]
            solve = "-"
            fb = "-"
            if run_name == "steered":
                s = b["solve_us"]
                solve = f"{_fmt(s['median'], 1)} / {_fmt(s['p99'], 1)}"
                fb = str(b["fallbacks"])
            rows.append((sc, run_name, _fmt(m.get("rmse_z"), 1e3), _fmt(m.get("rmse_pitch"), 1e3, 2),
                         _fmt(m.get("rmse_roll"), 1e3, 2), _fmt(m.get("apex_error_mean_abs"), 1e3, 2),
                         _fmt(m.get("vx_error_mean_abs"), 1e3), solve, fb))
    return _grid(head, rows)


def _grid(head: tuple[str, ...], rows: list[tuple[str, ...]]) -> str:
    w = [max(len(h), *(len(r[i]) for r in rows)) for i, h in enumerate(head)] if rows else [len(h) for h in head]
    line = lambda r: "| " + " | ".join(c.rjust(w[i]) if i > 1 else c.ljust(w[i]) for i, c in enumerate(r)) + " |"  # noqa: E731
    sep = "|" + "|".join(("-" * (w[i] + 1) + ":") if i > 1 else ("-" * (w[i] + 2)) for i in range(len(head))) + "|"
    return "\n".join([line(head), sep] + [line(r) for r in rows])


def format_robustness(rob: dict[str, Any]) -> str:
    """Robustness table: the scenario's key metrics, baseline -> steered, per condition."""
    head = ("scenario", "condition", "metric", "baseline", "steered", "ratio", "fallbacks")
    rows = []
    for sc, conds in rob.items():
        for cond, r in conds.items():
            if "error" in r:
                rows.append((sc, cond, "error", r["error"][:40], "", "", ""))
                continue
            mets = (("RMSE z [mm]", "rmse_z", 1e3), ("RMSE pitch [mrad]", "rmse_pitch", 1e3)) if sc == "flying" else (
                ("mean |apex err| [mm]", "apex_error_mean_abs", 1e3), ("RMSE pitch [mrad]", "rmse_pitch", 1e3),
                ("mean |vx err| [mm/s]", "vx_error_mean_abs", 1e3))
            mets += (("z_ref offset step rms [mm]", offset_step, 1e3),  # 0 without steering: no ratio
                     ("thrust at 0 or 1 [% of ticks]", "thrust_limit_share", 1e2))
            for i, (label, key, sc_) in enumerate(mets):
                get = key if callable(key) else (lambda m, k=key: m.get(k))
                b, s = get(r["baseline"]), get(r["steered"])
                ratio = f"{b / s:.1f}x" if b and s else "-"
                rows.append((sc if i == 0 else "", cond if i == 0 else "", label, _fmt(b, sc_, 2), _fmt(s, sc_, 2), ratio,
                             str(r["fallbacks"]) if i == 0 else ""))
    return _grid(head, rows)


# ----------------------------------------------------------------------------- the job
def run_demo(
    out_dir: str | Path = "reports",
    *,
    scenarios: tuple[str, ...] = ("flying", "hopping"),
    interpreted: bool | str = False,
    robustness: bool = True,
    figures: bool = True,
    durations: dict[str, float] | None = None,
    collect_specs: dict[str, CollectSpec] | None = None,
    generate_dir: str | Path = ROOT / "generated",
    save_data: bool = True,
    quiet: bool = False,
    baselines: bool = True,
) -> dict[str, Any]:
    """Run the demo; returns the summary dict (also written to ``<out_dir>/summary.json``)."""
    t0 = time.perf_counter()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    durations = {**DURATIONS, **(durations or {})}
    summary: dict[str, Any] = {}
    setups: dict[str, SteeringSetup] = {}
    runs: dict[str, tuple[RunResult, RunResult]] = {}
    for sc in scenarios:
        say(f"== {sc} ==", not quiet)
        setup = build_setup(sc, collect_spec=(collect_specs or {}).get(sc), generate_dir=generate_dir,
                            save_data=save_data, progress=not quiet)
        setups[sc] = setup
        say(f"[{sc}] {setup.info['excitation']}", not quiet)
        if setup.solver_path is not None:
            say(f"[{sc}] solver: {setup.solver_path} ({setup.info.get('backend')}, built in {setup.info.get('codegen_s')} s)", not quiet)
        dur = durations[sc]
        say(f"[{sc}] running {dur:.0f} s without steering ...", not quiet)
        base = run(None, sc, dur, steer=False, progress=not quiet, label="baseline")
        say(f"[{sc}] running {dur:.0f} s with steering ({'interpreted' if interpreted or setup.solver is None else 'generated C solver'}) ...", not quiet)
        steered = run(setup, sc, dur, interpreted=interpreted, progress=not quiet, label="steered")
        runs[sc] = (base, steered)
        block = summary_block(sc, base, steered)
        pc = prediction_check(setup, base.sim, stride=7)
        block["setup"] = {**{k: v for k, v in setup.info.items() if k != "config"},
                          "config": str(Path(setup.config.source).relative_to(ROOT)) if Path(setup.config.source).is_relative_to(ROOT) else setup.config.source,
                          "solver_path": str(setup.solver_path.relative_to(ROOT)) if setup.solver_path and setup.solver_path.is_relative_to(ROOT) else (str(setup.solver_path) if setup.solver_path else None),
                          "heldout_prediction_rmse": pc["rmse"], "heldout_windows": pc["windows"],
                          "t_ini": setup.config.t_ini, "t_f": setup.config.t_f}
        if sc == "hopping":
            block["setup"]["artificial_io_online"] = steered.steering.get("artificial_io") if steered.steering else None
        block["duration_s"] = dur
        summary[sc] = block
    noisy: dict[str, RunResult] = {}  # the robustness runs' steered "sensor noise" run (a figure)
    if robustness:
        summary["robustness"] = _robustness(setups, scenarios, durations, interpreted, quiet, noisy)
    if baselines:
        # Prefilter, ILC and a non-repeating case beside passthrough and steering (experiments/baselines_eval.py);
        # the runs above that are the same simulations are reused, not repeated.

        say("baselines: prefilter, ILC, non-repeating trajectories ...", not quiet)
        summary["baselines"] = evaluate_baselines(setups, durations=durations, reuse=reuse_from_summary(summary),
                                                  interpreted=interpreted, quiet=quiet, out_dir=out / "baselines")
    wall = time.perf_counter() - t0
    summary["meta"] = _meta(interpreted, wall)
    update_report(out / "summary.json", summary)
    if figures:
        summary["meta"]["figures"] = [str(Path(f).relative_to(ROOT)) if Path(f).is_relative_to(ROOT) else f
                                      for f in demo_figures(out, runs, noisy)]
        update_report(out / "summary.json", summary)
    return summary


def _robustness(setups: dict[str, SteeringSetup], scenarios: tuple[str, ...], durations: dict[str, float],
                interpreted: bool | str, quiet: bool, noisy: dict[str, RunResult] | None = None) -> dict[str, Any]:
    """Baseline vs steered under each robustness condition (same seed); errors reported, not raised.
    ``noisy`` (if given) receives each scenario's steered "sensor noise" run."""
    rob: dict[str, Any] = {}
    for sc in scenarios:
        rob[sc] = {}
        for cond, kw in ROBUSTNESS[sc].items():
            say(f"[{sc}] robustness: {cond} ...", not quiet)
            try:
                b = run(None, sc, durations[sc], steer=False, seed=3, **kw)
                s = run(setups[sc], sc, durations[sc], interpreted=interpreted, seed=3, **kw)
            except Exception as e:  # a simulator failure is reported, not fatal to the demo
                rob[sc][cond] = {"error": f"{type(e).__name__}: {e}"}
                continue
            blk = summary_block(sc, b, s)
            rob[sc][cond] = {k: blk[k] for k in ("baseline", "steered", "fallbacks", "fallback_reasons", "crashed")}
            if noisy is not None and cond == "sensor noise":
                noisy[sc] = s
    return rob


def _meta(interpreted: bool | str, wall: float) -> dict[str, Any]:
    """The summary's meta block: units, conditions, machine and metric definitions."""
    return {
        "units": "SI (m, rad, m/s); solve times in microseconds",
        "mass_error_kg": PogoXParams().controller_mass_error,
        "interpreted": bool(interpreted),
        "wall_time_s": round(wall, 1),
        "python": platform.python_version(),
        "machine": platform.machine(),
        "definitions": {
            "rmse_z, rmse_pitch (flying)": "true output minus desired, after the 3 s settle time",
            "apex_error_mean_abs": "mean over scored hops of |apex height - target| (first 3 hops skipped)",
            "rmse_pitch, rmse_roll, rmse_z (hopping)": "true minus desired over the aerial phase of the scored hops",
            "vx_error_mean_abs": "mean over hops of |average vx touchdown-to-touchdown - target|",
            "offset_step_rms": "per reference, rms of the tick-to-tick change of the steering offset u - r_nom "
                               "(flying after the settle time, hopping over the scored aerial ticks)",
            "thrust_limit_share": "fraction of the same ticks on which the controller's normalized thrust setpoint is "
                                  "clamped at 0 or 1",
            "solve_us": "median / p99 of the wall time of the solver call in the loop (Python -> C and back); "
                        "solver_median / solver_p99 from the solver's own timer",
            "fallbacks": "ticks on which the nominal reference was sent instead (solver failure, bound or step guard)",
        },
    }


# ----------------------------------------------------------------------------- CLI
def _add_demo_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", default=str(ROOT / "reports"), help="report folder (default reports/)")
    p.add_argument("--interpreted", nargs="?", const="fast", default=False, choices=("fast", "exact", "osqp"),
                   help="solve the steering QP in Python instead of the generated C solver (default method: fast)")
    p.add_argument("--scenario", choices=("flying", "hopping", "both"), default="both")
    p.add_argument("--no-robustness", action="store_true", help="skip the robustness runs")
    p.add_argument("--no-figures", action="store_true", help="skip the PNG figures")
    p.add_argument("--no-baselines", action="store_true", help="skip the prefilter / ILC / non-repeating comparison")
    p.add_argument("--quiet", action="store_true", help="no progress output on stderr")


def _cmd_demo(args: argparse.Namespace) -> int:
    t0 = time.perf_counter()
    scen = ("flying", "hopping") if args.scenario == "both" else (args.scenario,)
    summary = run_demo(args.out, scenarios=scen, interpreted=args.interpreted, robustness=not args.no_robustness,
                       figures=not args.no_figures, quiet=args.quiet, baselines=not args.no_baselines)
    print(format_table(summary))
    if "robustness" in summary:
        print()
        print(format_robustness(summary["robustness"]))
    if "baselines" in summary:
        print()
        print(format_baselines(summary["baselines"]))
    print()
    print(f"wrote {Path(args.out) / 'summary.json'}" + (
        f" and {len(summary['meta'].get('figures', []))} figures" if summary["meta"].get("figures") else ""))
    print(f"demo wall time {time.perf_counter() - t0:.0f} s")
    bad = [sc for sc in scen if summary[sc]["crashed"]["steered"] or summary[sc]["solver_failures"]]
    return 1 if bad else 0


def _parse_push(text: str) -> Push:
    try:
        v = [float(x) for x in text.split(",")]
    except ValueError:
        raise ConfigError(f"--push needs T,FX,FY,FZ[,DUR]; got {text!r}") from None
    if len(v) not in (4, 5):
        raise ConfigError(f"--push needs T,FX,FY,FZ[,DUR]; got {text!r}")
    return Push(v[0], (v[1], v[2], v[3]), v[4] if len(v) == 5 else 0.1)


def _cmd_evaluate(args: argparse.Namespace) -> int:
    scen = ("flying", "hopping") if args.scenario == "both" else (args.scenario,)
    try:
        params = PogoXParams(controller_mass_error=float(args.mass_error))
    except ValueError as e:
        raise ConfigError(str(e)) from None
    pushes = [_parse_push(t) for t in args.push]
    result: dict[str, Any] = {}
    for sc in scen:
        cfg = args.config if len(scen) == 1 and args.config else None
        if args.adapt:  # the solver must carry the online update: [adapt] enabled (the config's other values kept)
            cfg = SteeringConfig.from_toml(cfg or default_config(sc))
            cfg = cfg.replace(adapt=dataclasses.replace(cfg.adapt, enabled=True))
        setup = build_setup(sc, config=cfg, generate_dir=None if args.interpreted else ROOT / "generated",
                            save_data=False, progress=not args.quiet,
                            solver_name=f"steer_{sc}_adapt" if args.adapt else None)
        dur = args.duration or DURATIONS[sc]
        kw = dict(params=params, noise=args.noise or None, pushes=pushes, seed=args.seed, progress=not args.quiet)
        b = run(None, sc, dur, steer=False, **kw)
        s = run(setup, sc, dur, interpreted=args.interpreted, adapt=args.adapt, **kw)
        result[sc] = summary_block(sc, b, s)
        if args.adapt:
            result[sc]["adaptation"] = s.steering["adaptation"]
        if args.plot:
            from ddpc_codegen.sim.plots import plot_result, save_figure

            path = Path(args.plot)
            path = path.with_name(f"{path.stem}_{sc}{path.suffix or '.png'}") if len(scen) > 1 else path
            result[sc]["plot"] = str(save_figure(plot_result([b.sim, s.sim], ["without steering", "with steering"]), path))
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print(format_table(result))
    return 1 if any(result[sc]["crashed"]["steered"] for sc in scen) else 0


def register(subparsers: Any) -> None:
    """Add ``demo`` and ``evaluate`` to the ddpc-codegen command."""
    p = subparsers.add_parser(
        "demo",
        help="the main job: flying + hopping with and without steering, robustness runs, table, report, figures",
        description="Record data on the simulator, fit predictors (hopping: artificial ground-phase IO), generate "
                    "and compile the steering solvers, run both scenarios with and without steering under the "
                    "paper's -200 g mass error; writes reports/summary.json and PNG figures.",
    )
    _add_demo_args(p)
    p.set_defaults(func=_cmd_demo)

    e = subparsers.add_parser(
        "evaluate",
        help="one scenario, baseline vs steered, under chosen conditions (noise, pushes, mass error)",
        description="Build the steering setup (fresh data, predictor, solver) and compare baseline and steered runs.",
    )
    e.add_argument("--scenario", choices=("flying", "hopping", "both"), default="flying")
    e.add_argument("--config", default=None, help="steering config TOML (default configs/<scenario>.toml)")
    e.add_argument("--duration", type=float, default=None, help="simulated seconds (default flying 30, hopping 20)")
    e.add_argument("--mass-error", type=float, default=-0.2, help="controller model mass minus true mass [kg]")
    e.add_argument("--noise", action="store_true", help="sensor noise in the evaluation runs")
    e.add_argument("--push", action="append", default=[], metavar="T,FX,FY,FZ[,DUR]", help="external push; repeatable")
    e.add_argument("--seed", type=int, default=0)
    e.add_argument("--interpreted", nargs="?", const="fast", default=False, choices=("fast", "exact", "osqp"),
                   help="solve in Python instead of the generated C solver")
    e.add_argument("--adapt", action="store_true",
                   help="update the predictor online from steered ticks ([adapt] of the config, enabled)")
    e.add_argument("--plot", default=None, metavar="PATH", help="write a figure (baseline vs steered)")
    e.add_argument("--json", action="store_true", help="print the result as JSON")
    e.add_argument("--quiet", action="store_true")
    e.set_defaults(func=_cmd_evaluate)


def main(argv: list[str] | None = None) -> int:
    """``python -m ddpc_codegen.experiments.demo [options]`` = ``ddpc-codegen demo [options]``."""
    parser = argparse.ArgumentParser(prog="python -m ddpc_codegen.experiments.demo", description=__doc__.splitlines()[0])
    _add_demo_args(parser)
    args = parser.parse_args(argv)
    try:
        return _cmd_demo(args)
    except DDPCError as e:
        print(f"demo: error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
