"""The companion loop's record (:class:`FlightRecorder`): one tick-log row per tick, the tick log with its
metadata, the summary (the rows' statistics -- missed ticks, latency, reasons, the height error -- and what
each part of the loop counted), the summary file, and the statistics helpers."""

from __future__ import annotations

import json
import math
from dataclasses import asdict
from pathlib import Path

import numpy as np

from ddpc_codegen.values.phases import GROUND
from ddpc_codegen.flight_metrics import flight_metrics, scored_ticks
from ddpc_codegen.stats import percentiles

from firmware_bridge.clock import TickTrigger
from firmware_bridge.engagement import Engagement
from firmware_bridge.events import EventLog
from firmware_bridge.exit_status import RunEnd, run_outcome
from firmware_bridge.gate import GATE_FLAGS
from firmware_bridge.preflight import VehicleInfo
from firmware_bridge.reference_stage import TickReference
from firmware_bridge.setpoints import SetpointStream
from firmware_bridge.telemetry import TrajectoryFrame
from firmware_bridge.tick_gate import TickGate
from firmware_bridge.ticklog import (FALLBACK_REASONS, REASONS, TickLog, TickRecorder, _json_default, column_frames,
                                    reason_code)
from firmware_bridge.truth import SimTruth
from firmware_bridge.vehicle_link import VehicleLink

__all__ = ["FlightRecorder", "gap_statistics", "describe_trajectory", "telemetry_summary", "write_summary",
           "trajectory_ticks", "engaged_share"]

_GUARD_CLAMPED = reason_code("guard_clamped")
_TAKEOFF = reason_code("takeoff")


def trajectory_ticks(t_traj: np.ndarray, reason: np.ndarray) -> np.ndarray:
    """(N,) bool: the ticks of the flown trajectory -- after it started (a finite trajectory time that is not
    the take-off's approach, whose clock waits at 0), engaged or not. A stall's or a re-engagement's bumpless
    blend, a fallback and a stale tick are part of what the vehicle flew, so every score counts them; the
    engaged share (:func:`engaged_share`) says how much of it the loop was engaged for."""
    return np.isfinite(np.asarray(t_traj, dtype=float)) & (np.asarray(reason) != _TAKEOFF)


def engaged_share(active: np.ndarray, scored: np.ndarray) -> float | None:
    """The share of the ``scored`` ticks (N,) bool that were ``active`` (N,) bool (engaged, fresh, not blending);
    None without a scored tick."""
    on = np.asarray(scored, dtype=bool)
    return float(np.asarray(active, dtype=bool)[on].mean()) if on.any() else None


def gap_statistics(send_times: np.ndarray, period: float) -> dict:
    """Missed ticks from setpoint send times [s]: a gap of g seconds between two setpoints
    misses round(g / period) - 1 ticks once g >= 1.5 periods (jitter below that is not a miss)."""
    t = np.asarray(send_times, dtype=float)
    if t.size < 2:
        return {"missed_ticks": 0, "max_gap_ms": math.nan, "rate_hz": math.nan, "duration_s": 0.0}
    g = np.diff(t)
    miss = np.where(g >= 1.5 * period, np.rint(g / period) - 1, 0).astype(int)
    dur = float(t[-1] - t[0])
    return {"missed_ticks": int(miss.sum()), "max_gap_ms": float(g.max() * 1e3),
            "rate_hz": float((t.size - 1) / dur) if dur > 0 else math.nan, "duration_s": dur}


