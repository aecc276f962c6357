"""The tick's last gate, whatever produced the reference: the applied reference through the
:class:`.gate.SetpointGate` (finite, rate-limited, inside the envelope; a guard trip clamped to the guard), the
controller's setpoint clamped (tilt, thrust) and never sent non-finite, stalls of the loop's own clock, guard
saturation, and the events that say when each of them, a fallback or dropped telemetry happened.

Stalls. A gap in the bridge's own control clock longer than ``max_age`` (the process was stopped:
SIGSTOP, CPU starvation, a GC pause) is a stall even when the newest telemetry is fresh again when it
wakes up: the vehicle flew on its last setpoint meanwhile, and the steering window has a hole. The owner
treats it like stale telemetry: the steering history is forgotten and refilled, the reference resumes
bumplessly from the one last applied -- what the vehicle flew on meanwhile, never a nominal re-anchored to the
measured outputs: the resume tick's applied reference moves at most the rate bound -- and the stall is an event
(time, length) in the summary, the tick log's ``gate`` column (bit ``stall``) and ``summary["stalls"]``. The
pause is the bridge's, not the vehicle's: it is no link loss (:meth:`.vehicle_link.VehicleLink.bridge_paused`).

Guard clamps. A steered correction beyond the ``max_step`` guard is clamped to it, tick by tick: the reason
``guard_clamped`` (not a fallback), bit ``guard_clamped`` of the ``gate`` column, the solver's proposal in the
tick log's ``u_proposed`` and an event at the start of each streak.

Guard saturation. Clamped on every tick for ``guard_hold`` seconds, the steering is no longer a correction the
predictor can stand behind (an unseen change it cannot absorb, a vehicle that stopped following its references):
holding the reference at the guard indefinitely would be confidently wrong. The owner forgets the steering (its
warm-up hands the reference back toward the nominal one at the gate's rate bound), and the saturation is an event
(time, length), bit ``guard_saturated`` of the tick log's ``gate`` column and an entry of
``summary["guard_saturations"]``; it steers again once its window is full.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from ddpc_codegen.robot.frames import quat_from_euler
from ddpc_codegen.robot.profile import Envelope

from firmware_bridge.events import EventLog
from firmware_bridge.gate import GATE_FLAGS, SetpointGate
from firmware_bridge.reference_stage import TickReference
from firmware_bridge.ticklog import FALLBACK_REASONS

__all__ = ["TickGate", "make_gate"]

_GATE_EVENTS = ("rate_limited", "envelope", "nonfinite_reference", "nonfinite_setpoint")  # guard clamps: their own


def make_gate(cfg, mode: str, period: float, solver=None) -> SetpointGate:
    """The gate of a bridge: the config's reference bounds; the rate per tick from the profile's envelope,
    tightened by the steering solver's ``du_max`` where it has one; collect mode: no rate limit (PRBS)."""
    lo, hi = cfg.reference_bounds()
    if mode == "collect":
        return SetpointGate(lo, hi, None)
    rate = (cfg.envelope or Envelope()).offset_rates(cfg.scenario) * period
    if solver is not None:
        du = solver.manifest.get("bounds", {}).get("du_max") or []
        du = np.array([np.inf if v is None else float(v) for v in du], dtype=float)
        if du.shape == rate.shape:
            rate = np.minimum(rate, np.where(du > 0, du, np.inf))
    return SetpointGate(lo, hi, rate)


