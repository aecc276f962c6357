"""The proxy's app side: the endpoints where apps and ground stations connect, each with the same
small interface (descriptors to poll, what was read, send to one client).

- ``udpin:HOST:PORT``: a UDP server; each sender address is a client from its first datagram on, however long it
  is quiet afterwards (a ground station that only listens keeps the vehicle's stream, as on an autopilot's own
  port). Beyond :data:`MAX_UDP_CLIENTS` senders the one silent longest is dropped.
- ``udpout:HOST:PORT``: an app listening there (as PX4 sends to 14540); one fixed client.
- ``tcpin:HOST:PORT``: a TCP server; each connection is a client from accept to close. Its byte
  stream is cut into frames (garbage counted and left out), and only whole frames are written to it.
"""

from __future__ import annotations

import socket
import time
from collections import OrderedDict
from typing import Any

from firmware_bridge.proxy.frames import split_frames
from firmware_bridge.transports import UdpTransport, parse_url

__all__ = ["UdpApps", "TcpApps", "open_app_side", "deep_receive_buffer", "MAX_UDP_CLIENTS"]

# senders a udpin endpoint sends to at once: an app, ground stations, loggers; a port scan or a flood of spoofed
# sources cannot grow the fan-out of every vehicle message past it
MAX_UDP_CLIENTS = 16

_MAX_OUT = 1 << 16  # a TCP client this far behind misses messages rather than receiving them late
_RCVBUF = 1 << 21  # bytes: a few hundred ms of a 10 kHz flood, so a late wake-up loses nothing


def deep_receive_buffer(sock: socket.socket | None) -> None:
    """Ask for a deep receive buffer (the kernel caps it at net.core.rmem_max; best effort)."""
    if sock is not None:
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, _RCVBUF)
        except OSError:
            pass


class UdpApps:
    """A UDP endpoint of the app side (server or fixed client).

    A server's clients are the sender addresses heard, kept however quiet (``joined`` / ``gone`` report the
    changes); the ``max_clients`` + 1st sender replaces the one heard least recently, never one in ``kept``.
    """

    def __init__(self, host: str, port: int, listen: bool, max_clients: int = MAX_UDP_CLIENTS) -> None:
        self.t = UdpTransport(host, port, listen=listen)
        deep_receive_buffer(self.t.sock)
        self.listen, self.max_clients = listen, max_clients
        self.garbage = 0  # datagrams are forwarded whole: their garbage is counted by the proxy
        self.joined: list[Any] = [] if listen else [self.t.sock.getpeername()]
        self.gone: list[Any] = []
        self._heard: OrderedDict[Any, None] = OrderedDict()  # a server's clients, least recently heard first
        self.kept: set[Any] = set()  # never replaced by a new sender (the proxy's app: a flood cannot evict it)

    @property
    def local_address(self) -> tuple[str, int]:
        return self.t.local_address

    def fds(self) -> list[int]:
        return [self.t.fileno()]

    def read(self, fd: int) -> list[tuple[Any, bytes, float]]:
        """(client address, datagram, receive time [s, time.time()]) of everything pending; a server notes
        its new senders in ``joined`` (and the one replaced beyond the bound in ``gone``)."""
        got = [(addr, data, ts if ts is not None else time.time()) for data, addr, ts in self.t.read()]
        if self.listen:
            for addr, _, _ in got:
                self._hear(addr)
        return got

    def _hear(self, addr: Any) -> None:
        heard = self._heard
        if addr in heard:
            heard.move_to_end(addr)
            return
        heard[addr] = None
        if addr in self.gone:  # replaced and back before the proxy took note: still its client
            self.gone.remove(addr)
        else:
            self.joined.append(addr)
        if len(heard) > self.max_clients:  # the least recently heard that is not kept (the app streaming setpoints)
            old = next((a for a in heard if a not in self.kept), None)
            if old is not None:
                del heard[old]
                self.gone.append(old)

    def send(self, addr: Any, buf: bytes, frames: bytes) -> bool:
        """Send datagram ``buf`` to ``addr`` (``frames``: the same without garbage, for streams)."""
        try:
            self.t.sock.sendto(buf, addr)
        except OSError:  # full buffer, nobody listening (udpout): that client misses this datagram
            return False
        return True

    def close(self) -> None:
        self.t.close()


class TcpApps:
    """A TCP server of the app side: one client per connection."""

    def __init__(self, host: str, port: int) -> None:
        s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, port))
            s.listen(8)
        except OSError:
            s.close()
            raise
        s.setblocking(False)
        self.server = s
        self.conns: dict[Any, list] = {}  # address -> [socket, bytes in (partial frame), bytes out (unsent)]
        self._by_fd: dict[int, Any] = {}
        self.garbage = 0
        self.joined: list[Any] = []
        self.gone: list[Any] = []

    @property
    def local_address(self) -> tuple[str, int]:
        return self.server.getsockname()

    def fds(self) -> list[int]:
        return [self.server.fileno(), *self._by_fd]

    def read(self, fd: int) -> list[tuple[Any, bytes, float]]:
        """Accept new connections, or the whole frames a connection sent (client address, frames, time)."""
        if fd == self.server.fileno():
            self._accept()
            return []
        addr = self._by_fd.get(fd)
        if addr is None:
            return []
        c = self.conns[addr]
        try:
            data = c[0].recv(65536)
        except (BlockingIOError, InterruptedError):
            return []
        except OSError:
            data = b""
        t_rx = time.time()
        if not data:
            self._drop(addr)
            return []
        c[1] += data
        spans, garbage, used = split_frames(c[1], final=False)
        self.garbage += garbage
        frames = b"".join(bytes(c[1][i:i + n]) for i, n in spans)
        del c[1][:used]
        return [(addr, frames, t_rx)] if frames else []

    def _accept(self) -> None:
        while True:
            try:
                s, addr = self.server.accept()
            except (BlockingIOError, InterruptedError):
                return
            s.setblocking(False)
            s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self.conns[addr] = [s, bytearray(), bytearray()]
            self._by_fd[s.fileno()] = addr
            self.joined.append(addr)

    def _drop(self, addr: Any) -> None:
        c = self.conns.pop(addr, None)
        if c is not None:
            self._by_fd.pop(c[0].fileno(), None)
            c[0].close()
            self.gone.append(addr)

    def send(self, addr: Any, buf: bytes, frames: bytes) -> bool:
        """Write the whole ``frames`` to connection ``addr`` (what the socket does not take waits, up to a bound)."""
        c = self.conns.get(addr)
        if c is None:
            return False
        out = c[2]
        if len(out) + len(frames) > _MAX_OUT:
            return False
        out += frames
        try:
            n = c[0].send(out)
        except (BlockingIOError, InterruptedError):
            return True
        except OSError:
            self._drop(addr)
            return False
        del out[:n]
        return True

    def close(self) -> None:
        for addr in list(self.conns):
            self._drop(addr)
        self.server.close()


def open_app_side(url: str) -> UdpApps | TcpApps:
    """An app-side endpoint from ``udpin:``, ``udpout:`` or ``tcpin:HOST:PORT``."""
    if url.startswith("tcpin:"):
        ep = parse_url("tcp:" + url[len("tcpin:"):])
        return TcpApps(ep.host, ep.port)
    ep = parse_url(url)
    if ep.kind not in ("udpin", "udpout"):
        raise ValueError(f"--app {url!r}: the app side is udpin:HOST:PORT (a UDP server), udpout:HOST:PORT "
                         "(an app listening there) or tcpin:HOST:PORT (a TCP server)")
    return UdpApps(ep.host, ep.port, listen=ep.kind == "udpin")
