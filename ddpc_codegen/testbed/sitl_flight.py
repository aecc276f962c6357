"""One ``ddpc-bridge`` flight against a running SITL, from the ground and back to it: its command line
(:func:`bridge_command`), running it (:func:`fly`: the vehicle disarmed first, a flight that did not fly its
duration flown again), and its figures from the tick log (:func:`flight_figures`).

Why both: a SITL's land detector can miss a landing (PX4 SIH's, while its EKF height drifts on a long
session), and a flight started on a vehicle still armed and landing is disarmed mid-take-off and ends on its
timeout. Such a flight is kept beside its retry (``<name>_attempt<k>.*``: nothing recorded is lost), never
scored as flown; a second failure stops the run with the bridge's output.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from ddpc_codegen.flight_metrics import flight_metrics, near_changes, rms, scored_ticks
from firmware_bridge.gate import GATE_FLAGS
from firmware_bridge.report import engaged_share, trajectory_ticks
from firmware_bridge.ticklog import REASONS, load_ticklog

__all__ = ["PROFILES", "APPROACH_TIMEOUT", "ctrl_ff_profile", "bridge_command", "fly", "ensure_disarmed", "flight_figures"]

PROFILES = {"ardupilot": "arducopter_sitl", "px4": "px4_sih"}
# Seconds each flight waits, after the take-off ramp, for the height to hold at the trajectory's start
# (the bridge's default is 5). Measured on PX4 SIH: its EKF height estimate once stood 0.25 m above the
# start height for ~9 s after the ramp and then dropped 0.42 m in 0.3 s; a steered flight started on the
# 5 s timeout fought that error (121 vs 85 mm passthrough). Baseline and steered flights are compared
# from a settled start, so the pipeline waits longer.
APPROACH_TIMEOUT = 20.0
_STEERED = REASONS.index("steered")
_STALE = REASONS.index("stale")
_FORCE_DISARM = 21196.0  # MAV_CMD_COMPONENT_ARM_DISARM param2: disarm even if the autopilot thinks it flies


# ddpc-bridge's exits for a run that did not fly its duration (never engaged, the vehicle's own failsafe, timed
# out): such a flight is kept and flown again, as below.
_NOT_FLOWN_CODES = (8, 9, 10)


def ensure_disarmed(sitl, wait: float = 20.0, timeout: float = 15.0) -> bool:
    """Before a flight from the ground: the vehicle disarmed. One still armed (the last flight's LAND did not
    end in a disarm) gets ``wait`` s to disarm itself, then a forced disarm, which the SITL's heartbeat must
    confirm within ``timeout`` s. Returns True when it had to be disarmed. SITL harness only: after the
    bridge's 60 s of LAND the simulated vehicle is on the ground whatever its estimator says.

    Raises:
        RuntimeError: still armed after the forced disarm.
    """
    from pymavlink import mavutil

    conn = sitl.connect()
    try:
        def armed() -> bool | None:
            hb = conn.recv_match(type="HEARTBEAT", blocking=True, timeout=1.0)
            while hb is not None and (hb.get_srcSystem(), hb.get_srcComponent()) != (conn.target_system,
                                                                                    conn.target_component):
                hb = conn.recv_match(type="HEARTBEAT", blocking=True, timeout=1.0)
            return None if hb is None else bool(hb.base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED)

        if not armed():
            return False
        t_end = time.monotonic() + wait
        while time.monotonic() < t_end:
            if armed() is False:
                return True
        t_end = time.monotonic() + timeout
        while time.monotonic() < t_end:
            conn.mav.command_long_send(conn.target_system, conn.target_component,
                                       mavutil.mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 0.0, _FORCE_DISARM,
                                       0, 0, 0, 0, 0)
            if armed() is False:
                return True
    finally:
        conn.close()
    raise RuntimeError(f"the {sitl.autopilot} SITL is still armed after a forced disarm; log tail:\n{sitl.log_tail()}")


def _keep_attempt(out: Path, name: str, attempt: int) -> None:
    """Rename a failed flight's files to ``<name>_attempt<k>.*`` (kept for reading, not scored)."""
    for ext in (".npz", ".json", ".out"):
        f = out / f"{name}{ext}"
        if f.exists():
            f.rename(out / f"{name}_attempt{attempt}{ext}")


