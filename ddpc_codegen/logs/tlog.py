"""MAVLink telemetry logs (.tlog) -> IODataset.

Records are framed and decoded in :mod:`.tlog_reader` (corrupt stretches skipped with a warning);
here the channels are picked from the decoded messages and resampled into the dataset.

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

from pathlib import Path
from typing import Sequence

import numpy as np

from ddpc_codegen.design.data import IODataset
from ddpc_codegen.errors import DataError
from ddpc_codegen.logs.channels import ChannelSpec, resolve_channels
from ddpc_codegen.logs.dataset import assemble, channel_summary, file_meta, jsonable
from ddpc_codegen.logs.fields import ANGLE_FIELDS, derive_field
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
from ddpc_codegen.logs.options import ImportOptions, check_on_nan, check_time_range, crop_window, gap_rule_text
from ddpc_codegen.logs.series import Series, clean_series
from ddpc_codegen.logs.tlog_reader import TlogRow, list_tlog_messages, load_dialect, read_tlog

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
    # ArduCopter in GUIDED / GUIDED_NOGPS flown by attitude (SET_ATTITUDE_TARGET, e.g. ddpc-bridge), as a
    # GCS records it: the attitude target and the throttle ArduCopter applied (ATTITUDE_TARGET.thrust =
    # its throttle input, with either GUID_OPTIONS) -> height and attitude. The companion's own
    # references are only in its own log (ddpc-bridge --log).
    "ardupilot-guided-attitude": (
        ("roll_ref=ATTITUDE_TARGET.roll:rad", "pitch_ref=ATTITUDE_TARGET.pitch:rad",
         "yaw_ref=ATTITUDE_TARGET.yaw:rad", "thrust_ref=ATTITUDE_TARGET.thrust:1"),
        ("z=LOCAL_POSITION_NED.z_up:m", "roll=ATTITUDE.roll:rad", "pitch=ATTITUDE.pitch:rad",
         "yaw=ATTITUDE.yaw:rad"),
    ),
    "position": (
        ("x_ref=SET_POSITION_TARGET_LOCAL_NED.x:m", "y_ref=SET_POSITION_TARGET_LOCAL_NED.y:m",
         "z_ref=SET_POSITION_TARGET_LOCAL_NED.z_up:m"),
        ("x=LOCAL_POSITION_NED.x:m", "y=LOCAL_POSITION_NED.y:m", "z=LOCAL_POSITION_NED.z_up:m"),
    ),
}

_ATTITUDE_SETPOINTS = ("SET_ATTITUDE_TARGET", "ATTITUDE_TARGET")
_MAV_AUTOPILOT_INVALID = 8
_MAV_TYPE_GCS = 6
# HEARTBEAT types of vehicles that do not fly: a steering predictor for a flying robot fitted on their logs
# is almost surely a wrong file (the import still works; it warns).
_NOT_FLYING = {5: "ANTENNA_TRACKER", 10: "GROUND_ROVER", 11: "SURFACE_BOAT", 12: "SUBMARINE"}

# type_mask bits meaning "ignore this field" (MAVLink common.xml)
_ATT_MASK = {"q": 128, "thrust": 64, "body_roll_rate": 1, "body_pitch_rate": 2, "body_yaw_rate": 4}
_POS_MASK = {"x": 1, "y": 2, "z": 4, "vx": 8, "vy": 16, "vz": 32, "afx": 64, "afy": 128, "afz": 256,
             "yaw": 1024, "yaw_rate": 2048}
_TYPE_MASKS = {"SET_ATTITUDE_TARGET": _ATT_MASK, "ATTITUDE_TARGET": _ATT_MASK,
               "SET_POSITION_TARGET_LOCAL_NED": _POS_MASK, "POSITION_TARGET_LOCAL_NED": _POS_MASK}


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


def _sample_times(rows: Sequence[TlogRow], fields: dict[str, np.ndarray], spec: ChannelSpec,
                  time_source: str) -> np.ndarray:
    """Sample times (int64 µs) of one channel: tlog receive times, or the sender's time_boot_ms."""
    if time_source == "boot":
        if "time_boot_ms" not in fields:
            raise DataError(f"time_source='boot': {spec.source} has no time_boot_ms field")
        return (fields["time_boot_ms"] * 1000).astype(np.int64)
    return np.array([r[0] for r in rows], dtype=np.int64)


