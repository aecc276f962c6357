"""The real autopilots' results (``make sitl-demo``, ``reports/sitl.json``): their page and headline tables.

The page: which figure judges the steering, the loop on each autopilot and setup, then a section per autopilot
(true and measured height per method and condition, the measurement's own error, the error near path changes, the
steered loop's activity; with a lab run, both estimation setups side by side and the lab's own tables), then the
steps against the identified loop's front. The headline: per autopilot and condition, the true-height error of
passthrough, of the best simple fix and of the steering, steered / best simple fix named (the lab setup's where it
was flown: the one that judges the steering).

An autopilot's entry of ``sitl.json`` is its outdoor run (:func:`~ddpc_codegen.testbed.sitl_demo.run_pipeline`), with
the lab run of the same shape under ``lab`` (:func:`~ddpc_codegen.testbed.sitl_demo.merge_setups`).
"""

from __future__ import annotations

from ddpc_codegen.docsgen.results_format import (NA, best_simple_fix, label, missing, mm, num, page_head, ratio,
                                                 table, tally)
from ddpc_codegen.testbed.sitl_conditions import steered_estimator_rms

__all__ = ["METHODS", "autopilots", "headline", "sitl_page", "front_table", "judged_setup"]

METHODS = ("passthrough", "ctrl_ff", "prefilter", "ilc", "steered")


def autopilots(sitl: dict) -> dict[str, dict]:
    """The autopilots of a ``sitl.json`` (its ``adaptation`` key is ``make sitl-adapt``'s, not an autopilot)."""
    return {k: v for k, v in sitl.items() if k != "adaptation"}


JUDGE_TEXT = (
    "The true height in the **lab** setup judges the steering. There the height the loop measures (ArduCopter's "
    "EKF fused on the motion-capture stand-in; on PX4, whose build fuses no external vision, the motion capture "
    "itself) is within a few mm of the truth, and that measurement's own error stands beside each flight: a "
    "steered true-height error near it is the measurement's limit, anything above it the steering's. In the "
    "**outdoor** setup the autopilot's estimate is tens to hundreds of mm off the truth: the true height there is "
    "limited by the estimator, and the height on the estimate says what the steering did with what it measured.\n")


def judged_setup(ap: dict) -> tuple[str, dict]:
    """The setup whose true height judges the steering: ("lab", its result) where flown, else ("outdoor", ``ap``)."""
    return ("lab", ap["lab"]) if ap.get("lab") else ("outdoor", ap)


def _has_outdoor(ap: dict) -> bool:
    """An autopilot's entry holds its outdoor run (anything beside ``lab``: a lab-only run stores only that)."""
    return any(k != "lab" for k in ap)


def _runs(aps: dict[str, dict]) -> list[tuple[str, dict]]:
    """(column label, result) of every run: each autopilot's outdoor one (where flown), then its lab one."""
    out = []
    for a, ap in aps.items():
        if _has_outdoor(ap):
            out.append((label(a), ap))
        if ap.get("lab"):
            out.append((f"{label(a)} lab", ap["lab"]))
    return out


def _flown(ap: dict) -> list[tuple[str, dict]]:
    return [(n, c) for n, c in (ap.get("conditions") or {}).items() if "skipped" not in c]


def _loop_table(aps: dict[str, dict]) -> str:
    runs = _runs(aps)
    lat = lambda r, k: num((r.get("latency_us") or {}).get(k), 1e-3)  # noqa: E731
    rows = [["setpoint rate [Hz]", *(num(r["rate_hz"]) for _, r in runs)],
            ["missed ticks", *(str(r["missed_ticks"]) for _, r in runs)],
            ["steered share of scored ticks [%]", *(num(r["engaged_fraction"], 1e2) for _, r in runs)]]
    if any("engaged_share" in r for _, r in runs):
        rows.append(["engaged share of the trajectory's ticks [%]",
                     *(num(r.get("engaged_share"), 1e2) for _, r in runs)])
    rows += [["tick latency p50 / p99 [ms]", *(f"{lat(r, 'p50')} / {lat(r, 'p99')}" for _, r in runs)],
             ["fallbacks [ticks]", *(str(r["fallbacks"]) for _, r in runs)],
             ["wall time [s]", *(num(r["wall_s"], 1, 0) for _, r in runs)]]
    return table(["the ellipse flight", *(name for name, _ in runs)], rows)


