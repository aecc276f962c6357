"""Steer mode's set-up (a mixin of :class:`.bridge.Bridge`): load the generated solver, check it
against the loop it will steer (references, outputs, rate), wrap it in the steering policy (with the
online update when ``--adapt``), and check the trajectory against the solver's bounds before flying."""

from __future__ import annotations

import math
import sys

import numpy as np

from ddpc_codegen.runtime.adapt_loop import OnlineAdaptation
from ddpc_codegen.runtime.policy import SteeringPolicy
from ddpc_codegen.runtime.steerer import ReferenceSteerer, solver_input_bounds

from firmware_bridge.bridge_config import FaultInjectingSolver
from firmware_bridge.preflight import check_trajectory_bounds, check_trajectory_extent, trajectory_rate_warning

__all__ = ["SteeringSetup"]


class SteeringSetup:
    """``_setup_solver``: needs the bridge's ``cfg``, ``ctrl``, ``ctrl_cfg``, ``m``, ``p``, ``period``,
    ``hopping``; sets ``solver``, ``steerer``, ``policy``, ``t_f`` and ``_ahead``."""

    def _setup_solver(self, solver) -> None:
        from ddpc_codegen.runtime.loader import load_solver

        c = self.cfg
        solver = solver if solver is not None else load_solver(c.solver)
        man = solver.manifest
        d = man["dims"]
        if (d["m"], d["p"]) != (self.m, self.p):
            raise ValueError(f"solver has m={d['m']}, p={d['p']} but the flying loop has m={self.m}, p={self.p}")
        sig = man.get("signals", {})
        if sig.get("inputs") and tuple(sig["inputs"]) != self.ctrl.input_names:
            raise ValueError(f"solver inputs {sig['inputs']} != controller references {list(self.ctrl.input_names)}")
        if sig.get("outputs") and tuple(sig["outputs"]) != self.ctrl.output_names:
            raise ValueError(f"solver outputs {sig['outputs']} != controller outputs {list(self.ctrl.output_names)}")
        if sig.get("dt") and abs(float(sig["dt"]) - self.period) > 1e-9:
            raise ValueError(f"solver dt {sig['dt']} s does not match the bridge rate {c.rate_hz} Hz")
        if c.inject_solver_failure:
            start, count, *kind = c.inject_solver_failure
            solver = FaultInjectingSolver(solver, int(start), int(count), kind[0] if kind else "fail")
        self.solver = solver
        self.steerer = ReferenceSteerer.for_solver(
            solver, max_step=None if c.max_step is None else np.asarray(c.max_step, float))
        adaptation = None
        if c.adapt:
            if getattr(solver, "adaptation", None) is None:
                raise ValueError(f"--adapt needs a solver generated with [adapt] enabled; {c.solver} has no online update")
            # the re-solve (tens of ms at flight sizes) runs in a worker thread, never inside a 5 ms tick
            adaptation = OnlineAdaptation(solver, seed=c.seed, background=True)
        self.policy = SteeringPolicy(self.steerer, max_gap_fill=c.max_gap_fill, adaptation=adaptation)
        lo, hi = solver_input_bounds(solver)
        if self.hopping:  # the nominal hop: from the leg's rest length up to the apex target
            cc = self.ctrl_cfg
            check_trajectory_bounds(np.array([cc.leg_length, cc.apex_height]), float(lo[0]), float(hi[0]), "hop")
        else:  # any trajectory: its own extent and time span (the ellipse, a file, a random path)
            check_trajectory_extent(self.ctrl.trajectory, float(lo[0]), float(hi[0]))
            du = (man.get("bounds") or {}).get("du_max") or [None]
            warning = trajectory_rate_warning(self.ctrl.trajectory, math.inf if du[0] is None else float(du[0]),
                                              c.rate_hz)
            if warning:
                print(f"[bridge] WARNING: {warning}", file=sys.stderr, flush=True)
        self.t_f = d["t_f"]
        self._ahead = self.period * np.arange(self.t_f)
