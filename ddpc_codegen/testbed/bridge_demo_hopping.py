"""``make bridge-demo SCENARIO=hopping``: DDPC-Hopping over MAVLink, the simulated hopping robot as robot.

Vehicle (``ddpc-vehicle --scenario hopping --contact-signal --no-noise``) and bridge (``ddpc-bridge
--scenario hopping``) as two processes on UDP 127.0.0.1 (lock-step by default: deterministic, and
as fast as the machine allows)::

    1. collect   aerial PRBS on the references, hops labelled by the bridge's phase detection
    2. codegen   ddpc-codegen codegen configs/hopping.toml --dataset <the collect tick log>
    3. baseline  the hopping controller alone (--mode passthrough)
    4. steered   the generated solver + its artificial-IO operator in the loop (--mode steer)
    5. in-process reference: the same solver in :func:`ddpc_codegen.experiments.evaluate.run`'s hook

Metrics over the link come from the vehicle's truth log (true state per tick, true touchdown /
liftoff times) with the in-process definitions (:func:`ddpc_codegen.experiments.evaluate.scenario_metrics`,
first 3 hops not scored). Phase-detection delays: per true event, the bridge's detection tick
minus the first tick at or after the event, from telemetry alone (the estimate) and from the
contact signal (both replayed with the bridge's :class:`PhaseEstimator` on the logged telemetry
and flags: the same estimator on the same per-tick inputs as in the flight; the logged labels
differ only by the touchdowns back-dated after confirmation).

Writes ``reports/bridge_hopping.json``.
"""

from __future__ import annotations

import math
import subprocess
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ddpc_codegen.values.phases import DESCENT
from ddpc_codegen.robot.frames import euler_from_quat
from ddpc_codegen.robot.phases import ContactConfig, PhaseEstimator
from ddpc_codegen.testbed.bridge_flights import ROOT, child_env, fly, python_m, write_report
from ddpc_codegen.experiments.evaluate import scenario_metrics
from ddpc_codegen.experiments.policy_hook import PolicyHook
from ddpc_codegen.robot.controller import ControllerConfig
from ddpc_codegen.robot.profile import load_profile
from ddpc_codegen.runtime.loader import load_solver
from ddpc_codegen.runtime.policy import SteeringPolicy
from ddpc_codegen.runtime.steerer import ReferenceSteerer
from ddpc_codegen.sim import simulate
from ddpc_codegen.sim.metrics import compute_metrics
from ddpc_codegen.sim.params import PogoXParams
from ddpc_codegen.sim.scenarios import HoppingScenario
from firmware_bridge.hopping_loop import hopping_window
from firmware_bridge.ticklog import load_ticklog

__all__ = ["LinkRun", "link_run", "link_metrics", "detection_delays", "replay_phases"]


@dataclass
class LinkRun:
    """A flight over the link in the shape the simulator's metrics read (:class:`ddpc_codegen.sim.metrics.RunLogs`):
    truth rows from the first to the last engaged tick, each with that tick's desired outputs, phase and
    references (applied u, nominal r_nom) and the thrust setpoint sent (normalized, after the bridge's clamps;
    the vehicle's truth and the bridge tick in lock-step, one per row)."""

    t: np.ndarray
    state: np.ndarray
    y_true: np.ndarray
    y_des: np.ndarray
    phase: np.ndarray
    u: np.ndarray
    r_nom: np.ndarray
    setpoint_thrust: np.ndarray
    touchdowns: np.ndarray
    liftoffs: np.ndarray
    config: object
    params: object
    scenario_obj: object
    dt: float
    scenario: str = "hopping"
    extras: dict = field(default_factory=dict)
    crashed: bool = False
    crash_reason: str = ""
    wall_time: float = 0.0
    n_bottom_outs: int = 0

    @property
    def n(self) -> int:
        return int(self.t.shape[0])

    def metrics(self) -> dict:
        return compute_metrics(self)


