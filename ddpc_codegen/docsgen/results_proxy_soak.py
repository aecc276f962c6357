"""The proxy soak's section of the proxy results page, from ``reports/proxy_soak.json`` (``make proxy-soak``,
:mod:`ddpc_codegen.testbed.proxy_soak`): messages and added latency of a long transparent session with a ground
station, and of a session under a foreign flood, against the issue's targets."""

from __future__ import annotations

from ddpc_codegen.docsgen.results_format import NA, missing, num, table

__all__ = ["SESSIONS", "soak_section"]

SESSIONS = ("baseline", "flood")  # the report's sessions, in the order shown
P99_MS = 1.0  # the target: app -> vehicle p99 added latency, and its change under a flood


def _ms(lat: dict | None, scale: float = 1.0) -> str:
    """p50 / p99 / max of a latency summary as ms (``scale``: its unit in ms); the proxy's ring keeps its newest
    values only: then how many of how many."""
    lat = lat or {}
    cells = " / ".join(num(lat.get(k), scale, 2) for k in ("p50", "p99", "max"))
    kept, count = lat.get("kept"), lat.get("count")
    return cells + (f" (last {kept} of {count})" if kept is not None and count and kept < count else "")


def _name(s: dict) -> str:
    """The session's length and flood, e.g. ``2 min, 10 kHz flood`` (``0.3 min``: as given)."""
    m, hz = s.get("minutes"), s.get("flood_hz") or 0
    return (f"{m:g} min" if isinstance(m, (int, float)) else NA) + (f", {hz / 1e3:g} kHz flood" if hz else "")


def _messages(sessions: dict) -> str:
    rows = []
    for s in sessions.values():
        sp, px, g = s.get("setpoints", {}), s.get("proxy", {}), s.get("gcs", {})
        up, down = px.get("app_to_vehicle", {}), px.get("vehicle_to_app", {})
        rows.append([_name(s), f"{sp.get('sent', NA)} / {sp.get('received', NA)}",
                     " / ".join(str(sp.get(k, NA)) for k in ("lost", "duplicated", "reordered", "fields_changed")),
                     " / ".join(str(up.get(k, NA)) for k in ("received", "forwarded", "dropped", "seq_gaps")),
                     f"{s.get('vehicle', {}).get('rx', NA)}",
                     " / ".join(str(down.get(k, NA)) for k in ("received", "dropped", "seq_gaps")),
                     f"{s.get('app', {}).get('lost_by_seq', NA)} / {g.get('lost_by_seq', NA)}",
                     f"{g.get('param_lists_complete', NA)} of {g.get('param_lists', NA)}",
                     str(s.get("udp_rcvbuf_errors", NA))])
    return table(["session", "app setpoints sent / at the vehicle", "lost / duplicated / reordered / changed",
                  "proxy app -> vehicle frames in / out / dropped / seq gaps", "frames the vehicle parsed",
                  "proxy vehicle -> apps frames in / dropped / seq gaps", "vehicle's messages lost at app / GCS",
                  "GCS full parameter lists", "kernel UDP drops"], rows)


def _latency(sessions: dict) -> str:
    rows = [[_name(s), _ms(s.get("proxy", {}).get("app_to_vehicle", {}).get("latency_us"), 1e-3),
             _ms(s.get("setpoints", {}).get("send_to_vehicle_ms")),
             _ms(s.get("proxy", {}).get("vehicle_to_app", {}).get("latency_us"), 1e-3)] for s in sessions.values()]
    return table(["session", "proxy, app -> vehicle (every datagram)", "app's send -> vehicle's receive (its setpoints)",
                  "proxy, vehicle -> apps"], rows)


def _p99(s: dict | None) -> float | None:
    """The proxy's app -> vehicle p99 [us]."""
    return (((s or {}).get("proxy") or {}).get("app_to_vehicle") or {}).get("latency_us", {}).get("p99")


def _e2e(s: dict | None) -> float | None:
    """The app's setpoints' p99 from its send to the vehicle's receive [ms]."""
    return (((s or {}).get("setpoints") or {}).get("send_to_vehicle_ms") or {}).get("p99")


def _diff(a: float | None, b: float | None, scale: float) -> str:
    return num(None if a is None or b is None else b - a, scale, 2)


def _verdict(report: dict, sessions: dict) -> str:
    out = []
    for key, s in sessions.items():
        sp, p99 = s.get("setpoints", {}), _p99(s)
        clean = all(sp.get(k) == 0 for k in ("lost", "duplicated", "reordered", "fields_changed", "seq_changed"))
        out.append(f"- {_name(s)}: added latency p99 {num(p99, 1e-3, 2)} ms by the proxy's stamps "
                   f"({'within' if p99 is not None and p99 * 1e-3 <= P99_MS else 'NOT within'} the {P99_MS:g} ms "
                   f"target), {num(_e2e(s), 1.0, 2)} ms from the app's send to the vehicle's receive; the app's "
                   f"setpoints {'each arrived once, in order, unchanged' if clean else 'NOT all arrived once, in order, unchanged'}.")
    cmp_, base, fl = report.get("flood_vs_baseline"), sessions.get("baseline"), sessions.get("flood")
    if cmp_ is not None:
        same = cmp_.get("differing") == 0  # over the shorter session (each session's counts: the lines above)
        out.append(f"- Under the flood the vehicle's setpoints from the app are {'identical' if same else 'NOT identical'}"
                   f" to the session without ({cmp_.get('compared', NA)} compared, {cmp_.get('differing', NA)} differing);"
                   f" the p99 changed by {_diff(_p99(base), _p99(fl), 1e-3)} ms by the proxy's stamps, by "
                   f"{_diff(_e2e(base), _e2e(fl), 1.0)} ms from the app's send to the vehicle's receive.")
    return "\n".join(out) + "\n"


def soak_section(report: dict | None) -> str:
    """The soak section (Markdown) of ``reports/proxy_soak.json``; the not-measured paragraph without one."""
    head = "## Soak: a long session with a ground station, and a foreign flood\n\n"
    if not report:
        return head + missing("make proxy-soak", "proxy_soak.json")
    sessions = {k: report[k] for k in SESSIONS if isinstance(report.get(k), dict)}
    return head + "\n".join([
        "`ddpc-proxy` in pass-through in front of `ddpc-vehicle`; a pymavlink app streams position setpoints at 50 Hz "
        "over UDP, a ground station on the proxy's TCP port asks for the full parameter list, stream rates and the "
        "mode every minute; the flood (garbage and other systems' MAVLink from several ports) goes to the app's port. "
        "The vehicle logs every setpoint it receives; the app's are compared with what it sent.\n",
        _messages(sessions), "Added latency, p50 / p99 / max [ms] (the proxy's own receive and send stamps; the "
        "app's send to the vehicle's kernel receive stamp includes both loopback hops, an upper bound):\n",
        _latency(sessions), _verdict(report, sessions)])
