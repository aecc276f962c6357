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

import hashlib
import math
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable, Sequence

import numpy as np
from scipy.interpolate import CubicSpline, make_interp_spline

from ddpc_codegen.errors import DataError
from ddpc_codegen.logs.frames import unwrap_angle

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

RULES = ("hold", "linear", "cubic")

RESAMPLING_RULE = (
    "uniform grid t_k = t_start + k/rate_hz (integer microseconds) inside the intersection of all "
    "channels' covered intervals; hold: latest sample with timestamp <= t_k (zero-order hold); "
    "linear/cubic: scipy interpolation between the bracketing samples; angles unwrapped first; "
    "gaps longer than the gap threshold split trajectories and are never bridged; "
    "no extrapolation"
)


class LogImportWarning(UserWarning):
    """Something was dropped or is of doubtful quality while importing a log (the data was
    not changed to hide it: the message says what was dropped and where)."""


class Notes:
    """Collects import warnings: each is issued with :func:`warnings.warn` and kept for the
    dataset's provenance (``metadata['warnings']``)."""

    def __init__(self) -> None:
        self.items: list[str] = []

    def warn(self, msg: str) -> None:
        self.items.append(msg)
        warnings.warn(msg, LogImportWarning, stacklevel=3)


def fmt_t(t_us: int | float, origin_us: int) -> str:
    """A log time as seconds since the log's origin, the way errors quote time ranges."""
    return f"{(float(t_us) - origin_us) / 1e6:.3f} s"


# ---------------------------------------------------------------------------- channel specs
_SPEC_RE = re.compile(
    r"""^\s*(?:(?P<name>[A-Za-z_][\w\-]*)\s*=\s*)?      # optional NAME=
        (?P<source>[A-Za-z_]\w*)                        # topic / message name
        (?:@(?P<instance>\d+))?                         # optional @instance / @sysid
        \.(?P<field>[A-Za-z_][\w\[\]\.]*?)              # field (raw or derived)
        (?::(?P<unit>[^:=]*))?\s*$                      # optional :UNIT
    """,
    re.VERBOSE,
)

# Known units by (base) field name: PX4 uORB and MAVLink agree on SI units for these.
_UNITS: dict[str, str] = {
    **{k: "rad" for k in ("roll", "pitch", "yaw", "roll_body", "pitch_body", "yaw_body", "heading")},
    **{k: "rad/s" for k in ("rollspeed", "pitchspeed", "yawspeed", "yaw_rate", "yawspeed_setpoint",
                            "body_roll_rate", "body_pitch_rate", "body_yaw_rate")},
    **{k: "m" for k in ("x", "y", "z", "position[0]", "position[1]", "position[2]", "dist_bottom")},
    **{k: "m/s" for k in ("vx", "vy", "vz", "velocity[0]", "velocity[1]", "velocity[2]")},
    **{k: "m/s^2" for k in ("ax", "ay", "az", "afx", "afy", "afz",
                            "acceleration[0]", "acceleration[1]", "acceleration[2]")},
    **{k: "1" for k in ("thrust", "thrust_body[0]", "thrust_body[1]", "thrust_body[2]")},
}


def guess_unit(field_name: str) -> str:
    """Unit of a (possibly derived) field by name; "" if unknown (then say so, don't guess)."""
    base = field_name[:-3] if field_name.endswith("_up") else field_name
    return _UNITS.get(base, "")


def _default_name(field_name: str, role: str) -> str:
    base = field_name[:-3] if field_name.endswith("_up") else field_name
    base = re.sub(r"\[(\d+)\]", r"\1", base).replace(".", "_")
    return f"{base}_ref" if role == "input" and not base.endswith("_ref") else base


