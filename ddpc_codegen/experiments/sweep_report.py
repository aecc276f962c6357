"""A finished sweep's table -> per-configuration means, the Pareto plot, the best config as TOML."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from ddpc_codegen.design.data import IODataset
from ddpc_codegen.experiments.pipeline import build_setup
from ddpc_codegen.experiments.sweep_spec import SweepSpec

__all__ = ["aggregate", "pareto_mask", "plot_pareto", "to_toml", "write_best", "write_report"]


def _num(s: str) -> float:
    try:
        return float(s)
    except (TypeError, ValueError):
        return math.nan


def aggregate(spec: SweepSpec, rows: list[dict[str, str]]) -> dict[str, dict[str, Any]]:
    """variant label -> {"points", "errors", "crashed", <metric>: mean over conditions x seeds}.

    A configuration with any failed or crashed point gets NaN means: it never wins.
    """
    keys = (spec.objective, *spec.pareto)
    groups: dict[str, list[dict[str, str]]] = {}
    for r in rows:
        groups.setdefault(r["variant"], []).append(r)
    out = {}
    for variant, rs in groups.items():
        bad = sum(r["status"] != "ok" for r in rs)
        crashed = sum(r.get("crashed") == "True" for r in rs)
        agg: dict[str, Any] = {"points": len(rs), "errors": bad, "crashed": crashed,
                               "first_error": next((r["error"] for r in rs if r["status"] != "ok"), "")}
        for k in keys:
            vals = [_num(r.get(k, "")) for r in rs]
            agg[k] = float(np.mean(vals)) if vals and not (bad or crashed) else math.nan
        out[variant] = agg
    return out


def pareto_mask(values: np.ndarray) -> np.ndarray:
    """(n, k) costs (lower is better) -> (n,) True where no other row is <= everywhere and < somewhere."""
    v = np.asarray(values, dtype=float)
    ok = np.all(np.isfinite(v), axis=1)
    mask = ok.copy()
    for i in np.flatnonzero(ok):
        dominated = np.all(v[ok] <= v[i], axis=1) & np.any(v[ok] < v[i], axis=1)
        mask[i] = not dominated.any()
    return mask


def plot_pareto(spec: SweepSpec, agg: dict[str, dict[str, Any]], best: str | None, path: Path) -> Path:
    """Scatter of per-configuration means (x, y = the first two Pareto metrics, colour = a third)."""
    from ddpc_codegen.sim.plots import _mpl, save_figure

    plt = _mpl()
    names = [v for v in agg if v != "baseline"]
    x, y = spec.pareto[0], spec.pareto[1]
    vals = np.array([[agg[v][k] for k in spec.pareto] for v in names]).reshape(len(names), len(spec.pareto))
    front = pareto_mask(vals) if names else np.zeros(0, bool)
    fig, ax = plt.subplots(figsize=(7, 5))
    if names:
        c = vals[:, 2] if vals.shape[1] > 2 else None
        if c is not None:
            sc = ax.scatter(vals[:, 0], vals[:, 1], c=c, cmap="viridis", s=30, label="configurations")
            fig.colorbar(sc, ax=ax, label=spec.pareto[2])
        else:
            ax.scatter(vals[:, 0], vals[:, 1], s=30, label="configurations")
        order = np.argsort(vals[front, 0])
        ax.plot(vals[front, 0][order], vals[front, 1][order], "r-", lw=1, label="Pareto front")
    if "baseline" in agg and np.isfinite(agg["baseline"][x]):
        ax.plot(agg["baseline"][x], agg["baseline"][y], "k*", ms=12, label="without steering")
    if best in agg:
        ax.plot(agg[best][x], agg[best][y], "o", mfc="none", mec="r", ms=14, label=f"best ({spec.objective})")
    ax.set_xlabel(f"{x} (mean over conditions x seeds)")
    ax.set_ylabel(y)
    shown = vals[np.all(np.isfinite(vals), axis=1)] if names else vals
    if shown.size and np.all(shown[:, :2] > 0):  # errors spanning decades; log needs positive values
        ax.set_xscale("log")
        ax.set_yscale("log")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    failed = int(np.sum(~np.all(np.isfinite(vals), axis=1))) if names else 0
    ax.set_title(f"sweep {Path(spec.path).stem}: {len(names)} configurations ({failed} failed), "
                 f"{int(front.sum())} on the Pareto front")
    fig.tight_layout()
    return save_figure(fig, path)


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v) if math.isfinite(v) else ("nan" if math.isnan(v) else ("inf" if v > 0 else "-inf"))
    if isinstance(v, str):
        return json.dumps(v)  # JSON string escapes are valid TOML basic-string escapes
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"cannot write {v!r} as a TOML value")


def to_toml(tables: dict[str, Any]) -> str:
    """A config's tables as flat TOML (one line per key, like configs/*.toml; nested tables one level)."""
    lines = [f"{k} = {_toml_value(v)}" for k, v in tables.items() if not isinstance(v, dict)]
    for k, v in tables.items():
        if isinstance(v, dict):
            lines += ["", f"[{k}]"] + [f"{kk} = {_toml_value(vv)}" for kk, vv in v.items()]
    return "\n".join(lines) + "\n"


def write_best(spec: SweepSpec, variant: str, out: Path, raw: IODataset) -> Path:
    """best.toml (base config + the winning overrides, [data] pointing at best_data.npz) and its dataset."""
    overrides = tuple(json.loads(variant).items())
    tables = spec.config_tables(overrides)
    tables["name"] = tables.get("name", spec.scenario)
    # The predictor's dataset (hopping: the stitched hops of this config) so that
    # `ddpc-codegen codegen best.toml` fits exactly the sweep's predictor.
    setup = build_setup(spec.scenario, config=spec.config(overrides), raw=raw, generate_dir=None, save_data=False)
    setup.dataset.save(out / "best_data.npz")
    tables["data"] = {"dataset": "best_data.npz"}
    head = (f"# Best configuration of sweep {spec.path} (objective: mean {spec.objective} over "
            f"{len(spec.conditions)} condition(s) x {len(spec.seeds)} seed(s)).\n# Overrides of {spec.config_path}: "
            f"{variant}\n")
    path = out / "best.toml"
    path.write_text(head + to_toml(tables))
    return path


def write_report(spec: SweepSpec, out: Path, rows: list[dict[str, str]], raw: IODataset) -> dict[str, Any]:
    """Means per configuration, best.toml, pareto.png; returns their summary for sweep.json."""
    agg = aggregate(spec, rows)
    ranked = sorted((a[spec.objective], v) for v, a in agg.items()
                    if v != "baseline" and math.isfinite(a[spec.objective]))
    best = ranked[0][1] if ranked else None
    res: dict[str, Any] = {"configurations": {v: {k: (None if isinstance(x, float) and not math.isfinite(x) else x)
                                                  for k, x in a.items()} for v, a in agg.items()},
                           "best": best, "best_toml": None}
    if best is not None:
        res["best_toml"] = str(write_best(spec, best, out, raw))
        res["best_" + spec.objective] = agg[best][spec.objective]
    try:
        res["pareto_png"] = str(plot_pareto(spec, agg, best, out / "pareto.png"))
    except ModuleNotFoundError as e:  # matplotlib is the plots extra
        res["pareto_png"] = f"skipped: {e}"
    return res
