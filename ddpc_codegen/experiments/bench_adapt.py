"""Timing of the generated online predictor update (issue 30): the rank-one update per tick and the
re-solve of G, rebuild of the QP data (Hessian, linear-term map, output rows, gain) and verification, in C, at the
benchmark's flying and hopping sizes; the output offset's share of a re-solve (``[adapt] offset``: the mean
residual of the recent window, the same re-solves timed in a build without it); and the same pushes and re-solves
timed by a C program cross-compiled for aarch64 under qemu, with its native build as the reference
(:mod:`ddpc_codegen.experiments.bench_adapt_cross`).

The problems are the benchmark's (``bench.build_problem``) refitted with a relative ridge of 1e-6 (the
update re-solves G by a triangular solve, which needs a full-rank R11: the configs' ridge gives it).
Times are wall-clock per call through cffi (~0.2 us of call overhead included).
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time

import numpy as np

from ddpc_codegen.codegen import standalone
from ddpc_codegen.codegen.adapt import compile_alone
from ddpc_codegen.design.adaptation import fit_layout
from ddpc_codegen.design.data import IODataset, prbs
from ddpc_codegen.design.predictor import fit_predictor
from ddpc_codegen.errors import CodegenError
from ddpc_codegen.experiments.bench_adapt_cross import cross_figures, cross_line
from ddpc_codegen.design.problem import SteeringProblem
from ddpc_codegen.runtime.adaptation import AdaptSettings

TARGET_UPDATE_US, TARGET_RESOLVE_MS = 5.0, 2.0


def _ridge_problem(size: str) -> SteeringProblem:
    from ddpc_codegen.experiments.bench import _simulate, build_problem

    prob, (A, B, C, off) = build_problem(size)
    c = prob.config
    u = prbs(4000, c.m, amplitude=0.05, min_hold=4, seed=0)
    y, _ = _simulate(A, B, C, off, u, np.zeros(A.shape[0]))
    pred = fit_predictor(IODataset(u, y - off, 0.005), c.t_ini, c.t_f, "lsq", ridge=1e-6)
    return SteeringProblem(pred, c)


def _resolve_times(prob: SteeringProblem, st: AdaptSettings, name: str, wins: np.ndarray, n_resolves: int,
                   tmp: str) -> tuple[np.ndarray, np.ndarray, int]:
    """(seconds per ``<name>_adapt_push``, seconds per ``<name>_adapt_snapshot`` + ``_resolve``, the last
    re-solve's verdict) of a fresh build."""
    ffi, lib = compile_alone(prob, st, tmp, name)
    ws = ffi.new(f"{name}_adapt_workspace *")
    if getattr(lib, f"{name}_adapt_init")(ws) != 0:
        raise RuntimeError("the benchmark's R factor is rank deficient")
    push, resolve = getattr(lib, f"{name}_adapt_push"), getattr(lib, f"{name}_adapt_resolve")
    snapshot = getattr(lib, f"{name}_adapt_snapshot")
    t_push = np.empty(wins.shape[0])
    for k in range(wins.shape[0]):
        buf = ffi.from_buffer("double[]", wins[k])
        t0 = time.perf_counter()
        push(ws, buf)
        t_push[k] = time.perf_counter() - t0
    t_res = np.empty(n_resolves)
    verdict = -1
    for k in range(n_resolves):
        t0 = time.perf_counter()
        snapshot(ws)  # timed with it: the synchronous re-solve
        verdict = resolve(ws)
        t_res[k] = time.perf_counter() - t0
    return t_push, t_res, verdict


def adapt_timing(size: str, n_updates: int = 2000, n_resolves: int = 9, log=None) -> dict:
    """Median / max microseconds of ``<name>_adapt_push``, milliseconds of ``<name>_adapt_resolve`` (with the output
    offset on), the offset's share: the median re-solve with it minus the median of a build without it, and
    ``aarch64_qemu``: the same calls timed in C under qemu aarch64 and natively (None, with ``aarch64_qemu_note``
    saying why, when the tools are missing or the cross build failed its checks)."""
    log = log or (lambda msg: print(msg, file=sys.stderr))
    prob = _ridge_problem(size)
    lay = fit_layout(prob.predictor)
    window = max(200, lay.min_window)  # the default window where it suffices
    st = AdaptSettings(enabled=True, offset=True, window=window)
    rng = np.random.default_rng(0)
    wins = rng.standard_normal((n_updates, lay.depth * (lay.m + lay.p))) * 0.05
    with tempfile.TemporaryDirectory() as tmp:
        t_push, t_res, verdict = _resolve_times(prob, st, f"bench_adapt_{size}", wins, n_resolves, tmp)
        try:  # the folder compile_alone emitted, built again by its Makefile (the same windows, the same verdict)
            arm, note = cross_figures(tmp, wins, n_resolves, verdict, log), standalone.MISSING_AARCH64
        except (CodegenError, subprocess.SubprocessError, OSError) as e:  # a figure missing, not the benchmark
            log(f"  aarch64 online update of {size}: failed ({e})")
            arm, note = None, f"failed: {str(e).splitlines()[0][:200]}"
    with tempfile.TemporaryDirectory() as tmp:  # the same windows and re-solves without the offset
        _, t_plain, _ = _resolve_times(prob, AdaptSettings(enabled=True, window=window), f"bench_adapt_{size}_plain",
                                       wins, n_resolves, tmp)
    return {"size": size, "width": lay.width, "window": st.window,
            "update_us_median": round(float(np.median(t_push)) * 1e6, 2),
            "update_us_p99": round(float(np.percentile(t_push, 99)) * 1e6, 2),
            "resolve_ms_median": round(float(np.median(t_res)) * 1e3, 3),
            "resolve_ms_max": round(float(np.max(t_res)) * 1e3, 3),
            "offset_ms_median": round(float(np.median(t_res) - np.median(t_plain)) * 1e3, 3),
            "aarch64_qemu": arm, **({"aarch64_qemu_note": note} if arm is None else {}),
            "targets": {"update_us": TARGET_UPDATE_US, "resolve_ms": TARGET_RESOLVE_MS}}


def adapt_lines(rows: list[dict]) -> list[str]:
    """Table lines of :func:`adapt_timing` results."""
    out = ["online update (C): size  width  update us (median/p99)  re-solve+rebuild+verify+offset ms (median/max)"
           "  of it the offset ms (a difference of two medians: ~0, the offset reuses the prediction check's residuals)"]
    for r in rows:
        out.append(f"  {r['size']:<8} {r['width']:>5}  {r['update_us_median']:>8.2f} / {r['update_us_p99']:<8.2f}"
                   f"  {r['resolve_ms_median']:>8.3f} / {r['resolve_ms_max']:<8.3f}  {r.get('offset_ms_median', 0.0):.3f}")
    out += [ln for ln in (cross_line(r["size"], r) for r in rows) if ln]
    return out


if __name__ == "__main__":
    res = [adapt_timing(s) for s in ("flying", "hopping", "preview")]
    print("\n".join(adapt_lines(res)))
