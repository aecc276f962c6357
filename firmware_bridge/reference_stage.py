"""The tick's reference stage: the nominal reference in, the reference to apply out, through the mode's
:class:`~ddpc_codegen.runtime.policy.Policy` (steer: the generated solver with its fallbacks; passthrough,
prefilter, feed-forward: the baselines; hopping steer: :class:`.hopping_loop.HoppingLoop`'s ground-phase
windows; collect: the nominal reference plus the PRBS).

While the loop is not engaged (no heartbeat, not armed + off-board, stale telemetry, a bumpless blend) the
nominal reference passes, with the reason. The product is a :class:`TickReference`. The stage knows nothing
of trajectories: the desired outputs ahead come from a function of trajectory time, so a front end whose
reference is someone else's setpoint stream owns one as the bridge does.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ddpc_codegen.runtime.adapt_loop import adapt_code
from ddpc_codegen.runtime.policy import Policy
from ddpc_codegen.runtime.steerer import ReferenceSteerer

from firmware_bridge.baseline_modes import feedforward_row
from firmware_bridge.excitation import Excitation
from firmware_bridge.hopping_loop import HoppingLoop

__all__ = ["ReferenceStage", "TickReference", "HOLD_REASONS"]

# Why the nominal reference passes untouched (the tick log's reason).
HOLD_REASONS = ("no_heartbeat", "inactive", "stale", "blend", "takeoff")


@dataclass(frozen=True, slots=True)
class TickReference:
    """One tick's reference, before the last gate.

    Attributes:
        r_nom: (m,) the nominal reference (after a take-off ramp or a blend); y: (p,) the measured outputs.
        u: (m,) the reference the mode proposes; reason: why (a tick-log reason).
        u_steered: (m,) the solver's reference on a steered tick (else None).
        excitation: (m,) collect mode's PRBS sample (else None).
        solve_us: the solver call [us] (nan: none).
        candidate: (m,) a steered reference refused by the step guard (the gate clamps it to the guard).
        observed: the policy's history holds this tick (the gate's applied reference is written back).
        adapt, adapt_offset, adapt_snap: the online update's state code, offset norm and snapshot.
    """

    r_nom: np.ndarray
    y: np.ndarray
    u: np.ndarray
    reason: str
    u_steered: np.ndarray | None = None
    excitation: np.ndarray | None = None
    solve_us: float = math.nan
    candidate: np.ndarray | None = None
    observed: bool = False
    adapt: int = 0
    adapt_offset: float = math.nan
    adapt_snap: int = 0


class ReferenceStage:
    """Nominal reference -> the mode's reference (see the module docstring).

    Args:
        mode: "steer", "passthrough", "prefilter", "feedforward" or "collect".
        desired: desired outputs (len(t), p) at trajectory times t [s].
        period: the tick [s].
        policy: the mode's policy (collect: None); ahead: the trajectory-time offsets [s] its ``decide``
            needs desired outputs at.
        steerer: steer mode: the policy's steerer (its history takes the applied reference).
        hop: hopping: the phases and (steer) the ground-phase windows.
        excitation: collect mode: the PRBS.
    """

    def __init__(self, mode: str, desired: Callable[[np.ndarray], np.ndarray], period: float, *,
                 policy: Policy | None = None, ahead: np.ndarray | None = None,
                 steerer: ReferenceSteerer | None = None, hop: HoppingLoop | None = None,
                 excitation: Excitation | None = None) -> None:
        if mode == "collect" and excitation is None:
            raise ValueError("collect mode needs its excitation")
        if mode != "collect" and policy is None:
            raise ValueError(f"{mode} mode needs its policy")
        self.mode = mode
        self.desired = desired
        self.period = period
        self.policy = policy
        self.ahead = np.zeros(1) if ahead is None else np.asarray(ahead, dtype=float)
        self.steerer = steerer
        self.hop = hop
        self.excitation = excitation

    def reset(self) -> None:
        """Forget the steering history (hopping: its own (u, y, phase) history too)."""
        if self.hop is not None:
            self.hop.reset()
        elif self.steerer is not None:
            self.policy.reset()

    def step(self, r_nom: np.ndarray, y: np.ndarray, t_traj: float, hold: str = "", fill: int = 0) -> TickReference:
        """This tick's reference.

        Args:
            r_nom: (m,) the nominal reference; y: (p,) the measured outputs; t_traj: trajectory time [s].
            hold: why the nominal reference passes ("" when engaged; one of :data:`HOLD_REASONS`).
            fill: lost ticks to bridge in the history before this one (lock-step gaps).
        """
        if hold:
            return self._hold(r_nom, y, hold)
        if self.mode == "steer" and self.hop is not None:
            self.hop.lost(fill)
            u, reason, solve_us, u_st = self.hop.steer(y, r_nom, t_traj, self.ahead)
            return TickReference(r_nom, y, u, reason, u_steered=u_st, solve_us=solve_us)
        if self.mode == "steer":
            return self._steer(r_nom, y, t_traj, fill)
        if self.mode == "collect":
            exc = self.excitation.next()
            if self.hop is not None:
                exc = self.hop.excitation(exc)
            return TickReference(r_nom, y, r_nom + exc, "collect", excitation=exc)
        if self.mode == "feedforward":  # the row of this trajectory tick (a re-engagement continues it)
            self.policy.seek(feedforward_row(t_traj, self.period))
        out = self.policy.decide(y, r_nom, self.desired(t_traj + self.ahead))
        return TickReference(r_nom, y, out.u, out.reason)

    def _hold(self, r_nom: np.ndarray, y: np.ndarray, reason: str) -> TickReference:
        observed = False
        if reason == "stale":
            if self.hop is not None:
                self.hop.reset()
            elif self.steerer is not None:
                self.steerer.reset()
        elif reason == "blend" and self.steerer is not None:
            # The hand-over is the controller's alone: the solver would pull the reference back to the
            # trajectory faster than the blend allows. The history fills meanwhile (no extra warm-up).
            self.policy.observe(r_nom, y)
            observed = True
        return TickReference(r_nom, y, r_nom, reason, observed=observed)

    def _steer(self, r_nom: np.ndarray, y: np.ndarray, t_traj: float, fill: int) -> TickReference:
        pol = self.policy
        pol.lost(fill, y)
        out = pol.decide(y, r_nom, self.desired(t_traj + self.ahead))
        cand = None
        if out.reason == "step_too_large" and out.result is not None:  # clamped to the guard by the gate
            cand = np.asarray(out.result.u[0], dtype=float)
        ad = pol.adaptation
        if ad is None:
            return TickReference(r_nom, y, out.u, out.reason, u_steered=out.u if out.steered else None,
                                 solve_us=out.solve_us, candidate=cand, observed=True)
        return TickReference(r_nom, y, out.u, out.reason, u_steered=out.u if out.steered else None,
                             solve_us=out.solve_us, candidate=cand, observed=True, adapt=adapt_code(ad.last),
                             adapt_offset=ad.offset_norm, adapt_snap=ad.last_snap)

    def applied(self, ref: TickReference, u: np.ndarray) -> None:
        """The gate's reference ``u`` (m,) for this tick: the steering history holds what the loop applied,
        not what was proposed."""
        st = self.steerer
        if ref.observed and self.hop is None and st is not None and st.ready and not np.array_equal(u, ref.u):
            u_ini, y_ini = st.window()
            u_ini[-1] = u
            st.set_window(u_ini, y_ini)

    def summary(self) -> dict:
        """The mode's own part of the bridge summary (hopping, steering, prefilter or feedforward counts)."""
        out: dict = {}
        if self.hop is not None:
            out["hopping"] = self.hop.summary()
        if self.steerer is not None:
            out["steering"] = self.steerer.summary()
            if getattr(self.policy, "adaptation", None) is not None:
                out["steering"]["adaptation"] = self.policy.adaptation.summary()
            injected = getattr(self.steerer.solver, "injected", None)  # a FaultInjectingSolver's count
            if isinstance(injected, int):
                out["steering"]["injected_failures"] = injected
        if self.mode == "prefilter":
            out["prefilter"] = {"model": self.policy.model.to_dict(), "counts": self.policy.summary()}
        if self.mode == "feedforward":  # beyond_table: ticks past the table's end (its last row held)
            out["feedforward"] = {"rows": int(self.policy.delta.shape[0]), "dt": self.policy.dt,
                                  "counts": self.policy.summary()}
        return out
