"""MAVLink I/O for the bridge and the simulated vehicle: transports, framing, filtering (commands with retries:
:mod:`.commands`).

Connection strings follow pymavlink's: ``udpin:HOST:PORT`` (listen; replies go to the pinned peer, see
below), ``udpout:HOST:PORT`` (a connected UDP socket:
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

The pinned peer (``udpin:`` on the bridge's side, a target system set): the first address whose
HEARTBEAT carries the expected system / component ids (or the ``vehicle_address`` given) becomes
the only source whose messages count and the only destination of ours. Packets from any other
address are counted (``foreign_packets``) and dropped unparsed, so a flood costs a receive call
each and a peer that copies the vehicle's ids steers nothing. The peer moves only when the pinned
one has been silent for ``repin_after`` seconds and a heartbeat with the ids comes from the new
address (a restarted vehicle on a new port), never with a given ``vehicle_address``. With a
signing key (:mod:`.signing`) every packet must carry a valid MAVLink 2 signature.
"""

from __future__ import annotations

import os
import select
import time
from collections import Counter
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from firmware_bridge.commands import CommandTracker, PendingCommand
from firmware_bridge.peer import PeerPin
from firmware_bridge.signing import enable_signing
from firmware_bridge.transports import (
    Endpoint,
    LinkError,
    SerialTransport,
    TcpTransport,
    UdpTransport,
    _Transport,
    open_transport,
    parse_url,
)

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
        vehicle_address: ``udpin:`` only: the vehicle's (host, port); the peer is pinned to it from the
            start and never moves. None: pinned to the first heartbeat with the target ids.
        signing_key: a 32-byte MAVLink 2 signing key: sign what we send, drop what is not signed with it.
        signing_link_id: the link id our signatures carry.
        repin_after: the pinned peer silent this long [s]: a heartbeat with the ids from a new address
            may take its place (no ``vehicle_address``).
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
        vehicle_address: tuple[str, int] | None = None,
        signing_key: bytes | None = None,
        signing_link_id: int = 0,
        repin_after: float = 3.0,
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
                                                      "foreign", "link_errors", "reconnects", "peer_changes",
                                                      "foreign_packets", "foreign_heartbeats", "unpinned",
                                                      "unsigned", "bad_signature")})
        self.foreign_systems: set[int] = set()
        self.pin = PeerPin(self.stats, vehicle_address, repin_after)
        self.signed = signing_key is not None
        if signing_key is not None:
            enable_signing(self.mav, signing_key, signing_link_id)
            enable_signing(self._parser, signing_key, signing_link_id, sign_outgoing=False)
        self._next_reopen = 0.0
        self.transport: _Transport | None = None
        self.last_error = ""
        if self.endpoint.kind == "serial" and not os.path.exists(self.endpoint.device):
            # at start a missing device is a wrong path, not a link drop (later it may re-enumerate)
            raise LinkError(f"serial device {self.endpoint.device} does not exist (check the path, the cable, "
                            "and that the flight controller's USB / UART is enabled)")
        try:
            self.transport = open_transport(self.endpoint)
        except (OSError, LinkError) as e:
            if self.endpoint.kind == "udpin":
                raise  # a port we cannot bind is a configuration error, not a link drop
            self._down(str(e), time.monotonic())
        if self.pinning and vehicle_address is not None and self.transport is not None:
            self.transport.peer = vehicle_address

    @classmethod
    def for_bridge(cls, c) -> MavLink:
        """The bridge's link from its :class:`.bridge_config.BridgeConfig` (``c``)."""
        return cls(c.url, baud=c.baud, source_system=c.sysid, source_component=c.compid, target_system=c.target_system,
                   target_component=c.target_component, vehicle_address=c.vehicle_address, signing_key=c.signing_key,
                   repin_after=c.link_timeout)

    # ------------------------------------------------------------------ state
    @property
    def pinning(self) -> bool:
        """A listening UDP link of the bridge (a target system set): replies go to one pinned peer."""
        return self.endpoint.kind == "udpin" and self.target_system is not None

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
        pinning = self.pinning
        for data, addr, kts in chunks:
            if pinning and not self.pin.admit(t, data, addr, now_m, self.target_system):
                continue
            rx = now_m
            if kts is not None:
                age = now_r - kts
                # a kernel stamp a hair "in the future" is clock-read jitter, not a bad stamp
                if -0.01 <= age < 1.0:
                    rx = now_m - max(age, 0.0)
            msgs = self._parse(data, t.datagram)
            for msg in msgs:
                if self._filter(msg, addr, now_m, pinning):
                    out.append((msg, rx))
        return out

    def _parse(self, data: bytes, datagram: bool) -> list:
        """The messages in one chunk; a datagram's partial packet is dropped with it."""
        parser, stats = self._parser, self.stats
        try:
            msgs = parser.parse_buffer(data)
        except Exception:  # a malformed packet must never take the loop down
            stats["parse_errors"] += 1
            _reset_parser(parser)
            return []
        if datagram:
            if len(parser.buf) > parser.buf_index:
                stats["bad_data"] += 1  # a truncated packet: dropped with its datagram
            _reset_parser(parser)
        if self.signed:
            sg = parser.signing
            stats["bad_signature"] = sg.badsig_count
            stats["unsigned"] = sg.reject_count - sg.badsig_count
        return msgs or []

    def _filter(self, msg, addr, now: float, pinning: bool) -> bool:
        """True if ``msg`` (from ``addr``) counts: not bad data, from the target, from the pinned peer."""
        stats = self.stats
        if msg.get_type() == "BAD_DATA":
            if getattr(msg, "reason", "") != "Invalid signature":  # counted as unsigned / bad_signature
                stats["bad_data"] += 1
            return False
        if not self._accept(msg):
            stats["foreign"] += 1
            self.foreign_systems.add(msg.get_srcSystem())
            return False
        t = self.transport
        if pinning:
            if not self.pin.counts(t, msg, addr, now):
                return False
        elif not pinning and t.datagram and isinstance(t, UdpTransport) and t.listen and addr is not None \
                and t.peer != addr:
            t.peer = addr  # the vehicle's side (any sender counts): reply to whoever spoke last
            stats["peer_changes"] += 1
        stats["rx"] += 1
        return True

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
