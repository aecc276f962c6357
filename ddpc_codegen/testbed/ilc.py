"""Iterative learning control between flights: a flight's tick log -> its error on the trajectory
tick grid -> the next feed-forward table (what ``--mode feedforward`` flies).

The law is the in-process demo's (:func:`ddpc_codegen.design.baselines.ilc_step`: P-type, lead
d_i and gain 1 / g_i of the prefilter fitted on the same loop's collect log, zero-phase 1 Hz
Q-filter); the grid is the bridge's (:func:`firmware_bridge.baseline_modes.feedforward_row`):
row j = round(t_traj / dt). numpy (+ scipy for the Q-filter, imported when a table is learned).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ddpc_codegen.design.baselines import ILC_CUTOFF_HZ, error_on_grid, ilc_step
from ddpc_codegen.values.prefilter import PrefilterModel
from ddpc_codegen.runtime.baselines import FeedforwardPolicy

from firmware_bridge.ticklog import TickLog, load_ticklog

__all__ = ["table_rows", "ticklog_error", "next_table"]


def table_rows(duration: float, dt: float) -> int:
    """Rows of a table covering a ``duration`` s flight, trajectory ticks 0 .. duration / dt."""
    return int(round(duration / dt)) + 1


def ticklog_error(log: TickLog, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(error (n, p), observed (n,)): y - y_des of a flight on the trajectory tick grid.

    Only the engaged ticks with fresh telemetry count (``active``: armed, off-board, after the
    take-off and the hand-over blend -- the ticks on which a table is applied); a missed tick
    inside the flight is interpolated (:func:`~ddpc_codegen.design.baselines.error_on_grid`).
    """
    t = log.ticks
    on = t["active"].astype(bool) & t["fresh"].astype(bool)
    tt = np.where(on, t["t_traj"], np.nan)
    return error_on_grid(tt, t["y"] - t["y_des"], n, log.dt)


def next_table(log_path: str | Path, table: FeedforwardPolicy | None, prefilter: PrefilterModel,
               duration: float, *, gain_scale: float = 1.0,
               cutoff_hz: float | None = ILC_CUTOFF_HZ) -> FeedforwardPolicy:
    """The ILC update after one flight: ``table`` (None: zeros, the passthrough flight) corrected by
    the flight's error (:func:`ticklog_error`); clock "trajectory", dt = the log's tick.
    ``gain_scale``, ``cutoff_hz``: of :func:`~ddpc_codegen.design.baselines.ilc_step` (the defaults
    are the in-process demo's)."""
    log = load_ticklog(log_path)
    n = table_rows(duration, log.dt)
    delta = np.zeros((n, prefilter.m)) if table is None else table.delta
    if delta.shape != (n, prefilter.m):
        raise ValueError(f"the table has shape {delta.shape}, the flight of {duration:g} s at dt {log.dt:g} s "
                         f"needs ({n}, {prefilter.m})")
    err, seen = ticklog_error(log, n)
    if not seen.any():
        raise ValueError(f"{log_path}: no engaged tick on the trajectory to learn from")
    new = ilc_step(delta, err, prefilter, dt=log.dt, mask=seen, gain_scale=gain_scale, cutoff_hz=cutoff_hz)
    return FeedforwardPolicy(new, log.dt, "trajectory")
