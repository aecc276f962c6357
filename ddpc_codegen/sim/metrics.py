"""Tracking metrics of a simulated run (true outputs vs desired outputs).

Flying (after the scenario's settle time): RMSE / mean / max of the z error, RMSE of pitch,
RMSE of x against the ellipse.
Hopping (after the first ``settle_hops`` hops): per-hop apex height error, per-hop average
horizontal velocity error (touchdown to touchdown), RMSE of z / roll / pitch over the aerial
phase, stance durations, bottom-outs.
All errors are realized - desired, in metres / radians / m/s. The per-output figures come from
:func:`ddpc_codegen.flight_metrics.flight_metrics`, the scoring every other path (the bridge, its tick
logs) uses.
"""

from __future__ import annotations

import math
from typing import Any, Protocol

import numpy as np

from ddpc_codegen.values.phases import GROUND
from ddpc_codegen.flight_metrics import flight_metrics, rms

__all__ = ["compute_metrics", "rmse", "hop_apexes", "RunLogs"]


class RunLogs(Protocol):
    """What the metrics read of a run (:class:`ddpc_codegen.sim.run_result.SimResult` has it all;
    a protocol, so that the result imports the metrics and not the other way round).
    Shapes as in SimResult: N ticks, p outputs."""

    scenario: str
    dt: float
    t: np.ndarray  # (N,) [s]
    state: np.ndarray  # (N, 19) true plant state
    y_true: np.ndarray  # (N, p)
    y_des: np.ndarray  # (N, p)
    phase: np.ndarray  # (N,) phase labels
    touchdowns: np.ndarray  # event times [s]
    liftoffs: np.ndarray
    config: Any  # ControllerConfig
    params: Any  # PogoXParams
    scenario_obj: Any
    extras: dict[str, np.ndarray]
    crashed: bool
    crash_reason: str
    wall_time: float
    n_bottom_outs: int

    @property
    def n(self) -> int: ...


def rmse(e: np.ndarray) -> float:
    """RMS of ``e`` (any shape); NaN without a value (:func:`ddpc_codegen.flight_metrics.rms`)."""
    return rms(e, math.nan)


def hop_apexes(res: RunLogs) -> tuple[np.ndarray, np.ndarray]:
    """(times [s], heights [m]) of the true apex of every aerial phase from a liftoff to the next touchdown."""
    z = res.state[:, 2]
    t = res.t
    times, heights = [], []
    lo = list(res.liftoffs)
    td = list(res.touchdowns)
    for a in lo:
        nxt = [b for b in td if b > a]
        if not nxt:
            break
        b = nxt[0]
        i0 = int(np.searchsorted(t, a))
        i1 = int(np.searchsorted(t, b))
        if i1 - i0 < 3:
            continue
        i = i0 + int(np.argmax(z[i0:i1]))
        # Refine with the vertex of the parabola through the samples around the max (ballistic).
        zi = z[i]
        if i0 < i < i1 - 1:
            y0, y1, y2 = z[i - 1], z[i], z[i + 1]
            den = y0 - 2 * y1 + y2
            if den < 0:
                off = 0.5 * (y0 - y2) / den
                zi = y1 - 0.25 * (y0 - y2) * off
        times.append(t[i])
        heights.append(zi)
    return np.array(times), np.array(heights)


def compute_metrics(res: RunLogs) -> dict[str, Any]:
    """A flat dict of floats/ints (JSON-friendly)."""
    out: dict[str, Any] = {
        "scenario": res.scenario,
        "duration": float(res.t[-1] + res.dt) if res.n else 0.0,
        "crashed": bool(res.crashed),
        "crash_reason": res.crash_reason,
        "wall_time_s": float(res.wall_time),
        "controller_model_mass": float(res.config.model_mass),
        "true_mass": float(res.params.mass),
    }
    if res.scenario == "flying":
        settle = float(getattr(res.scenario_obj, "settle_time", 0.0))
        sel = res.t >= settle
        f = flight_metrics(res.t, res.y_true, res.y_des, settle=settle, empty=math.nan)
        out.update(
            rmse_z=f["rmse"][0],
            mean_z_error=f["mean_error"][0],
            max_abs_z_error=f["max_abs_error"][0],
            rmse_pitch=f["rmse"][1],
            rmse_pitch_deg=math.degrees(f["rmse"][1]),
        )
        if "x_des" in res.extras:
            ex = res.state[sel, 0] - res.extras["x_des"][sel]
            out["rmse_x"] = rmse(ex)
            out["rmse_xz"] = rmse(np.hypot(ex, res.state[sel, 2] - res.extras["z_des"][sel]))
        return out

    # ---- hopping
    cfg = res.config
    settle_hops = int(getattr(res.scenario_obj, "settle_hops", 0))
    ta, za = hop_apexes(res)
    apex_err = za - cfg.apex_height
    td = res.touchdowns
    lo = res.liftoffs
    # Average horizontal velocity of each full cycle touchdown -> touchdown.
    vel_err = []
    x = res.state[:, 0:2]
    for a, b in zip(td[:-1], td[1:]):
        ia, ib = int(np.searchsorted(res.t, a)), int(np.searchsorted(res.t, b))
        if ib >= res.n or ib <= ia:
            continue
        v = (x[ib] - x[ia]) / (res.t[ib] - res.t[ia])
        vel_err.append(v - np.asarray(cfg.target_velocity))
    vel_err = np.array(vel_err).reshape(-1, 2)
    stance = [b - a for a in td for b in lo[lo > a][:1]]
    ap = apex_err[settle_hops:]
    ve = vel_err[settle_hops:]
    t_from = ta[settle_hops] if len(ta) > settle_hops else (res.t[-1] if res.n else 0.0)
    f = flight_metrics(res.t, res.y_true, res.y_des, settle=t_from, active=res.phase != GROUND, empty=math.nan)
    out.update(
        n_hops=int(len(td)),
        n_hops_scored=int(len(ap)),
        apex_target=float(cfg.apex_height),
        apex_error_mean_signed=float(np.mean(ap)) if ap.size else math.nan,
        apex_error_rmse=rmse(ap),
        apex_error_max_abs=float(np.max(np.abs(ap))) if ap.size else math.nan,
        apex_errors=[float(v) for v in apex_err],
        velocity_target=[float(v) for v in cfg.target_velocity],
        velocity_error_mean_signed=[float(v) for v in (np.mean(ve, axis=0) if len(ve) else [math.nan, math.nan])],
        velocity_error_rmse=rmse(ve[:, 0]) if len(ve) else math.nan,
        rmse_z_aerial=f["rmse"][0],
        mean_z_error_aerial=f["mean_error"][0],
        rmse_roll_aerial=f["rmse"][1],
        rmse_pitch_aerial=f["rmse"][2],
        stance_time_mean=float(np.mean(stance)) if stance else math.nan,
        n_bottom_outs=int(res.n_bottom_outs),
    )
    return out