@dataclass(frozen=True)
class ChannelSpec:
    """One dataset channel as asked for on the command line.

    Syntax ``[NAME=]SOURCE[@N].FIELD[:UNIT]``:

    - SOURCE: ULog topic (``vehicle_attitude``) or MAVLink message (``ATTITUDE``);
      ``@N`` is the ULog multi-instance (default 0) or the MAVLink source system id.
    - FIELD: a raw field (``z``, ``q[0]``, ``thrust_body[2]``) or a derived one:
      ``roll``/``pitch``/``yaw`` (Euler ZYX in rad from ``q`` or ``q_d``), ``F_up`` (= -F, for a
      down-pointing NED/FRD field F: ``z_up``, ``vz_up``, ``thrust_body[2]_up``).
    - NAME: the dataset channel name (default: the field, ``_up`` dropped, ``_ref`` appended for
      inputs: ``trajectory_setpoint.z_up`` -> ``z_ref``, ``vehicle_attitude.pitch`` -> ``pitch``).
    - UNIT: the unit string (default: known SI unit of the field, else ""; MAVLink logs take
      the unit from the message definition instead, see ``logs.tlog.mavlink_unit``).
    ``unit_given``: the spec stated the unit (``:UNIT``).
    """

    name: str
    source: str
    instance: int | None
    field: str
    unit: str
    text: str
    unit_given: bool = False

    @property
    def where(self) -> str:
        inst = "" if self.instance is None else f"@{self.instance}"
        return f"{self.source}{inst}.{self.field}"


def parse_channel_spec(text: str | ChannelSpec, role: str) -> ChannelSpec:
    """Parse ``[NAME=]SOURCE[@N].FIELD[:UNIT]``; role is "input" or "output" (default names)."""
    if isinstance(text, ChannelSpec):
        return text
    m = _SPEC_RE.match(str(text))
    if m is None:
        raise DataError(
            f"bad {role} channel spec {text!r}: expected [NAME=]SOURCE[@N].FIELD[:UNIT], "
            "e.g. 'pitch_ref=vehicle_attitude_setpoint.pitch:rad' or 'ATTITUDE.pitch'"
        )
    fld = m["field"]
    unit = m["unit"].strip() if m["unit"] is not None else guess_unit(fld)
    return ChannelSpec(
        name=m["name"] or _default_name(fld, role),
        source=m["source"],
        instance=None if m["instance"] is None else int(m["instance"]),
        field=fld,
        unit=unit,
        text=str(text).strip(),
        unit_given=m["unit"] is not None,
    )


def check_names(inputs: Sequence[ChannelSpec], outputs: Sequence[ChannelSpec]) -> None:
    """Channel names must be unique across inputs and outputs (they key the dataset)."""
    if not inputs or not outputs:
        raise DataError(
            f"need at least one input and one output channel; got {len(inputs)} input(s) and "
            f"{len(outputs)} output(s) (use --preset or --input/--output)"
        )
    seen: dict[str, str] = {}
    for s in list(inputs) + list(outputs):
        if s.name in seen:
            raise DataError(
                f"channel name {s.name!r} is used twice ({seen[s.name]!r} and {s.text!r}); "
                "name one of them explicitly: NAME=SOURCE.FIELD"
            )
        seen[s.name] = s.text


# ---------------------------------------------------------------------------- raw series
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


# ---------------------------------------------------------------------------- intervals
Interval = tuple[int, int]  # half-open [a, b) in microseconds


def covered_intervals(t_us: np.ndarray, max_gap_us: float) -> list[Interval]:
    """Half-open intervals [first, last+1) of runs of samples with spacing <= max_gap_us."""
    t = np.asarray(t_us, dtype=np.int64)
    cut = np.flatnonzero(np.diff(t) > max_gap_us)
    starts = np.r_[0, cut + 1]
    ends = np.r_[cut, t.size - 1]
    return [(int(t[a]), int(t[b]) + 1) for a, b in zip(starts, ends)]


def intersect_intervals(a: Iterable[Interval], b: Iterable[Interval]) -> list[Interval]:
    """Intersection of two sorted lists of disjoint half-open intervals (boundaries kept,
    so adjacent windows [a,c), [c,b) stay separate trajectories)."""
    a, b = sorted(a), sorted(b)
    out: list[Interval] = []
    i = j = 0
    while i < len(a) and j < len(b):
        lo, hi = max(a[i][0], b[j][0]), min(a[i][1], b[j][1])
        if lo < hi:
            out.append((lo, hi))
        if a[i][1] <= b[j][1]:
            i += 1
        else:
            j += 1
    return out


