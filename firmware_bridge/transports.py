"""Byte transports under the MAVLink link: connection strings, UDP (kernel receive stamps),
TCP (non-blocking reconnects) and POSIX serial; each returns whole datagrams / reads with their
receive time on the ``time.monotonic()`` clock. :mod:`.link` frames MAVLink on top of them."""

from __future__ import annotations

import errno
import os
import socket
import struct
import sys
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any

__all__ = ["LinkError", "Endpoint", "parse_url", "UdpTransport", "TcpTransport", "SerialTransport", "open_transport",
           "parse_address"]

_LINUX = sys.platform.startswith("linux")
_SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)  # asm-generic value on Linux
_MAX_DATAGRAMS_PER_DRAIN = 2000  # a flood must not starve the tick loop; the rest comes next call
_MAX_OUTBUF = 1 << 16


class LinkError(RuntimeError):
    """A transport failed (closed, refused, device gone)."""


# ----------------------------------------------------------------------------- endpoints
@dataclass(frozen=True)
class Endpoint:
    """A parsed connection string."""

    kind: str  # "udpin" | "udpout" | "tcp" | "serial"
    host: str = ""
    port: int = 0
    device: str = ""
    baud: int = 921600

    def __str__(self) -> str:
        if self.kind == "serial":
            return f"{self.device}@{self.baud}"
        return f"{self.kind}:{self.host}:{self.port}"


def parse_url(url: str, baud: int | None = None) -> Endpoint:
    """Parse a pymavlink-style connection string (see the module docstring)."""
    url = url.strip()
    for prefix, kind in (("udpin:", "udpin"), ("udp:", "udpin"), ("udpout:", "udpout"), ("tcp:", "tcp")):
        if url.startswith(prefix):
            rest = url[len(prefix):]
            host, sep, port = rest.rpartition(":")
            if not sep or not port.isdigit():
                raise ValueError(f"{url!r}: expected {prefix}HOST:PORT")
            if not 1 <= int(port) <= 65535:
                raise ValueError(f"{url!r}: port {port} is outside 1..65535")
            return Endpoint(kind, host or "127.0.0.1", int(port))
    if url.startswith(("tcpin:", "udpbcast:", "ws:", "wss:", "mcast:")):
        raise ValueError(f"{url!r}: supported links are udpin:, udpout:, tcp: and serial devices")
    dev, b = url, baud
    for sep in (",", ":"):
        head, s, tail = url.rpartition(sep)
        if s and tail.isdigit() and head:
            dev, b = head, int(tail)
            break
    if not dev.startswith("/") and not dev.upper().startswith("COM"):
        raise ValueError(f"{url!r} is neither udpin:/udpout:/tcp: nor a serial device path")
    return Endpoint("serial", device=dev, baud=int(b or 921600))


def parse_address(text: str) -> tuple[str, int]:
    """``HOST:PORT`` as the (IPv4 address, port) a UDP datagram from there carries (names resolved once).

    Raises:
        ValueError: not HOST:PORT, a port outside 1..65535, or a name that does not resolve.
    """
    host, sep, port = text.strip().rpartition(":")
    if not sep or not host or not port.isdigit() or not 1 <= int(port) <= 65535:
        raise ValueError(f"{text!r}: expected HOST:PORT with a port in 1..65535")
    try:
        return socket.gethostbyname(host), int(port)
    except OSError as e:
        raise ValueError(f"{text!r}: cannot resolve {host!r} ({e})") from None


# ----------------------------------------------------------------------------- transports
class _Transport(ABC):
    datagram = False
    peer: Any = None

    @abstractmethod
    def fileno(self) -> int | None: ...

    @property
    def is_open(self) -> bool:
        return self.fileno() is not None

    @abstractmethod
    def read(self) -> list[tuple[bytes, Any, float | None]]:
        """All pending chunks: (data, source address or None, kernel receive time (epoch s) or None)."""
        ...

    @abstractmethod
    def write(self, buf: bytes) -> bool: ...

    @abstractmethod
    def open(self) -> None: ...

    @abstractmethod
    def close(self) -> None: ...


