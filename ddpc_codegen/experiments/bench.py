"""``make bench``: per-tick steering time and accuracy of every solver path, measured in one run.

Sizes: flying (m = p = 2, Tini = 20, Tf = 15) and hopping (m = p = 3, Tini = 20, Tf = 25). The
plant is a coupled, lightly damped LTI tracking loop (the shape of a closed loop of references to
outputs); the parameter stream is the sliding window of a closed-loop run of the generated exact
solver tracking a desired trajectory with steps, so both inactive ticks (fast path) and active
bounds occur. Every solver replays the same stream in order (warm starts as in the loop); errors
are max |u - u*| against the exact interpreted solution. Writes reports/bench.json.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import osqp
import scipy.sparse as sp

from ddpc_codegen.design.problem import SteeringProblem
from ddpc_codegen.experiments.bench_adapt import adapt_lines, adapt_timing
from ddpc_codegen.experiments.bench_artio import completion_timing
from ddpc_codegen.experiments.bench_codegen import aarch64_figures, osqp_accuracy, standalone_figures, table_lines
from ddpc_codegen.experiments.bench_preview import preview_tracking
from ddpc_codegen.experiments.bench_problems import SIZES, bench_data, theta_stream
from ddpc_codegen.experiments.bench_scale import scale_report
from ddpc_codegen.pipeline.solver_build import build_solver
from ddpc_codegen.runtime.loader import load_solver

def _time_python(fn, thetas) -> tuple[np.ndarray, list]:
    times = np.empty(len(thetas))
    outs = []
    for i, th in enumerate(thetas):
        t0 = time.perf_counter_ns()
        out = fn(th)
        times[i] = (time.perf_counter_ns() - t0) * 1e-3
        outs.append(out)
    return times, outs


def _stats(times: np.ndarray, err: float, fast: float | None = None, extra: dict | None = None,
           active: np.ndarray | None = None) -> dict:
    d = {"median_us": float(np.median(times)), "p99_us": float(np.percentile(times, 99)),
         "max_err": float(err)}
    if active is not None and active.any():
        d["median_us_active"] = float(np.median(times[active]))
    if fast is not None:
        d["fast_path_fraction"] = float(fast)
    d.update(extra or {})
    return d


def bench_size(size: str, n: int, workdir: Path, log=print) -> dict:
    cfg, ds, plant = bench_data(size)
    built = {b: build_solver(cfg, ds, workdir / f"{size}_{b}", backend=b, name=f"bench_{size}_{b}")
             for b in ("daqp", "osqp")}
    problem = built["daqp"].problem
    solvers = {b: load_solver(v.path) for b, v in built.items()}
    thetas = theta_stream(problem, plant, solvers["daqp"], n)
    solvers["daqp"].reset()
    log(f"  {size}: {n} ticks, n_u={problem.n_u}, n_z={problem.n_z}, n_theta={problem.n_theta}; computing exact "
        "references ...")
    ref = np.array([problem.solve_theta(th, solver="exact").u.ravel() for th in thetas])
    results: dict[str, dict] = {}
    # Which ticks have an active bound (the unconstrained optimum is infeasible): the hard ones.
    active = np.array([not problem.is_feasible(problem.unconstrained(th), *problem.qp_vectors(th)[1:])
                       for th in thetas])

    def err_of(us):
        return max(np.abs(u - r).max() if np.all(np.isfinite(u)) else np.inf for u, r in zip(us, ref))

    for b, s in solvers.items():
        s.reset()
        tp, outs = _time_python(s.solve_theta, thetas)
        s.reset()
        tc, st, _ = s.bench(thetas)
        ok = [o.ok for o in outs]
        results[b] = _stats(tp, err_of([o.u.ravel() for o in outs if o.ok]), np.mean([o.fast_path for o in outs]),
                            {"c_median_us": float(np.median(tc)), "c_p99_us": float(np.percentile(tc, 99)),
                             "failures": int(len(ok) - sum(ok))}, active)
        if (~active).any():
            results[b]["median_us_fast_path"] = float(np.median(tp[~active]))
        if b == "osqp":
            results[b]["accuracy"] = osqp_accuracy(outs, ref, active)
    log(f"  {size}: standalone C builds (native, aarch64 under qemu) ...")
    results["standalone"] = {b: standalone_figures(s, thetas, active, log) for b, s in solvers.items()}
    results["aarch64_qemu"] = aarch64_figures(solvers["daqp"].folder, log)
    # Interpreted OSQP (Python), default settings (adaptive rho, polishing off as embedded), warm-started.
    q0, l0, u0 = problem.qp_vectors(thetas[0])
    for eps in (1e-3, 1e-6):
        s = osqp.OSQP()
        s.setup(sp.triu(sp.csc_matrix(problem.P), format="csc"), q0, sp.csc_matrix(problem.A),
                np.maximum(l0, -1e30), np.minimum(u0, 1e30), verbose=False, eps_abs=eps, eps_rel=eps,
                max_iter=20000, warm_starting=True, polishing=False)

        def call(th, s=s):
            q, l, u = problem.qp_vectors(th)
            s.update(q=q, l=np.maximum(l, -1e30), u=np.minimum(u, 1e30))
            return s.solve(raise_error=False)

        tp, outs = _time_python(call, thetas)
        its = [o.info.iter for o in outs]
        results[f"osqp_interp_{eps:.0e}".replace("e-0", "e-")] = _stats(
            tp, err_of([problem.to_u(o.x) for o in outs]), None, {"median_iter": float(np.median(its))}, active)
    # Interpreted exact (CasADi daqp from Python) and the numpy unconstrained gain.
    tp, outs = _time_python(lambda th: problem.solve_theta(th, solver="exact"), thetas)
    results["daqp_interp"] = _stats(tp, err_of([o.u.ravel() for o in outs]), active=active)
    tp, _ = _time_python(problem.unconstrained, thetas)
    results["numpy_gain"] = _stats(tp, float("nan"), extra={"note": "K @ theta only (exact only when no bound is active)"})
    results["cvxpygen"] = _bench_cvxpygen(problem, thetas, ref, workdir, size, log, active)
    base = results["osqp_interp_1e-6"]["median_us"]
    for k in ("daqp", "osqp"):
        results[k]["speedup_vs_osqp_interp_1e-6"] = base / results[k]["median_us"]
        results[k]["speedup_vs_osqp_interp_1e-3"] = results["osqp_interp_1e-3"]["median_us"] / results[k]["median_us"]
    for k in ("daqp", "osqp"):
        if "median_us_active" in results[k]:
            results[k]["speedup_active_vs_osqp_interp_1e-6"] = (results["osqp_interp_1e-6"]["median_us_active"]
                                                                 / results[k]["median_us_active"])
    results["active_fraction"] = {"value": float(active.mean())}
    return results


def predictor_scaling(samples: int = 10**6) -> dict:
    """Fit both predictors on ``samples`` samples (m = p = 2, Tini = 20, Tf = 15) in a fresh
    process; report wall time and the process's peak resident memory (includes Python + numpy)."""
    import subprocess

    code = f"""
import json, resource, time, numpy as np
from ddpc_codegen.experiments.bench_problems import bench_plant, simulate_plant
from ddpc_codegen import IODataset, prbs, fit_predictor
A, B, C, off = bench_plant(2, 0)
u = prbs({samples}, 2, amplitude=0.05, min_hold=4, seed=0)
y, _ = simulate_plant(A, B, C, off, u, np.zeros(4)) if {samples} <= 20000 else (None, None)
if y is None:
    from scipy.signal import dlsim
    _, y, _ = dlsim((A, B, C, np.zeros((2, 2)), 1.0), u)
ds = IODataset(u, y, 0.005)
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
out = {{"samples": {samples}, "rss_before_fit_mib": base}}
for method in ("lsq", "pem"):
    t0 = time.perf_counter()
    fit_predictor(ds, 20, 15, method)
    out[method + "_seconds"] = time.perf_counter() - t0
out["peak_rss_mib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
print(json.dumps(out))
"""
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return json.loads(res.stdout.strip().splitlines()[-1])


