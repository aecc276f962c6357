"""The steering cost's penalties on the steered references, as CasADi expressions (one place for every
``[cost]`` weight but Q and lambda_sigma): R by ``R_mode``, the rate penalty ``R_du``, the offset-rate penalty
``R_doffset``, the curvature penalty ``R_ddu`` and the tracking-error-rate penalty ``R_de``.

Shapes: u_full (m*Tf) the references over the horizon, time-major; du (m*Tf) their increments, the first against
u_ini[-1]; u_ini (m*Ti); u_nom (m*Tf) the nominal references (R_mode "offset" only, else None); y (p*Tf) the
predicted outputs; y_ini_last (p,) the last measured outputs.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ddpc_codegen.values.config import SteeringConfig
from ddpc_codegen.values.solve_result import nominal_increments

__all__ = ["reference_penalties"]


def _quad(v: ca.SX, W: np.ndarray, t_f: int) -> ca.SX:
    """v' kron(I_Tf, W) v."""
    return ca.mtimes([v.T, ca.DM(np.kron(np.eye(t_f), W)), v])


def reference_penalties(c: SteeringConfig, u_full: ca.SX, du: ca.SX, u_ini: ca.SX, u_nom: ca.SX | None,
                        y: ca.SX, y_ini_last: ca.SX) -> ca.SX:
    """The sum of the reference penalties the config sets (each term without a 1/2)."""
    m, Tf = c.m, c.t_f
    n_u = m * Tf
    ru = {"absolute": u_full, "offset": u_full - u_nom if u_nom is not None else None, "increment": du}[c.R_mode]
    J = _quad(ru, c.R, Tf)
    if np.any(c.R_du):
        J = J + _quad(du, c.R_du, Tf)
    if np.any(c.R_doffset):
        # the increments of u less the nominal's, which the references may then follow for free; the nominal's
        # increment before the horizon is not a parameter: its first one, extrapolated back (exact on a ramp)
        J = J + _quad(du - ca.mtimes(ca.DM(nominal_increments(m, Tf)), u_nom), c.R_doffset, Tf)
    D = np.eye(n_u) - np.eye(n_u, k=-m)  # stacked differences
    if np.any(c.R_ddu):
        # second differences, the first against the last applied increment u_ini[-1] - u_ini[-2]
        du_prev = u_ini[m * (c.t_ini - 1) :] - u_ini[m * (c.t_ini - 2) : m * (c.t_ini - 1)]
        J = J + _quad(ca.mtimes(ca.DM(D), du) - ca.vertcat(du_prev, ca.DM.zeros(n_u - m)), c.R_ddu, Tf)
    if np.any(c.R_de):
        # changes of the tracking error e = u_i - y_i (input i against output i; the first against
        # u_ini[-1] - y_ini[-1]), which a PD on it turns into command (thrust) steps
        e = u_full - ca.mtimes(ca.DM(np.kron(np.eye(Tf), np.eye(m, c.p))), y)
        e_prev = u_ini[m * (c.t_ini - 1) :] - y_ini_last[:m]
        J = J + _quad(ca.mtimes(ca.DM(D), e) - ca.vertcat(e_prev, ca.DM.zeros(n_u - m)), c.R_de, Tf)
    return J
