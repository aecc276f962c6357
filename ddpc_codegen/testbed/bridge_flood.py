"""``make bridge-demo``'s flood round: the same steered flight on ``ddpc-vehicle`` without and with a flood from a
foreign address (:mod:`.proxy_flood`, its own process: garbage and valid-but-foreign MAVLink from four ports, each
its own system id, at ``FLOOD_HZ`` datagrams/s from before the bridge starts to after it ends).

Per flight: the tick latency bridge-demo reports (telemetry receive -> setpoint sent, over the ticks that had new
telemetry; :func:`tick_latency_us`) with where its time goes (:func:`latency_parts`), the ticks missed, the
setpoints the bridge sent against those the vehicle received, and the flood's datagrams against what the bridge
counted and dropped. The figures are measured, not asserted: the machine's load is part of them.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ddpc_codegen.stats import percentiles
from ddpc_codegen.testbed.bridge_flights import fly
from firmware_bridge.ticklog import load_ticklog

__all__ = ["FLOOD_HZ", "tick_latency_us", "latency_parts", "round_figures", "flood_command", "flood_round", "flood_rows"]

FLOOD_HZ = 10_000.0
FLOOD_PORTS = 4
_EDGE_PERCENTILE = 0.5  # the grid's deadlines sit at this percentile of the ticks' phases (see latency_parts)
_PHASE_BLOCK = 50  # ticks whose median phase is the typical one (the locked grid's phase moves a little a tick)


def tick_latency_us(ticks: dict[str, np.ndarray]) -> np.ndarray:
    """The latency bridge-demo reports [us]: per tick with new telemetry (``event``), the newest telemetry sample's
    receive time to its setpoint's send. It includes the wait from the receive to the tick's grid boundary (the
    bridge ticks on its own 200 Hz grid), the wake-up, and the tick's work."""
    return np.asarray(ticks["latency_us"])[np.asarray(ticks["event"], bool)]


def latency_parts(ticks: dict[str, np.ndarray], period: float) -> dict:
    """Where the tick latency goes, per event tick [us] (percentiles of each part):

    ``compute``: tick start -> setpoint sent (the tick's work; ``solve``: its solver call); ``receive_to_start``: telemetry receive -> tick start
    (latency - compute), split into ``receive_to_deadline`` (waiting for the grid boundary; negative when the sample
    arrived after the deadline, before the late wake-up) and ``wake`` (deadline -> tick start). The deadlines are
    the grid ``period`` [s] placed at the phase of the least-late ticks (the 0.5th percentile), so ``wake`` is the
    lateness above theirs; the grid's phase follows the telemetry's (:mod:`firmware_bridge.phase_lock`), so the
    ticks' phases are taken against their running median (:func:`_tick_phase`)."""
    ev = np.asarray(ticks["event"], bool)
    lat, comp = np.asarray(ticks["latency_us"], float), np.asarray(ticks["compute_us"], float)
    t = np.asarray(ticks["t_wall"], float)
    solve = np.asarray(ticks["solve_us"], float) if "solve_us" in ticks else np.full(t.shape, np.nan)
    if t.size == 0:
        return {k: percentiles(()) for k in ("compute", "solve", "receive_to_start", "receive_to_deadline", "wake")}
    dev = _tick_phase(t, period)
    wake = (dev - np.percentile(dev, _EDGE_PERCENTILE)) * 1e6
    start = lat - comp
    return {"compute": percentiles(comp[ev]), "solve": percentiles(solve[ev]), "receive_to_start": percentiles(start[ev]),
            "receive_to_deadline": percentiles((start - wake)[ev]), "wake": percentiles(wake[ev])}


