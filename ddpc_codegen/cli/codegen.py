"""``ddpc-codegen codegen``: TOML config(s) + dataset -> generated/<name>/ (C sources, extension, manifest).

    ddpc-codegen codegen configs/flying.toml
    ddpc-codegen codegen configs/flying.toml --dataset data/flight1.npz --backend osqp --out generated
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

from ddpc_codegen.design.config import SteeringConfig
from ddpc_codegen.design.data import IODataset
from ddpc_codegen.errors import ConfigError, DataError
from ddpc_codegen.design.predictor import fit_predictor
from ddpc_codegen.design.problem import SteeringProblem
from ddpc_codegen.codegen import BACKENDS, generate

__all__ = ["register", "build_from_config"]


def build_from_config(config: SteeringConfig, dataset: str | Path | None = None,
                      log=lambda msg: None) -> SteeringProblem:
    """Config + dataset file -> SteeringProblem (predictor fitted with the config's [predictor] options)."""
    path = dataset or config.dataset
    if not path:
        raise ConfigError(f"{config.source}: no dataset: give --dataset or set [data] dataset in the config")
    ds = IODataset.load(path)
    if ds.metadata.get("fit_ok") is False:
        # A bridge tick log without closed-loop data (firmware_bridge.ticklog): fitting on it
        # would splice gaps, stale stretches and mode changes into one trajectory.
        raise DataError(f"{path} is marked unfit for fitting: {ds.metadata.get('unfit_reason', 'no reason given')}")
    if (ds.m, ds.p) != (config.m, config.p):
        raise ConfigError(
            f"{config.source}: the config has {config.m} inputs {list(config.input_names)} and {config.p} outputs "
            f"{list(config.output_names)}, but {path} has m={ds.m} {list(ds.input_names)}, p={ds.p} {list(ds.output_names)}"
        )
    if config.input_names and ds.input_names != config.input_names:
        log(f"  note: dataset inputs {list(ds.input_names)} are used as config inputs {list(config.input_names)}")
    opts = {k: v for k, v in config.predictor.items() if k != "method"}
    t0 = time.perf_counter()
    pred = fit_predictor(ds, config.t_ini, config.t_f, config.predictor["method"], **opts)
    pe = pred.excitation()
    log(f"  data: {ds.n_trajectories} trajectories, {ds.n_samples} samples -> {pred.n_columns} Hankel columns")
    log(f"  excitation: {pe.summary()}")
    log(f"  predictor: {pred.method}, rank {pred.rank}, fitted in {time.perf_counter() - t0:.2f} s")
    return SteeringProblem(pred, config)


def _cmd_codegen(args: argparse.Namespace) -> int:
    say = (lambda msg: None) if args.quiet else (lambda msg: print(msg, file=sys.stderr))
    for cfg_path in args.configs:
        cfg = SteeringConfig.from_toml(cfg_path)
        backend = args.backend or cfg.codegen["backend"]
        say(f"[{cfg.name}] {cfg_path}: m={cfg.m} p={cfg.p} Tini={cfg.t_ini} Tf={cfg.t_f} backend={backend}")
        prob = build_from_config(cfg, args.dataset, say)
        out = Path(args.out) / cfg.name
        t0 = time.perf_counter()
        generate(prob, out, backend, march_native=args.march_native or None)
        say(f"  generated + compiled {out}/ in {time.perf_counter() - t0:.1f} s "
            f"({prob.n_u} variables, {prob.n_theta} parameters, {prob.n_g} general constraints)")
        print(out)
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
    p.add_argument("--backend", choices=BACKENDS, default=None, help="override the config's [codegen] backend")
    p.add_argument("--out", default="generated", help="output root (default generated/)")
    p.add_argument("--march-native", action="store_true", help="opt-in -march=native (binary tied to this CPU)")
    p.add_argument("--quiet", action="store_true", help="print only the output folders")
    p.set_defaults(func=_cmd_codegen)
