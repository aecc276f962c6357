"""``ddpc-codegen sweep``: a tuning sweep from a spec TOML, serial or on Ray.

    ddpc-codegen sweep configs/sweeps/flying_weights.toml --workers 2
    ddpc-codegen sweep SPEC.toml --out reports/sweeps/x --resume        # continue an interrupted sweep
    ddpc-codegen sweep SPEC.toml --address auto                         # an existing Ray cluster
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any
from ddpc_codegen.experiments.sweep import run_sweep
from ddpc_codegen.values.files import checked_output_folder
from ddpc_codegen.experiments.sweep_spec import SweepSpec

__all__ = ["register"]


def _cmd_sweep(args: argparse.Namespace) -> int:
    spec = SweepSpec.from_toml(args.spec)
    out = checked_output_folder(Path(args.out) if args.out else Path("reports") / "sweeps" / Path(args.spec).stem,
                                "--out")
    try:
        s = run_sweep(spec, out, workers=args.workers, address=args.address, resume=args.resume,
                      progress=not args.quiet)
    except KeyboardInterrupt:
        print(f"\ninterrupted: finished points are in {out / 'results.csv'}; continue with --resume",
              file=sys.stderr)
        return 130
    print(f"{s['points']} points ({s['ran']} run now, {s['resumed_from']} before, {s['errors']} with errors) "
          f"in {s['wall_s']:.1f} s on {s['workers']} worker(s)")
    print(f"table: {s['results']}")
    if s.get("best"):
        print(f"best ({spec.objective} {s['best_' + spec.objective]:.4g}): {s['best']}")
        print(f"config: {s['best_toml']}  (ddpc-codegen codegen {s['best_toml']})")
    if s.get("pareto_png"):
        print(f"pareto: {s['pareto_png']}")
    return 0


def register(subparsers: Any) -> None:
    """Add ``sweep`` to the ddpc-codegen command."""
    p = subparsers.add_parser(
        "sweep",
        help="tuning sweep (grid / random) of steering-config fields x conditions x seeds, serial or on Ray",
        description="Each point: fit (cached), generated solver (cached per config), one closed-loop run. Writes "
                    "results.csv, pareto.png and best.toml (ready for `ddpc-codegen codegen`) into --out. "
                    "The spec format is documented in ddpc_codegen/experiments/sweep_spec.py.",
    )
    p.add_argument("spec", help="sweep spec TOML")
    p.add_argument("--out", default=None, help="output folder (default reports/sweeps/<spec name>)")
    p.add_argument("--workers", type=int, default=1,
                   help="parallel tasks: 1 = serial in this process (default); N = a local Ray runtime on 127.0.0.1")
    p.add_argument("--address", default=None,
                   help="an existing Ray cluster (e.g. auto, ray://head:10001) instead of a local runtime")
    p.add_argument("--resume", action="store_true", help="continue the sweep in --out (finished points are kept)")
    p.add_argument("--quiet", action="store_true", help="no progress output")
    p.set_defaults(func=_cmd_sweep)
