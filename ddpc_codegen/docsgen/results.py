"""Render the measured results into the docs: ``docs/results.md`` and the README's results table.

Each measuring make target (``make demo``, ``make bench``, ``make sitl-demo``) ends with
``python -m ddpc_codegen.docsgen.results``, which rewrites the results page from whichever of
``reports/summary.json``, ``reports/bench.json`` and ``reports/sitl.json`` exist, copies the demo's
figures to ``docs/figures/`` and replaces the README's table between its marker comments. A report
that does not exist yet is named on the page with the target that writes it; nothing is copied by hand.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path
from typing import Any

from ddpc_codegen.testbed.sitl_conditions import steered_estimator_rms

ROOT = Path(__file__).resolve().parents[2]
BEGIN = "<!-- results:begin (written by make demo: python -m ddpc_codegen.docsgen.results) -->"
END = "<!-- results:end -->"
# report file -> (the make target that writes it, the page section that renders it)
REPORTS = {"summary.json": "make demo", "bench.json": "make bench", "sitl.json": "make sitl-demo"}

__all__ = ["ROOT", "BEGIN", "END", "REPORTS", "load_reports", "results_page", "readme_block", "replace_block",
           "copy_figures", "markdown_table", "main"]


def load_reports(reports: Path) -> dict[str, dict]:
    """The reports that exist in ``reports`` (file name -> parsed JSON); unreadable JSON is an error."""
    out = {}
    for name in REPORTS:
        path = reports / name
        if path.is_file():
            try:
                out[name] = json.loads(path.read_text())
            except json.JSONDecodeError as e:
                raise ValueError(f"{path}: not valid JSON ({e}); rerun {REPORTS[name]}") from None
    return out


def markdown_table(grid: str) -> str:
    """A printed table as valid Markdown: pipes inside cells (``|apex err|``) escaped.

    A separator pipe starts or ends the line or has a space on both sides; any other is cell text.
    Lines printed after the table (notes) go into a code block below it.
    """
    out, notes = [], []
    for line in grid.splitlines():
        if not line.startswith("|"):
            notes.append(line)
            continue
        if set(line) <= set("|-: "):
            out.append(line)
            continue
        chars = list(line)
        for i, c in enumerate(line):
            if c == "|" and 0 < i < len(line) - 1 and not (line[i - 1] == " " and line[i + 1] == " "):
                chars[i] = "\\|"
        out.append("".join(chars))
    return "\n".join(out) + ("\n\n```\n" + "\n".join(notes) + "\n```" if notes else "")


def _missing(name: str) -> str:
    return f"Not measured yet -- run `{REPORTS[name]}` (it writes `reports/{name}` and rewrites this page).\n"


def _demo_section(summary: dict) -> str:
    from ddpc_codegen.experiments.baselines_eval import format_baselines
    from ddpc_codegen.experiments.demo import format_robustness, format_table

    meta = summary.get("meta", {})
    parts = [f"Wall time {meta.get('wall_time_s', '?')} s on {meta.get('machine', '?')} "
             f"(Python {meta.get('python', '?')}); solver: "
             f"{'interpreted QP' if meta.get('interpreted') else 'the generated C solver in the loop'}; "
             f"controller mass error {meta.get('mass_error_kg', '?')} kg.\n", markdown_table(format_table(summary)) + "\n"]
    if "robustness" in summary:
        parts += ["### Robustness\n", "Same predictors and solvers; the mass errors were never in the data.\n",
                  markdown_table(format_robustness(summary["robustness"])) + "\n"]
    if "baselines" in summary:
        parts += ["### Against the simple fixes\n", "Best of passthrough / controller feed-forward / prefilter / "
                  "ILC divided by the steering's figure (> 1: steering is better; `*`: ILC's table learned on the "
                  "periodic case, flown unchanged).\n", markdown_table(format_baselines(summary["baselines"])) + "\n"]
    figures = [Path(f).name for f in meta.get("figures", [])]
    parts += [f"![{Path(f).stem}](figures/{f})\n" for f in figures]
    defs = meta.get("definitions", {})
    if defs:
        parts += ["### Definitions\n", "Every flight figure comes from one function, `ddpc_codegen.flight_metrics`, "
                  "in-process and from a tick log alike.\n", "\n".join(f"- **{k}**: {v}" for k, v in defs.items()) + "\n"]
    return "\n".join(parts)


def _bench_section(bench: dict) -> str:
    from ddpc_codegen.experiments.bench import _table  # the table make bench prints

    meta = bench.get("meta", {})
    text = f"{meta.get('ticks', '?')} ticks per size on {meta.get('machine', '?')}, {meta.get('date', '?')}.\n"
    text += "\n```\n" + _table(bench) + "\n```\n"
    if bench.get("adapt"):
        from ddpc_codegen.experiments.bench_adapt import adapt_lines  # the lines make bench prints

        text += ("\nOnline adaptation in the generated C (`[adapt]`): what the tick does (a column queued, the "
                 "recent window copied once per period), the rank-one fold of each column into R and the verified "
                 "re-solve (G, QP data, fast-path gain, output offset) off the tick; the phase lines: the same "
                 "re-solve timed inside the C, phase by phase (G + QP rebuild is what a new G costs, the "
                 "verification after it what makes it safe to swap in); the aarch64 line: the same calls in a C "
                 "program cross-compiled for aarch64 under qemu-user, with its native build as the reference:\n\n```\n"
                 + "\n".join(adapt_lines(list(bench["adapt"].values()))) + "\n```\n")
    p = bench.get("predictor_1e6")
    if p:
        text += (f"\nPredictor fit on 10^6 samples (m = p = 2, Tini 20, Tf 15): lsq {p['lsq_seconds']:.1f} s, "
                 f"pem {p['pem_seconds']:.1f} s, peak RSS {p['peak_rss_mib']:.0f} MiB "
                 f"({p['rss_before_fit_mib']:.0f} MiB before fitting).\n")
    return text


def _mm(v: Any) -> str:
    return "--" if v is None else f"{1e3 * v:.1f}"


def _sitl_section(sitl: dict) -> str:
    from ddpc_codegen.testbed.sitl_demo import format_baselines

    if not sitl:
        return "`make sitl-demo` found no SITL (set `DDPC_PX4_SITL` / `DDPC_ARDUPILOT_SITL`).\n"
    adaptation = sitl.get("adaptation")  # make sitl-adapt's key; every other key is an autopilot
    sitl = {k: v for k, v in sitl.items() if k != "adaptation"}
    aps = list(sitl)
    row = lambda label, f: f"| {label} | " + " | ".join(f(sitl[a]) for a in aps) + " |"  # noqa: E731
    ratio = lambda r: f" ({r['baseline'] / r['steered']:.0f}x)" if r["baseline"] and r["steered"] else ""  # noqa: E731
    lat = lambda r: " / ".join(f"{(r.get('latency_us') or {}).get(k, float('nan')) / 1e3:.1f}"  # noqa: E731
                               for k in ("p50", "p99")) + " ms"
    lines = ["| | " + " | ".join(aps) + " |", "|---|" + "---|" * len(aps),
             row("setpoint rate / missed ticks", lambda r: f"{r['rate_hz']:.1f} Hz / {r['missed_ticks']}"),
             row("steered share of engaged ticks", lambda r: f"{100 * r['engaged_fraction']:.1f} %"),
             row("height RMSE passthrough -> steered [mm]",
                 lambda r: f"{_mm(r['rmse_z']['baseline'])} -> {_mm(r['rmse_z']['steered'])}{ratio(r['rmse_z'])}"),
             row("true height RMSE passthrough -> steered [mm]",
                 lambda r: f"{_mm(r['rmse_z_truth']['baseline'])} -> {_mm(r['rmse_z_truth']['steered'])}"),
             row("latency p50 / p99", lat),
             row("fallbacks", lambda r: str(r["fallbacks"])),
             row("wall time", lambda r: f"{r['wall_s']:.0f} s")]
    text = "\n".join(lines) + "\n"
    printed = [format_baselines(a, sitl[a]["baselines"]) for a in aps if "baselines" in sitl[a]]
    if printed:
        text += "\nThe baselines flown in the same run (height RMSE):\n\n```\n" + "\n".join(printed) + "\n```\n"
    conditions = [(a, n, c) for a in aps for n, c in (sitl[a].get("conditions") or {}).items()]
    if conditions:
        text += "\n" + _conditions_table(conditions)
        text += _front_table([(a, c["front"], c) for a, n, c in conditions if n == "steps" and "model" in c.get("front", {})])
    text += "\n### Online adaptation, change applied mid-flight (`make sitl-adapt`)\n\n"
    text += _sitl_adaptation_table(adaptation) if adaptation else (
        "Not measured yet -- run `make sitl-adapt` (it adds `adaptation` to `reports/sitl.json` and rewrites this page).\n")
    return text


def _cost(res: dict, name: str) -> str:
    """``make sitl-adapt``'s change cost to the static steering (true, EKF) as table text."""
    from ddpc_codegen.testbed.sitl_adapt import change_cost
    return ", ".join("--" if v is None else f"{v:.2f}x" for v in change_cost(res.get("conditions") or {}, name))


