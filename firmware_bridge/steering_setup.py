"""The mode's set-up, before anything connects. Steer mode: load the generated solver, check it against the
loop it will steer (references, outputs, rate), wrap it in the steering policy (with the online update when
``--adapt``), and check the trajectory against the solver's bounds before flying. Every mode: the
:class:`.reference_stage.ReferenceStage` with the mode's policy (hopping: its phases and ground-phase windows)."""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass

import numpy as np

from ddpc_codegen.robot.controller import HeightLegAngleController
from ddpc_codegen.robot.phases import ContactConfig
from ddpc_codegen.runtime.adapt_loop import OnlineAdaptation
from ddpc_codegen.runtime.loader import load_solver
from ddpc_codegen.runtime.policy import SteeringPolicy
from ddpc_codegen.runtime.steerer import ReferenceSteerer, solver_input_bounds

from firmware_bridge.baseline_modes import BASELINE_MODES, baseline_policy
from firmware_bridge.bridge_config import BridgeConfig, FaultInjectingSolver
from firmware_bridge.excitation import Excitation
from firmware_bridge.hopping_loop import HoppingLoop, completion_time_warning, hopping_window
from firmware_bridge.preflight import (check_solver_loop, check_trajectory_bounds, check_trajectory_extent,
                                       trajectory_rate_warning)
from firmware_bridge.profiles import Profile
from firmware_bridge.reference_stage import ReferenceStage

__all__ = ["Steering", "build_reference_stage", "build_steering", "loop_warnings"]


@dataclass(frozen=True)
class Steering:
    """Steer mode's pieces: the solver (wrapped when failures are injected), its steerer and policy, the
    prediction horizon ``t_f`` [ticks] and ``ahead``, the trajectory-time offsets of its desired outputs [s]."""

    solver: object
    steerer: ReferenceSteerer
    policy: SteeringPolicy
    t_f: int
    ahead: np.ndarray


def _check_signals(man: dict, ctrl: HeightLegAngleController, period: float, rate_hz: float) -> None:
    d = man["dims"]
    if (d["m"], d["p"]) != (ctrl.m, ctrl.p):
        raise ValueError(f"solver has m={d['m']}, p={d['p']} but the flying loop has m={ctrl.m}, p={ctrl.p}")
    sig = man.get("signals", {})
    if sig.get("inputs") and tuple(sig["inputs"]) != ctrl.input_names:
        raise ValueError(f"solver inputs {sig['inputs']} != controller references {list(ctrl.input_names)}")
    if sig.get("outputs") and tuple(sig["outputs"]) != ctrl.output_names:
        raise ValueError(f"solver outputs {sig['outputs']} != controller outputs {list(ctrl.output_names)}")
    if sig.get("dt") and abs(float(sig["dt"]) - period) > 1e-9:
        raise ValueError(f"solver dt {sig['dt']} s does not match the bridge rate {rate_hz} Hz")


def build_steering(c: BridgeConfig, ctrl: HeightLegAngleController, solver=None) -> Steering:
    """Steer mode's pieces for the loop of ``ctrl`` at ``c.rate_hz``; ``solver``: a loaded one (default:
    ``load_solver(c.solver)``).

    Raises:
        ValueError: the solver does not fit the loop, ``--adapt`` without an online update, or the trajectory
            leaves the solver's bounds.
    """
    period = 1.0 / c.rate_hz
    solver = solver if solver is not None else load_solver(c.solver)
    man = solver.manifest
    _check_signals(man, ctrl, period, c.rate_hz)
    if c.inject_solver_failure:
        start, count, *kind = c.inject_solver_failure
        solver = FaultInjectingSolver(solver, int(start), int(count), kind[0] if kind else "fail")
    steerer = ReferenceSteerer.for_solver(solver, max_step=None if c.max_step is None else np.asarray(c.max_step, float))
    adaptation = None
    if c.adapt:
        if getattr(solver, "adaptation", None) is None:
            raise ValueError(f"--adapt needs a solver generated with [adapt] enabled; {c.solver} has no online update")
        # the re-solve (tens of ms at flight sizes) runs in a worker thread, never inside a 5 ms tick
        adaptation = OnlineAdaptation(solver, seed=c.seed, background=True)
    policy = SteeringPolicy(steerer, max_gap_fill=c.max_gap_fill, adaptation=adaptation)
    lo, hi = solver_input_bounds(solver)
    if ctrl.mode == "hopping":  # the nominal hop: from the leg's rest length up to the apex target
        cc = ctrl.config
        check_trajectory_bounds(np.array([cc.leg_length, cc.apex_height]), float(lo[0]), float(hi[0]), "hop")
    else:  # any trajectory: its own extent and time span (the ellipse, a file, a random path)
        check_trajectory_extent(ctrl.trajectory, float(lo[0]), float(hi[0]))
        du = (man.get("bounds") or {}).get("du_max") or [None]
        warning = trajectory_rate_warning(ctrl.trajectory, math.inf if du[0] is None else float(du[0]), c.rate_hz)
        if warning:
            print(f"[bridge] WARNING: {warning}", file=sys.stderr, flush=True)
    t_f = man["dims"]["t_f"]
    return Steering(solver, steerer, policy, t_f, period * np.arange(t_f))


def build_reference_stage(c: BridgeConfig, ctrl: HeightLegAngleController, steering: Steering | None,
                          contact: ContactConfig) -> ReferenceStage:
    """The reference stage of ``c.mode`` (``steering``: steer mode's pieces, else None); hopping: with its
    phases (``contact``) and, steering, the solver's ground-phase windows."""
    period = 1.0 / c.rate_hz
    hopping = ctrl.mode == "hopping"
    desired = ctrl.desired_outputs
    if steering is not None:
        st = steering
        hop = HoppingLoop(ctrl, contact, st.policy, hopping_window(st.solver, st.steerer.t_ini)) if hopping else None
        return ReferenceStage("steer", desired, period, policy=st.policy, ahead=st.ahead, steerer=st.steerer, hop=hop)
    hop = HoppingLoop(ctrl, contact) if hopping else None
    if c.mode in BASELINE_MODES:  # a baseline behind the steering's interface
        lo, hi = c.reference_bounds()
        policy, ahead = baseline_policy(c.mode, getattr(c, c.mode, None), c.rate_hz, ctrl.m, hopping, hi - lo)
        return ReferenceStage(c.mode, desired, period, policy=policy, ahead=ahead, hop=hop)
    exc = Excitation(ctrl.m, c.excitation, c.excitation_hold, c.seed)
    exc.prepare()  # off the tick path: making a PRBS block imports scipy.signal
    return ReferenceStage("collect", desired, period, hop=hop, excitation=exc)


def loop_warnings(steering: Steering | None, hop: HoppingLoop | None, profile: Profile, rate_hz: float) -> list[str]:
    """Once the vehicle is known: the solver against the loop it was collected in (autopilot, thrust field), and
    the hopping completion's time against the tick."""
    out = []
    if steering is not None:
        field = "climb_rate" if profile.climb_rate_thrust else "thrust"
        out.append(check_solver_loop(steering.solver.manifest, profile.name, field))
    if hop is not None and hop.steering is not None and hop.steering.window is not None:
        out.append(completion_time_warning(hop.steering.window.art, rate_hz))
    return [w for w in out if w]