def ctrl_ff_profile(autopilot: str, out: Path) -> Path:
    """The autopilot's profile with the controller's own feed-forward of the trajectory velocity
    (``ref_velocity_gain`` 1, the in-process ``ctrl_ff`` baseline), written to ``out``; its path."""
    base = PROFILES[autopilot]
    path = out / f"ctrl_ff_{base}.toml"
    path.write_text(f'name = "{base}_ctrl_ff"\ndescription = "{base} with the velocity feed-forward of the '
                    f'trajectory"\nextends = "{base}"\n\n[controller]\nref_velocity_gain = 1.0\n')
    return path


def bridge_command(sitl, autopilot: str, mode: str, out: Path, duration: float, timeout: float,
                   extra: tuple[str, ...] = (), tag: str | None = None) -> list[str]:
    """The ``ddpc-bridge`` command of one flight from the ground (arm, take off, fly ``duration`` s,
    land); log ``<out>/<autopilot>_<tag or mode>.npz``, summary ``.json``; the SITL setup's own arguments
    (``sitl.bridge_args``: :class:`~ddpc_codegen.testbed.sitl_setups.SetupSitl`, the lab's position source) last."""
    name = f"{autopilot}_{tag or mode}"
    return [sys.executable, "-m", "firmware_bridge.cli", "bridge", sitl.url, "--autopilot", autopilot,
            "--profile", PROFILES[autopilot], "--mode", mode, "--arm", "--offboard", "--takeoff", "--land",
            "--duration", f"{duration:g}", "--timeout", f"{timeout:g}", "--wait-heartbeat", "60",
            "--log", str(out / f"{name}.npz"), "--overwrite", "--summary", str(out / f"{name}.json"), "--verbose",
            "--rt-priority", "10", "--approach-timeout", f"{APPROACH_TIMEOUT:g}",
            "--target-system", str(getattr(sitl, "sysid", 1)), *extra, *getattr(sitl, "bridge_args", ())]


def fly(sitl, autopilot: str, mode: str, out: Path, duration: float, *, solver: Path | None = None,
        timeout: float = 150.0, extra: tuple[str, ...] = (), tag: str | None = None, attempts: int = 2) -> dict:
    """One bridge flight from the ground (:func:`bridge_command`) on a disarmed vehicle (:func:`ensure_disarmed`);
    its summary. A flight that did not fly its ``duration`` (its summary's ``stop_reason``) is kept as
    ``<name>_attempt<k>.*`` and flown again, up to ``attempts`` flights.

    Raises:
        ValueError: ``attempts`` < 1.
        RuntimeError: the bridge exited non-zero, or no attempt flew the duration.
    """
    if attempts < 1:
        raise ValueError(f"attempts must be >= 1; got {attempts}")
    name = f"{autopilot}_{tag or mode}"
    cmd = bridge_command(sitl, autopilot, mode, out, duration, timeout, extra, tag)
    if solver is not None:
        cmd += ["--solver", str(solver)]
    for attempt in range(1, attempts + 1):
        if ensure_disarmed(sitl):
            print(f"[sitl-demo] {name}: the vehicle was still armed after the last flight: disarmed", flush=True)
        with open(out / f"{name}.out", "w") as f:
            rc = subprocess.run(cmd, stdout=f, stderr=subprocess.STDOUT, timeout=timeout + 90, cwd=out).returncode
        if rc not in _NOT_FLOWN_CODES and rc != 0:
            raise RuntimeError(f"{name}: ddpc-bridge exited {rc}:\n{(out / f'{name}.out').read_text()[-3000:]}\n"
                               f"{autopilot} SITL console tail:\n{sitl.log_tail()}")
        summary = json.loads((out / f"{name}.json").read_text())
        if str(summary.get("stop_reason", "")).startswith("duration"):
            break
        _keep_attempt(out, name, attempt)
        print(f"[sitl-demo] {name}: stopped before its {duration:g} s ({summary.get('stop_reason')}): kept as "
              f"{name}_attempt{attempt}.*" + (", flying it again" if attempt < attempts else ""), flush=True)
    else:
        raise RuntimeError(f"{name}: {attempts} attempts, none flew its {duration:g} s "
                           f"(see {out}/{name}_attempt*.out)")
    rz, rt = summary.get("rmse_z_measured"), summary.get("rmse_z_truth")
    print(f"[sitl-demo] {name}: flown ({duration:g} s), rmse z "
          f"{'-' if rz is None else f'{1e3 * rz:.1f}'} mm, true {'-' if rt is None else f'{1e3 * rt:.1f}'} mm",
          flush=True)  # progress (live through run_isolated)
    return summary