def _sitl_adaptation_table(a: dict) -> str:
    """``make sitl-adapt``: per autopilot and condition, true-height RMSE in the window after the mid-flight change
    (static / adapted / prefilter, mean of the rounds), static / adapted, the nominal part before it, the estimator's
    error in the static and the adapted flights (on PX4 SIH it differs by tens of mm from flight to flight), the adapted flights' counters (columns folded in, re-solves accepted / rejected by reason) and the loop's
    missed ticks (a re-solve runs inside a tick)."""
    head = ("| autopilot | condition | static | adapted | prefilter | static / adapted | static's first "
            f"{a.get('learn_s', '?')} s alone | static: this change / nominal (true, EKF) | before: static / adapted / "
            "prefilter | EKF after: static / adapted | estimator error after: static / adapted | updates | swaps accepted | "
            "their error ratio | rejected | "
            "missed ticks: static / adapted |")
    lines = [f"The change at trajectory time {a.get('t_change_s', '?')} s (set by the harness over a second MAVLink link "
             f"while the bridge flies), true-height RMSE [mm] in the {a.get('window_s', '?')} s after it; before: from "
             f"{a.get('settle_s', '?')} s to the change; mean of {a.get('rounds', '?')} round(s). Static's first "
             f"{a.get('learn_s', '?')} s alone: the window's RMS if the error were zero after them, a floor for any "
             "learner that needs data of the change (its verification window is that long). Static: this change / "
             "nominal: what the change cost the static steering, all an adaptation can give back. Their error ratio: "
             "the accepted swaps' prediction error on the recent window over the current G's (min-max): a swap in "
             "nominal flight that cuts it as much as one after a change shows the check cannot tell the two apart.\n",
             head,
             "|" + "---|" * (head.count("|") - 1)]
    for ap, res in (a.get("autopilots") or {}).items():
        for name, c in (res.get("conditions") or {}).items():
            get = lambda m, w, k="rmse_z_truth": _mm(((c.get(m) or {}).get(w) or {}).get(k))  # noqa: E731
            ratio = (c.get("static_over_adapted") or {}).get("after")
            ad = (c.get("adapted") or {}).get("adapt") or {}
            rej = ", ".join(f"{k} {v}" for k, v in (ad.get("rejected") or {}).items()) or "0"
            lines.append(f"| {ap} | {name} | {get('static', 'after')} | {get('adapted', 'after')} | "
                         f"{get('prefilter', 'after')} | {'--' if ratio is None else f'{ratio:.2f}'} | "
                         f"{_mm((c.get('static') or {}).get('floor'))} | {_cost(res, name)} | "
                         f"{get('static', 'before')} / {get('adapted', 'before')} / {get('prefilter', 'before')} | "
                         f"{get('static', 'after', 'rmse_z')} / {get('adapted', 'after', 'rmse_z')} | "
                         f"{get('static', 'after', 'estimator_rms')} / {get('adapted', 'after', 'estimator_rms')} | "
                         f"{ad.get('updates', '--')} | "
                         f"{ad.get('accepted', '--')} | {_ratio_range(c)} | {rej} | "
                         f"{(c.get('static') or {}).get('missed_ticks', '--')} / "
                         f"{(c.get('adapted') or {}).get('missed_ticks', '--')} |")
    return "\n".join(lines) + "\n"


