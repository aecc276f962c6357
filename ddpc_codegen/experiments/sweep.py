"""``ddpc-codegen sweep SPEC.toml``: tuning sweeps of the steering config over simulated conditions.

Each point (configuration overrides x condition x seed; see :mod:`.sweep_spec`) is one task: fit
the predictor and generate + compile the solver (both cached when their inputs repeat: in the
worker's memory, and on disk, shared by the workers of a node under file locks), one closed-loop
run, its metrics. Tasks run serially (``workers=1``) or on Ray (:mod:`ddpc_codegen.cluster`).

Output folder::

    results.csv   one row per point (appended as points finish, rewritten in point order at the end)
    sweep.json    the spec's context hash (a resume must match it), counts, timings, the best config
    data.npz      the training data (recorded once; a resume reads it back)
    best.toml     the best configuration, ready for ``ddpc-codegen codegen best.toml``
    best_data.npz the dataset best.toml's predictor is fitted on
    pareto.png    per-configuration means of the spec's Pareto metrics
    solvers/      the generated solvers (one folder per configuration) and fitted predictors (fits/)

An interrupted sweep resumes from results.csv (``resume=True``): finished points are not redone.
A point that fails (an infeasible config, a fit error, a crash of the simulator) is a row with
``status = error`` and the message; the sweep goes on.
"""

from __future__ import annotations

import csv
import fcntl
import hashlib
import io
import itertools
import json
import sys
import time
from collections import OrderedDict
from contextlib import closing, contextmanager
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np

from ddpc_codegen.cluster import engine
from ddpc_codegen.values.config import SteeringConfig
from ddpc_codegen.design.data import IODataset
from ddpc_codegen.design.fit import fit_configured
from ddpc_codegen.design.predictor import Predictor
from ddpc_codegen.errors import ConfigError, ManifestError
from ddpc_codegen.experiments.pipeline import SteeringSetup, build_setup, collect
from ddpc_codegen.experiments.evaluate import run
from ddpc_codegen.experiments.sweep_cache import load_predictor, save_predictor
from ddpc_codegen.experiments.sweep_spec import METRICS, Point, SweepSpec
from ddpc_codegen.codegen import generate
from ddpc_codegen.experiments.sweep_report import write_report
from ddpc_codegen.runtime.loader import load_solver
from ddpc_codegen.values.files import MiB, load_json_bounded, read_text_bounded

__all__ = ["SweepContext", "evaluate_point", "run_sweep", "read_results", "columns", "TIMING_COLUMNS"]

RESULTS_MAX_BYTES = 256 * MiB  # MAX_POINTS rows of a few hundred bytes each, ten times over

# Columns that measure this machine's speed: they differ between any two runs of the same point.
TIMING_COLUMNS = ("solve_us_p50", "solve_us_p99", "setup_s", "wall_s")
_RUN_COLUMNS = ("crashed", "fallbacks", "solver_failures", "steered_ticks", "solver")
_CACHE = 4  # setups (predictor + loaded solver) kept per worker process


def columns(spec: SweepSpec) -> list[str]:
    """The results table's columns for a spec (space keys hold JSON values)."""
    return (["index", "id", "kind", "variant", *spec.space, "condition", "seed", "status", "error",
             *METRICS[spec.scenario], *_RUN_COLUMNS, *TIMING_COLUMNS])


@dataclass(frozen=True)
class SweepContext:
    """What every task gets (shipped once through the object store): the spec, the training data
    (numpy arrays: read zero-copy by workers on the driver's node), the solver cache folder."""

    spec: SweepSpec
    raw: IODataset
    cache_dir: str


# ----------------------------------------------------------------------------- worker side
_SETUPS: "OrderedDict[str, SteeringSetup]" = OrderedDict()
_FITS: "OrderedDict[str, Predictor]" = OrderedDict()


