"""The steering proxy's results (``make proxy-demo``, ``reports/proxy.json``): a user's own app flown directly and
through ``ddpc-proxy`` (pass-through, steered with the local preview, with a declared delay, with the app's path as a
file), per autopilot and app path, on the true height; which preview wins where; the proxy's message counts and
added latency."""

from __future__ import annotations

from ddpc_codegen.docsgen.results_format import NA, label, missing, num, page_head, ratio, table

__all__ = ["KINDS", "proxy_page", "headline", "autopilots"]

KINDS = ("direct", "passthrough", "steer_local", "steer_delay", "steer_file")
STEERED = ("steer_local", "steer_delay", "steer_file")
_NAMES = {"direct": "app direct (its own ff)", "passthrough": "through the proxy",
          "steer_local": "steered, local preview", "steer_delay": "steered, delay", "steer_file": "steered, path file"}
_PREVIEWS = {"steer_local": "the local preview", "steer_delay": "the declared delay", "steer_file": "the path file"}


_SETUPS = {"lab": "lab (ArduCopter's EKF on the motion-capture stand-in: the true height judges)",
           "outdoor": "outdoor (GPS and barometer: the estimator's own error is beside each flight)"}


def autopilots(report: dict) -> dict[str, dict]:
    """The autopilots the report holds (name -> entry)."""
    return {k: v for k, v in report.items() if isinstance(v, dict) and "paths" in v}


def _truth(run: dict | None) -> float | None:
    return None if not run else run.get("rmse_z_truth_mm")


def _judged(run: dict | None) -> float | None:
    """The figure that judges a flight: the true height, else (a vehicle whose telemetry is its truth) the measured."""
    if not run:
        return None
    v = run.get("rmse_z_truth_mm")
    return v if isinstance(v, (int, float)) else run.get("rmse_z_mm")


def _best(runs: dict) -> tuple[str, float] | None:
    """The steered flight with the lowest true-height error."""
    flown = [(v, k) for k in STEERED if isinstance(v := _judged(runs.get(k)), (int, float))]
    return (min(flown)[1], min(flown)[0]) if flown else None


def headline(name: str, ap: dict) -> str:
    """Per app path: the app direct, the best steered flight, their ratio (true height)."""
    rows = []
    for path, runs in ap["paths"].items():
        best = _best(runs)
        rows.append([path, num(_judged(runs.get("direct"))), NA if best is None else f"{best[1]:.1f} ({_NAMES[best[0]]})",
                     NA if best is None else ratio(_judged(runs.get("direct")), best[1])])
    return table(["app path", "app direct [mm]", "best steered [mm]", "direct / steered"], rows)


def _errors(ap: dict) -> str:
    rows = []
    for path, runs in ap["paths"].items():
        d = _judged(runs.get("direct"))
        for k in (k for k in KINDS if k in runs):
            r = runs.get(k) or {}
            flight = _NAMES[k] + (f" {r.get('delay_s', 0):g} s" if k == "steer_delay" else "") + _matched(r)
            rows.append([path, flight,
                         num(r.get("rmse_z_truth_mm")), num(r.get("rmse_z_mm")), num(r.get("estimator_rms_mm")),
                         ratio(d, _judged(r)) if k != "direct" else NA, _handed_back(r), _paused(r)])
    return table(["app path", "flight", "true height [mm]", "estimate [mm]", "estimator error [mm]",
                  "app direct / this", "handed back by the prediction watch", "paused by the jerk guard"], rows)


def _matched(run: dict) -> str:
    """A path-file flight's share of ticks the file previewed (the rest fell back to the local preview); "" else."""
    pv = ((run.get("proxy") or {}).get("steering") or {}).get("preview") or {}
    n = (pv.get("matched") or 0) + (pv.get("fallback") or 0)
    if pv.get("kind") != "file" or not n:
        return ""
    return f" ({100.0 * pv['matched'] / n:.0f} % of ticks matched, {pv.get('losses', 0)} losses)"


def _handed_back(run: dict) -> str:
    """The share of a steered flight's ticks the prediction watch handed back to the app ("--" unsteered or unwatched)."""
    st = (run.get("proxy") or {}).get("steering") or {}
    if st.get("mode") != "steer" or st.get("prediction_watch") is None or not st.get("ticks"):
        return NA
    return f"{100.0 * st.get('model_mismatch', 0) / st['ticks']:.0f} % ({st['prediction_watch'].get('trips', 0)} trips)"


def _paused(run: dict) -> str:
    """The share of a steered flight's ticks the ``--max-jerk`` guard paused, and whether the preview spread the app's
    acceleration jumps ("--" without the guard)."""
    st = (run.get("proxy") or {}).get("steering") or {}
    jb = st.get("jerk_bound")
    if st.get("mode") != "steer" or not jb or not st.get("ticks"):
        return NA
    spread = f", {jb.get('smoothed', 0)} setpoints spread" if jb.get("preview_s") else ""
    return f"{100.0 * st.get('beyond_jerk', 0) / st['ticks']:.0f} % ({jb.get('jumps', 0)} jumps{spread})"