class UdpTransport(_Transport):
    """UDP. ``listen``: bound to (host, port), replies to the pinned peer. Else connected to (host, port)."""

    datagram = True

    def __init__(self, host: str, port: int, listen: bool) -> None:
        self.host, self.port, self.listen = host, int(port), listen
        self.sock: socket.socket | None = None
        self.peer = None if listen else (host, self.port)
        self.kernel_timestamps = False
        self.dropped = 0
        self.open()

    def open(self) -> None:
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            if self.listen:
                s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                s.bind((self.host, self.port))
            else:
                # connect(): default destination, local address chosen for that route (127.0.0.1 for
                # loopback), and the kernel filters out datagrams from any other sender.
                s.connect((self.host, self.port))
            s.setblocking(False)
            if _LINUX:
                try:
                    s.setsockopt(socket.SOL_SOCKET, _SO_TIMESTAMPNS, 1)
                    self.kernel_timestamps = True
                except OSError:
                    self.kernel_timestamps = False
        except OSError:
            s.close()
            raise
        self.sock = s

    @property
    def local_address(self) -> tuple[str, int]:
        assert self.sock is not None
        return self.sock.getsockname()

    def fileno(self) -> int | None:
        return self.sock.fileno() if self.sock is not None else None

    def read(self) -> list[tuple[bytes, Any, float | None]]:
        out: list[tuple[bytes, Any, float | None]] = []
        s = self.sock
        if s is None:
            return out
        ts_on = self.kernel_timestamps
        for _ in range(_MAX_DATAGRAMS_PER_DRAIN):
            try:
                if ts_on:
                    data, anc, _flags, addr = s.recvmsg(65535, 64)
                    ts = None
                    for level, typ, cdata in anc:
                        if level == socket.SOL_SOCKET and typ == _SO_TIMESTAMPNS:
                            # struct timespec: 2 x 64 bit (2 x 32 bit on older 32-bit ARM userlands)
                            fmt = "qq" if len(cdata) >= 16 else "ii"
                            sec, nsec = struct.unpack(fmt, cdata[:struct.calcsize(fmt)])
                            ts = sec + nsec * 1e-9
                else:
                    data, addr = s.recvfrom(65535)
                    ts = None
            except (BlockingIOError, InterruptedError):
                break
            except ConnectionRefusedError:
                # A connected UDP socket reports an earlier ICMP "port unreachable" once: the peer
                # is not (yet) listening. Nothing to read; keep going.
                continue
            except OSError as e:
                raise LinkError(f"udp receive failed: {e}") from e
            out.append((data, addr, ts))
        return out

    def write(self, buf: bytes) -> bool:
        s = self.sock
        if s is None:
            return False
        try:
            if self.listen:
                if self.peer is None:
                    return False  # nobody to talk to yet
                s.sendto(buf, self.peer)
            else:
                s.send(buf)
            return True
        except (BlockingIOError, ConnectionRefusedError, InterruptedError):
            self.dropped += 1
            return False
        except OSError as e:
            if e.errno in (errno.ENOBUFS, errno.EHOSTUNREACH, errno.ENETUNREACH, errno.ECONNREFUSED):
                self.dropped += 1
                return False
            raise LinkError(f"udp send failed: {e}") from e

    def close(self) -> None:
        if self.sock is not None:
            self.sock.close()
            self.sock = None


class _StreamTransport(_Transport):
    """Byte-stream transports share partial-write buffering."""

    def __init__(self) -> None:
        self._out = bytearray()
        self.dropped = 0

    @abstractmethod
    def _raw_write(self, buf: bytes | bytearray) -> int: ...

    def write(self, buf: bytes) -> bool:
        if not self.is_open:
            return False
        if len(self._out) + len(buf) > _MAX_OUTBUF:
            # The link cannot keep up (baud rate too low?): drop rather than send stale setpoints late.
            self.dropped += 1
            self._out.clear()
            return False
        self._out += buf
        try:
            n = self._raw_write(self._out)
        except (BlockingIOError, InterruptedError):
            return True
        del self._out[:n]
        return True


