"""Any per-tick :class:`~ddpc_codegen.runtime.policy.Policy` as the simulator's ``reference_hook``.

One hook for the steering and every baseline, flying and hopping, so an in-process run drives a
policy through the same methods the MAVLink bridge does (``decide`` / ``observe`` / ``reset``):

* flying: every tick ``decide(y, r_nom, y_des)`` with y_des = the desired outputs over the policy's
  ``horizon`` (z of the trajectory, the pitch of the horizontal PD with its current correction held);
* hopping, steering (:class:`SteeringPolicy`): :class:`~ddpc_codegen.runtime.hopping.HoppingSteering`,
  the implementation the bridge runs (ground ticks unsteered and observed, aerial windows with the
  ground part filled, the desired arc continued ballistically);
* hopping, a baseline: ground ticks keep r_nom and are observed; a feed-forward table on the
  "liftoff" clock is reset at every liftoff and not applied before the first one (the release arc).

It lives with the experiments, not in :mod:`ddpc_codegen.sim`: the simulator is a plant that takes
any callable, and binding the robot-side policies to it is the evaluation layer's job (the bridge,
the other binding, must not import the simulator).
"""

from __future__ import annotations

import numpy as np

from ddpc_codegen.values.phases import GROUND
from ddpc_codegen.runtime.hopping import HoppingSteering, HoppingWindow
from ddpc_codegen.runtime.policy import Policy, SteeringPolicy
from ddpc_codegen.sim import TickContext

__all__ = ["PolicyHook"]


class PolicyHook:
    """A :class:`Policy` as the simulator's ``reference_hook`` (see the module docstring).

    Args:
        policy: what decides (steering or a baseline); the caller resets it before a run.
        scenario: "flying" or "hopping".
        window: hopping steering only: the ground-phase completion of the past window.
        g_eff: hopping steering only: gravity of the ballistic arc [m/s^2] (None: y_des as given).
        dt: tick [s].

    Attributes:
        counts: ticks, ground, no_window:<reason>, filled (hopping steering: its own counts).
        solver_us: the solver's own time per solve [us] (C for a generated solver).
    """

    def __init__(self, policy: Policy, scenario: str, *, window: HoppingWindow | None = None,
                 g_eff: float | None = None, dt: float = 0.005) -> None:
        if scenario not in ("flying", "hopping"):
            raise ValueError(f"scenario must be 'flying' or 'hopping'; got {scenario!r}")
        self.policy = policy
        self.scenario = scenario
        self.window = window
        steering = isinstance(policy, SteeringPolicy)
        if not steering and (window is not None or g_eff is not None):
            raise ValueError(f"window and g_eff are the hopping steering's; {type(policy).__name__} takes neither")
        self.hopping = HoppingSteering(policy, window, g_eff, dt) if scenario == "hopping" and steering else None
        self._counts: dict[str, int] = {}
        self.solver_us: list[float] = []
        self._was_ground = False
        self._lifted = False

    @property
    def counts(self) -> dict[str, int]:
        return self.hopping.counts if self.hopping is not None else self._counts

    def __call__(self, ctx: TickContext) -> np.ndarray | None:
        pol = self.policy
        if self.hopping is not None:
            n = pol.horizon
            _, out = self.hopping.decide(int(ctx.phase), ctx.y, ctx.r_nom, ctx.desired_ahead(n), ctx.phases_ahead(n))
            if out is None:
                return None
        else:
            self._counts["ticks"] = self._counts.get("ticks", 0) + 1
            if self.scenario == "hopping" and not self._aerial(ctx):
                return None
            out = pol.decide(ctx.y, ctx.r_nom, ctx.desired_ahead(pol.horizon))
        if out.result is not None and np.isfinite(out.result.solve_time) and out.result.solve_time > 0:
            self.solver_us.append(out.result.solve_time * 1e6)
        return out.u

    def _aerial(self, ctx: TickContext) -> bool:
        """Hopping with a baseline: False on ground ticks (observed, r_nom kept) and, for a table on the
        liftoff clock, before the first liftoff; resets that table at every liftoff."""
        pol = self.policy
        liftoff_clock = getattr(pol, "clock", None) == "liftoff"
        if ctx.phase == GROUND:
            self._counts["ground"] = self._counts.get("ground", 0) + 1
            self._was_ground = True
            pol.observe(ctx.r_nom, ctx.y)
            return False
        if self._was_ground:
            self._was_ground, self._lifted = False, True
            if liftoff_clock:
                pol.reset()
        return self._lifted or not liftoff_clock
