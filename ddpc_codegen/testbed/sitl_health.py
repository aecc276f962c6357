"""Whether a SITL flight can judge the steering, and what a flight did when a judgement fails.

A software-in-the-loop autopilot on a loaded machine sometimes misbehaves in ways no reference
steering causes or can see: PX4 SIH's simulator once stood still for 9 s (true height and vertical
velocity frozen, the EKF drifting away) and its EKF height can leave the true height by tens of
centimetres. :func:`sitl_fault` names such a flight (the tests then report it instead of judging
it); :func:`flight_diagnosis` summarises a tick log in a few numbers -- the estimator's error, the
tick reasons, the gate's flags, the steering's offset, the error over the flight's thirds -- so
that a failed judgement explains itself in CI output, where the logs do not survive.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ddpc_codegen.flight_metrics import rms, scored_ticks
from firmware_bridge.gate import GATE_FLAGS
from firmware_bridge.ticklog import REASONS, load_ticklog

__all__ = ["simulator_froze", "estimator_departure", "sitl_fault", "flight_diagnosis", "ESTIMATOR_DEPARTURE_M"]

# How far the EKF height may move away from its own typical offset to the true height within one
# flight before the flight is the estimator's, not the steering's: on the shared SITLs it moves by up
# to 0.23 m (PX4 SIH, steps file; 0.11-0.16 m on the ellipse) and 0.05 m (ArduCopter).
ESTIMATOR_DEPARTURE_M = 0.40


def _flown(t: dict) -> np.ndarray:
    """Indices of the ticks on the trajectory with a true height."""
    return np.flatnonzero(np.isfinite(t["t_traj"]) & np.isfinite(t["truth_position"][:, 2]))


def simulator_froze(t: dict, window_s: float = 2.0, dt: float = 0.005) -> bool:
    """The SITL stopped simulating: its true height and vertical velocity stood exactly still (fresh truth
    samples, ptp < 0.1 mm, vz == 0) for >= ``window_s`` s while the bridge sent a thrust below half of the
    flight's median (a flying vehicle falls then). ``t``: a tick log's ticks; ``dt``: its tick [s]."""
    k = _flown(t)
    z, vz, thr = t["truth_position"][k, 2], t["truth_velocity"][k, 2], t["sp_thrust"][k]
    n = int(round(window_s / dt))
    low = thr < 0.5 * np.median(thr) if thr.size else thr.astype(bool)
    for i in range(0, max(0, k.size - n), max(1, n // 4)):
        w = slice(i, i + n)
        if np.ptp(z[w]) < 1e-4 and np.all(vz[w] == 0.0) and low[w].mean() > 0.5:
            return True
    return False


def estimator_departure(t: dict) -> float | None:
    """Largest distance [m] of the EKF's height error (EKF - true height) from its own median over the
    flown ticks: how far the estimate wandered within the flight (a constant offset does not count: the
    steering follows the estimate). None without the truth."""
    k = _flown(t)
    if not k.size:
        return None
    d = t["position"][k, 2] - t["truth_position"][k, 2]
    return float(np.max(np.abs(d - np.median(d))))


def sitl_fault(log: str | Path) -> str | None:
    """Why the flight in tick log ``log`` cannot judge the steering (the simulator froze, the estimator
    wandered more than :data:`ESTIMATOR_DEPARTURE_M`), or None when it can."""
    t = load_ticklog(log).ticks
    if "truth_position" not in t:
        return None
    if simulator_froze(t):
        return "the simulator's true height stood still for >= 2 s under a thrust far from hover"
    dep = estimator_departure(t)
    if dep is not None and dep > ESTIMATOR_DEPARTURE_M:
        return f"the EKF height wandered {dep:.2f} m from its typical offset to the true height"
    return None


def flight_diagnosis(log: str | Path, settle: float = 3.0) -> dict:
    """A few numbers that say what the flight in tick log ``log`` did (mm unless named): the ticks per
    reason and per gate flag, the largest |u - r_nom| of the height reference, the estimator's error
    (EKF - true height: mean, std, departure), whether the simulator froze, and the height error on the
    EKF and on the truth over each third of the scored ticks (after ``settle`` s of trajectory)."""
    t = load_ticklog(log).ticks
    on = scored_ticks(t["t_traj"], settle, t["active"])
    codes, counts = np.unique(t["reason"][np.isfinite(t["t_traj"])], return_counts=True)
    out: dict = {"ticks": int(on.sum()),
                 "reasons": {REASONS[int(c)] if 0 <= c < len(REASONS) else int(c): int(n) for c, n in zip(codes, counts)},
                 "gate": {f: int(np.count_nonzero(t["gate"][on] & v)) for f, v in GATE_FLAGS.items()
                          if np.any(t["gate"][on] & v)}}
    off = (t["u"][:, 0] - t["r_nom"][:, 0])[on]
    out["max_offset"] = _mm(np.max(np.abs(off[np.isfinite(off)]), initial=0.0))
    thirds = np.array_split(np.flatnonzero(on), 3)
    out["rmse_z_thirds"] = [_mm(rms(t["y"][i, 0] - t["y_des"][i, 0], np.nan)) for i in thirds]
    if "truth_position" in t and np.isfinite(t["truth_position"][on, 2]).any():
        e = t["truth_position"][:, 2] - t["y_des"][:, 0]
        out["rmse_z_truth_thirds"] = [_mm(rms(e[i][np.isfinite(e[i])], np.nan)) for i in thirds]
        d = (t["position"][:, 2] - t["truth_position"][:, 2])[on]
        d = d[np.isfinite(d)]
        out["estimator"] = {"mean": _mm(d.mean()), "std": _mm(d.std()), "departure": _mm(estimator_departure(t))}
        out["simulator_froze"] = simulator_froze(t)
    return out


def _mm(x: float) -> float:
    return round(1e3 * float(x), 1)
