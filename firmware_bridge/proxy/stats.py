"""The proxy's measurements: message counters per direction, the added latency of every forwarded
datagram / frame (receive stamp to send return) in a bounded ring, and the app's setpoint period.
Recording is an index store into preallocated arrays; statistics are computed only when asked."""

from __future__ import annotations

from array import array

import numpy as np

__all__ = ["COUNTERS", "Ring", "DirectionStats", "SetpointPeriod"]

_STX_V2 = 0xFD

COUNTERS = ("datagrams", "received", "forwarded", "rewritten", "dropped", "garbage_bytes", "send_errors", "seq_gaps")


class Ring:
    """The last ``size`` values (float), oldest overwritten first."""

    def __init__(self, size: int = 1 << 16) -> None:
        self._v = array("d", bytes(8 * size))
        self._size = size
        self.count = 0  # values ever added

    def add(self, v: float) -> None:
        self._v[self.count % self._size] = v
        self.count += 1

    def values(self) -> np.ndarray:
        """The kept values, oldest first."""
        v = np.frombuffer(self._v, dtype=np.float64)
        if self.count <= self._size:
            return v[:self.count].copy()
        k = self.count % self._size
        return np.concatenate((v[k:], v[:k]))

    def summary(self, scale: float = 1.0) -> dict:
        """count, p50, p99, max of the kept values times ``scale`` (None when empty)."""
        v = self.values() * scale
        if v.size == 0:
            return {"count": self.count, "p50": None, "p99": None, "max": None}
        p50, p99 = np.percentile(v, [50, 99])
        return {"count": self.count, "kept": int(v.size), "p50": float(p50), "p99": float(p99), "max": float(v.max())}


class DirectionStats:
    """Counters of one direction (app -> vehicle or vehicle -> apps) and its added latency.

    ``received``/``forwarded``/``rewritten``/``dropped`` count MAVLink frames (a datagram may hold
    several); ``forwarded`` counts each frame once per destination it was handed to; ``datagrams``
    counts what was read (datagrams, or stream reads); ``garbage_bytes`` the bytes that were not part
    of a valid frame; ``seq_gaps`` the frames whose sequence number does not follow the previous one
    of the same (system, component) as received: loss or reordering before the proxy.
    """

    def __init__(self, ring_size: int = 1 << 16) -> None:
        self.c = dict.fromkeys(COUNTERS, 0)
        self.latency = Ring(ring_size)  # seconds
        self._last_seq: dict[int, int] = {}  # sysid << 8 | compid -> last sequence number

    def see(self, buf: bytes | bytearray, i: int) -> None:
        """Check the sequence number of the frame at ``buf[i]`` against its sender's previous one."""
        o = i + 2 if buf[i] == _STX_V2 else i  # v2 has two flag bytes before seq
        key, seq = buf[o + 3] << 8 | buf[o + 4], buf[o + 2]
        last = self._last_seq.get(key)
        if last is not None and seq != (last + 1) & 0xFF:
            self.c["seq_gaps"] += 1
        self._last_seq[key] = seq

    def summary(self) -> dict:
        return {**self.c, "latency_us": self.latency.summary(1e6)}


class SetpointPeriod:
    """Arrival times of the app's setpoints: the period it streams at (median, max gap) and when the
    last one came, so that a steering can stop when the stream misses its own period."""

    def __init__(self, ring_size: int = 4096) -> None:
        self.gaps = Ring(ring_size)  # seconds between consecutive setpoints
        self.last: float | None = None  # arrival of the last one [s, time.time()]
        self.count = 0

    def add(self, t: float) -> None:
        if self.last is not None:
            self.gaps.add(t - self.last)
        self.last = t
        self.count += 1

    def period(self) -> float | None:
        """The median gap of the kept arrivals [s] (None before two setpoints): numpy's median, in plain Python (a
        tick asks for it; a sort of the few kept values costs less than numpy's call)."""
        g = self.gaps
        v = sorted(g._v[:g.count] if g.count <= g._size else g._v)
        n = len(v)
        if not n:
            return None
        return v[n // 2] if n % 2 else (v[n // 2 - 1] + v[n // 2]) / 2

    def summary(self) -> dict:
        v = self.gaps.values()
        return {"count": self.count, "period_s": float(np.median(v)) if v.size else None,
                "max_gap_s": float(v.max()) if v.size else None}
