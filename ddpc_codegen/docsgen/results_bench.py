"""The solver bench's results (``make bench``, ``reports/bench.json``): its page and its headline table.

The page: each solver's call per tick at each benchmark size, the generated C alone and cross-compiled for
aarch64, the OSQP backend's accuracy, the online update in the generated C, the horizon length, hopping's
completion, the 10^6-sample fit and the fleet fit and sweep on Ray. The
headline: per size, the generated solver's call against CVXPYgen and interpreted OSQP.
"""

from __future__ import annotations

from ddpc_codegen.docsgen.results_format import NA, missing, num, page_head, ratio, table

__all__ = ["bench_sizes", "headline", "bench_page"]

_REPORT_KEYS = ("standalone", "aarch64_qemu", "preview_tracking", "hopping_completion", "adapt", "predictor_1e6",
                "scale", "meta")


def bench_sizes(bench: dict) -> list[str]:
    """The benchmark sizes of a report (each a dict of solver -> figures), in the report's order."""
    return [k for k, v in bench.items() if k not in _REPORT_KEYS and isinstance(v, dict) and "daqp" in v]


def _e(v: float | None) -> str:
    return NA if v is None else f"{v:.1e}"


def _solver_table(sz: dict) -> str:
    rows = []
    for name, r in sz.items():
        if name == "active_fraction":
            continue
        if not isinstance(r, dict) or "median_us" not in r:
            rows.append([name, f"skipped: {(r or {}).get('skipped', '')}", NA, NA, NA, NA])
            continue
        rows.append([name, num(r["median_us"]), num(r["p99_us"]), num(r.get("c_median_us")), _e(r.get("max_err")),
                     num(r.get("fast_path_fraction"), 1e2, 0)])
    return table(["solver", "call median [µs]", "call p99 [µs]", "inside the C, median [µs]",
                  "max |Δu| vs the reference", "fast-path ticks [%]"], rows)


def _daqp_row(size: str, sz: dict) -> list[str]:
    d, o6, cv = sz["daqp"], sz.get("osqp_interp_1e-6", {}), sz.get("cvxpygen", {})
    return [size, num(d.get("median_us_fast_path")),
            f"{num((sz.get('active_fraction') or {}).get('value'), 1e2, 0)} / {num(d.get('median_us_active'))}",
            ratio(cv.get("median_us"), d.get("median_us"), 0),
            f"{num(d.get('speedup_vs_osqp_interp_1e-6'), 1, 0)} / {num(d.get('speedup_active_vs_osqp_interp_1e-6'), 1, 0)}",
            f"{_e(d.get('max_err'))} / {_e(o6.get('max_err'))}", str(sz.get("osqp", {}).get("failures", NA))]


def _standalone_table(bench: dict, sizes: list[str]) -> str:
    rows = []
    for size in sizes:
        sa = (bench.get("standalone") or {}).get(size)
        arm = (bench.get("aarch64_qemu") or {}).get(size)
        for r in ((sa, sa.get("osqp")) if sa else ()):
            if r:
                rows.append([size, r["backend"], f"{num(r['c_only_median_us'], 1, 2)} / {num(r['c_only_p99_us'])}",
                             num(r["python_call_median_us"]), _e(r.get("max_err_vs_vectors")),
                             "tools missing" if arm is None else _e(arm.get("max_err_vs_vectors"))])
    return table(["size", "backend", "C-only tick median / p99 [µs]", "Python call median [µs]",
                  "example vs vectors, max |Δu|", "aarch64 (qemu) vs vectors, max |Δu|"], rows)


def _accuracy_table(bench: dict, sizes: list[str]) -> str:
    rows = []
    for size in sizes:
        acc = bench[size].get("osqp", {}).get("accuracy")
        if acc:
            rows.append([size, str(acc["qp_ticks"]), num(acc["converged_fraction"], 1e2), num(acc["refined_fraction"], 1e2),
                         _e(acc["max_err"]), _e(acc["max_err_unrefined"])])
    return table(["size", "QP ticks", "converged [%]", "refined to the exact optimum [%]", "max |Δu|",
                  "max |Δu| of the unrefined answers"], rows) if rows else ""


