"""``ddpc-codegen codegen``: TOML config(s) + dataset -> generated/<name>/ (C sources, extension, manifest).

    ddpc-codegen codegen configs/flying.toml
    ddpc-codegen codegen configs/flying.toml --dataset data/flight1.npz --backend osqp --out generated
    ddpc-codegen codegen configs/hopping.toml --dataset data/hopping_raw.npz   # raw hopping log, phases labelled
    ddpc-codegen codegen cfg.toml --dataset log.npz --map-channels z=pos_z,pitch=att_pitch

Every config is loaded and checked before any fit; the dataset must match the config's channel
names and order, units and dt (or be mapped explicitly with --map-channels). A hopping config
([artificial_io]) takes the raw hopping log: the hops are stitched here and the artifact carries the
generated artificial-IO completion.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

from ddpc_codegen.codegen.emit import BACKENDS
from ddpc_codegen.values.config import SteeringConfig
from ddpc_codegen.design.match import parse_channel_map
from ddpc_codegen.pipeline.solver_build import build_solver, noise_warning
from ddpc_codegen.values.files import checked_output_folder

__all__ = ["register", "noise_warning"]


def _share(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        v = float("nan")
    if not 0.0 <= v < 1.0:
        raise argparse.ArgumentTypeError(f"a share in [0, 1), got {text!r}")
    return v


def _cmd_codegen(args: argparse.Namespace) -> int:
    say = (lambda msg: None) if args.quiet else (lambda msg: print(msg, file=sys.stderr))
    mapping = parse_channel_map(args.map_channels)
    configs = [SteeringConfig.from_toml(p) for p in args.configs]  # every config refused before any fit
    checked_output_folder(args.out, "--out")
    for cfg_path, cfg in zip(args.configs, configs):
        backend = args.backend or cfg.codegen["backend"]
        say(f"[{cfg.name}] {cfg_path}: m={cfg.m} p={cfg.p} Tini={cfg.t_ini} Tf={cfg.t_f} backend={backend}")
        t0 = time.perf_counter()
        built = build_solver(cfg, args.dataset, Path(args.out) / cfg.name, backend=backend, channel_map=mapping,
                             march_native=args.march_native or None, holdout=args.holdout, log=say)
        prob = built.problem
        say(f"  generated + compiled {built.path}/ in {time.perf_counter() - t0:.1f} s "
            f"({prob.n_z} QP variables{'' if cfg.knots is None else f' on {len(cfg.knots)} knots'}, "
            f"{prob.n_theta} parameters, {prob.n_g} general constraints)")
        print(built.path)
    return 0


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "codegen",
        help="emit and compile steering solvers from TOML configs into generated/<name>/",
        description="Fit the predictor from the dataset, form the steering QP, emit C (CasADi parameter map + "
                    "daqp/osqp backend + exact fast path), compile a Python-loadable extension, write manifest.json.",
    )
    p.add_argument("configs", nargs="+", help="steering config TOML file(s)")
    p.add_argument("--dataset", default=None, help="IODataset .npz (default: the config's [data] dataset)")
    p.add_argument("--map-channels", default=None, metavar="CFG=DATA,...",
                   help="use dataset channel DATA as config channel CFG (names that differ on purpose; also "
                        "allows another order and extra dataset channels). Without it the dataset must have "
                        "the config's channel names in the config's order")
    p.add_argument("--backend", choices=BACKENDS, default=None, help="override the config's [codegen] backend")
    p.add_argument("--out", default="generated", help="output root (default generated/)")
    p.add_argument("--march-native", action="store_true", help="opt-in -march=native (binary tied to this CPU)")
    p.add_argument("--holdout", type=_share, default=0.2, metavar="SHARE",
                   help="keep the last SHARE of each trajectory (of stretches too short to split: the last whole "
                        "ones) out of a second fit and print how well that predictor predicts it (RMSE, persistence, "
                        "fit %%; in the manifest; ddpc-proxy's --model-watch needs it); 0 = skip (default 0.2)")
    p.add_argument("--quiet", action="store_true", help="print only the output folders")
    p.set_defaults(func=_cmd_codegen)
