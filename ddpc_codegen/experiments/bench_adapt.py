"""Timing of the generated online predictor update (issue 30): the tick's share (a column queued per tick, the
recent window copied once per period), the rank-one fold of each column into R and the re-solve of G rebuild of the QP data (Hessian, linear-term map, output rows, gain) and verification, in C, at the
benchmark's flying and hopping sizes; the output offset's share of a re-solve (``[adapt] offset``: the mean
residual of the recent window, the same re-solves timed in a build without it); and the same pushes and re-solves
timed by a C program cross-compiled for aarch64 under qemu, with its native build as the reference
(:mod:`ddpc_codegen.experiments.bench_adapt_cross`).

The problems are the benchmark's (``bench_problems.build_problem``) refitted with a relative ridge of 1e-6 (the
update re-solves G by a triangular solve, which needs a full-rank R11: the configs' ridge gives it).
Times are wall-clock per call through cffi (the call overhead included).
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time

import numpy as np

from ddpc_codegen.codegen import standalone
from ddpc_codegen.codegen.artifact import compile_alone
from ddpc_codegen.design.adaptation import fit_layout
from ddpc_codegen.design.data import IODataset, prbs
from ddpc_codegen.design.predictor import fit_predictor
from ddpc_codegen.errors import CodegenError
from ddpc_codegen.experiments.bench_adapt_cross import cross_figures, cross_line, native_figures
from ddpc_codegen.design.problem import SteeringProblem
from ddpc_codegen.experiments.bench_problems import build_problem, simulate_plant
from ddpc_codegen.values.adapt import AdaptSettings

# issue 30: the tick's update <= 5 us, "a full G + QP rebuild <= 2 ms" (the verification after it is timed beside)
TARGET_UPDATE_US, TARGET_RESOLVE_MS = 5.0, 2.0


def _ridge_problem(size: str) -> SteeringProblem:
    prob, (A, B, C, off) = build_problem(size)
    c = prob.config
    u = prbs(4000, c.m, amplitude=0.05, min_hold=4, seed=0)
    y, _ = simulate_plant(A, B, C, off, u, np.zeros(A.shape[0]))
    pred = fit_predictor(IODataset(u, y - off, 0.005), c.t_ini, c.t_f, "lsq", ridge=1e-6)
    return SteeringProblem(pred, c)


def _resolve_times(prob: SteeringProblem, st: AdaptSettings, name: str, wins: np.ndarray, n_resolves: int,
                   tmp: str) -> tuple[dict, int]:
    """Seconds per call of a fresh build, as the bridge calls them ({"push": the tick's ``<name>_adapt_push``,
    "fold": per column, the fold of the queued columns older than the held-out window into R (``<name>_adapt_r``:
    the re-solve's first step, in the worker), "snapshot": the tick's ``<name>_adapt_snapshot`` once per period, "resolve":
    ``_snapshot`` + ``_resolve`` on the last snapshot}) and the last re-solve's verdict."""
    ffi, lib = compile_alone(prob, st, tmp, name)
    ws = ffi.new(f"{name}_adapt_workspace *")
    if getattr(lib, f"{name}_adapt_init")(ws) != 0:
        raise RuntimeError("the benchmark's R factor is rank deficient")
    fn = {k: getattr(lib, f"{name}_adapt_{k}") for k in ("push", "r", "snapshot", "resolve")}
    w = fit_layout(prob.predictor).width
    r_out = ffi.new("double[]", w * w)
    t: dict[str, list[float]] = {"push": [], "fold": [], "snapshot": [], "resolve": []}
    for k in range(wins.shape[0]):
        buf = ffi.from_buffer("double[]", wins[k])
        t0 = time.perf_counter()
        fn["push"](ws, buf)
        t["push"].append(time.perf_counter() - t0)
        if (k + 1) % st.period_ticks == 0:
            before = ws.counts.folded
            t0 = time.perf_counter()
            fn["r"](ws, r_out)
            if ws.counts.folded > before:  # none while the held-out window fills
                t["fold"].append((time.perf_counter() - t0) / (ws.counts.folded - before))
            t0 = time.perf_counter()
            fn["snapshot"](ws)
            t["snapshot"].append(time.perf_counter() - t0)
    verdict = -1
    for _ in range(n_resolves):
        t0 = time.perf_counter()
        fn["snapshot"](ws)  # timed with it: the synchronous re-solve
        verdict = fn["resolve"](ws)
        t["resolve"].append(time.perf_counter() - t0)
    return {k: np.asarray(v) for k, v in t.items()}, verdict


def adapt_timing(size: str, n_updates: int = 2000, n_resolves: int = 9, log=None) -> dict:
    """Median / p99 microseconds of the tick's ``<name>_adapt_push`` (``update_us``: the column queued), of the fold
    of each column into R off the tick (``fold_us``) and of the tick's snapshot once per period (``snapshot_us``),
    milliseconds of ``<name>_adapt_resolve`` (with the output offset on), the offset's share: the median re-solve with it minus the median of a build without it, and
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
        t, verdict = _resolve_times(prob, st, f"bench_adapt_{size}", wins, n_resolves, tmp)
        # the folder compile_alone emitted, built again by its Makefile with the phase clock (the same windows,
        # the same verdict): the re-solve's phases in C
        native = native_figures(tmp, wins, n_resolves, verdict)
        try:
            arm, note = cross_figures(tmp, wins, n_resolves, verdict, log, native), standalone.MISSING_AARCH64
        except (CodegenError, subprocess.SubprocessError, OSError) as e:  # a figure missing, not the benchmark
            log(f"  aarch64 online update of {size}: failed ({e})")
            arm, note = None, f"failed: {str(e).splitlines()[0][:200]}"
    with tempfile.TemporaryDirectory() as tmp:  # the same windows and re-solves without the offset
        plain, _ = _resolve_times(prob, AdaptSettings(enabled=True, window=window), f"bench_adapt_{size}_plain",
                                  wins, n_resolves, tmp)
    us = lambda a, f: round(float(f(a)) * 1e6, 2)  # noqa: E731
    p99 = lambda a: np.percentile(a, 99)  # noqa: E731
    return {"size": size, "width": lay.width, "window": st.window, "period_ticks": st.period_ticks,
            "update_us_median": us(t["push"], np.median), "update_us_p99": us(t["push"], p99),
            "fold_us_median": us(t["fold"], np.median), "fold_us_max": us(t["fold"], np.max),
            "snapshot_us_median": us(t["snapshot"], np.median), "snapshot_us_max": us(t["snapshot"], np.max),
            "resolve_ms_median": round(float(np.median(t["resolve"])) * 1e3, 3),
            "resolve_ms_max": round(float(np.max(t["resolve"])) * 1e3, 3),
            "offset_ms_median": round(float(np.median(t["resolve"]) - np.median(plain["resolve"])) * 1e3, 3),
            **_phase_figures(native),
            "aarch64_qemu": arm, **({"aarch64_qemu_note": note} if arm is None else {}),
            "targets": {"update_us": TARGET_UPDATE_US, "resolve_ms": TARGET_RESOLVE_MS}}


def _phase_figures(native: dict) -> dict:
    """The C timing program's re-solve phases (median ms; -1: not stamped): each phase, the G solve + QP rebuild
    (the issue's "full G + QP rebuild") and the verification after it (excitation + prediction check)."""
    ph = {k: round(v * 1e-6, 3) if v >= 0 else -1.0 for k, v in native["phase_ns_median"].items()}
    stamped = all(v >= 0 for v in ph.values())
    return {"phase_ms_median": ph, "resolve_c_ms_median": round(native["resolve_ns_median"] * 1e-6, 3),
            "c_runs": native.get("runs", 1),
            "g_rebuild_ms_median": round(ph["g_solve"] + ph["qp_rebuild"], 3) if stamped else None,
            "verify_ms_median": round(ph["excitation"] + ph["prediction"], 3) if stamped else None}


def phase_line(row: dict) -> str | None:
    """The table line of a row's re-solve phases (None: an older report without them)."""
    ph = row.get("phase_ms_median")
    if not ph or row.get("g_rebuild_ms_median") is None:
        return None
    return (f"  {row['size']:<8} re-solve phases (C program, median ms of {row.get('c_runs', 1)} processes; the "
            f"whole call {row['resolve_c_ms_median']:.3f}): "
            f"G + QP rebuild {row['g_rebuild_ms_median']:.3f} (G solve {ph['g_solve']:.3f}, QP rebuild "
            f"{ph['qp_rebuild']:.3f}; target <= {TARGET_RESOLVE_MS:g}), then the verification "
            f"{row['verify_ms_median']:.3f} (excitation {ph['excitation']:.3f}, prediction check "
            f"{ph['prediction']:.3f}), offset {ph['offset']:.3f}")


def adapt_lines(rows: list[dict]) -> list[str]:
    """Table lines of :func:`adapt_timing` results."""
    out = ["online update (C), in the tick: a column queued per tick, the window copied once per period; off the "
           "tick (worker): each column folded into R, then the re-solve",
           "  size  width  tick: update us (median/p99)  snapshot us (median/max)  worker: fold us per column "
           "(median/max)  re-solve+rebuild+verify+offset ms (median/max)  of it the offset ms (a difference of two "
           "medians: ~0, the offset reuses the prediction check's residuals)"]
    for r in rows:
        fold = (f"{r['snapshot_us_median']:>8.1f} / {r['snapshot_us_max']:<8.1f}  {r['fold_us_median']:>8.2f} / "
                f"{r['fold_us_max']:<8.2f}" if "fold_us_median" in r else f"{'-':>28}")  # older reports: in the tick
        out.append(f"  {r['size']:<8} {r['width']:>5}  {r['update_us_median']:>8.2f} / {r['update_us_p99']:<8.2f}"
                   f"  {fold}  {r['resolve_ms_median']:>8.3f} / {r['resolve_ms_max']:<8.3f}"
                   f"  {r.get('offset_ms_median', 0.0):.3f}")
    out += [ln for ln in (phase_line(r) for r in rows) if ln]
    out += [ln for ln in (cross_line(r["size"], r) for r in rows) if ln]
    return out


if __name__ == "__main__":
    res = [adapt_timing(s) for s in ("flying", "hopping", "preview")]
    print("\n".join(adapt_lines(res)))
