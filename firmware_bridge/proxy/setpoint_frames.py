"""The frames of the app's position setpoints the proxy steers, and the offset that puts each into the vehicle's
local frame.

Steered: ``SET_POSITION_TARGET_LOCAL_NED`` in ``MAV_FRAME_LOCAL_NED`` (the height is ``-z``) and
``SET_POSITION_TARGET_GLOBAL_INT`` in ``MAV_FRAME_GLOBAL_RELATIVE_ALT(_INT)`` (``alt`` above home) or
``MAV_FRAME_GLOBAL(_INT)`` (``alt`` above mean sea level), the height not ignored by ``type_mask``. Any other frame
(terrain, body, offset frames) is never touched.

A global setpoint is steered in the local frame: its height there is ``alt`` minus the frame's offset (the vehicle's
height in the app's frame minus its local height), the steered local height goes back into ``alt`` plus the same
offset, and lat, lon and every other field stay the app's. Why this and not steering in the app's frame on
``GLOBAL_POSITION_INT``: everything else the steering holds stays in the one local frame -- the measured height,
its plausibility and freshness, the motion capture's offset (measured disarmed; above home it would jump when the
autopilot resets home at arming), the solver's bounds (an absolute-height solver's range excludes an altitude above
sea level) and the recorded datasets (a global app's flights fit the same solver as a local app's).

The offset comes from the vehicle's own reports: each ``GLOBAL_POSITION_INT`` (``relative_alt``, ``alt``) against
the ``LOCAL_POSITION_NED`` on the same time line (``time_boot_ms``; the local height advanced by its vertical
velocity to the global report's stamp). Both come from the one estimator, so their difference is the constant the
autopilot itself converts the app's ``alt`` with (home's or the origin's altitude), free of the estimator's drift.
It changes when home is reset (PX4 and ArduPilot set it at arming) or the origin moves: a sample off the running
median by more than ``tolerance`` starts it anew, and until ``agree`` samples agree (or when no global report came
for ``max_age``) the offset is unknown and the app's global setpoints go out unsteered.
"""

from __future__ import annotations

import math
from collections import deque

from firmware_bridge.proxy.rewrite import mavlink

__all__ = ["LOCAL", "RELATIVE_ALT", "AMSL", "steered_frame", "app_height", "height_fields", "FrameOffsets"]

LOCAL, RELATIVE_ALT, AMSL = "local", "relative_alt", "amsl"
_LOCAL_ID = mavlink.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED
_GLOBAL_ID = mavlink.MAVLINK_MSG_ID_SET_POSITION_TARGET_GLOBAL_INT
_FRAMES = {(_LOCAL_ID, mavlink.MAV_FRAME_LOCAL_NED): LOCAL,
           (_GLOBAL_ID, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT): RELATIVE_ALT,
           (_GLOBAL_ID, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT): RELATIVE_ALT,
           (_GLOBAL_ID, mavlink.MAV_FRAME_GLOBAL_INT): AMSL,
           (_GLOBAL_ID, mavlink.MAV_FRAME_GLOBAL): AMSL}
_Z_IGNORE = mavlink.POSITION_TARGET_TYPEMASK_Z_IGNORE  # the same bit ignores a global setpoint's alt
_MAX_SKEW_S = 0.1  # a global report further from the newest local one is not paired


def steered_frame(msg) -> str | None:
    """The steered frame of the app's setpoint ``msg`` (:data:`LOCAL`, :data:`RELATIVE_ALT`, :data:`AMSL`), or None:
    another frame, the height ignored by ``type_mask`` or not finite (never steered)."""
    kind = _FRAMES.get((msg.get_msgId(), int(msg.coordinate_frame)))
    if kind is None or int(msg.type_mask) & _Z_IGNORE or not math.isfinite(app_height(msg)):
        return None
    return kind


def app_height(msg) -> float:
    """The setpoint's height in its own frame, up [m]."""
    return float(msg.alt) if msg.get_msgId() == _GLOBAL_ID else -float(msg.z)


def height_fields(msg, height: float) -> dict[str, float]:
    """The fields that set ``msg``'s height to ``height`` [m, up, its own frame]."""
    return {"alt": height} if msg.get_msgId() == _GLOBAL_ID else {"z": -height}


class FrameOffsets:
    """Each global frame's height minus the local frame's, from the vehicle's reports (see the module docstring).

    Args:
        tolerance: a sample further than this from the running median starts it anew [m].
        agree: samples it takes to know the offset; window: the median's samples.
        max_age: no global report for this long: the offset is unknown [s].
    """

    def __init__(self, tolerance: float = 0.05, agree: int = 3, window: int = 15, max_age: float = 2.0) -> None:
        self.tolerance, self.agree, self.max_age = tolerance, agree, max_age
        self._samples = {RELATIVE_ALT: deque(maxlen=window), AMSL: deque(maxlen=window)}
        self._local: tuple[int, float, float] | None = None  # (time_boot_ms, height up [m], vertical speed up [m/s])
        self.arrivals: deque = deque(maxlen=20)  # the global reports' receive times [s]
        self.restarts = self.reports = 0

    def local(self, msg) -> None:
        """The vehicle's newest LOCAL_POSITION_NED."""
        self._local = (int(msg.time_boot_ms), -float(msg.z), -float(msg.vz))

    def global_position(self, msg, t_rx: float) -> None:
        """A GLOBAL_POSITION_INT of the vehicle, received at ``t_rx`` [s]: one sample per frame."""
        self.arrivals.append(t_rx)
        self.reports += 1
        if self._local is None:
            return
        t_l, h, vz = self._local
        skew = (int(msg.time_boot_ms) - t_l) * 1e-3
        if abs(skew) > _MAX_SKEW_S:
            return
        h += vz * skew
        for kind, height in ((RELATIVE_ALT, msg.relative_alt * 1e-3), (AMSL, msg.alt * 1e-3)):
            s = self._samples[kind]
            if s and abs(height - h - _median(s)) > self.tolerance:
                s.clear()
                self.restarts += 1
            s.append(height - h)

    def offset(self, kind: str, now: float) -> float:
        """The ``kind`` frame's height minus the local one [m] (0 for :data:`LOCAL`; nan: not known)."""
        if kind == LOCAL:
            return 0.0
        s = self._samples[kind]
        if len(s) < self.agree or not self.arrivals or now - self.arrivals[-1] > self.max_age:
            return math.nan
        return _median(s)

    def period(self) -> float:
        """The mean gap of the global reports' arrivals [s] (inf before two)."""
        a = self.arrivals
        return (a[-1] - a[0]) / (len(a) - 1) if len(a) > 1 else math.inf

    def summary(self, now: float) -> dict:
        """The offsets now [m] (None: unknown) and how often one started anew (JSON-ready)."""
        out = {}
        for kind in (RELATIVE_ALT, AMSL):
            v = self.offset(kind, now)
            out[f"{kind}_m"] = None if math.isnan(v) else v
        return {**out, "restarts": self.restarts, "reports": self.reports}


def _median(s) -> float:
    v = sorted(s)
    return float(v[len(v) // 2])