def link_run(ticks_path: Path, truth_path: Path) -> LinkRun:
    """The engaged part of a hopping flight: vehicle truth per tick + the bridge's y_des / phase at that tick."""
    log = load_ticklog(ticks_path)
    tl = log.ticks
    act = np.flatnonzero(tl["active"])
    with np.load(truth_path) as z:
        tt, st, td, lo = z["t"], z["state"], z["touchdowns"], z["liftoffs"]
    tv = tl["t_vehicle"][act]
    t0, t1 = tv[0], tv[-1]
    sel = np.flatnonzero((tt >= t0 - 1e-9) & (tt <= t1 + 1e-9))
    # The tick that decided at (or last before) each truth row's time.
    j = np.clip(np.searchsorted(tv, tt[sel] + 1e-9) - 1, 0, act.size - 1)
    rows = act[j]
    eul = np.array([euler_from_quat(q) for q in st[sel, 6:10]])
    cc = ControllerConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in log.metadata["controller"].items()})
    inside = lambda ev: np.asarray(ev)[(np.asarray(ev) >= t0) & (np.asarray(ev) <= t1)] - t0  # noqa: E731
    return LinkRun(t=tt[sel] - t0, state=st[sel], y_true=np.column_stack([st[sel, 2], eul[:, 0], eul[:, 1]]),
                   y_des=tl["y_des"][rows], phase=tl["phase"][rows], u=tl["u"][rows], r_nom=tl["r_nom"][rows],
                   setpoint_thrust=tl["sp_thrust"][rows], touchdowns=inside(td), liftoffs=inside(lo),
                   config=cc, params=PogoXParams(), scenario_obj=HoppingScenario(), dt=log.dt)


def replay_phases(ticks_path: Path, contact: ContactConfig) -> tuple[np.ndarray, np.ndarray]:
    """(vehicle times, GROUND flags) of the engaged ticks as the bridge's :class:`PhaseEstimator` with
    ``contact`` sees them from the logged telemetry (trajectory frame) and contact flags, started
    at the release in DESCENT, like the bridge."""
    tl = load_ticklog(ticks_path).ticks
    act = np.flatnonzero(tl["active"])
    est = PhaseEstimator(contact, phase=DESCENT)
    g = np.zeros(act.size, dtype=bool)
    for n, i in enumerate(act):
        flag = bool(tl["contact"][i] == 1) if contact.source == "signal" else None
        if contact.source == "signal" and tl["contact"][i] < 0:
            raise ValueError(f"{ticks_path}: no contact flag logged (fly the vehicle with --contact-signal)")
        est.update(float(tl["position"][i, 2]), float(tl["velocity"][i, 2]), float(tl["euler"][i, 0]),
                   float(tl["euler"][i, 1]), signal=flag)
        g[n] = est.contact
    return tl["t_vehicle"][act], g


def detection_delays(t: np.ndarray, ground: np.ndarray, touchdowns, liftoffs, dt: float) -> dict:
    """Per true event: the tick of the matching detected transition minus the first tick at or after the
    event [ticks] (None: none detected within -3 .. +10 ticks). Returns the delays per kind, the share
    within 0 .. 2 ticks over both kinds, and the detected transitions with no true event (chatter)."""
    k = np.rint(np.asarray(t) / dt).astype(int)
    edges = np.diff(ground.astype(np.int8))
    det = {"touchdown": k[1:][edges == 1], "liftoff": k[1:][edges == -1]}
    out: dict = {}
    matched = 0
    for kind, times in (("touchdown", touchdowns), ("liftoff", liftoffs)):
        ds = []
        for te in times:
            k0 = int(math.ceil(te / dt - 1e-9))
            near = [int(x - k0) for x in det[kind] if -3 <= x - k0 <= 10]
            ds.append(near[0] if near else None)
        matched += sum(d is not None for d in ds)
        out[kind] = ds
    both = out["touchdown"] + out["liftoff"]
    out["within_2_ticks"] = float(np.mean([d is not None and 0 <= d <= 2 for d in both])) if both else math.nan
    out["events"] = len(both)
    out["spurious"] = int(sum(len(v) for v in det.values()) - matched)
    for kind in ("touchdown", "liftoff"):
        v = [d for d in out[kind] if d is not None]
        out[f"{kind}_mean_ticks"] = float(np.mean(v)) if v else math.nan
        out[f"{kind}_max_ticks"] = int(max(v)) if v else None
    return out


