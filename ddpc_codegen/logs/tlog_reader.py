"""Reading MAVLink telemetry logs (.tlog): framing records, decoding the wanted messages.

A tlog is a sequence of records: an 8-byte big-endian timestamp (µs since the Unix epoch, when
the logger received the packet) followed by one raw MAVLink v1 or v2 packet. Packets are framed
here and decoded with pymavlink's dialect module (no global mavutil state is touched); wanted
messages are CRC-checked, corrupt stretches are skipped with a warning saying where.
"""

from __future__ import annotations

import importlib
import struct
from pathlib import Path
from types import ModuleType
from typing import Sequence

import numpy as np

from ddpc_codegen.errors import DataError
from ddpc_codegen.logs.notes import Notes, fmt_t
from ddpc_codegen.values.files import MAX_LOG_BYTES, checked_input_path, read_bytes_bounded

__all__ = ["read_tlog", "list_tlog_messages", "load_dialect", "TlogRow"]

TlogRow = tuple[int, int, int, object]  # (receive time µs, sysid, compid, decoded message)

_V1, _V2 = 0xFE, 0xFD
_MAX_JUMP_US = 24 * 3600 * 10**6  # resync: a record timestamp this far off is not a record start


def load_dialect(name: str) -> ModuleType:
    """The pymavlink dialect module ``pymavlink.dialects.v20.<name>``; DataError if there is none."""
    try:
        return importlib.import_module(f"pymavlink.dialects.v20.{name}")
    except ImportError as e:
        raise DataError(f"unknown MAVLink dialect {name!r} (pymavlink.dialects.v20.{name}): {e}") from None


def _wanted_ids(mod: ModuleType, wanted: Sequence[str] | None, dialect: str) -> set[int]:
    """Message ids to decode: those of the ``wanted`` names (all if None); unknown names are an error."""
    by_name = {cls.msgname: cls for cls in mod.mavlink_map.values()}
    if wanted is None:
        return set(mod.mavlink_map)
    unknown = sorted(set(wanted) - set(by_name))
    if unknown:
        raise DataError(f"MAVLink message(s) {', '.join(unknown)} not in dialect {dialect!r}")
    return {by_name[n].id for n in wanted}


def _packet_header(data: bytes, pos: int) -> tuple[int, int, int, int] | None:
    """(packet length, sysid, compid, msgid) of the record at ``pos``; None if no complete header."""
    n = len(data)
    magic = data[pos + 8]
    if magic == _V1 and pos + 14 <= n:
        return 6 + data[pos + 9] + 2, data[pos + 11], data[pos + 12], data[pos + 13]
    if magic == _V2 and pos + 18 <= n:
        total = 10 + data[pos + 9] + 2 + (13 if data[pos + 10] & 1 else 0)  # + signature if signed
        msgid = data[pos + 15] | (data[pos + 16] << 8) | (data[pos + 17] << 16)
        return total, data[pos + 13], data[pos + 14], msgid
    return None


def _resync(data: bytes, pos: int, last_t: int | None) -> int:
    """Next offset from ``pos`` that looks like a record: a magic byte after a timestamp near the last one."""
    n = len(data)
    while pos + 9 <= n:
        if data[pos + 8] in (_V1, _V2):
            tt = struct.unpack_from(">Q", data, pos)[0]
            if last_t is None or abs(tt - last_t) <= _MAX_JUMP_US:
                break
        pos += 1
    return pos


def _warn_damage(notes: Notes, name: str, origin: int, skipped: list[tuple[int, int, int | None]],
                 crc_bad: list[tuple[int, int, str]]) -> None:
    """One warning for the corrupt stretches skipped, one for the packets failing the CRC."""
    if skipped:
        where = ", ".join(f"offset {off} ({nb} bytes, after {fmt_t(t, origin) if t is not None else 'start'})"
                          for off, nb, t in skipped[:3])
        notes.warn(f"{name}: skipped {sum(nb for _, nb, _ in skipped)} corrupt byte(s) in "
                   f"{len(skipped)} place(s): {where}{' ...' if len(skipped) > 3 else ''}")
    if crc_bad:
        names = sorted({nm for _, _, nm in crc_bad})
        per = ", ".join(f"{nm} x{sum(1 for *_, x in crc_bad if x == nm)}" for nm in names)
        where = ", ".join(f"{nm} at offset {off}, {fmt_t(t, origin)}" for off, t, nm in crc_bad[:3])
        notes.warn(f"{name}: dropped {len(crc_bad)} packet(s) failing the MAVLink CRC/decode ({per}): "
                   f"{where}{' ...' if len(crc_bad) > 3 else ''}")


