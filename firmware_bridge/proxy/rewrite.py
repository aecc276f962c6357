"""The rewrite hook: the one place where the proxy may change what the app sends.

The proxy calls a :class:`SetpointRewrite` for each ``SET_POSITION_TARGET_LOCAL_NED`` and
``SET_POSITION_TARGET_GLOBAL_INT`` (:data:`SETPOINT_MSGIDS`) from the app (the client whose setpoints it
follows) that has a position enabled (``type_mask`` does not ignore
all of x, y, z). The hook returns the replacement frame or None (pass the app's own frame). It is
only ever asked about a setpoint the app just sent, so it can replace one but never add one: the
proxy sends no setpoint the app did not cause. A hook that raises or returns anything but one valid
frame of the same message is ignored for that setpoint (the app's own frame goes out; counted).

A hook may split its work around the send (the added latency is only what decides the bytes): with ``decide`` and
``settle`` methods the proxy asks ``decide(msg, frame, t_rx)`` for the bytes, sends, then calls ``settle()`` (its
bookkeeping); with a true ``passive`` attribute (it never replaces a setpoint) the whole call comes after the send.

Replacement frames carry the proxy's own component id (default :data:`PROXY_COMPONENT`) and its
own sequence numbers, on the app's system id: the autopilot and a ground station can tell them
from the app's, and the app's sequence stays gap-free for any other receiver.
"""

from __future__ import annotations

import struct
from typing import Protocol

from pymavlink.dialects.v20 import common as mavlink

from firmware_bridge.proxy.frames import STX_V2, crc16, msgid

__all__ = ["SETPOINT_MSGID", "SETPOINT_MSGIDS", "PROXY_COMPONENT", "SetpointRewrite", "decode_frame", "decode_setpoint",
           "has_position", "SetpointEncoder"]

SETPOINT_MSGID = mavlink.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED
SETPOINT_MSGIDS = frozenset((SETPOINT_MSGID, mavlink.MAVLINK_MSG_ID_SET_POSITION_TARGET_GLOBAL_INT))
PROXY_COMPONENT = mavlink.MAV_COMP_ID_ONBOARD_COMPUTER2  # 192: not the bridge's 191, nor a GCS's 190
_POSITION_IGNORE = (mavlink.POSITION_TARGET_TYPEMASK_X_IGNORE | mavlink.POSITION_TARGET_TYPEMASK_Y_IGNORE
                    | mavlink.POSITION_TARGET_TYPEMASK_Z_IGNORE)


class SetpointRewrite(Protocol):
    """``hook(msg, frame, t_rx) -> bytes | None``: ``msg`` the decoded setpoint, ``frame`` its bytes as
    received, ``t_rx`` its receive time [s, ``time.time()`` clock]."""

    def __call__(self, msg: mavlink.MAVLink_message, frame: bytes, t_rx: float) -> bytes | None: ...


_decoder = mavlink.MAVLink(None)
_HEADER_V2 = struct.Struct("<BBBBBBBHB")  # STX, payload length, incompat, compat flags, seq, sysid, compid, msgid
_CRC = struct.Struct("<H")


def decode_frame(frame: bytes) -> mavlink.MAVLink_message | None:
    """pymavlink's decode of one whole frame (a copy; the bytes are not touched); None when invalid."""
    try:
        return _decoder.decode(bytearray(frame))
    except Exception:  # MAVError, struct.error, ...: a frame the app sent malformed is not a setpoint
        return None


def decode_setpoint(frame: bytes) -> mavlink.MAVLink_message | None:
    """:func:`decode_frame` of one whole setpoint frame (:data:`SETPOINT_MSGIDS`) whose checksum was checked already
    (:func:`.frames.split_frames`): the same message, made without pymavlink's second checksum and generic parse (it
    runs between a setpoint's receipt and its send); any other frame goes to :func:`decode_frame`."""
    v2 = frame[0] == STX_V2
    head, n, flags = (10, frame[1], frame[2]) if v2 else (6, frame[1], 0)
    mid = msgid(frame, 0)
    if mid not in SETPOINT_MSGIDS or flags & mavlink.MAVLINK_IFLAG_SIGNED or len(frame) != head + n + 2:
        return decode_frame(frame)
    cls = mavlink.mavlink_map[mid]
    size = cls.unpacker.size
    payload = frame[head:head + n]
    t = cls.unpacker.unpack((payload + bytes(size - n))[:size] if n < size else payload[:size])
    m = cls(*[t[i] for i in cls.orders])  # (wire order -> the message's field order; no arrays, no strings)
    m._signed, m._msgbuf, m._payload = False, bytearray(frame), bytearray(frame[6:len(frame) - 2])
    m._crc = frame[-2] | frame[-1] << 8
    m._header = mavlink.MAVLink_header(mid, flags, frame[3] if v2 else 0, n, *frame[4:7] if v2 else frame[2:5])
    return m


def has_position(msg: mavlink.MAVLink_message) -> bool:
    """Whether a SET_POSITION_TARGET_* message uses at least one of x, y, z."""
    return (msg.type_mask & _POSITION_IGNORE) != _POSITION_IGNORE


class SetpointEncoder:
    """Re-encodes an app's setpoint with a new position (everything else copied) under the proxy's
    own component id and sequence (see the module docstring).

    The frame is pymavlink's MAVLink 2 encoding of the message (its struct packs the payload, trailing zero bytes
    are cut, no signature), assembled here without building a message object: it runs between a setpoint's receipt
    and its send."""

    def __init__(self, component: int = PROXY_COMPONENT) -> None:
        self.component = component
        self._seq: dict[int, int] = {}  # per source system: its own sequence counter

    def encode(self, msg: mavlink.MAVLink_message, position_ned: tuple[float, float, float] | None = None,
               **fields: float) -> bytes:
        """The replacement frame: ``msg`` (a SET_POSITION_TARGET_LOCAL_NED or _GLOBAL_INT) with x, y, z =
        ``position_ned`` [m, the message's frame; local only] and any other field given by name (e.g. ``alt=2.5``,
        ``vz=0.0``); every other field is the app's, as decoded."""
        if position_ned is not None:  # (a field given by name wins)
            fields = {**dict(zip("xyz", (float(v) for v in position_ned))), **fields}
        cls = type(msg)
        payload = cls.unpacker.pack(*[fields[f] if f in fields else getattr(msg, f) for f in cls.ordered_fieldnames])
        n = len(payload)
        while n > 1 and payload[n - 1] == 0:  # MAVLink 2 cuts the payload's trailing zeros
            n -= 1
        mid, sysid = cls.id, msg.get_srcSystem()
        seq = self._seq.get(sysid, 0)
        head = _HEADER_V2.pack(STX_V2, n, 0, 0, seq, sysid, self.component, mid & 0xFFFF, mid >> 16)
        crc = crc16(head[1:] + payload[:n] + bytes((cls.crc_extra,)))
        self._seq[sysid] = (seq + 1) % 256  # (counted once the frame is made, as pymavlink's send does)
        return head + payload[:n] + _CRC.pack(crc)
