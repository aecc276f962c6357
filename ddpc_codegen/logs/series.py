"""One logged channel as irregular samples, and its validation (order, duplicates, NaN, crop)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ddpc_codegen.errors import DataError
from ddpc_codegen.logs.fields import unwrap_angle
from ddpc_codegen.logs.notes import Notes, fmt_t

__all__ = ["Series", "clean_series"]


@dataclass
class Series:
    """One logged channel: sample times ``t_us`` (N,) int64 microseconds and values ``x`` (N,).

    ``rule`` is how it is resampled (hold / linear / cubic); ``angle`` marks radians to unwrap.
    """

    name: str
    unit: str
    source: str
    t_us: np.ndarray
    x: np.ndarray
    rule: str = "linear"
    angle: bool = False
    info: dict = field(default_factory=dict)

    @property
    def median_interval_us(self) -> float:
        return float(np.median(np.diff(self.t_us))) if self.t_us.size > 1 else math.inf


def _ranges(t_us: np.ndarray, idx: np.ndarray, origin_us: int, limit: int = 3) -> str:
    """Human list of where the flagged samples are: "12.000 s..12.340 s (35 samples), ..."."""
    if idx.size == 0:
        return ""
    breaks = np.flatnonzero(np.diff(idx) > 1)
    starts = np.r_[idx[0], idx[breaks + 1]]
    ends = np.r_[idx[breaks], idx[-1]]
    parts = [
        f"{fmt_t(t_us[a], origin_us)}..{fmt_t(t_us[b], origin_us)} ({b - a + 1} samples)"
        for a, b in zip(starts[:limit], ends[:limit])
    ]
    if starts.size > limit:
        parts.append(f"and {starts.size - limit} more run(s)")
    return ", ".join(parts)


def clean_series(
    s: Series, *, origin_us: int, on_nan: str, notes: Notes, crop_us: tuple[int, int] | None = None
) -> Series:
    """Validate one channel; returns a copy with strictly increasing times and finite values.

    Raises DataError for no samples, timestamps going backwards (the log is corrupt or spliced:
    re-ordering would invent an order) and, with ``on_nan="error"``, NaN/inf values.
    Drops (with a warning saying how many and where) NaN/inf samples when ``on_nan="drop"``
    and exact duplicate timestamps (the later sample wins: it is what a subscriber saw last).
    ``crop_us`` = [a, b): only samples stamped inside are kept, before any check, so a damaged
    part of a log can be left out with a time range.
    """
    t = np.asarray(s.t_us, dtype=np.int64)
    x = np.asarray(s.x, dtype=float)
    if t.size == 0:
        raise DataError(f"{s.source}: no samples in the log")
    if crop_us is not None:
        inside = (t >= crop_us[0]) & (t < crop_us[1])
        if not inside.any():
            raise DataError(
                f"{s.source}: no samples inside the time range {fmt_t(crop_us[0], origin_us)}..."
                f"{fmt_t(crop_us[1] - 1, origin_us)} (logged {fmt_t(t.min(), origin_us)}..{fmt_t(t.max(), origin_us)})"
            )
        t, x = t[inside], x[inside]
    d = np.diff(t)
    back = np.flatnonzero(d < 0)
    if back.size:
        i = int(back[0])
        more = (f"; {back.size} such places between {fmt_t(t[back[0]], origin_us)} and "
                f"{fmt_t(t[back[-1]], origin_us)}" if back.size > 1 else "")
        raise DataError(
            f"{s.source}: timestamps go backwards: {fmt_t(t[i], origin_us)} -> {fmt_t(t[i + 1], origin_us)} "
            f"(samples {i} -> {i + 1}){more}; the log is corrupt or spliced. "
            "Restrict the import to a clean part with time_range / --time-range"
        )
    dup = np.flatnonzero(d == 0)
    if dup.size:
        notes.warn(
            f"{s.source}: dropped {dup.size} sample(s) with a repeated timestamp (kept the later one) "
            f"at {_ranges(t, dup, origin_us)}"
        )
        keep = np.ones(t.size, dtype=bool)
        keep[dup] = False
        t, x = t[keep], x[keep]
    bad = np.flatnonzero(~np.isfinite(x))
    if bad.size:
        where = _ranges(t, bad, origin_us)
        if on_nan == "error":
            raise DataError(
                f"{s.source}: {bad.size} NaN/inf value(s) at {where}; "
                "crop them with --time-range, or pass --nan drop to drop those samples"
            )
        if bad.size == t.size:
            raise DataError(
                f"{s.source}: every sample is NaN/inf ({fmt_t(t[0], origin_us)}..{fmt_t(t[-1], origin_us)}); "
                "the field is not used in this flight (pick another topic/field)"
            )
        notes.warn(f"{s.source}: dropped {bad.size} NaN/inf sample(s) at {where}")
        keep = np.ones(t.size, dtype=bool)
        keep[bad] = False
        t, x = t[keep], x[keep]
    if s.angle:
        x = unwrap_angle(x)
    return Series(s.name, s.unit, s.source, t, x, s.rule, s.angle, dict(s.info))

