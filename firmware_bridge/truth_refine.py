"""A SITL's ground truth made finer than its messages carry it: below the grid each message reports the position on
(:class:`Dequantizer`), and on the sender's clock rather than its arrival (:class:`LinkClock`).

Used wherever the truth is read: the bridge's tick log (:class:`.truth.SimTruth`), the test bed's motion-capture
stand-in and its SITL observer (:mod:`ddpc_codegen.testbed`), so that every figure judged on the true height reads
the same truth.

* The grid: ArduPilot's SIM_STATE carries its simulator's Location, the altitude in whole centimetres (truncated:
  the truth is in [q, q + 1 cm)) and latitude / longitude in 1e-7 deg; PX4's HIL_STATE_QUATERNION its altitude in
  whole millimetres (truncated) and latitude / longitude in 1e-7 deg. The velocities are exact (ArduPilot: float
  m/s) or on a 1 cm/s grid (PX4). On the raw centimetres a moving flight's height carries the grid's error and a
  hover up to a centimetre of offset that neither estimate nor steering has.
* The clock: ArduCopter sends the truth in bursts (TCP), some loops late: stamped on arrival a moving truth is off
  by its speed times that, and a velocity integral over arrival gaps breaks the Dequantizer's cells. A message
  with the autopilot's time, asked at the truth's rate, leaves in the same loop and arrives beside it: the truth
  takes that time. PX4 SIH sends no such pair (its truth leaves apart from its telemetry).
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any

__all__ = ["Dequantizer", "LinkClock", "TRUTH_GRID", "DEG7_M", "EARTH_RADIUS_M"]

# The altitude grid [m] of each truth message (truncated down: the true altitude lies in [q, q + grid)).
TRUTH_GRID = {"SIM_STATE": 0.01, "HIL_STATE_QUATERNION": 0.001}
EARTH_RADIUS_M = 6378137.0  # WGS-84 equatorial radius (what ArduPilot's flat-earth offsets use)
DEG7_M = math.radians(1e-7) * EARTH_RADIUS_M  # 1e-7 deg of latitude [m] (the latitude / longitude grid)


class Dequantizer:
    """One coordinate reported on a grid, made finer with its rate: the integral of the rate since the
    first sample, plus the offset that keeps it inside every grid cell seen (the intersection of the cells,
    widened by ``drift`` [m/s] for the integral's own error). A vehicle standing still gets the middle of its
    cell; one that moves across cell edges gets them as bounds (a hover's millimetres of motion cross them).

    Args:
        step: the grid [m]; cell: the true value's interval around a reported q, as multiples of ``step``
            ((0, 1): truncated down; (-1, 1): the rounding unknown).
    """

    def __init__(self, step: float, cell: tuple[float, float] = (0.0, 1.0), drift: float = 0.001):
        self.step, self.cell, self.drift = step, cell, drift
        self._t = self._v = math.nan
        self._integral = 0.0
        self._lo, self._hi = -math.inf, math.inf

    def update(self, q: float, rate: float, t: float) -> float:
        """Fold in the reported value ``q`` [m] and rate [m/s] at ``t`` [s]; the refined value [m]."""
        if math.isfinite(self._t):
            dt = max(0.0, t - self._t)
            self._integral += 0.5 * (self._v + rate) * dt
            self._lo, self._hi = self._lo - self.drift * dt, self._hi + self.drift * dt
        self._t, self._v = t, rate
        a = q + self.cell[0] * self.step - self._integral
        b = q + self.cell[1] * self.step - self._integral
        lo, hi = max(self._lo, a), min(self._hi, b)
        if lo > hi:  # the integral drifted out of the cells (or the position was reset): start again here
            lo, hi = a, b
        self._lo, self._hi = lo, hi
        return self._integral + 0.5 * (lo + hi)


class LinkClock:
    """A link's truth samples stamped with the sender's clock. Each one is matched, first come first matched, with a
    message carrying the sender's ``time_boot_ms`` that arrived within ``pair_s`` of it, before or after (the two
    leave the sender's same loop, in either order), and takes that time, mapped onto the receiver's clock by the
    smallest arrival - boot offset of the last ``window_s`` (the link's quickest transit; the window follows a SITL
    clock that slips behind). A truth sample with no partner keeps its arrival time.

    Feed every message in arrival order: :meth:`stamped` (the partner) and :meth:`truth`, or either through
    :meth:`place`; each returns the truth samples now placed, as (message, time [s, the receiver's clock]) in
    arrival order."""

    def __init__(self, pair_s: float = 0.002, window_s: float = 2.0) -> None:
        self.pair_s, self.window_s = pair_s, window_s
        self._offsets: deque[tuple[float, float]] = deque()  # (rx, rx - boot), offsets increasing: a running min
        self._stamps: deque[tuple[float, float]] = deque()   # (rx, boot) not matched yet
        self._truth: deque[tuple[Any, float]] = deque()      # (message, rx) not matched yet
        self.paired = self.unpaired = 0

    def _expire(self, rx: float) -> list[tuple[Any, float]]:
        while self._stamps and rx - self._stamps[0][0] > self.pair_s:
            self._stamps.popleft()
        out = []
        while self._truth and rx - self._truth[0][1] > self.pair_s:  # no partner came: its arrival time
            self.unpaired += 1
            out.append(self._truth.popleft())
        return out

    def at(self, boot_s: float) -> float:
        """The sender's time ``boot_s`` [s] on the receiver's clock [s] (after a :meth:`stamped`)."""
        return boot_s + self._offsets[0][1]

    def stamped(self, boot_s: float, rx: float) -> list[tuple[Any, float]]:
        """A message with the sender's time ``boot_s`` [s] arrived at ``rx`` [s]."""
        off = rx - boot_s
        while self._offsets and self._offsets[-1][1] >= off:
            self._offsets.pop()
        self._offsets.append((rx, off))
        while self._offsets[0][0] < rx - self.window_s:
            self._offsets.popleft()
        out = self._expire(rx)
        if self._truth:
            self.paired += 1
            out.append((self._truth.popleft()[0], self.at(boot_s)))
        else:
            self._stamps.append((rx, boot_s))
        return out

    def truth(self, msg: Any, rx: float) -> list[tuple[Any, float]]:
        """A truth sample arrived at ``rx`` [s]: placed now if its partner came first, else when it comes."""
        out = self._expire(rx)
        if self._stamps:
            self.paired += 1
            out.append((msg, self.at(self._stamps.popleft()[1])))
        else:
            self._truth.append((msg, rx))
        return out

    def place(self, msg: Any, rx: float, partner: str) -> list[tuple[Any, float]]:
        """A MAVLink message arrived at ``rx`` [s]: the ``partner`` type (its ``time_boot_ms`` stamps), else truth."""
        if msg.get_type() == partner:
            return self.stamped(msg.time_boot_ms * 1e-3, rx)
        return self.truth(msg, rx)