def _methods_table(ap: dict, key: str, judged: bool) -> str:
    """Per condition, each method's height RMSE (``key``: rmse_z_truth or rmse_z) [mm]; ``judged``: with the best
    simple fix and steered / best simple fix."""
    rows = []
    for name, c in _flown(ap):
        v = c.get(key) or {}
        row = [name, *(mm(v.get(m)) for m in METHODS)]
        if judged:
            best = best_simple_fix(v)
            row += [NA if best is None else label(best[0]), NA if best is None else ratio(v.get("steered"), best[1])]
        rows.append(row)
    head = ["condition", *(f"{label(m)} [mm]" for m in METHODS)]
    return table(head + (["best simple fix", "steered / best simple fix"] if judged else []), rows)


def _estimator_table(ap: dict, ekf: bool = False) -> str:
    """Per condition, the measured height's error in the steered flights; ``ekf``: the autopilot's EKF's beside
    (the lab where the loop measured the motion capture)."""
    rows = []
    for name, c in _flown(ap):
        est = steered_estimator_rms(c)
        rows.append([name, mm(est), mm((c.get("estimator_bias_rms") or {}).get("steered")),
                     ratio((c.get("rmse_z_truth") or {}).get("steered"), est)]
                    + ([mm((c.get("ekf_rms") or {}).get("steered"))] if ekf else []))
    return table(["condition", "estimator error, steered flights: RMS [mm]", "its constant part [mm]",
                  "steered true-height RMSE / estimator error"]
                 + (["the autopilot's EKF, beside: RMS [mm]"] if ekf else []), rows)


def _side_by_side(ap: dict) -> str:
    """Per condition, the steered and best simple fix's true height and the measurement's error in each setup."""
    out, lab = ap, ap["lab"]
    names = list(dict.fromkeys([n for n, _ in _flown(out)] + [n for n, _ in _flown(lab)]))
    rows = []
    for name in names:
        row = [name]
        for res in (out, lab):
            c = (res.get("conditions") or {}).get(name) or {}
            v = c.get("rmse_z_truth") or {}
            best = best_simple_fix(v)
            row += [mm(v.get("steered")), NA if best is None else f"{mm(best[1])} ({label(best[0])})",
                    mm(steered_estimator_rms(c)) if c else NA]
        rows.append(row)
    return table(["condition", "outdoor: steered [mm]", "outdoor: best simple fix [mm]",
                  "outdoor: measured height's error [mm]", "lab: steered [mm]", "lab: best simple fix [mm]",
                  "lab: measured height's error [mm]"], rows)


def _split_table(ap: dict) -> str:
    rows = []
    for name, c in _flown(ap):
        ch, st = c.get("rmse_z_truth_changing") or {}, c.get("rmse_z_truth_steady") or {}
        if ch.get("steered") is not None and st.get("steered") is not None:
            rows.append([name, mm(ch["steered"]), mm(st["steered"]), mm(ch.get("prefilter")), mm(st.get("prefilter"))])
    return table(["condition", "steered near path changes [mm]", "steered steady [mm]",
                  "prefilter near path changes [mm]", "prefilter steady [mm]"], rows) if rows else ""


def _loop_activity_table(ap: dict) -> str:
    """The steered flights' activity: the largest reference step, the thrust steps against passthrough's,
    fallbacks, the bridge's stalls, the guard's saturations and the solver call's p99 in flight."""
    rows = []
    for name, c in _flown(ap):
        steered = lambda k: (c.get(k) or {}).get("steered")  # noqa: E731
        thr = c.get("thrust_step_rms") or {}
        fmt = lambda v: NA if v is None else f"{v:g}"  # noqa: E731
        rows.append([name, mm(steered("max_ref_step")), ratio(thr.get("steered"), thr.get("passthrough"), 1),
                     fmt(steered("fallbacks")), fmt(steered("stalls")), fmt(steered("guard_saturations")),
                     num(steered("solve_us_p99"), 1e-3, 2)])
    return table(["condition", "largest reference step [mm/tick]", "thrust steps / passthrough's",
                  "fallbacks [ticks]", "bridge stalls", "guard saturations", "solver call p99 in flight [ms]"], rows)