def flight_figures(log_path: Path, settle: float = 3.0) -> dict:
    """From a tick log, over every tick of the flown trajectory after ``settle`` s of it
    (:func:`~firmware_bridge.report.trajectory_ticks`: engaged or not -- a stall's bumpless blend, a fallback and a
    stale tick are flown too) with the share of them the loop was engaged for (``engaged_share``): RMSE of z on the
    measured height (the position source's: the EKF's, or the motion capture's) and on the
    simulator's true height (ArduPilot SIM_STATE, PX4 SIH HIL_STATE_QUATERNION; None without it), the
    measurement's own error (``estimator_rms``: RMS of the measured - true height; ``ekf_rms``: the autopilot's
    estimate's, which is the same figure unless the loop measured the motion capture), the steered fraction of
    those ticks (``engaged_fraction``), the
    tick-to-tick thrust change (rms), the largest tick-to-tick step of the applied height reference
    (``max_ref_step``: the trajectory's own steps included) and of its correction u - r_nom
    (``max_offset_step``: what the steering, its fallbacks and the bridge's gate moved), and the bridge's own
    stalls (``stalls``: ticks after a gap in its clock, each resumed from where the vehicle then was) and the
    ticks on stale telemetry (``stale_ticks``) and the steering's hand-backs after its correction held at the step
    guard (``guard_saturations``) from the start of the trajectory: what explains a step beyond the
    rate bound (a stall resumes relative to the measured height, and the vehicle moved meanwhile); with the
    truth, the true-height RMSE split into the ticks near a change of the desired height
    (``rmse_z_truth_changing``: :func:`~ddpc_codegen.flight_metrics.near_changes`) and the rest
    (``rmse_z_truth_steady``; None without such ticks)."""
    t = load_ticklog(log_path).ticks
    flown_traj = trajectory_ticks(t["t_traj"], t["reason"])
    f = flight_metrics(t["t_traj"], t["y"], t["y_des"], settle=settle, active=flown_traj, u=t["u"], r_nom=t["r_nom"],
                       thrust=t["sp_thrust"], z_truth=t["truth_position"][:, 2] if "truth_position" in t else None,
                       steered=t["reason"] == _STEERED)
    on = scored_ticks(t["t_traj"], settle, flown_traj)
    near = near_changes(t["t_traj"], t["y_des"][:, 0])
    split: dict = {"ekf_rms": None}
    if "truth_position" in t:  # the true-height error where the path changes height (lead, ramp, settling) and elsewhere
        e = t["truth_position"][:, 2] - t["y_des"][:, 0]
        for key, mask in (("rmse_z_truth_changing", on & near), ("rmse_z_truth_steady", on & ~near)):
            split[key] = rms(e[mask & np.isfinite(e)])
        if "estimate_position" in t:  # the autopilot's estimate beside the measurement (the same without mocap)
            ekf = t["estimate_position"][on, 2] - t["truth_position"][on, 2]
            split["ekf_rms"] = rms(ekf[np.isfinite(ekf)])
    solve = t["solve_us"][np.isfinite(t["solve_us"])] if "solve_us" in t else np.empty(0)
    flown = np.isfinite(t["t_traj"])
    return {"rmse_z": f["rmse"][0], "rmse_z_truth": f.get("rmse_z_truth"), "estimator_rms": f.get("estimator_rms"),
            "estimator_bias": f.get("estimator_bias"),
            "engaged_fraction": f["engaged_fraction"], "engaged_share": engaged_share(t["active"], on),
            "thrust_step_rms": f["thrust_step_rms"],
            "max_ref_step": f["max_ref_step"], "max_offset_step": f["max_offset_step"], "ticks": f["ticks"],
            "ref_rate_ratio": f["ref_rate_ratio"],
            # the steering's solver call in the loop (Python -> C and back) beside the SITL; None: nothing solved
            "solve_us_p99": float(np.percentile(solve, 99)) if solve.size else None,
            "stalls": int(np.count_nonzero(flown & (t["gate"] & GATE_FLAGS["stall"]).astype(bool))),
            "guard_saturations": int(np.count_nonzero(flown & (t["gate"] & GATE_FLAGS["guard_saturated"]).astype(bool))),
            "stale_ticks": int(np.count_nonzero(flown & (t["reason"] == _STALE))), **split}
