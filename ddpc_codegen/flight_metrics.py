"""The figures of one flight from its per-tick arrays: one scoring path for every run.

In-process runs (:func:`ddpc_codegen.experiments.evaluate.scenario_metrics` via
:func:`ddpc_codegen.sim.metrics.compute_metrics`) and runs over the link (the bridge's summary,
:func:`ddpc_codegen.testbed.sitl_demo.flight_figures`, the bridge demos) hand their arrays to
:func:`flight_metrics`, so "rmse z" is one computation wherever it is printed. numpy only (the
bridge on the companion computer uses it).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ddpc_codegen.stats import limit_share, step_rms

__all__ = ["flight_metrics", "rms", "scored_ticks", "near_changes"]


def rms(e: ArrayLike, empty: Any = None) -> Any:
    """sqrt(mean(e^2)) over every value of ``e`` (any shape, its units); ``empty`` without any value."""
    e = np.asarray(e, dtype=float)
    return float(np.sqrt(np.mean(e * e))) if e.size else empty


def scored_ticks(t: ArrayLike, settle: float = 0.0, active: ArrayLike | None = None) -> np.ndarray:
    """(N,) bool: the ticks a flight is scored on -- ``active`` (default all) and trajectory time
    ``t`` [s] >= ``settle`` (a NaN time, before the trajectory started, never counts)."""
    t = np.asarray(t, dtype=float).ravel()
    on = np.nan_to_num(t, nan=-np.inf) >= settle
    if active is not None:
        active = np.asarray(active, dtype=bool).ravel()
        if active.shape != t.shape:
            raise ValueError(f"active has {active.shape[0]} ticks, t has {t.shape[0]}")
        on &= active
    return on


def near_changes(t: ArrayLike, y_des: ArrayLike, before: float = 0.5, after: float = 1.5,
                 eps: float = 5e-4) -> np.ndarray:
    """(N,) bool: the ticks within [-before, +after] s [trajectory time ``t``] of a tick where the desired height
    (``y_des`` (N,), m) moves by more than ``eps`` m from the tick before: a step's lead, its ramp and the settling
    after it. The rest is the path holding still (or moving slower than ``eps`` per tick)."""
    t = np.asarray(t, dtype=float).ravel()
    z = np.asarray(y_des, dtype=float).ravel()
    moving = np.zeros(t.shape, dtype=bool)
    moving[1:] = np.abs(np.diff(z)) > eps  # NaN (before the trajectory) never moves
    out = np.zeros(t.shape, dtype=bool)
    tm = np.sort(t[moving])
    if tm.size:  # distance to the nearest moving tick on each side
        i = np.searchsorted(tm, np.nan_to_num(t, nan=-np.inf))
        nxt = np.where(i < tm.size, tm[np.minimum(i, tm.size - 1)], np.inf) - t
        prv = t - np.where(i > 0, tm[np.maximum(i - 1, 0)], -np.inf)
        out = (nxt <= before) | (prv <= after)
    return out & np.isfinite(t)


def flight_metrics(t: ArrayLike, y: ArrayLike, y_des: ArrayLike, *, settle: float = 0.0,
                   active: ArrayLike | None = None, u: ArrayLike | None = None, r_nom: ArrayLike | None = None,
                   thrust: ArrayLike | None = None, z_truth: ArrayLike | None = None,
                   steered: ArrayLike | None = None, empty: Any = None) -> dict[str, Any]:
    """The figures of a flight over its scored ticks (:func:`scored_ticks`: ``active`` and t >= ``settle``).

    Args:
        t: (N,) trajectory time [s] (NaN before it starts).
        y, y_des: (N, p) the outputs scored and the desired ones (output 0 is the height z [m]).
        active: (N,) bool, the ticks that count (default all).
        u, r_nom: (N, m) applied and nominal references (offset and reference steps).
        thrust: (N,) the normalized thrust setpoint sent (its steps; its share at 0 or 1).
        z_truth: (N,) true height [m], NaN where unknown (the z error on the truth, the estimator's error).
        steered: (N,) bool, the ticks the policy steered (the engaged fraction).
        empty: the value of a statistic without any sample (None: JSON null; the simulator's figures use NaN).
    Returns:
        ``rmse``, ``mean_error``, ``max_abs_error``: per output, y - y_des; ``ticks``: scored ticks.
        With z_truth: ``rmse_z_truth`` (z_truth - y_des z), ``estimator_rms`` (y z - z_truth) and its mean
        ``estimator_bias`` (the part no steering on the estimate can see), ``truth_ticks``.
        With u and r_nom: ``offset_step_rms`` (per reference, :func:`~ddpc_codegen.stats.step_rms` of u - r_nom
        over pairs of scored ticks), ``max_offset_step`` and ``max_ref_step`` (reference 0: largest
        |change| of u - r_nom and of u from one tick to the next, over every pair of adjacent ticks after
        ``settle`` whether active or not: a fallback's or a stall's hand-over counts, a hole never spans two ticks),
        ``ref_rate_ratio`` (the RMS of reference 0's tick-to-tick change over that of output 0's desired path, over
        the same pairs: 1.0 for passthrough; what :mod:`ddpc_codegen.design.front` calls the activity).
        With thrust: ``thrust_step_rms`` (over the same adjacent pairs), ``thrust_limit_share``
        (:func:`~ddpc_codegen.stats.limit_share` at 0 and 1; None without a tick). With steered: ``engaged_fraction``.
    """
    y = np.asarray(y, dtype=float)
    y_des = np.asarray(y_des, dtype=float)
    on = scored_ticks(t, settle, active)
    if y.shape != y_des.shape or y.shape[:1] != on.shape:
        raise ValueError(f"y {y.shape} and y_des {y_des.shape} must both be (N, p) with N = {on.shape[0]} ticks")
    e = y[on] - y_des[on]
    out: dict[str, Any] = {
        "rmse": [rms(e[:, i], empty) for i in range(e.shape[1])],
        "mean_error": [float(np.mean(e[:, i])) if e.shape[0] else empty for i in range(e.shape[1])],
        "max_abs_error": [float(np.max(np.abs(e[:, i]))) if e.shape[0] else empty for i in range(e.shape[1])],
        "ticks": int(on.sum()),
    }
    if z_truth is not None:
        zt = np.asarray(z_truth, dtype=float)[on]
        ok = np.isfinite(zt)
        est = y[on, 0][ok] - zt[ok]
        out.update(rmse_z_truth=rms(zt[ok] - y_des[on, 0][ok], empty), estimator_rms=rms(est, empty),
                   estimator_bias=float(np.mean(est)) if est.size else empty, truth_ticks=int(ok.sum()))
    flown = scored_ticks(t, settle)  # every tick of the trajectory, engaged or not: what the vehicle was sent
    if u is not None and r_nom is not None:
        u, r_nom = np.asarray(u, dtype=float), np.asarray(r_nom, dtype=float)
        out["offset_step_rms"] = step_rms(u - r_nom, on)
        out["max_offset_step"] = _max_abs_step(u[:, 0] - r_nom[:, 0], flown, empty)
        out["max_ref_step"] = _max_abs_step(u[:, 0], flown, empty)
        path, ref = rms(_adjacent_steps(y_des[:, 0], flown)), rms(_adjacent_steps(u[:, 0], flown))
        out["ref_rate_ratio"] = ref / path if path and ref is not None else empty
    if thrust is not None:
        thr = np.asarray(thrust, dtype=float)
        out["thrust_step_rms"] = rms(_adjacent_steps(thr, flown), empty)
        out["thrust_limit_share"] = limit_share(thr, 0.0, 1.0, on)  # None without a tick, as every caller reported it
    if steered is not None:
        s = np.asarray(steered, dtype=bool)[on]
        out["engaged_fraction"] = float(s.mean()) if s.size else empty
    return out


def _adjacent_steps(x: np.ndarray, win: np.ndarray) -> np.ndarray:
    """x[k+1] - x[k] for the adjacent ticks k, k+1 both in ``win`` with finite values (never across a gap)."""
    x = np.asarray(x, dtype=float).ravel()
    pair = win[:-1] & win[1:] & np.isfinite(x[:-1]) & np.isfinite(x[1:])
    return (x[1:] - x[:-1])[pair]


def _max_abs_step(x: np.ndarray, win: np.ndarray, empty: Any) -> Any:
    d = np.abs(_adjacent_steps(x, win))
    return float(d.max()) if d.size else empty
