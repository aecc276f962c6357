"""The simulator's results (``make demo``, ``reports/summary.json``): its page and its headline table.

The page: the flying and hopping runs with and without steering, the robustness conditions, the steering
against the simple fixes, the figures and the metric definitions. The headline (also the README's table):
per scenario and condition, the judged error of passthrough, of the best simple fix and of the steering.
"""

from __future__ import annotations

from pathlib import Path
from ddpc_codegen.docsgen.results_format import (NA, best_simple_fix, label, missing, mm, num, page_head, ratio,
                                                 table, tally)

__all__ = ["SCENARIOS", "headline", "sim_page"]

# scenario -> (its judged metric in summary.json, how the page names it with its unit)
SCENARIOS = {"flying": ("rmse_z", "RMSE z [mm]"), "hopping": ("apex_error_mean_abs", "mean |apex err| [mm]")}
_METHODS = ("passthrough", "ctrl_ff", "prefilter", "ilc", "ddpc")  # summary.json's baselines keys


def _runs_table(sc: str, block: dict) -> str:
    """One scenario's runs: each metric without and with steering, the solve time and the fallbacks."""
    b, s = block["baseline"], block["steered"]
    metrics = [("RMSE z [mm]", "rmse_z", 1e3, 1), ("RMSE pitch [mrad]", "rmse_pitch", 1e3, 2)]
    if sc == "hopping":
        metrics += [("RMSE roll [mrad]", "rmse_roll", 1e3, 2), ("mean |apex err| [mm]", "apex_error_mean_abs", 1e3, 2),
                    ("mean |vx err| [mm/s]", "vx_error_mean_abs", 1e3, 1)]
    rows = [[name, num(b.get(k), f, d), num(s.get(k), f, d), ratio(b.get(k), s.get(k))] for name, k, f, d in metrics]
    solve = block.get("solve_us") or {}
    rows.append(["solver call median / p99 [µs]", NA, f"{num(solve.get('median'))} / {num(solve.get('p99'))}", NA])
    rows.append(["fallbacks [ticks]", NA, str(block.get("fallbacks", NA)), NA])
    return table(["metric", "without steering", "steered", "without / steered"], rows)


def _robustness_table(sc: str, conds: dict) -> str:
    """One scenario's robustness conditions: the judged metric, the side metrics, the steering's activity."""
    key, name = SCENARIOS[sc]
    side = [("RMSE pitch without / steered [mrad]", "rmse_pitch", 2)]
    if sc == "hopping":
        side.append(("mean |vx err| without / steered [mm/s]", "vx_error_mean_abs", 1))
    head = ["condition", f"{name} without", f"{name} steered", "without / steered", *(h for h, _, _ in side),
            "z_ref offset step rms, steered [mm]", "thrust at 0 or 1, steered [% of ticks]", "fallbacks [ticks]"]
    rows = []
    for cond, r in conds.items():
        if "error" in r:
            rows.append([cond, f"failed: {r['error'][:60]}"] + [NA] * (len(head) - 2))
            continue
        b, s = r["baseline"], r["steered"]
        offset = (s.get("offset_step_rms") or [None])[0]
        rows.append([cond, mm(b.get(key), 2), mm(s.get(key), 2), ratio(b.get(key), s.get(key), 1),
                     *(f"{num(b.get(k), 1e3, d)} / {num(s.get(k), 1e3, d)}" for _, k, d in side),
                     mm(offset, 2), num(s.get("thrust_limit_share"), 1e2, 2), str(r.get("fallbacks", NA))])
    return table(head, rows)


def _fix_values(row: dict, metric: str) -> dict[str, float | None]:
    """A baselines condition's judged error per method (None: crashed or not flown)."""
    return {m: None if row.get(m, {}).get("crashed") else row.get(m, {}).get(metric) for m in _METHODS}


def _baselines_table(sc: str, blk: dict) -> str:
    """One scenario against the simple fixes, per condition: every method, the best fix, steered / best fix."""
    metric, name = blk["metric"], SCENARIOS[sc][1]
    rows = []
    for cname, row in blk["conditions"].items():
        vals = _fix_values(row, metric)
        cells = ["crash" if row.get(m, {}).get("crashed") else mm(vals[m], 2) for m in _METHODS]
        if not row.get("ilc_learned_here", True):
            cells[3] += "*"
        best = best_simple_fix(vals)
        rows.append([cname, *cells, NA if best is None else label(best[0]),
                     NA if best is None else ratio(vals["ddpc"], best[1])])
    head = ["condition", *(f"{label(m)} [mm]" for m in _METHODS), "best simple fix", "steered / best simple fix"]
    return f"{name} per condition:\n\n" + table(head, rows)


def _ilc_text(sc: str, blk: dict) -> str:
    il = blk.get("ilc")
    if not il:
        return ""
    per = ", ".join(mm(v, 2) for v in il["metric_per_iteration"])
    return (f"\nILC on the periodic {sc} case: {per} mm per iteration (0 = unmodified; within 10 % of its best at "
            f"iteration {il['iterations_to_settle']}; the last one is flown). `*`: that table, learned on the "
            "periodic case, flown unchanged on this one.\n")


