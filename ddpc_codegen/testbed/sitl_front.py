"""The steps condition of ``make sitl-demo`` against the identified loop's front.

From the run's collect flight and the steps file, the front of :mod:`ddpc_codegen.design.front` (the least
height error any z_ref reaches at each activity on the identified loop), the steering and passthrough flown
on the same predictor, and the front's error at the activity the steered flights had on the autopilot:
whether what is left of the steps error is the steering's or the loop's.
"""

from __future__ import annotations

from pathlib import Path

from ddpc_codegen.design.front import FrontPoint, desired_from_trajectory, front_error_at, front_report
from ddpc_codegen.pipeline.solver_build import build_from_config
from ddpc_codegen.robot.trajectory_files import load_trajectory
from ddpc_codegen.testbed.sitl_conditions import STEPS_DURATION
from ddpc_codegen.values.config import SteeringConfig

__all__ = ["steps_front"]


def steps_front(folder: Path, autopilot: str, config: Path, flown_rate_ratio: float | None,
                duration: float = STEPS_DURATION) -> dict:
    """The front on the first ``duration`` s of ``folder/steps.csv`` for the predictor ``config`` fits on
    ``folder/<autopilot>_collect.npz`` (as the run's codegen did): ``model`` (the front, passthrough's and the
    steering's points, :func:`~ddpc_codegen.design.front.front_report`), and with the steered flights' mean
    activity ``flown_rate_ratio`` the front's error there (``front_at_flown``; {"skipped": why} without
    the files)."""
    collect, steps = folder / f"{autopilot}_collect.npz", folder / "steps.csv"
    missing = [str(p) for p in (collect, steps) if not p.is_file()]
    if missing:
        return {"skipped": f"not found: {', '.join(missing)}"}
    cfg = SteeringConfig.from_toml(config)
    desired, out_idx = desired_from_trajectory(cfg, load_trajectory(steps), cfg.output_names[0], duration)
    model = front_report(build_from_config(cfg, collect), desired, 0, out_idx)
    front = [FrontPoint(**p) for p in model["front"]]
    at = front_error_at(front, flown_rate_ratio) if flown_rate_ratio else None
    return {"config": config.name, "model": model, "flown_rate_ratio": flown_rate_ratio, "front_at_flown": at}
