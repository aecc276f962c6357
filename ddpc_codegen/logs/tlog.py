"""MAVLink telemetry logs (.tlog) -> IODataset.

A tlog is a sequence of records: an 8-byte big-endian timestamp (µs since the Unix epoch, when
the logger received the packet) followed by one raw MAVLink v1 or v2 packet. Packets are framed
here and decoded with pymavlink's dialect module (no global mavutil state is touched); wanted
messages are CRC-checked, corrupt stretches are skipped with a warning saying where.

Channels: ``[NAME=]MESSAGE[@SYSID].FIELD[:UNIT]``, e.g. ``pitch_ref=SET_ATTITUDE_TARGET.pitch``
(Euler pitch of q), ``z=LOCAL_POSITION_NED.z_up`` (height up), ``ATTITUDE.pitch`` (raw).
Samples whose ``type_mask`` marks the field as ignored (SET_ATTITUDE_TARGET, ATTITUDE_TARGET,
[SET_]POSITION_TARGET_LOCAL_NED) are dropped with a warning: their values mean nothing.

Time base: ``time_source="log"`` (default) uses the tlog receive timestamps, one clock for all
messages. ``"boot"`` uses each message's ``time_boot_ms`` (the sender's clock, ms resolution,
free of link jitter); then every channel must come from the same system/component.

The MAVLink bridge's own tick logs are IODataset .npz files already; ``import_tlog`` loads
them as they are (several are merged as separate trajectories).
"""

from __future__ import annotations

import importlib
import struct
from pathlib import Path
from typing import Sequence

import numpy as np

from ddpc_codegen.design.data import IODataset
from ddpc_codegen.errors import DataError
from ddpc_codegen.logs.channels import ChannelSpec, resolve_channels
from ddpc_codegen.logs.dataset import assemble, file_meta, jsonable
from ddpc_codegen.logs.frames import ANGLE_FIELDS, derive_field
from ddpc_codegen.logs.grid import check_rule
from ddpc_codegen.logs.intervals import intersect_windows, state_windows
from ddpc_codegen.logs.mavlink_defs import (  # noqa: F401 (PX4_MAIN_MODES, ARDUPILOT_OFFBOARD_MODES re-exported)
    ARDUPILOT_OFFBOARD_MODES,
    MAV_AUTOPILOT_ARDUPILOTMEGA,
    MAV_MODE_FLAG_SAFETY_ARMED,
    PX4_MAIN_MODES,
    heartbeat_mode,
    mavlink_unit,
    with_mavlink_units,
)
from ddpc_codegen.logs.notes import Notes, fmt_t
from ddpc_codegen.logs.resample import build_segments
from ddpc_codegen.logs.series import Series, clean_series

__all__ = ["import_tlog", "read_tlog", "list_tlog_messages", "mavlink_unit", "TLOG_PRESETS", "PX4_MAIN_MODES",
           "ARDUPILOT_OFFBOARD_MODES"]

TLOG_PRESETS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    # PogoX flying: the companion's height + pitch references as sent on the link
    "pogox-flying": (
        ("z_ref=SET_POSITION_TARGET_LOCAL_NED.z_up:m", "pitch_ref=SET_ATTITUDE_TARGET.pitch:rad"),
        ("z=LOCAL_POSITION_NED.z_up:m", "pitch=ATTITUDE.pitch:rad"),
    ),
    # attitude loop, setpoints as sent by the offboard computer
    "attitude": (
        ("roll_ref=SET_ATTITUDE_TARGET.roll:rad", "pitch_ref=SET_ATTITUDE_TARGET.pitch:rad",
         "yaw_ref=SET_ATTITUDE_TARGET.yaw:rad", "thrust_ref=SET_ATTITUDE_TARGET.thrust:1"),
        ("roll=ATTITUDE.roll:rad", "pitch=ATTITUDE.pitch:rad", "yaw=ATTITUDE.yaw:rad"),
    ),
    # attitude loop, setpoints as the autopilot reports it is tracking them
    "attitude-target": (
        ("roll_ref=ATTITUDE_TARGET.roll:rad", "pitch_ref=ATTITUDE_TARGET.pitch:rad",
         "yaw_ref=ATTITUDE_TARGET.yaw:rad", "thrust_ref=ATTITUDE_TARGET.thrust:1"),
        ("roll=ATTITUDE.roll:rad", "pitch=ATTITUDE.pitch:rad", "yaw=ATTITUDE.yaw:rad"),
    ),
    "position": (
        ("x_ref=SET_POSITION_TARGET_LOCAL_NED.x:m", "y_ref=SET_POSITION_TARGET_LOCAL_NED.y:m",
         "z_ref=SET_POSITION_TARGET_LOCAL_NED.z_up:m"),
        ("x=LOCAL_POSITION_NED.x:m", "y=LOCAL_POSITION_NED.y:m", "z=LOCAL_POSITION_NED.z_up:m"),
    ),
}

