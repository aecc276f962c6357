"""PX4 ULog flight logs -> IODataset (inputs: setpoints sent, outputs: what the vehicle did).

Channels are picked by ``[NAME=]TOPIC[@INSTANCE].FIELD[:UNIT]`` (see
:class:`~ddpc_codegen.logs.channels.ChannelSpec`), e.g.::

    pitch_ref=vehicle_attitude_setpoint.pitch     # Euler pitch of q_d, rad
    z_ref=trajectory_setpoint.z_up                # -position[2] (or -z on PX4 < 1.14), m
    z=vehicle_local_position.z_up                 # height, m, up
    pitch=vehicle_attitude.pitch                  # Euler pitch of q, rad

Times are PX4's ``timestamp`` field (µs since boot); errors quote seconds since the ULog's
start timestamp, as Flight Review's time axis does. Mode filters use ``vehicle_status``:
``nav_state`` (14 = offboard) and ``arming_state`` (2 = armed); vehicle_status is published
on every change, so a mode lasts from its first report to the next change.

What PX4 logs depends on the kind of off-board control (``offboard_control_mode``, measured on
PX4 SITL with SIH and the default logger profile): in *attitude* off-board (SET_ATTITUDE_TARGET,
what ``ddpc-bridge`` sends) it logs the attitude and thrust it was given
(``vehicle_attitude_setpoint``, ~20 Hz at the default profile), ``vehicle_attitude`` (250 Hz) and
``vehicle_local_position`` (125 Hz) -- preset ``px4-offboard-attitude`` -- but no
``trajectory_setpoint``: the height and pitch references a companion computer steered never
reach PX4. A preset that reads ``trajectory_setpoint`` is therefore refused on such a log, with
the advice to use the companion's own log (``ddpc-bridge --log``: a dataset already).
"""

from __future__ import annotations

import contextlib
import io
import struct
from pathlib import Path
from typing import Sequence

import numpy as np

from ddpc_codegen.design.data import IODataset
from ddpc_codegen.errors import DataError
from ddpc_codegen.logs.channels import ChannelSpec, resolve_channels
from ddpc_codegen.logs.dataset import assemble, channel_summary, file_meta
from ddpc_codegen.logs.fields import ANGLE_FIELDS, derive_field
from ddpc_codegen.logs.grid import check_rule
from ddpc_codegen.logs.intervals import intersect_windows, state_windows
from ddpc_codegen.logs.notes import Notes, fmt_t
from ddpc_codegen.logs.options import ImportOptions, check_on_nan, check_time_range, crop_window, gap_rule_text
from ddpc_codegen.logs.series import Series, clean_series
from ddpc_codegen.values.files import MAX_LOG_BYTES, checked_input_path

__all__ = ["import_ulog", "list_ulog_topics", "ULOG_PRESETS", "NAV_STATE_NAMES", "NAV_STATE_OFFBOARD"]

# preset -> (input specs, output specs)
ULOG_PRESETS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    # PogoX flying: height + pitch references from the companion, as PX4 logged them
    "pogox-flying": (
        ("z_ref=trajectory_setpoint.z_up:m", "pitch_ref=vehicle_attitude_setpoint.pitch:rad"),
        ("z=vehicle_local_position.z_up:m", "pitch=vehicle_attitude.pitch:rad"),
    ),
    # attitude loop: attitude + collective thrust setpoint -> attitude
    "attitude": (
        (
            "roll_ref=vehicle_attitude_setpoint.roll:rad",
            "pitch_ref=vehicle_attitude_setpoint.pitch:rad",
            "yaw_ref=vehicle_attitude_setpoint.yaw:rad",
            "thrust_ref=vehicle_attitude_setpoint.thrust_body[2]_up:1",
        ),
        ("roll=vehicle_attitude.roll:rad", "pitch=vehicle_attitude.pitch:rad", "yaw=vehicle_attitude.yaw:rad"),
    ),
    # PX4 in attitude off-board (a companion sending SET_ATTITUDE_TARGET, e.g. ddpc-bridge): the
    # attitude + collective thrust PX4 was given -> height and attitude (the loop under the
    # companion's controller; its own references are only in the companion's log)
    "px4-offboard-attitude": (
        (
            "roll_ref=vehicle_attitude_setpoint.roll:rad",
            "pitch_ref=vehicle_attitude_setpoint.pitch:rad",
            "yaw_ref=vehicle_attitude_setpoint.yaw:rad",
            "thrust_ref=vehicle_attitude_setpoint.thrust_body[2]_up:1",
        ),
        ("z=vehicle_local_position.z_up:m", "roll=vehicle_attitude.roll:rad", "pitch=vehicle_attitude.pitch:rad",
         "yaw=vehicle_attitude.yaw:rad"),
    ),
    # position loop: position setpoint -> position (x north, y east, z up)
    "position": (
        ("x_ref=trajectory_setpoint.x:m", "y_ref=trajectory_setpoint.y:m", "z_ref=trajectory_setpoint.z_up:m"),
        ("x=vehicle_local_position.x:m", "y=vehicle_local_position.y:m", "z=vehicle_local_position.z_up:m"),
    ),
}