class FlightRecorder:
    """The tick log's rows of one loop (see :mod:`.ticklog` for the fields).

    Args:
        m, p: references / outputs; period: the tick [s]; t0: the loop's start [s, monotonic].
        lockstep: a row is ``valid`` only on event ticks (each is one vehicle sample).
        capacity: rows allocated at first (grows by doubling).
    """

    def __init__(self, m: int, p: int, period: float, t0: float, *, lockstep: bool, capacity: int = 4096) -> None:
        self.rows = TickRecorder(m, p, capacity=capacity)
        self.period = period
        self.t0 = t0
        self.lockstep = lockstep

    @property
    def n(self) -> int:
        """Rows recorded."""
        return self.rows.n

    def record(self, ref: TickReference, u: np.ndarray, state, *, now: float, t_sent: float, t_vehicle: float,
               t_traj: float, age: float, q, thrust: float, field: float, event: bool, engaged: bool, fresh: bool,
               sent: bool, gap: bool, n_new: int, latency: float, gate: int, armed: bool, offboard: bool,
               y_des: np.ndarray, phase: int, backdate: int, contact: bool | None, truth: SimTruth) -> None:
        """One tick: ``ref`` and the applied reference ``u`` (m,), the measured ``state`` (trajectory frame), the
        setpoint sent (``q`` NED, ``thrust``, the message's ``field``), times [s] and flags."""
        i = self.rows.new_row()
        A = self.rows.arrays
        A["t_wall"][i] = now - self.t0
        A["t_vehicle"][i] = t_vehicle
        A["t_traj"][i] = t_traj
        A["age_ms"][i] = age * 1e3
        A["position"][i] = state.position
        A["velocity"][i] = state.velocity
        A["euler"][i] = state.euler
        A["rates"][i] = state.body_rates
        A["y"][i] = ref.y
        A["y_des"][i] = y_des
        A["r_nom"][i] = ref.r_nom
        A["u"][i] = u
        if ref.u_steered is not None:
            A["u_steered"][i] = ref.u_steered
        clamped = gate & GATE_FLAGS["guard_clamped"]
        if clamped and ref.candidate is not None:
            A["u_proposed"][i] = ref.candidate
        A["excitation"][i] = ref.excitation if ref.excitation is not None else 0.0
        A["sp_q"][i] = q
        A["sp_thrust"][i] = thrust
        A["sp_field"][i] = field
        A["reason"][i] = _GUARD_CLAMPED if clamped else reason_code(ref.reason)
        A["solve_us"][i] = ref.solve_us
        A["latency_us"][i] = latency
        A["compute_us"][i] = (t_sent - now) * 1e6
        A["event"][i] = event
        A["new_samples"][i] = min(n_new, 127)
        A["armed"][i] = armed
        A["offboard"][i] = offboard
        A["active"][i] = engaged and fresh
        A["fresh"][i] = fresh
        A["sent"][i] = sent
        A["valid"][i] = event and engaged and fresh if self.lockstep else engaged and fresh
        A["gap"][i] = gap
        A["gate"][i] = gate
        A["adapt"][i] = ref.adapt
        A["adapt_offset"][i] = ref.adapt_offset
        A["adapt_snap"][i] = ref.adapt_snap
        A["phase"][i] = phase
        if backdate:
            # A touchdown confirmed late: the samples already on the ground before it are ground samples.
            A["phase"][max(0, i - backdate) : i] = GROUND
        A["contact"][i] = -1 if contact is None else int(contact)
        if truth.present:
            A["truth_position"][i] = truth.position
            A["truth_velocity"][i] = truth.velocity
            A["truth_euler"][i] = truth.euler
            A["truth_age_ms"][i] = truth.age(now) * 1e3

    def statistics(self, send_times, settle: float) -> dict:
        """The rows' part of the summary: ticks, the setpoint stream's rate and misses (``send_times`` [s] on
        the clock that counts), latency percentiles, reasons and fallbacks, the height error over every event tick
        of the flown trajectory after the settle time (:func:`trajectory_ticks`) and the engaged share of them."""
        v = self.rows.view()
        n = self.rows.n
        reasons = v["reason"]
        names = np.array(REASONS)
        counts = {str(names[i]): int((reasons == i).sum()) for i in np.unique(reasons)} if n else {}
        fb = {k: cnt for k, cnt in counts.items() if k in FALLBACK_REASONS}
        gaps = gap_statistics(np.asarray(send_times), self.period)
        # every event tick of the trajectory after the settle time (a held sample is not scored twice), engaged
        # or not, scored as every other run is
        scored = v["event"] & trajectory_ticks(v["t_traj"], reasons)
        fm = flight_metrics(v["t_traj"], v["y"], v["y_des"], settle=settle, active=scored,
                            z_truth=v["truth_position"][:, 2])
        return {"ticks": n, "rate_hz": gaps["rate_hz"], "duration_s": gaps["duration_s"],
                "latency_us": percentiles(v["latency_us"]) if n else percentiles(()),
                "missed_ticks": gaps["missed_ticks"], "max_gap_ms": gaps["max_gap_ms"],
                "fallbacks": int(sum(fb.values())), "fallback_reasons": fb, "reasons": counts,
                "event_ticks": int(v["event"].sum()) if n else 0,
                "rmse_z_measured": fm["rmse"][0], "rmse_samples": fm["ticks"], "rmse_z_truth": fm["rmse_z_truth"],
                "engaged_share": engaged_share(v["active"], scored_ticks(v["t_traj"], settle, scored))}

    def ticklog(self, c, ctrl, vehicle: VehicleLink, frame: TrajectoryFrame, events: EventLog, gate: TickGate,
                solver=None) -> TickLog:
        """The tick log with the controller's signal names and units, and its metadata: the loop's config ``c``,
        controller, trajectory, autopilot, frame, truth, events, stalls, guard saturations, the solver."""
        prof = vehicle.profile
        meta = {"bridge": {k: v for k, v in asdict(c).items() if k not in ("controller", "trajectory")},
                "controller": asdict(ctrl.config), "trajectory": describe_trajectory(ctrl.trajectory),
                "autopilot": prof.name, "dataset_skip": c.dataset_skip, "min_segment": 50,
                # what SET_ATTITUDE_TARGET.thrust meant: a solver fits the loop it was collected in
                "thrust_field": "climb_rate" if prof.climb_rate_thrust else "thrust",
                # tick_position / velocity / euler are in this frame (last capture: the latest engagement), truth_* in
                # world ENU: each column's frame in words under "columns"
                "frame": frame.as_dict(), "columns": column_frames(frame.mode), "truth": vehicle.truth.as_dict(),
                "events": list(events.events),
                "stalls": list(gate.stalls), "guard_saturations": list(gate.guard_saturations),
                "solver": None if solver is None else {"folder": str(getattr(solver, "folder", "")),
                                                      "config_hash": solver.manifest.get("config_hash"),
                                                      "predictor_hash": solver.manifest.get("predictor_hash")}}
        tel = vehicle.telem
        samples = {name: np.array(s.history, dtype=float).reshape(-1, 2) - np.array([0.0, self.t0])
                   for name, s in (("attitude", tel.att), ("position", tel.pos))}
        return self.rows.to_log(dt=self.period, input_names=ctrl.input_names, output_names=ctrl.output_names,
                                input_units=ctrl.input_units, output_units=ctrl.output_units, metadata=meta,
                                samples=samples)

    def summary(self, head: dict, c, *, vehicle: VehicleLink, vehicle_info: VehicleInfo | None,
                stream: SetpointStream, trigger: TickTrigger, engagement: Engagement, gate: TickGate,
                frame: TrajectoryFrame, events: EventLog, scheduling: str) -> dict:
        """The summary of a run: ``head`` (mode, autopilot, stop reason), then the rows' statistics and what each
        part of the loop counted (``c``: the loop's config: lock-step, settle time)."""
        # In lock-step the vehicle's clock is the one that matters: wall-clock gaps only say the
        # machine was busy, not that a tick of the (paused) vehicle went without a setpoint.
        r = self.statistics(stream.send_stamps if c.lockstep else stream.send_times, c.settle)
        e = engagement
        code, why = run_outcome(RunEnd(head["stop_reason"], r["ticks"], e.activations, e.engaged, e.left_mode,
                                       e.flown_s(), c.duration, c.vehicle_lost_timeout))
        return {
            **head, "ticks": r["ticks"], "setpoints_sent": len(stream.send_times),
            "setpoints_repeated": stream.repeats, "rate_hz": r["rate_hz"],
            "duration_s": r["duration_s"],
            **{k: r[k] for k in ("latency_us", "missed_ticks", "max_gap_ms", "fallbacks", "fallback_reasons",
                                 "reasons", "event_ticks")},
            "activations": engagement.activations, "grid_skipped": trigger.clock.skipped,
            "phase_lock": None if trigger.lock is None else trigger.lock.summary(),
            "telemetry": telemetry_summary({"attitude": vehicle.telem.att, "position": vehicle.telem.pos}),
            "arming": {"attempts": vehicle.arming.attempts, "refusals": vehicle.arming.refusals[-5:]},
            "vehicle": None if vehicle_info is None else asdict(vehicle_info),
            "rmse_z_measured": r["rmse_z_measured"], "rmse_samples": r["rmse_samples"],
            "rmse_z_truth": r["rmse_z_truth"], "engaged_share": r["engaged_share"], "truth_samples": vehicle.truth.seq,
            **gate.counts, "telemetry_gaps": trigger.gaps, **vehicle.counts,
            "link": {**dict(vehicle.link.stats), "foreign_systems": sorted(vehicle.link.foreign_systems)},
            "params": vehicle.params, "scheduling": scheduling, "frame": frame.as_dict(),
            "events": events.events, "approach": engagement.approach_result,
            # the last gate: ticks per action (rate_limited, envelope, nonfinite_*, guard_clamped, stall) and its bounds
            "gate": gate.summary(), "stalls": list(gate.stalls),
            "guard_saturations": list(gate.guard_saturations), "telemetry_dropped": vehicle.telem.dropped,
            # how the run ended: ddpc-bridge's exit code and its one line (exit_status.EXIT_CODES)
            "flown_s": e.flown_s(), "exit": {"code": code, "reason": why},
        }


