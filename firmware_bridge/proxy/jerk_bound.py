"""An autopilot's vertical jerk limit and the app's setpoints (``--max-jerk J``): pause the steering around the jumps
the autopilot shapes, and with a true preview spread them to the limit.

ArduCopter's guided mode does not fly a position + velocity + acceleration setpoint as sent: its position controller
moves its own target towards the setpoint's kinematics with the vertical jerk limited (``PSC_JERK_Z``, 5 m/s^3 by
default; ``AC_PosControl::input_pos_vel_accel_U_cm``). An app whose acceleration field jumps (a ramp that starts at
once) is followed late, then overshoots, and by more than in proportion to the jump. That loop is not the linear one
the steering's predictor was fitted on: steered there, the offsets add to the swing.

:class:`JerkBound` does two things with the app's stream:

* **The guard** (always): a jump of the app's ``afz`` between two of its setpoints that the autopilot needs longer
  than :data:`SHAPED_S` to make (a change over ``J * SHAPED_S``) pauses the steering, from the time that jump is
  known before it is sent (the preview's delay; at once without one) until :attr:`JerkBound.hold` after it was sent
  (the loop's settling). The app's own setpoints go out meanwhile, the offset fading out as after any fallback.
* **The spread** (with ``--preview-delay S``): the proxy holds the app's acceleration up to ``S`` ahead, so it spreads
  each jump over the time the limit needs, centred on it. Each delayed setpoint's ``vz`` / ``afz`` become the app's
  own averaged over a window centred on it, as wide as the largest change of ``afz`` between two setpoints within
  the preview needs (that change / ``FILL`` of J, the rest of J left to the path's own smooth jerk), at most twice
  the preview (then counted as ``short``). Where the app's acceleration has no jump, the window holds one setpoint
  and the fields stay the app's. The height stays the app's (the steering adds its offset to it).

Times on the proxy's ``time.time()`` clock [s]; ``vz`` [m/s] and ``afz`` [m/s^2] in the setpoint's NED sense.
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from firmware_bridge.proxy.rewrite import mavlink

__all__ = ["JerkBound", "FILL", "SHAPED_S"]

_VZ_IGNORE = mavlink.POSITION_TARGET_TYPEMASK_VZ_IGNORE
_AZ_IGNORE = mavlink.POSITION_TARGET_TYPEMASK_AZ_IGNORE
FILL = 0.8  # the share of the jerk limit a spread jump may use
SHAPED_S = 0.1  # s: a jump the autopilot needs longer than this to make puts the loop outside its linear range


def _fields_ok(msg) -> bool:
    return not int(msg.type_mask) & (_VZ_IGNORE | _AZ_IGNORE) and math.isfinite(msg.vz) and math.isfinite(msg.afz)


class JerkBound:
    """The guard and the spread of the app's ``afz`` jumps (see the module docstring).

    Args:
        max_jerk: the autopilot's vertical jerk limit [m/s^3] (ArduCopter: ``PSC_JERK_Z``).
        preview: how far ahead of the sent setpoint the app's stream is held [s] (the preview's delay; 0: none,
            no spread).
        hold: the steering stays paused this long after a jump was sent [s] (the loop's settling).
    """

    def __init__(self, max_jerk: float, preview: float = 0.0, hold: float = 2.0, max_buffer: int = 1 << 14) -> None:
        if not (0.0 < max_jerk < math.inf):
            raise ValueError(f"--max-jerk must be a finite number of m/s^3 > 0; got {max_jerk}")
        if not (0.0 <= preview < math.inf and 0.0 <= hold < math.inf):
            raise ValueError(f"the preview and the hold must be finite times >= 0 s; got {preview}, {hold}")
        self.max_jerk, self.preview, self.hold = float(max_jerk), float(preview), float(hold)
        self._buf: deque = deque(maxlen=max_buffer)  # (t, vz, afz, msg) with usable fields, oldest first
        self._jumps: deque = deque(maxlen=256)  # arrival times of the setpoints that jump
        self._last: tuple[float, float] | None = None  # (t, afz) of the previous usable setpoint
        self.counts = {"jumps": 0, "paused": 0, "smoothed": 0, "short": 0}

    def push(self, t: float, msg) -> None:
        """The app's setpoint ``msg`` arrived at ``t`` [s] (every one, in order)."""
        if not _fields_ok(msg):
            self._last = None
            return
        a = float(msg.afz)
        if self._last is not None and abs(a - self._last[1]) > self.max_jerk * SHAPED_S:
            self._jumps.append(t)
            self.counts["jumps"] += 1
        self._last = (t, a)
        if self.preview > 0:
            self._buf.append((t, float(msg.vz), a, msg))
            while len(self._buf) > 2 and self._buf[0][0] < t - 3.0 * self.preview:
                self._buf.popleft()

    def paused(self, t_sent: float) -> bool:
        """Whether the steering pauses for the setpoint that arrived at ``t_sent`` [s] and goes out now."""
        lo, hi = t_sent - self.hold, t_sent + self.preview + 1e-6
        out = any(lo <= j <= hi for j in self._jumps)
        self.counts["paused"] += out
        return out

    def fields(self, msg) -> dict:
        """``{"vz": ..., "afz": ...}`` [m/s, m/s^2] to send with the held setpoint ``msg`` (pushed earlier), or {}
        when there is no preview, ``msg`` ignores them, is no longer held or has no jump to spread."""
        if self.preview <= 0 or not _fields_ok(msg):
            return {}
        t0 = next((row[0] for row in self._buf if row[3] is msg), None)
        if t0 is None:
            return {}
        rows = np.array([row[:3] for row in self._buf if t0 - self.preview <= row[0] <= t0 + self.preview])
        ts, vz, az = rows[:, 0], rows[:, 1], rows[:, 2]
        if ts.size < 2:
            return {}
        width = float(np.max(np.abs(np.diff(az)))) / (FILL * self.max_jerk)
        if width > 2.0 * self.preview:
            width = 2.0 * self.preview
            self.counts["short"] += 1
        period = float(np.median(np.diff(ts)))  # each setpoint stands for one period of the app's stream
        inside = np.abs(ts - t0) <= 0.5 * (width + period)
        if np.count_nonzero(inside) < 2:
            return {}
        self.counts["smoothed"] += 1
        return {"vz": float(np.mean(vz[inside])), "afz": float(np.mean(az[inside]))}

    def summary(self) -> dict:
        """The limit, the preview, the hold and the counts (JSON-ready)."""
        return {"max_jerk": self.max_jerk, "preview_s": self.preview, "hold_s": self.hold, **self.counts}
