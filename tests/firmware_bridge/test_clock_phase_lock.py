"""The tick grid locked to the telemetry's arrival phase (:mod:`firmware_bridge.phase_lock` driven by
:class:`firmware_bridge.clock.TickTrigger`): simulated arrivals over phase, drift, jitter and bursts, an ideal loop
that wakes at each deadline; the lock converges, the grid stays uniform within the slew bound, late samples never
make a catch-up burst, and without periodic telemetry the grid runs free."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from firmware_bridge.bridge_config import BridgeConfig
from firmware_bridge.clock import TickTrigger
from firmware_bridge.phase_lock import SPREAD_LEAD, ArrivalPhase, PhaseLock, wrap

P = 0.005
MARGIN = 200e-6
SLEW = 2e-3 * P  # PhaseLock's default bound per tick
# ticks to converge from any phase: the first estimate's 40 arrivals (bursts: one per two periods), the largest phase
# error at the slew bound, then the proportional tail
CONVERGED = 2 * 40 + int(0.5 * P / SLEW) + 60
HALF_IQR = 0.6745  # of a standard normal


def arrivals(n: int, *, phase: float, ppm: float, jitter: float, burst: bool, late: float, seed: int,
             t_start: float = 100.0) -> tuple[np.ndarray, np.ndarray]:
    """(receive times [s], each one's undisturbed time [s]) of ``n`` samples sent every ``P * (1 + ppm)``:
    gaussian jitter (``jitter`` [s], sigma), a share ``late`` of them up to 0.9 period late, bursts: two samples
    delivered together when the second is sent (ArduCopter over TCP)."""
    rng = np.random.default_rng(seed)
    ideal = t_start + phase + np.arange(n) * P * (1.0 + ppm * 1e-6)
    if burst:
        ideal[0::2] = ideal[1::2] if n % 2 == 0 else np.append(ideal[1::2], ideal[-1])
    rx = ideal + rng.normal(0.0, jitter, n)
    out = rng.random(n) < late
    rx[out] += rng.uniform(0.0, 0.9 * P, int(out.sum()))
    if burst:
        rx[0::2] = rx[1::2] if n % 2 == 0 else np.append(rx[1::2], rx[-1])  # the pair arrives in one read
    return np.maximum.accumulate(rx), ideal  # a stream arrives in order


def run_loop(rx: np.ndarray, *, n_ticks: int, start: float | None = None, margin: float | None = MARGIN,
             wake: float = 30e-6, compute: float = 400e-6) -> tuple[TickTrigger, np.ndarray, list[float]]:
    """An ideal real-time loop on the arrivals ``rx``: wakes ``wake`` after each deadline (or at an arrival), ticks
    for ``compute``. Returns the trigger, the deadlines its ticks were due at, and the lock's error after each."""
    trig = TickTrigger(P, lockstep=False, max_gap_fill=3, margin=margin)
    pos = SimpleNamespace(seq=0, rx=-math.inf)
    tel = SimpleNamespace(has_data=False, pos=pos)
    if start is not None:
        trig.clock.start(start)
    deadlines, errors, i = [], [], 0
    while len(deadlines) < n_ticks:
        dl = trig.clock.deadline
        if i < rx.size and (rx[i] <= dl + wake or not tel.has_data):
            now = rx[i]
            while i < rx.size and rx[i] == now:  # a burst is read in one go
                pos.seq, pos.rx, i = pos.seq + 1, now, i + 1
            tel.has_data = True
        elif math.isfinite(dl):
            now = dl + wake
        else:
            break
        kind = trig.due(now, tel)
        if kind:
            deadlines.append(trig.clock.deadline)
            trig.done(kind, now + compute)
            errors.append(trig.lock.error if trig.lock is not None else math.nan)
    return trig, np.asarray(deadlines), errors


def lead(deadlines: np.ndarray, ideal_t: np.ndarray) -> np.ndarray:
    """Each deadline's lead on the typical arrival (the undisturbed send time's phase) [s], wrapped."""
    t0, step = ideal_t[1], (ideal_t[3] - ideal_t[1]) / 2.0  # bursts: the odd samples' times are the true ones
    return np.array([wrap(d - t0 - step * round((d - t0) / step), P) for d in deadlines])


@settings(max_examples=50, deadline=None)
@given(phase=st.floats(0.0, P, exclude_max=True), start=st.floats(0.0, P, exclude_max=True),
       ppm=st.floats(-500.0, 500.0), jitter=st.floats(0.0, 150e-6), burst=st.booleans(), late=st.floats(0.0, 0.05),
       seed=st.integers(0, 2**16))
def test_the_lock_converges_and_keeps_the_grid_uniform(phase, start, ppm, jitter, burst, late, seed):
    n_ticks = CONVERGED + 400
    rx, ideal = arrivals(n_ticks + 200, phase=phase, ppm=ppm, jitter=jitter, burst=burst, late=late, seed=seed)
    trig, dl, _ = run_loop(rx, n_ticks=n_ticks, start=rx[0] - start)  # any phase within the first period
    steps = np.diff(dl)
    # uniform: only the phase slews, within its bound per tick (no skipped tick, never a catch-up burst)
    assert trig.clock.skipped == 0
    assert np.all(np.abs(steps - P) <= SLEW + 1e-9), (steps.min(), steps.max())
    # converged: each tick a margin after the arrivals' late edge (median + SPREAD_LEAD half IQRs), within the
    # estimate's noise (a median's, and the late samples' share of the phases a drift spreads over the window: up to
    # 4 s of bursts; they widen the IQR a little too)
    s = trig.lock.summary()
    spread = s["arrival_spread_us"] * 1e-6
    assert abs(spread - HALF_IQR * jitter) <= 5e-6 + 0.15 * jitter + 2.0 * late * jitter + late * abs(ppm) * 1e-6
    err = lead(dl[CONVERGED:], ideal) - MARGIN - SPREAD_LEAD * HALF_IQR * jitter
    # (the largest error of 400 ticks: 0.4 jitter for the median's noise was exceeded by a burst stream at 409 ppm,
    # where pairs halve the independent arrivals)
    tol = 20e-6 + 0.5 * jitter + late * abs(ppm) * 1e-6 * 4.0 + SPREAD_LEAD * (0.15 + 2.0 * late) * jitter
    assert np.max(np.abs(err)) < tol, (np.max(np.abs(err)) * 1e6, tol * 1e6)
    assert s["locked_ticks"] > n_ticks - CONVERGED and abs(s["drift_ppm"] - ppm) < 60.0 + jitter * 3e5


@settings(max_examples=25, deadline=None)
@given(start=st.floats(0.0, P, exclude_max=True), backlog=st.integers(2, 40), seed=st.integers(0, 2**16))
def test_late_samples_never_make_a_catch_up_burst(start, backlog, seed):
    """The vehicle stalls, then delivers ``backlog`` samples at once: the grid keeps its period within the slew
    bound, and the backlog's one late arrival moves the lock's phase estimate by nothing."""
    rx, _ = arrivals(1200, phase=0.0, ppm=0.0, jitter=30e-6, burst=False, late=0.0, seed=seed)
    rx[600:600 + backlog] = rx[600 + backlog]
    trig, dl, errors = run_loop(rx, n_ticks=1100, start=rx[0] - start)
    assert np.all(np.abs(np.diff(dl) - P) <= SLEW + 1e-9)
    e = np.asarray(errors[700:])
    assert np.nanmax(np.abs(e)) < 30e-6


@pytest.mark.parametrize("steps_ms", [(4, 8, 12), (4,), (8, 12)])
def test_irregular_arrivals_leave_the_grid_free(steps_ms):
    """PX4 SIH's stamps step 4/8/12 ms: the arrival phases do not cluster on the period's circle, no lock."""
    rng = np.random.default_rng(3)
    rx = 100.0 + np.cumsum(rng.choice(np.asarray(steps_ms) * 1e-3, 2000)) + rng.normal(0, 30e-6, 2000)
    trig, dl, _ = run_loop(np.maximum.accumulate(rx), n_ticks=1500, start=100.0)
    assert trig.lock.summary()["locked_ticks"] == 0 and trig.lock.slewed == 0.0
    np.testing.assert_allclose(np.diff(dl), P, atol=1e-9)


def test_without_telemetry_the_grid_runs_free_and_relearns():
    rx, _ = arrivals(400, phase=1e-3, ppm=0.0, jitter=20e-6, burst=False, late=0.0, seed=1)
    trig, dl, errors = run_loop(rx, n_ticks=600, start=100.0)
    assert not math.isnan(errors[390])
    # silent for 1 s after sample 400: no estimate holds, the grid keeps its phase exactly
    assert all(math.isnan(e) for e in errors[400 + 120:])
    np.testing.assert_allclose(np.diff(dl[400 + 120:]), P, atol=1e-9)
    est = trig.lock.arrivals
    est.observe(rx[-1] + 1.0)  # after the silence: the window starts afresh
    assert est._n == 1 and not est.locked(rx[-1] + 1.0)


def test_the_grid_time_and_lockstep_are_untouched():
    rx, _ = arrivals(800, phase=2e-3, ppm=200.0, jitter=50e-6, burst=False, late=0.0, seed=2)
    trig, dl, _ = run_loop(rx, n_ticks=700, start=100.0)
    assert trig.clock.time() == pytest.approx(700 * P)  # k * period: the control clock never slews
    assert trig.lock.slewed > 0
    assert TickTrigger(P, lockstep=True, max_gap_fill=3, margin=MARGIN).lock is None
    assert TickTrigger(P, lockstep=False, max_gap_fill=3).lock is None  # margin None: free grid
    free, dl_free, _ = run_loop(rx, n_ticks=700, start=100.0, margin=None)
    np.testing.assert_allclose(np.diff(dl_free), P, atol=1e-9)


def test_the_estimate_ignores_bursts_and_outliers():
    est = ArrivalPhase(P, window=200, refresh=20)
    rx, ideal = arrivals(400, phase=3e-3, ppm=0.0, jitter=40e-6, burst=True, late=0.05, seed=4)
    for t in np.unique(rx):
        est.observe(float(t))
    assert est.update() or est.phase == est.phase
    assert est.locked(float(rx[-1]))
    assert abs(wrap(est.at(float(rx[-1])) - math.fmod(ideal[1], P), P)) < 20e-6
    assert est.spread < 60e-6 and est.concentration > 0.9


def test_lock_settings_are_checked():
    with pytest.raises(ValueError, match="margin"):
        PhaseLock(P, margin=P)
    with pytest.raises(ValueError, match="max_slew"):
        PhaseLock(P, margin=0.0, max_slew=P)
    with pytest.raises(ValueError, match="window"):
        ArrivalPhase(P, window=4)
    assert BridgeConfig(mode="collect").tick_margin == MARGIN and BridgeConfig(mode="collect", tick_margin=None)
    with pytest.raises(ValueError, match="tick_margin"):
        BridgeConfig(mode="collect", tick_margin=0.003)  # over half the 5 ms period
