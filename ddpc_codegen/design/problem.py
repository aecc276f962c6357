"""The steering QP (DDPC-Flying / DDPC-Hopping), condensed in the steered references u alone.

With the predictor y = Gy_w w + Gy_u u, sigma = Gs_w w + Gs_u u (w = [u_ini; y_ini]) the
paper's problem becomes a dense QP in u (m*Tf variables):

    min_u  1/2 u' P u + q(theta)' u     s.t.  l(theta) <= A u <= u(theta)

With ``[horizon] knots`` the QP variable is z = v, the references at the knots (m*K variables), and
u = B v (``design.blocking``); without it z = u (B = I, the QP as written above).

with P and A constant and (q, l, u) affine in the parameters theta = [u_ini; y_ini; y_des
(; u_nom)]. Everything is formed symbolically in CasADi; P and A are evaluated once, the
parameter map is a CasADi Function (later exported as C).
"""

from __future__ import annotations

import time

import casadi as ca
import numpy as np
import osqp
import scipy.linalg as sla
import scipy.sparse as sp

from ddpc_codegen.design.blocking import distinct_rows, knot_basis
from ddpc_codegen.design.penalties import reference_penalties
from ddpc_codegen.values.config import SteeringConfig
from ddpc_codegen.errors import ConfigError, DataError
from ddpc_codegen.design.predictor import Predictor
from ddpc_codegen.values.solve_result import BOUND_TOL, SteeringResult, stack_window, within_bounds

__all__ = ["SteeringProblem", "SteeringResult", "SOLVERS", "P_COND_MAX", "DAQP_OPTIONS"]

SOLVERS = ("osqp", "exact", "fast")
# Largest accepted condition number of the condensed Hessian P. An active-set solve loses about
# cond(P) * eps of relative accuracy; above BOUND_TOL / eps (4.5e7) no solver can promise answers
# inside the bounds to BOUND_TOL, and the QP is semidefinite in all but name (R = 0 style configs).
P_COND_MAX = BOUND_TOL / np.finfo(float).eps
# DAQP's own acceptance test, set to the package tolerance (the library default is 1e-6); every
# "solved" answer is checked again against the bounds in their own units by SteeringProblem.check.
DAQP_OPTIONS = {"primal_tol": BOUND_TOL, "iter_limit": 1000}

_OSQP_OK = {"solved"}
# DAQP exit flags (daqp/include/constants.h)
_DAQP_STATUS = {1: "solved", 2: "solved", -1: "infeasible", -2: "cycling", -3: "unbounded",
                -4: "max_iter", -5: "nonconvex", -6: "overdetermined_initial_active_set"}