_MAV_AUTOPILOT_INVALID = 8
_MAV_TYPE_GCS = 6

# type_mask bits meaning "ignore this field" (MAVLink common.xml)
_ATT_MASK = {"q": 128, "thrust": 64, "body_roll_rate": 1, "body_pitch_rate": 2, "body_yaw_rate": 4}
_POS_MASK = {"x": 1, "y": 2, "z": 4, "vx": 8, "vy": 16, "vz": 32, "afx": 64, "afy": 128, "afz": 256,
             "yaw": 1024, "yaw_rate": 2048}
_TYPE_MASKS = {"SET_ATTITUDE_TARGET": _ATT_MASK, "ATTITUDE_TARGET": _ATT_MASK,
               "SET_POSITION_TARGET_LOCAL_NED": _POS_MASK, "POSITION_TARGET_LOCAL_NED": _POS_MASK}

_V1, _V2 = 0xFE, 0xFD
_MAX_JUMP_US = 24 * 3600 * 10**6  # resync: a record timestamp this far off is not a record start


def _dialect(name: str):
    try:
        return importlib.import_module(f"pymavlink.dialects.v20.{name}")
    except ImportError as e:
        raise DataError(f"unknown MAVLink dialect {name!r} (pymavlink.dialects.v20.{name}): {e}") from None


