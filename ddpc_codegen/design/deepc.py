"""The standard DeePC steering QP (the paper's eq. DDPC), as a reference formulation.

Variables (g, u, y, sigma) with [Up; Yp; Uf; Yf] g = [u_ini; y_ini - sigma; u; y]. It is
large (g has one entry per Hankel column) and meant for checking the condensed
:class:`~ddpc_codegen.design.problem.SteeringProblem`, not for the loop. It is solved with a dense
active-set method (qpOASES through CasADi): on noise-free data the equality block is rank
deficient, which first-order methods such as OSQP do not resolve to useful accuracy.
"""

from __future__ import annotations

import time

import numpy as np
import casadi as ca
import scipy.sparse as sp

from ddpc_codegen.values.config import SteeringConfig
from ddpc_codegen.design.data import IODataset
from ddpc_codegen.errors import ConfigError, DataError
from ddpc_codegen.design.hankel import mosaic_hankel
from ddpc_codegen.values.solve_result import SteeringResult, nominal_increments, stack_window, within_bounds

__all__ = ["DeePCProblem"]


class DeePCProblem:
    """DeePC QP from a dataset and a steering config (same weights, modes and bounds).

    Cost, exactly as written: ||y - y_des||_Q^2 + (R term of the config's R_mode, + R_du, + R_doffset, + R_ddu, + R_de)
    + lambda_g ||g||^2 + lambda_sigma ||sigma||^2 (every term without a 1/2; the QP form
    1/2 x'Px carries the factor 2 on all of them). g (N,) has one entry per Hankel column.
    """

    def __init__(self, dataset: IODataset, config: SteeringConfig, lambda_g: float = 1e-6) -> None:
        if (dataset.m, dataset.p) != (config.m, config.p):
            raise ConfigError(f"config has m={config.m}, p={config.p} but the dataset has m={dataset.m}, p={dataset.p}")
        c = config
        L = c.t_ini + c.t_f
        Hu = mosaic_hankel(list(dataset.u), L)
        Hy = mosaic_hankel(list(dataset.y), L)
        m, p, Ti, Tf = c.m, c.p, c.t_ini, c.t_f
        self.Up, self.Uf = Hu[: m * Ti], Hu[m * Ti :]
        self.Yp, self.Yf = Hy[: p * Ti], Hy[p * Ti :]
        self.config, self.lambda_g = c, float(lambda_g)
        N = Hu.shape[1]
        nu, ny, ns = m * Tf, p * Tf, p * Ti
        self._n = (N, nu, ny, ns)
        # variable order x = [g, u, y, sigma]
        Qb = np.kron(np.eye(Tf), c.Q)
        Rb = np.kron(np.eye(Tf), c.R)
        D = np.eye(nu) - np.eye(nu, k=-m)
        Ru = D.T @ Rb @ D if c.R_mode == "increment" else Rb
        Rdu = np.kron(np.eye(Tf), c.R_du)
        Rddu = np.kron(np.eye(Tf), c.R_ddu)
        Rdo = np.kron(np.eye(Tf), c.R_doffset)
        Ru = Ru + D.T @ (Rdu + Rdo) @ D + (D @ D).T @ Rddu @ (D @ D)
        P = sp.block_diag([2 * self.lambda_g * sp.eye(N), 2 * Ru, 2 * Qb, 2 * c.lambda_sigma * sp.eye(ns)], format="csc")
        # R_de: ||D (u - S y) - e0||^2 (S: output i of each step against input i) couples the u and y blocks
        S = np.kron(np.eye(Tf), np.eye(m, p))
        Wde = D.T @ np.kron(np.eye(Tf), c.R_de) @ D
        if np.any(c.R_de):
            cross = np.zeros(P.shape)
            iu, iy = slice(N, N + nu), slice(N + nu, N + nu + ny)
            cross[iu, iu], cross[iy, iy] = 2 * Wde, 2 * S.T @ Wde @ S
            cross[iu, iy] = -2 * Wde @ S
            cross[iy, iu] = cross[iu, iy].T
            P = (P + sp.csc_matrix(cross)).tocsc()
        I = sp.eye
        Z = lambda a, b: sp.csc_matrix((a, b))  # noqa: E731
        Aeq = sp.bmat([
            [sp.csc_matrix(self.Up), Z(m * Ti, nu), Z(m * Ti, ny), Z(m * Ti, ns)],
            [sp.csc_matrix(self.Yp), Z(ns, nu), Z(ns, ny), I(ns)],
            [sp.csc_matrix(self.Uf), -I(nu), Z(nu, ny), Z(nu, ns)],
            [sp.csc_matrix(self.Yf), Z(ny, nu), -I(ny), Z(ny, ns)],
        ], format="csc")
        Abox = sp.bmat([[Z(nu, N), I(nu), Z(nu, ny), Z(nu, ns)],
                        [Z(ny, N), Z(ny, nu), I(ny), Z(ny, ns)],
                        [Z(nu, N), sp.csc_matrix(D), Z(nu, ny), Z(nu, ns)]], format="csc")
        self._A = sp.vstack([Aeq, Abox], format="csc")
        self._P = sp.triu(P, format="csc")
        self._Qb, self._Rb, self._D, self._Rdu, self._Rddu = Qb, Rb, D, Rdu, Rddu
        self._S, self._Rde = S, np.kron(np.eye(Tf), c.R_de)
        self._solver = None

    def solve(self, u_ini, y_ini, y_des, u_nom=None) -> SteeringResult:
        """Solve DeePC (dense active set). Same arguments as SteeringProblem.solve."""
        c = self.config
        m, p, Ti, Tf = c.m, c.p, c.t_ini, c.t_f
        N, nu, ny, ns = self._n
        ui = stack_window(u_ini, Ti, m, "u_ini")
        yi = stack_window(y_ini, Ti, p, "y_ini")
        yd = stack_window(y_des, Tf, p, "y_des")
        q = np.zeros(N + nu + ny + ns)
        q[N + nu : N + nu + ny] = -2 * self._Qb @ yd
        d0 = np.zeros(nu)  # D u - d0 = increments, the first against the last applied input
        d0[:m] = ui[-m:]
        if c.R_mode == "offset":
            if u_nom is None:
                raise DataError("R_mode 'offset' needs u_nom")
            q[N : N + nu] = -2 * self._Rb @ stack_window(u_nom, Tf, m, "u_nom")
        elif c.R_mode == "increment":
            q[N : N + nu] = -2 * self._D.T @ self._Rb @ d0
        if np.any(c.R_du):
            q[N : N + nu] += -2 * self._D.T @ self._Rdu @ d0
        if np.any(c.R_doffset):  # D u - d0 - Dn u_nom = changes of u - u_nom (Dn: nominal_increments)
            dn = nominal_increments(m, Tf) @ stack_window(u_nom, Tf, m, "u_nom")
            q[N : N + nu] += -2 * self._D.T @ np.kron(np.eye(Tf), c.R_doffset) @ (d0 + dn)
        if np.any(c.R_ddu):  # D D u - dd0 = second differences, the first against u_ini[-1] and u_ini[-2]
            dd0 = self._D @ d0
            dd0[:m] += ui[-m:] - ui[-2 * m : -m]
            q[N : N + nu] += -2 * (self._D @ self._D).T @ self._Rddu @ dd0
        if np.any(c.R_de):  # D (u - S y) - e0 = changes of u - y, the first against u_ini[-1] - y_ini[-1]
            e0 = np.zeros(nu)
            e0[:m] = ui[-m:] - yi[-p:][:m]
            g0 = self._D.T @ self._Rde @ e0
            q[N : N + nu] += -2 * g0
            q[N + nu : N + nu + ny] += 2 * self._S.T @ g0
        beq = np.concatenate([ui, yi, np.zeros(nu), np.zeros(ny)])
        n_eq = beq.size
        du = np.tile(c.du_max, Tf)
        lo = np.concatenate([beq, np.tile(c.u_min, Tf), np.tile(c.y_min, Tf), d0 - du])
        hi = np.concatenate([beq, np.tile(c.u_max, Tf), np.tile(c.y_max, Tf), d0 + du])
        if self._solver is None:
            Pd = self._P.toarray()
            self._Pd = Pd + Pd.T - np.diag(np.diag(Pd))
            self._Ad = self._A.toarray()
            self._solver = ca.conic("deepc", "qpoases", {"h": ca.DM(self._Pd).sparsity(),
                                    "a": ca.DM(self._Ad).sparsity()},
                                    {"error_on_fail": False, "printLevel": "none"})
        t0 = time.perf_counter()
        r = self._solver(h=self._Pd, g=q, a=self._Ad, lba=lo, uba=hi)
        dt = time.perf_counter() - t0
        st = self._solver.stats()
        status = ("solved" if st.get("success")
                  else str(st.get("return_status", "failed")).lower().rstrip(".").replace(" ", "_"))
        x = np.array(r["x"], dtype=float).reshape(-1)
        if status == "solved":  # verified like every interpreted answer: finite, u, du, y inside the bounds
            u, y = x[N : N + nu], x[N + nu : N + nu + ny]
            if not np.all(np.isfinite(x)):
                status = "nonfinite"
            elif not (within_bounds(u, lo[n_eq : n_eq + nu], hi[n_eq : n_eq + nu])
                      and within_bounds(y, lo[n_eq + nu : n_eq + nu + ny], hi[n_eq + nu : n_eq + nu + ny])
                      and within_bounds(self._D @ u, lo[n_eq + nu + ny :], hi[n_eq + nu + ny :])):
                status = "out_of_bounds"
        if status != "solved":  # never a finite guess: the README promises NaN on failure
            x = np.full_like(x, np.nan)
        return SteeringResult(x[N : N + nu].reshape(Tf, m), x[N + nu : N + nu + ny].reshape(Tf, p),
                              x[N + nu + ny :].reshape(Ti, p), status, int(st.get("iter_count", 0) or 0), dt,
                              info={"g": x[:N]})
