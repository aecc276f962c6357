"""Building the IODataset from every file's trajectories, with provenance metadata."""

from __future__ import annotations

import hashlib
import math
from pathlib import Path
from typing import Sequence

import numpy as np

from ddpc_codegen.logs.channels import ChannelSpec
from ddpc_codegen.logs.notes import Notes
from ddpc_codegen.logs.resample import RESAMPLING_RULE, Segment
from ddpc_codegen.logs.series import Series
from ddpc_codegen.design.data import IODataset

__all__ = ["assemble", "file_meta", "jsonable", "channel_summary"]


def jsonable(x):
    """numpy scalars/arrays -> plain Python, so provenance survives json.dumps."""
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return jsonable(x.tolist())
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def assemble(
    per_file: Sequence[tuple[dict, list[Segment], int]],
    ins: Sequence[ChannelSpec],
    outs: Sequence[ChannelSpec],
    *,
    rate_hz: float,
    notes: Notes,
    settings: dict,
    channel_info: Sequence[dict],
):
    """Build the IODataset from every file's segments, with provenance metadata.

    ``per_file`` holds (file metadata, segments, time origin µs) per log file; segment time
    ranges are recorded in seconds since that file's origin.
    """
    u, y, segs_meta = [], [], []
    for fi, (fmeta, segs, origin) in enumerate(per_file):
        for s in segs:
            u.append(s.u)
            y.append(s.y)
            segs_meta.append(
                {
                    "file": fi,
                    "file_name": fmeta.get("name", ""),
                    "t_start_s": round((int(s.t_us[0]) - origin) / 1e6, 6),
                    "t_end_s": round((int(s.t_us[-1]) - origin) / 1e6, 6),
                    "samples": int(s.t_us.size),
                    "mode": s.label,
                }
            )
    meta = {
        **settings,
        "rate_hz": float(rate_hz),
        "resampling": RESAMPLING_RULE,
        "inputs": [ci for ci in channel_info if ci["role"] == "input"],
        "outputs": [ci for ci in channel_info if ci["role"] == "output"],
        "files": [f for f, _, _ in per_file],
        "segments": segs_meta,
        "warnings": list(notes.items),
    }
    return IODataset(
        u,
        y,
        1.0 / float(rate_hz),
        input_names=[s.name for s in ins],
        output_names=[s.name for s in outs],
        input_units=[s.unit for s in ins],
        output_units=[s.unit for s in outs],
        metadata=jsonable(meta),
    )


def file_meta(path) -> dict:
    """Provenance of one log file: absolute path, name, size and SHA-256."""
    p = Path(path)
    h = hashlib.sha256()
    with open(p, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return {"path": str(p.resolve()), "name": p.name, "bytes": p.stat().st_size, "sha256": h.hexdigest()}


def channel_summary(series: Sequence[Series], origin_us: int) -> dict[str, dict]:
    """Per channel of one file: its source, first/last sample (s since the origin), count, log rate."""
    return {
        ser.name: {"source": ser.source, "t_first_s": round((int(ser.t_us[0]) - origin_us) / 1e6, 6),
                   "t_last_s": round((int(ser.t_us[-1]) - origin_us) / 1e6, 6),
                   "samples": int(ser.t_us.size), "log_rate_hz": ser.info.get("log_rate_hz")}
        for ser in series
    }
