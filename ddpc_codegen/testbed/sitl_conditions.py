"""``make sitl-demo`` beyond the ellipse: a non-repeating 3-D trajectory with height steps, and
changes the collect never saw (wind with turbulence, one motor's thrust loss, a heavier vehicle),
each flown with every method against the real SITL, in rounds.

The changes are each SITL's own simulation parameters, set over MAVLink between flights
(:meth:`~ddpc_codegen.testbed.sitl.Sitl.set_params`) after the collect and put back afterwards:

* ArduCopter: ``SIM_WIND_SPD`` / ``SIM_WIND_DIR`` / ``SIM_WIND_TURB`` (wind with turbulence),
  ``SIM_ENGINE_FAIL`` (a bit mask of motors) with ``SIM_ENGINE_MUL`` (their thrust factor): one
  motor at 90 %, or all four at 85 % -- ArduPilot's SITL has no mass parameter, and every motor
  weaker by 15 % is a vehicle 1/0.85 = 1.18x heavier for the loop;
* PX4 SIH: ``SIH_MASS`` (1.2 kg instead of 1.0), ``SIH_T_MAX`` (each rotor's thrust, 5 N -> 4.5 N:
  SIH has no per-rotor factor). The SIH build here has no wind parameter (its ``SIH_*`` list has
  none), so wind is reported as not flown on PX4.

Every condition flies the same trajectory file with passthrough, the controller's own feed-forward
(ctrl ff), the prefilter fitted on the collect, and steering with the collect's solver; ILC needs a
repeating path and is flown on the ellipse only (its figures here are None). Figures: height RMSE on
the measured height (``rmse_z``: the EKF's, or the motion capture's in the lab setup) and on the SITL's truth
(``rmse_z_truth``), the measurement's own error (RMS of measured - true height, ``estimator_rms``; the EKF's beside
it, ``ekf_rms``), the largest tick-to-tick step of the applied
height reference, the thrust change, the fallbacks: per round and averaged over the rounds.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from ddpc_codegen.testbed.sitl_flight import ctrl_ff_profile, flight_figures, fly

__all__ = ["CONDITIONS", "METHODS", "STEPS_DURATION", "write_steps_trajectory", "fly_condition", "summarize_rounds",
           "steered_estimator_rms"]

# Trajectory seconds each flight of the steps file flies (four height steps, at 4, 8, 12, 16 s).
STEPS_DURATION = 20.0
METHODS = ("passthrough", "ctrl_ff", "prefilter", "steered")
# name -> (parameters that make the change, parameters that undo it) per autopilot; None: not available.
CONDITIONS: dict[str, dict[str, tuple[dict, dict] | str]] = {
    "ardupilot": {
        "steps": ({}, {}),
        "wind": ({"SIM_WIND_SPD": 3.0, "SIM_WIND_DIR": 90.0, "SIM_WIND_TURB": 1.0},
                 {"SIM_WIND_SPD": 0.0, "SIM_WIND_DIR": 180.0, "SIM_WIND_TURB": 0.0}),
        "motor": ({"SIM_ENGINE_MUL": 0.9, "SIM_ENGINE_FAIL": 1.0}, {"SIM_ENGINE_MUL": 1.0, "SIM_ENGINE_FAIL": 0.0}),
        "heavy": ({"SIM_ENGINE_MUL": 0.85, "SIM_ENGINE_FAIL": 15.0}, {"SIM_ENGINE_MUL": 1.0, "SIM_ENGINE_FAIL": 0.0}),
    },
    "px4": {
        "steps": ({}, {}),
        "wind": "PX4 SIH in this build has no wind parameter (no SIH_WIND_*): not flown",
        "motor": ({"SIH_T_MAX": 4.5}, {"SIH_T_MAX": 5.0}),
        "heavy": ({"SIH_MASS": 1.2}, {"SIH_MASS": 1.0}),
    },
}


def _quintic(s: np.ndarray) -> np.ndarray:
    u = np.clip(s, 0.0, 1.0)
    return u**3 * (10.0 - 15.0 * u + 6.0 * u * u)


def write_steps_trajectory(path: str | Path, seed: int = 0, duration: float = STEPS_DURATION + 2.0,
                           z0: float = 1.0, ramp: float = 0.6, dt: float = 0.05) -> Path:
    """A non-repeating 3-D path with height steps, as a trajectory CSV (t, x, y, z).

    Height: z0, then a step every 4 s from t = 4 s to a new seeded level in [z0 - 0.25, z0 + 0.4]
    (each 0.15-0.3 m from the last), each a quintic ramp over ``ramp`` s (peak rate 1.875 * step / ramp).
    Horizontal: x = 0.6 (1 - cos(2 pi t / 11)), y = 0.5 sin^2(pi t / 7.3): from rest at the origin,
    incommensurate periods (the path never repeats).
    """
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration + 0.5 * dt, dt)
    z = np.full(t.size, z0)
    level = z0
    for ts in np.arange(4.0, duration, 4.0):
        while True:
            new = float(rng.uniform(z0 - 0.25, z0 + 0.4))
            if 0.15 <= abs(new - level) <= 0.3:
                break
        z += (new - level) * _quintic((t - ts) / ramp)
        level = new
    x = 0.6 * (1.0 - np.cos(2.0 * math.pi * t / 11.0))
    y = 0.5 * np.sin(math.pi * t / 7.3) ** 2
    path = Path(path)
    lines = ["# non-repeating 3-D path with height steps (ddpc_codegen.testbed.sitl_conditions); t [s], x, y, z [m]",
             "t,x,y,z"] + [f"{a:.3f},{b:.6f},{c:.6f},{d:.6f}" for a, b, c, d in zip(t, x, y, z)]
    path.write_text("\n".join(lines) + "\n")
    return path


def _say(text: str) -> None:
    print(text, flush=True)  # live through run_isolated (the child's stdout is passed through)


def fly_condition(sitl, autopilot: str, name: str, out: Path, trajectory: Path, solver: Path, prefilter: Path,
                  rounds: int, duration: float = STEPS_DURATION, say=_say) -> dict:
    """Apply condition ``name`` (:data:`CONDITIONS`), fly every method ``rounds`` times on ``trajectory``,
    undo the condition; the figures (:func:`summarize_rounds`), or {"skipped": why}."""
    spec = CONDITIONS[autopilot][name]
    if isinstance(spec, str):
        return {"skipped": spec}
    apply, undo = spec
    extra = {"passthrough": (), "ctrl_ff": ("--profile", str(ctrl_ff_profile(autopilot, out))),
             "prefilter": ("--prefilter", str(prefilter)), "steered": ()}
    t0 = time.monotonic()
    sitl.set_params(apply)
    per_round: list[dict] = []
    try:
        for r in range(rounds):
            figs = {}
            for method in METHODS:
                tag = f"{name}_{method}_r{r}"
                mode = {"ctrl_ff": "passthrough", "steered": "steer"}.get(method, method)
                summary = fly(sitl, autopilot, mode, out, duration, solver=solver if method == "steered" else None,
                              extra=("--trajectory", str(trajectory), *extra[method]), tag=tag)
                f = flight_figures(out / f"{autopilot}_{tag}.npz")
                f["fallbacks"] = summary.get("fallbacks")
                figs[method] = f
                say(f"[sitl-demo] {autopilot} {name} round {r + 1}/{rounds} {method}: rmse z {_mm(f['rmse_z'])}, "
                    f"true {_mm(f['rmse_z_truth'])}, estimator {_mm(f['estimator_rms'])} mm "
                    f"({time.monotonic() - t0:.0f} s)")
            per_round.append(figs)
    finally:
        sitl.set_params(undo)
    res = summarize_rounds(per_round)
    res.update(params=apply, trajectory=str(trajectory), duration_s=duration, wall_s=round(time.monotonic() - t0, 1))
    return res


def summarize_rounds(per_round: list[dict]) -> dict:
    """Per key (rmse_z, rmse_z_truth and its split near path changes / steady, thrust_step_rms, max_ref_step,
    max_offset_step, ref_rate_ratio, fallbacks, stalls, stale_ticks, guard_saturations, engaged_share) and method: the mean over the
    rounds (None where any round has none; ``solve_us_p99``: the largest over the rounds); ``ilc`` None (the path does not repeat); the estimator's
    error per method (RMS over the rounds: the steered figure is the one of the steered flights, which the
    target compares against) and the autopilot estimate's (``ekf_rms``); the rounds themselves."""
    out: dict = {}
    for key in ("rmse_z", "rmse_z_truth", "rmse_z_truth_changing", "rmse_z_truth_steady", "thrust_step_rms",
                "max_ref_step", "max_offset_step", "ref_rate_ratio", "fallbacks", "stalls", "stale_ticks",
                "guard_saturations", "solve_us_p99", "engaged_share"):
        out[key] = {}
        worst = max if key == "solve_us_p99" else np.mean  # a latency target holds in every flight
        for method in METHODS:
            vals = [r[method].get(key) for r in per_round]  # None: a round without it (older reports)
            out[key][method] = None if any(v is None for v in vals) else float(worst(vals))
        if key in ("rmse_z", "rmse_z_truth"):
            out[key]["ilc"] = None
    out["estimator_rms"] = {m: rms_of([r[m]["estimator_rms"] for r in per_round]) for m in METHODS}
    # the autopilot's estimate beside it (the same figure unless the loop measured the motion capture)
    out["ekf_rms"] = {m: rms_of([r[m].get("ekf_rms") for r in per_round]) for m in METHODS}
    # its constant part per flight (RMS over the rounds): a bias of the estimate, which steering on it cannot see
    out["estimator_bias_rms"] = {m: rms_of([r[m].get("estimator_bias") for r in per_round]) for m in METHODS}
    out["rounds"] = per_round
    return out


def rms_of(values: list) -> float | None:
    """RMS of the figures (each an RMS over one flight), None if any flight has none."""
    return None if not values or any(v is None for v in values) else float(np.sqrt(np.mean(np.square(values))))


def steered_estimator_rms(c: dict) -> float | None:
    """The estimator's error in the steered flights of a condition (reports before it was per method: the
    figure over every flight)."""
    est = c.get("estimator_rms")
    return est.get("steered") if isinstance(est, dict) else est


def _mm(v) -> str:
    return "-" if v is None else f"{1e3 * v:.1f}"
