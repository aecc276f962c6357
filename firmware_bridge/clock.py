"""The bridge's own control clock: ticks on a uniform grid, whatever the telemetry does.

Real autopilots do not deliver telemetry on the control period: PX4 SIH stamps step 4/8/12 ms
(about 125 distinct samples per second when 200 Hz is requested), ArduCopter over TCP delivers
200 Hz in bursts of two. A loop that waits for "every stream advanced by one period" never gets
going there. Like the paper's 200 Hz ROS loop, the bridge ticks at ``t0 + k * period`` on its
monotonic clock and each tick uses the newest telemetry with its age (zero-order hold, see
:class:`firmware_bridge.telemetry.TelemetryState`), so the closed loop the predictor learns from
the tick log contains the telemetry delay it will see when steering.

An overrun longer than one period (the process was not scheduled) skips grid points instead of
firing a burst of catch-up ticks: the skipped ones are counted, the grid phase is kept.
"""

from __future__ import annotations

import math

__all__ = ["TickClock"]


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
