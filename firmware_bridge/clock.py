"""The bridge's own control clock: ticks on a uniform grid, whatever the telemetry does.

Real autopilots do not deliver telemetry on the control period: PX4 SIH stamps step 4/8/12 ms
(fewer distinct samples per second than the 200 Hz requested), ArduCopter over TCP delivers
200 Hz in bursts of two. A loop that waits for "every stream advanced by one period" never gets
going there. Like the paper's 200 Hz ROS loop, the bridge ticks at ``t0 + k * period`` on its
monotonic clock and each tick uses the newest telemetry with its age (zero-order hold, see
:class:`firmware_bridge.telemetry.TelemetryState`), so the closed loop the predictor learns from
the tick log contains the telemetry delay it will see when steering.

An overrun longer than one period (the process was not scheduled) skips grid points instead of
firing a burst of catch-up ticks: the skipped ones are counted, the grid phase is kept.

The grid's phase follows the telemetry's arrivals (:class:`firmware_bridge.phase_lock.PhaseLock`): the vehicle's
send clock and this one run free and drift against each other, so with a fixed phase a sample would at times arrive
just after a tick and wait a whole period. Locked, each tick fires a margin after the position sample's typical
arrival; the phase slews by a bounded amount per tick (the period and the control-clock time ``k * period`` are
unchanged), and without periodic telemetry the grid runs free.

:class:`TickTrigger` says when a tick is due: on the grid in real time, on every sample of both streams in
lock-step (the vehicle's stamps are the clock there; a lost sample is a gap, bridged in the history for up to
``max_gap_fill`` ticks).
"""

from __future__ import annotations

import math

from firmware_bridge.phase_lock import PhaseLock
from firmware_bridge.telemetry import TelemetryState

__all__ = ["TickClock", "TickTrigger"]