def scale_entry(log=print) -> dict:
    """The ``scale`` entry: fleet fit (10^7 samples, 100 files) and a 64-point sweep, serial vs 2 Ray
    workers (:mod:`ddpc_codegen.experiments.bench_scale`; ~10-15 min on a loaded 2-core machine)."""
    return scale_report(log)


def _bench_cvxpygen(problem: SteeringProblem, thetas: np.ndarray, ref: np.ndarray, workdir: Path, size: str,
                    log, active: np.ndarray) -> dict:
    """The same condensed QP through CVXPY + CVXPYgen (OSQP, its default settings), called from Python."""
    try:
        import cvxpy as cp
        from cvxpygen import cpg
    except ImportError:
        return {"skipped": "cvxpygen not installed (pip install -e '.[bench]')"}
    import contextlib
    import importlib
    import io

    log(f"  {size}: generating the CVXPYgen solver ...")
    L = np.linalg.cholesky(problem.P)
    z = cp.Variable(problem.n_z, name="z")
    th = cp.Parameter(problem.n_theta, name="theta")
    cons = []
    fin_lo, fin_hi = np.isfinite(problem.lb_u), np.isfinite(problem.ub_u)
    if fin_lo.any():
        cons.append(z[np.nonzero(fin_lo)[0]] >= problem.lb_u[fin_lo])
    if fin_hi.any():
        cons.append(z[np.nonzero(fin_hi)[0]] <= problem.ub_u[fin_hi])
    if problem.n_g:
        cons += [problem.A_g @ z >= problem.lg0 + problem.F_g @ th, problem.A_g @ z <= problem.ug0 + problem.F_g @ th]
    prob = cp.Problem(cp.Minimize(0.5 * cp.sum_squares(L.T @ z) + (problem.F_q @ th + problem.q0) @ z), cons)
    pkg = f"cpg_{size}"
    cwd = os.getcwd()
    try:
        os.chdir(workdir)  # CVXPYgen names the Python package after a relative code_dir
        with contextlib.redirect_stdout(io.StringIO()):
            cpg.generate_code(prob, code_dir=pkg, solver="OSQP", prefix=size, wrapper=True)
        os.chdir(cwd)
        sys.path.insert(0, str(workdir))
        mod = importlib.import_module(f"{pkg}.cpg_solver")
    except Exception as e:  # an optional comparison must not sink the benchmark
        os.chdir(cwd)
        return {"skipped": f"CVXPYgen generation failed: {type(e).__name__}: {e}"[:300]}
    prob.register_solve("CPG", mod.cpg_solve)

    def call(t):
        th.value = t
        prob.solve(method="CPG")
        return None if z.value is None else problem.to_u(z.value)

    tp, outs = _time_python(call, thetas)
    errs = [np.abs(o - r).max() if o is not None and np.all(np.isfinite(o)) else np.inf for o, r in zip(outs, ref)]
    return _stats(tp, max(errs), None, {"note": "CVXPYgen (OSQP, default eps 1e-3) via prob.solve(method='CPG')"},
                  active)


