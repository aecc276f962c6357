"""Test vectors shipped with a generated solver: parameters -> expected status and steered references,
from the interpreted exact solver, covering fast-path (no active bound) and active-bound ticks.

File format (text, so that any C program reads it with fscanf; 17 significant digits round-trip):
``ddpc-vectors 1 <name> <n_theta> <n_u> <count>`` then one line per vector
``<status> <fast_path> <theta ...> <u ...>`` with status 0 = solved (u is ``nan`` otherwise).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ddpc_codegen.design.problem import SteeringProblem
from ddpc_codegen.values.solve_result import BOUND_TOL
from ddpc_codegen.codegen.tuning import sample_thetas

MAGIC = "ddpc-vectors"
VERSION = 1
STATUS_CODES = {"solved": 0, "infeasible": -1, "max_iter": -2, "nonfinite": -3, "solver_error": -4,
                "unverified": -5}


@dataclass
class Vectors:
    """Recorded vectors: theta (n, n_theta), u (n, n_u; NaN where not solved), status codes, fast flags."""

    theta: np.ndarray
    u: np.ndarray
    status: np.ndarray
    fast: np.ndarray

    def summary(self) -> dict:
        """Counts by kind, as the manifest records them."""
        solved = self.status == 0
        return {"count": int(len(self.status)), "fast_path": int((self.fast & solved).sum()),
                "active_bound": int((~self.fast & solved).sum()), "not_solved": int((~solved).sum())}


def _steady_output(problem: SteeringProblem, u0: np.ndarray) -> np.ndarray:
    """y0 with (u0, y0) held over the past window predicting y0 again (the predictor's steady state);
    zeros if that linear system is singular."""
    c, pr = problem.config, problem.predictor
    mu, p = c.m * c.t_ini, c.p
    rows = slice(p * (c.t_f - 1), p * c.t_f)  # last predicted step
    Ay = pr.Gy_w[rows, mu:].reshape(p, c.t_ini, p).sum(axis=1)
    by = pr.Gy_w[rows, :mu] @ np.tile(u0, c.t_ini) + pr.Gy_u[rows] @ np.tile(u0, c.t_f)
    try:
        y0 = np.linalg.solve(np.eye(p) - Ay, by)
    except np.linalg.LinAlgError:
        return np.zeros(p)
    return y0 if np.all(np.isfinite(y0)) else np.zeros(p)


def _easy_thetas(problem: SteeringProblem, n: int, seed: int) -> np.ndarray:
    """Tiny moves around a steady state inside the input box: no active bound (the fast path)."""
    c = problem.config
    rng = np.random.default_rng(seed)
    lo = np.where(np.isfinite(c.u_min), c.u_min, -1.0)
    hi = np.where(np.isfinite(c.u_max), c.u_max, 1.0)
    out = np.empty((n, problem.n_theta))
    for k in range(n):
        u0 = lo + (hi - lo) * rng.uniform(0.4, 0.6, c.m)
        y0 = _steady_output(problem, u0)
        y_des = np.tile(y0, (c.t_f, 1)) + 10.0 ** rng.uniform(-7, -4) * rng.standard_normal((c.t_f, c.p))
        out[k] = problem.theta(np.tile(u0, (c.t_ini, 1)), np.tile(y0, (c.t_ini, 1)), y_des, np.tile(u0, (c.t_f, 1)))
    return out


def violation(problem: SteeringProblem, z: np.ndarray, th: np.ndarray) -> float:
    """Largest violation of the QP's rows by its variable z (n_z,) at theta relative to max(1, |bound|)
    (the C solver's measure; with knots the C solver also checks every tick, as ``problem.check`` does)."""
    _, l, u = problem.qp_vectors(th)
    az = np.concatenate([z, problem.A_g @ z])
    with np.errstate(invalid="ignore"):
        lo = np.where(np.isfinite(l), (l - az) / np.maximum(1.0, np.abs(l)), 0.0)
        hi = np.where(np.isfinite(u), (az - u) / np.maximum(1.0, np.abs(u)), 0.0)
    v = float(max(0.0, np.max(lo), np.max(hi)))
    return v if np.all(np.isfinite(az)) else float("inf")


def feasible(problem: SteeringProblem, th: np.ndarray) -> bool:
    """Whether the QP's constraints at theta admit any z (an LP by HiGHS, independent of the QP solvers)."""
    from scipy.optimize import linprog

    _, l, u = problem.qp_vectors(th)
    lo, hi = np.isfinite(l), np.isfinite(u)
    r = linprog(np.zeros(problem.n_z), A_ub=np.vstack([problem.A[hi], -problem.A[lo]]),
                b_ub=np.concatenate([u[hi], -l[lo]]), bounds=(None, None), method="highs")
    return r.status != 2  # 2: infeasible


def _refused(problem: SteeringProblem, th: np.ndarray, status: str) -> str:
    """The status a refused vector is recorded with: "infeasible" when no z satisfies the constraints (whatever
    the interpreted solver said on the way), "unverified" for an answer outside its bounds, else the solver's."""
    if status != "infeasible" and not feasible(problem, th):
        return "infeasible"
    return "unverified" if status == "out_of_bounds" else status


def record(problem: SteeringProblem, n: int = 48, seed: int = 0, feas_tol: float = BOUND_TOL) -> Vectors:
    """Half easy, half bound-activating parameter vectors, solved by the interpreted exact solver.
    An exact answer outside the bounds by more than ``feas_tol`` is recorded as not solved (the C solver
    must refuse it too). The manifest records how many of each kind there are (a problem whose bounds
    can never bind has no active-bound vectors)."""
    thetas = np.vstack([_easy_thetas(problem, n - n // 2, seed), sample_thetas(problem, n // 2, seed + 1)])
    thetas = thetas[np.random.default_rng(seed).permutation(len(thetas))]  # interleave: warm starts see both
    us, sts, fast = [], [], []
    for th in thetas:
        r = problem.solve_theta(th, solver="exact")
        u = np.asarray(r.u, dtype=float).ravel()
        ok = r.ok and np.all(np.isfinite(u)) and violation(problem, problem.to_z(u), th) <= feas_tol
        us.append(u if ok else np.full(problem.n_u, np.nan))
        sts.append(0 if ok else STATUS_CODES.get(_refused(problem, th, r.status) if not r.ok else "unverified", -4))
        zf = problem.unconstrained(th)
        fast.append(bool(ok and violation(problem, zf, th) <= feas_tol and problem.check(zf, th) == "solved"))
    return Vectors(thetas, np.array(us), np.array(sts, dtype=int), np.array(fast, dtype=bool))


def write(path: Path, name: str, v: Vectors) -> str:
    """Write the vectors file; returns its sha256."""
    rows = [f"{MAGIC} {VERSION} {name} {v.theta.shape[1]} {v.u.shape[1]} {len(v.status)}"]
    for th, u, st, f in zip(v.theta, v.u, v.status, v.fast):
        nums = " ".join(repr(float(x)) for x in np.concatenate([th, u]))
        rows.append(f"{int(st)} {int(f)} {nums}")
    text = "\n".join(rows) + "\n"
    Path(path).write_text(text)
    return hashlib.sha256(text.encode()).hexdigest()


def read(path: Path) -> Vectors:
    """Read a vectors file (ValueError with the reason if it is not one)."""
    lines = Path(path).read_text().splitlines()
    head = lines[0].split() if lines else []
    if len(head) != 6 or head[0] != MAGIC or head[1] != str(VERSION):
        raise ValueError(f"{path}: not a {MAGIC} v{VERSION} file")
    n_theta, n_u, count = int(head[3]), int(head[4]), int(head[5])
    body = np.array([[float(x) for x in ln.split()] for ln in lines[1 : 1 + count]])
    if body.shape != (count, 2 + n_theta + n_u):
        raise ValueError(f"{path}: expected {count} rows of {2 + n_theta + n_u} numbers, got {body.shape}")
    return Vectors(body[:, 2 : 2 + n_theta], body[:, 2 + n_theta :], body[:, 0].astype(int), body[:, 1] == 1)
