"""The bridge's results (:mod:`ddpc_codegen.docsgen.results_bridge`): make bridge-demo's flights and its flood round
on the timing page and the index, from a small report, one without the round, and a missing one."""

from __future__ import annotations

from ddpc_codegen.docsgen import results
from ddpc_codegen.docsgen.results_bridge import bridge_section, index_lines


def _flight(p99: float, compute: float, sent: int, received: int, flood: dict | None, load: float) -> dict:
    pct = lambda v: {"p50": v / 2, "p99": v, "max": 3 * v, "n": 3900}  # noqa: E731
    return {"latency_us": pct(p99), "latency_parts_us": {"compute": pct(compute), "solve": pct(61.0),
                                                          "receive_to_start": pct(p99 - compute),
                                                          "receive_to_deadline": pct(310.0), "wake": pct(180.0)},
            "latency_over_1ms": 7, "event_ticks": 3900, "waited_a_period": 2, "missed_ticks": 0, "setpoints_sent": sent,
            "setpoints_received": received, "setpoints_lost": sent - received, "flood": flood,
            "foreign": {"foreign_packets": 190000 if flood else 0, "foreign_heartbeats": 0, "unpinned": 18,
                        "foreign": 6800 if flood else 0, "bad_data": 2300 if flood else 0, "parse_errors": 0,
                        "peer_changes": 1},
            "load_before": [load, 1.0, 1.1], "load_after": [load, 1.0, 1.1]}


FLOOD = {"rate_hz": 10000.0, "datagrams": 205000, "received": 0}
REPORT = {"rate_hz": 200.0, "latency_us": {"p50": 560.0, "p99": 930.0, "max": 5100.0, "n": 20000}, "missed_ticks": 2,
          "link_seconds": 100.0, "fallbacks": 0, "rmse_z": {"baseline": 0.0412, "steered": 0.0101},
          "rmse_z_in_process": {"baseline": 0.0405, "steered": 0.0095}, "scheduling": "SCHED_FIFO 30, mlockall",
          "kernel": {"preemption": "PREEMPT_DYNAMIC"},
          "flood_round": {"rate_hz": 10000.0, "ports": 4, "duration_s": 20.0,
                          "quiet": {**_flight(912.4, 545.0, 4005, 4005, None, 0.42),
                                    "age_at_tick_us": {"p1": 280.0, "p50": 300.0, "p99": 350.0},
                                    "phase_lock": {"margin_us": 200.0, "locked_ticks": 3960, "free_ticks": 40}},
                          "flood": _flight(987.6, 560.0, 4004, 4004, FLOOD, 1.37)}}


def test_the_timing_page_shows_the_flights_and_the_flood_round_with_the_load():
    md = bridge_section(REPORT)
    assert md.startswith("## The bridge over MAVLink (`make bridge-demo`)")
    assert "SCHED_FIFO 30, mlockall; kernel preemption PREEMPT_DYNAMIC" in md
    assert "receive to the grid boundary and the wake-up, not only the tick's work" in md  # which latency it is
    assert "| 200.0 | 560 / 930 / 5100 | 2 | 100 | 0 | 41.2 / 40.5 | 10.1 / 9.5 |" in md
    assert "under a 10 kHz flood (garbage and valid MAVLink of other system ids) from 4 foreign ports" in md
    assert "| no flood | 0.42 | 912 | 545 | 61 | 310 | 280 / 300 / 350 | 180 | 7 of 3900 | 2 | 0 | 4005 / 4005 | 0 | -- | -- |" in md
    assert ("| 10 kHz flood | 1.37 | 988 | 560 | 61 | 310 | -- | 180 | 7 of 3900 | 2 | 0 | 4004 / 4004 | 205000 | 190000 / 9100 "
            "| 0 |") in md
    assert "phase-locked to the position sample's arrivals, 200 µs after their late edge" in md
    older = {**REPORT, "flood_round": {**REPORT["flood_round"], "quiet": _flight(912.4, 545.0, 4005, 4005, None, 0.42)}}
    assert "grids run free, their phase set by the first tick" in bridge_section(older)


def test_the_index_gives_the_p99_quiet_and_flooded_and_links_the_section():
    text = "\n".join(index_lines(REPORT))
    assert "Tick latency p99 930 µs over the demo's flights; the steered flight 912 µs quiet and 988 µs under a 10 kHz " \
           "flood from foreign addresses, setpoints lost at the vehicle 0 and 0" in text
    assert "(bench.md#the-bridge-over-mavlink-make-bridge-demo)" in text


def test_a_report_without_the_round_and_a_missing_report():
    md = bridge_section({**REPORT, "flood_round": None})
    assert "The flood round was not flown (`--flood-hz 0`)." in md and "| no flood |" not in md
    assert "Tick latency p99 930 µs over the demo's flights; details" in "\n".join(index_lines({**REPORT,
                                                                                                   "flood_round": None}))
    assert "Not measured yet -- run `make bridge-demo` (it writes `reports/bridge.json`" in bridge_section(None)
    pages = results.pages({"bridge.json": REPORT})
    assert "## The bridge over MAVLink" in pages["bench.md"] and "Tick latency p99 930 µs" in pages["index.md"]
