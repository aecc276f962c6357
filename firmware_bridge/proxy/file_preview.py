"""``--preview-file FILE``: the app's path given ahead as a trajectory file, matched to its setpoint stream.

No delay: the setpoint steered at a tick is the app's newest (as :class:`.preview.LocalPreview`). The file
(:func:`ddpc_codegen.robot.trajectory_files.load_trajectory`: ``t`` [s] and ``z`` [m, up]; x, y and the rest are
not used) gives the future: the stream is matched to it on the height, the steered axis. The app may fly the file's
path from any start height and start it at any moment, so the match tracks two numbers:

* ``s``: the file time [s] of the newest setpoint. It advances with the setpoints' arrival times (the proxy's
  ``time.time()`` clock [s]) and is corrected every :attr:`FilePreview.every` seconds from the recent stream: a
  least-squares match of the last :attr:`FilePreview.window` seconds of (arrival time, height) against the file over
  candidate ``s`` near the estimate (and, before the lock, over the whole file). A correction needs an informative
  window (the height changes in it by more than ``min_change``): during a hold the clock alone carries ``s``, so a
  hold does not make it wander.
* ``c``: the constant height offset [m] of the stream above the file (the app's start height, its frame's offset).

``desired(ahead) = z_file(s + ahead) + c`` (the file's first point held before it, its last after it), heights in the
app's frame as the stream's (the steering subtracts the frame's offset, as for the other previews).

Lock: the best match of the last ``lock_window`` seconds (longer than ``window``: a short stretch of a smooth
path looks like many stretches of another) over the whole file, its residual RMS within ``_LOCK`` ``tolerance`` and
within ``sharpness`` of the window's own spread (a small wiggle matches too much of any path to lock on), and every
other match predicting the same next ``horizon`` seconds (a path that repeats itself locks; one whose windows look
alike with different futures waits for a window that tells them apart). Loss of lock: the window's RMS over
``tolerance`` at a correction, or the newest setpoint more than twice ``tolerance`` off the file's height at ``s``
(checked every tick).

The match runs after the tick's send (:meth:`FilePreview.catch_up`; the next tick uses it), and its cost stays
bounded: a match uses at most ``_MAX_POINTS`` of the window's setpoints, and the whole file is scanned ``_CHUNK``
candidates a tick.

Fallback: a tick without the lock (before the first, after a loss, a frame change: :meth:`FilePreview.reset`) takes
the local preview's guess (:class:`.preview.LocalPreview`) and counts as ``fallback``, a locked one as ``matched``
(:meth:`FilePreview.summary`); each lock and loss is an event. A file that never matches the stream never steers.
"""

from __future__ import annotations

from collections import deque
from pathlib import Path
from typing import Callable

import numpy as np

from ddpc_codegen.robot.trajectory_files import load_trajectory
from firmware_bridge.proxy.preview import LocalPreview

__all__ = ["FilePreview"]

_FINE, _MID = 0.005, 0.02  # s: a match's fine and coarse steps (the fine one refined by a parabola)
_COARSE = 0.05  # s: the whole file's scan step
_CHUNK = 150  # candidates of the whole file's scan a tick (the tick's cost stays bounded on a long file)
_CANDIDATES = 8  # the scan's best local minima refined (and checked to agree on the future)
_LOCK = 0.4  # a lock's RMS: at most this fraction of the tolerance (a match tighter than the one that keeps it)
_MAX_POINTS = 40  # the window's setpoints used in a match (evenly thinned: the cost of a match is bounded)