def read_tlog(
    path: str | Path, wanted: Sequence[str] | None, *, dialect: str = "common", notes: Notes | None = None
) -> tuple[dict[str, list[tuple[int, int, int, object]]], int]:
    """Decode a tlog: (message name -> [(t_us, sysid, compid, message), ...] in file order,
    timestamp of the first record in µs).

    Only the ``wanted`` message names are decoded (all if None). Corrupt bytes are skipped
    (resynchronising on the next plausible record) and packets failing the CRC are dropped,
    each with a warning giving the file offset and time.
    """
    notes = notes if notes is not None else Notes()
    path = Path(path)
    if not path.is_file():
        raise DataError(f"tlog file {path} does not exist")
    mod = _dialect(dialect)
    by_name = {cls.msgname: cls for cls in mod.mavlink_map.values()}
    if wanted is not None:
        unknown = sorted(set(wanted) - set(by_name))
        if unknown:
            raise DataError(f"MAVLink message(s) {', '.join(unknown)} not in dialect {dialect!r}")
        ids = {by_name[n].id for n in wanted}
    else:
        ids = set(mod.mavlink_map)
    mav = mod.MAVLink(None)
    data = path.read_bytes()
    n = len(data)
    if n < 9:
        raise DataError(f"{path}: not a tlog (only {n} bytes)")
    out: dict[str, list] = {}
    pos = 0
    last_t: int | None = None
    origin: int | None = None
    skipped: list[tuple[int, int, int | None]] = []  # (offset, bytes, t near)
    crc_bad: list[tuple[int, int]] = []
    while pos + 9 <= n:
        magic = data[pos + 8]
        total = None
        if magic == _V1 and pos + 14 <= n:
            total = 6 + data[pos + 9] + 2
            sysid, compid, msgid = data[pos + 11], data[pos + 12], data[pos + 13]
        elif magic == _V2 and pos + 18 <= n:
            total = 10 + data[pos + 9] + 2 + (13 if data[pos + 10] & 1 else 0)
            sysid, compid = data[pos + 13], data[pos + 14]
            msgid = data[pos + 15] | (data[pos + 16] << 8) | (data[pos + 17] << 16)
        t_us = struct.unpack_from(">Q", data, pos)[0]
        if total is None and magic in (_V1, _V2):
            break  # a header cut short by the end of the file (reported below)
        if total is None or (last_t is not None and abs(t_us - last_t) > _MAX_JUMP_US):
            # resync: next offset that looks like a record, "timestamp near the last one + magic"
            start = pos
            pos += 1
            while pos + 9 <= n:
                if data[pos + 8] in (_V1, _V2):
                    tt = struct.unpack_from(">Q", data, pos)[0]
                    if last_t is None or abs(tt - last_t) <= _MAX_JUMP_US:
                        break
                pos += 1
            skipped.append((start, pos - start, last_t))
            continue
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
    o = origin or 0
    if skipped:
        where = ", ".join(f"offset {off} ({nb} bytes, after {fmt_t(t, o) if t is not None else 'start'})"
                          for off, nb, t in skipped[:3])
        notes.warn(f"{path.name}: skipped {sum(nb for _, nb, _ in skipped)} corrupt byte(s) in "
                   f"{len(skipped)} place(s): {where}{' ...' if len(skipped) > 3 else ''}")
    if crc_bad:
        names = sorted({nm for _, _, nm in crc_bad})
        per = ", ".join(f"{nm} x{sum(1 for *_, x in crc_bad if x == nm)}" for nm in names)
        where = ", ".join(f"{nm} at offset {off}, {fmt_t(t, o)}" for off, t, nm in crc_bad[:3])
        notes.warn(f"{path.name}: dropped {len(crc_bad)} packet(s) failing the MAVLink CRC/decode ({per}): "
                   f"{where}{' ...' if len(crc_bad) > 3 else ''}")
    if origin is None:
        raise DataError(f"{path}: no MAVLink record found; is it a tlog (8-byte timestamp + packet records)?")
    return out, origin


def _flatten(msgs: Sequence[object]) -> dict[str, np.ndarray]:
    """field name -> (N,) float array, arrays as ``q[0]``..; text fields left out."""
    cls = type(msgs[0])
    fields: dict[str, np.ndarray] = {}
    for name in cls.fieldnames:
        vals = [getattr(m, name) for m in msgs]
        first = vals[0]
        if isinstance(first, (bytes, str)):
            continue
        if isinstance(first, (list, tuple)):
            arr = np.asarray(vals, dtype=float)
            for i in range(arr.shape[1]):
                fields[f"{name}[{i}]"] = arr[:, i]
        else:
            fields[name] = np.asarray(vals, dtype=float)
    return fields


def _base_field(field: str) -> str:
    f = field[:-3] if field.endswith("_up") else field
    return "q" if f in ANGLE_FIELDS else f.split("[")[0]


def _pick_source(rows: list, msgname: str, sysid: int | None, path: Path, what: str) -> list:
    if sysid is not None:
        rows = [r for r in rows if r[1] == sysid]
        if not rows:
            raise DataError(f"{what}: no {msgname} from system {sysid} in {path}")
    sources: dict[tuple[int, int], int] = {}
    for r in rows:
        sources[(r[1], r[2])] = sources.get((r[1], r[2]), 0) + 1
    if len(sources) > 1:
        listing = ", ".join(f"system {s}/component {c}: {k} msgs" for (s, c), k in sorted(sources.items()))
        raise DataError(
            f"{what}: {msgname} in {path} comes from {len(sources)} sources ({listing}); "
            "interleaving them would mix vehicles. Choose one: MESSAGE@SYSID.FIELD or --sysid"
        )
    return rows


