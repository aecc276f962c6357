"""The bridge's results: the tick-log row, the tick log with its metadata, the summary (a mixin of
:class:`.bridge.Bridge`), and the statistics helpers."""

from __future__ import annotations

import json
import math
from dataclasses import asdict
from pathlib import Path

import numpy as np

from ddpc_codegen.design.phases import GROUND
from ddpc_codegen.flight_metrics import flight_metrics
from ddpc_codegen.stats import percentiles

from firmware_bridge.bridge_config import FaultInjectingSolver
from firmware_bridge.ticklog import FALLBACK_REASONS, REASONS, TickLog, _json_default, reason_code

__all__ = ["Reporting", "gap_statistics"]


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



class Reporting:
    """Tick-log rows, the tick log and the summary (mixed into :class:`.bridge.Bridge`)."""

    def _record(self, ref: dict, state, *, now: float, t_sent: float, t_vehicle: float, t_traj: float, age: float,
                q, thrust: float, field: float, event: bool, engaged: bool, fresh: bool, sent: bool, gap: bool,
                n_new: int, latency: float, gate: int = 0) -> None:
        """One row of the tick log (see :mod:`.ticklog` for the fields)."""
        i = self.rec.new_row()
        A = self.rec.arrays
        A["t_wall"][i] = now - self.t0
        A["t_vehicle"][i] = t_vehicle
        A["t_traj"][i] = t_traj
        A["age_ms"][i] = age * 1e3
        A["position"][i] = state.position
        A["velocity"][i] = state.velocity
        A["euler"][i] = state.euler
        A["rates"][i] = state.body_rates
        A["y"][i] = ref["y"]
        A["y_des"][i] = self.ctrl.y_des
        A["r_nom"][i] = ref["r_nom"]
        A["u"][i] = ref["u"]
        if ref["u_st"] is not None:
            A["u_steered"][i] = ref["u_st"]
        A["excitation"][i] = ref["exc"] if ref["exc"] is not None else 0.0
        A["sp_q"][i] = q
        A["sp_thrust"][i] = thrust
        A["sp_field"][i] = field
        A["reason"][i] = reason_code(ref["reason"])
        A["solve_us"][i] = ref["solve_us"]
        A["latency_us"][i] = latency
        A["compute_us"][i] = (t_sent - now) * 1e6
        A["event"][i] = event
        A["new_samples"][i] = min(n_new, 127)
        A["armed"][i] = self.armed
        A["offboard"][i] = self.offboard
        A["active"][i] = engaged and fresh
        A["fresh"][i] = fresh
        A["sent"][i] = sent
        A["valid"][i] = event and engaged and fresh if self.cfg.lockstep else engaged and fresh
        A["gap"][i] = gap
        A["gate"][i] = gate
        A["adapt"][i] = ref.get("adapt", 0)
        A["adapt_offset"][i] = ref.get("adapt_offset", math.nan)
        A["adapt_snap"][i] = ref.get("adapt_snap", 0)
        A["phase"][i] = self.ctrl.phase
        if self.hop is not None and self.hop.backdate:
            # A touchdown confirmed late: the samples already on the ground before it are ground samples.
            A["phase"][max(0, i - self.hop.backdate) : i] = GROUND
        A["contact"][i] = -1 if self.telem.contact is None else int(self.telem.contact)
        tr = self.truth
        if tr.present:
            A["truth_position"][i] = tr.position
            A["truth_velocity"][i] = tr.velocity
            A["truth_euler"][i] = tr.euler
            A["truth_age_ms"][i] = tr.age(now) * 1e3

    # ------------------------------------------------------------------ results
    def ticklog(self) -> TickLog:
        c = self.cfg
        meta = {"bridge": {k: v for k, v in asdict(c).items() if k not in ("controller", "trajectory")},
                "controller": asdict(self.ctrl_cfg), "trajectory": _describe_trajectory(self.ctrl.trajectory),
                "autopilot": self.profile.name, "dataset_skip": c.dataset_skip, "min_segment": 50,
                # what SET_ATTITUDE_TARGET.thrust meant: a solver fits the loop it was collected in
                "thrust_field": "climb_rate" if self.profile.climb_rate_thrust else "thrust",
                # tick_position / velocity / euler are in this frame (last capture: the latest engagement)
                "frame": self.frame.as_dict(), "truth": self.truth.as_dict(), "events": list(self.events),
                "stalls": list(self.stalls), "guard_saturations": list(self.guard_saturations),
                "solver": None if self.solver is None else {"folder": str(getattr(self.solver, "folder", "")),
                                                           "config_hash": self.solver.manifest.get("config_hash"),
                                                           "predictor_hash": self.solver.manifest.get("predictor_hash")}}
        samples = {name: np.array(s.history, dtype=float).reshape(-1, 2) - np.array([0.0, self.t0])
                   for name, s in (("attitude", self.telem.att), ("position", self.telem.pos))}
        return self.rec.to_log(dt=self.period, input_names=self.ctrl.input_names, output_names=self.ctrl.output_names,
                               input_units=self.ctrl.input_units, output_units=self.ctrl.output_units, metadata=meta,
                               samples=samples)

    def summary(self) -> dict:
        c = self.cfg
        v = self.rec.view()
        n = self.rec.n
        reasons = v["reason"]
        names = np.array(REASONS)
        counts = {str(names[i]): int((reasons == i).sum()) for i in np.unique(reasons)} if n else {}
        fb = {k: cnt for k, cnt in counts.items() if k in FALLBACK_REASONS}
        # In lock-step the vehicle's clock is the one that matters: wall-clock gaps only say the
        # machine was busy, not that a tick of the (paused) vehicle went without a setpoint.
        gaps = gap_statistics(np.asarray(self._send_stamps if c.lockstep else self._send_times), self.period)
        # the engaged event ticks after the settle time, scored as every other run is
        fm = flight_metrics(v["t_traj"], v["y"], v["y_des"], settle=c.settle, active=v["event"] & v["active"],
                            z_truth=v["truth_position"][:, 2])
        out = {
            "mode": c.mode, "autopilot": self.profile.name, "stop_reason": self.stop_reason, "ticks": n,
            "setpoints_sent": len(self._send_times), "rate_hz": gaps["rate_hz"], "duration_s": gaps["duration_s"],
            "latency_us": percentiles(v["latency_us"]) if n else percentiles(()),
            "missed_ticks": gaps["missed_ticks"], "max_gap_ms": gaps["max_gap_ms"],
            "fallbacks": int(sum(fb.values())), "fallback_reasons": fb, "reasons": counts,
            "event_ticks": int(v["event"].sum()) if n else 0, "activations": self._n_activations,
            "grid_skipped": self.clock.skipped, "telemetry": self._telemetry_summary(),
            "arming": {"attempts": self.arming.attempts, "refusals": self.arming.refusals[-5:]},
            "vehicle": None if self.vehicle is None else asdict(self.vehicle),
            "rmse_z_measured": fm["rmse"][0], "rmse_samples": fm["ticks"],
            "rmse_z_truth": fm["rmse_z_truth"], "truth_samples": self.truth.seq,
            **self.counts,
            "link": {**dict(self.link.stats), "foreign_systems": sorted(self.link.foreign_systems)},
            "params": self.params, "scheduling": self.scheduling, "frame": self.frame.as_dict(),
            "events": self.events, "approach": self.approach_result,
            # the last gate: ticks per action (rate_limited, envelope, nonfinite_*, guard_clamped, stall) and its bounds
            "gate": self.gate.summary(), "stalls": list(self.stalls),
            "guard_saturations": list(self.guard_saturations), "telemetry_dropped": self.telem.dropped,
        }
        if self.hop is not None:
            out["hopping"] = self.hop.summary()
        if self.steerer is not None:
            out["steering"] = self.steerer.summary()
            if getattr(self.policy, "adaptation", None) is not None:
                out["steering"]["adaptation"] = self.policy.adaptation.summary()
            if isinstance(self.solver, FaultInjectingSolver):
                out["steering"]["injected_failures"] = self.solver.injected
        if self.cfg.mode == "prefilter":
            out["prefilter"] = {"model": self.policy.model.to_dict(), "counts": self.policy.summary()}
        if self.cfg.mode == "feedforward":  # beyond_table: ticks past the table's end (its last row held)
            out["feedforward"] = {"file": str(self.cfg.feedforward), "rows": int(self.policy.delta.shape[0]),
                                  "dt": self.policy.dt, "counts": self.policy.summary()}
        return out

    def _telemetry_summary(self) -> dict:
        """Per stream: samples received (every one is kept in the log), distinct stamps per second,
        the most common stamp steps [ms: count] -- what the autopilot really delivers."""
        out = {}
        for name, s in (("attitude", self.telem.att), ("position", self.telem.pos)):
            h = np.array(s.history, dtype=float).reshape(-1, 2)
            st = np.unique(h[:, 0])
            span = st[-1] - st[0] if st.size > 1 else 0.0
            steps, cnt = np.unique(np.round(np.diff(h[:, 0]) * 1e3).astype(int), return_counts=True)
            top = sorted(zip(cnt.tolist(), steps.tolist()), reverse=True)[:4]
            out[name] = {"samples": int(h.shape[0]), "distinct_per_s": float((st.size - 1) / span) if span > 0 else None,
                         "step_ms": {str(k): c for c, k in top}}
        return out

    def _finish(self) -> None:
        c = self.cfg
        if c.log:  # always, even without a tick (interrupted, vehicle lost): the log says what happened
            self.log_path = self.ticklog().save(c.log)
        s = self.summary()
        if c.summary:
            Path(c.summary).parent.mkdir(parents=True, exist_ok=True)
            Path(c.summary).write_text(json.dumps(s, indent=2, default=_json_default) + "\n")
        self.link.close()


def _describe_trajectory(traj) -> dict:
    """The trajectory for the log's metadata: its type and parameters (a sampled one by its source)."""
    if traj is None:
        return {"type": "hop cycle (the hopping controller's apex / velocity targets)"}
    d = {"type": type(traj).__name__}
    if hasattr(traj, "source") and hasattr(traj, "t"):
        d.update(source=traj.source, points=len(traj.t), t_end=float(traj.t[-1]))
    else:
        d.update(asdict(traj))
    return d