def read_tlog(
    path: str | Path, wanted: Sequence[str] | None, *, dialect: str = "common", notes: Notes | None = None
) -> tuple[dict[str, list[TlogRow]], int]:
    """Decode a tlog: (message name -> [(t_us, sysid, compid, message), ...] in file order,
    timestamp of the first record in µs).

    Only the ``wanted`` message names are decoded (all if None). Corrupt bytes are skipped
    (resynchronising on the next plausible record) and packets failing the CRC are dropped,
    each with a warning giving the file offset and time.
    """
    notes = notes if notes is not None else Notes()
    path = Path(path)
    if not path.exists():
        raise DataError(f"tlog file {path} does not exist")
    checked_input_path(path, "tlog file", MAX_LOG_BYTES, error=DataError)  # a FIFO or a device is never opened
    mod = load_dialect(dialect)
    ids = _wanted_ids(mod, wanted, dialect)
    mav = mod.MAVLink(None)
    data = read_bytes_bounded(path, "tlog file", MAX_LOG_BYTES, error=DataError)
    n = len(data)
    if n < 9:
        raise DataError(f"{path}: not a tlog (only {n} bytes)")
    out: dict[str, list[TlogRow]] = {}
    pos = 0
    last_t: int | None = None
    origin: int | None = None
    skipped: list[tuple[int, int, int | None]] = []  # (offset, bytes, t near)
    crc_bad: list[tuple[int, int, str]] = []  # (offset, t, message name)
    while pos + 9 <= n:
        header = _packet_header(data, pos)
        t_us = struct.unpack_from(">Q", data, pos)[0]
        if header is None and data[pos + 8] in (_V1, _V2):
            break  # a header cut short by the end of the file (reported below)
        if header is None or (last_t is not None and abs(t_us - last_t) > _MAX_JUMP_US):
            start, pos = pos, _resync(data, pos + 1, last_t)
            skipped.append((start, pos - start, last_t))
            continue
        total, sysid, compid, msgid = header
        if pos + 8 + total > n:
            notes.warn(f"{path.name}: the file ends inside a packet at offset {pos}; its last {n - pos} bytes are ignored")
            pos = n
            break
        if origin is None:
            origin = t_us
        last_t = t_us
        if msgid in ids:
            try:
                msg = mav.decode(bytearray(data[pos + 8: pos + 8 + total]))
            except Exception:  # pymavlink raises MAVError and, on odd payloads, struct errors
                crc_bad.append((pos, t_us, mod.mavlink_map[msgid].msgname))
            else:
                out.setdefault(msg.get_type(), []).append((t_us, sysid, compid, msg))
        pos += 8 + total
    if pos < n:
        notes.warn(f"{path.name}: {n - pos} trailing byte(s) at offset {pos} are not a complete record; ignored")
    _warn_damage(notes, path.name, origin or 0, skipped, crc_bad)
    if origin is None:
        raise DataError(f"{path}: no MAVLink record found; is it a tlog (8-byte timestamp + packet records)?")
    return out, origin


def list_tlog_messages(path: str | Path, dialect: str = "common") -> list[tuple[str, int, int, int, float, list[str]]]:
    """(message, sysid, compid, count, rate Hz, fields) for every message source in a tlog."""
    msgs, _ = read_tlog(path, None, dialect=dialect)
    out = []
    for name, rows in sorted(msgs.items()):
        by_src: dict[tuple[int, int], list[int]] = {}
        for r in rows:
            by_src.setdefault((r[1], r[2]), []).append(r[0])
        for (s, c), ts in sorted(by_src.items()):
            d = np.diff(np.asarray(ts, dtype=np.int64))
            rate = float(1e6 / np.median(d)) if d.size and np.median(d) > 0 else 0.0
            out.append((name, s, c, len(ts), rate, list(type(rows[0][3]).fieldnames)))
    return out
