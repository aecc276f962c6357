"""From irregular logged samples to uniform-grid trajectories.

The rule, stated once (it is also written into every dataset's metadata):

- Time is kept in integer microseconds (the unit of ULog and tlog timestamps), so a hold
  decision "sample at or before grid time" is exact, never a float tie.
- A channel is *covered* from its first to its last sample, except across a gap: a spell
  without samples longer than ``max_gap`` seconds (default: ``gap_factor`` times that
  channel's median sampling interval). Gaps are never bridged: the log is split there.
- Trajectories are the intersection of all channels' covered intervals with the requested
  windows (mode filter, time range). Each becomes one trajectory of the dataset, on the grid
  ``t_k = t_start + k / rate_hz`` (rounded to the microsecond), never extrapolated.
- Setpoints (inputs, rule ``hold``) take the value of the latest sample with timestamp
  <= t_k: the zero-order hold a flight controller applies to the setpoint it last received.
- States (outputs, rule ``linear``/``cubic``) are interpolated with scipy between the samples
  that bracket t_k (``make_interp_spline`` k=1 / ``CubicSpline``), inside a covered interval.
- Angle channels are unwrapped (continuous) before resampling; interpolating across ±π
  would invent a spin, and the closed loop is LTI in the continuous angle.
- Trajectories shorter than ``min_duration`` seconds are dropped with a warning naming them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from ddpc_codegen.errors import DataError
from ddpc_codegen.logs.channels import ChannelSpec, parse_channel_spec
from ddpc_codegen.logs.grid import RULES, resample_series, uniform_grid
from ddpc_codegen.logs.intervals import Interval, covered_intervals, intersect_intervals, state_windows
from ddpc_codegen.logs.notes import LogImportWarning, Notes, fmt_t
from ddpc_codegen.logs.series import Series, clean_series

# The steps of the rule live in their own modules (channels, series, intervals, grid); this module
# joins them into trajectories and keeps their names importable from here, as before the split.
__all__ = [
    "RULES",
    "LogImportWarning",
    "Notes",
    "ChannelSpec",
    "parse_channel_spec",
    "Series",
    "Segment",
    "clean_series",
    "covered_intervals",
    "intersect_intervals",
    "state_windows",
    "uniform_grid",
    "resample_series",
    "build_segments",
    "fmt_t",
    "RESAMPLING_RULE",
]

RESAMPLING_RULE = (
    "uniform grid t_k = t_start + k/rate_hz (integer microseconds) inside the intersection of all "
    "channels' covered intervals; hold: latest sample with timestamp <= t_k (zero-order hold); "
    "linear/cubic: scipy interpolation between the bracketing samples; angles unwrapped first; "
    "gaps longer than the gap threshold split trajectories and are never bridged; "
    "no extrapolation"
)


@dataclass
class Segment:
    """One trajectory on the grid: times ``t_us`` (K,), inputs ``u`` (K, m), outputs ``y`` (K, p)."""

    t_us: np.ndarray
    u: np.ndarray
    y: np.ndarray
    label: str = ""


def gap_threshold_us(s: Series, max_gap_s: float | None, gap_factor: float) -> float:
    """Gap threshold of one channel: ``max_gap_s`` if given, else gap_factor x median interval."""
    if max_gap_s is not None:
        return float(max_gap_s) * 1e6
    return gap_factor * s.median_interval_us if s.t_us.size > 1 else math.inf


# Memory bound of a resampled dataset: grid samples over all segments (x channels x 8 bytes, plus the
# grid itself). 5e7 samples is 69 hours at 200 Hz; a --rate typo (1e9) would otherwise allocate GiBs.
MAX_GRID_SAMPLES = 50_000_000
MAX_RATE_HZ = 1e6


Window = tuple[int, int, str]  # half-open [a, b) in microseconds, with a label (flight mode)


def check_rate(rate_hz: float) -> None:
    """DataError for a grid rate that is not a positive number of Hz the µs time stamps can carry."""
    if not (rate_hz > 0 and math.isfinite(rate_hz)):
        raise DataError(f"rate must be a positive number of Hz; got {rate_hz}")
    if rate_hz > MAX_RATE_HZ:
        raise DataError(f"--rate {rate_hz:g} Hz is above {MAX_RATE_HZ:g} Hz: log time stamps are whole microseconds; "
                        "use the controller rate (e.g. --rate 200)")


def check_grid_size(pieces: Sequence[Window], rate_hz: float, n_channels: int, what: str) -> None:
    """DataError before allocating when the grid would exceed MAX_GRID_SAMPLES."""
    span_s = sum(max(0, b - a) for a, b, _ in pieces) / 1e6
    n = span_s * rate_hz
    if n > MAX_GRID_SAMPLES:
        gib = n * (n_channels + 1) * 8 / 2**30
        raise DataError(
            f"--rate {rate_hz:g} Hz over {span_s:.1f} s of {Path(what).name} would make {n:.3g} grid samples "
            f"(~{gib:.3g} GiB for {n_channels} channels), above the limit of {MAX_GRID_SAMPLES:.3g}; use the "
            "controller rate (e.g. --rate 200) or cut the log with --time-range")


def note_slow_channels(chans: Sequence[Series], rate_hz: float, notes: Notes, rate_hint: str) -> None:
    """Record each channel's log rate; warn where most grid values would be held/interpolated."""
    for s in chans:
        if s.t_us.size > 1:
            log_hz = 1e6 / s.median_interval_us
            s.info["log_rate_hz"] = round(log_hz, 3)
            if log_hz < rate_hz / 2:
                how = "held" if s.rule == "hold" else f"{s.rule}-interpolated"
                notes.warn(
                    f"{s.source} is logged at ~{log_hz:.1f} Hz but resampled to {rate_hz:g} Hz: "
                    f"most grid values are {how}, not logged samples; log it at the controller rate "
                    f"for a faithful dataset{rate_hint}"
                )


