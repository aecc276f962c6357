"""Against the real autopilots (skipped without them, see the README): from the ground -- arm
(retried while the EKF initialises), take off, baseline, collect, codegen, steer, land -- each SITL
in a private network namespace; steering must beat the baseline by >= 3x in a short run, the true
height is logged on both autopilots, and the same solver steers a 3-D steps file and a random path."""

from __future__ import annotations

import warnings
from pathlib import Path

import pytest

from ddpc_codegen.testbed.sitl import missing_reason, run_isolated
from ddpc_codegen.testbed.sitl_demo import trajectory_tag
from ddpc_codegen.testbed.sitl_health import flight_diagnosis, sitl_fault

pytestmark = [pytest.mark.sitl, pytest.mark.slow, pytest.mark.compiler, pytest.mark.realtime]


def _unjudgeable(tmp_path: Path, autopilot: str, tags: tuple[str, ...]) -> str | None:
    """Why the SITL (not the steering) spoiled one of these flights (``<autopilot>_<tag>.npz``), or None."""
    for tag in tags:
        why = sitl_fault(tmp_path / f"{autopilot}_{tag}.npz")
        if why:
            warnings.warn(f"{autopilot} {tag}: {why} (a loaded machine spoiled the SITL): flight not judged")
            return why
    return None


def _diagnosis(tmp_path: Path, autopilot: str, tags: tuple[str, ...]) -> dict:
    """What each flight did, for a failed assertion's message (the logs do not outlive a CI run)."""
    return {tag: flight_diagnosis(tmp_path / f"{autopilot}_{tag}.npz") for tag in tags}


@pytest.mark.parametrize("autopilot", ["px4", "ardupilot"])
def test_from_the_ground_to_steered_flight(tmp_path, autopilot):
    why = missing_reason(autopilot)
    if why:
        pytest.skip(why)
    # PX4 SIH's GPS-referenced EKF height is noisy and drifts (26-92 mm from the truth): its predictor
    # needs more data than ArduCopter's (20 s collects gave 2.0x and 2.9x in two of four runs; the
    # demo's 25 s collects 4.2-9.4x in four). The error changes along the ellipse, so PX4's RMSE is
    # taken over one whole period (10 s after the 3 s settle) on both flights.
    collect_s, fly_s = {"px4": (30.0, 13.0), "ardupilot": (20.0, 10.0)}[autopilot]
    res = run_isolated("ddpc_codegen.testbed.sitl_demo:run_pipeline",
                       {"autopilot": autopilot, "out_dir": str(tmp_path), "baseline_s": fly_s, "collect_s": collect_s,
                        "steer_s": fly_s, "baselines": False, "trajectories": ("steps", "random:3"), "steps_s": 12.0},
                       timeout=600)
    r, main = res["rmse_z"], ("collect", "passthrough", "steer")
    judged = _unjudgeable(tmp_path, autopilot, main) is None
    if judged:
        assert r["steered"] * 3.0 <= r["baseline"], (res, _diagnosis(tmp_path, autopilot, main))
    # Both SITLs' ground truth is in the tick log (PX4 SIH: HIL_STATE_QUATERNION, ArduCopter: SIM_STATE):
    # every figure also on the true height, where steering wins -- or, where the vehicle's own estimate is the
    # limit, stays within 1.2x of that estimate's error in the same flight (PX4 SIH's EKF height carries a
    # bias of its own in each flight, -127..+55 mm measured, which no reference steering can see)
    rt, est = res["rmse_z_truth"], res["estimator_rms"]["steered"]
    assert rt["baseline"] is not None and rt["steered"] is not None and est is not None, res
    assert not judged or rt["steered"] < rt["baseline"] or rt["steered"] <= 1.2 * est, \
        (rt, est, _diagnosis(tmp_path, autopilot, main))
    assert res["engaged_fraction"] >= 0.95, res
    assert res["arming"]["attempts"] >= 1 and res["rate_hz"] > 150.0
    # every telemetry sample the bridge received is in the tick log
    assert all(v["samples"] > 0 for v in res["telemetry"].values())
    # Any trajectory steers with the solver collected on the ellipse: the 3-D steps file and a random path,
    # judged on the height the steering sees (PX4 SIH's EKF height once stood 0.57 m off its truth for a
    # whole flight, 4.9 mm EKF error: the truth is logged, the estimator's error is not the steering's).
    for spec in ("steps", "random:3"):
        f = res["steered_trajectories"][spec]
        tag = trajectory_tag(spec)
        if _unjudgeable(tmp_path, autopilot, (tag,)):  # the SITL, not the steering: nothing to judge here
            continue
        assert f["engaged_fraction"] >= 0.9 and f["rmse_z"] < 0.05 and f["rmse_z_truth"] is not None, \
            (spec, f, _diagnosis(tmp_path, autopilot, (tag,)))

    # the steered tick log loads as a dataset and refits
    from ddpc_codegen.pipeline.solver_build import build_from_config
    from ddpc_codegen.values.config import SteeringConfig
    from ddpc_codegen.testbed.sitl_demo import CONFIGS, ROOT

    prob = build_from_config(SteeringConfig.from_toml(ROOT / "configs" / CONFIGS[autopilot]),
                             Path(tmp_path) / f"{autopilot}_steer.npz")
    assert prob.predictor.n_columns > 0
