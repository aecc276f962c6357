"""The benchmark's problems: a discrete tracking loop per size, its PRBS data, the fitted steering problem and
the parameter vectors a closed-loop run feeds the solver (shared by every ``bench_*`` entry)."""

from __future__ import annotations

import numpy as np

from ddpc_codegen.design.data import IODataset, prbs
from ddpc_codegen.design.predictor import fit_predictor
from ddpc_codegen.design.problem import SteeringProblem
from ddpc_codegen.values.config import SteeringConfig

__all__ = ["SIZES", "bench_plant", "simulate_plant", "bench_data", "build_problem", "theta_stream"]

# preview: a 500 ms horizon (what a PX4 / ArduPilot height loop needs) on 10 piecewise-linear knots
SIZES = {"flying": dict(m=2, p=2, t_ini=20, t_f=15), "hopping": dict(m=3, p=3, t_ini=20, t_f=25),
         "preview": dict(m=2, p=2, t_ini=20, t_f=100, knots=10)}


def bench_plant(m: int, seed: int):
    """Discrete (dt = 5 ms) tracking loop: each output follows its reference through a 2nd-order
    lag (wn ~ 8-12 rad/s, zeta ~ 0.6-0.8), weakly coupled, with a constant offset (model error)."""
    rng = np.random.default_rng(seed)
    dt = 0.005
    n = 2 * m
    Ac = np.zeros((n, n))
    Bc = np.zeros((n, m))
    for i in range(m):
        wn, z = rng.uniform(8, 12), rng.uniform(0.6, 0.8)
        Ac[2 * i, 2 * i + 1] = 1.0
        Ac[2 * i + 1, 2 * i] = -wn**2
        Ac[2 * i + 1, 2 * i + 1] = -2 * z * wn
        Bc[2 * i + 1, i] = wn**2
    Bc[1::2] += 0.1 * rng.standard_normal((m, m)) * 40
    from scipy.linalg import expm

    E = expm(np.block([[Ac, Bc], [np.zeros((m, n + m))]]) * dt)
    A, B = E[:n, :n], E[:n, n:]
    C = np.zeros((m, n))
    C[np.arange(m), 2 * np.arange(m)] = 1.0
    offset = -0.06 * np.ones(m)
    return A, B, C, offset


def simulate_plant(A, B, C, off, u, x0):
    """(outputs (n, p), final state) of the plant (A, B, C, offset) driven by u (n, m) from the state x0."""
    x = x0.copy()
    y = np.empty((u.shape[0], C.shape[0]))
    for k in range(u.shape[0]):
        y[k] = C @ x + off
        x = A @ x + B @ u[k]
    return y, x


def bench_data(size: str, seed: int = 0) -> tuple[SteeringConfig, IODataset, tuple]:
    """(config, PRBS dataset, plant (A, B, C, offset)) of a benchmark size."""
    d = SIZES[size]
    m, ti, tf = d["m"], d["t_ini"], d["t_f"]
    A, B, C, off = bench_plant(m, seed)
    u = prbs(4000, m, amplitude=0.05, min_hold=4, seed=seed)
    y, _ = simulate_plant(A, B, C, off, u, np.zeros(A.shape[0]))
    # An offset makes the IO map affine; data and windows are taken relative to the operating point.
    ds = IODataset(u, y - off, 0.005)
    cfg = SteeringConfig(t_ini=ti, t_f=tf, m=m, p=m, Q=[100.0] * m, R=[1.0] * m, R_mode="offset",
                         lambda_sigma=1e3, u_min=[-0.3] * m, u_max=[0.3] * m, du_max=[0.02] * m,
                         name=f"bench_{size}", predictor={"method": "lsq"}, knots=d.get("knots"))
    return cfg, ds, (A, B, C, off)


def build_problem(size: str, seed: int = 0) -> tuple[SteeringProblem, tuple]:
    """(interpreted problem, plant) of a benchmark size (no solver generated)."""
    cfg, ds, plant = bench_data(size, seed)
    return SteeringProblem(fit_predictor(ds, cfg.t_ini, cfg.t_f, "lsq"), cfg), plant


def closed_loop(problem: SteeringProblem, plant: tuple, solver, n: int, seed: int = 1):
    """Closed loop of ``solver`` (anything with ``solve_theta``) on the plant for n ticks, tracking a sine plus
    random steps; yields per tick (theta (n_theta,), its result, y_k (m,), y_des_k (m,))."""
    A, B, C, _ = plant
    c = problem.config
    m, ti, tf = c.m, c.t_ini, c.t_f
    rng = np.random.default_rng(seed)
    t = np.arange(n + tf) * 0.005
    steps = np.repeat(rng.uniform(-0.15, 0.15, (len(t) // 300 + 1, m)), 300, axis=0)[: len(t)]
    y_des = 0.1 * np.sin(2 * np.pi * 0.5 * t)[:, None] + steps
    x, u_hist, y_hist = np.zeros(A.shape[0]), np.zeros((ti, m)), np.zeros((ti, m))
    for k in range(n):
        y_k = C @ x  # relative to the operating point (offset removed, as in the data)
        yd = y_des[k : k + tf]
        th = problem.theta(u_hist, y_hist, yd, yd)
        r = solver.solve_theta(th)
        yield th, r, y_k, y_des[k]
        u_k = r.u[0] if r.ok else yd[0]
        x = A @ x + B @ u_k
        u_hist = np.vstack([u_hist[1:], u_k])
        y_hist = np.vstack([y_hist[1:], y_k])


def theta_stream(problem: SteeringProblem, plant: tuple, solver, n: int, seed: int = 1) -> np.ndarray:
    """The parameter vectors ``solver`` saw in :func:`closed_loop` (n, n_theta)."""
    return np.array([th for th, *_ in closed_loop(problem, plant, solver, n, seed)]).reshape(n, problem.n_theta)
