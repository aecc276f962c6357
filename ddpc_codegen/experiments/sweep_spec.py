"""The sweep spec (TOML): base config, search space, conditions, seeds -> the list of points.

    [sweep]
    scenario = "flying"                # "flying" | "hopping"
    config = "../configs/flying.toml"  # base steering config (relative to this file; default configs/<scenario>.toml)
    search = "grid"                    # "grid" (every combination) | "random" (samples draws)
    samples = 16                       # random only: configurations drawn
    seed = 0                           # random only: the sampling seed
    seeds = [0, 1]                     # simulation seeds (sensor noise, ...) per condition
    duration = 10.0                    # simulated seconds per evaluation run
    solver = "generated"               # "generated" (compiled C, the default) | "interpreted" (Python)
    baseline = true                    # also run every condition x seed without steering
    objective = "rmse_z"               # metric whose mean over conditions x seeds picks the best config
    pareto = ["rmse_z", "rmse_pitch"]  # 2 metrics (x, y) of the Pareto plot, a 3rd colours the points

    [data]                             # training data: CollectSpec fields (recorded once), or dataset = "x.npz"
    duration = 45.0
    seed = 1

    [space]                            # "section.key" of the steering config -> values
    "cost.R" = [[0.5, 0.5], [0.3, 0.3]]                  # grid: a list; random: a list is a choice
    "predictor.ridge" = {log_uniform = [1e-4, 1e-1]}     # random only: log_uniform / uniform / int_uniform

    [conditions.nominal]               # named conditions (default: one "nominal" with no change)
    [conditions.noisy_heavy]
    noise = true
    mass_error = -0.3                  # controller model mass minus true mass [kg] (default -0.2)
    pushes = [[12.0, 0.0, 0.0, -10.0, 0.2]]  # [t, fx, fy, fz(, duration(, px, py, pz))] [s, N, s, m]

A point is (configuration overrides, condition, seed) and has a stable id (a hash of just those),
which is what a resumed sweep matches finished rows by.
"""

from __future__ import annotations

import copy
import hashlib
import itertools
import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ddpc_codegen.values.config import _SCHEMA, SteeringConfig
from ddpc_codegen.experiments.pipeline import CollectSpec, default_config
from ddpc_codegen.sim import PogoXParams, Push
from ddpc_codegen.values.files import load_toml_bounded
from ddpc_codegen.values.tomlconfig import check_keys, dataclass_from_table
from ddpc_codegen.values.tomlconfig import config_error as _err

__all__ = ["Condition", "Point", "SweepSpec", "METRICS", "MAX_POINTS"]

# Per-run metrics of scenario_metrics (SI units, radians) that a sweep table carries.
METRICS: dict[str, tuple[str, ...]] = {
    "flying": ("rmse_z", "rmse_pitch", "rmse_x", "mean_z_error"),
    "hopping": ("apex_error_mean_abs", "apex_error_mean_signed", "apex_error_max_abs", "rmse_pitch", "rmse_roll",
                "rmse_z", "vx_error_mean_abs", "n_hops"),
}
_DEFAULTS = {"flying": ("rmse_z", ["rmse_z", "rmse_pitch"]),
             "hopping": ("apex_error_mean_abs", ["apex_error_mean_abs", "rmse_pitch", "vx_error_mean_abs"])}
_SWEEP_KEYS = ("scenario", "config", "search", "samples", "seed", "seeds", "duration", "solver", "baseline",
               "objective", "pareto")
# A point is a closed-loop simulation (seconds of compute each): 10^5 points are days of compute, and the
# list of points is built in memory; a larger sweep is refused before its grid is expanded.
MAX_POINTS = 100_000
_DISTRIBUTIONS = ("uniform", "log_uniform", "int_uniform", "choice")
_FIXED_SECTIONS = ("signals", "data")  # changing channels or the dataset is not a tuning knob


