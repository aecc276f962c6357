"""``ddpc-codegen fit``: one predictor from many data files (a fleet's logs), serial or on Ray, then
the steering solver generated as ``codegen`` does.

    ddpc-codegen fit configs/flying.toml logs/*.npz --workers 2
    ddpc-codegen fit configs/flying.toml logs/ --address auto --no-codegen     # a folder = its *.npz
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from ddpc_codegen.errors import ConfigError
from ddpc_codegen.pipeline.solver_build import FleetOptions, build_solver
from ddpc_codegen.values.config import SteeringConfig
from ddpc_codegen.values.files import checked_output_folder

__all__ = ["register", "expand_paths"]


def expand_paths(items: list[str]) -> list[Path]:
    """Files as given; a folder stands for its ``*.npz`` files (sorted: the fit's piece order)."""
    out: list[Path] = []
    for item in items:
        p = Path(item)
        if p.is_dir():
            found = sorted(p.glob("*.npz"))
            if not found:
                raise ConfigError(f"{p} holds no .npz dataset file")
            out += found
        elif p.exists():
            out.append(p)
        else:
            raise ConfigError(f"dataset file {p} does not exist")
    return out


def _cmd_fit(args: argparse.Namespace) -> int:
    say = (lambda msg: None) if args.quiet else (lambda msg: print(msg, file=sys.stderr, flush=True))
    cfg = SteeringConfig.from_toml(args.config)
    if not args.no_codegen:
        checked_output_folder(args.out, "--out")
    paths = expand_paths(args.data)
    say(f"[{cfg.name}] {len(paths)} files, Tini={cfg.t_ini} Tf={cfg.t_f} {cfg.predictor['method']}, "
        f"{args.workers} worker(s){' on ' + args.address if args.address else ''}")
    out = None if args.no_codegen else Path(args.out) / cfg.name
    built = build_solver(cfg, paths, out, backend=args.backend, log=say,
                         fleet=FleetOptions(args.workers, args.address, args.chunk_columns))
    pred = built.problem.predictor
    fleet = dict(built.report["fleet"])
    summary = fleet.pop("summary")
    report: dict[str, Any] = {**fleet, "rank": pred.rank, "predictor_digest": pred.digest}
    if built.path is not None:
        say(f"  generated + compiled {built.path}/ in {built.report['codegen_s']:.1f} s")
        report["solver"] = str(built.path)
    print(json.dumps(report, indent=2) if args.json else (report.get("solver") or summary))
    return 0


def register(subparsers: Any) -> None:
    """Add ``fit`` to the ddpc-codegen command."""
    p = subparsers.add_parser(
        "fit",
        help="fit one predictor from many dataset files (map/reduce, serial or on Ray) and generate the solver",
        description="Per file (or slice of a long trajectory) an R factor of its Hankel rows as one task, a "
                    "reduction tree of QRs, the predictor; files too short for one Hankel column are skipped "
                    "with a message. Then the steering solver is generated as `ddpc-codegen codegen` does.",
    )
    p.add_argument("config", help="steering config TOML (horizons, [predictor] options)")
    p.add_argument("data", nargs="+", help="IODataset .npz files, or folders of them")
    p.add_argument("--workers", type=int, default=1,
                   help="parallel tasks: 1 = serial in this process (default); N = a local Ray runtime on 127.0.0.1")
    p.add_argument("--address", default=None, help="an existing Ray cluster (e.g. auto, ray://head:10001)")
    p.add_argument("--chunk-columns", type=int, default=2**18, help="Hankel columns per task at most (memory bound)")
    p.add_argument("--out", default="generated", help="output root of the generated solver (default generated/)")
    p.add_argument("--backend", choices=("daqp", "osqp"), default=None, help="override the config's backend")
    p.add_argument("--no-codegen", action="store_true", help="fit and report only")
    p.add_argument("--json", action="store_true", help="print the fit report as JSON")
    p.add_argument("--quiet", action="store_true")
    p.set_defaults(func=_cmd_fit)