NAV_STATE_OFFBOARD = 14
ARMING_STATE_ARMED = 2
NAV_STATE_NAMES = {
    0: "manual", 1: "altctl", 2: "posctl", 3: "auto_mission", 4: "auto_loiter", 5: "auto_rtl",
    10: "acro", 12: "descend", 13: "termination", 14: "offboard", 15: "stab", 17: "auto_takeoff",
    18: "auto_land", 19: "auto_follow_target", 20: "auto_precland", 21: "orbit",
    22: "auto_vtol_takeoff",
}


def _nav_name(v: int) -> str:
    return NAV_STATE_NAMES.get(v, f"nav_state_{v}")


def _read(path: Path, topics: Sequence[str] | None, notes: Notes):
    """Parse a ULog with pyulog; its stdout chatter about corruption becomes warnings."""
    from pyulog import ULog
    from pyulog.exceptions import ULogException

    if not path.exists():
        raise DataError(f"ULog file {path} does not exist")
    checked_input_path(path, "ULog file", MAX_LOG_BYTES, error=DataError)  # a FIFO or a device is never opened
    buf = io.StringIO()
    try:
        with contextlib.redirect_stdout(buf):
            ulog = ULog(str(path), message_name_filter_list=None if topics is None else sorted(set(topics)))
    except RecursionError:  # pyulog expands nested formats recursively
        raise DataError(f"{path}: ULog format: a message format contains itself (directly or through others); "
                        "not a readable ULog file") from None
    except (ULogException, OSError, ValueError, IndexError, KeyError, struct.error) as e:
        raise DataError(f"{path}: not a readable ULog file ({type(e).__name__}: {e})") from e
    for line in buf.getvalue().splitlines():
        if line.strip():
            notes.warn(f"{path.name}: pyulog: {line.strip()}")
    if ulog.file_corruption:
        notes.warn(f"{path.name}: pyulog detected corrupt bytes and skipped them; data may be missing there")
    return ulog


def _topic_fields(ulog, path: Path, topic: str, instance: int) -> tuple[np.ndarray, dict]:
    """(timestamps int64 µs (N,), field name -> (N,) array) of one topic instance."""
    data = [d for d in ulog.data_list if d.name == topic]
    if not data:
        full = _read(path, None, Notes())  # error path only: list what is logged
        logged = sorted({d.name for d in full.data_list})
        why = "is defined but has no logged samples" if topic in ulog.message_formats else "is not in the log"
        raise DataError(f"topic {topic!r} {why} ({path}); logged topics: {', '.join(logged) or 'none'}")
    inst = [d for d in data if d.multi_id == instance]
    if not inst:
        have = sorted(d.multi_id for d in data)
        raise DataError(f"topic {topic!r} has no instance {instance} in {path}; instances: {have}")
    d = inst[0]
    if "timestamp" not in d.data:
        raise DataError(f"topic {topic!r} in {path} has no 'timestamp' field")
    return d.data["timestamp"].astype(np.int64), d.data


def _mode_windows(
    ulog, path: Path, origin: int, *, offboard_only: bool, armed_only: bool, split_on_mode: bool
) -> list[tuple[int, int, str]] | None:
    """Allowed (a, b, label) windows from vehicle_status, or None when no mode filter is asked."""
    if not (offboard_only or armed_only or split_on_mode):
        return None
    what = "--offboard-only" if offboard_only else "--armed-only" if armed_only else "--split-on-mode"
    try:
        t, f = _topic_fields(ulog, path, "vehicle_status", 0)
    except DataError as e:
        raise DataError(f"{what} needs topic vehicle_status (nav_state, arming_state): {e}") from None
    t_end = int(ulog.last_timestamp)
    wins = None
    if offboard_only or split_on_mode:
        if "nav_state" not in f:
            raise DataError(f"{what}: vehicle_status in {path} has no field nav_state")
        keep = (lambda v: v == NAV_STATE_OFFBOARD) if offboard_only else None
        wins = [(a, b, _nav_name(v)) for a, b, v in state_windows(t, f["nav_state"], t_end_us=t_end, keep=keep)]
        if offboard_only and not wins:
            seen = sorted({_nav_name(int(v)) for v in f["nav_state"]})
            raise DataError(
                f"--offboard-only: {path} never is in offboard mode "
                f"({fmt_t(t[0], origin)}..{fmt_t(t_end, origin)}; modes seen: {', '.join(seen)})"
            )
    if armed_only:
        if "arming_state" not in f:
            raise DataError(f"--armed-only: vehicle_status in {path} has no field arming_state")
        arm = [(a, b, "armed") for a, b, _ in
               state_windows(t, f["arming_state"], t_end_us=t_end, keep=lambda v: v == ARMING_STATE_ARMED)]
        if not arm:
            raise DataError(f"--armed-only: the vehicle is never armed in {path}")
        wins = intersect_windows(wins, arm)
    return wins


