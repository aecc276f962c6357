"""The steering QP's data as a function of the re-solved predictor G (numpy reference of the rebuild in
the generated ``<name>_adapt_rebuild.c``; no casadi).

After a verified re-solve, everything of the QP that depends on G is rebuilt (issue 30): the Hessian P,
the linear-term map F_q (q = F_q theta + q0), the general rows that bound predicted outputs (their
A_g rows and their F_g rows, l_g = F_g theta + lg0) and the fast-path gain K = -P^-1 F_q. With the
data-unit predictor Gd = [Gy_w Gy_u; Gs_w Gs_u] = Lm G Rm + C0 (affine in the fit-domain G: the
channel scale, and for the incremental form the differencing and the accumulation), Gw = Gd[:, :n_w]
and Gu = Gd[:, n_w:] B (B: the knot basis, u = B z):

    P   = Gu^T Wd Gu + P_fixed                       Wd = blkdiag(2 kron(I, Q), 2 lambda_sigma I)
    F_q = F_fixed + [Gu^T Wd Gw | -(Wd Gu)_y^T | 0]  (columns: w, y_des, the rest of theta)
    A_g[j] = Gu[y_j], F_g[j, :n_w] = -Gw[y_j]       for the general rows j bounding output y_j

P_fixed and F_fixed (the input weights) do not depend on G. A rebuild is refused when a number is not
finite ("nonfinite") or P has a non-positive Cholesky pivot ("hessian").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["QPModel", "QPData", "cholesky", "steady_state_gain"]


@dataclass(frozen=True)
class QPData:
    """One buffer of G-dependent QP data. P (n_z, n_z), F_q (n_z, n_theta), A_g (n_g, n_z),
    F_g (n_g, n_theta), K (n_z, n_theta) = -P^-1 F_q, Gd (n_y + n_s, n_w + n_u): the data-unit predictor."""

    P: np.ndarray
    F_q: np.ndarray
    A_g: np.ndarray
    F_g: np.ndarray
    K: np.ndarray
    Gd: np.ndarray


def cholesky(H: np.ndarray) -> np.ndarray | None:
    """Lower factor of H by the plain algorithm the C code runs; None at the first pivot that is not > 0."""
    n = H.shape[0]
    L = np.zeros_like(H)
    for j in range(n):
        d = H[j, j] - L[j, :j] @ L[j, :j]
        if not d > 0.0:
            return None
        L[j, j] = np.sqrt(d)
        L[j + 1 :, j] = (H[j + 1 :, j] - L[j + 1 :, :j] @ L[j, :j]) / L[j, j]
    return L


def steady_state_gain(Gd: np.ndarray, m: int, p: int, t_ini: int, t_f: int) -> np.ndarray | None:
    """S (p, m): the constant outputs y_c the data-unit predictor Gd (p Tf + ..., (m+p) Tini + m Tf) holds for
    constant references u_c (its last predicted step at a fixed point: y_c = A u_c + B y_c, S = (I - B)^-1 A);
    None when I - B is singular (a pivot below 1e-12 of its largest entry). Gaussian elimination with partial
    pivoting, step for step the C code's."""
    rows = Gd[(t_f - 1) * p : t_f * p]
    nw = (m + p) * t_ini
    A = rows[:, : m * t_ini].reshape(p, t_ini, m).sum(axis=1) + rows[:, nw : nw + m * t_f].reshape(p, t_f, m).sum(axis=1)
    B = rows[:, m * t_ini : nw].reshape(p, t_ini, p).sum(axis=1)
    M, S = np.eye(p) - B, A.copy()
    if not np.all(np.isfinite(M)):
        return None
    tiny = 1e-12 * np.abs(M).max()
    for k in range(p):
        best = k + int(np.argmax(np.abs(M[k:, k])))
        if not abs(M[best, k]) > tiny:
            return None
        M[[k, best]], S[[k, best]] = M[[best, k]], S[[best, k]]
        for r in range(k + 1, p):
            f = M[r, k] / M[k, k]
            M[r, k:] -= f * M[k, k:]
            S[r] -= f * S[k]
    for k in range(p - 1, -1, -1):
        S[k] = (S[k] - M[k, k + 1 :] @ S[k + 1 :]) / M[k, k]
    return S


@dataclass(frozen=True)
class QPModel:
    """What a rebuild needs (all fixed at generation time; sizes in the class docstring of the module).

    Lm (n_o, q), Rm (r, n_w + n_u), C0 (n_o, n_w + n_u): the data-unit predictor of a fit-domain G;
    B (n_u, n_z); Wd (n_o, n_o); P_fixed (n_z, n_z); F_fixed (n_z, n_theta); y_rows (n_gy,): the output
    index of each of the first n_gy general rows; A_g0 (n_g, n_z), F_g0 (n_g, n_theta): the shipped rows.
    """

    Lm: np.ndarray
    Rm: np.ndarray
    C0: np.ndarray
    B: np.ndarray
    Wd: np.ndarray
    P_fixed: np.ndarray
    F_fixed: np.ndarray
    y_rows: np.ndarray
    A_g0: np.ndarray
    F_g0: np.ndarray
    n_w: int
    n_y: int
    dims: tuple[int, int, int, int] = (0, 0, 0, 0)  # (m, p, t_ini, t_f) of the predictor, for the gain check
    S0: np.ndarray | None = None  # its shipped steady-state gain (p, m); None: no gain check
    max_gain_change: float = np.inf

    def data_predictor(self, G: np.ndarray) -> np.ndarray:
        """Gd = Lm G Rm + C0 (n_o, n_w + n_u): [Gy_w Gy_u; Gs_w Gs_u] in the data's units."""
        return self.Lm @ G @ self.Rm + self.C0

    def terms(self, Gd: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(P, F_q) of a data-unit predictor Gd (n_o, n_w + n_u): the G parts plus the fixed parts."""
        Gw, Gu = Gd[:, : self.n_w], Gd[:, self.n_w :] @ self.B
        T = self.Wd @ Gu
        P = Gu.T @ T + self.P_fixed
        F_q = self.F_fixed.copy()
        F_q[:, : self.n_w] += T.T @ Gw
        F_q[:, self.n_w : self.n_w + self.n_y] -= T[: self.n_y].T
        return 0.5 * (P + P.T), F_q

    def rebuild(self, G: np.ndarray) -> QPData | str:
        """The QP data of a fit-domain G (q, r), or the reason it is refused ("nonfinite", "hessian")."""
        with np.errstate(all="ignore"):
            Gd = self.data_predictor(G)
            if self.S0 is not None:
                S = steady_state_gain(Gd, *self.dims)
                if S is None or not np.linalg.norm(S - self.S0) <= self.max_gain_change * np.linalg.norm(self.S0):
                    return "gain"
            Gw, Gu = Gd[:, : self.n_w], Gd[:, self.n_w :] @ self.B
            P, F_q = self.terms(Gd)
            A_g, F_g = self.A_g0.copy(), self.F_g0.copy()
            ny = self.y_rows.size
            A_g[:ny] = Gu[self.y_rows]
            F_g[:ny, : self.n_w] = -Gw[self.y_rows]
            if not all(np.all(np.isfinite(a)) for a in (P, F_q, A_g, F_g)):
                return "nonfinite"
            L = cholesky(P)
            if L is None:
                return "hessian"
            K = -np.linalg.solve(L.T, np.linalg.solve(L, F_q))
            if not np.all(np.isfinite(K)):
                return "nonfinite"
        return QPData(P, F_q, A_g, F_g, K, Gd)
