"""Hopping figure of ``make bench``: the generated artificial-IO completion per call (timed in C), on the
online windows a hopping run forms (``HoppingWindow`` over a held-out noisy run), against the
interpreted ``ArtificialIO`` on the same windows."""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from ddpc_codegen.runtime.hopping import HoppingWindow
from ddpc_codegen.values.config import SteeringConfig
from ddpc_codegen.experiments.pipeline import CollectSpec, collect, default_config
from ddpc_codegen.pipeline.solver_build import build_solver
from ddpc_codegen.runtime.loader import load_solver


class _Timed:
    """Wraps a completer: records every call's wall time [us] (C's own timer when it has one) and result."""

    def __init__(self, inner) -> None:
        self.inner, self.times, self.bounded, self.results, self.reduced = inner, [], [], [], []
        self.depth, self.noise_level, self.m, self.p, self.counts = (inner.depth, inner.noise_level, inner.m,
                                                                     inner.p, inner.counts)

    def complete(self, u, y, missing, **kw):
        t0 = time.perf_counter_ns()
        c = self.inner.complete(u, y, missing, **kw)
        wall = (time.perf_counter_ns() - t0) * 1e-3
        self.times.append(getattr(self.inner, "last_info", {}).get("solve_time_us", wall))
        self.bounded.append(c.bounded)
        self.reduced.append(bool(getattr(self.inner, "last_info", {}).get("reduced", False)))
        self.results.append(c)
        return c


def completion_timing(log=print, duration: float = 40.0) -> dict:
    """Median / p99 µs per call of the generated completion (unbounded and bounded calls apart) and of
    the interpreted one, and their largest difference, on the windows of a 20 s noisy hopping run."""
    cfg = SteeringConfig.from_toml(default_config("hopping"))
    raw = collect("hopping", CollectSpec(duration=duration, seed=1, amplitude=(0.01, 0.02, 0.02))).to_dataset("none")
    held = collect("hopping", CollectSpec(duration=20.0, seed=5, noise=True, amplitude=(0.01, 0.02, 0.02)))
    with tempfile.TemporaryDirectory() as tmp:
        log("  generating the hopping solver with its completion ...")
        built = build_solver(cfg, raw, Path(tmp) / "artio_bench", name="artio_bench")
        solver, art, sp = load_solver(built.path), built.art, built.art_spec
        out = {"depth": art.depth, "rank": art.rank}
        runs = {}
        for label, op in (("generated", solver.artificial_io), ("interpreted", art)):
            timed = _Timed(op)
            win = HoppingWindow(timed, cfg.t_ini, **sp.window_settings())
            for k in range(cfg.t_ini, held.n):
                win.window(held.u[:k], held.y[:k], held.phase[:k])
            runs[label] = timed
    g, i = runs["generated"], runs["interpreted"]
    tg, bg = np.asarray(g.times), np.asarray(g.bounded, dtype=bool)
    diff = max(max(np.abs(a.u - b.u).max(), np.abs(a.y - b.y).max()) for a, b in zip(g.results, i.results))
    out.update(calls=int(tg.size), bounded_calls=int(bg.sum()), bounded_reduced_form=int(np.sum(g.reduced)),
               c_median_us=float(np.median(tg)), c_p99_us=float(np.percentile(tg, 99)),
               c_unbounded_median_us=float(np.median(tg[~bg])) if (~bg).any() else None,
               c_bounded_median_us=float(np.median(tg[bg])) if bg.any() else None,
               python_interpreted_median_us=float(np.median(i.times)),
               max_abs_diff_generated_vs_interpreted=float(diff),
               statuses={s: sum(c.status == s for c in g.results) for s in {c.status for c in g.results}})
    log(f"  hopping completion: {out['calls']} calls ({out['bounded_calls']} bounded, "
        f"{out['bounded_reduced_form']} in the reduced form), C median "
        f"{out['c_median_us']:.1f} us (unbounded {out['c_unbounded_median_us']}, bounded {out['c_bounded_median_us']}), "
        f"p99 {out['c_p99_us']:.1f} us; interpreted median {out['python_interpreted_median_us']:.1f} us; "
        f"max |generated - interpreted| {diff:.2e}")
    return out
