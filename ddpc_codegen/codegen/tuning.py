"""Settings of the embedded OSQP backend: the interpreted OSQP solver whose code is generated, and a
fixed ADMM step size rho chosen by trial (embedded OSQP with parameters='vectors' cannot adapt rho)."""

from __future__ import annotations

import numpy as np
import osqp
import scipy.sparse as sp

from ddpc_codegen.design.problem import SteeringProblem

RHO_CANDIDATES = tuple(float(r) for r in 10.0 ** np.arange(-2.0, 2.01, 0.5))
# Tried first, then outwards: the benchmark problems' winners are 3.2 and 10, and an early good score prunes the rest.
FIRST_TRIED = 10.0 ** 0.5


def _bounds(problem: SteeringProblem) -> tuple[np.ndarray, np.ndarray]:
    """Representative finite bounds wherever a row can ever bind: embedded OSQP fixes its per-row rho
    from the bounds seen at setup (free rows get a tiny rho, equalities a large one)."""
    l0 = np.concatenate([problem.lb_u, problem.lg0])
    u0 = np.concatenate([problem.ub_u, problem.ug0])
    return np.maximum(l0, -1e30), np.minimum(u0, 1e30)


def osqp_embedded_solver(problem: SteeringProblem, settings: dict, rho: float | None = None) -> osqp.OSQP:
    """The OSQP object the backend is generated from (P, A fixed; q, l, u per tick; no adaptive rho)."""
    l0, u0 = _bounds(problem)
    s = osqp.OSQP()
    s.setup(sp.triu(sp.csc_matrix(problem.P), format="csc"), np.zeros(problem.n_z), sp.csc_matrix(problem.A),
            l0, u0, rho=float(settings["rho"] if rho is None else rho), adaptive_rho=False, verbose=False,
            eps_abs=float(settings["eps"]), eps_rel=float(settings["eps"]), max_iter=int(settings["max_iter"]),
            warm_starting=True, polishing=False)
    return s


def sample_thetas(problem: SteeringProblem, n: int, seed: int = 0) -> np.ndarray:
    """Parameter vectors that activate bounds: histories inside the input box, desired outputs stepped
    across a range as wide as the input range (the regime where the QP, not the fast path, runs)."""
    c = problem.config
    rng = np.random.default_rng(seed)
    lo = np.where(np.isfinite(c.u_min), c.u_min, -1.0)
    hi = np.where(np.isfinite(c.u_max), c.u_max, 1.0)
    span = np.resize(hi - lo, c.p)
    out = np.empty((n, problem.n_theta))
    for k in range(n):
        u0 = rng.uniform(lo, hi)
        u_ini = np.tile(u0, (c.t_ini, 1))
        y_ini = np.tile(rng.uniform(-0.5, 0.5, c.p) * span, (c.t_ini, 1))
        y_des = np.tile(y_ini[-1] + rng.uniform(-1, 1, c.p) * span * rng.choice([0.05, 0.3, 1.0]), (c.t_f, 1))
        u_nom = np.tile(u0, (c.t_f, 1))
        out[k] = problem.theta(u_ini, y_ini, y_des, u_nom)
    return out


def _score(problem: SteeringProblem, settings: dict, rho: float, vecs: list, bound: tuple[int, int] | None
           ) -> tuple[int, int] | None:
    """(non-converged solves, iterations) of ``rho`` over ``vecs``; None once it exceeds ``bound`` (it cannot
    win: both counts only grow), which spares the slow candidates most of their max_iter solves."""
    s = osqp_embedded_solver(problem, settings, rho)
    failed = its = 0
    for q, l, u in vecs:
        s.update(q=q, l=np.maximum(l, -1e30), u=np.minimum(u, 1e30))
        r = s.solve(raise_error=False)
        failed += str(r.info.status).lower() != "solved"
        its += r.info.iter
        if bound is not None and (failed, its) > bound:
            return None
    return failed, its


def choose_rho(problem: SteeringProblem, settings: dict, samples: int = 16, seed: int = 0) -> float:
    """The candidate rho with the fewest non-converged solves, then the fewest iterations (then the smaller rho),
    over a warm-started sequence of bound-activating parameter vectors (interpreted OSQP with the embedded
    settings). Candidates are tried nearest ``FIRST_TRIED`` first, so a good score prunes the others
    early (the answer is the exhaustive search's)."""
    thetas = sample_thetas(problem, samples, seed)
    vecs = [problem.qp_vectors(th) for th in thetas]
    order = sorted(range(len(RHO_CANDIDATES)), key=lambda i: abs(np.log(RHO_CANDIDATES[i] / FIRST_TRIED)))
    best: tuple[tuple[int, int], int] | None = None
    for i in order:
        score = _score(problem, settings, RHO_CANDIDATES[i], vecs, None if best is None else best[0])
        if score is not None and (best is None or (score, i) < best):
            best = (score, i)
    return RHO_CANDIDATES[best[1]]
