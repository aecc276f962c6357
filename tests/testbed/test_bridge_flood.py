"""make bridge-demo's flood round (ddpc_codegen/testbed/bridge_flood.py) without processes: the latency it reports
and its parts on a synthetic tick log, the counts of one flight, the round's two flights (fly faked), its table
rows; and the flooder's (proxy_flood) counts."""

from __future__ import annotations

import json
import signal
import socket

import numpy as np
import pytest

from ddpc_codegen.testbed import bridge_flood
from ddpc_codegen.testbed.bridge_flood import flood_rows, latency_parts, round_figures, tick_latency_us
from ddpc_codegen.testbed.proxy_flood import flood

P = 0.005


def _ticks(n: int = 400, rx_before: float = 300e-6, wake: float = 20e-6, compute: float = 400e-6,
           grid0: float = 1.0023, slew: float = 0.0) -> dict:
    """Ticks on a grid ``grid0 + k P`` [s]: each wakes ``wake`` s late (every 50th 1 ms, the 10th 3 ms, the 14th 4.5 ms), its telemetry arrived
    ``rx_before`` s before the deadline, compute ``compute`` s; every 4th tick has no new telemetry. ``slew``: the
    grid's phase moves this much per tick [s] (locked to drifting telemetry)."""
    k = np.arange(n)
    late = np.full(n, wake)
    late[::50] = 1e-3
    late[9] = 3e-3  # more than half a period late: still late, not early
    late[13] = 4.5e-3  # so late its phase wraps round to just before the deadline: no deadline is placed there
    t_wall = grid0 + k * (P + slew) + late
    return {"t_wall": t_wall, "latency_us": (rx_before + late + compute) * 1e6, "age_ms": (rx_before + late) * 1e3,
            "compute_us": np.full(n, compute * 1e6), "solve_us": np.full(n, 30.0), "event": k % 4 != 3}


def test_the_reported_latency_is_receive_to_send_on_ticks_with_new_telemetry():
    t = _ticks()
    lat = tick_latency_us(t)
    assert lat.size == 300 and np.allclose(lat[1], (300e-6 + 20e-6 + 400e-6) * 1e6)


@pytest.mark.parametrize("grid0", [1.0023, 1.00499, 7.0])  # a grid phase near 0 or P: no wrap-around error
def test_latency_parts_split_the_wait_for_the_grid_from_the_wake_up_and_the_work(grid0):
    parts = latency_parts(_ticks(grid0=grid0), P)
    assert parts["compute"]["p50"] == pytest.approx(400.0)
    assert parts["receive_to_start"]["p50"] == pytest.approx(320.0, abs=1e-3)
    # the deadlines sit at the least-late tick's phase (20 us late): the wake-up is measured above it
    assert parts["wake"]["p50"] == pytest.approx(0.0, abs=1e-3) and parts["wake"]["max"] == pytest.approx(2980.0, abs=1e-3)
    # (the 4.5 ms late tick's wake-up, wrapped round, is counted as waiting for the grid: one tick, not the p99)
    assert parts["receive_to_deadline"]["p99"] == pytest.approx(320.0, abs=1e-3)
    assert parts["compute"]["n"] == 300 and parts["solve"]["p99"] == pytest.approx(30.0)


def test_latency_parts_follow_a_slewing_grid():
    """A grid locked to drifting telemetry moves its phase by up to 10 us a tick: 10 ms over 1,000 ticks, yet the
    wake-up is measured against the deadlines nearby, not against one phase for the flight."""
    parts = latency_parts(_ticks(n=1000, slew=10e-6), P)
    assert parts["wake"]["p50"] == pytest.approx(0.0, abs=25.0) and parts["receive_to_deadline"]["p50"] == pytest.approx(
        300.0, abs=25.0)


def test_latency_parts_of_no_ticks_are_empty():
    empty = {k: np.zeros(0) for k in ("t_wall", "latency_us", "compute_us")} | {"event": np.zeros(0, bool)}
    assert latency_parts(empty, P)["compute"] == {"p50": None, "p99": None, "max": None, "n": 0}


SUMMARY = {"ticks": 400, "missed_ticks": 1, "grid_skipped": 0, "max_gap_ms": 9.5, "telemetry_gaps": 0, "fallbacks": 0,
           "setpoints_sent": 400, "setpoints_repeated": 3, "stop_reason": "duration 2 s flown",
           "link": {"foreign_packets": 9000, "unpinned": 18, "foreign": 700, "bad_data": 200, "parse_errors": 0,
                    "peer_changes": 1}}
VEHICLE = {"setpoints": 401, "setpoints_ignored": 0,
           "events": [[0.5, "mode OFFBOARD (command)"], [9.0, "mode HOLD (offboard setpoints lost for > 1 s)"]]}
FLOOD = {"rate_hz": 10000.0, "datagrams": 10500, "refused": 0, "received": 0}