class TickGate:
    """The last gate of every tick (see the module docstring).

    Args:
        gate: the reference gate (:func:`make_gate`); events: where events go.
        max_step: (m,) the steering's step guard (None: no guard).
        max_tilt: largest roll / pitch sent [rad]; thrust_min, thrust_max: the thrust clamps [0..1];
        hover_thrust: what a non-finite thrust becomes [0..1].
        max_age: a gap of the loop's clock longer than this is a stall [s] (``None``: lock-step, no stalls).
        guard_hold: guard-clamped this long (control clock) is a saturation [s] (0: never).
    """

    def __init__(self, gate: SetpointGate, events: EventLog, *, max_step: np.ndarray | None, max_tilt: float,
                 thrust_min: float, thrust_max: float, hover_thrust: float, max_age: float | None,
                 guard_hold: float, ref_rate: np.ndarray | None = None, period: float = 0.005) -> None:
        self.gate = gate
        self.events = events
        self.max_step = max_step
        self.max_tilt = max_tilt
        self.thrust_min, self.thrust_max = thrust_min, thrust_max
        self.hover_thrust = hover_thrust
        self.max_age = max_age
        self.guard_hold = guard_hold
        self.counts = {"tilt_clamped": 0, "thrust_clamped": 0}
        gate.counts.setdefault("ref_clamped", 0)  # summary["gate"]: ticks the envelope clamp acted on
        self.ref_step = None if ref_rate is None else np.asarray(ref_rate, dtype=float) * period
        self.quiet_ticks = max(int(round(1.0 / period)), 1)
        self.reset()

    def reset(self) -> None:
        """A new run: no stalls, streaks or saturations yet (the gate's own counts stay)."""
        self.stalls: list[dict] = []
        self.guard_saturations: list[dict] = []
        self.prev_tick_wall = math.nan
        self.clamped_since = math.nan  # control-clock time of the first tick of the current clamped streak
        self.prev_flags = 0
        self.prev_reason = ""
        self.dropped_seen = 0
        self.proposal: np.ndarray | None = None  # the solver's reference the guard clamped on this tick
        self.since_clamp = -1  # ticks since the envelope clamp last acted (-1: not yet in this run)

    def stalled(self, now: float) -> bool:
        """Real time: True (an event, a stall recorded) when the last tick was more than ``max_age`` ago."""
        if self.max_age is None:
            return False
        gap = now - self.prev_tick_wall
        self.prev_tick_wall = now
        if not (math.isfinite(gap) and gap > self.max_age):
            return False
        self.stalls.append({"t": round(self.events.since_start(now), 4), "gap_s": round(gap, 4)})
        self.events(f"bridge stalled: no tick for {gap:.3f} s (its own clock; limit {self.max_age * 1e3:.0f} ms): "
                    "steering history refilled, reference resumes from where it stood")
        return True

    def reference(self, ref: TickReference, edge: str = "") -> tuple[np.ndarray, int]:
        """(the reference to apply (m,), the gate flags): a guard trip (``ref.candidate``, the solver's proposal)
        clamps the steered offset to the guard instead of dropping it (a clamp, not a fallback); then the gate.
        ``edge``: the engagement's edge on this tick (:meth:`.engagement.Engagement.update`). "resume": this tick's
        nominal reference was re-anchored: the applied one moves at most the rate bound from where it stood,
        whatever the nominal's jump. "first": the run's first engagement: the vehicle never flew a reference of
        this run before (disarmed it got the idle ground setpoint, out of off-board it ignored them), so the
        applied reference starts at this tick's nominal one (the take-off's or the blend's start, from the
        measured outputs), not rate-limited from what the inactive ticks computed."""
        flags = 0
        u = ref.u
        if edge == "first":
            self.gate.passed(ref.r_nom)
        elif edge == "resume":
            self.gate.hold_nominal(ref.r_nom)
        self.proposal = None
        if ref.candidate is not None and self.max_step is not None:
            self.proposal = ref.candidate
            u = ref.r_nom + np.clip(ref.candidate - ref.r_nom, -self.max_step, self.max_step)
            flags |= GATE_FLAGS["guard_clamped"]
            self.gate.counts["guard_clamped"] += 1
        prev = self.gate.last_u
        applied, g = self.gate.apply(u, ref.r_nom)
        return self.envelope_clamp(applied, prev, flags | g)

    def envelope_clamp(self, u: np.ndarray, prev: np.ndarray | None, flags: int) -> tuple[np.ndarray, int]:
        """The envelope's own bound on every applied reference, whatever the mode (collect's PRBS included):
        at most ``ref_rate`` per second from what was applied on the last tick (``prev``), then inside the box.
        A clamp sets the ``rate_limited`` flag, is counted (the gate's ``ref_clamped``) and is an event at
        the first clamp of a run and after each second without one (an episode), never per tick."""
        if self.ref_step is None or prev is None or self.ref_step.shape != u.shape:
            return u, flags
        out = np.clip(np.clip(u, prev - self.ref_step, prev + self.ref_step), self.gate.lo, self.gate.hi)
        if np.array_equal(out, u):
            if self.since_clamp >= 0:
                self.since_clamp += 1
            return u, flags
        self.gate.last_u = out.copy()  # the next tick's bounds start from what is applied
        new = GATE_FLAGS["rate_limited"] & ~flags
        if new:
            self.gate.counts["rate_limited"] += 1
        self.gate.counts["ref_clamped"] += 1
        if self.since_clamp < 0 or self.since_clamp >= self.quiet_ticks:
            self.events(f"envelope: reference {np.round(u, 4).tolist()} clamped to {np.round(out, 4).tolist()} "
                        f"(at most {np.round(self.ref_step, 6).tolist()} per tick from the last applied "
                        f"{np.round(prev, 4).tolist()}, within {self.gate.lo.tolist()} .. {self.gate.hi.tolist()})")
        self.since_clamp = 0
        return out, flags | new

    def saturated(self, flags: int, now: float, t_ctrl: float) -> int:
        """The ``guard_saturated`` flag when this tick ends a streak of ``guard_hold`` s of guard-clamped ticks
        (the owner then hands the steering back); else 0. ``t_ctrl``: the control clock (vehicle time in
        lock-step, where a simulated vehicle runs faster than the wall); ``now``: the bridge's, for the record."""
        if not flags & GATE_FLAGS["guard_clamped"]:
            self.clamped_since = math.nan
            return 0
        if math.isnan(self.clamped_since):
            self.clamped_since = t_ctrl
        held = t_ctrl - self.clamped_since
        if not (self.guard_hold > 0 and held >= self.guard_hold):
            return 0
        self.clamped_since = math.nan
        self.guard_saturations.append({"t": round(self.events.since_start(now), 4), "held_s": round(held, 4)})
        self.gate.counts["guard_saturated"] += 1
        self.events(f"steering saturated: its correction held at the {self.max_step.tolist()} guard for "
                    f"{held:.2f} s (the predictor no longer explains the vehicle): steering refilled, reference "
                    "handed back to the nominal one at the rate bound")
        return GATE_FLAGS["guard_saturated"]

    def clamp(self, sp) -> tuple[tuple, float]:
        """The controller's setpoint (``q``, ``euler``, ``thrust``) with roll / pitch within ``max_tilt`` and
        the thrust within its clamps: (q ENU/FLU, thrust)."""
        e, q = sp.euler, sp.q
        roll, pitch, yaw = float(e[0]), float(e[1]), float(e[2])
        lim = self.max_tilt
        q_enu = (float(q[0]), float(q[1]), float(q[2]), float(q[3]))
        if abs(roll) > lim or abs(pitch) > lim or not (math.isfinite(roll) and math.isfinite(pitch)):
            self.counts["tilt_clamped"] += 1
            roll = max(-lim, min(lim, roll)) if math.isfinite(roll) else 0.0
            pitch = max(-lim, min(lim, pitch)) if math.isfinite(pitch) else 0.0
            q_enu = tuple(float(v) for v in quat_from_euler(roll, pitch, yaw if math.isfinite(yaw) else 0.0))
        thrust = float(sp.thrust)
        lo, hi = self.thrust_min, self.thrust_max
        if not math.isfinite(thrust):
            thrust = self.hover_thrust
            self.counts["thrust_clamped"] += 1
        if thrust < lo or thrust > hi:
            self.counts["thrust_clamped"] += 1
            thrust = min(max(thrust, lo), hi)
        return q_enu, thrust

    def setpoint(self, q, thrust: float, field: float,
                 fallback: Callable[[], tuple[tuple, float, float]]) -> tuple[tuple, float, float, int]:
        """A setpoint with a non-finite part becomes ``fallback()`` (never sent as is): (q, thrust, field, flags)."""
        isfinite = math.isfinite
        if (isfinite(q[0]) and isfinite(q[1]) and isfinite(q[2]) and isfinite(q[3]) and isfinite(thrust)
                and isfinite(field)):
            return q, thrust, field, 0
        q, thrust, field = fallback()
        self.gate.counts["nonfinite_setpoint"] += 1
        return q, thrust, field, GATE_FLAGS["nonfinite_setpoint"]

    def report(self, u: np.ndarray, r_nom: np.ndarray, reason: str, flags: int, notes: list[str],
               dropped: int) -> None:
        """Events at the start of each streak: gate actions, fallbacks (by reason); then ``notes`` (drained) and
        dropped telemetry (``dropped``: samples dropped so far)."""
        new = flags & ~self.prev_flags
        self.prev_flags = flags
        names = [k for k in _GATE_EVENTS if new & GATE_FLAGS[k]] if new else None
        if names:
            self.events(f"gate: {', '.join(names)} (reference {np.round(u, 4).tolist()}, "
                        f"nominal {np.round(r_nom, 4).tolist()})")
        if flags & GATE_FLAGS["guard_clamped"]:
            reason = "guard_clamped"  # the correction held at the guard: a clamp, not a fallback
            if new & GATE_FLAGS["guard_clamped"] and self.proposal is not None:
                self.events(f"guard: steered correction clamped at the {self.max_step.tolist()} guard (solver "
                            f"proposed {np.round(self.proposal, 4).tolist()}, applied {np.round(u, 4).tolist()}, "
                            f"nominal {np.round(r_nom, 4).tolist()})")
        own = reason in ("stale", "no_heartbeat")  # their own events (staleness, link)
        if reason != self.prev_reason and not own and (reason in FALLBACK_REASONS
                                                       or reason.startswith(("solver_", "nonfinite", "exception"))):
            self.events(f"fallback: {reason} (reference rate-limited back to the nominal one)")
        self.prev_reason = reason
        for note in notes:
            self.events(note)
        notes.clear()
        if dropped > self.dropped_seen:
            if self.dropped_seen == 0:
                self.events("telemetry with a non-finite field (or a non-unit quaternion) dropped; counted in "
                            "summary telemetry_dropped")
            self.dropped_seen = dropped

    def summary(self) -> dict:
        """The gate's ticks per action and bounds."""
        return self.gate.summary()