def common_coverage(
    chans: Sequence[Series], *, origin_us: int, notes: Notes, max_gap_s: float | None, gap_factor: float
) -> list[Interval]:
    """Where every channel has data: the intersection of their covered intervals (gaps warned)."""
    cover: list[Interval] | None = None
    for s in chans:
        c = covered_intervals(s.t_us, gap_threshold_us(s, max_gap_s, gap_factor))
        if len(c) > 1:
            gaps = ", ".join(f"{fmt_t(c[i][1] - 1, origin_us)}..{fmt_t(c[i + 1][0], origin_us)}" for i in range(min(3, len(c) - 1)))
            more = f" and {len(c) - 4} more" if len(c) > 4 else ""
            notes.warn(f"{s.source}: {len(c) - 1} gap(s) without samples, split there: {gaps}{more}")
        cover = c if cover is None else intersect_intervals(cover, c)
    assert cover is not None
    return cover


def pieces_in_windows(cover: Sequence[Interval], windows: Sequence[Window] | None) -> list[Window]:
    """The covered intervals cut to the allowed windows, each labelled with its window's label."""
    if windows is None:
        return [(a, b, "") for a, b in cover]
    pieces: list[Window] = []
    for a, b, lab in sorted(windows):
        for lo, hi in intersect_intervals(cover, [(a, b)]):
            pieces.append((lo, hi, lab))
    return pieces


def _no_span_error(chans: Sequence[Series], windows: Sequence[Window] | None, origin_us: int, what: str) -> DataError:
    """The error when no piece is left at all, listing each channel's span and the allowed windows."""
    spans = ", ".join(f"{s.source}: {fmt_t(s.t_us[0], origin_us)}..{fmt_t(s.t_us[-1], origin_us)}" for s in chans)
    win = ""
    if windows is not None:
        win = "; allowed windows: " + (
            ", ".join(f"{fmt_t(a, origin_us)}..{fmt_t(b - 1, origin_us)} {lab}".rstrip() for a, b, lab in list(windows)[:5])
            or "none (the requested mode never occurs)"
        )
    return DataError(f"no time span of {what} where all channels have data{win}; channel spans: {spans}")


def build_segments(
    inputs: Sequence[Series],
    outputs: Sequence[Series],
    *,
    rate_hz: float,
    origin_us: int,
    notes: Notes,
    windows: Sequence[Window] | None = None,
    max_gap_s: float | None = None,
    gap_factor: float = 5.0,
    min_duration_s: float = 1.0,
    what: str = "log",
    rate_hint: str = "",
) -> list[Segment]:
    """Split clean channels into trajectories and resample each onto the uniform grid.

    Args:
        inputs / outputs: clean series (see :func:`clean_series`), rules already set.
        rate_hz: controller rate of the grid.
        origin_us: time origin used in messages (log start).
        windows: allowed (a, b, label) windows (mode filter, time range); None = everything.
        max_gap_s / gap_factor: gap rule (see module docstring).
        min_duration_s: trajectories shorter than this are dropped with a warning.
        what / rate_hint: the log's name, and how to log faster, for messages.
    Returns:
        segments in time order. Raises DataError if none is left, naming what was found.
    """
    check_rate(rate_hz)
    chans = list(inputs) + list(outputs)
    note_slow_channels(chans, rate_hz, notes, rate_hint)
    cover = common_coverage(chans, origin_us=origin_us, notes=notes, max_gap_s=max_gap_s, gap_factor=gap_factor)
    pieces = pieces_in_windows(cover, windows)
    check_grid_size(pieces, rate_hz, len(chans), what)
    min_n = max(2, int(math.ceil(min_duration_s * rate_hz)))
    segs: list[Segment] = []
    short: list[str] = []
    for a, b, lab in pieces:
        g = uniform_grid(a, b, rate_hz)
        if g.size < min_n:
            if g.size:
                short.append(f"{fmt_t(g[0], origin_us)}..{fmt_t(g[-1], origin_us)} ({g.size} samples)")
            continue
        u = np.column_stack([resample_series(s, g) for s in inputs])
        y = np.column_stack([resample_series(s, g) for s in outputs])
        segs.append(Segment(g, u, y, lab))
    if short:
        listing = ", ".join(short[:5]) + (f" and {len(short) - 5} more" if len(short) > 5 else "")
        msg = (
            f"dropped {len(short)} segment(s) shorter than min_duration={min_duration_s:g} s "
            f"({min_n} samples at {rate_hz:g} Hz): {listing}"
        )
        if segs:
            notes.warn(f"{Path(what).name}: {msg}")
        else:
            raise DataError(f"no usable segment in {what}: {msg}; lower --min-duration or --rate, or raise --max-gap")
    if not segs:
        raise _no_span_error(chans, windows, origin_us, what)
    return segs
