"""The bridge tick's safety glue (a mixin of :class:`.bridge.Bridge`): the last gate on every applied
reference (:class:`.gate.SetpointGate`) and on the final setpoint, stalls of the bridge's own clock, and
the events that say when each of them, a fallback or a refused contact signal happened.

Stalls. A gap in the bridge's own control clock longer than ``max_age`` (the process was stopped:
SIGSTOP, CPU starvation, a GC pause) is a stall even when the newest telemetry is fresh again when it
wakes up: the vehicle flew on its last setpoint meanwhile, and the steering window has a hole. It is
treated like stale telemetry: the steering history is forgotten and refilled, the reference resumes
bumplessly from where it stood (:meth:`Supervisor._update_engagement`'s resume), and the stall is an
event (time, length) in the summary, the tick log's ``gate`` column (bit ``stall``) and ``summary["stalls"]``.

Guard saturation. A steered correction beyond the ``max_step`` guard is clamped to it, tick by tick. Clamped on
every tick for ``guard_hold`` seconds, the steering is no longer a correction the predictor can stand behind (an
unseen change it cannot absorb, a vehicle that stopped following its references): holding the reference at the
guard indefinitely would be confidently wrong. The steering is forgotten and refilled (its warm-up hands the
reference back toward the nominal one at the gate's rate bound), and the saturation is an event (time, length),
bit ``guard_saturated`` of the tick log's ``gate`` column and an entry of ``summary["guard_saturations"]``; it
steers again once its window is full.
"""

from __future__ import annotations

import math

import numpy as np

from firmware_bridge.gate import GATE_FLAGS, SetpointGate
from firmware_bridge.ticklog import FALLBACK_REASONS

__all__ = ["TickSafety", "make_gate"]

_GATE_EVENTS = ("rate_limited", "envelope", "nonfinite_reference", "nonfinite_setpoint", "guard_clamped")


def make_gate(cfg, mode: str, period: float, solver=None) -> SetpointGate:
    """The gate of a bridge: the config's reference bounds; the rate per tick from the profile's envelope,
    tightened by the steering solver's ``du_max`` where it has one; collect mode: no rate limit (PRBS)."""
    from ddpc_codegen.robot.profile import Envelope

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


class TickSafety:
    """Gate, stall detection and safety events of the tick (mixed into :class:`.bridge.Bridge`)."""

    def _init_safety(self) -> None:
        self._prev_tick_wall = math.nan
        self._gate_prev = 0
        self._prev_reason = ""
        self.stalls: list[dict] = []
        self.guard_saturations: list[dict] = []
        self._clamped_since = math.nan  # control-clock time of the first tick of the current clamped streak
        self._dropped_seen = 0

    def _check_stall(self, now: float) -> bool:
        """Real time: True (and the stall handled) when the last tick was more than ``max_age`` ago."""
        if self.cfg.lockstep:
            return False
        gap = now - self._prev_tick_wall
        self._prev_tick_wall = now
        if not (math.isfinite(gap) and gap > self.cfg.max_age):
            return False
        self.stalls.append({"t": round(now - self.t0, 4), "gap_s": round(gap, 4)})
        self._event(f"bridge stalled: no tick for {gap:.3f} s (its own clock; limit {self.cfg.max_age * 1e3:.0f} ms): "
                    "steering history refilled, reference resumes from where it stood")
        self._reset_steering()
        if self._flown:
            self._fresh_again = True  # the bumpless resume of a stale stretch (Supervisor._update_engagement)
        return True

    def _check_guard_saturation(self, flags: int, now: float) -> int:
        """The ``guard_saturated`` flag (and the steering handed back) when this tick ends a streak of
        ``guard_hold`` s of guard-clamped ticks; else 0. Held on the control clock (vehicle time in lock-step,
        where a simulated vehicle runs faster than the wall); ``now``: the bridge's clock, for the record."""
        if not flags & GATE_FLAGS["guard_clamped"]:
            self._clamped_since = math.nan
            return 0
        if math.isnan(self._clamped_since):
            self._clamped_since = self._tick_t
        held = self._tick_t - self._clamped_since
        if not (self.cfg.guard_hold > 0 and held >= self.cfg.guard_hold):
            return 0
        self._clamped_since = math.nan
        self.guard_saturations.append({"t": round(now - self.t0, 4), "held_s": round(held, 4)})
        self.gate.counts["guard_saturated"] += 1
        self._event(f"steering saturated: its correction held at the {self.steerer.max_step.tolist()} guard for "
                    f"{held:.2f} s (the predictor no longer explains the vehicle): steering refilled, reference "
                    "handed back to the nominal one at the rate bound")
        self._reset_steering()
        return GATE_FLAGS["guard_saturated"]

    def _gate_reference(self, ref: dict) -> int:
        """Pass ``ref["u"]`` through the gate (in place); returns the gate flags of this tick. A guard trip
        (step_too_large) clamps the steered offset to the guard instead of dropping it."""
        flags = 0
        u = ref["u"]
        cand = ref.pop("candidate", None)
        if cand is not None and self.steerer is not None and self.steerer.max_step is not None:
            u = ref["r_nom"] + np.clip(cand - ref["r_nom"], -self.steerer.max_step, self.steerer.max_step)
            flags |= GATE_FLAGS["guard_clamped"]
            self.gate.counts["guard_clamped"] += 1
        applied, g = self.gate.apply(u, ref["r_nom"])
        if (ref.pop("observed", False) and self.hop is None and self.steerer is not None and self.steerer.ready
                and not np.array_equal(applied, ref["u"])):
            # the history holds what the loop applied, not what was proposed
            u_ini, y_ini = self.steerer.window()
            u_ini[-1] = applied
            self.steerer.set_window(u_ini, y_ini)
        ref["u"] = applied
        return flags | g

    def _gate_setpoint(self, q, thrust: float, field: float) -> tuple[tuple, float, float, int]:
        """A setpoint with a non-finite part becomes the level hover setpoint (never sent as is)."""
        if all(math.isfinite(v) for v in (*q, thrust, field)):
            return q, thrust, field, 0
        q, thrust, field = self._level_setpoint()
        self.gate.counts["nonfinite_setpoint"] += 1
        return q, thrust, field, GATE_FLAGS["nonfinite_setpoint"]

    def _safety_events(self, ref: dict, flags: int) -> None:
        """Events at the start of each streak: gate actions, fallbacks (by reason), refused contact
        signals, dropped telemetry."""
        new = flags & ~self._gate_prev
        self._gate_prev = flags
        names = [k for k in _GATE_EVENTS if new & GATE_FLAGS[k]]
        if names:
            self._event(f"gate: {', '.join(names)} (reference {np.round(ref['u'], 4).tolist()}, "
                        f"nominal {np.round(ref['r_nom'], 4).tolist()})")
        reason = ref["reason"]
        own = reason in ("stale", "no_heartbeat")  # their own events (staleness, link)
        if reason != self._prev_reason and not own and (reason in FALLBACK_REASONS
                                                        or reason.startswith(("solver_", "nonfinite", "exception"))):
            self._event(f"fallback: {reason} (reference rate-limited back to the nominal one)")
        self._prev_reason = reason
        if self.hop is not None and self.hop.notes:
            for note in self.hop.notes:
                self._event(note)
            self.hop.notes.clear()
        if self.telem.dropped > self._dropped_seen:
            if self._dropped_seen == 0:
                self._event("telemetry with a non-finite field (or a non-unit quaternion) dropped; counted in "
                            "summary telemetry_dropped")
            self._dropped_seen = self.telem.dropped