def _adapt_tables(rows: list[dict]) -> str:
    """The online update in the generated C: in the tick, off it, the re-solve's phases, under qemu aarch64."""
    pair = lambda r, a, b, d=2: f"{num(r.get(a), 1, d)} / {num(r.get(b), 1, d)}"  # noqa: E731
    timing = [[r["size"], str(r["width"]), pair(r, "update_us_median", "update_us_p99"),
               pair(r, "snapshot_us_median", "snapshot_us_max", 1), pair(r, "fold_us_median", "fold_us_max"),
               pair(r, "resolve_ms_median", "resolve_ms_max", 3), num(r.get("offset_ms_median"), 1, 3)] for r in rows]
    text = ("In the tick a column is queued and, once per period, the recent window copied (snapshot); off the tick "
            "(a worker) each column is folded into R, then the verified re-solve (G, QP data, fast-path gain, output "
            "offset) runs.\n\n" + table(["size", "width", "update median / p99 [µs]", "snapshot median / max [µs]",
                                          "fold per column median / max [µs]", "re-solve median / max [ms]",
                                          "of it the offset [ms]"], timing))
    phases = [[r["size"], str(r.get("c_runs", 1)), num(r["resolve_c_ms_median"], 1, 3),
               f"{num(r['g_rebuild_ms_median'], 1, 3)} ({num(r['phase_ms_median']['g_solve'], 1, 3)} + "
               f"{num(r['phase_ms_median']['qp_rebuild'], 1, 3)})", num((r.get("targets") or {}).get("resolve_ms"), 1, 1),
               f"{num(r['verify_ms_median'], 1, 3)} ({num(r['phase_ms_median']['excitation'], 1, 3)} + "
               f"{num(r['phase_ms_median']['prediction'], 1, 3)})", num(r["phase_ms_median"]["offset"], 1, 3)]
              for r in rows if r.get("phase_ms_median") and r.get("g_rebuild_ms_median") is not None]
    if phases:
        text += ("\nThe re-solve timed inside the C program, phase by phase (median of its processes): G + QP rebuild "
                 "is what a new G costs, the verification after it what makes it safe to swap in.\n\n"
                 + table(["size", "processes", "whole re-solve [ms]", "G + QP rebuild (G solve + QP rebuild) [ms]",
                          "target for G + QP rebuild [ms]", "verification (excitation + prediction check) [ms]",
                          "offset [ms]"], phases))
    arm = [[r["size"], pair(a, "push_us_median", "push_us_max"), num(a.get("fold_us_median"), 1, 2),
            pair(a, "resolve_ms_median", "resolve_ms_max", 3),
            f"{num(a['native_push_us_median'], 1, 2)} / {num(a['native_resolve_ms_median'], 1, 3)}",
            f"{num(a['qemu_over_native_push'])} / {num(a['qemu_over_native_resolve'])}"]
           for r in rows if (a := r.get("aarch64_qemu"))]
    if arm:
        text += ("\nThe same calls in a C program cross-compiled for aarch64 and run under qemu-user, its native build "
                 "beside it:\n\n" + table(["size", "update median / max [µs]", "fold per column [µs]",
                                            "re-solve median / max [ms]", "native: update [µs] / re-solve [ms]",
                                            "qemu / native: update / re-solve"], arm))
    return text


_PREVIEW = {"tf15": "Tf 15", "tf100_knots10": "Tf 100 on 10 knots", "tf100_free": "Tf 100, every step free"}


def _preview_table(pt: dict) -> str:
    rows = [[_PREVIEW.get(k, k), str(r["n_z"]), " / ".join(num(v, 1e3, 2) for v in r["rmse"]),
             f"{num(r['tick_median_us'])} / {num(r['tick_p99_us'])}"] for k, r in pt.items()]
    return ("The same plant tracked by generated solvers of a short and a long horizon, the long one free or on "
            "knots (the references at the knots, linear in between).\n\n"
            + table(["horizon", "QP variables", "tracking RMSE per output [mm]", "solver tick median / p99 [µs]"], rows))


def _completion_table(c: dict) -> str:
    return (f"The generated artificial-IO completion of the hopping solver (depth {c['depth']}, rank {c['rank']}) "
            "called on the windows of a noisy hopping run, against the interpreted one.\n\n"
            + table(["calls (bounded)", "generated median / p99 [µs]", "unbounded / bounded calls, median [µs]",
                     "interpreted median [µs]", "max |difference|"],
                    [[f"{c['calls']} ({c['bounded_calls']})", f"{num(c['c_median_us'])} / {num(c['c_p99_us'])}",
                      f"{num(c['c_unbounded_median_us'])} / {num(c['c_bounded_median_us'])}",
                      num(c["python_interpreted_median_us"]), _e(c["max_abs_diff_generated_vs_interpreted"])]]))