class TickClock:
    """Deadlines ``t0 + k * period`` on the caller's clock (``time.monotonic()`` seconds).

    Args:
        period: tick period [s].
    """

    def __init__(self, period: float) -> None:
        if not period > 0:
            raise ValueError(f"period must be positive; got {period!r}")
        self.period = float(period)
        self.t0 = math.nan
        self.k = 0           # index of the next tick to fire
        self.skipped = 0     # grid points passed over after overruns

    @property
    def started(self) -> bool:
        return math.isfinite(self.t0)

    def start(self, now: float) -> None:
        """Put tick 0 at ``now``."""
        self.t0, self.k, self.skipped = float(now), 0, 0

    @property
    def deadline(self) -> float:
        """When the next tick is due [s] (inf before :meth:`start`)."""
        return self.t0 + self.k * self.period if self.started else math.inf

    def time(self) -> float:
        """Grid time of the next tick since tick 0 [s] (k * period: exact, no jitter)."""
        return self.k * self.period

    def due(self, now: float) -> bool:
        return now >= self.deadline

    def wait_time(self, now: float, cap: float = 0.05) -> float:
        """Seconds to sleep until the next deadline, at most ``cap``."""
        return max(0.0, min(cap, self.deadline - now))

    def catch_up(self, now: float) -> int:
        """Before a tick that fires a period or more after its deadline (the process was not scheduled, or
        stopped): move to the newest grid point at or before ``now``, so the tick's control-clock time is the
        wall's, not the missed deadline's (a stall's jump of the trajectory clock lands on the tick that detects
        the stall). The grid points passed over are counted as skipped; returns how many."""
        late = now - self.deadline
        if not late >= self.period:
            return 0
        n = int(late // self.period)
        self.k += n
        self.skipped += n
        return n

    def slew(self, delta: float) -> None:
        """Move the grid's phase by ``delta`` [s] (the caller bounds it well below the period): every later
        deadline moves with it, the grid time :meth:`time` does not."""
        self.t0 += delta

    def advance(self, now: float) -> int:
        """Mark the current tick done; returns how many grid points were skipped (0 normally)."""
        self.k += 1
        late = now - self.deadline
        if late < self.period:
            return 0
        n = int(late // self.period)
        self.k += n
        self.skipped += n
        return n


class TickTrigger:
    """When the loop ticks, and its control clock.

    Args:
        period: the tick [s]; lockstep: tick on telemetry (vehicle time) instead of the grid.
        max_gap_fill: lock-step: lost samples bridged in the history (a longer hole resets it).
        margin: real time: the grid's ticks lock to this long after the position samples' late edge of arrivals [s]
        (None: the grid runs free at the phase of its first tick).
    """

    def __init__(self, period: float, lockstep: bool, max_gap_fill: int, margin: float | None = None) -> None:
        self.period = period
        self.lockstep = lockstep
        self.max_gap_fill = max_gap_fill
        self.gaps = 0  # lock-step: telemetry gaps seen
        self.lock = PhaseLock(period, margin) if margin is not None and not lockstep else None
        self.reset()

    def reset(self) -> None:
        """A new run: the grid not started, no sample used yet."""
        self.clock = TickClock(self.period)
        self.last_seq = (0, 0)        # telemetry sample counts used by the last event tick
        self.seen_total = 0           # telemetry samples (both streams) up to the last tick
        self.last_stamp = math.nan
        if self.lock is not None:
            self.lock.reset()

    def restart_samples(self) -> None:
        """The vehicle rebooted: its sample counts start again."""
        self.last_seq = (0, 0)
        if self.lock is not None:
            self.lock.reset()  # a new time line: its arrivals are learnt afresh

    def wake_in(self, now: float) -> float:
        """Seconds the loop may sleep in the link's wait."""
        if self.lockstep or not self.clock.started:
            return 0.05
        return self.clock.wait_time(now)

    def due(self, now: float, tel: TelemetryState) -> str:
        """"event" (lock-step: every stream advanced), "grid" (real time: the clock's deadline), or ""."""
        if not tel.has_data:
            return ""
        if self.lockstep:
            return "event" if tel.att.seq > self.last_seq[0] and tel.pos.seq > self.last_seq[1] else ""
        if self.lock is not None:
            self.lock.observe(tel.pos.seq, tel.pos.rx)
        if not self.clock.started:
            self.clock.start(now)  # the grid starts with the first complete telemetry
        if not self.clock.due(now):
            return ""
        self.clock.catch_up(now)
        return "grid"

    def done(self, kind: str, now: float) -> None:
        """The tick of ``kind`` is done (the grid moves to its next deadline, its phase toward the lock's)."""
        if kind == "grid":
            self.clock.advance(now)
            if self.lock is not None:
                self.clock.slew(self.lock.slew(self.clock.deadline, now))

    def timing(self, now: float, tel: TelemetryState) -> tuple[float, float, int]:
        """(age of the oldest stream's newest sample [s], control-clock time [s], samples new since the last
        tick): lock-step on the vehicle's stamps, else on the grid (uniform, no jitter)."""
        if self.lockstep:
            age, t = tel.newest_stamp() - tel.oldest_stamp(), tel.newest_stamp()
        else:
            age, t = now - tel.oldest_rx(), self.clock.time()
        n_new = max(tel.seq_total - self.seen_total, 0)
        self.seen_total = tel.seq_total
        return age, t, n_new

    def consumed(self, tel: TelemetryState) -> None:
        """The current samples are used (an event tick that sent nothing)."""
        self.last_seq = (tel.att.seq, tel.pos.seq)

    def gap(self, stamp: float, tel: TelemetryState) -> tuple[bool, int, bool]:
        """Lock-step only (stamps are the tick clock there): (a gap, ticks to bridge in the history, a hole
        too long to bridge or time went backwards: the history must be refilled)."""
        self.consumed(tel)
        step = stamp - self.last_stamp
        self.last_stamp = stamp
        if not (math.isfinite(step) and abs(step - self.period) > 0.4 * self.period):
            return False, 0, False
        self.gaps += 1
        r = step / self.period
        n = int(round(r)) - 1
        if 1 <= n <= self.max_gap_fill and abs(r - round(r)) < 0.4:
            return True, n, False  # a few samples lost: bridged once this tick's y is known
        return True, 0, True