def _heartbeat_windows(rows, path: Path, origin: int, sysid: int | None, *, offboard_only: bool,
                       armed_only: bool, split_on_mode: bool):
    what = "--offboard-only" if offboard_only else "--armed-only" if armed_only else "--split-on-mode"
    ap = [r for r in rows if r[3].autopilot != _MAV_AUTOPILOT_INVALID and r[3].type != _MAV_TYPE_GCS]
    if sysid is not None:
        ap = [r for r in ap if r[1] == sysid]
    if not ap:
        raise DataError(f"{what} needs autopilot HEARTBEAT messages"
                        f"{'' if sysid is None else f' from system {sysid}'}; none in {path}")
    ap = _pick_source(ap, "HEARTBEAT (autopilot)", None, path, what)
    t = np.array([r[0] for r in ap], dtype=np.int64)
    base = np.array([r[3].base_mode for r in ap], dtype=np.int64)
    modes = [heartbeat_mode(r[3]) for r in ap]
    code = np.array([c for c, _, _ in modes], dtype=np.int64)
    label = {c: n for c, n, _ in modes}
    offboard = {c: o for c, _, o in modes}
    t_end = int(t[-1])

    wins = None
    # heartbeats come at ~1 Hz: a mode is only trusted from its first to its last report
    if offboard_only or split_on_mode:
        keep = (lambda v: offboard[v]) if offboard_only else None
        wins = [(a, b, label[v]) for a, b, v in state_windows(t, code, t_end_us=t_end, keep=keep, until_next=False)]
        if offboard_only and not wins:
            ardu = ap[0][3].autopilot == MAV_AUTOPILOT_ARDUPILOTMEGA
            which = "ArduPilot GUIDED / GUIDED_NOGPS" if ardu else "PX4 offboard"
            raise DataError(f"--offboard-only: {path} never reports {which} mode "
                            f"({fmt_t(t[0], origin)}..{fmt_t(t_end, origin)}; modes seen: "
                            f"{', '.join(sorted(set(label.values())))})")
    if armed_only:
        armed = (base & MAV_MODE_FLAG_SAFETY_ARMED) > 0
        arm = [(a, b, "armed") for a, b, _ in
               state_windows(t, armed, t_end_us=t_end, keep=lambda v: v == 1, until_next=False)]
        if not arm:
            raise DataError(f"--armed-only: the vehicle never reports armed in {path}")
        wins = intersect_windows(wins, arm)
    return wins


def _load_npz(paths: Sequence[Path]) -> IODataset:
    """The bridge's own logs are IODatasets already: load (and merge) them unchanged."""
    sets = [IODataset.load(p) for p in paths]
    if len(sets) == 1:
        return sets[0]
    d0 = sets[0]
    for p, d in zip(paths[1:], sets[1:]):
        if (d.input_names, d.output_names, d.dt) != (d0.input_names, d0.output_names, d0.dt):
            raise DataError(
                f"cannot merge {p} into {paths[0]}: channels/dt differ "
                f"({list(d.input_names)}, {list(d.output_names)}, dt={d.dt} vs "
                f"{list(d0.input_names)}, {list(d0.output_names)}, dt={d0.dt})"
            )
    return IODataset(
        [a for d in sets for a in d.u],
        [a for d in sets for a in d.y],
        d0.dt,
        input_names=d0.input_names, output_names=d0.output_names,
        input_units=d0.input_units, output_units=d0.output_units,
        metadata=jsonable({"source_format": "iodataset", "merged_from": [str(p) for p in paths],
                           "metadata": [d.metadata for d in sets]}),
    )