def _scale_tables(s: dict) -> str:
    out = []
    f = s.get("fit")
    if f:
        out.append(f"A predictor fitted on {f['samples']} samples in {f['files']} files ({f['method']}, Tini {f['t_ini']}, "
                   f"Tf {f['t_f']}). The workers' times include reading the files (and Ray's start-up for 2); serial, in "
                   "memory: the fit on data already loaded, one BLAS thread; peak: the fitting process, or the largest "
                   "Ray worker.\n\n"
                   + table(["serial, in memory [s]", "1 worker [s]", "2 workers [s]", "speed-up", "peak per worker [MiB]",
                            "max relative difference of G"],
                           [[num(f["serial_in_memory_s"]), num(f["workers_1_s"]), num(f["workers_2_s"]),
                             num(f["speedup"], 1, 2), num(f["peak_mib_per_worker"], 1, 0), _e(f["max_rel_diff_G"])]]))
    w = s.get("sweep")
    if w:
        out.append(f"A sweep of {w['points']} points: wall time of the whole sweep, fits, code generation, runs and "
                   "Ray's start-up included; same table: the parallel sweep's table equals the serial one but for its "
                   "timing columns.\n\n"
                   + table(["serial [s]", f"{w['workers']} workers [s]", "speed-up", "errors: serial / parallel",
                            "same table"],
                           [[num(w["serial_s"]), num(w["parallel_s"]), num(w["speedup"], 1, 2),
                             f"{w['serial_errors']} / {w['parallel_errors']}", "yes" if w.get("identical") else "no"]]))
    return "\n".join(out)


def headline(bench: dict) -> str:
    """Per size: the generated solver's call (median, p99), inside the C, and its speed-up and accuracy."""
    rows = []
    for size in bench_sizes(bench):
        d, sz = bench[size]["daqp"], bench[size]
        rows.append([size, f"{num(d['median_us'])} / {num(d['p99_us'])}", num(d.get("c_median_us")),
                     ratio(sz.get("cvxpygen", {}).get("median_us"), d["median_us"], 0),
                     num(d.get("speedup_vs_osqp_interp_1e-6"), 1, 0), _e(d.get("max_err"))])
    return table(["size", "generated solver (DAQP): call median / p99 [µs]", "inside the C, median [µs]",
                  "CVXPYgen / generated, median", "interpreted OSQP (eps 1e-6) / generated, median",
                  "max |Δu| vs the reference"], rows)


def bench_page(bench: dict | None) -> str:
    """The solver bench page (Markdown) from ``reports/bench.json`` (None: not measured yet)."""
    head = page_head("Solver timing", "`make bench`: each solver called on the same recorded steering problems, "
                     "tick by tick, at each benchmark size; the reference answer is the exact QP optimum.")
    if bench is None:
        return head + "\n" + missing("make bench", "bench.json")
    meta, sizes = bench.get("meta", {}), bench_sizes(bench)
    out = [head, f"{meta.get('ticks', '?')} ticks per size on {meta.get('machine', '?')}, {meta.get('date', '?')}.\n"]
    out += [f"## {size.capitalize()}\n\n" + _solver_table(bench[size]) for size in sizes]
    out += ["## The generated DAQP solver against the others\n",
            table(["size", "fast-path ticks median [µs]", "active-bound ticks: share [%] / median [µs]",
                   "CVXPYgen / generated, median", "interpreted OSQP 1e-6 / generated: all / active ticks",
                   "max |Δu|: generated / interpreted OSQP 1e-6", "OSQP backend failures"],
                  [_daqp_row(s, bench[s]) for s in sizes])]
    out += ["## The generated C alone\n", _standalone_table(bench, sizes)]
    acc = _accuracy_table(bench, sizes)
    if acc:
        out += ["The OSQP backend on the ticks with an active bound:\n", acc]
    if bench.get("adapt"):
        out += ["## Online adaptation in the generated C\n", _adapt_tables(list(bench["adapt"].values()))]
    if bench.get("preview_tracking"):
        out += ["## Horizon length\n", _preview_table(bench["preview_tracking"])]
    if bench.get("hopping_completion"):
        out += ["## Hopping's artificial-IO completion\n", _completion_table(bench["hopping_completion"])]
    p = bench.get("predictor_1e6")
    if p:
        out += ["## Predictor fit on 10^6 samples\n",
                table(["samples", "lsq [s]", "pem [s]", "peak RSS [MiB]", "RSS before fitting [MiB]"],
                      [[str(p.get("samples", 10 ** 6)), num(p["lsq_seconds"]), num(p["pem_seconds"]),
                        num(p["peak_rss_mib"], 1, 0), num(p["rss_before_fit_mib"], 1, 0)]])]
    if bench.get("scale"):
        out += ["## Fleet fits and sweeps on Ray\n", _scale_tables(bench["scale"])]
    return "\n".join(out)
