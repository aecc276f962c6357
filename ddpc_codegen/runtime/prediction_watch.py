"""Does the predictor still describe the loop? A watch on its predictions of the flight itself.

The steering is only as right as its predictor, and a predictor fitted on one kind of motion can be wrong on
another (a loop whose answer to a large, fast move is not its answer to the small dither it was fitted on). A
steering that trusts a wrong predictor is confidently wrong: it can make the error larger than no steering.

The watch keeps the last Tini + Tf applied references and measured outputs and, every ``every`` ticks, asks the
generated solver what it would have predicted over the last Tf ticks from the Tini before them under the
references the loop really applied (:meth:`GeneratedSolver.predict`; :meth:`PredictionWatch.poll` runs a due
check, so a front end can run it after its send). The error is scored in units of the
predictor's own held-out error (``manifest.json``: ``dataset.holdout.rmse``, the same horizon-averaged RMSE, per
output), averaged over the last ``span`` checks. Above ``ratio`` the predictor is not the loop any more: the
steerer falls back to the nominal reference ("model_mismatch") until ``resume`` checks in a row are back under it.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable

import numpy as np

__all__ = ["PredictionWatch"]


class PredictionWatch:
    """The predictor's error on the flight, against its held-out error (see the module docstring).

    Args:
        solver: a generated solver (``predict``, its manifest's dims).
        reference_rmse: (p,) the held-out horizon RMSE per output, in the outputs' units.
        ratio: the predictor is wrong above this many times ``reference_rmse``.
        every: ticks between checks; span: checks averaged; resume: good checks in a row to trust it again.
        on_change: called with (ok, score) when the verdict changes (a front end's event log).
    """

    def __init__(self, solver, reference_rmse, ratio: float = 8.0, every: int = 5, span: int = 10,
                 resume: int = 10, on_change: Callable[[bool, float], None] | None = None) -> None:
        d = solver.manifest["dims"]
        self.solver, self.t_ini, self.t_f = solver, d["t_ini"], d["t_f"]
        ref = np.asarray(reference_rmse, dtype=float).reshape(-1)
        if ref.shape != (d["p"],) or not (np.isfinite(ref).all() and (ref > 0).all()):
            raise ValueError(f"reference_rmse must be {d['p']} finite values > 0; got {reference_rmse!r}")
        if not (ratio > 1 and every >= 1 and span >= 1 and resume >= 1):
            raise ValueError(f"need ratio > 1 and every, span, resume >= 1; got {ratio}, {every}, {span}, {resume}")
        self.scale, self.ratio, self.every, self.resume = 1.0 / ref, ratio, every, resume
        n = self.t_ini + self.t_f
        self._u, self._y = np.zeros((n, d["m"])), np.zeros((n, d["p"]))
        self._n = 0  # pairs held since the last reset
        self._due = False
        self._mse: deque = deque(maxlen=span)  # the last checks' mean squared error, in held-out units
        self.ok = True
        self._good = 0
        self.score = math.nan  # the last averaged error [held-out RMSEs]
        self.worst = 0.0
        self.counts = {"checks": 0, "trips": 0, "resumes": 0}
        self.on_change = on_change

    @classmethod
    def for_solver(cls, solver, ratio: float = 8.0, **kw) -> "PredictionWatch | None":
        """The watch of ``solver`` from its manifest's held-out error (None: the manifest has none)."""
        rmse = ((solver.manifest.get("dataset") or {}).get("holdout") or {}).get("rmse")
        if not rmse or not all(isinstance(v, (int, float)) and v > 0 and math.isfinite(v) for v in rmse):
            return None
        return cls(solver, rmse, ratio, **kw)

    def push(self, u: np.ndarray, y: np.ndarray) -> None:
        """One tick's applied reference ``u`` (m,) and the output ``y`` (p,) its decision used; checks when due."""
        self._u[:-1], self._y[:-1] = self._u[1:], self._y[1:]
        self._u[-1], self._y[-1] = u, y
        self._n += 1
        self._due = self._due or (self._n >= len(self._u) and self._n % self.every == 0)

    def poll(self) -> None:
        """Check now if a check is due (a front end calls it after its send, off the tick's latency; the steerer
        calls it before it decides, so a check is never skipped)."""
        if self._due:
            self._due = False
            self._check()

    def amend(self, u_ini: np.ndarray, y_ini: np.ndarray) -> None:
        """The steerer's window was rewritten (the gate's applied reference): the same in the watch's history."""
        self._u[-self.t_ini:], self._y[-self.t_ini:] = u_ini, y_ini

    def reset(self) -> None:
        """The history is gone (a gap, stale telemetry); the verdict stays until new checks change it."""
        self._n, self._due = 0, False
        self._mse.clear()

    def _check(self) -> None:
        k = self.t_ini
        if not (np.isfinite(self._u).all() and np.isfinite(self._y).all()):
            return
        y_pred = self.solver.predict(self._u[:k], self._y[:k], self._u[k:])
        err = (y_pred - self._y[k:]) * self.scale
        self._mse.append(float(np.mean(err * err)))
        self.counts["checks"] += 1
        if len(self._mse) < self._mse.maxlen:
            return
        self.score = math.sqrt(sum(self._mse) / len(self._mse))
        self.worst = max(self.worst, self.score)
        was = self.ok
        if self.score > self.ratio:
            self.counts["trips"] += self.ok
            self.ok, self._good = False, 0
        elif not self.ok:
            self._good += 1
            if self._good >= self.resume:
                self.ok = True
                self.counts["resumes"] += 1
        if self.ok != was and self.on_change is not None:
            self.on_change(self.ok, self.score)

    def summary(self) -> dict:
        """Counts, the ratio and the worst averaged error [held-out RMSEs]."""
        return {**self.counts, "ratio": self.ratio, "worst": round(self.worst, 3), "ok": self.ok}