def _drop_ignored(fields: dict[str, np.ndarray], t: np.ndarray, x: np.ndarray, spec: ChannelSpec, path: Path,
                  origin: int, notes: Notes) -> tuple[np.ndarray, np.ndarray]:
    """Drop the samples whose type_mask marks the field as ignored (their values mean nothing)."""
    bit = _TYPE_MASKS.get(spec.source, {}).get(_base_field(spec.field))
    if bit is None or "type_mask" not in fields:
        return t, x
    ign = (fields["type_mask"].astype(np.int64) & bit) > 0
    if ign.all():
        raise DataError(f"{path.name}:{spec.where}: every {spec.source} marks "
                        f"{_base_field(spec.field)} as ignored (type_mask bit {bit}); it is not a setpoint here")
    if ign.any():
        k = np.flatnonzero(ign)
        notes.warn(f"{path.name}:{spec.where}: dropped {k.size} sample(s) whose type_mask marks "
                   f"{_base_field(spec.field)} as ignored ({fmt_t(t[k[0]], origin)}..{fmt_t(t[k[-1]], origin)})")
        return t[~ign], x[~ign]
    return t, x


def _channel(msgs: dict[str, list[TlogRow]], path: Path, spec: ChannelSpec, role: str, rule: str, *,
             sysid: int | None, time_source: str, origin: int, crop: tuple[int, int] | None, on_nan: str,
             notes: Notes) -> tuple[Series, dict]:
    """One channel of one tlog as a clean series, and its provenance (incl. the sender)."""
    rows = msgs.get(spec.source, [])
    if not rows:
        present = sorted(k for k in msgs if k != "HEARTBEAT")
        att = [k for k in _ATTITUDE_SETPOINTS if msgs.get(k)]
        if spec.source == "SET_POSITION_TARGET_LOCAL_NED" and att:
            raise DataError(
                f"{path} has attitude setpoints ({', '.join(att)}) but no SET_POSITION_TARGET_LOCAL_NED (for {role} "
                f"{spec.name!r}): an attitude off-board flight, like ddpc-bridge's -- the height reference a companion "
                "computer steered is in no MAVLink message. For the bridge's steering loop use its own tick log "
                "(ddpc-bridge --log flight.npz writes a dataset: ddpc-codegen codegen CONFIG --dataset flight.npz); "
                "for the attitude + throttle loop the autopilot reports use --preset ardupilot-guided-attitude")
        raise DataError(f"message {spec.source} (for {role} {spec.name!r}) is not in {path}; "
                        f"of the requested messages it has: {', '.join(present) or 'none'} "
                        "(list all with --list)")
    rows = _pick_source(rows, spec.source, spec.instance if spec.instance is not None else sysid, path,
                        f"{role} {spec.name!r}")
    fields = _flatten([r[3] for r in rows])
    t = _sample_times(rows, fields, spec, time_source)
    x, how = derive_field(fields, spec.field, f"message {spec.source} of {path}")
    t, x = _drop_ignored(fields, t, x, spec, path, origin, notes)
    raw = Series(spec.name, spec.unit, f"{path.name}:{spec.where}", t, x, rule, angle=spec.field in ANGLE_FIELDS)
    info = {"role": role, "name": spec.name, "unit": spec.unit, "spec": spec.text,
            "message": spec.source, "sysid": rows[0][1], "compid": rows[0][2],
            "field": spec.field, "derivation": how, "rule": rule,
            "angle_unwrapped": spec.field in ANGLE_FIELDS}
    return clean_series(raw, origin_us=origin, on_nan=on_nan, notes=notes, crop_us=crop), info


def _warn_not_flying(rows, systems: set[int], path: Path, notes: Notes) -> None:
    """A warning when a system whose outputs are imported reports a vehicle type that does not fly."""
    kinds = sorted({(r[1], r[3].type) for r in rows if r[1] in systems and r[3].type in _NOT_FLYING})
    for sys_id, typ in kinds:
        notes.warn(f"{path.name}: system {sys_id} reports HEARTBEAT type {typ} (MAV_TYPE_{_NOT_FLYING[typ]}): not a "
                   "flying vehicle; is this the right log?")


