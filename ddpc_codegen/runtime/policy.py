"""The per-tick steering policy: one implementation for every loop (the simulator's reference
hook, the MAVLink bridge, the bridge demo).

Per tick, with the closed loop's input u = the references and output y = what the robot does::

    y_des  (Tf, p)  the desired outputs over ticks k..k+Tf-1 (from the trajectory)
    u_nom  (Tf, m)  the nominal references over the same ticks: y_des (the controller's reference
                    *is* the desired output), with row 0 replaced by r_nom, the reference the
                    model-based controller would send now -- so the fallback is exactly r_nom
    u      (m,)     ReferenceSteerer.step(y_des, u_nom): steered, or r_nom with the reason why
    then the pair (u, y) joins the history the next window is built from.

Lost samples: up to ``max_gap_fill`` missing ticks are bridged in the history (reference held,
outputs interpolated) instead of forgetting it; longer holes reset it (Tini warm-up ticks).
Hopping adds its ground-phase window on top (``set_window`` before :meth:`decide`).

Bumpless transfer. The steering offset d = u - r_nom is what the robot feels on top of its own
controller. On (re-)engagement the offset is faded in over ``ramp_ticks`` (u = r_nom + a d, a
rising linearly from 0 to 1). A fallback applies exactly r_nom by default; with
``fallback_decay`` > 0 the last offset decays geometrically instead of vanishing in one tick. The applied
u is what enters the history, so the predictor sees exactly what the loop did.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from ddpc_codegen.runtime.adapt_loop import OnlineAdaptation
from ddpc_codegen.runtime.steerer import ReferenceSteerer, SteerOutcome

__all__ = ["Policy", "SteeringPolicy", "nominal_horizon"]


@runtime_checkable
class Policy(Protocol):
    """What every loop (the simulator's hook, the MAVLink bridge) drives, once per tick: the steering
    (:class:`SteeringPolicy`) and the baselines (passthrough, prefilter, feed-forward:
    :mod:`ddpc_codegen.runtime.baselines`). Hopping wraps a :class:`SteeringPolicy` in
    :class:`~ddpc_codegen.runtime.hopping.HoppingSteering` (ground-phase windows), which drives these methods."""

    @property
    def horizon(self) -> int:
        """Desired outputs :meth:`decide` needs ahead: ticks k..k+horizon-1."""
        ...

    def decide(self, y: np.ndarray, r_nom: np.ndarray, y_des: np.ndarray) -> SteerOutcome:
        """This tick's reference from the measured outputs y (p,), the nominal reference r_nom (m,) and
        the desired outputs y_des (horizon, p)."""
        ...

    def observe(self, u_applied: np.ndarray, y: np.ndarray) -> None:
        """A tick the policy did not decide (hopping's ground phase, a blend): u_applied (m,), y (p,)."""
        ...

    def reset(self) -> None:
        """Forget the history (a new run, a re-engagement, a liftoff for a liftoff-clocked table)."""
        ...

    def summary(self) -> dict:
        """Counts for the report (JSON-serialisable)."""
        ...


def nominal_horizon(y_des: np.ndarray, r_nom: np.ndarray) -> np.ndarray:
    """u_nom (Tf, m) for a loop whose references are its desired outputs (m == p): y_des with
    row 0 = r_nom (the nominal reference of this tick, which may carry the controller's corrections)."""
    u_nom = np.array(y_des, dtype=float, copy=True)
    u_nom[0] = r_nom
    return u_nom


@dataclass
class SteeringPolicy:
    """One tick of reference steering on top of a :class:`ReferenceSteerer`.

    Args:
        steerer: history, solver call and fallback rules.
        max_gap_fill: lost ticks bridged in the history (0: a lost sample resets it).
        ramp_ticks: steered ticks over which the offset fades in after a reset (40 = 0.2 s at
            200 Hz; 0: none).
        fallback_decay: per-tick factor of the last offset on fallback ticks (e.g. 0.9: ~50 ms
            time constant at 200 Hz); 0 (default): a fallback is exactly r_nom, as documented.
        adaptation: online predictor updates (:class:`OnlineAdaptation`): steered ticks update, with its
            dither on the applied reference; None (default): the predictor stays as generated.
    """

    steerer: ReferenceSteerer
    max_gap_fill: int = 3
    ramp_ticks: int = 40
    fallback_decay: float = 0.0
    adaptation: OnlineAdaptation | None = None

    def __post_init__(self) -> None:
        if isinstance(self.ramp_ticks, bool) or not isinstance(self.ramp_ticks, int) or self.ramp_ticks < 0:
            raise ValueError(f"ramp_ticks must be an integer >= 0; got {self.ramp_ticks!r}")
        if not 0.0 <= self.fallback_decay < 1.0:
            raise ValueError(f"fallback_decay must be in [0, 1); got {self.fallback_decay!r}")
        self._n_steered = 0  # steered ticks since the last reset (the ramp's clock)
        self._offset: np.ndarray | None = None  # the last applied steering offset (decays on fallbacks)

    @property
    def t_f(self) -> int:
        return self.steerer.t_f

    @property
    def horizon(self) -> int:
        """Desired outputs needed ahead (:class:`Policy`): the steering horizon Tf."""
        return self.steerer.t_f

    def reset(self) -> None:
        """Forget the history (mode change, long telemetry hole, re-engagement); the next steered
        ticks fade in again."""
        self.steerer.reset()
        self._n_steered = 0
        if self.adaptation is not None:
            self.adaptation.solver.adapt_clear()  # a window must not span the reset

    def lost(self, n_missing: int, y_now: np.ndarray) -> None:
        """``n_missing`` ticks had no sample: bridge them if few, else reset the history."""
        if n_missing <= 0:
            return
        if self.adaptation is not None:
            self.adaptation.solver.adapt_clear()  # filled samples are not measurements: never an update
        if n_missing <= self.max_gap_fill:
            self.steerer.fill_gap(n_missing, y_now)
        else:
            self.steerer.reset()

    def decide(self, y: np.ndarray, r_nom: np.ndarray, y_des: np.ndarray) -> SteerOutcome:
        """This tick's reference from the measured output ``y`` (p,), the nominal reference
        ``r_nom`` (m,) and the desired outputs ahead ``y_des`` (Tf, p); records (u, y)."""
        out = self.steerer.step(y_des, nominal_horizon(y_des, r_nom))
        self._blend(out, np.asarray(r_nom, dtype=float))
        if self.adaptation is not None:  # after the solve, before the next tick: a swap lands between ticks
            out.u = self.adaptation.perturb(out.u, out.steered)
            self.adaptation.tick(out.u, y, out.steered)
        self.steerer.observe(out.u, y)
        return out

    def _blend(self, out: SteerOutcome, r_nom: np.ndarray) -> None:
        """Fade the offset in after a reset and out after a fallback (modifies ``out.u``)."""
        if out.steered:
            self._n_steered += 1
            if self._n_steered <= self.ramp_ticks:
                out.u = r_nom + (self._n_steered / (self.ramp_ticks + 1)) * (out.u - r_nom)
            self._offset = out.u - r_nom
        elif self._offset is not None and self.fallback_decay > 0.0:
            self._offset = self._offset * self.fallback_decay
            if np.max(np.abs(self._offset)) < 1e-12:
                self._offset = None
            else:
                out.u = r_nom + self._offset
        else:
            self._offset = None

    def observe(self, u_applied: np.ndarray, y: np.ndarray) -> None:
        """A tick on which the policy did not decide (e.g. hopping ground phase): keep the history."""
        if self.adaptation is not None:
            self.adaptation.tick(u_applied, y, False)
        self.steerer.observe(u_applied, y)

    def summary(self) -> dict:
        return self.steerer.summary()