def test_one_flights_figures_count_setpoints_at_both_ends_and_the_flood_against_what_the_bridge_dropped():
    r = round_figures(SUMMARY, VEHICLE, _ticks(), P, FLOOD)
    assert (r["setpoints_sent"], r["setpoints_received"], r["setpoints_lost"]) == (403, 401, 2)
    assert r["vehicle_failsafes"] == 1 and r["missed_ticks"] == 1 and r["event_ticks"] == 300
    assert r["latency_over_1ms"] == 10  # the late wake-ups (k = 0, 50, ... 350, 9 and 13: all event ticks)
    assert r["foreign"]["foreign_packets"] == 9000 and r["foreign"]["peer_changes"] == 1 and r["flood"] is FLOOD
    assert r["latency_us"]["p50"] == pytest.approx(720.0) and r["waited_a_period"] == 2  # the 3 and 4.5 ms late ticks
    assert r["age_at_tick_us"]["p50"] == pytest.approx(320.0) and r["phase_lock"] is None
    lock = {"margin_us": 250.0, "locked_ticks": 380, "free_ticks": 20}
    assert round_figures({**SUMMARY, "phase_lock": lock}, VEHICLE, _ticks(), P, FLOOD)["phase_lock"] == lock
    quiet = round_figures({**SUMMARY, "link": {}}, None, _ticks(), P, None)
    assert quiet["setpoints_received"] is None and quiet["setpoints_lost"] is None and quiet["foreign"]["unpinned"] == 0


def test_the_round_flies_the_same_steered_flight_quiet_then_flooded(tmp_path, monkeypatch):
    flights = []

    def fake_fly(name, work, bridge_args, *, beside=None, **kw):
        flights.append((name, bridge_args, kw["seed"], kw["duration"], beside))
        if beside is not None:  # what the flooder would write: its --stats file
            cmd = beside(4242)
            assert cmd[:2] == ["ddpc_codegen.testbed.proxy_flood", "4242"] and "10000" in cmd
            (work / f"{name}_flood.json").write_text(json.dumps(FLOOD))
        np.savez(work / f"{name}.npz")
        return {"ticks": work / f"{name}.npz", "summary": SUMMARY, "vehicle": VEHICLE}

    class _Log:
        ticks, dt = _ticks(), P

    monkeypatch.setattr(bridge_flood, "fly", fake_fly)
    monkeypatch.setattr(bridge_flood, "load_ticklog", lambda path: _Log)
    loads = iter([(0.5, 0.4, 0.3), (0.6, 0.4, 0.3), (1.5, 0.7, 0.4), (1.9, 0.8, 0.4)])
    r = bridge_flood.flood_round(tmp_path, tmp_path / "solver", duration=7.0, seed=3, rt_priority=30,
                                 load=lambda: next(loads), log=lambda s: None)
    assert [f[0] for f in flights] == ["flood_round_quiet", "flood_round_flood"]
    assert flights[0][1] == flights[1][1] == ["--mode", "steer", "--solver", str(tmp_path / "solver")]
    assert flights[0][2:4] == flights[1][2:4] == (3, 7.0) and flights[0][4] is None and flights[1][4] is not None
    assert r["quiet"]["flood"] is None and r["flood"]["flood"] == FLOOD and r["rate_hz"] == 10_000.0
    assert r["quiet"]["load_before"] == (0.5, 0.4, 0.3) and r["flood"]["load_after"] == (1.9, 0.8, 0.4)
    rows = flood_rows(r)
    assert rows[0][0] == "no flood: latency p99 (compute p99)" and "load 0.50" in rows[0][1]
    assert rows[3] == ("10 kHz flood: setpoints sent / at the vehicle", "403 / 401, 1 missed ticks", "none lost")
    assert "10500 sent" in rows[4][1] and "0 answered" in rows[4][1]
    assert flood_rows(None) == []


def test_the_round_says_when_the_flood_did_not_run(tmp_path, monkeypatch):
    def fake_fly(name, work, bridge_args, *, beside=None, **kw):
        (work / f"{name}_beside.log").write_text("ModuleNotFoundError: no flooder")
        return {"ticks": work / f"{name}.npz", "summary": SUMMARY, "vehicle": VEHICLE}

    class _Log:
        ticks, dt = _ticks(), P

    monkeypatch.setattr(bridge_flood, "fly", fake_fly)
    monkeypatch.setattr(bridge_flood, "load_ticklog", lambda path: _Log)
    with pytest.raises(RuntimeError, match="the flood did not run: ModuleNotFoundError: no flooder"):
        bridge_flood.flood_round(tmp_path, tmp_path, duration=1.0, seed=1, rt_priority=0, log=lambda s: None)


def test_the_flooder_counts_what_it_sent_and_what_came_back():
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
        handler = signal.getsignal(signal.SIGTERM)
        try:
            res = flood(s.getsockname()[1], hz=2000.0, seconds=0.1, ports=2)
        finally:
            signal.signal(signal.SIGTERM, handler)  # the flooder's own (it ends on SIGTERM) is not pytest's
        s.setblocking(False)
        got = 0
        try:
            while s.recv(65536):
                got += 1
        except BlockingIOError:
            pass
    assert got == res["datagrams"] >= 150 and res["received"] == 0  # nobody answered the flooder