def _table(report: dict) -> str:
    rows = [f"{'size':8} {'solver':18} {'median µs':>10} {'p99 µs':>9} {'C med µs':>9} {'max |Δu|':>10} {'fast':>6}"]
    for size in SIZES:
        for name, r in report[size].items():
            if name == "active_fraction":
                continue
            if not isinstance(r, dict) or "median_us" not in r:
                rows.append(f"{size:8} {name:18} {r.get('skipped', '')}")
                continue
            cm = r.get("c_median_us")
            fp = r.get("fast_path_fraction")
            rows.append(f"{size:8} {name:18} {r['median_us']:10.1f} {r['p99_us']:9.1f} "
                        f"{'' if cm is None else f'{cm:9.1f}':>9} {r['max_err']:10.1e} "
                        f"{'' if fp is None else f'{fp:6.2f}':>6}")
        if "median_us" in report[size].get("cvxpygen", {}):
            cv = report[size]["cvxpygen"]["median_us"]
            rows.append(f"{size:8} daqp {cv / report[size]['daqp']['median_us']:.0f}x faster than CVXPYgen (same run)")
        d = report[size]["daqp"]
        o6 = report[size]["osqp_interp_1e-6"]
        rows.append(f"{size:8} daqp: fast-path ticks median {d['median_us_fast_path']:.1f} µs, active-bound ticks "
                    f"({report[size]['active_fraction']['value']:.0%}) median {d['median_us_active']:.1f} µs; "
                    f"{d['speedup_vs_osqp_interp_1e-6']:.0f}x faster than interpreted osqp eps 1e-6 overall, "
                    f"{d['speedup_active_vs_osqp_interp_1e-6']:.0f}x on active ticks; max |Δu| {d['max_err']:.0e} vs "
                    f"{o6['max_err']:.0e}; osqp backend failures: {report[size]['osqp']['failures']}")
    return "\n".join(rows + table_lines(report, SIZES))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m ddpc_codegen.experiments.bench", description=__doc__.splitlines()[0])
    ap.add_argument("--ticks", type=int, default=2000, help="ticks per size (default 2000)")
    ap.add_argument("--out", default="reports/bench.json")
    ap.add_argument("--skip-predictor", action="store_true", help="skip the 10^6-sample predictor fit")
    ap.add_argument("--skip-scale", action="store_true", help="skip the fleet-fit and sweep scaling (Ray)")
    ap.add_argument("--skip-adapt", action="store_true", help="skip the online predictor update timing")
    ap.add_argument("--skip-artio", action="store_true", help="skip the hopping artificial-IO completion timing")
    args = ap.parse_args(argv)
    log = lambda msg: print(msg, file=sys.stderr)  # noqa: E731
    report: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        for size in SIZES:
            log(f"bench {size} ...")
            report[size] = bench_size(size, args.ticks, Path(tmp), log)
            # issue 14's layout: "standalone": {size: ...} (daqp, osqp nested), "aarch64_qemu": {size: ...} or null
            sa = report[size].pop("standalone")
            report.setdefault("standalone", {})[size] = {**sa["daqp"], "osqp": sa["osqp"]}
            arm = report[size].pop("aarch64_qemu")
            report["aarch64_qemu"] = None if arm is None else {**(report.get("aarch64_qemu") or {}), size: arm}
        log("preview tracking (Tf 15 / Tf 100 on 10 knots / Tf 100 free) ...")
        report["preview_tracking"] = preview_tracking(Path(tmp), args.ticks, log)
    if not args.skip_artio:
        log("hopping artificial-IO completion ...")
        report["hopping_completion"] = completion_timing(log)
    if not args.skip_adapt:
        log("online predictor update (C) ...")
        # every size, the knot-parameterized preview included (its Hankel block is 4x the flying one's)
        report["adapt"] = {size: adapt_timing(size) for size in SIZES}
    if not args.skip_predictor:
        log("predictor fit on 10^6 samples (fresh process) ...")
        report["predictor_1e6"] = predictor_scaling()
    if not args.skip_scale:
        report["scale"] = scale_entry(log)
    report["meta"] = {"ticks": args.ticks, "machine": platform.machine(), "python": platform.python_version(),
                      "date": time.strftime("%Y-%m-%d")}
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(report, indent=2) + "\n")
    print(_table(report))
    for name, r in report["preview_tracking"].items():
        print(f"preview tracking {name:14} ({r['n_z']:3} QP variables): RMSE {', '.join(f'{v * 1e3:.2f}' for v in r['rmse'])} "
              f"mm, tick median {r['tick_median_us']:.1f} µs, p99 {r['tick_p99_us']:.1f} µs")
    if "predictor_1e6" in report:
        p = report["predictor_1e6"]
        print(f"\npredictor fit, 10^6 samples (m=p=2, Tini=20, Tf=15): lsq {p['lsq_seconds']:.1f} s, "
              f"pem {p['pem_seconds']:.1f} s, peak RSS {p['peak_rss_mib']:.0f} MiB "
              f"({p['rss_before_fit_mib']:.0f} MiB before fitting)")
    if "adapt" in report:
        print("\n" + "\n".join(adapt_lines(list(report["adapt"].values()))))
    print(f"\nwrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
