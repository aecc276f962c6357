"""MAVLink I/O for the bridge and the simulated vehicle: transports, framing, filtering, commands.

Connection strings follow pymavlink's: ``udpin:HOST:PORT`` (listen; replies go to the peer that
sent the last valid message of the target system), ``udpout:HOST:PORT`` (a connected UDP socket:
the kernel drops datagrams from anyone else), ``tcp:HOST:PORT`` (client, reconnects), or a serial
device ``/dev/ttyACM0`` (baud from ``--baud`` or ``/dev/ttyACM0:921600``; POSIX termios, no
pyserial needed). Messages are encoded / parsed with pymavlink's MAVLink 2 ``common`` dialect
(a MAVLink 1 peer is parsed too).

Why not ``mavutil.mavlink_connection`` as is: its UDP server sends every packet to *every*
address that ever sent it a datagram (garbage senders included), its TCP reconnect sleeps
inside the receive call, and a datagram with a truncated packet corrupts the parse of the
next one. Here each datagram is parsed on its own, the reply address is pinned to the vehicle,
reconnects are attempted at most once per ``reconnect_interval`` without blocking the tick loop
for longer than a connect timeout, and the receive path drains everything pending in one call.

Receive times: on Linux UDP the kernel's receive time stamp (SO_TIMESTAMPNS) is used, so a
message that waited in the socket while the process was busy is not reported younger than it
is. Times are returned on the ``time.monotonic()`` clock.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import errno
import math
import os
import select
import socket
import struct
import sys
import time
from collections import Counter, deque
from dataclasses import dataclass, field
from typing import Any, Callable

from pymavlink.dialects.v20 import common as mavlink

__all__ = [
    "mavlink",
    "LinkError",
    "parse_url",
    "Endpoint",
    "MavLink",
    "CommandTracker",
    "PendingCommand",
    "UdpTransport",
    "TcpTransport",
    "SerialTransport",
]

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
def _reset_parser(p: mavlink.MAVLink) -> None:
    """Forget a partial packet (UDP: every datagram starts clean, garbage cannot eat the next one)."""
    p.buf = bytearray()
    p.buf_index = 0
    p.expected_length = mavlink.HEADER_LEN_V1 + 2
    p.have_prefix_error = False


class MavLink:
    """One MAVLink connection with source filtering and a drain-everything receive path.

    Args:
        url: connection string (see :func:`parse_url`).
        source_system, source_component: our identity (companion computer: compid 191,
            MAV_COMP_ID_ONBOARD_COMPUTER).
        target_system, target_component: whose messages count. ``target_system=0``: lock onto
            the first autopilot HEARTBEAT; ``None``: accept every sender (the vehicle side).
            ``target_component=0``: any component of the target system.
        baud: serial baud rate (default from the string, else 921600).
        reconnect_interval: seconds between reopen attempts of a failed transport.
    """

    def __init__(
        self,
        url: str,
        *,
        source_system: int = 1,
        source_component: int = mavlink.MAV_COMP_ID_ONBOARD_COMPUTER,
        target_system: int | None = 1,
        target_component: int = 1,
        baud: int | None = None,
        reconnect_interval: float = 1.0,
    ) -> None:
        self.endpoint = parse_url(url, baud)
        self.url = url
        self.mav = mavlink.MAVLink(None, srcSystem=source_system, srcComponent=source_component)
        self._parser = mavlink.MAVLink(None)
        self._parser.robust_parsing = True
        self.source_system, self.source_component = source_system, source_component
        self.target_system, self.target_component = target_system, target_component
        self.reconnect_interval = reconnect_interval
        self.stats: Counter = Counter({k: 0 for k in ("rx", "tx", "tx_dropped", "bad_data", "parse_errors",
                                                      "foreign", "link_errors", "reconnects", "peer_changes")})
        self.foreign_systems: set[int] = set()
        self._next_reopen = 0.0
        self.transport: _Transport | None = None
        self.last_error = ""
        try:
            self.transport = open_transport(self.endpoint)
        except (OSError, LinkError) as e:
            if self.endpoint.kind == "udpin":
                raise  # a port we cannot bind is a configuration error, not a link drop
            self._down(str(e), time.monotonic())

    # ------------------------------------------------------------------ state
    @property
    def is_open(self) -> bool:
        return self.transport is not None and self.transport.is_open

    @property
    def peer(self):
        return self.transport.peer if self.transport is not None else None

    def local_address(self):
        t = self.transport
        return t.local_address if isinstance(t, UdpTransport) else None

    def fileno(self) -> int | None:
        return self.transport.fileno() if self.transport is not None else None

    def _down(self, why: str, now: float) -> None:
        self.last_error = why
        self.stats["link_errors"] += 1
        if self.transport is not None:
            try:
                self.transport.close()
            except OSError:
                pass
        self._next_reopen = now + self.reconnect_interval

    def poll(self, now: float | None = None) -> bool:
        """Reopen a failed transport (rate-limited). Returns True if it was reopened now."""
        if self.is_open:
            return False
        now = time.monotonic() if now is None else now
        if now < self._next_reopen:
            return False
        self._next_reopen = now + self.reconnect_interval
        try:
            if self.transport is None:
                self.transport = open_transport(self.endpoint)
            else:
                self.transport.open()
        except (OSError, LinkError, ValueError) as e:
            self.last_error = str(e)
            return False
        _reset_parser(self._parser)
        self.stats["reconnects"] += 1
        return True

    def wait(self, timeout: float) -> bool:
        """Block until data is readable or ``timeout`` seconds pass. Returns True if readable."""
        timeout = max(0.0, timeout)
        fd = self.fileno()
        if fd is None:
            time.sleep(min(timeout, 0.05))
            return False
        try:
            r, _, _ = select.select([fd], [], [], timeout)
        except (OSError, ValueError):
            return False
        return bool(r)

    # ------------------------------------------------------------------ receive
    def drain(self) -> list[tuple[Any, float]]:
        """Every message pending now that passes the source filter, in arrival order, each with its
        receive time (``time.monotonic()`` clock; kernel time stamp where available)."""
        t = self.transport
        if t is None or not t.is_open:
            return []
        try:
            chunks = t.read()
        except LinkError as e:
            self._down(str(e), time.monotonic())
            return []
        if not chunks:
            return []
        now_r = time.time()
        now_m = time.monotonic()
        out: list[tuple[Any, float]] = []
        parser = self._parser
        stats = self.stats
        for data, addr, kts in chunks:
            rx = now_m
            if kts is not None:
                age = now_r - kts
                # a kernel stamp a hair "in the future" is clock-read jitter, not a bad stamp
                if -0.01 <= age < 1.0:
                    rx = now_m - max(age, 0.0)
            try:
                msgs = parser.parse_buffer(data)
            except Exception:  # a malformed packet must never take the loop down
                stats["parse_errors"] += 1
                _reset_parser(parser)
                continue
            if t.datagram:
                if len(parser.buf) > parser.buf_index:
                    stats["bad_data"] += 1  # a truncated packet: dropped with its datagram
                _reset_parser(parser)
            if not msgs:
                continue
            for msg in msgs:
                if msg.get_type() == "BAD_DATA":
                    stats["bad_data"] += 1
                    continue
                if not self._accept(msg):
                    stats["foreign"] += 1
                    self.foreign_systems.add(msg.get_srcSystem())
                    continue
                stats["rx"] += 1
                if t.datagram and isinstance(t, UdpTransport) and t.listen and addr is not None and t.peer != addr:
                    # Pin replies to whoever sends valid messages of the system we talk to.
                    t.peer = addr
                    stats["peer_changes"] += 1
                out.append((msg, rx))
        return out

    def _accept(self, msg) -> bool:
        ts = self.target_system
        if ts is None:
            return True
        src = msg.get_srcSystem()
        if ts == 0:
            # Lock onto the first autopilot heartbeat (not a GCS, not another companion computer).
            if msg.get_type() == "HEARTBEAT" and msg.autopilot != mavlink.MAV_AUTOPILOT_INVALID:
                self.target_system = src
                if self.target_component == 0:
                    self.target_component = msg.get_srcComponent()
                return True
            return False
        if src != ts:
            return False
        tc = self.target_component
        return tc == 0 or msg.get_srcComponent() == tc

    # ------------------------------------------------------------------ send
    def send(self, msg) -> bool:
        """Encode and send one message; False if it could not go out (no peer, link down)."""
        t = self.transport
        if t is None or not t.is_open:
            return False
        buf = msg.pack(self.mav)
        self.mav.seq = (self.mav.seq + 1) % 256
        try:
            ok = t.write(buf)
        except LinkError as e:
            self._down(str(e), time.monotonic())
            return False
        if ok:
            self.stats["tx"] += 1
        else:
            self.stats["tx_dropped"] += 1
        return ok

    def send_many(self, msgs) -> bool:
        """Several messages in one write (one UDP datagram: one wake-up of the receiver, as PX4 batches)."""
        t = self.transport
        if t is None or not t.is_open or not msgs:
            return False
        buf = bytearray()
        mav = self.mav
        for m in msgs:
            buf += m.pack(mav)
            mav.seq = (mav.seq + 1) % 256
        try:
            ok = t.write(bytes(buf))
        except LinkError as e:
            self._down(str(e), time.monotonic())
            return False
        self.stats["tx" if ok else "tx_dropped"] += len(msgs)
        return ok

    def send_heartbeat(self, type_: int = mavlink.MAV_TYPE_ONBOARD_CONTROLLER,
                       autopilot: int = mavlink.MAV_AUTOPILOT_INVALID, base_mode: int = 0,
                       custom_mode: int = 0, system_status: int = mavlink.MAV_STATE_ACTIVE) -> bool:
        return self.send(self.mav.heartbeat_encode(type_, autopilot, base_mode, custom_mode, system_status))

    def command_long(self, command: int, params: tuple[float, ...], confirmation: int = 0,
                     target: tuple[int, int] | None = None) -> bool:
        p = list(params) + [0.0] * (7 - len(params))
        ts, tc = target if target is not None else (self.target_system or 0, self.target_component or 0)
        return self.send(self.mav.command_long_encode(ts, tc, command, confirmation, *p[:7]))

    def close(self) -> None:
        if self.transport is not None:
            self.transport.close()


# ----------------------------------------------------------------------------- commands
@dataclass
class PendingCommand:
    """A COMMAND_LONG waiting for its COMMAND_ACK."""

    command: int
    params: tuple[float, ...]
    label: str
    tries: int = 0
    sent_at: float = -math.inf
    result: int | None = None  # MAV_RESULT once acked
    done: bool = False
    timed_out: bool = False
    on_done: Callable[["PendingCommand"], None] | None = field(default=None, repr=False)

    @property
    def accepted(self) -> bool:
        return self.result == mavlink.MAV_RESULT_ACCEPTED


class CommandTracker:
    """Sends COMMAND_LONGs with retries. COMMAND_ACK names only the command id, so commands with
    the same id are sent one at a time (queued); different ids run in parallel.

    Args:
        timeout: seconds to wait for an ACK before resending (confirmation + 1).
        max_tries: give up (``timed_out``) after this many sends.
    """

    def __init__(self, link: MavLink, timeout: float = 0.5, max_tries: int = 4) -> None:
        self.link, self.timeout, self.max_tries = link, timeout, max_tries
        self.queues: dict[int, deque[PendingCommand]] = {}
        self.history: list[PendingCommand] = []

    def submit(self, command: int, params: tuple[float, ...], label: str = "",
               on_done: Callable[[PendingCommand], None] | None = None) -> PendingCommand:
        pc = PendingCommand(command, tuple(params), label or str(command), on_done=on_done)
        self.queues.setdefault(command, deque()).append(pc)
        return pc

    def busy(self) -> bool:
        return any(self.queues.values())

    def on_ack(self, msg) -> PendingCommand | None:
        q = self.queues.get(msg.command)
        if not q:
            return None
        if msg.result == mavlink.MAV_RESULT_IN_PROGRESS:
            q[0].sent_at = time.monotonic()  # still working on it: do not resend yet
            return None
        pc = q.popleft()
        pc.result, pc.done = int(msg.result), True
        self.history.append(pc)
        if pc.on_done:
            pc.on_done(pc)
        return pc

    def poll(self, now: float) -> None:
        for q in self.queues.values():
            if not q:
                continue
            pc = q[0]
            if now - pc.sent_at < self.timeout:
                continue
            if pc.tries >= self.max_tries:
                q.popleft()
                pc.done, pc.timed_out = True, True
                self.history.append(pc)
                if pc.on_done:
                    pc.on_done(pc)
                continue
            if self.link.command_long(pc.command, pc.params, confirmation=pc.tries):
                pc.tries += 1
                pc.sent_at = now
            else:
                pc.sent_at = now  # link down or no peer yet: try again after the timeout
