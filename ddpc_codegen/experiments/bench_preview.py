"""``make bench``'s preview figure: what knots cost in tracking and save in tick time.

On the benchmark plant (the closed loop of :mod:`ddpc_codegen.experiments.bench`), the same desired
trajectory (a sine plus steps) is tracked by generated solvers with a 75 ms horizon (Tf 15), a 500 ms
horizon on 10 knots, and the same 500 ms horizon with every sample free; each tick timed in C.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ddpc_codegen.design.problem import SteeringProblem
from ddpc_codegen.experiments.bench_problems import build_problem, closed_loop
from ddpc_codegen.codegen import generate
from ddpc_codegen.runtime.loader import load_solver

__all__ = ["track", "preview_tracking"]


def track(problem: SteeringProblem, plant: tuple, solver, n: int, seed: int = 1, settle: int = 200) -> dict:
    """Closed loop of ``solver`` (anything with ``solve_theta``) on the plant for n ticks: per-output tracking
    RMSE [m] after ``settle`` ticks, and the solver's own tick time [µs] (median, p99)."""
    err, times = np.empty((n, problem.config.m)), np.empty(n)
    for k, (_, r, y_k, y_des_k) in enumerate(closed_loop(problem, plant, solver, n, seed)):
        err[k] = y_k - y_des_k
        times[k] = r.solve_time * 1e6
    return {"rmse": np.sqrt((err[settle:] ** 2).mean(axis=0)).tolist(), "tick_median_us": float(np.median(times)),
            "tick_p99_us": float(np.percentile(times, 99))}


def preview_tracking(workdir: Path, n: int = 2000, log=print) -> dict:
    """{variant: track(...) | n_z} for Tf 15, Tf 100 on 10 knots and Tf 100 free (generated daqp solvers)."""
    knots, plant = build_problem("preview")
    short, _ = build_problem("flying")
    free = SteeringProblem(knots.predictor, knots.config.replace(knots=None, name="bench_preview_free"))
    out = {}
    for name, prob in (("tf15", short), ("tf100_knots10", knots), ("tf100_free", free)):
        log(f"  preview tracking: {name} ({prob.n_z} QP variables) ...")
        solver = load_solver(generate(prob, Path(workdir) / f"track_{name}", name=f"track_{name}"))
        out[name] = {"n_z": prob.n_z, **track(prob, plant, solver, n)}
    return out
