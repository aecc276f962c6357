"""Resampling one clean channel onto the uniform controller grid (hold / linear / cubic)."""

from __future__ import annotations

import math

import numpy as np

from ddpc_codegen.errors import DataError
from ddpc_codegen.logs.series import Series

__all__ = ["RULES", "check_rule", "uniform_grid", "resample_series"]

RULES = ("hold", "linear", "cubic")


def check_rule(rule: str, role: str) -> str:
    """The resampling rule, if it is one of RULES; else DataError naming the role."""
    if rule not in RULES:
        raise DataError(f"{role} resampling rule must be one of {RULES}; got {rule!r}")
    return rule


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
    # imported here: scipy.interpolate costs ~0.4 s, which every ddpc-codegen command would pay at start-up
    from scipy.interpolate import CubicSpline, make_interp_spline

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
