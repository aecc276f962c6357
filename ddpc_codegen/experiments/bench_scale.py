"""The ``scale`` entry of reports/bench.json: a sweep and a fleet fit, serial vs Ray workers.

    python -m ddpc_codegen.experiments.bench_scale            # only this entry (merged into bench.json)
    make bench                                                 # with everything else

Sweep: 64 points (8 flying configurations x 2 conditions x 4 seeds, 8 s runs) serially, then on a
local Ray runtime with 2 workers; ``identical`` compares the two tables without their timing
columns. Fit: 10^7 samples in 100 files of a simulated m = p = 2 loop, Tini = 20, Tf = 15, ``lsq``,
with 1 and 2 workers, each in a fresh process (peak memory = that process's, or the largest Ray
worker's), against ``fit_predictor`` on all samples in memory.
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
from ddpc_codegen.design.data import IODataset, prbs
from ddpc_codegen.experiments.bench_problems import bench_plant
from ddpc_codegen.experiments.sweep import TIMING_COLUMNS, _training_data, read_results, run_sweep
from ddpc_codegen.experiments.sweep_spec import SweepSpec

__all__ = ["sweep_scaling", "fit_scaling", "scale_report", "main"]

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


_FIT_JOB = """
import json, resource, sys, time
import numpy as np
from pathlib import Path
mode, folder, out = sys.argv[1], Path(sys.argv[2]), sys.argv[3]
paths = sorted(folder.glob("*.npz"))
t0 = time.perf_counter()
if mode == "reference":
    from ddpc_codegen.design.data import IODataset
    from ddpc_codegen.design.predictor import fit_predictor
    dss = [IODataset.load(p) for p in paths]
    ds = IODataset([d.u[0] for d in dss], [d.y[0] for d in dss], dss[0].dt)
    t0 = time.perf_counter()
    pred = fit_predictor(ds, 20, 15, "lsq", ridge=1e-2)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    workers = 1
else:
    from ddpc_codegen.design.fleet import fit_files
    fit = fit_files(paths, 20, 15, "lsq", ridge=1e-2, workers=int(mode))
    pred, peak, workers = fit.predictor, fit.peak_mib_per_worker, fit.workers
seconds = time.perf_counter() - t0
np.savez(out, Gy_w=pred.Gy_w, Gy_u=pred.Gy_u)
print(json.dumps({"seconds": seconds, "peak_mib": peak, "workers": workers}))
"""


def _fleet_files(folder: Path, samples: int, files: int) -> None:
    """``files`` IODataset files of samples/files samples: PRBS through bench.py's tracking loop."""
    import numpy as np
    from scipy.signal import dlsim

    A, B, C, off = bench_plant(2, 0)
    n = samples // files
    for i in range(files):
        u = prbs(n, 2, amplitude=0.05, min_hold=4, seed=i)
        _, y, _ = dlsim((A, B, C, np.zeros((2, 2)), 1.0), u)
        rng = np.random.default_rng(i)
        IODataset(u, y + off + 1e-4 * rng.standard_normal(y.shape), 0.005).save(folder / f"flight_{i:04d}.npz")


def fit_scaling(samples: int = 10**7, files: int = 100, log=print) -> dict[str, Any]:
    """Fleet fit with 1 and 2 workers vs the in-memory serial fit (each in a fresh process)."""
    import subprocess

    import numpy as np

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "fleet"
        folder.mkdir()
        log(f"  writing {files} files, {samples} samples ...")
        _fleet_files(folder, samples, files)
        out: dict[str, Any] = {"samples": samples, "files": files, "t_ini": 20, "t_f": 15, "m": 2, "p": 2,
                               "method": "lsq"}
        G = {}
        for mode in ("reference", "1", "2"):
            log(f"  fit: {mode} ...")
            # The in-memory reference with one BLAS thread too (threaded OpenBLAS on these QRs was 3x
            # slower on this shared 2-core machine, measured at 10^6 samples).
            env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"} if mode == "reference" else None
            res = subprocess.run([sys.executable, "-c", _FIT_JOB, mode, str(folder), f"{tmp}/{mode}.npz"],
                                 capture_output=True, text=True, check=True, env=env)
            r = json.loads(res.stdout.strip().splitlines()[-1])
            z = np.load(f"{tmp}/{mode}.npz")
            G[mode] = np.hstack([z["Gy_w"], z["Gy_u"]])
            key = "serial_in_memory" if mode == "reference" else f"workers_{mode}"
            out[f"{key}_s"] = round(r["seconds"], 2)
            out[f"{key}_peak_mib"] = round(r["peak_mib"], 1)
        out["peak_mib_per_worker"] = max(out["workers_1_peak_mib"], out["workers_2_peak_mib"])
        rel = lambda a: float(np.abs(a - G["reference"]).max() / np.abs(G["reference"]).max())  # noqa: E731
        out["max_rel_diff_G"] = max(rel(G["1"]), rel(G["2"]))
        out["speedup"] = round(out["workers_1_s"] / out["workers_2_s"], 2)
        out["load_avg_1min_after"] = round(os.getloadavg()[0], 1)
        out["note"] = ("workers_N_s: fit_files wall time incl. reading the files (and Ray start-up for 2); "
                       "serial_in_memory_s: fit_predictor on the loaded data (1 BLAS thread); peak MiB: the fitting process, or "
                       "the largest Ray worker")
    return out


def scale_report(log=print, samples: int = 10**7, files: int = 100) -> dict[str, Any]:
    """{"fit": ..., "sweep": ...} for reports/bench.json."""
    out: dict[str, Any] = {}
    log(f"scale: fleet fit ({samples} samples, {files} files, 1 vs 2 workers) ...")
    out["fit"] = fit_scaling(samples, files, log=log)
    log("scale: sweep (64 points, serial vs 2 workers) ...")
    out["sweep"] = sweep_scaling(log=log)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m ddpc_codegen.experiments.bench_scale", description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="reports/bench.json", help="bench report to merge the 'scale' entry into")
    ap.add_argument("--samples", type=int, default=10**7, help="fleet fit samples (default 10^7)")
    ap.add_argument("--files", type=int, default=100, help="fleet fit files (default 100)")
    args = ap.parse_args(argv)
    log = lambda msg: print(msg, file=sys.stderr, flush=True)  # noqa: E731
    path = Path(args.out)
    report = json.loads(path.read_text()) if path.exists() else {}
    report["scale"] = scale_report(log, args.samples, args.files)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(report, indent=2) + "\n")
    print(json.dumps(report["scale"], indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
