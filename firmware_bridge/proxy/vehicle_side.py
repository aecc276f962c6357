"""The proxy's vehicle side: one connection (the transports of :mod:`firmware_bridge.transports`),
reopened after a failure at most once per ``reconnect_interval``; a ``udpin:`` link pins the first
sender as the vehicle (another sender takes its place only after the pinned one has been silent for
``repin_after`` seconds: a restarted autopilot or SITL comes back from a new port); a byte stream is cut
into frames. Bytes are never changed here."""

from __future__ import annotations

import time
from typing import Any

from firmware_bridge.proxy.app_side import deep_receive_buffer
from firmware_bridge.proxy.frames import split_frames
from firmware_bridge.transports import LinkError, open_transport, parse_url

__all__ = ["VehicleSide", "Chunk"]

# ((datagram to forward, frames in it) ..., the frames' (start, length) in buf, buf, garbage bytes,
#  receive time [s, time.time()])
Chunk = tuple[list[tuple[bytes, int]], list[tuple[int, int]], bytes, int, float]


class VehicleSide:
    """The vehicle connection (see the module docstring).

    Args:
        url: ``udpin:``/``udpout:``/``tcp:`` or a serial device; baud: a serial device's rate.
        reconnect_interval: seconds between attempts to reopen a failed link.
        repin_after: a udpin link accepts a new vehicle address after this much silence of the old one [s].
    """

    def __init__(self, url: str, baud: int | None = None, reconnect_interval: float = 1.0,
                 repin_after: float = 5.0) -> None:
        self.endpoint = parse_url(url, baud)
        self.reconnect_interval, self.repin_after = reconnect_interval, repin_after
        self.transport: Any = None
        self.peer: Any = None  # a udpin link's vehicle address, once heard
        self.last_error = ""
        self.counts = dict.fromkeys(("foreign", "peer_changes", "link_errors", "reconnects"), 0)
        self._heard = 0.0  # when the pinned peer was last heard (monotonic)
        self._buf = bytearray()  # a byte stream's partial frame
        self._next_open = 0.0
        self._open(time.monotonic())

    @property
    def datagram(self) -> bool:
        """Whether the link carries datagrams (else a byte stream); True while it is down."""
        return self.transport is None or bool(self.transport.datagram)

    @property
    def ready(self) -> bool:
        """Whether a write can reach the vehicle (open, and a udpin link has heard it)."""
        t = self.transport
        return t is not None and not (t.datagram and t.peer is None)

    def fileno(self) -> int | None:
        return None if self.transport is None else self.transport.fileno()

    def maintain(self, now: float) -> None:
        """Reopen a failed link when its interval has passed."""
        if self.transport is None and now >= self._next_open:
            self.counts["reconnects"] += 1
            self._open(now)

    def _open(self, now: float) -> None:
        try:
            self.transport = open_transport(self.endpoint)
        except (OSError, LinkError) as e:
            if self.endpoint.kind == "udpin":
                raise  # a port we cannot bind is a configuration error, not a link drop
            self._down(str(e), now)
            return
        deep_receive_buffer(getattr(self.transport, "sock", None))
        self._buf.clear()

    def _down(self, why: str, now: float) -> None:
        self.counts["link_errors"] += 1
        self.last_error = why
        if self.transport is not None:
            try:
                self.transport.close()
            except OSError:
                pass
        self.transport, self._next_open = None, now + self.reconnect_interval

    def write(self, buf: bytes) -> bool:
        """Send ``buf`` (a datagram, or whole frames into a stream); False if it did not go out."""
        t = self.transport
        if t is None:
            return False
        try:
            return t.write(buf)
        except LinkError as e:
            self._down(str(e), time.monotonic())
            return False

    def read(self) -> list[Chunk]:
        """Everything pending, located into frames: a datagram is one chunk forwarded whole; a stream
        read gives its complete frames, each to be forwarded as its own datagram."""
        t = self.transport
        try:
            reads = t.read() if t is not None else []
        except LinkError as e:
            self._down(str(e), time.monotonic())
            return []
        out: list[Chunk] = []
        now = time.monotonic()
        for data, addr, ts in reads:
            t_rx = ts if ts is not None else time.time()
            if t.datagram:
                if t.listen and addr != t.peer and not self._pin(t, addr, now):
                    self.counts["foreign"] += 1
                    continue
                self._heard = now
                spans, garbage, _ = split_frames(data)
                out.append(([(data, len(spans))], spans, data, garbage, t_rx))
            else:
                self._buf += data
                spans, garbage, used = split_frames(self._buf, final=False)
                buf = bytes(self._buf[:used])
                del self._buf[:used]
                out.append(([(buf[i:i + n], 1) for i, n in spans], spans, buf, garbage, t_rx))
        return out

    def _pin(self, t: Any, addr: Any, now: float) -> bool:
        """Whether ``addr`` (not the pinned peer) becomes the vehicle of a udpin link: the first sender, or a
        new one after the pinned one fell silent. (A udpout link's peer is fixed: the kernel filters.)"""
        if t.peer is not None:
            if now - self._heard < self.repin_after:
                return False
            self.counts["peer_changes"] += 1
        t.peer = self.peer = addr
        self._heard = now
        return True

    def close(self) -> None:
        if self.transport is not None:
            self.transport.close()
            self.transport = None