def _link(ap: dict) -> str:
    rows = []
    for path, runs in ap["paths"].items():
        for k in KINDS[1:]:
            p = (runs.get(k) or {}).get("proxy")
            if not p:
                continue
            up, down, lat = p["app_to_vehicle"], p["vehicle_to_app"], p["latency_us"]["app_to_vehicle"]
            rows.append([path, _NAMES[k], str(up["received"]), str(up["forwarded"]), str(up["rewritten"]),
                         str(up["dropped"]), str(up["seq_gaps"]), str(down["dropped"]), str(down["seq_gaps"]),
                         num(lat.get("p50"), digits=0), num(lat.get("p99"), digits=0)])
    return table(["app path", "flight", "app msgs in", "forwarded", "rewritten", "dropped", "sequence gaps",
                  "vehicle msgs with no app yet", "vehicle sequence gaps", "added p50 [us]", "added p99 [us]"], rows)


def _ms(v) -> str:
    return NA if not isinstance(v, (int, float)) else f"{v * 1e3:.0f}"


def _stop_row(path: str, flight: str, a: dict) -> list[str]:
    return [path, flight, _ms(a.get("proxy_last_out_s")), _ms(a.get("failsafe_s")),
            f"{a.get('mode_before') or NA} -> {a.get('mode_after') or 'unchanged'}", a.get("timed_by") or NA]


def _stops(ap: dict) -> str:
    """When the app stops (every flight's end) and when the proxy dies: the last setpoint out of the proxy and the
    autopilot's own reaction, directly and through the proxy."""
    rows = [_stop_row(path, _NAMES[k], runs[k]["app_stops"]) for path, runs in ap["paths"].items()
            for k in KINDS if (runs.get(k) or {}).get("app_stops")]
    d = ap.get("proxy_death")
    if d and "error" not in d:
        rows.append(_stop_row("(any)", "the proxy killed mid-flight", d))
    if not rows:
        return ""
    return ("When the app stops streaming (the end of each flight; the proxy stays up) or the proxy itself dies: the "
            "proxy's last setpoint to the vehicle after the app's last, and the autopilot's own reaction (the first "
            "change of mode or arming, seen in its heartbeats and CURRENT_MODE messages; 'unchanged': none within 3 s):\n\n"
            + table(["app path", "flight", "last setpoint out after the app's [ms]", "mode change after [ms]",
                     "mode", "timed by"], rows))


_VERDICTS = {"within target": "shown (the interval lies inside +-{t} ms)",
             "target missed": "missed (the interval lies outside +-{t} ms)",
             "unresolved": "not resolved (the interval crosses +-{t} ms: more trials needed)",
             "too few trials": "not judged (too few trials)"}


def _repeats(ap: dict) -> str:
    """The repeated off-board-loss trials (``failsafe_repeats``): per arm, the difference and its interval."""
    rep = ap.get("failsafe_repeats")
    if not rep or "stats" not in rep:
        return ""
    st, params = rep["stats"], rep.get("params") or {}
    rows = [[arm, str(a["n"]), num(a["mean_s"], 1e3), num(a["median_s"], 1e3), num(a["std_s"], 1e3),
             f"{_ms(a['min_s'])}-{_ms(a['max_s'])}"] for arm, a in ((k, st[k]) for k in ("direct", "proxy"))]
    ci, t = st.get("ci95_s"), _ms(st.get("target_s"))
    diff = NA if st.get("mean_diff_s") is None else f"{st['mean_diff_s'] * 1e3:+.1f} ms"
    ci_txt = NA if not ci else f"{ci[0] * 1e3:+.1f} to {ci[1] * 1e3:+.1f} ms"
    out = [v for v in rep.get("proxy_last_out_s") or [] if isinstance(v, (int, float))]
    last = f"{min(out) * 1e3:+.2f} to {max(out) * 1e3:+.2f} ms" if out else NA
    return (f"The off-board-loss failsafe over {len(rep.get('trials', []))} trials of one flight, the app connected "
            "directly and through a transparent proxy alternately (it streams its position at "
            f"{num(rep.get('app_rate_hz'), digits=0)} Hz for about {num(rep.get('stream_s'))} s while asking for OFFBOARD, "
            "then stops; "
            f"loss action COM_OBL_RC_ACT {num(params.get('COM_OBL_RC_ACT'), digits=0)} (Hold), COM_OF_LOSS_T "
            f"{num(params.get('COM_OF_LOSS_T'))} s, read back): the time from the app's last setpoint to the mode "
            "change [ms]:\n\n"
            + table(["app", "trials", "mean", "median", "SD", "range"], rows)
            + f"\nThrough the proxy minus direct: {diff} (95 % interval {ci_txt}, {st.get('ci_method', '?')}); the "
            f"issue's target, within {t} ms (one app period + 10 ms): "
            + _VERDICTS.get(st.get("verdict"), str(st.get("verdict"))).format(t=t)
            + f". The proxy's last setpoint out, stamped on its receipt, against the app's own stamp after its last send: "
            f"{last}.\n")


