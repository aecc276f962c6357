"""The proxy soak's results section (:mod:`ddpc_codegen.docsgen.results_proxy_soak`): what it says of a small report,
of a failing one, and of a missing one."""

from __future__ import annotations

import copy

from ddpc_codegen.docsgen.results_proxy_soak import soak_section


def _session(minutes: float, flood_hz: float, p99_us: float, e2e_p99_ms: float, count: int = 900) -> dict:
    lat = {"count": count, "kept": min(count, 65536), "p50": 90.0, "p99": p99_us, "max": 2700.0}
    return {"minutes": minutes, "flood_hz": flood_hz, "udp_rcvbuf_errors": 0,
            "setpoints": {"sent": 900, "received": 900, "lost": 0, "duplicated": 0, "reordered": 0,
                          "fields_changed": 0, "seq_changed": 0,
                          "send_to_vehicle_ms": {"p50": 0.09, "p99": e2e_p99_ms, "max": 0.88}},
            "proxy": {"app_to_vehicle": {"received": 955, "forwarded": 953, "dropped": 2, "seq_gaps": 0,
                                         "latency_us": lat},
                      "vehicle_to_app": {"received": 1907, "dropped": 0, "seq_gaps": 0, "latency_us": lat}},
            "app": {"lost_by_seq": 0}, "gcs": {"lost_by_seq": 0, "param_lists": 4, "param_lists_complete": 4},
            "vehicle": {"rx": 953}}


REPORT = {"baseline": _session(10, 0.0, 550.0, 0.5), "flood": _session(2, 10000.0, 730.0, 0.99, 592405),
          "flood_vs_baseline": {"compared": 6000, "counts": [30000, 6000], "differing": 0}}


def test_the_section_tabulates_both_sessions_against_the_targets():
    md = soak_section(REPORT)
    assert md.startswith("## Soak: a long session with a ground station, and a foreign flood")
    assert "| 0.3 min, 2.5 kHz flood |" in soak_section({"baseline": _session(0.3, 2500.0, 1.0, 1.0)})
    assert "| 10 min | 900 / 900 | 0 / 0 / 0 / 0 | 955 / 953 / 2 / 0 | 953 | 1907 / 0 / 0 | 0 / 0 | 4 of 4 | 0 |" in md
    # the proxy's ring keeps its newest 65536 latencies: the page says so
    assert ("| 2 min, 10 kHz flood | 0.09 / 0.73 / 2.70 (last 65536 of 592405) | 0.09 / 0.99 / 0.88 | "
            "0.09 / 0.73 / 2.70 (last 65536 of 592405) |") in md
    assert ("- 10 min: added latency p99 0.55 ms by the proxy's stamps (within the 1 ms target), 0.50 ms from the app's "
            "send to the vehicle's receive; the app's setpoints each arrived once, in order, unchanged.") in md
    assert ("are identical to the session without (6000 compared, 0 differing); the p99 changed by 0.18 ms by the "
            "proxy's stamps, by 0.49 ms from the app's send to the vehicle's receive.") in md


def test_a_failing_session_says_so():
    bad = copy.deepcopy(REPORT)
    bad["flood"]["setpoints"]["lost"] = 3
    bad["flood"]["proxy"]["app_to_vehicle"]["latency_us"]["p99"] = 1500.0
    bad["flood_vs_baseline"]["differing"] = 2
    md = soak_section(bad)
    assert "- 2 min, 10 kHz flood: added latency p99 1.50 ms by the proxy's stamps (NOT within the 1 ms target)" in md
    assert "the app's setpoints NOT all arrived once" in md
    assert "are NOT identical to the session without (6000 compared, 2 differing)" in md


def test_a_missing_report_says_how_to_measure_it():
    md = soak_section(None)
    assert "Not measured yet -- run `make proxy-soak` (it writes `reports/proxy_soak.json`" in md
    only = soak_section({"baseline": REPORT["baseline"]})  # no flood session: no comparison
    assert "| 10 min |" in only and "kHz flood |" not in only and "Under the flood" not in only
