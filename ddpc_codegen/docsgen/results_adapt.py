"""The online adaptation's results: ``make adapt-eval`` (``reports/summary.json``'s ``adaptation``) and
``make sitl-adapt`` (``reports/sitl.json``'s ``adaptation``), static against adapted steering after a change.
"""

from __future__ import annotations

from ddpc_codegen.docsgen.results_format import NA, label, mm, num, page_head, ratio, table
from ddpc_codegen.testbed.sitl_adapt import change_cost

__all__ = ["sim_adaptation", "sitl_adaptation", "adaptation_page"]


def sim_adaptation(a: dict) -> str:
    """``make adapt-eval``: static vs adapted steering vs the prefilter per condition, and the swaps."""
    errors, swaps = [], []
    for name, c in a.get("conditions", {}).items():
        ad = c.get("adaptation", {})
        crashed = c.get("adapted_crashed")
        errors.append([name, c.get("what", ""), mm(c.get("static")), "vehicle lost" if crashed else mm(c.get("adapted")),
                       mm(c.get("offset_only")), mm(c.get("prefilter")),
                       NA if crashed else ratio(c.get("static"), c.get("adapted"))])
        swaps.append([name, str(ad.get("swaps", NA)), str(ad.get("rejected_gain", NA)), str(ad.get("offset_swaps", NA))])
    settings = ", ".join(f"{k} {v}" for k, v in a.get("adapt", {}).items() if k != "enabled")
    return (f"The {a.get('scenario', '?')} scenario, {a.get('duration_s', '?')} s, the change at t = "
            f"{a.get('t_change_s', '?')} s; true-height RMSE within {a.get('window_s', '?')} s of it. Adapted: the "
            "predictor's G re-solved and its output offset estimated online; offset only: the same with every G "
            "refused. Settings: " + settings + ".\n\n"
            + table(["condition", "change", "static [mm]", "adapted [mm]", "offset only [mm]", "prefilter [mm]",
                     "static / adapted"], errors)
            + "\nThe adapted runs' swaps:\n\n"
            + table(["condition", "G swaps", "G refused by the gain check", "offset swaps"], swaps))


def _ratio_range(c: dict) -> str:
    """min-max of the accepted swaps' error ratios of a condition (``--`` without a swap or in older reports)."""
    rng = (c.get("adapted") or {}).get("accepted_ratio_range")
    return f"{rng[0]:.2f}-{rng[1]:.2f}" if rng else NA


def _rows(a: dict):
    for ap, res in (a.get("autopilots") or {}).items():
        for name, c in (res.get("conditions") or {}).items():
            yield label(ap), name, res, c


def sitl_adaptation(a: dict) -> str:
    """``make sitl-adapt``: per autopilot and condition, static vs adapted vs prefilter after the mid-flight change,
    the part before it, the estimator's error, the adapted flights' counters and the loop's missed ticks."""
    get = lambda c, m, w, k="rmse_z_truth": mm(((c.get(m) or {}).get(w) or {}).get(k))  # noqa: E731
    learn = a.get("learn_s", "?")
    after, before, counters = [], [], []
    for ap, name, res, c in _rows(a):
        so = (c.get("static_over_adapted") or {}).get("after")
        after.append([ap, name, get(c, "static", "after"), get(c, "adapted", "after"), get(c, "prefilter", "after"),
                      num(so, 1, 2), mm((c.get("static") or {}).get("floor")),
                      " / ".join(num(v, 1, 2) for v in change_cost(res.get("conditions") or {}, name))])
        before.append([ap, name, " / ".join(get(c, m, "before") for m in ("static", "adapted", "prefilter")),
                       f"{get(c, 'static', 'after', 'rmse_z')} / {get(c, 'adapted', 'after', 'rmse_z')}",
                       f"{get(c, 'static', 'after', 'estimator_rms')} / {get(c, 'adapted', 'after', 'estimator_rms')}",
                       f"{(c.get('static') or {}).get('missed_ticks', NA)} / {(c.get('adapted') or {}).get('missed_ticks', NA)}"])
        ad = (c.get("adapted") or {}).get("adapt") or {}
        counters.append([ap, name, str(ad.get("updates", NA)), str(ad.get("accepted", NA)), _ratio_range(c),
                         ", ".join(f"{k} {v}" for k, v in (ad.get("rejected") or {}).items()) or "0"])
    return (f"The change at trajectory time {a.get('t_change_s', '?')} s, set by the harness over a second MAVLink "
            f"link while the bridge flies; true-height RMSE in the {a.get('window_s', '?')} s after it, mean of "
            f"{a.get('rounds', '?')} round(s). Static's first {learn} s alone: the window's RMS if the error were zero "
            "after them, a floor for any learner that needs data of the change. This change / nominal: what the change "
            "cost the static steering, all an adaptation can give back.\n\n"
            + table(["autopilot", "condition", "static [mm]", "adapted [mm]", "prefilter [mm]", "static / adapted",
                     f"static's first {learn} s alone [mm]", "this change / nominal, static: true / EKF"], after)
            + f"\nBefore the change (from {a.get('settle_s', '?')} s to it) and the estimator after it:\n\n"
            + table(["autopilot", "condition", "before: static / adapted / prefilter [mm]",
                     "EKF height after: static / adapted [mm]", "estimator error after: static / adapted [mm]",
                     "missed ticks: static / adapted"], before)
            + "\nThe adapted flights' counters. Their error ratio: the accepted swaps' prediction error on the recent "
            "window over the current G's (min-max); a swap in nominal flight that cuts it as much as one after a "
            "change shows the check cannot tell the two apart.\n\n"
            + table(["autopilot", "condition", "updates", "swaps accepted", "their error ratio", "rejected"], counters))


def adaptation_page(summary: dict | None, sitl: dict | None) -> str:
    """The adaptation page (Markdown): ``make adapt-eval`` on the simulator, ``make sitl-adapt`` on the SITLs."""
    out = [page_head("Online adaptation", "Static against adapted steering when the vehicle changes mid-flight: "
                     "the predictor's G and output offset re-solved online, verified, and swapped between ticks.")]
    sim = (summary or {}).get("adaptation")
    out += ["## Simulator (`make adapt-eval`)\n", sim_adaptation(sim) if sim else
            "Not measured yet -- run `make adapt-eval` (it adds `adaptation` to `reports/summary.json` and rewrites "
            "this page).\n"]
    real = (sitl or {}).get("adaptation")
    out += ["## Real autopilots, the change applied mid-flight (`make sitl-adapt`)\n", sitl_adaptation(real) if real else
            "Not measured yet -- run `make sitl-adapt` (it adds `adaptation` to `reports/sitl.json` and rewrites this "
            "page).\n"]
    return "\n".join(out)

