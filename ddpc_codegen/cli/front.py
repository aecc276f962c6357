"""``ddpc-codegen front``: how well the identified loop can follow a path at each reference activity, and
where the config's steering sits against that.

    ddpc-codegen front configs/sitl_ardupilot.toml --dataset collect.npz --trajectory steps.csv
    ddpc-codegen front cfg.toml --dataset collect.npz --trajectory path.toml --duration 12 --json front.json

The predictor is fitted as ``codegen`` fits it (no solver is generated); the path's output channel
(default: the config's first output, e.g. ``z``) is taken from the trajectory, every other output's
desired value is 0. Prints the front (error RMS at each reference activity, the activity relative to the
path's own: passthrough's), the passthrough point and the config's steering flown on the predictor (the
predictor as its own plant, no noise): see :mod:`ddpc_codegen.design.front`.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any


from ddpc_codegen.design.front import desired_from_trajectory, front_report
from ddpc_codegen.errors import ConfigError
from ddpc_codegen.pipeline.solver_build import build_from_config
from ddpc_codegen.robot.trajectory_files import load_trajectory
from ddpc_codegen.values.config import SteeringConfig

__all__ = ["register"]


def _cmd_front(args: argparse.Namespace) -> int:
    say = lambda msg: print(msg, file=sys.stderr, flush=True)  # noqa: E731
    cfg = SteeringConfig.from_toml(args.config)
    output = args.output or cfg.output_names[0]
    desired, out_idx = desired_from_trajectory(cfg, load_trajectory(args.trajectory), output, args.duration)
    if desired.shape[0] > 6000:
        raise ConfigError(f"{desired.shape[0]} samples: the front is dense (n x n); give --duration <= "
                          f"{6000 * cfg.dt:g} s")
    in_idx = out_idx if out_idx < cfg.m else 0  # the reference of the same channel
    say(f"[{cfg.name}] fitting the predictor ({cfg.predictor['method']}, Tini={cfg.t_ini} Tf={cfg.t_f}) ...")
    problem = build_from_config(cfg, args.dataset)
    say(f"  {desired.shape[0]} samples of {output}; steering {cfg.input_names[in_idx]}")
    rep = front_report(problem, desired, in_idx, out_idx, log=say)
    unit = cfg.output_units[out_idx] if cfg.output_units else ""
    print(f"{'reference activity / passthrough':>34}  {output} error RMS [{unit}]")
    for p in rep["front"]:
        print(f"{p['rate_ratio']:34.2f}  {p['error_rms']:.4g}")
    for k in ("passthrough", "steered"):
        p = rep[k]
        label = f"{k} {p['rate_ratio']:.2f}"
        print(f"{label:>34}  {p['error_rms']:.4g}  (the front at this activity: {p['front_error_at_this_rate']:.4g})")
    g = rep["step_gain"]
    print(f"step gain of the predictor as the plant {g['chained']:.3f}, of its multi-step prediction {g['predicted']:.3f}"
          + ("" if abs(g["chained"] - g["predicted"]) <= 0.1 * abs(g["predicted"]) else
             " (far apart: the steering plans with a loop other than the one it is flown on here)"))
    if args.json:
        Path(args.json).write_text(json.dumps(rep, indent=2))
    return 0


def register(subparsers: Any) -> None:
    """Add ``front`` to the ddpc-codegen command."""
    p = subparsers.add_parser(
        "front", help="the identified loop's tracking error at each reference activity on a path, and the steering's",
        description="Fit the predictor as codegen does; on a trajectory's output channel, the least error any "
                    "reference reaches at each activity (tick-to-tick change relative to the path's own), "
                    "passthrough's point and the config's steering flown on the predictor.")
    p.add_argument("config", help="steering config TOML")
    p.add_argument("--dataset", default=None, help="IODataset .npz (default: the config's [data] dataset)")
    p.add_argument("--trajectory", required=True, help="trajectory file (.csv / .toml)")
    p.add_argument("--output", default=None, help="the output channel to follow (default: the config's first)")
    p.add_argument("--duration", type=float, default=None, help="seconds of the path from its start (default: all)")
    p.add_argument("--json", default=None, help="also write the figures to this JSON file")
    p.set_defaults(func=_cmd_front)
