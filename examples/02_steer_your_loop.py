"""Steer the reference of your own loop from Python, tick by tick.

    python examples/02_steer_your_loop.py [OUT_DIR]

The plant stands for "your controller + your vehicle": a height loop (PD with a delay) whose model is
wrong, so it lags the reference and sags below it. The example records 20 s of it with a PRBS on the
reference, fits a predictor, generates the C solver into OUT_DIR (default generated/example_loop), and then
flies a path twice: with the nominal reference, and with the reference the ReferenceSteerer picks each tick.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from ddpc_codegen import (IODataset, ReferenceSteerer, SteeringConfig, SteeringProblem, fit_predictor, generate,
                          load_solver, prbs)

ROOT = Path(__file__).resolve().parents[1]
DT = 0.01  # s (100 Hz)
CONFIG = {"name": "loop", "horizon": {"t_ini": 10, "t_f": 20, "dt": DT},
          "signals": {"inputs": ["z_ref"], "outputs": ["z"]},
          "cost": {"Q": [1000.0], "R": [1.0], "R_du": [10.0], "R_mode": "offset"},
          "bounds": {"u_min": [-1.0], "u_max": [3.0], "du_max": [0.05]},
          "predictor": {"method": "lsq", "ridge": 1e-6}, "codegen": {"backend": "daqp"}}


class HeightLoop:
    """Your loop: z'' = kp (z_ref delayed - z) - kd z' - sag (the mass error), explicit Euler at DT."""

    def __init__(self, delay: int = 5, kp: float = 25.0, kd: float = 7.0, sag: float = 2.0) -> None:
        self.z, self.v, self.kp, self.kd, self.sag = 0.0, 0.0, kp, kd, sag
        self.queue = [0.0] * delay

    def step(self, z_ref: float) -> float:
        """Apply this tick's reference; returns the height measured at the next tick (m)."""
        self.queue.append(z_ref)
        r = self.queue.pop(0)
        self.v += DT * (self.kp * (r - self.z) - self.kd * self.v - self.sag)
        self.z += DT * self.v
        return self.z


def fly(path: np.ndarray, steerer: ReferenceSteerer | None, t_f: int) -> np.ndarray:
    """Fly ``path`` (T,) with the nominal reference or the steered one; returns the heights (T,)."""
    plant, z, heights = HeightLoop(), 0.0, []
    padded = np.concatenate([path, np.full(t_f, path[-1])])
    for k in range(len(path)):
        ahead = padded[k:k + t_f, None]                       # (Tf, p) desired outputs from now on
        u = ahead[0]                                          # the nominal reference: the path itself
        if steerer is not None:
            u = steerer.step(y_des=ahead, u_nom=ahead).u      # steered, or the nominal one with the reason
            steerer.observe(u, np.array([z]))                 # the pair this tick decided on
        heights.append(z)
        z = plant.step(float(u[0]))
    return np.array(heights)


def main(argv: list[str]) -> int:
    out_dir = Path(argv[0]) if argv else ROOT / "generated" / "example_loop"  # where examples/03_cpp looks
    cfg = SteeringConfig.from_dict(CONFIG)
    # 1. record: a PRBS around a hover reference, the height measured before each tick's reference is applied
    u = 1.0 + prbs(2000, 1, amplitude=0.2, min_hold=10, seed=1)
    plant, y = HeightLoop(), np.zeros((2000, 1))
    for k in range(1, 2000):
        y[k] = plant.step(float(u[k - 1, 0]))
    data = IODataset(u[200:], y[200:], DT, input_names=["z_ref"], output_names=["z"])  # drop the take-off
    # 2. fit, generate the C solver, load it
    solver = load_solver(generate(SteeringProblem(fit_predictor(data, cfg.t_ini, cfg.t_f, "lsq", ridge=1e-6), cfg),
                                  out_dir), config=cfg)
    # 3. your loop: a smooth climb, a hold and a descent, flown without and with steering
    t = np.arange(0, 12, DT)
    path = 1.0 + 0.5 * np.sin(2 * np.pi * 0.1 * t) ** 2
    steerer = ReferenceSteerer.for_solver(solver)
    scored = slice(int(2 / DT), None)  # after 2 s: the steerer needs Tini ticks, the plant a moment to settle
    rmse = {name: float(np.sqrt(np.mean((fly(path, s, cfg.t_f)[scored] - path[scored]) ** 2)))
            for name, s in (("nominal", None), ("steered", steerer))}
    print(f"height RMSE: nominal {1e3 * rmse['nominal']:.1f} mm, steered {1e3 * rmse['steered']:.1f} mm; "
          f"steerer {steerer.summary()['steered']} ticks steered, {steerer.summary()['fallbacks']} fallbacks")
    return 0 if rmse["steered"] < rmse["nominal"] else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