def _realtime(ap: dict) -> str:
    """How the proxy was scheduled in the path flights ("SCHED_FIFO 20, mlockall", "best effort")."""
    seen = {((r or {}).get("proxy") or {}).get("realtime") for runs in ap["paths"].values() for r in runs.values()}
    seen.discard(None)
    return " / ".join(sorted(seen)) if seen else "best effort"


def _verdict(ap: dict) -> str:
    """Which preview wins on which path (a sentence per path, from the figures)."""
    out, gains, better, n = [], {"steer_delay": [], "steer_file": []}, 0, 0
    for path, runs in ap["paths"].items():
        d = _judged(runs.get("direct"))
        flown = {k: v for k in STEERED if isinstance(v := _judged(runs.get(k)), (int, float))}
        if d is None or len(flown) < 2:
            continue
        win = min(flown, key=flown.get)
        others = [k for k in flown if k != win]
        against = f"{num(flown[others[0]])} mm" if len(others) == 1 else " and ".join(
            f"{num(flown[k])} mm ({_PREVIEWS[k]})" for k in others)
        worse = ": the steering made it worse" if flown[win] > d else ""
        out.append(f"- {path}: {_PREVIEWS[win]} wins ({num(flown[win])} mm against {against}; the app alone "
                   f"{num(d)} mm{worse}).")
        better, n = better + (flown[win] < d), n + 1
        for k, g in gains.items():
            if k in flown and "steer_local" in flown:
                g.append(100.0 * (flown[k] - flown["steer_local"]) / flown["steer_local"])
    if not out:
        return ""
    return (f"The steered app (its best preview) below the app alone on {better} of {n} paths.\n\n" + "\n".join(out)
            + "\n\n" + _gains(gains) + _coordinates(ap) + "\n")


def _gains(gains: dict[str, list[float]]) -> str:
    """The true previews (the delayed stream, the path file) against the local guess, in % of its error."""
    said = [f"{what} against the local guess: {min(g):+.0f} % to {max(g):+.0f} % of the error on these paths. "
            for k, what in (("steer_delay", "The true preview (the delayed stream)"),
                            ("steer_file", "The path file (the same preview without the delay)")) if (g := gains[k])]
    if not gains["steer_file"]:
        said.append("The path file (`--preview-file`) was not flown in this report. ")
    return "".join(said)


def _coordinates(ap: dict) -> str:
    """What the steering's coordinates make of a preview (deviation: the future heights do not enter it)."""
    if (ap.get("collect") or {}).get("coordinates") != "deviation":
        return ""
    return ("The steering here is in deviation coordinates (the offset added to the app's height in, the tracking "
            "error out): the error it wants ahead is zero whatever the app's future heights, so the local preview and "
            "the path file steer alike and their difference is the spread between flights; the delay changes what "
            "the vehicle is sent and when it is judged.")


def _setup(ap: dict) -> str:
    """The setup in words: what measured the height (the report's own description where it has one)."""
    detail = (ap.get("setup_detail") or {}).get("estimator")
    base = _SETUPS.get(ap.get("setup"), ap.get("setup", "?"))
    if not detail:
        return base
    src = (ap.get("setup_detail") or {}).get("position_source")
    return f"{ap.get('setup')}: {detail}" + ("; the proxy measures the height on the motion capture"
                                             if src == "mocap" else "")


def _section(name: str, ap: dict) -> str:
    col = ap.get("collect") or {}
    return "\n".join([
        f"## {label(name)}\n",
        f"Setup: {_setup(ap)}. The steering was fitted on one {num(col.get('seconds'), digits=0)} s flight of the app's `{col.get('path', '?')}` "
        f"path through `ddpc-proxy --collect --dither {col.get('dither_m', '?')}`; the paths below were flown after it. "
        "Errors are RMS over each path (its first seconds left out) against the height the app declared, played late "
        "by the delay for the delayed flights.\n",
        _errors(ap), _verdict(ap), "Messages and the latency the proxy added (its own receive and send stamps; the "
        f"vehicle's messages before the app joined have nobody to go to; the proxy ran {_realtime(ap)}, beside the "
        "SITL, the motion-capture stand-in, the observer and the app on this machine):\n",
        _link(ap), _stops(ap), *filter(None, [_repeats(ap)])])


def proxy_page(report: dict | None) -> str:
    """The proxy results page."""
    head = page_head("Steering your own app (ddpc-proxy)",
                     "A plain pymavlink app (`ddpc_codegen/testbed/proxy_app.py`) streams position setpoints with its "
                     "own velocity and acceleration feed-forward at 50 Hz; it flies the SITL directly, through the proxy "
                     "in pass-through, and steered. How to run it: [the proxy guide](../guides/proxy.md).")
    if report is None:
        return head + missing("make proxy-demo", "proxy.json")
    aps = autopilots(report)
    if not aps:
        return head + "`make proxy-demo` found no SITL.\n"
    return head + "\n".join(_section(n, ap) for n, ap in aps.items())
