"""``ddpc-codegen simulate`` and ``ddpc-codegen collect`` subcommands.

    ddpc-codegen simulate --scenario flying --duration 30 --json
    ddpc-codegen simulate --scenario hopping --apex 0.7 --velocity 0.3 --plot reports/hop.png
    ddpc-codegen collect --scenario flying --duration 60 --amplitude 0.05,0.03 -o data/fly.npz
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from typing import Any

from ddpc_codegen.errors import ConfigError
from ddpc_codegen.design.data import output_path
from ddpc_codegen.sim.loop import Excitation, Push, default_excitation, simulate
from ddpc_codegen.sim.params import PogoXParams
from ddpc_codegen.sim.scenarios import get_scenario

__all__ = ["register"]


def _floats(text: str, what: str) -> list[float]:
    try:
        return [float(v) for v in text.split(",") if v.strip() != ""]
    except ValueError:
        raise ConfigError(f"{what} must be comma-separated numbers; got {text!r}") from None


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenario", choices=("flying", "hopping"), default="flying", help="scenario (default flying)")
    p.add_argument("--duration", type=float, default=None, help="simulated seconds (simulate: 30, collect: 60)")
    p.add_argument("--seed", type=int, default=0, help="seed of noise and PRBS (runs are deterministic)")
    p.add_argument("--mass-error", type=float, default=-0.2, help="controller model mass minus true mass [kg] (default -0.2)")
    p.add_argument("--twr", type=float, default=None, help="thrust-to-weight ratio (default 1.25; the battery-carrying robot: 0.82)")
    p.add_argument("--noise", action="store_true", help="add sensor noise (SensorNoise defaults)")
    p.add_argument("--delay", type=float, default=None, help="measurement delay [s] (default 0.005)")
    p.add_argument(
        "--push", action="append", default=[], metavar="T,FX,FY,FZ[,DUR]",
        help="external force push at time T [s], force [N] world frame, duration DUR [s] (default 0.1); repeatable",
    )
    p.add_argument("--apex", type=float, default=None, help="hopping: target apex height [m] (default 0.7)")
    p.add_argument("--velocity", type=float, default=None, help="hopping: target forward velocity [m/s] (default 0.3)")
    p.add_argument("--plot", default=None, metavar="PATH", help="write a figure (x-z path, outputs vs time)")
    p.add_argument("--json", action="store_true", help="print the metrics as JSON on stdout")
    p.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")


def register(subparsers: Any) -> None:
    """Add ``simulate`` and ``collect`` to the ddpc-codegen command."""
    sp = subparsers.add_parser(
        "simulate",
        help="simulate PogoX (flying ellipse or periodic hopping) with the model-based controller",
        description="Closed-loop PogoX simulation: height & leg angle controller -> PX4-like flight controller -> hybrid plant.",
    )
    _common(sp)
    sp.set_defaults(func=_cmd_simulate)

    cp = subparsers.add_parser(
        "collect",
        help="collect PRBS-excited closed-loop IO data as an IODataset .npz",
        description="Simulate with a PRBS added to the references and write (u = references, y = outputs) as an IODataset.",
    )
    _common(cp)
    cp.add_argument("-o", "--out", required=True, help="output .npz path")
    cp.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    cp.add_argument("--amplitude", default=None, help="PRBS amplitude per input channel, comma-separated (m, rad); default by scenario")
    cp.add_argument("--min-hold", type=int, default=4, help="PRBS bit length in control ticks (default 4 = 20 ms)")
    cp.add_argument("--split", choices=("auto", "none", "hops", "aerial"), default="auto", help="trajectory split (hopping default: hops)")
    cp.set_defaults(func=_cmd_collect)


def _setup(args: argparse.Namespace, default_duration: float):
    changes: dict[str, Any] = {"controller_mass_error": float(args.mass_error)}
    if args.twr is not None:
        changes["thrust_to_weight"] = float(args.twr)
    if args.delay is not None:
        changes["meas_delay"] = float(args.delay)
    try:
        params = PogoXParams(**changes)
    except ValueError as e:
        raise ConfigError(str(e)) from None
    over: dict[str, Any] = {}
    if args.scenario == "hopping":
        if args.apex is not None:
            over["apex_height"] = float(args.apex)
        if args.velocity is not None:
            over["target_velocity"] = (float(args.velocity), 0.0)
    elif args.apex is not None or args.velocity is not None:
        raise ConfigError("--apex/--velocity apply to --scenario hopping only")
    scenario = get_scenario(args.scenario, **over)
    pushes = []
    for text in args.push:
        v = _floats(text, "--push")
        if len(v) not in (4, 5):
            raise ConfigError(f"--push needs T,FX,FY,FZ[,DUR]; got {text!r}")
        pushes.append(Push(v[0], (v[1], v[2], v[3]), v[4] if len(v) == 5 else 0.1))
    duration = float(args.duration) if args.duration is not None else default_duration
    if not (duration > 0 and math.isfinite(duration)):
        raise ConfigError(f"--duration must be a positive number of seconds; got {duration}")
    return params, scenario, pushes, duration


def _print_metrics(m: dict[str, Any], as_json: bool) -> None:
    if as_json:
        print(json.dumps(m, indent=2, sort_keys=True))
        return
    for k in sorted(m):
        v = m[k]
        if isinstance(v, list) and len(v) > 6:
            v = f"[{len(v)} values]"
        elif isinstance(v, float):
            v = f"{v:.4g}"
        print(f"{k:>24s}: {v}")


def _cmd_simulate(args: argparse.Namespace) -> int:
    params, scenario, pushes, duration = _setup(args, 30.0)
    res = simulate(
        scenario, duration, params=params, seed=args.seed, noise=args.noise or None,
        pushes=pushes, progress=not args.no_progress,
    )
    m = res.metrics()
    if args.plot:
        from ddpc_codegen.sim.plots import plot_result, save_figure

        m["plot"] = str(save_figure(plot_result(res), args.plot))
    _print_metrics(m, args.json)
    return 1 if res.crashed else 0


def _cmd_collect(args: argparse.Namespace) -> int:
    output_path(args.out, args.overwrite)  # refused before the simulation, not after it
    params, scenario, pushes, duration = _setup(args, 60.0)
    m_in = 2 if args.scenario == "flying" else 3
    if args.amplitude is None:
        amp = default_excitation(args.scenario).amplitude
    else:
        amp = _floats(args.amplitude, "--amplitude")
        if len(amp) == 1:
            amp = amp * m_in
        if len(amp) != m_in:
            raise ConfigError(f"--amplitude needs 1 or {m_in} values for {args.scenario}; got {len(amp)}")
    if args.min_hold < 1:
        raise ConfigError(f"--min-hold must be >= 1; got {args.min_hold}")
    exc = Excitation(amplitude=tuple(amp), min_hold=args.min_hold)
    res = simulate(
        scenario, duration, params=params, seed=args.seed, excitation=exc, noise=args.noise or None,
        pushes=pushes, progress=not args.no_progress,
    )
    if res.crashed:
        print(
            f"ddpc-codegen collect: the robot was lost ({res.crash_reason}); lower --amplitude",
            file=sys.stderr,
        )
        return 1
    ds = res.to_dataset(
        args.split,
        metadata={"excitation": {"amplitude": list(map(float, amp)), "min_hold": args.min_hold}, "duration": duration},
    )
    path = ds.save(args.out, overwrite=args.overwrite)
    m = res.metrics()
    m.update(dataset=str(path), n_trajectories=ds.n_trajectories, n_samples=ds.n_samples)
    if args.plot:
        from ddpc_codegen.sim.plots import plot_result, save_figure

        m["plot"] = str(save_figure(plot_result(res), args.plot))
    _print_metrics(m, args.json)
    if not args.json:
        print(f"wrote {ds!r} to {path}", file=sys.stderr)
    return 0