def telemetry_summary(streams: dict) -> dict:
    """Per stream (name -> its :class:`.telemetry.Sample`): samples received (every one is kept in the log),
    distinct stamps per second, the most common stamp steps [ms: count] -- what the autopilot really delivers."""
    out = {}
    for name, s in streams.items():
        h = np.array(s.history, dtype=float).reshape(-1, 2)
        st = np.unique(h[:, 0])
        span = st[-1] - st[0] if st.size > 1 else 0.0
        steps, cnt = np.unique(np.round(np.diff(h[:, 0]) * 1e3).astype(int), return_counts=True)
        top = sorted(zip(cnt.tolist(), steps.tolist()), reverse=True)[:4]
        out[name] = {"samples": int(h.shape[0]), "distinct_per_s": float((st.size - 1) / span) if span > 0 else None,
                     "step_ms": {str(k): c for c, k in top}}
    return out


def write_summary(summary: dict, path: str | Path) -> None:
    """The summary as JSON (non-finite numbers and arrays as the tick log's metadata writes them)."""
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    Path(path).write_text(json.dumps(summary, indent=2, default=_json_default) + "\n")


def describe_trajectory(traj) -> dict:
    """The trajectory for the log's metadata: its type and parameters (a sampled one by its source)."""
    if traj is None:
        return {"type": "hop cycle (the hopping controller's apex / velocity targets)"}
    d = {"type": type(traj).__name__}
    if hasattr(traj, "source") and hasattr(traj, "t"):
        d.update(source=traj.source, points=len(traj.t), t_end=float(traj.t[-1]))
    else:
        d.update(asdict(traj))
    return d
