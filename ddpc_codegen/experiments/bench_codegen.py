"""Generated-solver figures of ``make bench``: the tick timed in C vs the Python call, the standalone
example's agreement with the recorded vectors (natively and cross-compiled for aarch64 under qemu), and
the osqp backend's accuracy (error against the exact optimum, converged and refined fractions)."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from ddpc_codegen.codegen import standalone


def standalone_figures(solver, thetas: np.ndarray, active: np.ndarray, log=print) -> dict:
    """C-only tick (``<name>_bench``: each tick timed in C) and the Python call on the same stream, and the
    example built with the folder's own Makefile replaying the vectors."""
    solver.reset()
    tc, _, _ = solver.bench(thetas)
    solver.reset()
    tp = np.empty(len(thetas))
    for i, th in enumerate(thetas):
        t0 = time.perf_counter_ns()
        solver.solve_theta(th)
        tp[i] = (time.perf_counter_ns() - t0) * 1e-3
    out = {"backend": solver.backend, "c_only_median_us": float(np.median(tc)),
           "c_only_p99_us": float(np.percentile(tc, 99)), "python_call_median_us": float(np.median(tp))}
    if (~active).any():
        out["c_only_fast_path_median_us"] = float(np.median(tc[~active]))
    if active.any():
        out["c_only_active_median_us"] = float(np.median(tc[active]))
    with tempfile.TemporaryDirectory() as tmp:
        folder = standalone.relocated_copy(solver.folder, Path(tmp))
        try:
            run = standalone.run_example(standalone.make_example(folder), standalone.vectors_file(folder))
        except Exception as e:  # no make / compiler: the figure is missing, not the benchmark
            log(f"  standalone example of {solver.name} not built: {e}")
            return out | {"max_err_vs_vectors": None}
    return out | {"max_err_vs_vectors": run.max_err, "vector_mismatches": run.mismatches,
                  "example_median_us": run.median_us}


def aarch64_figures(folder: Path, log=print) -> dict | None:
    """The folder cross-compiled for aarch64 and its example run under qemu; None when the tools are missing."""
    tools = standalone.aarch64_tools()
    if tools is None:
        log(f"  aarch64: skipped ({standalone.MISSING_AARCH64})")
        return None
    with tempfile.TemporaryDirectory() as tmp:
        copy = standalone.relocated_copy(folder, Path(tmp))
        run = standalone.run_example(standalone.make_example(copy, cc=tools[0], build="build-aarch64"),
                                     standalone.vectors_file(copy), qemu=tools[1], ticks=1)
    return {"max_err_vs_vectors": run.max_err, "vector_mismatches": run.mismatches,
            "compiler": standalone.AARCH64_CC, "runner": standalone.QEMU}


def osqp_accuracy(outs: list, ref: np.ndarray, active: np.ndarray) -> dict:
    """Accuracy of the osqp backend on the QP ticks (fast-path ticks are exact by construction)."""
    qp = [i for i, o in enumerate(outs) if not o.fast_path]
    solved = [i for i in qp if outs[i].ok]
    refined = [i for i in solved if outs[i].info.get("refined")]
    err = [float(np.abs(outs[i].u.ravel() - ref[i]).max()) for i in solved]
    err_unrefined = [e for i, e in zip(solved, err) if i not in set(refined)]
    return {"qp_ticks": len(qp), "converged_fraction": len(solved) / max(1, len(qp)),
            "refined_fraction": len(refined) / max(1, len(qp)), "max_err": max(err, default=float("nan")),
            "max_err_unrefined": max(err_unrefined, default=0.0),
            "active_ticks": int(active.sum())}


def table_lines(report: dict, sizes) -> list[str]:
    """Summary lines of the figures above for the benchmark's printed table."""
    rows = []
    for size in sizes:
        sa = report.get("standalone", {}).get(size)
        if sa:
            for r in (sa, sa["osqp"]):
                err = r.get("max_err_vs_vectors")
                rows.append(f"{size:8} standalone {r['backend']}: C-only tick median {r['c_only_median_us']:.2f} µs "
                            f"(p99 {r['c_only_p99_us']:.1f}), Python call median {r['python_call_median_us']:.1f} µs; "
                            f"example vs vectors max |Δu| {'n/a' if err is None else f'{err:.1e}'}")
        arm = (report.get("aarch64_qemu") or {}).get(size)
        rows.append(f"{size:8} aarch64 (qemu): " + ("tools missing" if arm is None else
                                                    f"max |Δu| vs vectors {arm['max_err_vs_vectors']:.1e}"))
        acc = report[size]["osqp"].get("accuracy")
        if acc:
            rows.append(f"{size:8} osqp backend on {acc['qp_ticks']} QP ticks: converged {acc['converged_fraction']:.1%}, "
                        f"refined to the exact optimum {acc['refined_fraction']:.1%}, max |Δu| {acc['max_err']:.1e} "
                        f"(unrefined answers {acc['max_err_unrefined']:.1e})")
    return rows