def _hopping_side_table(blk: dict) -> str:
    """Hopping: the velocity error a height correction must not spoil, and each method's offset steps."""
    methods = [m for m in _METHODS if m != "ctrl_ff"]
    rows = []
    for cname, row in blk["conditions"].items():
        vx = " / ".join(num(row[m].get("vx_error_mean_abs"), 1e3) for m in methods)
        step = " / ".join(mm((row[m].get("offset_step_rms") or [None])[0], 2) for m in methods)
        rows.append([cname, vx, step])
    names = " / ".join(label(m) for m in methods)
    return ("\nHopping, what a height correction must not spoil:\n\n"
            + table(["condition", f"mean |vx err| [mm/s]: {names}", f"z_ref offset step rms [mm]: {names}"], rows))


def _baselines_section(baselines: dict) -> str:
    text = ["## Against the simple fixes\n", "The same paths flown with passthrough (the path as it is), the "
            "controller's own feed-forward, a prefilter fitted on the same data, ILC and the steering. Best simple "
            "fix: the lowest error of ctrl ff, prefilter and ILC; steered / best simple fix < 1: the steering is "
            "better.\n"]
    for sc, blk in baselines.items():
        text += [f"### {sc.capitalize()}\n", _baselines_table(sc, blk) + _ilc_text(sc, blk)
                 + (_hopping_side_table(blk) if blk["metric"] != "rmse_z" else "")]
    return "\n".join(text)


def headline(summary: dict) -> str:
    """Per scenario and condition: passthrough, the best simple fix and the steering on the judged error,
    steered / best simple fix, and the count of conditions the steering won."""
    rows, pairs = [], []
    for sc, (key, name) in SCENARIOS.items():
        blk = (summary.get("baselines") or {}).get(sc)
        if blk:
            for cname, row in blk["conditions"].items():
                vals = _fix_values(row, blk["metric"])
                best = best_simple_fix(vals)
                pairs.append((vals["ddpc"], None if best is None else best[1]))
                rows.append([sc, cname, name, mm(vals["passthrough"], 2),
                             NA if best is None else f"{mm(best[1], 2)} ({label(best[0])})", mm(vals["ddpc"], 2),
                             NA if best is None else ratio(vals["ddpc"], best[1])])
        elif sc in summary:
            b, s = summary[sc]["baseline"].get(key), summary[sc]["steered"].get(key)
            rows.append([sc, "nominal", name, mm(b, 2), NA, mm(s, 2), NA])
    head = ["scenario", "condition", "judged error", "passthrough", "best simple fix", "steered",
            "steered / best simple fix"]
    return table(head, rows) + ("\n" + tally(pairs) if pairs else "")


def _definitions(defs: dict) -> str:
    return ("## Definitions\n\nEvery flight figure comes from one function, `ddpc_codegen.flight_metrics`, in-process "
            "and from a tick log alike.\n\n" + "\n".join(f"- **{k}**: {v}" for k, v in defs.items()) + "\n")


def sim_page(summary: dict | None) -> str:
    """The simulator page (Markdown) from ``reports/summary.json`` (None: not measured yet)."""
    head = page_head("Simulator: flying and hopping PogoX", "`make demo` on the PogoX simulator: data recorded "
                     "with PRBS excitation, predictors fitted, the steering solvers generated and compiled, each "
                     "scenario flown without and with steering.")
    if summary is None:
        return head + "\n" + missing("make demo", "summary.json")
    meta = summary.get("meta", {})
    out = [head, f"Controller mass error {meta.get('mass_error_kg', '?')} kg (the data were recorded with it); "
           f"solver: {'interpreted QP' if meta.get('interpreted') else 'the generated C solver in the loop'}; "
           f"wall time {meta.get('wall_time_s', '?')} s on {meta.get('machine', '?')} "
           f"(Python {meta.get('python', '?')}).\n"]
    for sc in SCENARIOS:
        if sc in summary:
            out += [f"## {sc.capitalize()} ({num(summary[sc].get('duration_s'), 1, 0)} s)\n", _runs_table(sc, summary[sc])]
    if summary.get("robustness"):
        out += ["## Robustness\n", "Same predictors and solvers; the conditions were never in the data.\n"]
        out += [f"### {sc.capitalize()}\n\n" + _robustness_table(sc, conds) for sc, conds in summary["robustness"].items()]
    if summary.get("baselines"):
        out.append(_baselines_section(summary["baselines"]))
    figures = [Path(f) for f in meta.get("figures", [])]
    if figures:
        out += ["## Figures\n", "\n".join(f"![{f.stem}](../figures/{f.name})\n" for f in figures)]
    if meta.get("definitions"):
        out.append(_definitions(meta["definitions"]))
    return "\n".join(out)
