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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ddpc_codegen.runtime.steerer import ReferenceSteerer, SteerOutcome

__all__ = ["SteeringPolicy", "nominal_horizon"]


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
    """

    steerer: ReferenceSteerer
    max_gap_fill: int = 3

    @property
    def t_f(self) -> int:
        return self.steerer.t_f

    def reset(self) -> None:
        """Forget the history (mode change, long telemetry hole, re-engagement)."""
        self.steerer.reset()

    def lost(self, n_missing: int, y_now: np.ndarray) -> None:
        """``n_missing`` ticks had no sample: bridge them if few, else reset the history."""
        if n_missing <= 0:
            return
        if n_missing <= self.max_gap_fill:
            self.steerer.fill_gap(n_missing, y_now)
        else:
            self.steerer.reset()

    def decide(self, y: np.ndarray, r_nom: np.ndarray, y_des: np.ndarray) -> SteerOutcome:
        """This tick's reference from the measured output ``y`` (p,), the nominal reference
        ``r_nom`` (m,) and the desired outputs ahead ``y_des`` (Tf, p); records (u, y)."""
        out = self.steerer.step(y_des, nominal_horizon(y_des, r_nom))
        self.steerer.observe(out.u, y)
        return out

    def observe(self, u_applied: np.ndarray, y: np.ndarray) -> None:
        """A tick on which the policy did not decide (e.g. hopping ground phase): keep the history."""
        self.steerer.observe(u_applied, y)

    def summary(self) -> dict:
        return self.steerer.summary()
