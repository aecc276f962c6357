"""The bridge over MAVLink (``make bridge-demo``, ``reports/bridge.json``): its section on the timing page and its
line on the index.

The section: the demo's flights (rate, tick latency, missed ticks, true-height error over the link against
in-process) and the flood round (the steered flight quiet and under a flood from foreign addresses: tick latency
and where it goes, setpoints sent against those the vehicle received, the flood's datagrams against what the
bridge dropped). The tick latency is the bridge's own figure: the newest telemetry sample's receive to its
setpoint's send, on the ticks with new telemetry, waiting for the bridge's grid boundary included.
"""

from __future__ import annotations

from ddpc_codegen.docsgen.results_format import NA, missing, mm, num, table

__all__ = ["HEAD", "bridge_section", "index_lines"]

HEAD = "## The bridge over MAVLink (`make bridge-demo`)\n"
_LATENCY = ("Tick latency: the newest telemetry sample's receive to the setpoint's send, on the ticks with new "
            "telemetry; the bridge ticks on its own 200 Hz grid, so it includes the wait from the receive to the "
            "grid boundary and the wake-up, not only the tick's work (compute).")


def _us(d: dict | None, key: str = "p99") -> str:
    return num((d or {}).get(key), 1.0, 0)


def _load(r: dict) -> str:
    load = r.get("load_before")
    return num(load[0], 1.0, 2) if isinstance(load, (list, tuple)) and load else NA


def _flights_table(b: dict) -> str:
    lat, rm, ip = b.get("latency_us") or {}, b.get("rmse_z") or {}, b.get("rmse_z_in_process") or {}
    return table(["rate [Hz]", "latency p50 / p99 / max [µs]", "missed ticks", "link time [s]",
                  "fallbacks (steered)", "RMSE z baseline: link / in-process [mm]",
                  "RMSE z steered: link / in-process [mm]"],
                 [[num(b.get("rate_hz")), f"{_us(lat, 'p50')} / {_us(lat)} / {_us(lat, 'max')}",
                   str(b.get("missed_ticks", NA)), num(b.get("link_seconds"), 1.0, 0), str(b.get("fallbacks", NA)),
                   f"{mm(rm.get('baseline'))} / {mm(ip.get('baseline'))}",
                   f"{mm(rm.get('steered'))} / {mm(ip.get('steered'))}"]])


def _flood_row(name: str, r: dict) -> list[str]:
    parts, fl, fo = r.get("latency_parts_us") or {}, r.get("flood") or {}, r.get("foreign") or {}
    flooded = bool(fl)
    pre_pin = sum(fo.get(k, 0) for k in ("foreign", "bad_data", "parse_errors"))
    return [name, _load(r), _us(r.get("latency_us")), _us(parts.get("compute")), _us(parts.get("solve")),
            _us(parts.get("receive_to_deadline")), _age(r.get("age_at_tick_us")),
            _us(parts.get("wake")), f"{r.get('latency_over_1ms', NA)} of {r.get('event_ticks', NA)}",
            str(r.get("waited_a_period", NA)),
            str(r.get("missed_ticks", NA)), f"{r.get('setpoints_sent', NA)} / {r.get('setpoints_received', NA)}",
            str(fl.get("datagrams", NA)) if flooded else "0",
            f"{fo.get('foreign_packets', 0)} / {pre_pin}" if flooded else NA,
            str(fl.get("received", NA)) if flooded else NA]


def _age(d: dict | None) -> str:
    return f"{_us(d, 'p1')} / {_us(d, 'p50')} / {_us(d)}" if d else NA


def _grid(r: dict) -> str:
    """How the flight's tick grid was placed: locked to the arrivals (its margin) or free (an older report)."""
    lock = r.get("phase_lock")
    if not lock:
        return ("idle: the vehicle's and the bridge's 200 Hz grids run free, their phase set by the first tick")
    return (f"the bridge's grid is phase-locked to the position sample's arrivals, {num(lock.get('margin_us'), 1.0, 0)} "
            "µs after their late edge (the median plus three half interquartile ranges), so the telemetry's age at "
            "the tick is constant")


def _flood_section(rnd: dict | None) -> list[str]:
    if not rnd:
        return ["The flood round was not flown (`--flood-hz 0`).\n"]
    khz = num(rnd.get("rate_hz"), 1e-3, 0)
    intro = (f"The steered flight ({num(rnd.get('duration_s'), 1.0, 0)} s) flown twice back to back: quiet, then "
             f"under a {khz} kHz flood (garbage and valid MAVLink of other system ids) from {rnd.get('ports', '?')} "
             "foreign ports, from before the bridge started to after it ended. Per tick with new telemetry, p99 of "
             "each part of the latency: compute (tick start to send; of it the solver call), receive to the grid "
             f"boundary ({_grid(rnd.get('quiet') or {})}), and the wake-up after the boundary (above the least-late "
             "ticks'); the telemetry's age at the tick p1 / p50 / p99; a sample that arrived just after "
             "a boundary waits for the next tick (about 5 ms). The load is the machine's 1-minute load average before "
             "the flight (2 cores, shared). Target: p99 <= 1 ms, no setpoint lost at the vehicle.\n")
    rows = [_flood_row("no flood", rnd.get("quiet") or {}), _flood_row(f"{khz} kHz flood", rnd.get("flood") or {})]
    return [intro, table(["flight", "load", "latency p99 [µs]", "compute p99 [µs]", "of it the solver p99 [µs]",
                          "receive to boundary p99 [µs]", "age at the tick p1 / p50 / p99 [µs]",
                          "wake-up p99 [µs]", "ticks over 1 ms", "samples that waited for the next tick",
                          "missed ticks",
                          "setpoints sent / at the vehicle", "flood datagrams",
                          "dropped by the bridge: other address / parsed before the pin", "answered to the flooder"],
                         rows)]


def bridge_section(b: dict | None) -> str:
    """The timing page's section from ``reports/bridge.json`` (None: not measured yet)."""
    if b is None:
        return HEAD + "\n" + missing("make bridge-demo", "bridge.json")
    out = [HEAD, f"`ddpc-vehicle` and `ddpc-bridge` as two processes over UDP on 127.0.0.1 "
           f"({b.get('scheduling') or 'best effort'}; kernel preemption "
           f"{(b.get('kernel') or {}).get('preemption', '?')}). {_LATENCY}\n",
           "### Collect, baseline and steered flights\n", _flights_table(b),
           "### Under a flood from foreign addresses\n", *_flood_section(b.get("flood_round"))]
    return "\n".join(out)


def index_lines(b: dict | None) -> list[str]:
    """The index page's lines for the bridge (the tick latency p99, quiet and flooded)."""
    if b is None:
        return [HEAD, missing("make bridge-demo", "bridge.json")]
    rnd = b.get("flood_round") or {}
    flood = ""
    if rnd:
        q, f = rnd.get("quiet") or {}, rnd.get("flood") or {}
        flood = (f"; the steered flight {_us(q.get('latency_us'))} µs quiet and {_us(f.get('latency_us'))} µs under a "
                 f"{num(rnd.get('rate_hz'), 1e-3, 0)} kHz flood from foreign addresses, setpoints lost at the vehicle "
                 f"{q.get('setpoints_lost', NA)} and {f.get('setpoints_lost', NA)}")
    return [HEAD, f"Tick latency p99 {_us(b.get('latency_us'))} µs over the demo's flights{flood}; details on the "
            "[timing page](bench.md#the-bridge-over-mavlink-make-bridge-demo).\n"]