class FilePreview:
    """The preview of a trajectory file matched to the app's stream (see the module docstring).

    Args:
        trajectory: the file's trajectory: anything with ``sample(t) -> {"z": ...}`` and ``time_span()`` (file
            time [s]).
        source: the file's name for the summary and events.
        window: the recent stream matched to the file [s]; lock_window: the longer one a lock needs [s].
        every: the correction's period [s] (locked; a search for the lock runs at most every ``5 * every``).
        tolerance: the window's residual RMS that still matches [m]; min_change: an informative window's height
            range [m].
        sharpness: to lock, the RMS must also be under this fraction of the window's standard deviation.
        search: the correction's reach around the clock's estimate of ``s`` [s]; horizon: the future two matches
            must agree on for a lock [s]; step: the file's sampling for the match [s].
        reach: the local preview's reach [s] (the fallback).
    """

    delay = 0.0

    def __init__(self, trajectory, source: str = "<trajectory>", *, window: float = 2.5, lock_window: float = 5.0,
                 every: float = 0.1, tolerance: float = 0.025, min_change: float = 0.05, sharpness: float = 0.05,
                 search: float = 0.3, horizon: float = 2.0, step: float = 0.01, reach: float = 0.5) -> None:
        if not (0 < window <= lock_window and every > 0 and tolerance > 0 and min_change >= 0 and search > 0
                and step > 0):
            raise ValueError("FilePreview needs 0 < window <= lock_window; every, tolerance, search and step > 0; "
                             "min_change >= 0")
        self.source, self.window, self.lock_window, self.every = source, window, lock_window, every
        self.tolerance = tolerance
        self.min_change, self.sharpness, self.search, self.horizon = min_change, sharpness, search, horizon
        t0, t1 = trajectory.time_span()
        n = int(np.ceil((t1 - t0) / step)) + 1
        self._gs = t0 + step * np.arange(max(n, 2))  # the file sampled every ``step`` (its ends held)
        self._gz = np.asarray(trajectory.sample(self._gs)["z"], dtype=float)
        self._dz, self._step = np.r_[np.diff(self._gz), 0.0], step
        self.local = LocalPreview(reach)
        self.events: Callable[[str], None] = lambda what: None  # the steering's event log (:meth:`bind`)
        self._buf: deque = deque()  # (t, height) of the recent stream, oldest first
        self.locked = False
        self._s_ref = self._t_ref = 0.0  # file time ``s_ref`` at arrival time ``t_ref`` [s]
        self.offset = 0.0  # c [m]
        self.rms = float("nan")  # the last match's residual RMS [m]
        self._t = 0.0  # the newest setpoint's arrival [s]
        self._next = -np.inf  # the next correction or search [s]
        self._scan: tuple | None = None  # the whole file's scan under way: (its start [s], candidates, RMS, next)
        self.counts = dict.fromkeys(("matched", "fallback", "locks", "losses", "ambiguous"), 0)

    @classmethod
    def from_file(cls, path: str | Path, **kw) -> "FilePreview":
        """The preview of the ``.csv`` / ``.toml`` trajectory file ``path`` (ConfigError naming a bad one)."""
        return cls(load_trajectory(path), source=str(path), **kw)

    def bind(self, events: Callable[[str], None]) -> None:
        """Say the locks and losses in ``events`` (the steering's log)."""
        self.events = events

    # ------------------------------------------------------------------ the preview's interface
    def push(self, t: float, msg, height: float | None = None) -> None:
        """The app's setpoint ``msg`` arrived at ``t`` [s] (``height`` [m, up] when not LOCAL_NED's ``-z``)."""
        self.local.push(t, msg, height)
        h, self._t = self.local.height, t
        buf = self._buf
        buf.append((t, h))
        while buf[0][0] < t - self.lock_window:
            buf.popleft()
        off = abs(h - self._file(self.s(t)) - self.offset) if self.locked else 0.0
        if off > 2 * self.tolerance:
            self._lose(f"the newest setpoint is {off * 1e3:.0f} mm off it")
        self.counts["matched" if self.locked else "fallback"] += 1

    def catch_up(self) -> None:
        """The match's due work on the newest setpoint (a correction, or a part of the search for the lock): after
        the tick's send, off the app's latency (:meth:`.steering.ProxySteering.settle`); the next tick uses it."""
        if self._t >= self._next and self.locked:
            self._correct(self._t)
        elif self._t >= self._next and self._buf:
            self._lock(self._t)

    def current(self, t: float):
        """The setpoint to steer at ``t`` (the newest)."""
        return self.local.current(t)

    def desired(self, ahead: np.ndarray) -> np.ndarray:
        """(len(ahead), 1) desired heights [m, up] at ``ahead`` [s] after the newest setpoint: the file's, locked;
        the local preview's guess otherwise."""
        if not self.locked:
            return self.local.desired(ahead)
        return (self._file(self.s(self._t) + np.asarray(ahead, dtype=float)) + self.offset)[:, None]

    def reset(self) -> None:
        """The stream starts anew (another frame): the lock and the window are dropped."""
        self.local.reset()
        self._buf.clear()
        if self.locked:
            self._lose("the app's setpoints changed frame")
        self._scan, self._next = None, -np.inf

    def s(self, t: float) -> float:
        """The file time [s] at arrival time ``t`` [s] (the clock from the last match)."""
        return self._s_ref + (t - self._t_ref)

    def summary(self) -> dict:
        """The match's counts and state (JSON-ready)."""
        return {"kind": "file", "file": self.source, **self.counts, "locked": self.locked,
                "offset_m": self.offset if self.locked else None, "s": self.s(self._t) if self.locked else None,
                "rms_mm": None if not np.isfinite(self.rms) else self.rms * 1e3}

    # ------------------------------------------------------------------ the match
    def _file(self, s):
        """The file's height [m] at file times ``s`` (any shape; linear between its samples, its ends held)."""
        u = np.clip((np.asarray(s, dtype=float) - self._gs[0]) / self._step, 0.0, len(self._gz) - 1.000001)
        i = u.astype(np.intp)
        return self._gz[i] + (u - i) * self._dz[i]

    def _window(self, span: float) -> tuple[np.ndarray, np.ndarray] | None:
        """(arrival times relative to the newest (n,) [s], heights (n,) [m]) of the last ``span`` seconds of the
        stream when they are informative, else None."""
        if len(self._buf) < 3:
            return None
        w = np.asarray(self._buf)
        w = w[w[:, 0] >= self._t - span]
        if w[-1, 0] - w[0, 0] < 0.8 * span or np.ptp(w[:, 1]) <= self.min_change:
            return None
        w = w[np.linspace(0, len(w) - 1, min(len(w), _MAX_POINTS)).round().astype(int)]
        return w[:, 0] - self._t, w[:, 1]

    def _fit(self, cand: np.ndarray, tau: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(RMS (k,), offset c (k,)) of the window matched with its newest setpoint at the file times ``cand``."""
        r = h[None, :] - self._file(cand[:, None] + tau[None, :])
        c = r.mean(axis=1)
        return np.sqrt(np.mean((r - c[:, None]) ** 2, axis=1)), c

    def _refine(self, s0: float, tau: np.ndarray, h: np.ndarray, reach: float) -> tuple[float, float, float]:
        """(s, RMS, c) of the best match within ``reach`` [s] of ``s0``: a coarse pass, a fine one around its best,
        then a parabola through the fine pass's best three."""
        n = int(np.ceil(reach / _MID))
        rms, _ = self._fit(s0 + _MID * np.arange(-n, n + 1), tau, h)
        cand = s0 + _MID * (int(np.argmin(rms)) - n) + _FINE * np.arange(-_MID / _FINE, _MID / _FINE + 1)
        rms, _ = self._fit(cand, tau, h)
        k = int(np.clip(np.argmin(rms), 1, len(cand) - 2))
        e0, e1, e2 = rms[k - 1] ** 2, rms[k] ** 2, rms[k + 1] ** 2
        curv = e0 - 2 * e1 + e2
        s = float(np.clip(cand[k] + (0.5 * _FINE * (e0 - e2) / curv if curv > 0 else 0.0), cand[k - 1], cand[k + 1]))
        r, c = self._fit(np.array([s]), tau, h)
        return s, float(r[0]), float(c[0])

    def _correct(self, t: float) -> None:
        """Locked: keep ``s`` and ``c`` on the window (or lose the lock)."""
        self._next = t + self.every
        win = self._window(self.window)
        if win is None:  # a hold: the clock carries s; the window must still match where it is
            w = np.asarray(self._buf)
            w = w[w[:, 0] >= t - self.window]
            rms = float(np.sqrt(np.mean((w[:, 1] - self._file(self.s(t) + w[:, 0] - t) - self.offset) ** 2)))
        else:
            s, rms, c = self._refine(self.s(t), *win, self.search)
            if rms <= self.tolerance:
                self._s_ref, self._t_ref, self.offset = s, t, c
        self.rms = rms
        if rms > self.tolerance:
            self._lose(f"the window is {rms * 1e3:.0f} mm RMS off the file")

    def _lock(self, t: float) -> None:
        """Not locked: scan the whole file for the window, :data:`_CHUNK` candidates a tick (a candidate is a file time
        at the scan's start, moved on by the clock); at the scan's end, lock on a sharp, unambiguous match."""
        win = self._window(self.lock_window)
        if win is None:
            self._scan, self._next = None, t + self.every
            return
        tau, h = win
        if self._scan is None:
            cand = np.arange(self._gs[0], self._gs[-1] + _COARSE, _COARSE)
            self._scan = (t, cand, np.full(len(cand), np.inf), 0)
        t0, cand, rms, i = self._scan
        rms[i:i + _CHUNK] = self._fit(cand[i:i + _CHUNK] + (t - t0), tau, h)[0]
        self._scan = (t0, cand, rms, i + _CHUNK)
        if i + _CHUNK < len(cand):
            return  # (the next tick goes on)
        self._scan, self._next = None, t + 5 * self.every
        limit = min(_LOCK * self.tolerance, self.sharpness * float(np.std(h)))
        minima = np.flatnonzero(np.r_[True, rms[1:] <= rms[:-1]] & np.r_[rms[:-1] <= rms[1:], True])
        best_few = minima[np.argsort(rms[minima])[:_CANDIDATES]]  # (the coarse step misses a sharp minimum's depth)
        found = [f for f in (self._refine(float(cand[k] + t - t0), tau, h, _COARSE) for k in best_few) if f[1] <= limit]
        if not found:
            return
        best = min(found, key=lambda f: f[1])
        ahead = np.linspace(0.0, self.horizon, 21)
        future = self._file(best[0] + ahead) + best[2]
        if any(np.max(np.abs(self._file(f[0] + ahead) + f[2] - future)) > self.tolerance for f in found):
            self.counts["ambiguous"] += 1
            return
        self._s_ref, self._t_ref, self.offset, self.rms, self.locked = best[0], t, best[2], best[1], True
        self.counts["locks"] += 1
        self.events(f"the app's stream matches the trajectory file {self.source} at its t = {best[0]:.2f} s, "
                    f"{best[2]:+.3f} m above it ({best[1] * 1e3:.1f} mm RMS): the file previews the steering")

    def _lose(self, why: str) -> None:
        self.locked, self._scan = False, None
        self.counts["losses"] += 1
        self._next = -np.inf
        self.events(f"the app's stream left the trajectory file {self.source} ({why}): the local preview until it "
                    "matches again")