def state_windows(
    t_us: np.ndarray,
    values: np.ndarray,
    *,
    t_end_us: int,
    keep: Callable[[int], bool] | None = None,
    until_next: bool = True,
) -> list[tuple[int, int, int]]:
    """Windows (a, b, value) of constant value of a logged state (flight mode, arming).

    ``until_next=True``: a value holds from its first report until the next change is reported
    (right for PX4's vehicle_status, published on every change). ``until_next=False``: only from
    its first to its last report (conservative, for 1 Hz MAVLink heartbeats, where the true
    switch lies somewhere between two reports). ``keep`` filters values.
    """
    t = np.asarray(t_us, dtype=np.int64)
    v = np.asarray(values).astype(np.int64)
    if t.size == 0:
        return []
    change = np.flatnonzero(v[1:] != v[:-1]) + 1
    starts = np.r_[0, change]
    ends = np.r_[change, t.size]  # exclusive sample index
    out = []
    for s, e in zip(starts, ends):
        val = int(v[s])
        if keep is not None and not keep(val):
            continue
        if until_next:
            b = int(t[e]) if e < t.size else int(t_end_us) + 1
        else:
            b = int(t[e - 1]) + 1
        out.append((int(t[s]), b, val))
    return out


def uniform_grid(a_us: int, b_us: int, rate_hz: float) -> np.ndarray:
    """Grid times (int64 µs) t_k = a + round(k * 1e6 / rate_hz) inside [a, b)."""
    step = 1e6 / float(rate_hz)
    n = int(math.floor((b_us - 1 - a_us) / step)) + 1 if b_us > a_us else 0
    k = np.arange(max(n, 0))
    g = a_us + np.round(k * step).astype(np.int64)
    return g[g < b_us]


def resample_series(s: Series, grid_us: np.ndarray) -> np.ndarray:
    """Values of one clean channel on grid times (all inside its covered span); shape (K,)."""
    t, x = s.t_us, s.x
    if grid_us.size == 0:
        return np.empty(0)
    if grid_us[0] < t[0] or grid_us[-1] > t[-1]:
        # build_segments never asks this; a direct caller would get an extrapolation
        raise DataError(
            f"{s.source}: resampling outside the logged span would extrapolate "
            f"(grid {grid_us[0]}..{grid_us[-1]} µs, samples {t[0]}..{t[-1]} µs)"
        )
    if s.rule == "hold":
        return x[np.searchsorted(t, grid_us, side="right") - 1]
    # only the samples bracketing the grid: the fit never reaches across a gap
    lo = max(int(np.searchsorted(t, grid_us[0], side="right")) - 1, 0)
    hi = min(int(np.searchsorted(t, grid_us[-1], side="left")) + 1, t.size)
    tt = (t[lo:hi] - grid_us[0]) / 1e6
    xx = x[lo:hi]
    tg = (grid_us - grid_us[0]) / 1e6
    if tt.size == 1:
        return np.full(grid_us.size, xx[0])
    if s.rule == "linear":
        return make_interp_spline(tt, xx, k=1)(tg)
    if s.rule == "cubic":
        return CubicSpline(tt, xx)(tg) if tt.size >= 3 else make_interp_spline(tt, xx, k=1)(tg)
    raise DataError(f"{s.source}: unknown resampling rule {s.rule!r}; choose one of {RULES}")


# ---------------------------------------------------------------------------- segments
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


def _check_grid_size(pieces: Sequence[tuple[int, int, str]], rate_hz: float, n_channels: int, what: str) -> None:
    """DataError before allocating when the grid would exceed MAX_GRID_SAMPLES."""
    span_s = sum(max(0, b - a) for a, b, _ in pieces) / 1e6
    n = span_s * rate_hz
    if n > MAX_GRID_SAMPLES:
        gib = n * (n_channels + 1) * 8 / 2**30
        raise DataError(
            f"--rate {rate_hz:g} Hz over {span_s:.1f} s of {Path(what).name} would make {n:.3g} grid samples "
            f"(~{gib:.3g} GiB for {n_channels} channels), above the limit of {MAX_GRID_SAMPLES:.3g}; use the "
            "controller rate (e.g. --rate 200) or cut the log with --time-range")


