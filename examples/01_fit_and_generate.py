"""Fit a predictor on a recorded flight and generate its C solver.

    python examples/01_fit_and_generate.py [OUT_DIR] [DATASET.npz]

Without a DATASET the example records one first: 30 s of PogoX flying on the simulator with a PRBS added to
the references (u: the references sent to the controller, y: the measured height and pitch), saved beside
OUT_DIR as OUT_DIR_collect.npz (generate owns OUT_DIR's contents). OUT_DIR defaults to generated/example_flying. Weights, bounds and horizons come from
configs/flying.toml. A log of your own vehicle (ULog, tlog, bridge tick log): docs/guides/logs.md.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from ddpc_codegen import IODataset, SteeringConfig, SteeringProblem, fit_predictor, generate, load_solver
from ddpc_codegen.sim import simulate

ROOT = Path(__file__).resolve().parents[1]


def main(argv: list[str]) -> int:
    out_dir = Path(argv[0]) if argv else ROOT / "generated" / "example_flying"
    cfg = SteeringConfig.from_toml(ROOT / "configs" / "flying.toml")

    # 1. the recording: u (T, m) the references sent, y (T, p) what the vehicle did
    if len(argv) > 1:
        data_file = Path(argv[1])
    else:
        data_file = out_dir.with_name(out_dir.name + "_collect.npz")
        data_file.parent.mkdir(parents=True, exist_ok=True)
        simulate("flying", 30.0, excitation=True, noise=True, seed=3).to_dataset().save(data_file)
    data = IODataset.load(data_file)
    print(f"{data_file.name}: {sum(len(u) for u in data.u)} samples, inputs {data.input_names}, "
          f"outputs {data.output_names}")

    # 2. the predictor: y over the next Tf ticks from the last Tini ticks and the future references
    pred = fit_predictor(data, cfg.t_ini, cfg.t_f, cfg.predictor.get("method", "lsq"),
                         ridge=cfg.predictor.get("ridge", 0.0))

    # 3. the steering QP on that predictor, emitted as C and compiled into a loadable extension
    problem = SteeringProblem(pred, cfg)
    folder = generate(problem, out_dir)
    print(f"generated {folder}: {sorted(p.name for p in folder.glob('*.[ch]'))}")

    # 4. one tick on a window of the recording: steer toward the recorded future outputs
    solver = load_solver(folder, config=cfg)
    u, y = data.u[0], data.y[0]
    k = len(u) // 2
    res = solver.solve(u[k - cfg.t_ini:k], y[k - cfg.t_ini:k], y[k:k + cfg.t_f], u[k:k + cfg.t_f])
    print(f"status {res.status}, first steered reference {np.round(res.u[0], 4)} "
          f"(the recording sent {np.round(u[k], 4)})")
    return 0 if res.ok else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