def _import_file(path: Path, ins: Sequence[ChannelSpec], outs: Sequence[ChannelSpec], wanted: set[str], *,
                 opts: ImportOptions, sysid: int | None, time_source: str, dialect: str,
                 notes: Notes) -> tuple[dict, list, int, list[dict]]:
    """One tlog: (file metadata, segments, time origin µs, channel provenance)."""
    msgs, first_us = read_tlog(path, sorted(wanted), dialect=dialect, notes=notes)
    origin = 0 if time_source == "boot" else first_us
    crop = crop_window(origin, opts.time_range)
    series: dict[str, list[Series]] = {"input": [], "output": []}
    info: list[dict] = []
    for role, specs, rule in (("input", ins, opts.input_rule), ("output", outs, opts.output_rule)):
        for s in specs:
            ser, ci = _channel(msgs, path, s, role, rule, sysid=sysid, time_source=time_source, origin=origin,
                               crop=crop, on_nan=opts.on_nan, notes=notes)
            series[role].append(ser)
            info.append(ci)
    _warn_not_flying(msgs.get("HEARTBEAT", []), {ci["sysid"] for ci in info if ci["role"] == "output"}, path, notes)
    senders = {(ci["sysid"], ci["compid"]) for ci in info}
    if time_source == "boot" and len(senders) > 1:
        raise DataError(f"time_source='boot' mixes clocks: channels come from systems/components "
                        f"{sorted(senders)}; use time_source='log'")
    wins = None
    if opts.filters_modes:
        # the vehicle whose mode counts is the one sending the outputs (state messages)
        out_sys = {ci["sysid"] for ci in info if ci["role"] == "output"}
        hb_sys = sysid if sysid is not None else (next(iter(out_sys)) if len(out_sys) == 1 else None)
        wins = _heartbeat_windows(msgs.get("HEARTBEAT", []), path, origin, hb_sys, offboard_only=opts.offboard_only,
                                  armed_only=opts.armed_only, split_on_mode=opts.split_on_mode)
    if crop is not None:
        wins = intersect_windows(wins, [(crop[0], crop[1], "")])
    segs = opts.segments(series["input"], series["output"], origin_us=origin, notes=notes, windows=wins,
                         what=str(path))
    meta = file_meta(path)
    meta.update({
        "format": "tlog",
        "log_start_us": origin,
        "messages": sorted(wanted),
        "channels": channel_summary(series["input"] + series["output"], origin),
    })
    return meta, segs, origin, info


def _settings(opts: ImportOptions, *, preset: str | None, dialect: str, time_source: str,
              sysid: int | None) -> dict:
    """How the import was run, for the dataset's metadata."""
    return {
        "source_format": "tlog",
        "importer": "ddpc_codegen.logs.import_tlog",
        "preset": preset,
        "dialect": dialect,
        "time_source": time_source,
        "time_base": ("seconds since each file's first tlog record (receive time)" if time_source == "log"
                      else "seconds since the sender's boot (time_boot_ms)"),
        "gap_rule": gap_rule_text(opts.max_gap, opts.gap_factor),
        "min_duration_s": float(opts.min_duration),
        "mode_filter": opts.mode_filter_settings(),
        "sysid": sysid,
        "time_range_s": None if opts.time_range is None else [float(v) for v in opts.time_range],
        "on_nan": opts.on_nan,
    }


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
    check_on_nan(on_nan)
    if time_source not in ("log", "boot"):
        raise DataError(f"time_source must be 'log' or 'boot'; got {time_source!r}")
    check_time_range(time_range)
    check_rule(input_rule, "input")
    check_rule(output_rule, "output")
    ins, outs = resolve_channels(preset, inputs, outputs, TLOG_PRESETS, "tlog")
    mod = load_dialect(dialect)
    ins, outs = with_mavlink_units(ins, mod), with_mavlink_units(outs, mod)
    opts = ImportOptions(rate_hz, max_gap, gap_factor, min_duration, offboard_only, armed_only, split_on_mode,
                         time_range, input_rule, output_rule, on_nan)
    if opts.filters_modes and time_source == "boot":
        raise DataError("mode filters need time_source='log': HEARTBEAT carries no time_boot_ms")
    notes = Notes()
    wanted = {s.source for s in ins + outs} | {"HEARTBEAT"}  # also for the vehicle type check
    if "SET_POSITION_TARGET_LOCAL_NED" in wanted:
        wanted |= set(_ATTITUDE_SETPOINTS)  # to tell an attitude off-board log apart when it is missing
    per_file, chan_info = [], []
    for fi, path in enumerate(path_list):
        meta, segs, origin, info = _import_file(path, ins, outs, wanted, opts=opts, sysid=sysid,
                                                time_source=time_source, dialect=dialect, notes=notes)
        per_file.append((meta, segs, origin))
        if fi == 0:
            chan_info = info
    settings = _settings(opts, preset=preset, dialect=dialect, time_source=time_source, sysid=sysid)
    return assemble(per_file, ins, outs, rate_hz=rate_hz, notes=notes, settings=settings, channel_info=chan_info)
