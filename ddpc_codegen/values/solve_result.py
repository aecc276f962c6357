"""The result of one steering solve and the parameter-window check, shared by the interpreted
problem and the generated solvers (no CasADi here: the robot side imports this)."""

from __future__ import annotations

import numpy as np

from ddpc_codegen.errors import DataError

__all__ = ["SteeringResult", "stack_window", "nominal_increments", "within_bounds", "BOUND_TOL"]

# The one feasibility tolerance of the package: a result may say "solved" only when every bound
# holds within BOUND_TOL * max(1, |bound|) (u, du and y bounds; the generated C, the fast path,
# DAQP's settings, the interpreted solvers and ReferenceSteerer all use this value).
BOUND_TOL = 1e-8


class SteeringResult:
    """Outcome of one steering solve.

    u (Tf, m): steered references over the horizon (u[0] is what to send now).
    y_pred (Tf, p): predicted outputs under u. sigma (Tini, p): predictor slack. (Generated
    solvers compute these two on first access, so a loop that only needs u does not pay for them.)
    status: "solved", or the solver's failure status ("max_iter", "infeasible", ...).
    fast_path: True when the unconstrained optimum was feasible and returned as is.
    solve_time: seconds spent in the solver call.
    """

    __slots__ = ("u", "status", "iterations", "solve_time", "cost", "fast_path", "info", "_y_pred", "_sigma",
                 "_predict")

    def __init__(self, u: np.ndarray, y_pred: np.ndarray | None = None, sigma: np.ndarray | None = None,
                 status: str = "solved", iterations: int = 0, solve_time: float = 0.0,
                 cost: float = float("nan"), fast_path: bool = False, info: dict | None = None,
                 predict=None) -> None:
        self.u = u
        self._y_pred = y_pred
        self._sigma = sigma
        self.status = status
        self.iterations = iterations
        self.solve_time = solve_time
        self.cost = cost
        self.fast_path = fast_path
        self.info = info if info is not None else {}
        self._predict = predict

    def _fill(self) -> None:
        if self._y_pred is None and self._predict is not None:
            self._y_pred, self._sigma = self._predict()
            self._predict = None

    @property
    def y_pred(self) -> np.ndarray:
        self._fill()
        return self._y_pred

    @property
    def sigma(self) -> np.ndarray:
        self._fill()
        return self._sigma

    @property
    def ok(self) -> bool:
        return self.status == "solved"

    @property
    def u_next(self) -> np.ndarray:
        """The reference to apply at this tick, (m,)."""
        return self.u[0]

    def __repr__(self) -> str:
        return (f"SteeringResult(status={self.status!r}, fast_path={self.fast_path}, iterations={self.iterations}, "
                f"solve_time={self.solve_time:.3g}, u_next={self.u[0]})")


def stack_window(x, T: int, c: int, what: str, check_finite: bool = True) -> np.ndarray:
    """A (T, c) time-major window or its stacked (T*c,) form, as a stacked float array.

    Raises DataError naming ``what`` on a wrong shape or (with ``check_finite``) NaN / inf.
    """
    a = np.asarray(x, dtype=float)
    if a.size != T * c or a.ndim > 2 or (a.ndim == 2 and a.shape != (T, c)):
        raise DataError(f"{what} must be ({T}, {c}) time-major or stacked ({T * c},); got shape {a.shape}")
    a = a.reshape(-1)
    if check_finite and not np.all(np.isfinite(a)):
        raise DataError(f"{what} contains NaN or inf; refusing to steer on it")
    return a


def nominal_increments(m: int, t_f: int) -> np.ndarray:
    """(m*Tf, m*Tf) map of the stacked nominal references u_nom (time-major) to their increments over the
    horizon, the first one (before the horizon: not known) extrapolated one step back, u_nom_1 - u_nom_0 (zero
    when Tf = 1): what ``[cost] R_doffset`` takes off the references' increments."""
    n = m * t_f
    Dn = np.eye(n) - np.eye(n, k=-m)
    Dn[:m, :] = 0.0
    if t_f > 1:
        Dn[:m, :m], Dn[:m, m : 2 * m] = -np.eye(m), np.eye(m)
    return Dn


def within_bounds(x: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> bool:
    """lo - BOUND_TOL*max(1,|lo|) <= x <= hi + BOUND_TOL*max(1,|hi|) elementwise; ±inf bounds never bind.

    The acceptance test of every "solved" answer (x, lo, hi of one shape, in the bounds' own units).
    """
    with np.errstate(invalid="ignore", over="ignore"):
        return bool(np.all(x >= lo - BOUND_TOL * np.maximum(1.0, np.abs(lo)))
                    and np.all(x <= hi + BOUND_TOL * np.maximum(1.0, np.abs(hi))))
