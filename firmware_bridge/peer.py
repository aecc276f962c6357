"""Who a listening UDP link answers: the pinned peer (see :mod:`.link`'s docstring).

:class:`PeerPin` decides, per datagram, before it is parsed, whether its source may count (the pinned
peer, or any address while none is pinned or the pinned one fell silent), and, per valid message,
whether a heartbeat with the target's ids (re)pins the peer. It counts what it turns away in the
link's statistics: ``foreign_packets`` (another address), ``foreign_heartbeats`` (another address
claiming the target's ids: a second vehicle or a spoofer), ``unpinned`` (before the first heartbeat).
"""

from __future__ import annotations

import math
from collections import Counter

from pymavlink.dialects.v20 import common as mavlink

__all__ = ["PeerPin"]


def _claims_heartbeat(data: bytes, system: int | None) -> bool:
    """The datagram starts with a MAVLink 2 HEARTBEAT header from ``system`` (looked at, not parsed)."""
    return len(data) >= 10 and data[0] == mavlink.PROTOCOL_MARKER_V2 and data[5] == system and data[7:10] == b"\0\0\0"


class PeerPin:
    """The pinned peer of one listening link.

    Args:
        stats: the link's counters (updated in place).
        vehicle_address: pinned from the start and never moved; None: the first heartbeat's address.
        repin_after: the pinned peer silent this long [s]: a heartbeat from a new address may take its place.
    """

    def __init__(self, stats: Counter, vehicle_address: tuple[str, int] | None, repin_after: float) -> None:
        self.stats = stats
        self.vehicle_address = vehicle_address
        self.repin_after = repin_after
        self.heard = -math.inf  # when the pinned peer last sent a valid message [s, monotonic]
        self.foreign_address = None  # the last other address that claimed the target's ids

    def admit(self, transport, data: bytes, addr, now: float, system: int | None) -> bool:
        """May the datagram ``data`` from ``addr`` be parsed at all? (Counted and dropped if not.)"""
        if addr == transport.peer or self._may_pin(transport, now):
            return True
        self.stats["foreign_packets"] += 1  # not the vehicle's address: never parsed, never answered
        if _claims_heartbeat(data, system):
            self.stats["foreign_heartbeats"] += 1  # said by the link's owner (an event)
            self.foreign_address = addr
        return False

    def counts(self, transport, msg, addr, now: float) -> bool:
        """A valid message of the target from ``addr``: True if it counts (the peer's, or a heartbeat that pins)."""
        if addr is not None and addr != transport.peer:
            if msg.get_type() != "HEARTBEAT":
                self.stats["unpinned" if transport.peer is None else "foreign_packets"] += 1
                return False
            # The first heartbeat with the target's ids pins the peer; later, only after the peer fell silent
            # (admit lets no other address through before that, and none with a given vehicle address).
            transport.peer = addr
            self.stats["peer_changes"] += 1
        self.heard = now
        return True

    def _may_pin(self, transport, now: float) -> bool:
        if self.vehicle_address is not None:
            return False
        return transport.peer is None or now - self.heard > self.repin_after
