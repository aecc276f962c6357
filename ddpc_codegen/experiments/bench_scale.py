"""The ``scale`` entry of reports/bench.json: a sweep and a fleet fit, serial vs Ray workers.

    python -m ddpc_codegen.experiments.bench_scale            # only this entry (merged into bench.json)
    make bench                                                 # with everything else

Sweep: 64 points (8 flying configurations x 2 conditions x 4 seeds, 8 s runs) serially, then on a
local Ray runtime with 2 workers; ``identical`` compares the two tables without their timing
columns. Fit: see :func:`fit_scaling`.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from ddpc_codegen.experiments.pipeline import ROOT

__all__ = ["sweep_scaling", "main"]

_SWEEP = f"""
[sweep]
scenario = "flying"
config = "{ROOT / 'configs' / 'flying.toml'}"
duration = 8.0
seeds = [0, 1, 2, 3]
baseline = false

[data]
duration = 30.0

[space]
"cost.R" = [[1.0, 1.0], [0.5, 0.5], [0.3, 0.3], [0.2, 0.2]]
"predictor.ridge" = [0.01, 0.001]

[conditions.nominal]
[conditions.noisy]
noise = true
"""


def sweep_scaling(workers: int = 2, log=print) -> dict[str, Any]:
    """64-point sweep, serial then ``workers`` Ray workers; wall times include Ray's start-up."""
    from ddpc_codegen.experiments.sweep import TIMING_COLUMNS, _training_data, read_results, run_sweep
    from ddpc_codegen.experiments.sweep_spec import SweepSpec

    with tempfile.TemporaryDirectory() as tmp:
        spec = Path(tmp) / "bench_sweep.toml"
        spec.write_text(_SWEEP)
        # Record the training data once, outside both timings (both sweeps read it from data.npz).
        _training_data(SweepSpec.from_toml(spec), Path(tmp) / "warm", lambda msg: None)
        out: dict[str, Any] = {}
        tables = []
        for name, w in (("serial", 1), ("parallel", workers)):
            folder = Path(tmp) / name
            folder.mkdir()
            (folder / "data.npz").write_bytes((Path(tmp) / "warm" / "data.npz").read_bytes())
            log(f"  sweep, {name} ({w} worker(s)) ...")
            t0 = time.perf_counter()
            s = run_sweep(spec, folder, workers=w, progress=False, report=False)
            out[f"{name}_s"] = round(time.perf_counter() - t0, 2)
            out["points"] = s["points"]
            rows = read_results(folder / "results.csv")
            tables.append([{k: v for k, v in r.items() if k not in TIMING_COLUMNS} for r in rows])
            out[f"{name}_errors"] = s["errors"]
        out["workers"] = workers
        out["load_avg_1min_after"] = round(os.getloadavg()[0], 1)  # the machine is shared: context for the speedup
        out["speedup"] = round(out["serial_s"] / out["parallel_s"], 2)
        out["identical"] = tables[0] == tables[1]
        out["note"] = ("wall time of the whole sweep incl. fits, codegen, runs and (parallel) Ray start-up; "
                       "identical = same table except timing columns")
    return out


def scale_report(log=print) -> dict[str, Any]:
    """{"fit": ..., "sweep": ...} for reports/bench.json."""
    out: dict[str, Any] = {}
    log("scale: sweep (64 points, serial vs 2 workers) ...")
    out["sweep"] = sweep_scaling(log=log)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m ddpc_codegen.experiments.bench_scale", description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="reports/bench.json", help="bench report to merge the 'scale' entry into")
    args = ap.parse_args(argv)
    log = lambda msg: print(msg, file=sys.stderr, flush=True)  # noqa: E731
    path = Path(args.out)
    report = json.loads(path.read_text()) if path.exists() else {}
    report["scale"] = scale_report(log)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(report, indent=2) + "\n")
    print(json.dumps(report["scale"], indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