def build_segments(
    inputs: Sequence[Series],
    outputs: Sequence[Series],
    *,
    rate_hz: float,
    origin_us: int,
    notes: Notes,
    windows: Sequence[tuple[int, int, str]] | None = None,
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
    if not (rate_hz > 0 and math.isfinite(rate_hz)):
        raise DataError(f"rate must be a positive number of Hz; got {rate_hz}")
    if rate_hz > MAX_RATE_HZ:
        raise DataError(f"--rate {rate_hz:g} Hz is above {MAX_RATE_HZ:g} Hz: log time stamps are whole microseconds; "
                        "use the controller rate (e.g. --rate 200)")
    chans = list(inputs) + list(outputs)
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
    cover: list[Interval] | None = None
    for s in chans:
        c = covered_intervals(s.t_us, gap_threshold_us(s, max_gap_s, gap_factor))
        if len(c) > 1:
            gaps = ", ".join(f"{fmt_t(c[i][1] - 1, origin_us)}..{fmt_t(c[i + 1][0], origin_us)}" for i in range(min(3, len(c) - 1)))
            more = f" and {len(c) - 4} more" if len(c) > 4 else ""
            notes.warn(f"{s.source}: {len(c) - 1} gap(s) without samples, split there: {gaps}{more}")
        cover = c if cover is None else intersect_intervals(cover, c)
    assert cover is not None
    if windows is not None:
        pieces: list[tuple[int, int, str]] = []
        for a, b, lab in sorted(windows):
            for lo, hi in intersect_intervals(cover, [(a, b)]):
                pieces.append((lo, hi, lab))
    else:
        pieces = [(a, b, "") for a, b in cover]
    _check_grid_size(pieces, rate_hz, len(chans), what)
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
        spans = ", ".join(f"{s.source}: {fmt_t(s.t_us[0], origin_us)}..{fmt_t(s.t_us[-1], origin_us)}" for s in chans)
        win = ""
        if windows is not None:
            win = "; allowed windows: " + (
                ", ".join(f"{fmt_t(a, origin_us)}..{fmt_t(b - 1, origin_us)} {lab}".rstrip() for a, b, lab in list(windows)[:5])
                or "none (the requested mode never occurs)"
            )
        raise DataError(f"no time span of {what} where all channels have data{win}; channel spans: {spans}")
    return segs


# ---------------------------------------------------------------------------- assembly
def intersect_windows(
    a: Sequence[tuple[int, int, str]] | None, b: Sequence[tuple[int, int, str]] | None
) -> list[tuple[int, int, str]] | None:
    """Intersection of two labelled window lists (None = no restriction); labels joined."""
    if a is None:
        return None if b is None else list(b)
    if b is None:
        return list(a)
    out = []
    for a0, a1, la in a:
        for b0, b1, lb in b:
            lo, hi = max(a0, b0), min(a1, b1)
            if lo < hi:
                out.append((lo, hi, "+".join(x for x in (la, lb) if x)))
    return sorted(out)


def resolve_channels(
    preset: str | None,
    inputs: Sequence[str | ChannelSpec] | None,
    outputs: Sequence[str | ChannelSpec] | None,
    presets: dict[str, tuple[Sequence[str], Sequence[str]]],
    kind: str,
) -> tuple[list[ChannelSpec], list[ChannelSpec]]:
    """Preset channels (if any) followed by the explicit ones, parsed and checked."""
    pin: Sequence[str] = ()
    pout: Sequence[str] = ()
    if preset is not None:
        if preset not in presets:
            raise DataError(f"unknown {kind} preset {preset!r}; presets: {', '.join(sorted(presets))}")
        pin, pout = presets[preset]
    ins = [parse_channel_spec(s, "input") for s in list(pin) + list(inputs or [])]
    outs = [parse_channel_spec(s, "output") for s in list(pout) + list(outputs or [])]
    check_names(ins, outs)
    return ins, outs


def check_rule(rule: str, role: str) -> str:
    if rule not in RULES:
        raise DataError(f"{role} resampling rule must be one of {RULES}; got {rule!r}")
    return rule


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
    from ddpc_codegen.design.data import IODataset  # local: keep `logs` importable without the data layer loaded

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
