"""The bridge's hopping part: phases on the companion computer and the hopping steering tick.

Per tick, before the controller's stage (a)::

    phase  = PhaseEstimator.update(z, vz, roll, pitch[, contact flag])   robot/phases.py, [contact]
    state.contact = (phase == GROUND)                                     the controller's stance switch
    r_nom  = controller.nominal_reference(state)                          hopping mode: arc / Raibert / stance

and the mode's reference: passthrough r_nom; collect r_nom + PRBS in the air only (the ground phase
keeps the spring leg's natural dynamics, as the in-process collection does); steer
:class:`~ddpc_codegen.runtime.hopping.HoppingSteering` -- the same per-tick policy as the
simulator's hook (ground ticks pass r_nom, aerial windows with the ground part completed by the
solver's generated artificial-IO operator, the desired arc continued ballistically).

The phase label logged and given to the steering is the controller's (GROUND from the contact
estimate, ASCENT / DESCENT from its arc), as in :func:`ddpc_codegen.sim.simulate`, so a tick log
splits into aerial segments and hops exactly like a simulated run.

A touchdown estimated from telemetry is confirmed 0-1 samples after the foot went below the
plane; the samples in between are relabelled ground in the steering history and the tick log
(:attr:`PhaseEstimator.backdate`): spring dynamics labelled aerial would corrupt the aerial data.

A contact signal is believed only while it is plausible: a value other than 0 / 1, or a contact reported
while the foot (estimated from telemetry) is more than ``CONTACT_HEIGHT_TOL`` above the ground -- a
touchdown faster than the hop's own dynamics allow -- is refused: the phases switch to the telemetry
estimate for the rest of the flight, counted (``contact_refused``) and said once in ``notes`` (the bridge
logs them as events).

At the first engagement the controller is released at rest where the robot hovers (the first
arc's apex is the measured height, trajectory time 0) and the estimator starts in DESCENT. A telemetry
hole (lock-step: a missing stamp), stale telemetry or a re-engagement resets the hopping history
(:meth:`HoppingSteering.lost` / ``reset``): a window cannot be bridged across a possible ground
phase; the policy fades the offset back in (bumpless). In real time a late sample is held, as
when flying.
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from ddpc_codegen.values.phases import DESCENT, GROUND
from ddpc_codegen.robot.controller import HeightLegAngleController
from ddpc_codegen.robot.phases import ContactConfig, PhaseEstimator
from ddpc_codegen.runtime.hopping import HoppingSteering, HoppingWindow
from ddpc_codegen.runtime.policy import SteeringPolicy

__all__ = ["HoppingLoop", "hopping_window", "completion_time_warning", "CONTACT_HEIGHT_TOL"]

CONTACT_HEIGHT_TOL = 0.05  # m: a foot this far above the ground cannot be on it (telemetry noise is mm)


def hopping_window(solver, t_ini: int) -> HoppingWindow:
    """The online ground-phase window of a generated hopping solver: its artificial-IO operator
    (``solver.artificial_io``) with the window settings it was generated with (manifest
    ``artificial_io``: t_d_online, min_ascent, the online sigma, denoise_online) -- the same window
    the in-process loop builds from the config.

    Raises:
        ValueError: the solver carries no artificial-IO operator (not generated from hopping data).
    """
    art = getattr(solver, "artificial_io", None)
    if art is None:
        raise ValueError("the solver has no artificial-IO operator (manifest 'artificial_io'): hopping steering "
                         "needs one; generate the solver from hopping data (ddpc-codegen codegen configs/hopping.toml "
                         "--dataset <hopping tick log>)")
    if (art.m, art.p) != (solver.manifest["dims"]["m"], solver.manifest["dims"]["p"]):
        raise ValueError(f"artificial-IO operator has m={art.m}, p={art.p}, the solver {solver.manifest['dims']}")
    return HoppingWindow(art, t_ini, **art.window_settings())


def completion_time_warning(art, rate_hz: float, *, share: float = 0.5, repeats: int = 3) -> str | None:
    """Time the artificial-IO operator on its longest windows before the loop runs: ``depth`` samples
    all known (every denoised or refitted window under sensor noise) and with the first third missing
    (a ground phase filled). The operator's counters are left as they were.

    Args:
        art: the operator (``depth``, ``m``, ``p``, ``lo``, ``hi``, ``complete``, ``counts``).
        rate_hz: the loop rate; share: the part of a tick the completion may take.
    Returns:
        a warning when the slower window (best of ``repeats`` calls) takes more than ``share`` of a tick
        -- the tick would run late on every such window -- else None.
    """
    L, m = int(art.depth), int(art.m)
    lo, hi = np.asarray(art.lo, dtype=float), np.asarray(art.hi, dtype=float)
    # inside every bound, so the fill is the unbounded one (a bounded fill is rarer and slower)
    fl, fh = np.isfinite(lo), np.isfinite(hi)
    mid = np.zeros(lo.shape)
    mid[fl & fh] = 0.5 * (lo[fl & fh] + hi[fl & fh])
    mid[fl & ~fh], mid[~fl & fh] = lo[fl & ~fh], hi[~fl & fh]
    w = np.tile(mid, (L, 1))
    ground = np.zeros(L, dtype=bool)
    ground[: L // 3] = True
    counts = dict(art.counts)
    worst = 0.0
    try:
        for missing in (np.zeros(L, dtype=bool), ground):
            best = math.inf
            for _ in range(repeats):
                t0 = time.perf_counter()
                art.complete(w[:, :m], w[:, m:], missing, replace_known=True)
                best = min(best, time.perf_counter() - t0)
            worst = max(worst, best)
    finally:
        art.counts.clear()
        art.counts.update(counts)
    tick = 1.0 / rate_hz
    if worst <= share * tick:
        return None
    return (f"the artificial-IO completion takes {worst * 1e3:.2f} ms on a {L}-sample window, more than "
            f"{share:.0%} of the {tick * 1e3:.1f} ms tick: hopping ticks will run late (a faster companion "
            f"computer, or regenerate with a smaller depth: [artificial_io] t_a / ground_margin)")


class HoppingLoop:
    """Phase detection and the hopping reference of one bridge (see the module docstring).

    Args:
        ctrl: the hopping-mode controller.
        contact: how contact is detected (``source`` "estimate" or "signal").
        policy: steer mode: the shared policy around the loaded solver (None otherwise).
        window: steer mode: the ground-phase completion (:func:`hopping_window`).
    """

    def __init__(self, ctrl: HeightLegAngleController, contact: ContactConfig,
                 policy: SteeringPolicy | None = None, window: HoppingWindow | None = None) -> None:
        if ctrl.mode != "hopping":
            raise ValueError("HoppingLoop needs the controller in hopping mode")
        self.ctrl = ctrl
        c = ctrl.config
        self.contact = contact
        self.estimator = PhaseEstimator(contact)
        self.steering = HoppingSteering(policy, window, c.g_eff, c.dt) if policy is not None else None
        self.counts = {"contact_missing": 0, "contact_old": 0, "contact_refused": 0}
        self.phase = DESCENT
        self.notes: list[str] = []  # what the bridge should log as events (drained by it)

    @property
    def uses_signal(self) -> bool:
        return self.contact.source == "signal"

    def observe(self, state, telem):
        """This tick's phase from the measured state (trajectory frame) and, with a leg sensor, the
        newest contact flag; returns the state with ``contact`` set for the controller."""
        e = state.euler
        z, vz = float(state.position[2]), float(state.velocity[2])
        if self.uses_signal:
            if telem.contact is None:
                # No flag yet: keep the phase (the robot is released in the air).
                self.counts["contact_missing"] += 1
                return dataclasses.replace(state, contact=self.estimator.contact)
            if not telem.contact_stamp >= telem.newest_stamp() - 1e-6:
                self.counts["contact_old"] += 1  # an older flag than the state sample: used, counted
            why = self._implausible(telem.contact_value, z, float(e[0]), float(e[1]))
            if why is None:
                self.estimator.update(z, vz, float(e[0]), float(e[1]), signal=telem.contact)
                return dataclasses.replace(state, contact=self.estimator.contact)
            self._refuse_signal(why)
        if not self.uses_signal:
            self.estimator.update(z, vz, float(e[0]), float(e[1]))
            if self.estimator.backdate and self.steering is not None:
                self.steering.relabel(self.estimator.backdate, GROUND)
        return dataclasses.replace(state, contact=self.estimator.contact)

    def _implausible(self, value: int | None, z: float, roll: float, pitch: float) -> str | None:
        """Why this contact flag cannot be true, or None."""
        if value not in (0, 1):
            return f"contact value {value} (a contact flag is 0 or 1)"
        h = self.estimator.foot_height(z, roll, pitch)
        if value == 1 and h > CONTACT_HEIGHT_TOL:
            return f"contact reported with the foot {h:.3f} m above the ground (more than {CONTACT_HEIGHT_TOL:g} m)"
        return None

    def _refuse_signal(self, why: str) -> None:
        """Stop believing the contact signal: phases from the telemetry estimate from now on."""
        self.counts["contact_refused"] += 1
        self.contact = dataclasses.replace(self.contact, source="estimate")
        self.estimator.config = self.contact
        self.notes.append(f"contact signal refused: {why}; phases from the telemetry estimate from now on")

    @property
    def backdate(self) -> int:
        """Ticks before this one to relabel ground (a touchdown confirmed late; see PhaseEstimator)."""
        return self.estimator.backdate

    def release(self, state) -> None:
        """First engagement: the controller's first arc is a release from rest at the measured height
        (trajectory time 0); phases start in DESCENT; no steering history."""
        self.ctrl.reset(0.0, float(state.position[2]))
        self.estimator.reset(DESCENT)
        self.reset()

    def reset(self) -> None:
        """Forget the steering history (re-engagement, stale telemetry, a long hole)."""
        if self.steering is not None:
            self.steering.reset()

    def lost(self, n_missing: int) -> None:
        if self.steering is not None:
            self.steering.lost(n_missing)

    def excitation(self, exc: np.ndarray) -> np.ndarray:
        """Collect mode: the PRBS sample in the air, zeros on the ground."""
        return np.zeros_like(exc) if self.ctrl.phase == GROUND else exc

    def steer(self, y: np.ndarray, r_nom: np.ndarray, t_traj: float,
              ahead: np.ndarray) -> tuple[np.ndarray, str, float, np.ndarray | None]:
        """Steer mode: this tick's reference (m,), why, the solve time [us] (nan: none) and the steered
        reference (None unless steered)."""
        y_des, phases = self.ctrl.predict(t_traj + ahead)
        u, out = self.steering.decide(self.ctrl.phase, y, r_nom, y_des, phases)
        if out is None:
            return u, "ground" if self.ctrl.phase == GROUND else "no_window", math.nan, None
        return out.u, out.reason, out.solve_us, out.u if out.steered else None

    def summary(self) -> dict:
        ev = self.estimator.events
        out = {"contact_source": self.contact.source, **self.counts,
               "touchdowns": sum(1 for _, k in ev if k == "touchdown"),
               "liftoffs": sum(1 for _, k in ev if k == "liftoff")}
        if self.steering is not None:
            out["hopping"] = dict(self.steering.counts)
            if self.steering.window is not None:
                out["artificial_io"] = dict(self.steering.window.counts)
        return out