def foot_heights_at_contact_changes(tl: dict, contact: ContactConfig) -> dict:
    """Where the robot's own contact flag switches, the foot height the estimate sees [m]: h of the
    first sample with the flag set (touchdown) / cleared (liftoff), min / median / max, from a tick
    log's ``ticks``. The thresholds that detect on the sensor's sample: touchdown_margin <=
    -max(touchdown h), liftoff_margin below min(liftoff h) (how the pogox_hopping profile's were chosen)."""
    act = np.flatnonzero(tl["active"] & (tl["contact"] >= 0))
    if act.size < 2:
        return {}
    est = PhaseEstimator(contact)
    h = np.array([est.foot_height(float(tl["position"][i, 2]), float(tl["euler"][i, 0]), float(tl["euler"][i, 1]))
                  for i in act])
    flag = tl["contact"][act] == 1
    edge = np.diff(flag.astype(np.int8))
    out = {}
    for kind, sign in (("touchdown", 1), ("liftoff", -1)):
        v = h[1:][edge == sign]
        if v.size:
            out[kind] = {"min": float(v.min()), "median": float(np.median(v)), "max": float(v.max()), "n": int(v.size)}
    return out


def link_metrics(ticks_path: Path, truth_path: Path, contact: ContactConfig | None = None) -> dict:
    """The in-process hopping metrics of a flight over the link, plus the phase-detection delays from
    telemetry alone and (if the vehicle sent it) from the contact signal, replayed with ``contact``
    (default: the thresholds the bridge flew with, from the tick log)."""
    run = link_run(ticks_path, truth_path)
    met = scenario_metrics(run)
    log = load_ticklog(ticks_path)
    tl = log.ticks
    if contact is None:  # the thresholds the bridge flew with (its tick log's metadata)
        flown = (log.metadata.get("bridge") or {}).get("contact")
        contact = ContactConfig(**flown) if flown else ContactConfig(leg_length=run.config.leg_length)
    with np.load(truth_path) as z:
        td, lo = z["touchdowns"], z["liftoffs"]
    t_end = float(tl["t_vehicle"][tl["active"]][-1])
    td, lo = td[td <= t_end], lo[lo <= t_end]
    met["phase_detection"] = {}
    sources = ("estimate", "signal") if np.any(tl["contact"][tl["active"]] >= 0) else ("estimate",)
    for src in sources:
        t, g = replay_phases(ticks_path, replace(contact, source=src))
        met["phase_detection"][src] = detection_delays(t, g, td, lo, run.dt)
    if "signal" in sources:
        met["foot_height_at_contact_changes"] = foot_heights_at_contact_changes(tl, contact)
    return met


# ----------------------------------------------------------------------------- the demo
def in_process(solver_dir: Path, duration: float, seed: int, noise: bool) -> dict:
    """Baseline and steered hopping in-process (simulate + the simulator's steering hook), the same
    generated solver and artificial-IO operator as over the link."""
    solver = load_solver(solver_dir)
    st = ReferenceSteerer.for_solver(solver)
    cc = load_profile("pogox_hopping").controller
    hook = PolicyHook(SteeringPolicy(st, max_gap_fill=0), "hopping", window=hopping_window(solver, st.t_ini),
                      g_eff=cc.g_eff, dt=cc.dt)
    out = {}
    for name, h in (("baseline", None), ("steered", hook)):
        out[name] = scenario_metrics(simulate("hopping", duration, seed=seed, noise=noise or None, reference_hook=h))
    out["steering"] = {**st.summary(), "hook": dict(hook.counts)}
    return out


