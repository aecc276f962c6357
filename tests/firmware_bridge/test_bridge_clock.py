"""The bridge's own control clock: a uniform tick grid whatever the telemetry does, every sample
kept, no history reset on late samples (real time, against the scripted fake vehicle imitating
PX4 SIH's and ArduCopter's measured stamp patterns)."""

from __future__ import annotations

import time

import numpy as np
from scipy.ndimage import median_filter
import pytest
from support.bridge_helpers import FakeVehicle, Procs, free_port, read_json

from firmware_bridge.clock import TickClock
from firmware_bridge.ticklog import REASONS, load_ticklog

R = {r: i for i, r in enumerate(REASONS)}


def test_clock_ticks_on_a_uniform_grid_and_skips_after_an_overrun():
    c = TickClock(0.005)
    assert not c.started and c.wait_time(0.0) == 0.05
    c.start(10.0)
    assert c.due(10.0) and c.time() == 0.0
    assert c.advance(10.001) == 0 and c.deadline == pytest.approx(10.005) and not c.due(10.004)
    assert c.wait_time(10.002) == pytest.approx(0.003)
    assert c.advance(10.0051) == 0 and c.time() == pytest.approx(0.010)
    # tick 2 (due 10.010) ends at 10.022: tick 3 is skipped (no catch-up burst), tick 4 is due
    # at once and the grid phase is kept
    assert c.advance(10.022) == 1 and c.skipped == 1 and c.deadline == pytest.approx(10.020)
    assert c.advance(10.0205) == 0 and c.deadline == pytest.approx(10.025)
    with pytest.raises(ValueError, match="period must be positive"):
        TickClock(0.0)


@pytest.mark.e2e
@pytest.mark.compiler
@pytest.mark.realtime
@pytest.mark.parametrize("pattern", ["px4", "burst"])
def test_irregular_telemetry_steers_on_the_grid_and_keeps_every_sample(tmp_path, flying_solver, pattern):
    pr = Procs(tmp_path)
    port = free_port()
    veh = FakeVehicle(port, pattern=pattern)
    veh.telemetry = False  # heartbeats only until the bridge listens: then every sample sent arrives
    try:
        veh.start()
        br = pr.spawn("bridge", f"udpin:127.0.0.1:{port}", "--mode", "steer", "--solver", str(flying_solver),
                      "--log", str(tmp_path / "t.npz"), "--summary", str(tmp_path / "s.json"), "--timeout", "60",
                      name="bridge")
        assert veh.bridge_seen.wait(30), pr.log(br)
        veh.telemetry = True
        t_end = time.monotonic() + 30
        while len(veh.setpoints) < 800 and time.monotonic() < t_end:
            time.sleep(0.02)
        veh.telemetry = False  # stop sending before the bridge stops: sent == received
        time.sleep(0.1)
        assert pr.terminate(br) == 0, pr.log(br)
        sent = dict(veh.sent)
    finally:
        veh.close()
        pr.cleanup()
    s = read_json(tmp_path / "s.json")
    log = load_ticklog(tmp_path / "t.npz")
    t = log.ticks
    # every sample the vehicle sent is in the log (a burst is two samples, not one)
    assert {k: v["samples"] for k, v in s["telemetry"].items()} == sent
    assert log.samples["attitude"].shape == (sent["attitude"], 2)
    # setpoints on the bridge's grid: ticks a multiple of 5 ms apart (the grid's phase may slew onto the
    # arrivals, by at most 10 us a tick); a tick the machine could not run in time is skipped and counted,
    # never fired late in a burst (a loaded 2-core CI box skips some)
    grid = (t["t_wall"] - t["t_wall"][0]) / 0.005
    phase = np.unwrap(2 * np.pi * (grid - np.round(grid))) / (2 * np.pi)  # [periods], slewing slowly
    assert np.median(np.abs(phase - median_filter(phase, size=51, mode="nearest"))) < 0.2
    gaps = np.diff(t["t_wall"]) * 1e3
    assert s["ticks"] + s["grid_skipped"] == pytest.approx(np.round(grid[-1]) + 1, abs=2), (
        f"ticks {s['ticks']} + skipped {s['grid_skipped']} vs grid span {np.round(grid[-1]) + 1:.0f}; largest gaps "
        f"[ms] {np.sort(gaps)[-5:].round(1).tolist()} at rows {np.argsort(gaps)[-5:].tolist()}; stalls {s.get('stalls')}")
    assert s["rate_hz"] == pytest.approx(200.0, rel=0.05)
    # steering engaged once and its history was never reset by a late or missing sample
    t_ini = read_json(flying_solver / "manifest.json")["dims"]["t_ini"]
    # (a stale stretch -- telemetry older than 50 ms, which a loaded CI box can cause -- is the one
    # thing allowed to reset it: one more warm-up per stale episode)
    n_blend = int((t["reason"] == R["blend"]).sum())  # hand-over ticks fill the history too
    stale = t["reason"] == R["stale"]
    episodes = int(np.sum(stale[1:] & ~stale[:-1]) + stale[0])
    assert s["activations"] == 1
    assert s["steering"]["warmup"] + n_blend <= t_ini * (1 + episodes)
    if episodes == 0:
        assert (t["reason"] == R["warmup"]).sum() + n_blend == t_ini
    # the dataset is the grid: one trajectory, all engaged ticks after the warm-up (a stale stretch ends a
    # trajectory: the dataset is never spliced across it)
    assert 1 <= len(log.segments()) <= 1 + episodes, episodes
    assert np.all(t["age_ms"][t["active"]] < 50.0)
