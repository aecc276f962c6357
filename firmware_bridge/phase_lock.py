"""The tick grid's phase locked to the telemetry's arrivals: the period fixed, only the phase slews.

The vehicle and the bridge each run their own free clock at the control rate. With the bridge's phase fixed at its
first tick, the vehicle's send phase drifts against it; when the two cross, every sample arrives just after a tick
and waits a whole period for the next one, and the telemetry's age at the tick sweeps through a period as they
drift. Here the grid follows the arrivals instead: a tick fires ``margin`` after the typical arrival of the position
sample (after the arrivals' late edge: the median plus a multiple of their spread), so the age at the tick is constant
and the closed loop the predictor learns from the tick log has a constant delay.

:class:`ArrivalPhase` estimates where on the period's circle the samples arrive, robustly: the median of the recent
arrival phases (unwrapped around their circular mean), with a drift rate from the medians of the window's two
halves, so a burst of two (ArduCopter over TCP), a late sample or a few outliers move nothing. Arrivals that do
not cluster on the circle (PX4 SIH's stamps step 4/8/12 ms), too few of them, or none lately: no estimate, and
:class:`PhaseLock` leaves the grid free-running where it is. Locked, it slews the grid's phase toward the target
by at most ``max_slew`` per tick, so consecutive deadlines stay within ``period +- max_slew`` (never a burst of
catch-up ticks) and the grid's control-clock time (``k * period``) is untouched.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["ArrivalPhase", "PhaseLock"]

_DRIFT_SMOOTHING = 0.25  # share of a new drift estimate taken in (the rest is the previous ones')
# The tick's lead on the median arrival beyond the margin, in half interquartile ranges of the arrivals (3: about two
# standard deviations of gaussian jitter): a loaded machine delays the vehicle's samples more, and then the lock
# leads by more, so that a stretch of late samples does not wait a period each.
SPREAD_LEAD = 3.0


def _warm_up(period: float) -> None:
    """One estimate on made-up arrivals, before any loop runs: a process's first ``np.percentile`` / ``np.median``
    costs milliseconds of lazy set-up, which the first real estimate, 40 arrivals into the flight, paid inside the
    loop (one missed tick in every ``make bridge-demo`` flight)."""
    global _WARM
    if not _WARM:
        _WARM = True
        probe = ArrivalPhase(period, window=8, refresh=4)
        for k in range(8):
            probe.observe(k * period)
        probe.update()


_WARM = False


def wrap(x: float, period: float) -> float:
    """``x`` [s] wrapped into [-period/2, period/2)."""
    return (x + 0.5 * period) % period - 0.5 * period


class ArrivalPhase:
    """Where in the period a stream's samples arrive (receive times on the loop's clock).

    Args:
        period: the control period [s]; window: arrivals the estimate uses; refresh: new arrivals between two
        estimates (the estimate is a few numpy calls on ``window`` values, run after a tick, never per sample);
        min_concentration: the least mean resultant length of the (drift-corrected) arrival phases on the
        period's circle that counts as periodic (1: all on one phase, about 0 for uniform phases);
        max_drift: the largest drift of the arrivals against the grid that is tracked [s/s];
        hold: arrivals further apart than this [s] start the window afresh (a gap, a reboot).
    """

    def __init__(self, period: float, window: int = 400, refresh: int = 20, min_concentration: float = 0.8,
                 max_drift: float = 2e-3, hold: float = 0.5) -> None:
        if not (period > 0 and window >= 8 and 1 <= refresh <= window):
            raise ValueError(f"need period > 0, window >= 8, 1 <= refresh <= window; got {period}, {window}, {refresh}")
        self.period, self.window, self.refresh_every = float(period), int(window), int(refresh)
        self.min_concentration, self.max_drift, self.hold = float(min_concentration), float(max_drift), float(hold)
        self._rx = np.zeros(self.window)
        self.clear()
        _warm_up(self.period)

    def clear(self) -> None:
        """Forget every arrival (no estimate until half a window has arrived again)."""
        self._n = 0                  # arrivals stored since the last clear (ring index: _n % window)
        self._new = 0                # arrivals since the last estimate
        self._estimates = 0          # estimates since the last clear
        self.last_rx = -math.inf
        self.phase = math.nan        # estimated arrival phase at time ``t_ref`` [s, in [0, period)]
        self.t_ref = math.nan
        self.drift = 0.0             # the arrival phase's rate against the period [s/s]
        self.concentration = 0.0     # mean resultant length of the drift-corrected phases
        self.spread = math.nan       # half the interquartile range of their deviations [s]

    def observe(self, rx: float) -> None:
        """One arrival received at ``rx`` [s]; O(1)."""
        if not rx - self.last_rx <= self.hold:
            self.clear()
        self._rx[self._n % self.window] = rx
        self._n += 1
        self._new += 1
        self.last_rx = rx

    def update(self) -> bool:
        """Re-estimate once ``refresh`` arrivals came in since the last one (and twice that since the window
        started); returns whether it did."""
        if self._new < self.refresh_every or self._n < 2 * self.refresh_every:
            return False
        self._new = 0
        n = min(self._n, self.window)
        i = self._n % self.window  # the oldest arrival once the ring is full
        t = np.concatenate((self._rx[i:], self._rx[:i])) if self._n >= self.window else self._rx[:n]
        P = self.period
        ang = (2.0 * np.pi / P) * np.fmod(t, P)
        centre = math.atan2(float(np.mean(np.sin(ang))), float(np.mean(np.cos(ang)))) * P / (2.0 * np.pi)
        dev = np.mod(np.fmod(t, P) - centre + 0.5 * P, P) - 0.5 * P  # unwrapped around the circular mean
        half = n // 2
        t1, t2 = float(np.median(t[:half])), float(np.median(t[half:]))
        raw = (float(np.median(dev[half:])) - float(np.median(dev[:half]))) / max(t2 - t1, 1e-9)
        q25, q75 = np.percentile(dev - raw * (t - t2), (25.0, 75.0))
        # The drift from two medians is noisy: one within two of its standard errors (a median's is 1.25 sigma /
        # sqrt(n), sigma from the interquartile range) is none, and the estimates are smoothed (a drift changes
        # slowly). Extrapolated over the window's age, an unsmoothed one doubled the lock's error.
        se = 1.2533 * float(q75 - q25) / 1.349 * math.sqrt(2.0 / half) / max(t2 - t1, 1e-9)
        raw = 0.0 if abs(raw) < 2.0 * se else raw
        self.drift = raw if self._estimates == 0 else self.drift + _DRIFT_SMOOTHING * (raw - self.drift)
        self._estimates += 1
        resid = dev - self.drift * (t - t2)
        self.concentration = float(np.abs(np.mean(np.exp((2j * np.pi / P) * resid))))
        q25, q50, q75 = np.percentile(resid, (25.0, 50.0, 75.0))
        self.phase, self.t_ref, self.spread = (centre + float(q50)) % P, t2, 0.5 * float(q75 - q25)
        return True

    def locked(self, now: float) -> bool:
        """An estimate that holds at ``now`` [s]: periodic arrivals, a drift within bounds, heard lately."""
        return (math.isfinite(self.phase) and now - self.last_rx <= self.hold
                and self.concentration >= self.min_concentration and abs(self.drift) <= self.max_drift)

    def at(self, now: float) -> float:
        """The arrival phase at ``now`` [s, in [0, period)] (nan without an estimate)."""
        return (self.phase + self.drift * (now - self.t_ref)) % self.period


class PhaseLock:
    """Steers a :class:`firmware_bridge.clock.TickClock`'s phase to ``margin`` after the position sample's late edge
    of arrivals (the median arrival plus :data:`SPREAD_LEAD` half interquartile ranges).

    Args:
        period: the control period [s]; margin: the tick's lead on the arrivals' late edge [s] (>= 0, < period / 2);
        max_slew: the largest phase change per tick [s]; gain: the share of the phase error corrected per tick
        (within ``max_slew``); the rest goes to :class:`ArrivalPhase`.
    """

    def __init__(self, period: float, margin: float, max_slew: float | None = None, gain: float = 0.1,
                 **estimator) -> None:
        if not 0.0 <= margin < 0.5 * period:
            raise ValueError(f"the tick margin must be in [0, period / 2); got {margin!r} s")
        self.period, self.margin = float(period), float(margin)
        self.max_slew = 2e-3 * self.period if max_slew is None else float(max_slew)
        if not (0.0 < self.max_slew < 0.1 * self.period and 0.0 < gain <= 1.0):
            raise ValueError(f"need 0 < max_slew < period / 10 and 0 < gain <= 1; got {max_slew!r}, {gain!r}")
        self.gain = float(gain)
        self.arrivals = ArrivalPhase(period, **estimator)
        self.reset()

    def reset(self) -> None:
        """A new run: nothing heard, the grid free."""
        self.arrivals.clear()
        self._seq = 0
        self.locked_ticks = 0
        self.free_ticks = 0
        self.slewed = 0.0       # the phase moved in all [s] (sum of |slew|)
        self.error = math.nan   # the last tick's phase error (target - deadline) [s]

    def observe(self, seq: int, rx: float) -> None:
        """The position stream's sample count ``seq`` and its newest receive time ``rx`` [s]: an arrival when
        the count moved (a burst read in one go is one arrival)."""
        if seq != self._seq:
            if seq > self._seq:
                self.arrivals.observe(rx)
            self._seq = seq

    def slew(self, deadline: float, now: float) -> float:
        """After a tick: the phase change for the next ``deadline`` [s] (within +-max_slew; 0 while free)."""
        est = self.arrivals
        est.update()
        if not est.locked(now):
            self.free_ticks += 1
            self.error = math.nan
            return 0.0
        self.locked_ticks += 1
        self.error = wrap(est.at(deadline) + SPREAD_LEAD * est.spread + self.margin - deadline, self.period)
        # the arrivals' drift over a period, then a share of the error: a drift is followed without a lag
        step = min(self.max_slew, max(-self.max_slew, est.drift * self.period + self.gain * self.error))
        self.slewed += abs(step)
        return step

    def summary(self) -> dict:
        """What the lock did in this run (times in us)."""
        a = self.arrivals
        return {"margin_us": self.margin * 1e6, "locked_ticks": self.locked_ticks, "free_ticks": self.free_ticks,
                "slewed_us": self.slewed * 1e6, "error_us": _us(self.error), "drift_ppm": a.drift * 1e6,
                "arrival_spread_us": _us(a.spread), "concentration": a.concentration}


def _us(x: float) -> float | None:
    return x * 1e6 if math.isfinite(x) else None
