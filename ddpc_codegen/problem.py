"""The steering QP (DDPC-Flying / DDPC-Hopping), condensed in the steered references u alone.

With the predictor y = Gy_w w + Gy_u u, sigma = Gs_w w + Gs_u u (w = [u_ini; y_ini]) the
paper's problem becomes a dense QP in u (m*Tf variables):

    min_u  1/2 u' P u + q(theta)' u     s.t.  l(theta) <= A u <= u(theta)

with P and A constant and (q, l, u) affine in the parameters theta = [u_ini; y_ini; y_des
(; u_nom)]. Everything is formed symbolically in CasADi; P and A are evaluated once, the
parameter map is a CasADi Function (later exported as C).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import casadi as ca
import numpy as np
import osqp
import scipy.sparse as sp

from .config import SteeringConfig
from .errors import ConfigError, DataError
from .predictor import Predictor

__all__ = ["SteeringProblem", "SteeringResult"]

_OSQP_OK = {"solved"}
# DAQP exit flags (daqp/include/constants.h)
_DAQP_STATUS = {1: "solved", 2: "solved", -1: "infeasible", -2: "cycling", -3: "unbounded",
                -4: "max_iter", -5: "nonconvex", -6: "overdetermined_initial_active_set"}


@dataclass
class SteeringResult:
    """Outcome of one steering solve.

    u (Tf, m): steered references over the horizon (u[0] is what to send now).
    y_pred (Tf, p): predicted outputs under u. sigma (Tini, p): predictor slack.
    status: "solved", or the solver's failure status ("max_iter", "infeasible", ...).
    fast_path: True when the unconstrained optimum was feasible and returned as is.
    solve_time: seconds spent in the solver call (wall clock).
    """

    u: np.ndarray
    y_pred: np.ndarray
    sigma: np.ndarray
    status: str
    iterations: int = 0
    solve_time: float = 0.0
    cost: float = float("nan")
    fast_path: bool = False
    info: dict = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.status == "solved"

    @property
    def u_next(self) -> np.ndarray:
        """The reference to apply at this tick, (m,)."""
        return self.u[0]


def _window(x: np.ndarray, T: int, c: int, what: str) -> np.ndarray:
    a = np.asarray(x, dtype=float)
    if a.size != T * c or (a.ndim == 2 and a.shape != (T, c)) or a.ndim > 2:
        raise DataError(f"{what} must be ({T}, {c}) time-major or stacked ({T * c},); got shape {a.shape}")
    a = a.reshape(-1)
    if not np.all(np.isfinite(a)):
        raise DataError(f"{what} contains NaN or inf; refusing to steer on it")
    return a


class SteeringProblem:
    """Condensed steering QP for a fitted predictor and a steering configuration.

    Attributes:
        P (n_u, n_u), A (n_c, n_u): constant QP matrices (dense numpy).
        param_map: CasADi Function theta (n_theta,) -> (q (n_u,), l (n_c,), u (n_c,)).
        n_u = m*Tf, n_theta = (m+p)*Tini + p*Tf (+ m*Tf in R_mode "offset").
    """

    def __init__(self, predictor: Predictor, config: SteeringConfig) -> None:
        for key in ("t_ini", "t_f", "m", "p"):
            if getattr(predictor, key) != getattr(config, key):
                raise ConfigError(
                    f"{config.source}: {key}={getattr(config, key)} but the predictor was fitted with "
                    f"{key}={getattr(predictor, key)}; refit the predictor or fix the config"
                )
        self.predictor = predictor
        self.config = config
        c, pr = config, predictor
        m, p, Ti, Tf = c.m, c.p, c.t_ini, c.t_f
        self.n_u = m * Tf
        self.n_w = (m + p) * Ti
        self.has_nominal = c.R_mode == "offset"
        self.n_theta = self.n_w + p * Tf + (m * Tf if self.has_nominal else 0)

        u = ca.SX.sym("u", self.n_u)
        theta = ca.SX.sym("theta", self.n_theta)
        w = theta[: self.n_w]
        y_des = theta[self.n_w : self.n_w + p * Tf]
        u_ini = theta[: m * Ti]
        y = ca.mtimes(ca.DM(pr.Gy_w), w) + ca.mtimes(ca.DM(pr.Gy_u), u)
        sig = ca.mtimes(ca.DM(pr.Gs_w), w) + ca.mtimes(ca.DM(pr.Gs_u), u)
        Qb = ca.DM(np.kron(np.eye(Tf), c.Q))
        Rb = ca.DM(np.kron(np.eye(Tf), c.R))
        e = y - y_des
        J = ca.mtimes([e.T, Qb, e]) + c.lambda_sigma * ca.dot(sig, sig)
        D = np.eye(self.n_u) - np.eye(self.n_u, k=-m)  # stacked differences
        if c.R_mode == "absolute":
            ru = u
        elif c.R_mode == "offset":
            ru = u - theta[self.n_w + p * Tf :]
        else:
            u_prev = u_ini[m * (Ti - 1) :]
            ru = ca.mtimes(ca.DM(D), u) - ca.vertcat(u_prev, ca.DM.zeros(self.n_u - m))
        J = J + ca.mtimes([ru.T, Rb, ru])

        # Constraint rows: boxes on u, on predicted y, on increments — only rows that bound something.
        rows, lo, hi, kinds = [], [], [], []
        um = np.tile(c.u_min, Tf), np.tile(c.u_max, Tf)
        sel = np.isfinite(um[0]) | np.isfinite(um[1])
        for i in np.nonzero(sel)[0]:
            rows.append(u[int(i)]); lo.append(um[0][i]); hi.append(um[1][i]); kinds.append("u")
        ym = np.tile(c.y_min, Tf), np.tile(c.y_max, Tf)
        for i in np.nonzero(np.isfinite(ym[0]) | np.isfinite(ym[1]))[0]:
            rows.append(y[int(i)]); lo.append(ym[0][i]); hi.append(ym[1][i]); kinds.append("y")
        du = np.tile(c.du_max, Tf)
        if np.any(np.isfinite(du)):
            dexpr = ca.mtimes(ca.DM(D), u) - ca.vertcat(u_ini[m * (Ti - 1) :], ca.DM.zeros(self.n_u - m))
            for i in np.nonzero(np.isfinite(du))[0]:
                rows.append(dexpr[int(i)]); lo.append(-du[i]); hi.append(du[i]); kinds.append("du")
        self.constraint_kinds = tuple(kinds)
        g = ca.vertcat(*rows) if rows else ca.SX(0, 1)
        self.n_c = int(g.shape[0])

        H, grad = ca.hessian(J, u)
        Ag = ca.jacobian(g, u)
        if ca.depends_on(H, theta) or (self.n_c and ca.depends_on(Ag, theta)):
            raise AssertionError("steering QP is not a parametric QP with constant P and A")  # pragma: no cover
        q_expr = ca.substitute(grad, u, ca.DM.zeros(self.n_u))
        g0 = ca.substitute(g, u, ca.DM.zeros(self.n_u)) if self.n_c else g
        lo_v, hi_v = ca.DM(np.asarray(lo, float)), ca.DM(np.asarray(hi, float))
        l_expr = lo_v - g0 if self.n_c else ca.SX(0, 1)
        u_expr = hi_v - g0 if self.n_c else ca.SX(0, 1)
        consts = ca.Function("consts", [theta], [H, Ag])
        Hn, An = consts(np.zeros(self.n_theta))
        self.P = np.array(Hn, dtype=float)
        self.P = 0.5 * (self.P + self.P.T)
        self.A = np.array(An, dtype=float).reshape(self.n_c, self.n_u)
        # CasADi-generated C of this function is the per-tick parameter map in the generated solver.
        self.param_map = ca.Function(
            "ddpc_param_map", [theta], [q_expr, l_expr, u_expr], ["theta"], ["q", "l", "u"]
        )
        self._cost_fn = ca.Function("cost", [u, theta], [J])
        # q, l, u are affine in theta: keep the dense matrices for numpy evaluation and the gain.
        jac = ca.Function("param_jacobian", [theta], [ca.jacobian(q_expr, theta),
                                            ca.jacobian(l_expr, theta) if self.n_c else ca.DM(0, self.n_theta)])
        Fq, Fl = jac(np.zeros(self.n_theta))
        self.F_q = np.array(Fq, dtype=float).reshape(self.n_u, self.n_theta)
        self.F_c = np.array(Fl, dtype=float).reshape(self.n_c, self.n_theta)  # l = l0 + F_c theta, u = u0 + F_c theta
        q0, l0, u0 = self.param_map(np.zeros(self.n_theta))
        self.q0 = np.array(q0, dtype=float).reshape(-1)
        self.l0 = np.array(l0, dtype=float).reshape(-1)
        self.u0 = np.array(u0, dtype=float).reshape(-1)
        try:
            self._P_chol = np.linalg.cholesky(self.P)
        except np.linalg.LinAlgError:
            raise ConfigError(
                f"{c.source}: the steering QP is not strictly convex (P singular); use R > 0 on every input"
            ) from None
        # Unconstrained optimum u* = K theta + k0 (exact fast path when it satisfies the bounds).
        Pinv = np.linalg.inv(self.P)
        self.K = -Pinv @ self.F_q
        self.k0 = -Pinv @ self.q0
        self._osqp = None
        self._exact = None

    # ------------------------------------------------------------------ parameters
    def theta(
        self, u_ini: np.ndarray, y_ini: np.ndarray, y_des: np.ndarray, u_nom: np.ndarray | None = None
    ) -> np.ndarray:
        """Stack and validate the parameter vector (n_theta,). Windows may be time-major or stacked."""
        c = self.config
        parts = [
            _window(u_ini, c.t_ini, c.m, "u_ini"),
            _window(y_ini, c.t_ini, c.p, "y_ini"),
            _window(y_des, c.t_f, c.p, "y_des"),
        ]
        if self.has_nominal:
            if u_nom is None:
                raise DataError("R_mode 'offset' needs u_nom, the nominal (unsteered) references over the horizon")
            parts.append(_window(u_nom, c.t_f, c.m, "u_nom"))
        return np.concatenate(parts)

    def qp_vectors(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(q, l, u) of the QP at theta (numpy evaluation of the affine parameter map)."""
        return self.q0 + self.F_q @ theta, self.l0 + self.F_c @ theta, self.u0 + self.F_c @ theta

    def unconstrained(self, theta: np.ndarray) -> np.ndarray:
        """Unconstrained optimum K theta + k0, (n_u,)."""
        return self.K @ theta + self.k0

    def cost(self, u: np.ndarray, theta: np.ndarray) -> float:
        """Objective J(u; theta) as written (without the 1/2 of the QP form)."""
        return float(self._cost_fn(u, theta))

    # ------------------------------------------------------------------ solving
    def solve(
        self,
        u_ini: np.ndarray,
        y_ini: np.ndarray,
        y_des: np.ndarray,
        u_nom: np.ndarray | None = None,
        *,
        solver: str = "osqp",
        eps: float = 1e-7,
        max_iter: int = 20000,
    ) -> SteeringResult:
        """Solve the steering QP interpretively.

        solver: ``"osqp"`` (OSQP Python, polished, warm-started), ``"exact"`` (dense active set,
        CasADi's daqp: exact to round-off), or ``"fast"`` (unconstrained optimum if feasible,
        exact active set otherwise).
        """
        th = self.theta(u_ini, y_ini, y_des, u_nom)
        return self.solve_theta(th, solver=solver, eps=eps, max_iter=max_iter)

    def solve_theta(self, th: np.ndarray, *, solver: str = "osqp", eps: float = 1e-7,
                    max_iter: int = 20000) -> SteeringResult:
        """Like :meth:`solve`, from a stacked parameter vector."""
        q, l, ub = self.qp_vectors(th)
        t0 = time.perf_counter()
        fast = False
        if solver == "fast":
            z = self.unconstrained(th)
            if self.n_c == 0 or np.all((self.A @ z >= l - 1e-9) & (self.A @ z <= ub + 1e-9)):
                z, status, it, fast = z, "solved", 0, True
            else:
                z, status, it = self._solve_exact(q, l, ub)
        elif solver == "exact":
            z, status, it = self._solve_exact(q, l, ub)
        elif solver == "osqp":
            z, status, it = self._solve_osqp(q, l, ub, eps, max_iter)
        else:
            raise ConfigError(f"unknown solver {solver!r}; choose 'osqp', 'exact' or 'fast'")
        dt = time.perf_counter() - t0
        return self.result(z, th, status, it, dt, fast)

    def result(self, z: np.ndarray, th: np.ndarray, status: str, iterations: int = 0,
               solve_time: float = 0.0, fast_path: bool = False) -> SteeringResult:
        """Package a solution vector z (n_u,) at theta into a SteeringResult."""
        c, pr = self.config, self.predictor
        if status != "solved" or z is None or not np.all(np.isfinite(z)):
            nan = np.full(self.n_u, np.nan)
            return SteeringResult(nan.reshape(c.t_f, c.m), np.full((c.t_f, c.p), np.nan),
                                  np.full((c.t_ini, c.p), np.nan), status if status != "solved" else "nan",
                                  iterations, solve_time)
        w = th[: self.n_w]
        y = pr.Gy_w @ w + pr.Gy_u @ z
        s = pr.Gs_w @ w + pr.Gs_u @ z
        return SteeringResult(z.reshape(c.t_f, c.m), y.reshape(c.t_f, c.p), s.reshape(c.t_ini, c.p),
                              status, int(iterations), solve_time, self.cost(z, th), fast_path)

    def _solve_osqp(self, q, l, ub, eps, max_iter):
        if self._osqp is None:
            s = osqp.OSQP()
            A = sp.csc_matrix(self.A) if self.n_c else sp.csc_matrix((0, self.n_u))
            s.setup(sp.triu(sp.csc_matrix(self.P), format="csc"), q, A, l, ub, verbose=False,
                    eps_abs=eps, eps_rel=eps, polishing=True, max_iter=max_iter, warm_starting=True)
            self._osqp = s
        else:
            self._osqp.update(q=q, l=l, u=ub)
        r = self._osqp.solve(raise_error=False)
        status = str(r.info.status).lower()
        status = "solved" if status in _OSQP_OK else status.replace(" ", "_")
        return r.x, status, int(r.info.iter)

    def _solve_exact(self, q, l, ub):
        if self._exact is None:
            Hs = ca.DM(self.P).sparsity()
            As = ca.DM(self.A).sparsity() if self.n_c else ca.Sparsity(0, self.n_u)
            self._exact = ca.conic("exact", "daqp", {"h": Hs, "a": As},
                                   {"error_on_fail": False, "print_problem": False})
        kw = dict(h=self.P, g=q, lbx=-np.inf, ubx=np.inf)
        if self.n_c:
            kw.update(a=self.A, lba=l, uba=ub)
        r = self._exact(**kw)
        st = self._exact.stats()
        ok = bool(st.get("success", False))
        z = np.array(r["x"], dtype=float).reshape(-1)
        if ok:
            return z, "solved", max(0, int(st.get("iter_count", 0) or 0))
        rs = st.get("return_status", "failed")
        try:
            status = _DAQP_STATUS.get(int(rs), f"daqp_{rs}")
        except (TypeError, ValueError):
            status = str(rs).lower().replace(" ", "_")
        return z, status, 0