def _refuse_attitude_offboard(ulog, path: Path, specs: Sequence[ChannelSpec]) -> None:
    """A ``trajectory_setpoint`` channel on a log whose off-board flight was attitude control only:
    PX4 published no trajectory_setpoint there, so say why and what to use instead."""
    if not any(s.source == "trajectory_setpoint" for s in specs):
        return
    ocm = [d for d in ulog.data_list if d.name == "offboard_control_mode"]
    if not ocm:
        return
    f = ocm[0].data
    on = {k: bool(np.any(f[k])) for k in ("position", "velocity", "acceleration", "attitude", "body_rate") if k in f}
    if on.get("attitude", False) and not any(on.get(k, False) for k in ("position", "velocity", "acceleration")):
        raise DataError(
            f"{path}: PX4 flew attitude off-board here (offboard_control_mode: attitude, never position, velocity "
            "or acceleration), so it published no trajectory_setpoint: the references a companion computer "
            "steered (z_ref ...) are not in PX4's log. For ddpc-bridge's steering loop use the bridge's own tick "
            "log instead (ddpc-bridge --log flight.npz writes a dataset: ddpc-codegen codegen CONFIG --dataset "
            "flight.npz); for the attitude + thrust loop PX4 did log use --preset px4-offboard-attitude")


def _channel(ulog, path: Path, spec: ChannelSpec, role: str, rule: str, *, origin: int,
             crop: tuple[int, int] | None, on_nan: str, notes: Notes) -> tuple[Series, dict]:
    """One channel of one ULog as a clean series, and its provenance."""
    inst = 0 if spec.instance is None else spec.instance
    t, fields = _topic_fields(ulog, path, spec.source, inst)
    x, how = derive_field(fields, spec.field, f"topic {spec.source!r} of {path}")
    raw = Series(spec.name, spec.unit, f"{path.name}:{spec.where}", t, x, rule, angle=spec.field in ANGLE_FIELDS)
    info = {"role": role, "name": spec.name, "unit": spec.unit, "spec": spec.text,
            "topic": spec.source, "instance": inst, "field": spec.field,
            "derivation": how, "rule": rule,
            "angle_unwrapped": spec.field in ANGLE_FIELDS}
    return clean_series(raw, origin_us=origin, on_nan=on_nan, notes=notes, crop_us=crop), info


def _import_file(path: Path, ins: Sequence[ChannelSpec], outs: Sequence[ChannelSpec], topics: set[str], *,
                 opts: ImportOptions, notes: Notes) -> tuple[dict, list, int, list[dict]]:
    """One ULog: (file metadata, segments, time origin µs, channel provenance)."""
    ulog = _read(path, sorted(topics), notes)
    origin = int(ulog.start_timestamp)
    crop = crop_window(origin, opts.time_range)
    _refuse_attitude_offboard(ulog, path, list(ins) + list(outs))
    series: dict[str, list[Series]] = {"input": [], "output": []}
    info: list[dict] = []
    for role, specs, rule in (("input", ins, opts.input_rule), ("output", outs, opts.output_rule)):
        for s in specs:
            ser, ci = _channel(ulog, path, s, role, rule, origin=origin, crop=crop, on_nan=opts.on_nan, notes=notes)
            series[role].append(ser)
            info.append(ci)
    wins = _mode_windows(ulog, path, origin, offboard_only=opts.offboard_only, armed_only=opts.armed_only,
                         split_on_mode=opts.split_on_mode)
    if crop is not None:
        wins = intersect_windows(wins, [(crop[0], crop[1], "")])
    segs = opts.segments(series["input"], series["output"], origin_us=origin, notes=notes, windows=wins,
                         what=str(path), rate_hint=" (PX4: SDLOG_PROFILE 'high rate' or a custom logger topic list)")
    if ulog.dropouts:
        lost = sum(d.duration for d in ulog.dropouts)
        notes.warn(f"{path.name}: the logger reported {len(ulog.dropouts)} dropout(s), {lost} ms in total "
                   f"(first at {fmt_t(ulog.dropouts[0].timestamp, origin)}); gaps they leave are split by the gap rule")
    meta = file_meta(path)
    meta.update({
        "format": "ulog",
        "log_start_us": origin,
        "duration_s": round((int(ulog.last_timestamp) - origin) / 1e6, 6),
        "sys_name": str(ulog.msg_info_dict.get("sys_name", "")),
        "ver_sw": str(ulog.msg_info_dict.get("ver_sw", "")),
        "topics": sorted({s.source if s.instance is None else f"{s.source}@{s.instance}" for s in list(ins) + list(outs)}),
        "channels": channel_summary(series["input"] + series["output"], origin),
    })
    return meta, segs, origin, info


