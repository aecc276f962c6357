"""``ddpc-codegen import-ulog`` / ``import-tlog``: flight logs -> IODataset .npz."""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path
from typing import Callable

from ddpc_codegen.design.data import IODataset, output_path
from ddpc_codegen.errors import DataError
from ddpc_codegen.logs.resample import RULES, LogImportWarning
from ddpc_codegen.logs.tlog import TLOG_PRESETS, import_tlog, list_tlog_messages
from ddpc_codegen.logs.ulog import ULOG_PRESETS, import_ulog, list_ulog_topics

__all__ = ["register"]

_SPEC_HELP = """\
channel spec: [NAME=]SOURCE[@N].FIELD[:UNIT]
  SOURCE  ULog topic (vehicle_attitude) / MAVLink message (ATTITUDE); @N = ULog instance / MAVLink sysid
  FIELD   raw field (z, q[0], thrust_body[2]) or derived:
            roll|pitch|yaw  Euler ZYX in rad from the quaternion q / q_d
            F_up            -F: NED/FRD down -> up (z_up, vz_up, thrust_body[2]_up)
  NAME    dataset channel (default: field without _up, plus _ref for inputs: z_up -> z_ref)
  UNIT    unit string (default: tlog: the unit in the MAVLink message definition, e.g. VFR_HUD.heading
          deg, GLOBAL_POSITION_INT.vz cm/s, none if it gives none; ulog: the field's SI unit if known).
          Units are labels, never converted: a tlog UNIT that contradicts the definition is an error

resampling: uniform grid at --rate; inputs held (latest sample <= t, zero-order hold),
outputs interpolated (scipy); angles unwrapped; split at gaps (never bridged), mode
changes (--split-on-mode) and to offboard spans (--offboard-only: PX4 OFFBOARD, ArduPilot GUIDED /
GUIDED_NOGPS; ArduPilot modes are decoded with the vehicle type's mode map); no extrapolation.
"""


def _presets_help(presets: dict) -> str:
    lines = ["presets:"]
    for name, (ins, outs) in presets.items():
        lines.append(f"  {name}:")
        lines.append(f"    inputs : {'  '.join(ins)}")
        lines.append(f"    outputs: {'  '.join(outs)}")
    return "\n".join(lines)


