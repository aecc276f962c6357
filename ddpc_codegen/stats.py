"""One percentile summary for every timing / latency report (solver, bridge, link, vehicle)."""

from __future__ import annotations

from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["percentiles"]


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
