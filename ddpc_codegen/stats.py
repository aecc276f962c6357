"""One percentile summary for every timing / latency report (solver, bridge, link, vehicle)."""

from __future__ import annotations

from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["percentiles", "step_rms", "limit_share"]


def percentiles(a: ArrayLike, qs: Sequence[float] = (50, 99)) -> dict[str, float | int | None]:
    """``{"p50": .., "p99": .., "max": .., "n": ..}`` of the finite values of ``a`` (any shape).

    Keys are ``p<q>`` for each q in ``qs`` (``p99.9`` for fractional q), then ``max`` and the
    count ``n`` of finite values; with none, every statistic is None (JSON null), never NaN.
    Units are the caller's (name the dict for them, e.g. ``solve_us``).
    """
    x = np.asarray(a, dtype=float).ravel()
    x = x[np.isfinite(x)]
    keys = [f"p{q:g}" for q in qs]
    if x.size == 0:
        return {**{k: None for k in keys}, "max": None, "n": 0}
    vals = np.percentile(x, list(qs))
    return {**{k: float(v) for k, v in zip(keys, vals)}, "max": float(x.max()), "n": int(x.size)}


def step_rms(x: ArrayLike, mask: ArrayLike | None = None) -> list[float | None]:
    """Per column of ``x`` (N, c): the rms of the tick-to-tick change x[k+1] - x[k] over the pairs
    whose both ticks are in ``mask`` (N,) bool (default all), in x's units per tick.

    Used on the steering offset u - r_nom: how much the steered reference jumps from one tick to
    the next (a loop reacting to noise jitters it; a feed-forward table does not). None (JSON null)
    for a column without any pair.
    """
    a = np.asarray(x, dtype=float)
    a = a.reshape(a.shape[0], -1)
    keep = np.ones(a.shape[0], bool) if mask is None else np.asarray(mask, dtype=bool).ravel()
    if keep.shape[0] != a.shape[0]:
        raise ValueError(f"mask has {keep.shape[0]} ticks, x has {a.shape[0]}")
    pairs = keep[1:] & keep[:-1]
    if not np.any(pairs):
        return [None] * a.shape[1]
    d = np.diff(a, axis=0)[pairs]
    return [float(v) for v in np.sqrt(np.mean(d * d, axis=0))]


def limit_share(x: ArrayLike, lo: float, hi: float, mask: ArrayLike | None = None, tol: float = 1e-6) -> float | None:
    """The fraction of the samples of ``x`` (N,) in ``mask`` (N,) bool (default all) that sit at a
    limit: x <= lo + tol or x >= hi - tol. None (JSON null) without any sample.

    Used on the controller's normalized thrust setpoint (limits 0 and 1): a clamped thrust is where the
    closed loop stops being the linear one the data describe, and at 0 the rotors lose attitude authority.
    """
    a = np.asarray(x, dtype=float).ravel()
    keep = np.ones(a.shape[0], bool) if mask is None else np.asarray(mask, dtype=bool).ravel()
    if keep.shape[0] != a.shape[0]:
        raise ValueError(f"mask has {keep.shape[0]} samples, x has {a.shape[0]}")
    v = a[keep]
    if v.size == 0:
        return None
    return float(np.mean((v <= lo + tol) | (v >= hi - tol)))