def _common(p: argparse.ArgumentParser, presets: dict) -> None:
    p.add_argument("files", nargs="+", metavar="FILE", help="log file(s); each adds its own trajectories")
    p.add_argument("-o", "--out", metavar="DATA.npz", help="dataset file to write (required unless --list)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    p.add_argument("--preset", choices=sorted(presets), help="named channel set (see below)")
    p.add_argument("--input", action="append", default=[], metavar="SPEC", help="input (setpoint) channel; repeatable")
    p.add_argument("--output", action="append", default=[], metavar="SPEC", help="output (state) channel; repeatable")
    p.add_argument("--rate", type=float, default=200.0, metavar="HZ", help="controller rate of the grid (default 200; at most 1e6 Hz and 5e7 grid samples in all)")
    p.add_argument("--max-gap", type=float, default=None, metavar="S",
                   help="split at spells longer than S seconds without samples (default: --gap-factor x median interval)")
    p.add_argument("--gap-factor", type=float, default=5.0, metavar="K", help="default gap threshold factor (5)")
    p.add_argument("--min-duration", type=float, default=1.0, metavar="S",
                   help="drop trajectories shorter than S seconds (default 1)")
    p.add_argument("--offboard-only", action="store_true", help="keep only offboard-mode spans (PX4 OFFBOARD; ArduPilot GUIDED, GUIDED_NOGPS)")
    p.add_argument("--armed-only", action="store_true", help="keep only armed spans")
    p.add_argument("--split-on-mode", action="store_true", help="split trajectories at every flight-mode change")
    p.add_argument("--time-range", nargs=2, type=float, metavar=("START", "END"),
                   help="keep only this window (seconds since log start)")
    p.add_argument("--input-rule", choices=RULES, default="hold", help="input resampling (default hold)")
    p.add_argument("--output-rule", choices=RULES, default="linear", help="output resampling (default linear)")
    p.add_argument("--nan", choices=("drop", "error"), default="drop",
                   help="NaN samples: drop with a warning (default) or fail")
    p.add_argument("--list", action="store_true", help="list the log's topics/messages and fields, then exit")


def register(subparsers) -> None:
    """Add the ``import-ulog`` and ``import-tlog`` subcommands."""
    fmt = argparse.RawDescriptionHelpFormatter
    pu = subparsers.add_parser(
        "import-ulog",
        help="PX4 ULog flight log(s) -> IODataset .npz",
        description="Build an IODataset (inputs = setpoints sent, outputs = what the vehicle did) from PX4 ULog files.",
        epilog=_SPEC_HELP + "\n" + _presets_help(ULOG_PRESETS) + """

examples:
  ddpc-codegen import-ulog flight.ulg --preset pogox-flying --offboard-only -o data.npz
  ddpc-codegen import-ulog a.ulg b.ulg --input pitch_ref=vehicle_attitude_setpoint.pitch \\
      --output pitch=vehicle_attitude.pitch --rate 200 -o pitch.npz
  ddpc-codegen import-ulog flight.ulg --list
""",
        formatter_class=fmt,
    )
    _common(pu, ULOG_PRESETS)
    pu.set_defaults(func=_run_ulog)

    pt = subparsers.add_parser(
        "import-tlog",
        help="MAVLink telemetry log(s) -> IODataset .npz",
        description="Build an IODataset from MAVLink telemetry logs (.tlog: 8-byte big-endian µs timestamp + "
        "packet records). The bridge's own logs are IODataset .npz files already: they are loaded as they are.",
        epilog=_SPEC_HELP + "\n" + _presets_help(TLOG_PRESETS) + """

examples:
  ddpc-codegen import-tlog flight.tlog --preset pogox-flying --offboard-only -o data.npz
  ddpc-codegen import-tlog flight.tlog --input SET_ATTITUDE_TARGET.pitch --output ATTITUDE.pitch --sysid 1 -o d.npz
  ddpc-codegen import-tlog flight.tlog --list
""",
        formatter_class=fmt,
    )
    _common(pt, TLOG_PRESETS)
    pt.add_argument("--sysid", type=int, default=None, help="keep only messages from this MAVLink system id")
    pt.add_argument("--time-source", choices=("log", "boot"), default="log",
                    help="tlog receive time (default) or the messages' time_boot_ms")
    pt.add_argument("--dialect", default="common", help="pymavlink dialect for decoding (default common)")
    pt.set_defaults(func=_run_tlog)


def _common_kwargs(args: argparse.Namespace) -> dict:
    return dict(
        preset=args.preset,
        rate_hz=args.rate,
        max_gap=args.max_gap,
        gap_factor=args.gap_factor,
        min_duration=args.min_duration,
        offboard_only=args.offboard_only,
        armed_only=args.armed_only,
        split_on_mode=args.split_on_mode,
        time_range=None if args.time_range is None else tuple(args.time_range),
        input_rule=args.input_rule,
        output_rule=args.output_rule,
        on_nan=args.nan,
    )


def _with_warnings(fn: Callable[[], IODataset]) -> IODataset:
    """Run an import, printing each LogImportWarning to stderr (they are also in metadata)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", LogImportWarning)
        try:
            return fn()
        finally:
            for w in caught:
                if issubclass(w.category, LogImportWarning):
                    print(f"warning: {w.message}", file=sys.stderr)
                else:
                    warnings.showwarning(w.message, w.category, w.filename, w.lineno)


def _summary(ds: IODataset, out: Path) -> str:
    md = ds.metadata
    lines = [f"wrote {out}: {ds.n_trajectories} trajectories, {ds.n_samples} samples, "
             f"dt={ds.dt:g} s ({1 / ds.dt:g} Hz)"]
    for role, names, units in (("inputs", ds.input_names, ds.input_units), ("outputs", ds.output_names, ds.output_units)):
        info = {c["name"]: c for c in md.get(role, [])}
        parts = []
        for n, u in zip(names, units):
            c = info.get(n)
            src = f" <- {c.get('topic') or c.get('message')}.{c['field']} ({c['rule']})" if c else ""
            parts.append(f"{n} [{u or '?'}]{src}")
        lines.append(f"  {role:7s}: " + "; ".join(parts))
    for s in md.get("segments", [])[:20]:
        mode = f", {s['mode']}" if s.get("mode") else ""
        lines.append(f"  {s['file_name']} {s['t_start_s']:.3f}..{s['t_end_s']:.3f} s ({s['samples']} samples{mode})")
    if len(md.get("segments", [])) > 20:
        lines.append(f"  ... {len(md['segments']) - 20} more segments")
    return "\n".join(lines)


def _need_out(args: argparse.Namespace) -> Path:
    """The checked output file (refused before any log is read: a folder, or an existing file without
    --overwrite)."""
    if not args.out:
        raise DataError("-o/--out DATA.npz is required (or use --list to inspect the log)")
    return output_path(args.out, args.overwrite)


def _run_ulog(args: argparse.Namespace) -> int:
    if args.list:
        for f in args.files:
            print(f"{f}:")
            for name, inst, n, rate, fields in list_ulog_topics(f):
                print(f"  {name}@{inst}: {n} samples, ~{rate:.1f} Hz: {', '.join(fields)}")
        return 0
    out = _need_out(args)
    ds = _with_warnings(lambda: import_ulog(args.files, args.input, args.output, **_common_kwargs(args)))
    path = ds.save(out, overwrite=args.overwrite)
    print(_summary(ds, path))
    return 0


def _run_tlog(args: argparse.Namespace) -> int:
    if args.list:
        for f in args.files:
            print(f"{f}:")
            for name, s, c, n, rate, fields in list_tlog_messages(f, dialect=args.dialect):
                print(f"  {name}@{s} (component {c}): {n} msgs, ~{rate:.1f} Hz: {', '.join(fields)}")
        return 0
    if all(Path(f).suffix == ".npz" for f in args.files):
        ds = import_tlog(args.files)
        print(f"{', '.join(args.files)}: already an IODataset (the bridge's log), no conversion needed: {ds!r}")
        if args.out:
            print(f"wrote {ds.save(args.out, overwrite=args.overwrite)}")
        return 0
    out = _need_out(args)
    ds = _with_warnings(lambda: import_tlog(args.files, args.input, args.output, sysid=args.sysid,
                                            time_source=args.time_source, dialect=args.dialect,
                                            **_common_kwargs(args)))
    path = ds.save(out, overwrite=args.overwrite)
    print(_summary(ds, path))
    return 0