def _ilc_text(ap: dict) -> str:
    il = (ap.get("baselines") or {}).get("ilc")
    if not il:
        return ""
    parts = [f"{what}: {', '.join(mm(v) for v in il[key])} mm" for key, what in
             (("rmse_z_truth_per_iteration", "true height"), ("rmse_z_per_iteration", "EKF height"))
             if (il.get(key) or [None])[0] is not None]
    return (f"ILC on the ellipse per iteration (0 = passthrough), {'; '.join(parts)}; within 10 % of its best at "
            f"iteration {il['iterations_to_settle']} of {il['iterations_run']}, the last one flown.\n")


def _setup_tables(ap: dict, lab: bool) -> list[str]:
    """One setup's tables (``ap``: its result): true height, measured height, the measurement's error, near path
    changes, the steered loop; ``lab``: headed and described as the lab setup's."""
    pre, where = ("Lab: ", "the lab setup's measured height") if lab else ("", "the autopilot's estimate (EKF)")
    out = [f"### {pre}True height RMSE\n",
           "The judged figure: the simulator's true height against the desired one (mean of the rounds; `--` not "
           "flown: ILC needs a repeating path). Steered / best simple fix < 1: the steering is better.\n",
           _methods_table(ap, "rmse_z_truth", judged=True), _ilc_text(ap),
           f"### {pre}Height RMSE on {where}\n", _methods_table(ap, "rmse_z", judged=False),
           f"### {pre}The estimator's own error\n"]
    if lab:
        out += ["The measured height against the true height in the steered flights (the loop's measurement: "
                f"{(ap.get('setup') or {}).get('estimator', 'the lab setup')}); where it is not the EKF's, the EKF's "
                "error beside.\n", _estimator_table(ap, ekf=True)]
    else:
        out += ["The EKF height against the true height in the steered flights. The steering acts on the estimate: a "
                "ratio near 1 means the true-height error left is the estimator's own.\n", _estimator_table(ap)]
    split = _split_table(ap)
    if split:
        out += [f"### {pre}Near path changes and steady\n", "Near path changes: from 0.5 s before to 1.5 s after any "
                "tick where the desired height moves (a step's lead, ramp and settling); steady: the rest.\n", split]
    out += [f"### {pre}The steered loop\n", _loop_activity_table(ap)]
    skipped = [f"- {n}: {c['skipped']}" for n, c in (ap.get("conditions") or {}).items() if "skipped" in c]
    if skipped:
        out += ["Not flown:\n", "\n".join(skipped) + "\n"]
    return out


def _autopilot_section(name: str, ap: dict) -> str:
    out = [f"## {label(name)}\n"]
    if ap.get("lab"):
        out += ["### Outdoor and lab side by side\n",
                "True-height RMSE of the steering and of the best simple fix per condition and setup, with the error "
                "of the height each loop measured; the lab column judges the steering.\n", _side_by_side(ap)]
    if _has_outdoor(ap):
        out += _setup_tables(ap, lab=False)
    if ap.get("lab"):
        out += _setup_tables(ap["lab"], lab=True)
    return "\n".join(out)


