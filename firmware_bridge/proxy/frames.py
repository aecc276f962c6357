"""MAVLink frame boundaries without decoding: where each frame in a buffer starts and ends, its
header fields, and whether its checksum holds. The proxy forwards the bytes it finds here as they
are; only a candidate for rewriting is decoded (by pymavlink, on a copy).

Frame layout (MAVLink 1 / 2): ``FE len seq sys comp id  payload  crc2`` (8 + len bytes) and
``FD len incompat compat seq sys comp id3  payload  crc2 [signature13]`` (12 + len bytes, + 13 when
``incompat & 1``). The checksum covers everything after the start byte plus the message's
``crc_extra``; for a message id the dialect does not know, a frame is accepted when the next byte
starts a frame (or the buffer ends there), so that unknown messages still pass while garbage
cannot swallow the frame after it.
"""

from __future__ import annotations

from typing import NamedTuple

from pymavlink.dialects.v20 import common as mavlink

__all__ = ["STX_V1", "STX_V2", "MAX_FRAME", "Header", "frame_size", "header", "msgid", "checksum_ok", "crc16", "split_frames",
           "splice"]

STX_V1, STX_V2 = 0xFE, 0xFD
MAX_FRAME = 12 + 255 + 13  # the longest MAVLink 2 frame (signed)
_CRC_EXTRA = {mid: cls.crc_extra for mid, cls in mavlink.mavlink_map.items()}
_mcrf4xx = getattr(mavlink, "mcrf4xx", None)  # fastcrc's when installed (pymavlink imports it)


class Header(NamedTuple):
    """A frame's header fields."""

    version: int  # 1 or 2
    seq: int
    sysid: int
    compid: int
    msgid: int


def frame_size(buf: bytes | bytearray, i: int) -> int:
    """Total length of the frame starting at ``buf[i]`` [bytes]; 0: no start byte there; -1: the
    header is not complete yet."""
    b = buf[i]
    if b == STX_V2:
        if len(buf) - i < 3:
            return -1
        return 12 + buf[i + 1] + (13 if buf[i + 2] & 1 else 0)
    if b == STX_V1:
        if len(buf) - i < 2:
            return -1
        return 8 + buf[i + 1]
    return 0


def header(buf: bytes | bytearray, i: int = 0) -> Header:
    """The header of the (complete) frame at ``buf[i]``."""
    if buf[i] == STX_V2:
        return Header(2, buf[i + 4], buf[i + 5], buf[i + 6], buf[i + 7] | buf[i + 8] << 8 | buf[i + 9] << 16)
    return Header(1, buf[i + 2], buf[i + 3], buf[i + 4], buf[i + 5])


def msgid(buf: bytes | bytearray, i: int) -> int:
    """The message id of the frame at ``buf[i]``."""
    return buf[i + 7] | buf[i + 8] << 8 | buf[i + 9] << 16 if buf[i] == STX_V2 else buf[i + 5]


def setpoint_target(buf: bytes | bytearray, i: int) -> int:
    """The target system of the position setpoint frame at ``buf[i]`` (SET_POSITION_TARGET_LOCAL_NED and _GLOBAL_INT
    both carry it at payload byte 50; a MAVLink 2 payload cut before it is 0, a broadcast)."""
    v2 = buf[i] == STX_V2
    start, n = i + (10 if v2 else 6), buf[i + 1]
    return buf[start + 50] if n > 50 else 0


def crc16(data: bytes) -> int:
    """MAVLink's checksum (CRC-16/MCRF4XX) of ``data`` (a frame's bytes after the start byte, then its crc_extra)."""
    if _mcrf4xx is not None:
        return _mcrf4xx(data, 0xFFFF)
    return mavlink.x25crc(data).crc


def checksum_ok(buf: bytes | bytearray, i: int, n: int) -> bool | None:
    """Whether the frame ``buf[i:i+n]`` has a valid checksum; None when its message id is unknown."""
    v2 = buf[i] == STX_V2
    msgid = buf[i + 7] | buf[i + 8] << 8 | buf[i + 9] << 16 if v2 else buf[i + 5]
    extra = _CRC_EXTRA.get(msgid)
    if extra is None:
        return None
    end = i + (10 if v2 else 6) + buf[i + 1]  # header + payload (the signature is not covered)
    crc = crc16(bytes(buf[i + 1:end]) + bytes((extra,)))
    return buf[end] | buf[end + 1] << 8 == crc


def split_frames(buf: bytes | bytearray, final: bool = True) -> tuple[list[tuple[int, int]], int, int]:
    """Frames in ``buf``: ``(spans, garbage, used)``.

    ``spans``: (start, length) of each frame with a valid checksum (or an unknown id, see the module
    docstring), in order; ``garbage``: bytes skipped between them; ``used``: bytes consumed. With
    ``final`` (a datagram) an incomplete frame at the end is garbage; without (a stream) it is left
    for the next read (``used`` stops before it).
    """
    spans: list[tuple[int, int]] = []
    size = len(buf)
    i = garbage = 0
    while i < size:
        n = frame_size(buf, i)
        if n == 0:
            i += 1
            garbage += 1
            continue
        if n < 0 or i + n > size:
            if not final:
                break
            i += 1
            garbage += 1
            continue
        ok = checksum_ok(buf, i, n)
        if ok is None:
            ok = i + n == size or buf[i + n] in (STX_V1, STX_V2)
        if ok:
            spans.append((i, n))
            i += n
        else:
            i += 1
            garbage += 1
    return spans, garbage, i


def splice(data: bytes, spans: list[tuple[int, int]], replaced: dict[int, bytes]) -> bytes:
    """``data`` with the frames (of ``spans``) starting at the keys of ``replaced`` swapped for its values."""
    if not replaced:
        return data
    parts, last = [], 0
    for i, n in spans:
        if i in replaced:
            parts += (data[last:i], replaced[i])
            last = i + n
    parts.append(data[last:])
    return b"".join(parts)