def _ratio_range(c: dict) -> str:
    """min-max of the accepted swaps' error ratios of a condition ("--" without a swap or in older reports)."""
    rng = (c.get("adapted") or {}).get("accepted_ratio_range")
    return f"{rng[0]:.2f}-{rng[1]:.2f}" if rng else "--"


_METHODS = ("passthrough", "ctrl_ff", "prefilter", "ilc", "steered")


def _bias(c: dict) -> str:
    """`` (x.x)``: the constant part of the estimator's error in the steered flights [mm], when recorded."""
    b = (c.get("estimator_bias_rms") or {}).get("steered")
    return "" if b is None else f" ({_mm(b)})"


def _split(c: dict) -> str:
    """The steered (and prefilter) true-height RMSE near changes of the path's height / elsewhere [mm]."""
    ch, st = c.get("rmse_z_truth_changing") or {}, c.get("rmse_z_truth_steady") or {}
    if ch.get("steered") is None or st.get("steered") is None:
        return "--"
    return f"{_mm(ch['steered'])} / {_mm(st['steered'])} ({_mm(ch.get('prefilter'))} / {_mm(st.get('prefilter'))})"


def _gains(g: dict | None) -> str:
    return "--" if not g else f"{g['chained']:.2f} / {g['predicted']:.2f}"