def _tick_phase(t: np.ndarray, period: float) -> np.ndarray:
    """Each tick's phase [s] around the typical one's: from a quarter period before it (no tick wakes before its
    deadline) to three quarters after, the typical one the running median of the (unwrapped) phases over
    :data:`_PHASE_BLOCK` ticks (the locked grid's phase moves, by a bounded step a tick). The deadline is the lower
    edge of that cluster: a low percentile, not the least value, which a tick later than three quarters of a period
    would be, wrapped round."""
    phase = np.unwrap(np.mod(t, period), period=period)
    h = min(_PHASE_BLOCK // 2, (t.size - 1) // 2)
    centre = np.median(np.lib.stride_tricks.sliding_window_view(phase, 2 * h + 1), axis=1)  # ticks h .. n - h - 1
    if h > 0:  # the first and last h ticks: the running median's trend continued
        lo, hi = (centre[min(h, centre.size - 1)] - centre[0]) / h, (centre[-1] - centre[max(centre.size - 1 - h, 0)]) / h
        k = np.arange(1, h + 1)
        centre = np.concatenate((centre[0] - lo * k[::-1], centre, centre[-1] + hi * k))
    return np.mod(phase - centre + period / 4, period) - period / 4


def round_figures(summary: dict, vehicle: dict | None, ticks: dict[str, np.ndarray], period: float,
                  flood: dict | None) -> dict:
    """One flight's figures from the bridge's ``summary``, the vehicle's summary, the tick log's ``ticks`` (period
    [s]) and the flooder's counts (None: no flood). ``waited_a_period``: event ticks whose sample arrived after the
    previous tick's boundary (the two processes' grids drifted into each other); ``age_at_tick_us``: the telemetry's
    age at the event ticks (constant when the grid is locked to the arrivals: ``phase_lock``, the bridge's)."""
    link = summary.get("link") or {}
    sent = int(summary.get("setpoints_sent", 0)) + int(summary.get("setpoints_repeated", 0))
    got = None if vehicle is None else int(vehicle.get("setpoints", 0)) + int(vehicle.get("setpoints_ignored", 0))
    lat = tick_latency_us(ticks)
    # a sample that arrived after a tick's boundary waits for the next one: about a period
    waited = tick_latency_us({"latency_us": np.asarray(ticks["latency_us"]) - np.asarray(ticks["compute_us"]),
                              "event": ticks["event"]}) > period * 1e6 / 2
    return {
        "latency_us": percentiles(lat), "latency_parts_us": latency_parts(ticks, period),
        "latency_over_1ms": int(np.sum(lat > 1000.0)), "event_ticks": int(lat.size),
        "waited_a_period": int(np.sum(waited)),
        "age_at_tick_us": percentiles(np.asarray(ticks["age_ms"])[np.asarray(ticks["event"], bool)] * 1e3,
                                      (1, 50, 99)),
        "phase_lock": summary.get("phase_lock"),
        "ticks": int(summary.get("ticks", 0)), "missed_ticks": int(summary.get("missed_ticks", 0)),
        "grid_skipped": int(summary.get("grid_skipped", 0)), "max_gap_ms": summary.get("max_gap_ms"),
        "telemetry_gaps": summary.get("telemetry_gaps"), "fallbacks": int(summary.get("fallbacks", 0)),
        "setpoints_sent": sent, "setpoints_received": got,
        "setpoints_lost": None if got is None else sent - got,
        "vehicle_failsafes": None if vehicle is None else _failsafes(vehicle),
        "flood": flood,
        "foreign": {k: int(link.get(k, 0)) for k in ("foreign_packets", "foreign_heartbeats", "unpinned", "foreign",
                                                      "parse_errors", "bad_data", "peer_changes")},
        "stop_reason": summary.get("stop_reason"),
    }


def _failsafes(vehicle: dict) -> int:
    """The vehicle's own off-board-loss failsafes (setpoints stopped for COM_OF_LOSS_T): missed setpoints it acted
    on."""
    return sum("setpoints lost" in str(e[-1]) for e in vehicle.get("events", []))


def flood_command(port: int, hz: float, seconds: float, stats: Path) -> list[str]:
    """``python -m`` arguments of the flooder against 127.0.0.1:``port``."""
    return ["ddpc_codegen.testbed.proxy_flood", str(port), "--hz", f"{hz:g}", "--seconds", f"{seconds:g}",
            "--ports", str(FLOOD_PORTS), "--stats", str(stats)]


def flood_round(work: Path, solver: Path, *, duration: float, seed: int, hz: float = FLOOD_HZ, rt_priority: int,
                cpu_latency_us: int = 0, pin: bool = False, load=None, log=print) -> dict:
    """The steered flight (``solver``, ``duration`` s) flown twice, back to back: quiet, then under a ``hz`` flood.
    ``load()``: the machine's load averages beside each flight (e.g. :func:`os.getloadavg`)."""
    out: dict = {"rate_hz": hz, "ports": FLOOD_PORTS, "duration_s": duration}
    for name, flood_hz in (("quiet", 0.0), ("flood", hz)):
        stats = work / f"flood_round_{name}_flood.json"
        stats.unlink(missing_ok=True)
        beside = (lambda port: flood_command(port, flood_hz, duration + 120.0, stats)) if flood_hz > 0 else None
        before = load() if load else None
        log(f"    {name}: {duration:g} s steered" + (f", {flood_hz:g} datagrams/s from {FLOOD_PORTS} foreign ports"
                                                    if flood_hz > 0 else ", no flood"))
        run = fly(f"flood_round_{name}", work, ["--mode", "steer", "--solver", str(solver)], duration=duration,
                  seed=seed, rt_priority=rt_priority, cpu_latency_us=cpu_latency_us, pin=pin, log=log, beside=beside)
        tl = load_ticklog(run["ticks"])
        counts = _read_json(stats) if flood_hz > 0 else None
        if flood_hz > 0 and counts is None:
            raise RuntimeError(f"the flood did not run: {(work / f'flood_round_{name}_beside.log').read_text()[-1500:]}")
        out[name] = round_figures(run["summary"], run["vehicle"], tl.ticks, tl.dt, counts)
        out[name]["load_before"] = before
        out[name]["load_after"] = load() if load else None
    return out


def _read_json(path: Path) -> dict | None:
    return json.loads(path.read_text()) if path.is_file() else None



def flood_rows(rnd: dict | None) -> list[tuple[str, str, str]]:
    """bridge-demo's table rows (label, figure, target) for the flood round (none when it was not flown)."""
    if not rnd:
        return []
    rows = []
    for name in ("quiet", "flood"):
        r = rnd[name]
        lat, parts = r["latency_us"], r["latency_parts_us"]
        load = r.get("load_before")
        label = "no flood" if name == "quiet" else f"{rnd['rate_hz'] / 1e3:g} kHz flood"
        rows.append((f"{label}: latency p99 (compute p99)", f"{_us(lat['p99'])} ({_us(parts['compute']['p99'])}) us"
                     + (f", load {load[0]:.2f}" if load else ""), "p99 <= 1000 us"))
        rows.append((f"{label}: setpoints sent / at the vehicle",
                     f"{r['setpoints_sent']} / {r['setpoints_received']}, {r['missed_ticks']} missed ticks",
                     "none lost"))
    fl, fo = rnd["flood"]["flood"] or {}, rnd["flood"]["foreign"]
    pre_pin = fo["foreign"] + fo["bad_data"] + fo["parse_errors"]
    rows.append(("flood: datagrams", f"{fl.get('datagrams', '-')} sent, {fo['foreign_packets']} dropped by the bridge "
                 f"(+{pre_pin} parsed before the pin), {fl.get('received', '-')} answered", "none answered"))
    return rows


def _us(v) -> str:
    return "-" if v is None or not math.isfinite(v) else f"{v:.0f}"
