"""The app's setpoint stream as the steering's nominal reference and its preview.

An app streams only the present; the steering wants the desired height over its horizon. Two ways:

* :class:`LocalPreview` (no delay): the setpoint now is the nominal reference; ahead, the height goes on
  along the setpoint's own velocity and acceleration fields when the app fills them (``type_mask``), else
  along the slope of its last setpoints, for at most ``reach`` seconds (then held): a guess, right on
  straight stretches, late in turns.
* :class:`DelayedPreview` (``--preview-delay S``): the vehicle is sent the app's stream ``S`` seconds late,
  and the ``S`` seconds the proxy holds are a true preview. The setpoint sent at a tick is the one the app
  sent ``S`` before (all of its fields: position, velocity, yaw stay consistent with each other); beyond
  what arrived, the newest is held. Only ever a setpoint the app sent: when the app stops, so does the
  stream (the tick is the app's own next setpoint).

A third, :class:`.file_preview.FilePreview` (``--preview-file FILE``), matches the app's path given ahead as a
trajectory file to the stream. Each preview has ``push`` / ``current`` / ``desired`` / ``reset``, ``delay``, and
``bind`` (the steering's event log) / ``summary`` (JSON-ready).

Heights are up (the setpoints' LOCAL_NED ``-z``, or the height the caller gives: a global setpoint's ``alt``) [m];
times on the ``time.time()`` clock [s].
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from firmware_bridge.proxy.rewrite import mavlink

__all__ = ["LocalPreview", "DelayedPreview", "make_preview"]

_VZ_IGNORE = mavlink.POSITION_TARGET_TYPEMASK_VZ_IGNORE
_AZ_IGNORE = mavlink.POSITION_TARGET_TYPEMASK_AZ_IGNORE


def _height(msg) -> float:
    return -float(msg.z)


class LocalPreview:
    """Nominal reference = the app's setpoint now; the preview extrapolated (see the module docstring).

    Args:
        reach: extrapolate at most this far ahead [s] (then hold).
    """

    delay = 0.0

    def __init__(self, reach: float = 0.5) -> None:
        self.reach = reach
        self._prev: tuple[float, float] | None = None  # (t, height) of the previous setpoint
        self._slope = 0.0
        self.msg = None
        self._h = 0.0
        self._v = self._a = 0.0

    def push(self, t: float, msg, height: float | None = None) -> None:
        """The app's setpoint ``msg`` arrived at ``t`` (``height``: its height [m, up], when not LOCAL_NED's ``-z``)."""
        h = _height(msg) if height is None else height
        if self._prev is not None and t > self._prev[0]:
            self._slope = (h - self._prev[1]) / (t - self._prev[0])
        self._prev = (t, h)
        self.msg, self._h = msg, h
        mask = int(msg.type_mask)
        self._v = -float(msg.vz) if not mask & _VZ_IGNORE and math.isfinite(msg.vz) else self._slope
        self._a = -float(msg.afz) if not mask & _AZ_IGNORE and math.isfinite(msg.afz) else 0.0

    def current(self, t: float):
        """The setpoint to steer at ``t`` (the newest)."""
        return self.msg

    @property
    def height(self) -> float:
        """The newest setpoint's height [m, up]."""
        return self._h

    def desired(self, ahead: np.ndarray) -> np.ndarray:
        """(len(ahead), 1) desired heights at the offsets ``ahead`` [s] from the current setpoint."""
        tau = np.minimum(np.asarray(ahead, dtype=float), self.reach)
        return (self._h + self._v * tau + 0.5 * self._a * tau * tau)[:, None]

    def reset(self) -> None:
        self._prev, self._slope = None, 0.0

    def bind(self, events) -> None:
        """Nothing to say (:class:`.file_preview.FilePreview` says its locks)."""

    def catch_up(self) -> None:
        """Nothing left for after the send (:class:`.file_preview.FilePreview` matches its file then)."""

    def summary(self) -> dict:
        return {"kind": "local", "reach_s": self.reach}


class DelayedPreview:
    """The app's stream played ``delay`` seconds late, the held part its preview (see the module docstring)."""

    def __init__(self, delay: float, max_buffer: int = 1 << 14) -> None:
        if not delay > 0:
            raise ValueError(f"--preview-delay must be > 0 s; got {delay}")
        self.delay = delay
        self._buf: deque = deque(maxlen=max_buffer)  # (t, height, msg), oldest first
        self._t0 = 0.0  # the current setpoint's arrival time

    def push(self, t: float, msg, height: float | None = None) -> None:
        self._buf.append((t, _height(msg) if height is None else height, msg))

    def current(self, t: float):
        """The setpoint the app sent ``delay`` before ``t`` (the oldest held while the stream is younger)."""
        buf, cut = self._buf, t - self.delay + 1e-6  # (a setpoint exactly S old is due)
        while len(buf) > 1 and buf[1][0] <= cut:
            buf.popleft()
        self._t0 = buf[0][0]
        return buf[0][2]

    def desired(self, ahead: np.ndarray) -> np.ndarray:
        """(len(ahead), 1) the app's heights at the current setpoint's time + ``ahead`` [s] (held past the newest)."""
        ts = np.fromiter((b[0] for b in self._buf), float, len(self._buf))
        hs = np.fromiter((b[1] for b in self._buf), float, len(self._buf))
        return np.interp(self._t0 + np.asarray(ahead, dtype=float), ts, hs)[:, None]

    def reset(self) -> None:
        """Nothing to forget: the held stream stays the app's."""

    def bind(self, events) -> None:
        """Nothing to say."""

    def catch_up(self) -> None:
        """Nothing left for after the send."""

    def summary(self) -> dict:
        return {"kind": "delay", "delay_s": self.delay}


def make_preview(delay: float) -> LocalPreview | DelayedPreview:
    """The preview of ``--preview-delay`` (0: local)."""
    return DelayedPreview(delay) if delay > 0 else LocalPreview()