@dataclass(frozen=True)
class Condition:
    """Evaluation condition: sensor noise, controller mass error [kg], pushes (t, force, duration, point)."""

    name: str
    noise: bool = False
    mass_error: float = PogoXParams().controller_mass_error
    pushes: tuple[tuple[float, ...], ...] = ()

    def run_kwargs(self) -> dict[str, Any]:
        """Keyword arguments of :func:`~ddpc_codegen.experiments.evaluate.run`."""
        pushes = [Push(p[0], tuple(p[1:4]), *([p[4]] if len(p) > 4 else []), *([tuple(p[5:8])] if len(p) > 5 else []))
                  for p in self.pushes]
        return {"params": PogoXParams(controller_mass_error=self.mass_error), "noise": self.noise or None,
                "pushes": pushes or None}


@dataclass(frozen=True)
class Point:
    """One evaluation: ``kind`` "steered" (with ``overrides`` of the base config) or "baseline"."""

    index: int
    kind: str
    overrides: tuple[tuple[str, Any], ...]
    condition: Condition
    seed: int

    @property
    def id(self) -> str:
        """Stable identity (kind, overrides, condition, seed): independent of the point's position."""
        key = {"kind": self.kind, "overrides": [list(o) for o in self.overrides],
               "condition": asdict(self.condition), "seed": self.seed}
        return hashlib.sha256(json.dumps(key, sort_keys=True, default=float).encode()).hexdigest()[:16]

    @property
    def variant(self) -> str:
        """The overrides as compact JSON (the table's configuration label)."""
        return json.dumps(dict(self.overrides), separators=(",", ":")) if self.kind == "steered" else "baseline"


def _space_key(key: str, src: str) -> tuple[str, str]:
    sec, _, name = key.partition(".")
    if not name or sec not in _SCHEMA or sec in _FIXED_SECTIONS or name not in _SCHEMA[sec]:
        tunable = sorted(f"{s}.{k}" for s, ks in _SCHEMA.items() if s and s not in _FIXED_SECTIONS for k in ks)
        raise _err(src, f"[space] {key!r}", f"is not a steering-config field; use one of {tunable}")
    return sec, name


def _conditions(table: Any, src: str) -> tuple[Condition, ...]:
    if not isinstance(table, dict):
        raise _err(src, "[conditions]", f"must be a table of named conditions; got {table!r}")
    out = []
    for name, body in table.items():
        where = f"[conditions.{name}]"
        check_keys(body, ("noise", "mass_error", "pushes"), where, src)
        noise = body.get("noise", False)
        if not isinstance(noise, bool):
            raise _err(src, f"{where} noise", f"must be true or false; got {noise!r}")
        me = body.get("mass_error", Condition.mass_error)
        try:
            PogoXParams(controller_mass_error=float(me))
        except (TypeError, ValueError) as e:
            raise _err(src, f"{where} mass_error", f"= {me!r}: {e}") from None
        pushes = body.get("pushes", [])
        ok = isinstance(pushes, list) and all(
            isinstance(p, list) and len(p) in (4, 5, 8) and all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                                                   for x in p) for p in pushes)
        if not ok:
            raise _err(src, f"{where} pushes", f"must be a list of [t, fx, fy, fz(, duration(, px, py, pz))]; got {pushes!r}")
        out.append(Condition(str(name), noise, float(me), tuple(tuple(float(x) for x in p) for p in pushes)))
    return tuple(out) or (Condition("nominal"),)


