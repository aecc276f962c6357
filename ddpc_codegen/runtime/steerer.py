"""Reference steering in the loop: ring buffers of the last Tini (u, y), one solve per tick,
and a safe fallback to the nominal reference whenever steering cannot be trusted.

Timing convention (the one data is collected with): at tick k the controller has measured
y[k] and applied u[0..k-1]. The window is u_ini = u[k-Tini:k], y_ini = y[k-Tini:k] and the
horizon covers ticks k..k+Tf-1, so ``observe`` is called once per tick *after* the applied
reference of that tick is known, with the measurement that tick's decision used.
"""

from __future__ import annotations

import time
from collections import Counter
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from ddpc_codegen.runtime.prediction_watch import PredictionWatch
from ddpc_codegen.values.solve_result import BOUND_TOL, SteeringResult
from ddpc_codegen.stats import percentiles

__all__ = ["ReferenceSteerer", "SteerOutcome", "SolverLike", "solver_input_bounds"]


def solver_input_bounds(solver) -> tuple[np.ndarray, np.ndarray]:
    """(u_min, u_max), (m,) each, ±inf where unbounded, of a generated solver (what it reports
    itself, else its manifest, where null means unbounded) or of a SteeringProblem (its config)."""
    if hasattr(solver, "input_bounds"):
        lo, hi = solver.input_bounds()
        return np.asarray(lo, float), np.asarray(hi, float)
    if hasattr(solver, "manifest"):
        b = solver.manifest["bounds"]
        return (np.array([-np.inf if v is None else v for v in b["u_min"]], float),
                np.array([np.inf if v is None else v for v in b["u_max"]], float))
    return np.asarray(solver.config.u_min, float), np.asarray(solver.config.u_max, float)


class SolverLike(Protocol):
    def solve(self, u_ini, y_ini, y_des, u_nom=None) -> SteeringResult: ...


@dataclass
class SteerOutcome:
    """What one tick decided: ``u`` (m,) to apply, and why."""

    u: np.ndarray
    steered: bool
    reason: str  # "steered", "warmup", or the fallback cause
    solve_us: float = float("nan")
    result: SteeringResult | None = None