def _front_table(rows: list[tuple[str, dict, dict]]) -> str:
    """The steps condition against the identified loop's front (``testbed.sitl_front``), per autopilot."""
    if not rows:
        return ""
    lines = ["\nThe steps against the identified loop's front (`ddpc-codegen front` on the run's collect and the steps "
             "file: the predictor as the plant, no noise; the front is the least height error any z_ref reaches at "
             "each activity, its tick-to-tick change relative to the path's own, with the whole path known in "
             "advance). A steered point near the front at its activity leaves a tuning change nothing to gain "
             "there; only more reference activity (and thrust) or a better loop lowers it. The model flight is the "
             "steering's own loop only where the predictor agrees with itself: the steady-state gain of its "
             "one-step chain (the plant here) beside that of its multi-step prediction (what the steering plans "
             "with):\n",
             "| autopilot | passthrough on the model [mm] (the front at 1.00x) | steered on the model [mm] at its activity "
             "| the front at that activity [mm] | flown steered: activity, the front there [mm], EKF error [mm] "
             "| step gain: the predictor as the plant / its multi-step prediction |",
             "|---|---|---|---|---|---|"]
    for ap, f, c in rows:
        m = f["model"]
        pt, st = m["passthrough"], m["steered"]
        flown = (f"{f['flown_rate_ratio']:.2f}x, {_mm(f['front_at_flown'])}, {_mm(c['rmse_z'].get('steered'))}"
                 if f.get("flown_rate_ratio") else "--")
        lines.append(f"| {ap} | {_mm(pt['error_rms'])} ({_mm(pt['front_error_at_this_rate'])}) | "
                     f"{_mm(st['error_rms'])} at {st['rate_ratio']:.2f}x | {_mm(st['front_error_at_this_rate'])} | "
                     f"{flown} | {_gains(m.get('step_gain'))} |")
    return "\n".join(lines) + "\n"