def _settings(opts: ImportOptions, preset: str | None) -> dict:
    """How the import was run, for the dataset's metadata."""
    return {
        "source_format": "ulog",
        "importer": "ddpc_codegen.logs.import_ulog",
        "preset": preset,
        "time_base": "seconds since each file's ULog start timestamp",
        "gap_rule": gap_rule_text(opts.max_gap, opts.gap_factor),
        "min_duration_s": float(opts.min_duration),
        "mode_filter": opts.mode_filter_settings(),
        "time_range_s": None if opts.time_range is None else [float(v) for v in opts.time_range],
        "on_nan": opts.on_nan,
    }


def import_ulog(
    paths: str | Path | Sequence[str | Path],
    inputs: Sequence[str | ChannelSpec] | None = None,
    outputs: Sequence[str | ChannelSpec] | None = None,
    *,
    preset: str | None = None,
    rate_hz: float = 200.0,
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
    """Read PX4 ULog file(s) into an IODataset on a uniform ``rate_hz`` grid.

    Args:
        paths: one .ulg file or several (each contributes its own trajectories).
        inputs / outputs: channel specs ``[NAME=]TOPIC[@N].FIELD[:UNIT]``; appended to the
            preset's channels if ``preset`` is given (see ``ULOG_PRESETS``).
        rate_hz: controller rate of the grid (dt = 1/rate_hz s).
        max_gap: split at spells without samples longer than this (s); default per channel
            ``gap_factor`` x its median sampling interval.
        min_duration: drop (with a warning) trajectories shorter than this (s).
        offboard_only / armed_only: keep only offboard (nav_state 14) / armed spans;
            split_on_mode: split at every nav_state change (trajectories keep one mode).
        time_range: (start, end) in s since the log start, applied to every file.
        input_rule / output_rule: "hold" (zero-order hold), "linear" or "cubic".
        on_nan: "drop" NaN samples with a warning, or "error".
    Returns:
        IODataset, u (T_i, m) references, y (T_i, p) realized motion, with provenance metadata.
    Raises:
        DataError for missing files/topics/fields, backwards timestamps, no usable segment.
    """
    check_on_nan(on_nan)
    check_time_range(time_range)
    check_rule(input_rule, "input")
    check_rule(output_rule, "output")
    ins, outs = resolve_channels(preset, inputs, outputs, ULOG_PRESETS, "ULog")
    path_list = [paths] if isinstance(paths, (str, Path)) else list(paths)
    if not path_list:
        raise DataError("no ULog file given")
    opts = ImportOptions(rate_hz, max_gap, gap_factor, min_duration, offboard_only, armed_only, split_on_mode,
                         time_range, input_rule, output_rule, on_nan)
    notes = Notes()
    topics = {s.source for s in ins + outs}
    if opts.filters_modes:
        topics.add("vehicle_status")
    if "trajectory_setpoint" in topics:
        topics.add("offboard_control_mode")  # to tell an attitude off-board log (no trajectory_setpoint) apart
    per_file = []
    chan_info: list[dict] = []
    for fi, p in enumerate(path_list):
        meta, segs, origin, info = _import_file(Path(p), ins, outs, topics, opts=opts, notes=notes)
        per_file.append((meta, segs, origin))
        if fi == 0:
            chan_info = info
    return assemble(per_file, ins, outs, rate_hz=rate_hz, notes=notes, settings=_settings(opts, preset),
                    channel_info=chan_info)


def list_ulog_topics(path: str | Path) -> list[tuple[str, int, int, float, list[str]]]:
    """(topic, instance, samples, rate Hz, fields) for every logged topic, to choose channels."""
    notes = Notes()
    ulog = _read(Path(path), None, notes)
    out = []
    for d in ulog.data_list:
        t = d.data["timestamp"].astype(np.int64)
        rate = float(1e6 / np.median(np.diff(t))) if t.size > 1 and np.median(np.diff(t)) > 0 else 0.0
        out.append((d.name, d.multi_id, int(t.size), rate, [k for k in d.data if k != "timestamp"]))
    return out