@dataclass
class ReferenceSteerer:
    """Per-tick steering with fallback.

    Args:
        solver: a generated solver (``load_solver``) or an interpreted ``SteeringProblem``.
        t_ini, t_f, m, p: horizons and dims (must match the solver).
        u_min, u_max: (m,) absolute limits on the applied reference; outside -> fallback.
        has_nominal: pass ``u_nom`` to the solver (R_mode "offset").
        max_step: (m,) largest allowed |u_steered - u_nom| per channel; larger -> fallback
            (a guard against a predictor driven outside its data).
        watch: a :class:`~ddpc_codegen.runtime.prediction_watch.PredictionWatch` fed the same history; while it
            finds the predictor wrong, the tick falls back ("model_mismatch") without a solve.
        pause: set by the caller for the ticks its loop is outside the predictor's range (e.g. the proxy's
            ``--max-jerk`` guard): while not "", the tick falls back with this reason, without a solve.
    """

    solver: SolverLike
    t_ini: int
    t_f: int
    m: int
    p: int
    u_min: np.ndarray | None = None
    u_max: np.ndarray | None = None
    has_nominal: bool = True
    max_step: np.ndarray | None = None
    watch: PredictionWatch | None = None
    pause: str = ""
    counts: Counter = field(default_factory=Counter)
    solve_us: list = field(default_factory=list)

    def __post_init__(self) -> None:
        self._u = np.zeros((self.t_ini, self.m))
        self._y = np.zeros((self.t_ini, self.p))
        self._n = 0
        self._tolerant: tuple | None = None  # (u_min, u_max, widened u_min, widened u_max) of the bounds in use
        for k in ("u_min", "u_max", "max_step"):
            v = getattr(self, k)
            if v is not None:
                setattr(self, k, np.broadcast_to(np.asarray(v, float), (self.m,)).copy())

    @classmethod
    def for_solver(cls, solver, **kw) -> "ReferenceSteerer":
        """Build from a generated solver's (or SteeringProblem's) own dimensions and, unless
        ``u_min`` / ``u_max`` are given, its own input bounds (:func:`solver_input_bounds`)."""
        if hasattr(solver, "manifest"):
            d = solver.manifest["dims"]
            dims = d["t_ini"], d["t_f"], d["m"], d["p"]
        else:
            c = solver.config
            dims = c.t_ini, c.t_f, c.m, c.p
        if "u_min" not in kw and "u_max" not in kw:
            kw["u_min"], kw["u_max"] = solver_input_bounds(solver)
        return cls(solver, *dims, has_nominal=solver.has_nominal, **kw)

    @property
    def ready(self) -> bool:
        """True once Tini (u, y) pairs have been observed."""
        return self._n >= self.t_ini

    def reset(self) -> None:
        """Forget the history (e.g. after a mode change or a telemetry gap)."""
        self._n = 0
        if self.watch is not None:
            self.watch.reset()
        if hasattr(self.solver, "reset"):
            self.solver.reset()

    def observe(self, u_applied: np.ndarray, y_measured: np.ndarray) -> None:
        """Push the pair of one tick: the reference applied and the output it was decided on."""
        self._u[:-1] = self._u[1:]  # in-place shift: no allocation per tick
        self._y[:-1] = self._y[1:]
        self._u[-1] = u_applied
        self._y[-1] = y_measured
        self._n += 1
        if self.watch is not None:
            self.watch.push(self._u[-1], self._y[-1])

    def fill_gap(self, n_missing: int, y_now: np.ndarray) -> None:
        """Bridge ``n_missing`` lost ticks instead of forgetting the history.

        During a lost tick the plant kept the last applied reference (zero-order hold), so u
        repeats the last observed u; the outputs of the lost ticks are interpolated linearly
        between the last observed y and ``y_now`` (p,), this tick's output (a few ms of a
        smooth signal). Call before :meth:`step` of the tick that ended the gap.
        """
        if self._n == 0 or n_missing <= 0:
            return
        u_last, y_last = self._u[-1].copy(), self._y[-1].copy()
        y_now = np.asarray(y_now, dtype=float)
        for j in range(1, n_missing + 1):
            self.observe(u_last, y_last + (y_now - y_last) * (j / (n_missing + 1)))
        self.counts["gap_filled_ticks"] += n_missing

    def window(self) -> tuple[np.ndarray, np.ndarray]:
        """(u_ini (Tini, m), y_ini (Tini, p)) copies."""
        return self._u.copy(), self._y.copy()

    def set_window(self, u_ini: np.ndarray, y_ini: np.ndarray) -> None:
        """Overwrite the history (e.g. with artificial ground-phase IO for hopping)."""
        self._u[:] = u_ini
        self._y[:] = y_ini
        self._n = max(self._n, self.t_ini)
        if self.watch is not None:
            self.watch.amend(self._u, self._y)

    def step(self, y_des: np.ndarray, u_nom: np.ndarray) -> SteerOutcome:
        """Decide this tick's reference.

        Args:
            y_des: (Tf, p) desired outputs over ticks k..k+Tf-1.
            u_nom: (Tf, m) nominal (unsteered) references over the same ticks; u_nom[0] is the fallback.
        """
        u_nom = np.asarray(u_nom, float).reshape(self.t_f, self.m)
        fallback = u_nom[0].copy()
        self.counts["ticks"] += 1
        if not self.ready:
            self.counts["warmup"] += 1
            return SteerOutcome(fallback, False, "warmup")
        if not (np.isfinite(self._u).all() and np.isfinite(self._y).all() and np.isfinite(y_des).all()
                and np.isfinite(u_nom).all()):
            return self._fallback(fallback, "nonfinite_input")
        if self.watch is not None:
            self.watch.poll()
            if not self.watch.ok:
                return self._fallback(fallback, "model_mismatch")
        if self.pause:
            return self._fallback(fallback, self.pause)
        t0 = time.perf_counter()
        try:
            res = self.solver.solve(self._u, self._y, y_des, u_nom if self.has_nominal else None)
        except Exception as e:  # a solver must never take the loop down
            return self._fallback(fallback, f"exception:{type(e).__name__}")
        us = (time.perf_counter() - t0) * 1e6
        self.solve_us.append(us)
        if not res.ok:
            return self._fallback(fallback, f"solver_{res.status}", us, res)
        u = res.u[0]
        if not np.isfinite(u).all():
            return self._fallback(fallback, "nonfinite_solution", us, res)
        lo, hi = self._tolerant_bounds()
        if (lo is not None and np.any(u < lo)) or (hi is not None and np.any(u > hi)):
            return self._fallback(fallback, "out_of_bounds", us, res)
        if self.max_step is not None and np.any(np.abs(u - fallback) > self.max_step):
            return self._fallback(fallback, "step_too_large", us, res)
        self.counts["steered"] += 1
        return SteerOutcome(u.copy(), True, "steered", us, res)

    def _tolerant_bounds(self) -> tuple[np.ndarray | None, np.ndarray | None]:
        """(u_min, u_max) widened by BOUND_TOL of their size (at least absolutely); made once per bounds (an
        assigned bound is new; per tick they would be a dozen array operations on the way to the send)."""
        c = self._tolerant
        if c is None or c[0] is not self.u_min or c[1] is not self.u_max:
            lo, hi = self.u_min, self.u_max
            c = self._tolerant = (lo, hi, None if lo is None else lo - BOUND_TOL * np.maximum(1.0, np.abs(lo)),
                                  None if hi is None else hi + BOUND_TOL * np.maximum(1.0, np.abs(hi)))
        return c[2], c[3]

    def _fallback(self, u, reason, us=float("nan"), res=None) -> SteerOutcome:
        self.counts["fallbacks"] += 1
        self.counts[f"fallback:{reason}"] += 1
        return SteerOutcome(u, False, reason, us, res)

    def summary(self) -> dict:
        """Counts and solve-time statistics (µs, wall clock around the solver call)."""
        return {
            "ticks": self.counts["ticks"], "steered": self.counts["steered"],
            "fallbacks": self.counts["fallbacks"], "warmup": self.counts["warmup"],
            "gap_filled_ticks": self.counts["gap_filled_ticks"],
            "fallback_reasons": {k.split(":", 1)[1]: v for k, v in self.counts.items() if k.startswith("fallback:")},
            "solve_us": percentiles(self.solve_us),
            "max_step": None if self.max_step is None else [float(v) for v in self.max_step],
            "prediction_watch": None if self.watch is None else self.watch.summary(),
        }