def _conditions_table(conditions: list[tuple[str, str, dict]]) -> str:
    """Per autopilot and condition: each method's true-height RMSE (mean over the rounds), the estimator's
    own error in the steered flights (and its constant part per flight, when recorded), the steering against the best simple method (ctrl ff, prefilter, ILC) and the estimator, the
    steered and prefilter true-height error near changes of the path's height (0.5 s before to 1.5 s after) and
    elsewhere, the
    largest tick-to-tick step of the applied height reference in the steered flights (fallbacks included;
    the config's rate bound ``du_max`` is the limit; a stall resumes from the measured height, wherever the
    vehicle went meanwhile), the thrust steps against passthrough's, the fallbacks (with the bridge's own stalls
    and the steering's guard saturations in the steered flights, when recorded) and the
    p99 of the steering's solver call in flight (the worst round's)."""
    head = ("| autopilot | condition | " + " | ".join(m.replace("_", " ") for m in _METHODS)
            + " | EKF steered | estimator error (steered flights): RMS (its constant part) | best simple / steered "
            "| steered / estimator | near path changes / steady: steered (prefilter) "
            "| largest reference step [mm/tick] | thrust steps / passthrough | fallbacks (bridge stalls, guard saturations) "
            "| solve p99 in flight [ms] |")
    lines = ["True height RMSE [mm] per condition (`--` not flown: ILC needs a repeating path), mean of the rounds; "
             "near path changes: from 0.5 s before to 1.5 s after any tick where the desired height moves (a step's "
             "lead, ramp and settling), steady: the rest:\n",
             head, "|" + "---|" * (head.count("|") - 1)]
    for ap, name, c in conditions:
        if "skipped" in c:
            lines.append(f"| {ap} | {name} | " + " | ".join(["--"] * (len(_METHODS) + 9)) + " |")
            continue
        vt, est = c["rmse_z_truth"], steered_estimator_rms(c)
        simple = [vt.get(m) for m in ("ctrl_ff", "prefilter", "ilc") if vt.get(m) is not None]
        st = vt.get("steered")
        best = f"{min(simple) / st:.2f}x" if st and simple else "--"
        vs_est = f"{st / est:.2f}x" if st and est else "--"
        thr = c.get("thrust_step_rms") or {}
        thr_ratio = f"{thr['steered'] / thr['passthrough']:.1f}x" if thr.get("steered") and thr.get("passthrough") else "--"
        step = (c.get("max_ref_step") or {}).get("steered")
        fb = (c.get("fallbacks") or {}).get("steered")
        stalls = (c.get("stalls") or {}).get("steered")
        sat = (c.get("guard_saturations") or {}).get("steered")
        held = ("" if stalls is None else f" ({stalls:g}" + ("" if sat is None else f", {sat:g}") + ")")
        solve = (c.get("solve_us_p99") or {}).get("steered")
        lines.append(f"| {ap} | {name} | " + " | ".join(_mm(vt.get(m)) for m in _METHODS)
                     + f" | {_mm(c['rmse_z'].get('steered'))} | {_mm(est)}{_bias(c)} | {best} | {vs_est} | {_split(c)} | "
                     + f"{'--' if step is None else f'{1e3 * step:.1f}'} | {thr_ratio} | "
                     + f"{'--' if fb is None else f'{fb:g}'}{held} | "
                     + f"{'--' if solve is None else f'{solve / 1e3:.2f}'} |")
    skipped = [f"{ap} {name}: {c['skipped']}" for ap, name, c in conditions if "skipped" in c]
    return "\n".join(lines) + "\n" + ("".join(f"\n- {s}" for s in skipped) + "\n" if skipped else "")


def _adaptation_section(a: dict) -> str:
    """``ddpc-codegen adapt-eval``'s figures: static vs adapted steering vs the prefilter per condition."""
    rows = ["| condition | change | static | adapted | offset only | prefilter | static / adapted | G swaps | "
            "refused by the gain check | offset swaps |", "|---|---|---|---|---|---|---|---|---|---|"]
    for name, c in a.get("conditions", {}).items():
        ad = c.get("adaptation", {})
        adapted = "vehicle lost" if c.get("adapted_crashed") else _mm(c.get("adapted"))
        st, adv = c.get("static"), c.get("adapted")
        gain = f"{st / adv:.2f}" if st and adv and not c.get("adapted_crashed") else "--"
        rows.append(f"| {name} | {c.get('what', '')} | {_mm(st)} | {adapted} | {_mm(c.get('offset_only'))} | "
                    f"{_mm(c.get('prefilter'))} | {gain} | {ad.get('swaps', '--')} | {ad.get('rejected_gain', '--')} | "
                    f"{ad.get('offset_swaps', '--')} |")
    s = a.get("adapt", {})
    return (f"{a.get('scenario', '?')} scenario, {a.get('duration_s', '?')} s, the change at t = {a.get('t_change_s', '?')} s; "
            f"true-height RMSE [mm] within {a.get('window_s', '?')} s of it. Settings: "
            + ", ".join(f"{k} {v}" for k, v in s.items() if k != "enabled")
            + ". Adapted: the predictor's G re-solved and its output offset estimated online; offset only: the same with "
            "every G refused (the offset carries the adaptation: closed-loop data explain a change's offset by "
            "distorting G's gains, which the gain check refuses).\n\n" + "\n".join(rows) + "\n")