class SteeringProblem:
    """Condensed steering QP for a fitted predictor and a steering configuration.

    Attributes:
        P (n_z, n_z): constant Hessian of the QP variable z (z = u, or the knot values v with knots).
        lb_u, ub_u (n_z,): constant simple bounds on z (the references at the knots).
        A_g (n_g, n_z): constant general constraint rows (predicted-y bounds, increments);
        A = [I; A_g] (n_c, n_z) is the OSQP form.
        B (n_u, n_z) or None: the knot basis, u = B z (None: no knots, z = u).
        param_map: CasADi Function theta (n_theta,) -> (q (n_z,), l_g (n_g,), u_g (n_g,)).
        n_u = m*Tf, n_z = m*K (n_u without knots), n_theta = (m+p)*Tini + p*Tf (+ m*Tf in R_mode "offset").
    """

    def __init__(self, predictor: Predictor, config: SteeringConfig) -> None:
        self._check_dimensions(predictor, config)
        self.predictor = predictor
        self.config = config
        c = config
        m, p, Ti, Tf = c.m, c.p, c.t_ini, c.t_f
        self.n_u = m * Tf
        self.B = None if c.knots is None else knot_basis(c.knots, Tf, m)
        self.n_z = self.n_u if self.B is None else self.B.shape[1]
        self.n_w = (m + p) * Ti
        self.has_nominal = c.R_mode == "offset"
        self.n_theta = self.n_w + p * Tf + (m * Tf if self.has_nominal else 0)

        u = ca.SX.sym("u", self.n_z)
        theta = ca.SX.sym("theta", self.n_theta)
        J, y, du_expr, D = self._cost(u, theta)
        g, lo, hi = self._general_constraints(y, du_expr, D)
        self._evaluate(J, g, lo, hi, u, theta)
        self._check_hessian()
        self._precompute(D)
        self._osqp = None
        self._exact = None

    @staticmethod
    def _check_dimensions(predictor: Predictor, config: SteeringConfig) -> None:
        """ConfigError unless the config's window sizes and channel counts are the predictor's."""
        for key in ("t_ini", "t_f", "m", "p"):
            if getattr(predictor, key) != getattr(config, key):
                raise ConfigError(
                    f"{config.source}: {key}={getattr(config, key)} but the predictor was fitted with "
                    f"{key}={getattr(predictor, key)}; refit the predictor or fix the config"
                )

    def _through_basis(self, M: np.ndarray) -> np.ndarray:
        """M B: a matrix acting on u as one acting on the QP variable z (M itself without knots)."""
        return M if self.B is None else M @ self.B

    def _cost(self, u: ca.SX, theta: ca.SX) -> tuple[ca.SX, ca.SX, ca.SX, np.ndarray]:
        """The cost J(z, theta) of the QP variable (named u: it is u without knots), the predicted outputs
        y, the increments du of u = B z and the difference matrix D (n_u, n_u) acting on u."""
        c, pr = self.config, self.predictor
        m, p, Ti, Tf = c.m, c.p, c.t_ini, c.t_f
        w = theta[: self.n_w]
        y_des = theta[self.n_w : self.n_w + p * Tf]
        u_ini = theta[: m * Ti]
        # Products with B are formed numerically (small dense matrices instead of a long SX graph).
        y = ca.mtimes(ca.DM(pr.Gy_w), w) + ca.mtimes(ca.DM(self._through_basis(pr.Gy_u)), u)
        sig = ca.mtimes(ca.DM(pr.Gs_w), w) + ca.mtimes(ca.DM(self._through_basis(pr.Gs_u)), u)
        Qb = ca.DM(np.kron(np.eye(Tf), c.Q))
        e = y - y_des
        J = ca.mtimes([e.T, Qb, e]) + c.lambda_sigma * ca.dot(sig, sig)
        D = np.eye(self.n_u) - np.eye(self.n_u, k=-m)  # stacked differences
        # Increments du_k = u_k - u_(k-1), the first against the last applied input u_ini[-1].
        du_expr = ca.mtimes(ca.DM(self._through_basis(D)), u) - ca.vertcat(u_ini[m * (Ti - 1) :],
                                                                            ca.DM.zeros(self.n_u - m))
        u_full = u if self.B is None else ca.mtimes(ca.DM(self.B), u)
        u_nom = theta[self.n_w + p * Tf :] if c.R_mode == "offset" else None
        y_ini_last = theta[m * Ti + p * (Ti - 1) : m * Ti + p * Ti]
        J = J + reference_penalties(c, u_full, du_expr, u_ini, u_nom, y, y_ini_last)
        return J, y, du_expr, D

    def _general_constraints(self, y: ca.SX, du_expr: ca.SX, D: np.ndarray) -> tuple[ca.SX, list, list]:
        """Simple bounds on z (constant) and the general rows g with their bounds: predicted y and
        increments, only rows that bound something (with knots: one increment row per segment, as the
        increments inside a segment are equal)."""
        c, Tf = self.config, self.config.t_f
        n_steps = Tf if self.B is None else len(c.knots)
        self.lb_u = np.tile(c.u_min, n_steps).astype(float)
        self.ub_u = np.tile(c.u_max, n_steps).astype(float)
        rows, lo, hi, kinds = [], [], [], []
        ym = np.tile(c.y_min, Tf), np.tile(c.y_max, Tf)
        for i in np.nonzero(np.isfinite(ym[0]) | np.isfinite(ym[1]))[0]:
            rows.append(y[int(i)]); lo.append(ym[0][i]); hi.append(ym[1][i]); kinds.append("y")
        du = np.tile(c.du_max, Tf)
        du_rows = np.nonzero(np.isfinite(du))[0]
        if self.B is not None and du_rows.size:
            first = (np.arange(self.n_u) < c.m) * (np.arange(self.n_u) % c.m + 1.0)  # rows that read u_ini[-1]
            rhs = np.c_[first, np.where(np.isfinite(du), du, 0.0)]
            du_rows = du_rows[distinct_rows((D @ self.B)[du_rows], rhs[du_rows])]
        if du_rows.size:
            for i in du_rows:
                rows.append(du_expr[int(i)]); lo.append(-du[i]); hi.append(du[i]); kinds.append("du")
        self.general_kinds = tuple(kinds)
        g = ca.vertcat(*rows) if rows else ca.SX(0, 1)
        self.n_g = int(g.shape[0])
        self.n_c = self.n_z + self.n_g  # OSQP form: A = [I; A_g]
        return g, lo, hi

    def _evaluate(self, J: ca.SX, g: ca.SX, lo: list, hi: list, u: ca.SX, theta: ca.SX) -> None:
        """P and A evaluated once; the parameter maps theta -> (q, l_g, u_g) as CasADi Functions
        and, since they are affine, as dense matrices."""
        # The gradient by reverse mode (one sweep of J's graph); P, A_g and the parameter Jacobians are then
        # read off by evaluating these affine maps at unit vectors: a symbolic hessian / jacobian of the
        # dense SX graph costs O(n_z * graph) nodes (20 s for a free 100-step horizon against 0.2 s here).
        grad = ca.gradient(J, u)
        zero = ca.DM.zeros(self.n_z)
        q_expr = ca.substitute(grad, u, zero)
        g0 = ca.substitute(g, u, zero) if self.n_g else g
        lo_v, hi_v = ca.DM(np.asarray(lo, float)), ca.DM(np.asarray(hi, float))
        l_expr = lo_v - g0 if self.n_g else ca.SX(0, 1)
        u_expr = hi_v - g0 if self.n_g else ca.SX(0, 1)
        affine = ca.Function("affine", [u, theta], [grad, g])
        self.P, self.A_g = self._slopes_in_u(affine)
        self.A = np.vstack([np.eye(self.n_z), self.A_g])
        # CasADi Functions of the parameters; their generated C is the per-tick parameter map.
        self.param_map = ca.Function("ddpc_param_map", [theta], [q_expr, l_expr, u_expr],
                                     ["theta"], ["q", "l_g", "u_g"])
        self.linear_map = ca.Function("ddpc_linear_map", [theta], [q_expr], ["theta"], ["q"])
        self.bounds_map = ca.Function("ddpc_bounds_map", [theta], [l_expr, u_expr], ["theta"], ["l_g", "u_g"])
        self._cost_fn = ca.Function("cost", [u, theta], [J])
        # q, l_g, u_g are affine in theta: keep dense matrices for numpy evaluation and the gain.
        q0, l0, u0 = self.param_map(np.zeros(self.n_theta))
        self.q0 = np.array(q0, dtype=float).reshape(-1)
        self.lg0 = np.array(l0, dtype=float).reshape(-1)
        self.ug0 = np.array(u0, dtype=float).reshape(-1)
        # Slopes in theta from unit steps; F_g from g0 itself (the bounds may be infinite: inf - inf).
        slopes = ca.Function("theta_slopes", [theta], [q_expr, -g0 if self.n_g else ca.SX(0, 1)])
        (qs, gs), (q_0, g_0) = (slopes.map(self.n_theta)(np.eye(self.n_theta)), slopes(np.zeros(self.n_theta)))
        self.F_q = np.array(qs, dtype=float).reshape(self.n_z, self.n_theta) - np.array(q_0, dtype=float)
        # l_g = lg0 + F_g theta, same for u_g
        self.F_g = (np.array(gs, dtype=float).reshape(self.n_g, self.n_theta)
                    - np.array(g_0, dtype=float).reshape(self.n_g, 1))

    def _slopes_in_u(self, affine: ca.Function) -> tuple[np.ndarray, np.ndarray]:
        """(P (n_z, n_z), A_g (n_g, n_z)): the constant slopes in z of the gradient and of g, from unit steps
        in z at theta = 0; the same at a second theta checks that they do not depend on it."""
        steps = np.hstack([np.zeros((self.n_z, 1)), np.eye(self.n_z)])
        slopes = []
        for th in (np.zeros(self.n_theta), np.linspace(-1.0, 1.0, self.n_theta)):
            gr, g = affine.map(self.n_z + 1)(steps, np.tile(th[:, None], self.n_z + 1))
            gr, g = np.array(gr, dtype=float), np.array(g, dtype=float).reshape(self.n_g, self.n_z + 1)
            slopes.append((gr[:, 1:] - gr[:, :1], g[:, 1:] - g[:, :1]))
        (P, A), (P2, A2) = slopes
        scale = max(1.0, float(np.max(np.abs(P))))
        if not (np.allclose(P, P2, rtol=0, atol=1e-9 * scale) and np.allclose(A, A2, rtol=0, atol=1e-9)):
            raise AssertionError("steering QP is not a parametric QP with constant P and A")  # pragma: no cover
        return 0.5 * (P + P.T), A

    def _precompute(self, D: np.ndarray) -> None:
        """The unconstrained gain and the bounds in their own units (for check())."""
        c, Tf = self.config, self.config.t_f
        # Unconstrained optimum u* = K theta + k0 (exact fast path when it satisfies the bounds).
        chol = sla.cho_factor(self.P)
        self.K = -sla.cho_solve(chol, self.F_q)
        self.k0 = -sla.cho_solve(chol, self.q0)
        self._y_lo, self._y_hi = np.tile(c.y_min, Tf).astype(float), np.tile(c.y_max, Tf).astype(float)
        self._du_max = np.tile(c.du_max, Tf).astype(float)
        self._u_lo, self._u_hi = np.tile(c.u_min, Tf).astype(float), np.tile(c.u_max, Tf).astype(float)
        self._D = D  # stacked differences (n_u, n_u)

    def _check_hessian(self) -> None:
        """ConfigError naming [cost] R when P is not numerically positive definite (cond > P_COND_MAX)."""
        c = self.config
        ev = np.linalg.eigvalsh(self.P)
        cond = ev[-1] / ev[0] if ev[0] > 0 else np.inf
        if not cond <= P_COND_MAX:
            raise ConfigError(
                f"{c.source}: [cost] R = {np.diag(c.R).tolist()} (R_mode {c.R_mode!r}"
                + (f", R_du = {np.diag(c.R_du).tolist()}" if np.any(c.R_du) else "")
                + (f", R_ddu = {np.diag(c.R_ddu).tolist()}" if np.any(c.R_ddu) else "")
                + f") leaves the steering QP not strictly convex: the condensed Hessian has eigenvalues "
                f"{ev[0]:.3g} .. {ev[-1]:.3g} (condition number {cond:.3g} > {P_COND_MAX:.3g}); give every input "
                "a positive R (or R_du), or raise it relative to Q"
            )

    # ------------------------------------------------------------------ parameters
    def theta(
        self, u_ini: np.ndarray, y_ini: np.ndarray, y_des: np.ndarray, u_nom: np.ndarray | None = None
    ) -> np.ndarray:
        """Stack and validate the parameter vector (n_theta,). Windows may be time-major or stacked."""
        c = self.config
        parts = [
            stack_window(u_ini, c.t_ini, c.m, "u_ini"),
            stack_window(y_ini, c.t_ini, c.p, "y_ini"),
            stack_window(y_des, c.t_f, c.p, "y_des"),
        ]
        if self.has_nominal:
            if u_nom is None:
                raise DataError("R_mode 'offset' needs u_nom, the nominal (unsteered) references over the horizon")
            parts.append(stack_window(u_nom, c.t_f, c.m, "u_nom"))
        return np.concatenate(parts)

    def qp_vectors(self, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(q, l, u) of the QP in OSQP form (A = [I; A_g]) at theta; unbounded entries are ±inf."""
        Ft = self.F_g @ theta
        return (self.q0 + self.F_q @ theta, np.concatenate([self.lb_u, self.lg0 + Ft]),
                np.concatenate([self.ub_u, self.ug0 + Ft]))

    def is_feasible(self, z: np.ndarray, l: np.ndarray, u: np.ndarray, tol: float = BOUND_TOL) -> bool:
        """Whether z satisfies l - tol*max(1,|l|) <= A z <= u + tol*max(1,|u|) (QP form, shifted bounds)."""
        with np.errstate(over="ignore", invalid="ignore"):
            Az = np.concatenate([z, self.A_g @ z])
            return bool(np.all(Az >= l - tol * np.maximum(1.0, np.abs(l)))
                        and np.all(Az <= u + tol * np.maximum(1.0, np.abs(u))))

    def to_u(self, z: np.ndarray) -> np.ndarray:
        """The references over the horizon u = B z (n_u,) of a QP answer z (n_z,) (z itself without knots)."""
        return z if self.B is None else self.B @ z

    def to_z(self, u: np.ndarray) -> np.ndarray:
        """The QP variable of a trajectory u (n_u,): its values at the knots (u itself without knots)."""
        u = np.asarray(u, dtype=float).reshape(-1)
        if self.B is None:
            return u
        return u.reshape(self.config.t_f, self.config.m)[list(self.config.knots)].reshape(-1)

    def check(self, z: np.ndarray | None, th: np.ndarray) -> str:
        """Verify an answer z (n_z,) at theta in the bounds' own units, on the whole horizon u = B z.

        Returns "solved" when u and its predicted y are finite and u, du (against u_ini[-1] first)
        and y are inside their bounds within BOUND_TOL * max(1, |bound|) at every tick; else
        "nonfinite" or "out_of_bounds". This is the one acceptance test of every interpreted answer.
        """
        if z is None or not np.all(np.isfinite(z)):
            return "nonfinite"
        m, ti, pr = self.config.m, self.config.t_ini, self.predictor
        with np.errstate(over="ignore", invalid="ignore"):
            u = self.to_u(z)
            y = pr.Gy_w @ th[: self.n_w] + pr.Gy_u @ u
            du = self._D @ u
            du[:m] -= th[m * (ti - 1) : m * ti]  # the first increment is against the last applied input
            if not np.all(np.isfinite(y)) or not np.all(np.isfinite(du)):
                return "nonfinite"
            inside = (within_bounds(u, self._u_lo, self._u_hi) and within_bounds(y, self._y_lo, self._y_hi)
                      and within_bounds(du, -self._du_max, self._du_max))
        return "solved" if inside else "out_of_bounds"

    def qp_finite(self, q: np.ndarray, l: np.ndarray, u: np.ndarray) -> bool:
        """Whether (q, l, u) is a QP a solver can be handed: q finite, no NaN, every finite entry below
        1e30 in magnitude (OSQP's infinity), no +inf lower or -inf upper bound.

        Extreme parameters (|theta| ~ 1e308) overflow here; they are refused before any solver sees them.
        """
        with np.errstate(invalid="ignore"):
            lu = np.concatenate([l, u])
            big = np.abs(lu[np.isfinite(lu)])
            return bool(np.all(np.isfinite(q)) and np.all(np.abs(q) < 1e30) and not np.any(np.isnan(lu))
                        and np.all(big < 1e30) and not np.any(l == np.inf) and not np.any(u == -np.inf))

    def unconstrained(self, theta: np.ndarray) -> np.ndarray:
        """Unconstrained optimum K theta + k0 of the QP variable, (n_z,)."""
        return self.K @ theta + self.k0

    def cost(self, u: np.ndarray, theta: np.ndarray) -> float:
        """Objective J(z; theta) of the QP variable z (n_z,; u without knots) as written (without the 1/2)."""
        return float(self._cost_fn(u, theta))

    # ------------------------------------------------------------------ solving
    def reset(self) -> None:
        """Back to the post-construction state: OSQP's warm start and the DAQP workspace are dropped."""
        self._osqp = None
        self._exact = None

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
        if solver not in SOLVERS:
            raise ConfigError(f"unknown solver {solver!r}; choose one of {list(SOLVERS)}")
        th = self.theta(u_ini, y_ini, y_des, u_nom)
        return self.solve_theta(th, solver=solver, eps=eps, max_iter=max_iter)

    def solve_theta(self, th: np.ndarray, *, solver: str = "osqp", eps: float = 1e-7,
                    max_iter: int = 20000) -> SteeringResult:
        """Like :meth:`solve`, from a stacked parameter vector.

        Every answer is verified (:meth:`check`): "solved" means inside all bounds within
        BOUND_TOL; otherwise the status says why ("out_of_bounds", "nonfinite",
        "nonfinite_parameters" or the solver's own) and u is NaN.
        """
        if solver not in SOLVERS:
            raise ConfigError(f"unknown solver {solver!r}; choose one of {list(SOLVERS)}")
        t0 = time.perf_counter()
        with np.errstate(over="ignore", invalid="ignore"):
            q, l, ub = self.qp_vectors(th)
        if not self.qp_finite(q, l, ub):
            return self.result(None, th, "nonfinite_parameters", 0, time.perf_counter() - t0)
        fast = False
        if solver == "fast":
            with np.errstate(over="ignore", invalid="ignore"):
                z = self.unconstrained(th)
            if self.check(z, th) == "solved":
                status, it, fast = "solved", 0, True
            else:
                z, status, it = self._solve_exact(q, l, ub)
        elif solver == "exact":
            z, status, it = self._solve_exact(q, l, ub)
        else:
            z, status, it = self._solve_osqp(q, l, ub, eps, max_iter)
        if status == "solved":
            status = self.check(z, th)
        if status != "solved" and solver == "osqp":
            self._osqp = None  # a failed solve leaves no warm start behind
        return self.result(z, th, status, it, time.perf_counter() - t0, fast)

    def result(self, z: np.ndarray | None, th: np.ndarray, status: str, iterations: int = 0,
               solve_time: float = 0.0, fast_path: bool = False) -> SteeringResult:
        """Package a solution vector z (n_z,) at theta into a SteeringResult of u = B z (NaN unless "solved")."""
        c, pr = self.config, self.predictor
        if status != "solved" or z is None or not np.all(np.isfinite(z)):
            nan = np.full(self.n_u, np.nan)
            return SteeringResult(nan.reshape(c.t_f, c.m), np.full((c.t_f, c.p), np.nan),
                                  np.full((c.t_ini, c.p), np.nan), status if status != "solved" else "nonfinite",
                                  iterations, solve_time)
        w, u = th[: self.n_w], self.to_u(z)
        y = pr.Gy_w @ w + pr.Gy_u @ u
        s = pr.Gs_w @ w + pr.Gs_u @ u
        return SteeringResult(u.reshape(c.t_f, c.m), y.reshape(c.t_f, c.p), s.reshape(c.t_ini, c.p),
                              status, int(iterations), solve_time, self.cost(z, th), fast_path)

    def _solve_osqp(self, q, l, ub, eps, max_iter):
        # OSQP's infinity is 1e30 (finite entries beyond it were refused by qp_finite).
        lo, hi = np.maximum(l, -1e30), np.minimum(ub, 1e30)
        warm = self._osqp is not None
        if warm:
            self._osqp.update(q=q, l=lo, u=hi)
        else:
            self._osqp_setup(q, lo, hi, eps, max_iter)
        r = self._osqp.solve(raise_error=False)
        status = str(r.info.status).lower()
        if status not in _OSQP_OK and warm:
            # A first-order method can stall from a far-away warm start (e.g. after an extreme
            # tick that did solve): the answer must not depend on history, so retry cold once.
            self._osqp_setup(q, lo, hi, eps, max_iter)
            r = self._osqp.solve(raise_error=False)
            status = str(r.info.status).lower()
        status = "solved" if status in _OSQP_OK else status.replace(" ", "_")
        return r.x, status, int(r.info.iter)

    def _osqp_setup(self, q, lo, hi, eps, max_iter) -> None:
        s = osqp.OSQP()
        s.setup(sp.triu(sp.csc_matrix(self.P), format="csc"), q, sp.csc_matrix(self.A), lo, hi, verbose=False,
                eps_abs=eps, eps_rel=eps, polishing=True, max_iter=max_iter, warm_starting=True)
        self._osqp = s

    def _solve_exact(self, q, l, ub):
        if self._exact is None:
            Hs = ca.DM(self.P).sparsity()
            As = ca.DM(self.A_g).sparsity() if self.n_g else ca.Sparsity(0, self.n_z)
            self._exact = ca.conic("exact", "daqp", {"h": Hs, "a": As},
                                   {"error_on_fail": False, "print_problem": False, "daqp": dict(DAQP_OPTIONS)})
        kw = dict(h=self.P, g=q, lbx=l[: self.n_z], ubx=ub[: self.n_z])
        if self.n_g:
            kw.update(a=self.A_g, lba=l[self.n_z :], uba=ub[self.n_z :])
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
        return None, status, 0