def _remember(cache: OrderedDict, key: str, value: Any) -> Any:
    cache[key] = value
    while len(cache) > _CACHE:  # bounded: a long sweep must not grow a worker's memory
        cache.popitem(last=False)
    return value


@contextmanager
def _locked(path: Path) -> Iterator[None]:
    """An exclusive lock file: two workers on one node never build the same solver folder at once."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def _cached_fit(cfg: SteeringConfig, ds: IODataset, cache_dir: str) -> Predictor:
    """fit_configured (the config's [predictor] table), memoised on (data, horizons, predictor options):
    in this process, then on disk (the first worker of a node fits, the others read its result)."""
    h = hashlib.sha256(json.dumps([cfg.t_ini, cfg.t_f, cfg.predictor], sort_keys=True).encode())
    for a in (*ds.u, *ds.y):
        h.update(np.ascontiguousarray(a).tobytes())
    key = h.hexdigest()[:24]
    if key in _FITS:
        _FITS.move_to_end(key)
        return _FITS[key]
    path = Path(cache_dir) / "fits" / f"{key}.npz"
    with _locked(path.with_suffix(".lock")):
        if path.exists():  # numbers + JSON with a content hash, never pickle (the folder is user-writable)
            pred = load_predictor(path, key)
        else:
            pred = fit_configured(cfg, ds)
            save_predictor(path, pred, key)
    return _remember(_FITS, key, pred)


def _attach_solver(setup: SteeringSetup, cache_dir: str) -> None:
    """Load the configuration's generated solver from the cache, or generate + compile it there."""
    folder = Path(cache_dir) / f"sweep_{setup.config.digest[:12]}"
    with _locked(folder.with_suffix(".lock")):
        try:  # the manifest check refuses a folder made from another config or predictor
            solver = load_solver(folder, config=setup.config, predictor_hash=setup.predictor.digest)
        except ManifestError:
            generate(setup.problem, folder, name=folder.name)
            solver = load_solver(folder)
    setup.solver, setup.solver_path = solver, folder


def _setup(ctx: SweepContext, point: Point) -> SteeringSetup:
    cfg = ctx.spec.config(point.overrides)
    if cfg.digest in _SETUPS:
        _SETUPS.move_to_end(cfg.digest)
        return _SETUPS[cfg.digest]
    setup = build_setup(ctx.spec.scenario, config=cfg, raw=ctx.raw, generate_dir=None, save_data=False,
                        fit=partial(_cached_fit, cache_dir=ctx.cache_dir))
    if ctx.spec.solver == "generated":
        _attach_solver(setup, ctx.cache_dir)
    return _remember(_SETUPS, cfg.digest, setup)


def _run_row(res: Any, scenario: str) -> dict[str, Any]:
    """The table's metric and run columns of one run."""
    row: dict[str, Any] = {k: res.metrics.get(k) for k in METRICS[scenario]}
    st = res.steering or {}
    reasons = st.get("fallback_reasons", {})
    row.update(crashed=bool(res.metrics.get("crashed")), fallbacks=st.get("fallbacks", 0),
               solver_failures=sum(v for k, v in reasons.items()
                                   if k.startswith(("solver_", "exception", "nonfinite_solution"))),
               steered_ticks=st.get("steered", 0), solver=st.get("solver", ""),
               solve_us_p50=st.get("solve_us", {}).get("p50"), solve_us_p99=st.get("solve_us", {}).get("p99"),
               wall_s=res.metrics.get("wall_s"))
    return row


def evaluate_point(ctx: SweepContext, point: Point) -> dict[str, Any]:
    """One point -> one table row. Never raises: a failure is ``status = error`` with its message."""
    row: dict[str, Any] = {"index": point.index, "id": point.id, "kind": point.kind, "variant": point.variant,
                           **{k: json.dumps(v) for k, v in point.overrides}, "condition": point.condition.name,
                           "seed": point.seed, "status": "ok", "error": ""}
    from threadpoolctl import threadpool_limits

    # One BLAS thread in every engine (a Ray task has one CPU): the fit's rounding then does not
    # depend on where a point runs, and serial and parallel tables are equal to the last bit.
    with threadpool_limits(1):
        return _evaluate(ctx, point, row)


def _evaluate(ctx: SweepContext, point: Point, row: dict[str, Any]) -> dict[str, Any]:
    spec = ctx.spec
    try:
        setup = None
        if point.kind == "steered":
            t0 = time.perf_counter()
            setup = _setup(ctx, point)
            row["setup_s"] = round(time.perf_counter() - t0, 3)
        res = run(setup, spec.scenario, spec.duration, steer=setup is not None,
                  interpreted=spec.solver == "interpreted", seed=point.seed, **point.condition.run_kwargs())
        row.update(_run_row(res, spec.scenario))
    except Exception as e:  # noqa: BLE001 - a bad point is a row, not the end of the sweep
        row.update(status="error", error=f"{type(e).__name__}: {e}".replace("\n", " "))
    return row


# ----------------------------------------------------------------------------- results file
def _cell(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return repr(v)  # round-trips exactly: serial and parallel tables compare byte for byte
    return str(v)


def read_results(path: str | Path) -> list[dict[str, str]]:
    """Rows of a results.csv (strings, as written); read bounded (a resumed sweep reads what is on disk)."""
    text = read_text_bounded(path, "sweep results", RESULTS_MAX_BYTES)
    try:
        return list(csv.DictReader(io.StringIO(text, newline="")))
    except csv.Error as e:  # a cell longer than csv.field_size_limit() (128 KiB)
        raise ConfigError(f"{path}: sweep results: {e}; choose another --out") from None


def _write_sorted(path: Path, cols: list[str], rows: list[dict[str, str]]) -> None:
    tmp = path.with_suffix(".tmp")
    with open(tmp, "w", newline="") as f:
        w = csv.DictWriter(f, cols, extrasaction="ignore")
        w.writeheader()
        w.writerows(sorted(rows, key=lambda r: int(r["index"])))
    tmp.replace(path)  # atomic: an interruption here leaves the old, complete file


def _training_data(spec: SweepSpec, out: Path, say: Callable[[str], None]) -> IODataset:
    """The spec's dataset, or the recording kept in out/data.npz, or a new recording."""
    if spec.dataset:
        return IODataset.load(spec.dataset)
    path = out / "data.npz"
    if path.exists():
        return IODataset.load(path)
    say(f"[sweep] recording {spec.collect.duration:.0f} s of {spec.scenario} training data ...")
    res = collect(spec.scenario, spec.collect)
    t_min = getattr(res.scenario_obj, "settle_time", 0.0) if spec.scenario == "flying" else 0.0
    ds = res.to_dataset("none", t_min=t_min)
    ds.save(path)
    return ds


def _prepare(spec: SweepSpec, out: Path, resume: bool) -> tuple[list[dict[str, str]], dict]:
    """Existing rows of a resumed sweep (checked against the spec's context), or a fresh folder."""
    results, meta_path = out / "results.csv", out / "sweep.json"
    meta = {"spec": spec.path, "context": spec.context_digest}
    if results.exists() and not resume:
        raise ConfigError(f"{results} exists: pass --resume to continue that sweep, or choose another --out")
    if not results.exists():
        out.mkdir(parents=True, exist_ok=True)
        meta_path.write_text(json.dumps(meta, indent=2) + "\n")
        return [], meta
    old = load_json_bounded(meta_path, "sweep meta") if meta_path.exists() else {}
    old = old if isinstance(old, dict) else {}
    if old.get("context") != spec.context_digest:
        raise ConfigError(f"{results} was made with another base config, data, duration or solver "
                          f"(context {old.get('context')} vs {spec.context_digest}); choose another --out")
    rows = read_results(results)
    if rows and list(rows[0]) != columns(spec):
        raise ConfigError(f"{results} has other columns than this spec's table; choose another --out")
    return rows, {**old, **meta}


def spread_variants(points: list[Point], workers: int) -> list[Point]:
    """Dispatch order for ``workers`` parallel workers: the points of ``workers`` consecutive variants
    interleaved, so the workers start on different variants and build their solvers (fit + codegen, a
    few seconds each) at the same time instead of one waiting on the other's lock; a worker then keeps
    meeting the same few variants (its setup cache holds them). Serial: the order is unchanged."""
    if workers <= 1:
        return list(points)
    groups: OrderedDict[str, list[Point]] = OrderedDict()
    for p in points:
        groups.setdefault(p.variant, []).append(p)
    blocks = list(groups.values())
    out: list[Point] = []
    for i in range(0, len(blocks), workers):
        chunk = blocks[i : i + workers]
        out += [p for row in itertools.zip_longest(*chunk) for p in row if p is not None]
    return out


def run_sweep(spec: SweepSpec | str | Path, out_dir: str | Path, *, workers: int = 1, address: str | None = None,
              resume: bool = False, progress: bool = True, on_row: Callable[[dict], None] | None = None,
              report: bool = True) -> dict[str, Any]:
    """Run (or resume) a sweep; returns the summary also written to ``out_dir/sweep.json``.

    Args:
        workers, address: the engine (1 = serial in this process; see :func:`ddpc_codegen.cluster.engine`).
        resume: continue from ``out_dir/results.csv`` (its finished points are kept, not rerun).
        on_row: called with every finished row (after it is appended to the file).
        report: write best.toml, best_data.npz and pareto.png at the end.
    """
    spec = spec if isinstance(spec, SweepSpec) else SweepSpec.from_toml(spec)
    out = Path(out_dir)
    say = (lambda m: print(m, file=sys.stderr, flush=True)) if progress else (lambda m: None)
    done, meta = _prepare(spec, out, resume)
    cols, results = columns(spec), out / "results.csv"
    points = spec.points()
    ids = {p.id for p in points}
    done = [r for r in done if r["id"] in ids]  # rows of points no longer in the spec are dropped
    finished = {r["id"] for r in done}
    todo = [p for p in points if p.id not in finished]
    raw = _training_data(spec, out, say)
    ctx = SweepContext(spec, raw, str((out / "solvers").resolve()))
    say(f"[sweep] {len(points)} points ({len(finished)} done before), {len(todo)} to run on "
        f"{'1 worker (serial)' if workers == 1 and address is None else f'{workers} workers'}")
    t0 = time.perf_counter()
    new = 0
    if not results.exists():
        _write_sorted(results, cols, [])
    from tqdm import tqdm

    with engine(workers, address, quiet=not progress) as eng, \
            tqdm(total=len(points), initial=len(finished), desc="sweep", unit="pt", disable=not progress,
                 file=sys.stderr) as bar, open(results, "a", newline="") as f, \
            closing(eng.imap_unordered(evaluate_point, spread_variants(todo, eng.workers if eng.parallel else 1),
                                       shared=ctx)) as finished_rows:
        writer = csv.DictWriter(f, cols, extrasaction="ignore")
        for _, row in finished_rows:
            cells = {k: _cell(row.get(k)) for k in cols}
            writer.writerow(cells)
            f.flush()  # a finished point survives an interruption
            done.append(cells)
            new += 1
            bar.update(1)
            if on_row is not None:
                on_row(row)
        workers_used = eng.workers
    wall = time.perf_counter() - t0
    _write_sorted(results, cols, done)
    summary = {**meta, "points": len(points), "ran": new, "resumed_from": len(finished),
               "errors": sum(r["status"] != "ok" for r in done), "workers": workers_used,
               "address": address, "wall_s": round(wall, 2), "results": str(results)}
    if report:
        summary.update(write_report(spec, out, read_results(results), raw))
    (out / "sweep.json").write_text(json.dumps(summary, indent=2) + "\n")
    return summary