def front_table(rows: list[tuple[str, dict, dict]]) -> str:
    """The steps condition against the identified loop's front (``testbed.sitl_front``), per autopilot."""
    if not rows:
        return ""
    lines = []
    for ap, f, c in rows:
        m = f["model"]
        pt, st, g = m["passthrough"], m["steered"], m.get("step_gain")
        flown = (f"{num(f['flown_rate_ratio'], 1, 2)}x, {mm(f['front_at_flown'])}, {mm(c['rmse_z'].get('steered'))}"
                 if f.get("flown_rate_ratio") else NA)
        lines.append([label(ap), f"{mm(pt['error_rms'])} ({mm(pt['front_error_at_this_rate'])})",
                      f"{mm(st['error_rms'])} at {num(st['rate_ratio'], 1, 2)}x", mm(st["front_error_at_this_rate"]),
                      flown, NA if not g else f"{num(g['chained'], 1, 2)} / {num(g['predicted'], 1, 2)}"])
    return ("## The steps against the identified loop's front\n\n`ddpc-codegen front` on the run's collect and "
            "the steps file: the predictor as the plant, no noise; the front is the least height error any z_ref "
            "reaches at each activity (its tick-to-tick change relative to the path's own), the whole path known in "
            "advance. A steered point near the front at its activity leaves a tuning change nothing to gain there. "
            "The model flight is the steering's own loop only where the predictor agrees with itself: the "
            "steady-state gain of its one-step chain (the plant here) beside that of its multi-step prediction.\n\n"
            + table(["autopilot", "passthrough on the model [mm] (the front at 1.00x)",
                     "steered on the model [mm] at its activity", "the front at that activity [mm]",
                     "flown steered: activity, the front there [mm], EKF error [mm]",
                     "step gain: the predictor as the plant / its multi-step prediction"], lines))


def headline(name: str, ap: dict) -> str:
    """One autopilot, per condition: true-height RMSE of passthrough, the best simple fix and the steering,
    steered / best simple fix, steered / the estimator's own error, and the count of conditions the steering won;
    the lab setup's where it was flown (:func:`judged_setup`), said above the table."""
    setup, res = judged_setup(ap)
    rows, pairs = [], []
    for cname, c in _flown(res):
        v = c.get("rmse_z_truth") or {}
        best = best_simple_fix(v)
        pairs.append((v.get("steered"), None if best is None else best[1]))
        rows.append([cname, mm(v.get("passthrough")), NA if best is None else f"{mm(best[1])} ({label(best[0])})",
                     mm(v.get("steered")), NA if best is None else ratio(v.get("steered"), best[1]),
                     ratio(v.get("steered"), steered_estimator_rms(c))])
    head = "The lab setup (the height measured on the motion capture).\n\n" if setup == "lab" else ""
    return head + table(["condition", "passthrough [mm]", "best simple fix [mm]", "steered [mm]",
                         "steered / best simple fix", "steered / the estimator's error"], rows) + "\n" + tally(pairs)


def sitl_page(sitl: dict | None) -> str:
    """The real-autopilot page (Markdown) from ``reports/sitl.json`` (None: not measured yet)."""
    head = page_head("Real autopilots in the loop", "`make sitl-demo`: PX4 (SIH) and ArduCopter SITLs flown by "
                     "the bridge over MAVLink, each condition with passthrough, the simple fixes and the steering. "
                     "Every height figure is an RMSE against the desired height, mean of the rounds.")
    if sitl is None:
        return head + "\n" + missing("make sitl-demo", "sitl.json")
    aps = autopilots(sitl)
    if not aps:
        return head + "\n`make sitl-demo` found no SITL (set `DDPC_PX4_SITL` / `DDPC_ARDUPILOT_SITL`).\n"
    flown_lab = any(ap.get("lab") for ap in aps.values())
    judge = JUDGE_TEXT if flown_lab else (
        "Only the outdoor setup is flown here (`make sitl-demo --setups lab` flies the lab one, on a motion "
        "capture): the autopilot's estimate is tens to hundreds of mm off the truth, so the true height is limited "
        "by the estimator, and the height on the estimate says what the steering did with what it measured.\n")
    out = [head, "## Which figure judges the steering\n", judge, "## The loop\n", _loop_table(aps)]
    out += [_autopilot_section(name, ap) for name, ap in aps.items()]
    out.append(front_table([(a if res is ap else f"{label(a)} lab", c["front"], c) for a, ap in aps.items()
                            for res in (ap, ap.get("lab") or {}) for n, c in (res.get("conditions") or {}).items()
                            if n == "steps" and "model" in c.get("front", {})]))
    return "\n".join(out)
