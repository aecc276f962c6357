"""Half-open time intervals in microseconds: where a channel is covered (split at gaps), where a
logged state (flight mode, arming) holds, and their intersections."""

from __future__ import annotations

from typing import Callable, Iterable, Sequence

import numpy as np

__all__ = ["Interval", "covered_intervals", "intersect_intervals", "state_windows", "intersect_windows"]

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