class TcpTransport(_StreamTransport):
    """TCP client (e.g. a SITL or a telemetry radio bridge). Reconnected by :class:`MavLink`."""

    def __init__(self, host: str, port: int, connect_timeout: float = 0.2) -> None:
        super().__init__()
        self.host, self.port, self.connect_timeout = host, int(port), connect_timeout
        self.sock: socket.socket | None = None
        self.open()

    def open(self) -> None:
        s = socket.create_connection((self.host, self.port), timeout=self.connect_timeout)
        s.setblocking(False)
        s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.sock = s
        self._out.clear()

    def fileno(self) -> int | None:
        return self.sock.fileno() if self.sock is not None else None

    def read(self) -> list[tuple[bytes, Any, float | None]]:
        out = []
        s = self.sock
        if s is None:
            return out
        for _ in range(256):
            try:
                data = s.recv(65536)
            except (BlockingIOError, InterruptedError):
                break
            except OSError as e:
                self.close()
                raise LinkError(f"tcp receive failed: {e}") from e
            if not data:
                self.close()
                raise LinkError("tcp peer closed the connection")
            out.append((data, None, None))
        return out

    def _raw_write(self, buf) -> int:
        assert self.sock is not None
        try:
            return self.sock.send(buf)
        except (BlockingIOError, InterruptedError):
            raise
        except OSError as e:
            self.close()
            raise LinkError(f"tcp send failed: {e}") from e

    def close(self) -> None:
        if self.sock is not None:
            self.sock.close()
            self.sock = None


class SerialTransport(_StreamTransport):
    """A serial device in raw 8N1 mode via termios (POSIX; e.g. a UART to the flight controller)."""

    def __init__(self, device: str, baud: int) -> None:
        super().__init__()
        self.device, self.baud = device, int(baud)
        self.fd: int | None = None
        self.open()

    def open(self) -> None:
        import termios

        speed = getattr(termios, f"B{self.baud}", None)
        if speed is None:
            raise ValueError(f"unsupported baud rate {self.baud}")
        fd = os.open(self.device, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
        try:
            iflag, oflag, cflag, lflag, _isp, _osp, cc = termios.tcgetattr(fd)
            cflag = termios.CS8 | termios.CREAD | termios.CLOCAL
            cc = list(cc)
            cc[termios.VMIN], cc[termios.VTIME] = 0, 0
            termios.tcsetattr(fd, termios.TCSANOW, [0, 0, cflag, 0, speed, speed, cc])
        except termios.error:
            # Not a tty (e.g. a FIFO in tests): use it as a raw byte stream.
            pass
        self.fd = fd
        self._out.clear()

    def fileno(self) -> int | None:
        return self.fd

    def read(self) -> list[tuple[bytes, Any, float | None]]:
        out = []
        if self.fd is None:
            return out
        for _ in range(256):
            try:
                data = os.read(self.fd, 4096)
            except (BlockingIOError, InterruptedError):
                break
            except OSError as e:
                self.close()
                raise LinkError(f"serial read failed: {e}") from e
            if not data:
                break
            out.append((data, None, None))
        return out

    def _raw_write(self, buf) -> int:
        assert self.fd is not None
        try:
            return os.write(self.fd, buf)
        except (BlockingIOError, InterruptedError):
            raise
        except OSError as e:
            self.close()
            raise LinkError(f"serial write failed: {e}") from e

    def close(self) -> None:
        if self.fd is not None:
            os.close(self.fd)
            self.fd = None


def open_transport(ep: Endpoint) -> _Transport:
    if ep.kind == "udpin":
        return UdpTransport(ep.host, ep.port, listen=True)
    if ep.kind == "udpout":
        return UdpTransport(ep.host, ep.port, listen=False)
    if ep.kind == "tcp":
        return TcpTransport(ep.host, ep.port)
    return SerialTransport(ep.device, ep.baud)


# ----------------------------------------------------------------------------- the link