@dataclass(frozen=True)
class SweepSpec:
    """A validated sweep spec (see the module docstring for the TOML layout)."""

    path: str
    scenario: str
    config_path: str
    base: dict  # the base config's TOML tables
    search: str = "grid"
    samples: int = 8
    seed: int = 0
    seeds: tuple[int, ...] = (0,)
    duration: float = 10.0
    solver: str = "generated"
    baseline: bool = True
    objective: str = "rmse_z"
    pareto: tuple[str, ...] = ("rmse_z", "rmse_pitch")
    collect: CollectSpec | None = None
    dataset: str | None = None
    space: dict = field(default_factory=dict)
    conditions: tuple[Condition, ...] = (Condition("nominal"),)

    @classmethod
    def from_toml(cls, path: str | Path) -> "SweepSpec":
        """Load and validate; every error names the file, the key and the value."""
        path = Path(path)
        src = str(path)
        raw = load_toml_bounded(path, "sweep spec")
        check_keys(raw, ("sweep", "data", "space", "conditions"), "top-level", src)
        sw = check_keys(raw.get("sweep", {}), _SWEEP_KEYS, "[sweep]", src)
        scenario = sw.get("scenario", "flying")
        if scenario not in METRICS:
            raise _err(src, "[sweep] scenario", f"must be one of {list(METRICS)}; got {scenario!r}")
        cfg_path = (path.parent / sw["config"]).resolve() if "config" in sw else default_config(scenario)
        base = load_toml_bounded(cfg_path, "steering config")
        SteeringConfig.from_dict(base, source=str(cfg_path))  # the base must be valid on its own
        objective, pareto = _DEFAULTS[scenario]
        kw: dict[str, Any] = {"objective": sw.get("objective", objective), "pareto": tuple(sw.get("pareto", pareto))}
        for key, typ, lo in (("samples", int, 1), ("seed", int, 0), ("duration", (int, float), 1e-9)):
            if key in sw:
                v = sw[key]
                if isinstance(v, bool) or not isinstance(v, typ) or v < lo:
                    raise _err(src, f"[sweep] {key}", f"must be a number >= {lo}; got {v!r}")
                kw[key] = v
        for key, allowed in (("search", ("grid", "random")), ("solver", ("generated", "interpreted"))):
            if key in sw and sw[key] not in allowed:
                raise _err(src, f"[sweep] {key}", f"must be one of {list(allowed)}; got {sw[key]!r}")
            kw[key] = sw.get(key, allowed[0])
        seeds = sw.get("seeds", [0])
        if not (isinstance(seeds, list) and seeds and all(isinstance(s, int) and not isinstance(s, bool) for s in seeds)):
            raise _err(src, "[sweep] seeds", f"must be a non-empty list of integers; got {seeds!r}")
        if not isinstance(sw.get("baseline", True), bool):
            raise _err(src, "[sweep] baseline", f"must be true or false; got {sw['baseline']!r}")
        for key in (kw["objective"], *kw["pareto"]):
            if key not in METRICS[scenario]:
                raise _err(src, "[sweep] objective/pareto", f"{key!r} is not a {scenario} metric; use {list(METRICS[scenario])}")
        if not 2 <= len(kw["pareto"]) <= 3:
            raise _err(src, "[sweep] pareto", f"must name 2 or 3 metrics; got {list(kw['pareto'])}")
        data = dict(raw.get("data", {}))
        dataset = data.pop("dataset", None)
        if dataset is not None:
            dataset = str((path.parent / dataset).resolve())
            if data:
                raise _err(src, "[data]", f"dataset = {dataset!r} excludes recording keys {sorted(data)}")
        collect = None if dataset else dataclass_from_table(CollectSpec, data, "[data]", src,
                                                             base=CollectSpec.default(scenario))
        space = raw.get("space", {})
        if not isinstance(space, dict):
            raise _err(src, "[space]", f"must be a table of \"section.key\" = values; got {space!r}")
        for key, values in space.items():
            _space_key(key, src)
            _check_values(key, values, kw["search"], src)
        conditions = _conditions(raw.get("conditions", {}), src)
        _check_point_count(src, space, kw.get("samples", cls.samples), kw["search"], len(conditions), len(seeds),
                           sw.get("baseline", True))
        return cls(src, scenario, str(cfg_path), base, seeds=tuple(seeds), baseline=sw.get("baseline", True),
                   collect=collect, dataset=dataset, space=dict(space), conditions=conditions, **kw)

    # ------------------------------------------------------------------ points
    def variants(self) -> list[tuple[tuple[str, Any], ...]]:
        """Configuration overrides: the grid's combinations or the random draws, in a fixed order."""
        keys = list(self.space)
        if not keys:
            return [()]
        if self.search == "grid":
            return [tuple(zip(keys, combo)) for combo in itertools.product(*(self.space[k] for k in keys))]
        rng = np.random.default_rng(self.seed)
        return [tuple((k, _draw(self.space[k], rng)) for k in keys) for _ in range(self.samples)]

    def points(self) -> list[Point]:
        """Every evaluation: baselines first (per condition x seed), then variants x conditions x seeds."""
        out: list[Point] = []
        if self.baseline:
            out += [Point(0, "baseline", (), c, s) for c in self.conditions for s in self.seeds]
        out += [Point(0, "steered", v, c, s) for v in self.variants() for c in self.conditions for s in self.seeds]
        return [Point(i, p.kind, p.overrides, p.condition, p.seed) for i, p in enumerate(out)]

    def config_tables(self, overrides: tuple[tuple[str, Any], ...]) -> dict:
        """The base config's TOML tables with the overrides applied (a deep copy)."""
        raw = copy.deepcopy(self.base)
        for key, value in overrides:
            sec, name = key.split(".", 1)
            raw.setdefault(sec, {})[name] = value
        return raw

    def config(self, overrides: tuple[tuple[str, Any], ...], label: str = "") -> SteeringConfig:
        """The validated configuration of a variant (ConfigError names the spec and the overrides)."""
        return SteeringConfig.from_dict(self.config_tables(overrides),
                                        source=f"{self.path} {label}{json.dumps(dict(overrides))}")

    @property
    def context_digest(self) -> str:
        """Hash of what every point's result depends on besides the point itself (a resumed
        results file must come from the same context)."""
        ctx = {"scenario": self.scenario, "base": self.base, "duration": self.duration, "solver": self.solver,
               "data": asdict(self.collect) if self.collect else self.dataset}
        return hashlib.sha256(json.dumps(ctx, sort_keys=True, default=str).encode()).hexdigest()[:16]