def import_tlog(
    paths: str | Path | Sequence[str | Path],
    inputs: Sequence[str | ChannelSpec] | None = None,
    outputs: Sequence[str | ChannelSpec] | None = None,
    *,
    preset: str | None = None,
    rate_hz: float = 200.0,
    sysid: int | None = None,
    time_source: str = "log",
    dialect: str = "common",
    max_gap: float | None = None,
    gap_factor: float = 5.0,
    min_duration: float = 1.0,
    offboard_only: bool = False,
    armed_only: bool = False,
    split_on_mode: bool = False,
    time_range: tuple[float, float] | None = None,
    input_rule: str = "hold",
    output_rule: str = "linear",
    on_nan: str = "drop",
) -> IODataset:
    """Read MAVLink telemetry log(s) into an IODataset on a uniform ``rate_hz`` grid.

    Same arguments and rules as :func:`~ddpc_codegen.logs.import_ulog`, plus:

    Args:
        sysid: keep only messages from this MAVLink system (default: error if a message
            comes from several sources). ``MESSAGE@SYSID`` in a spec overrides it.
        time_source: "log" (tlog receive timestamps) or "boot" (messages' time_boot_ms).
        dialect: pymavlink dialect module for decoding ("common", "development", "all"...).
        time_range: (start, end) in s since the first record ("log") or since boot ("boot").
    Mode filters read the autopilot's HEARTBEAT (PX4: custom main mode 6 = offboard; ArduPilot:
    the mode number of the vehicle type's map, GUIDED / GUIDED_NOGPS = off-board; base_mode
    armed flag); heartbeats come at ~1 Hz, so a mode counts from its first to its last report.
    Units: from the MAVLink message definitions (:func:`mavlink_unit`), never guessed from names.
    ``.npz`` files (the bridge's own IODataset logs) are returned as they are.
    """
    path_list = [Path(paths)] if isinstance(paths, (str, Path)) else [Path(p) for p in paths]
    if not path_list:
        raise DataError("no tlog file given")
    npz = [p.suffix == ".npz" for p in path_list]
    if all(npz):
        return _load_npz(path_list)
    if any(npz):
        raise DataError("mix of .npz datasets and tlogs: import the tlogs first, then pass datasets separately")
    if on_nan not in ("drop", "error"):
        raise DataError(f"on_nan must be 'drop' or 'error'; got {on_nan!r}")
    if time_source not in ("log", "boot"):
        raise DataError(f"time_source must be 'log' or 'boot'; got {time_source!r}")
    if time_range is not None and not float(time_range[1]) > float(time_range[0]):
        raise DataError(f"time_range end must be after start; got {time_range[0]}..{time_range[1]} s")
    check_rule(input_rule, "input")
    check_rule(output_rule, "output")
    ins, outs = resolve_channels(preset, inputs, outputs, TLOG_PRESETS, "tlog")
    mod = _dialect(dialect)
    ins, outs = with_mavlink_units(ins, mod), with_mavlink_units(outs, mod)
    modes = offboard_only or armed_only or split_on_mode
    if modes and time_source == "boot":
        raise DataError("mode filters need time_source='log': HEARTBEAT carries no time_boot_ms")
    notes = Notes()
    wanted = {s.source for s in ins + outs} | ({"HEARTBEAT"} if modes else set())
    per_file, chan_info = [], []
    for fi, path in enumerate(path_list):
        msgs, first_us = read_tlog(path, sorted(wanted), dialect=dialect, notes=notes)
        origin = 0 if time_source == "boot" else first_us
        crop = None if time_range is None else (
            origin + int(round(float(time_range[0]) * 1e6)), origin + int(round(float(time_range[1]) * 1e6)) + 1)
        series = {"input": [], "output": []}
        senders: dict[str, set[tuple[int, int]]] = {"input": set(), "output": set()}
        for role, specs, rule in (("input", ins, input_rule), ("output", outs, output_rule)):
            for s in specs:
                rows = msgs.get(s.source, [])
                if not rows:
                    present = sorted(k for k in msgs if k != "HEARTBEAT")
                    raise DataError(f"message {s.source} (for {role} {s.name!r}) is not in {path}; "
                                    f"of the requested messages it has: {', '.join(present) or 'none'} "
                                    "(list all with --list)")
                rows = _pick_source(rows, s.source, s.instance if s.instance is not None else sysid, path,
                                    f"{role} {s.name!r}")
                senders[role].add((rows[0][1], rows[0][2]))
                fields = _flatten([r[3] for r in rows])
                if time_source == "boot":
                    if "time_boot_ms" not in fields:
                        raise DataError(f"time_source='boot': {s.source} has no time_boot_ms field")
                    t = (fields["time_boot_ms"] * 1000).astype(np.int64)
                else:
                    t = np.array([r[0] for r in rows], dtype=np.int64)
                x, how = derive_field(fields, s.field, f"message {s.source} of {path}")
                bit = _TYPE_MASKS.get(s.source, {}).get(_base_field(s.field))
                if bit is not None and "type_mask" in fields:
                    ign = (fields["type_mask"].astype(np.int64) & bit) > 0
                    if ign.all():
                        raise DataError(f"{path.name}:{s.where}: every {s.source} marks "
                                        f"{_base_field(s.field)} as ignored (type_mask bit {bit}); it is not a setpoint here")
                    if ign.any():
                        k = np.flatnonzero(ign)
                        notes.warn(f"{path.name}:{s.where}: dropped {k.size} sample(s) whose type_mask marks "
                                   f"{_base_field(s.field)} as ignored ({fmt_t(t[k[0]], origin)}..{fmt_t(t[k[-1]], origin)})")
                        t, x = t[~ign], x[~ign]
                src = f"{path.name}:{s.where}"
                raw = Series(s.name, s.unit, src, t, x, rule, angle=s.field in ANGLE_FIELDS)
                series[role].append(clean_series(raw, origin_us=origin, on_nan=on_nan, notes=notes, crop_us=crop))
                if fi == 0:
                    chan_info.append({"role": role, "name": s.name, "unit": s.unit, "spec": s.text,
                                      "message": s.source, "sysid": rows[0][1], "compid": rows[0][2],
                                      "field": s.field, "derivation": how, "rule": rule,
                                      "angle_unwrapped": s.field in ANGLE_FIELDS})
        all_senders = senders["input"] | senders["output"]
        if time_source == "boot" and len(all_senders) > 1:
            raise DataError(f"time_source='boot' mixes clocks: channels come from systems/components "
                            f"{sorted(all_senders)}; use time_source='log'")
        wins = None
        if modes:
            # the vehicle whose mode counts is the one sending the outputs (state messages)
            out_sys = {sy for sy, _ in senders["output"]}
            hb_sys = sysid if sysid is not None else (next(iter(out_sys)) if len(out_sys) == 1 else None)
            wins = _heartbeat_windows(msgs.get("HEARTBEAT", []), path, origin, hb_sys, offboard_only=offboard_only,
                                      armed_only=armed_only, split_on_mode=split_on_mode)
        if crop is not None:
            wins = intersect_windows(wins, [(crop[0], crop[1], "")])
        segs = build_segments(series["input"], series["output"], rate_hz=rate_hz, origin_us=origin, notes=notes,
                              windows=wins, max_gap_s=max_gap, gap_factor=gap_factor,
                              min_duration_s=min_duration, what=str(path))
        meta = file_meta(path)
        meta.update({
            "format": "tlog",
            "log_start_us": origin,
            "messages": sorted(wanted),
            "channels": {
                ser.name: {"source": ser.source, "t_first_s": round((int(ser.t_us[0]) - origin) / 1e6, 6),
                           "t_last_s": round((int(ser.t_us[-1]) - origin) / 1e6, 6),
                           "samples": int(ser.t_us.size), "log_rate_hz": ser.info.get("log_rate_hz")}
                for ser in series["input"] + series["output"]
            },
        })
        per_file.append((meta, segs, origin))
    settings = {
        "source_format": "tlog",
        "importer": "ddpc_codegen.logs.import_tlog",
        "preset": preset,
        "dialect": dialect,
        "time_source": time_source,
        "time_base": ("seconds since each file's first tlog record (receive time)" if time_source == "log"
                      else "seconds since the sender's boot (time_boot_ms)"),
        "gap_rule": (f"split at spells > {max_gap} s without samples" if max_gap is not None
                     else f"split at spells > {gap_factor:g} x the channel's median sampling interval"),
        "min_duration_s": float(min_duration),
        "mode_filter": {"offboard_only": offboard_only, "armed_only": armed_only, "split_on_mode": split_on_mode},
        "sysid": sysid,
        "time_range_s": None if time_range is None else [float(v) for v in time_range],
        "on_nan": on_nan,
    }
    return assemble(per_file, ins, outs, rate_hz=rate_hz, notes=notes, settings=settings, channel_info=chan_info)


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