def results_page(reports: dict[str, dict]) -> str:
    """The whole results page (Markdown) from the loaded reports (any subset of :data:`REPORTS`)."""
    sections = [("summary.json", "Simulator: flying and hopping PogoX (`make demo`)", _demo_section),
                ("bench.json", "Solver timing (`make bench`)", _bench_section),
                ("sitl.json", "Real autopilots in the loop (`make sitl-demo`)", _sitl_section)]
    out = ["# Results\n", "<!-- written by python -m ddpc_codegen.docsgen.results: edit the code, not this page -->\n",
           "Every figure on this page is rendered from `reports/*.json` by the make target that measured it. "
           "What the figures mean and how the steering behaves: [reference steering](concepts/reference-steering.md), "
           "[artificial IO](concepts/artificial-io.md) and [the simple fixes](concepts/baselines.md).\n"]
    for name, title, render in sections:
        out.append(f"## {title}\n")
        out.append(render(reports[name]) if name in reports else _missing(name))
        if name == "summary.json":
            out.append("### Online adaptation (`make adapt-eval`)\n")
            adaptation = reports.get(name, {}).get("adaptation")
            out.append(_adaptation_section(adaptation) if adaptation else
                       "Not measured yet -- run `make adapt-eval` (it adds `adaptation` to `reports/summary.json` "
                       "and rewrites this page).\n")
    return "\n".join(out)


def readme_block(reports: dict[str, dict]) -> str:
    """The README's results table (the demo's main table), marker comments included."""
    from ddpc_codegen.experiments.demo import format_table

    if "summary.json" not in reports:
        body = _missing("summary.json")
    else:
        s = reports["summary.json"]
        body = (markdown_table(format_table(s)) + f"\n\nRMSE and apex errors against the desired trajectory under a "
                f"{s.get('meta', {}).get('mass_error_kg', '?')} kg controller mass error; solve times in µs "
                f"(demo wall time {s.get('meta', {}).get('wall_time_s', '?')} s).\n")
    return f"{BEGIN}\n{body.rstrip()}\n{END}"


def replace_block(text: str, block: str) -> str:
    """``text`` with the part between the results markers (inclusive) replaced by ``block``."""
    i, j = text.find(BEGIN), text.find(END)
    if i < 0 or j < i:
        raise ValueError(f"no results markers in the text: expected {BEGIN!r} ... {END!r}")
    return text[:i] + block + text[j + len(END):]


def copy_figures(summary: dict, root: Path, dest: Path) -> list[Path]:
    """Copy the figures ``make demo`` listed in its summary into ``dest`` (the docs' figures)."""
    dest.mkdir(parents=True, exist_ok=True)
    copied = []
    for f in summary.get("meta", {}).get("figures", []):
        src = Path(f) if Path(f).is_absolute() else root / f
        if src.is_file():
            copied.append(Path(shutil.copy2(src, dest / src.name)))
    return copied


def main(argv: list[str] | None = None) -> int:
    """Rewrite ``docs/results.md`` and the README's results table from ``reports/``."""
    ap = argparse.ArgumentParser(prog="python -m ddpc_codegen.docsgen.results", description=main.__doc__)
    ap.add_argument("--reports", default=str(ROOT / "reports"), help="folder of the JSON reports")
    ap.add_argument("--docs", default=str(ROOT / "docs"), help="docs folder (results.md, figures/)")
    ap.add_argument("--readme", default=str(ROOT / "README.md"), help="README with the results markers")
    a = ap.parse_args(argv)
    readme = Path(a.readme)
    try:
        reports = load_reports(Path(a.reports))
        if "summary.json" in reports:  # the README's table is make demo's: other targets leave it alone
            readme.write_text(replace_block(readme.read_text(), readme_block(reports)))
    except ValueError as e:
        print(f"docsgen: error: {e}", file=sys.stderr)
        return 2
    if "summary.json" in reports:
        copy_figures(reports["summary.json"], ROOT, Path(a.docs) / "figures")
    (Path(a.docs) / "results.md").write_text(results_page(reports))
    print(f"rendered {', '.join(reports) or 'no reports'} into {Path(a.docs) / 'results.md'}"
          + (f" and {readme}" if "summary.json" in reports else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