def _check_point_count(src: str, space: dict, samples: int, search: str, n_conditions: int, n_seeds: int,
                       baseline: bool) -> None:
    """The number of points, computed from the spec before any list of them is built, at most :data:`MAX_POINTS`."""
    variants = math.prod(len(v) for v in space.values()) if search == "grid" else samples
    total = (variants + bool(baseline)) * n_conditions * n_seeds
    if total > MAX_POINTS:
        key = "[sweep] seeds" if n_seeds >= max(variants, n_conditions) else \
            "[conditions]" if n_conditions >= variants else "[space]" if search == "grid" else "[sweep] samples"
        raise _err(src, key, f"makes {total} points (({variants} configurations{' + the baseline' if baseline else ''}) x "
                   f"{n_conditions} conditions x {n_seeds} seeds), more than a sweep may have ({MAX_POINTS}); "
                   "split the sweep or use search = \"random\"")


def _check_values(key: str, values: Any, search: str, src: str) -> None:
    where = f"[space] {key!r}"
    if isinstance(values, list):
        if not values:
            raise _err(src, where, "must list at least one value")
        return
    if search == "grid":
        raise _err(src, where, f"must be a list of values for a grid search; got {values!r}")
    if not (isinstance(values, dict) and len(values) == 1 and next(iter(values)) in _DISTRIBUTIONS):
        raise _err(src, where, f"must be a list or one of {{{', '.join(d + ' = ...' for d in _DISTRIBUTIONS)}}}; got {values!r}")
    (dist, arg), = values.items()
    if dist == "choice":
        if not isinstance(arg, list) or not arg:
            raise _err(src, where, f"choice must be a non-empty list; got {arg!r}")
        return
    ok = isinstance(arg, list) and len(arg) == 2 and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in arg)
    if not ok or arg[0] > arg[1] or (dist == "log_uniform" and arg[0] <= 0):
        raise _err(src, where, f"{dist} needs [low, high] with low <= high" + (" and low > 0" if dist == "log_uniform" else "")
                   + f"; got {arg!r}")


def _draw(values: Any, rng: np.random.Generator) -> Any:
    """One random value of a space entry (a list = a uniform choice)."""
    if isinstance(values, list):
        return values[int(rng.integers(len(values)))]
    (dist, arg), = values.items()
    if dist == "choice":
        return arg[int(rng.integers(len(arg)))]
    lo, hi = arg
    if dist == "int_uniform":
        return int(rng.integers(int(lo), int(hi) + 1))
    if dist == "log_uniform":
        return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))
    return float(rng.uniform(lo, hi))