def run_hopping_demo(out: Path, work: Path, *, collect_s: float = 120.0, flight_s: float = 20.0,
                     solver: Path | None = None, config: Path | None = None, lockstep: bool = True,
                     noise: bool = False, contact: str = "estimate", rt_priority: int = 30, seed: int = 1,
                     log=print) -> dict:
    """collect -> codegen -> baseline -> steered over the link, then the in-process reference (see
    the module docstring). ``lockstep`` False: both processes in real time (SCHED_FIFO if permitted).
    ``contact``: the bridge's phase source ("estimate": telemetry alone; "signal": the leg sensor's flag)."""
    config = config or ROOT / "configs" / "hopping.toml"
    work.mkdir(parents=True, exist_ok=True)
    t_start = time.monotonic()
    veh = ["--scenario", "hopping", "--contact-signal"] + ([] if noise else ["--no-noise"])
    br = ["--scenario", "hopping", "--contact", contact]
    if lockstep:
        veh, br = veh + ["--lockstep"], br + ["--lockstep"]
    kw = dict(rt_priority=0 if lockstep else rt_priority, log=log, vehicle_args=veh)
    runs: dict[str, dict] = {}
    if solver is None:
        log(f"1. collect: {collect_s:g} s of hopping with aerial PRBS over MAVLink")
        runs["collect"] = fly("hop_collect", work, br + ["--mode", "collect", "--seed", str(seed)],
                              duration=collect_s, seed=seed, **kw)
        log(f"2. codegen: ddpc-codegen codegen {config} --dataset {runs['collect']['ticks']}")
        r = subprocess.run(python_m() + ["ddpc_codegen.cli.main", "codegen", str(config), "--dataset",
                                    str(runs["collect"]["ticks"]), "--out", str(work / "generated")],
                           env=child_env(), capture_output=True, text=True, timeout=900)
        if r.returncode != 0:
            raise RuntimeError(f"codegen failed:\n{r.stderr}")
        log("    " + r.stderr.strip().replace("\n", "\n    "))
        solver = Path(r.stdout.strip().splitlines()[-1])
    log(f"3. baseline: {flight_s:g} s, the hopping controller alone (passthrough)")
    runs["baseline"] = fly("hop_baseline", work, br + ["--mode", "passthrough"], duration=flight_s, seed=seed + 1, **kw)
    log(f"4. steered: {flight_s:g} s, generated solver {solver} in the loop")
    runs["steered"] = fly("hop_steered", work, br + ["--mode", "steer", "--solver", str(solver)], duration=flight_s,
                          seed=seed + 1, **kw)
    log("5. in-process reference (simulate, same solver)")
    ip = in_process(solver, flight_s, seed + 1, noise)
    link = {k: link_metrics(runs[k]["ticks"], runs[k]["truth"]) for k in ("baseline", "steered")}
    report = {
        "link": link, "in_process": ip, "solver": str(solver),
        "fallbacks": int(runs["steered"]["summary"]["fallbacks"]),
        "runs": {k: {key: v["summary"].get(key) for key in ("rate_hz", "missed_ticks", "fallbacks", "fallback_reasons",
                                                             "reasons", "duration_s", "stop_reason", "hopping", "steering")}
                 for k, v in runs.items()},
        "settings": {"collect_s": collect_s if "collect" in runs else None, "flight_s": flight_s, "seed": seed,
                     "config": str(config), "lockstep": lockstep, "noise": noise, "contact": contact,
                     "settle_hops": 3},
    }
    return write_report(report, out, t_start, format_table, log)


def format_table(r: dict) -> str:
    """The README table: per run mean / max |apex error|, leg-angle RMSE, vx error, fallbacks; the delays."""
    f = lambda v, s=1e3, fmt="{:.2f}": "-" if v is None or not math.isfinite(v) else fmt.format(v * s)  # noqa: E731
    lines = ["", "| run | mean / max abs apex err [mm] | RMSE pitch [mrad] | RMSE roll [mrad] | mean abs vx err [mm/s] | fallbacks |",
             "|---|---:|---:|---:|---:|---:|"]
    for where, src in (("link", r["link"]), ("in-process", r["in_process"])):
        for run in ("baseline", "steered"):
            m = src[run]
            fb = r["fallbacks"] if (where, run) == ("link", "steered") else (
                src["steering"]["fallbacks"] if where == "in-process" and run == "steered" else "-")
            lines.append(f"| {where} {run} | {f(m['apex_error_mean_abs'])} / {f(m['apex_error_max_abs'])} | "
                         f"{f(m['rmse_pitch'])} | {f(m['rmse_roll'])} | {f(m['vx_error_mean_abs'], fmt='{:.1f}')} | {fb} |")
    lines += ["", "| phase detection (link) | touchdown mean / max [ticks] | liftoff mean / max [ticks] | within 2 ticks | spurious |",
              "|---|---:|---:|---:|---:|"]
    for run in ("baseline", "steered"):
        for srcname, d in r["link"][run]["phase_detection"].items():
            lines.append(f"| {run}, {srcname} | {d['touchdown_mean_ticks']:.2f} / {d['touchdown_max_ticks']} | "
                         f"{d['liftoff_mean_ticks']:.2f} / {d['liftoff_max_ticks']} | "
                         f"{100 * d['within_2_ticks']:.1f} % of {d['events']} | {d['spurious']} |")
    fh = r["link"]["baseline"].get("foot_height_at_contact_changes") or {}
    if fh:  # the numbers to place the estimate's thresholds by (the profile's [contact])
        lines.append("foot height at the contact flag's changes (baseline) [mm], min / median / max: " + "; ".join(
            f"{k} {v['min'] * 1e3:.1f} / {v['median'] * 1e3:.1f} / {v['max'] * 1e3:.1f}" for k, v in fh.items()))
    return "\n".join(lines)
