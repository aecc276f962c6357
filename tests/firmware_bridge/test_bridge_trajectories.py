"""Any trajectory steers: the bridge's solver setup, bound and rate checks work from each trajectory's
own extent and time span (ellipse, file, random), and a 3-D figure-eight file and a random path fly
steered over the link against the simulated vehicle (separate processes, lock-step UDP on 127.0.0.1)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ddpc_codegen.robot.profile import load_profile
from ddpc_codegen.robot.trajectory import EllipseTrajectory, RandomSmoothTrajectory, SampledTrajectory
from ddpc_codegen.robot.trajectory_files import trajectory_from_arg
from ddpc_codegen.testbed.bridge_demo import truth_rmse
from firmware_bridge.bridge import Bridge, BridgeConfig
from firmware_bridge.preflight import check_trajectory_extent, trajectory_rate_warning
from firmware_bridge.ticklog import REASONS, load_ticklog

from support.bridge_helpers import Procs, flying_solver, free_port, read_json  # noqa: F401 (fixture)

FLIGHT = 10.0  # s of off-board flight per run (figures over t >= 3 s)


def figure_eight_csv(path, period: float = 10.0, ax: float = 0.6, ay: float = 0.3, z0: float = 1.0,
                     dz: float = 0.1, t_end: float = 12.0):
    """A horizontal figure eight (x = ax sin wt, y = ay sin 2wt) that climbs and sinks dz with x, as a
    multirotor user writes one: samples every 0.1 s, x, y, z columns, no velocities."""
    t = np.arange(0.0, t_end + 1e-9, 0.1)
    w = 2.0 * math.pi / period
    rows = ["# a figure eight: t [s], x, y, z [m]", "t,x,y,z"]
    rows += [f"{ti:.3f},{ax * math.sin(w * ti):.6f},{ay * math.sin(2 * w * ti):.6f},{z0 + dz * math.sin(w * ti):.6f}"
             for ti in t]
    path.write_text("\n".join(rows) + "\n")
    return path


def _bridge(solver_dir, trajectory) -> Bridge:
    cfg = BridgeConfig(mode="steer", solver=str(solver_dir), controller=load_profile("pogox").controller,
                       trajectory=trajectory, url=f"udpin:127.0.0.1:{free_port()}")
    return Bridge(cfg)


@pytest.mark.compiler
def test_every_kind_of_trajectory_sets_up_the_steering_solver(tmp_path, flying_solver):  # noqa: F811
    kinds = [EllipseTrajectory(), trajectory_from_arg("random:3"),
             trajectory_from_arg(str(figure_eight_csv(tmp_path / "eight.csv")))]
    for traj in kinds:
        b = _bridge(flying_solver, traj)
        try:
            assert b.steering is not None and b.steering.t_f == read_json(flying_solver / "manifest.json")["dims"]["t_f"]
            # The frame anchors at the trajectory's own start (x, y): the vehicle maps there.
            np.testing.assert_array_equal(b.frame.anchor, traj.start_position()[:2])
        finally:
            b.link.close()


@pytest.mark.compiler
def test_a_file_above_the_solver_bounds_is_refused_naming_the_file(tmp_path, flying_solver):  # noqa: F811
    # Samples at 2.9 m and back: the spline overshoots between them past the solver's 3 m bound.
    path = tmp_path / "high.csv"
    path.write_text("t,x,z\n0,0,1.0\n1,0,2.9\n2,0,2.9\n3,0,1.0\n")
    traj = trajectory_from_arg(str(path))
    lo, hi = traj.extent()["z"]
    assert hi > 2.9  # the overshoot the samples alone do not show
    with pytest.raises(ValueError, match=rf"^the trajectory {path} spans z = 1.000 .. {hi:.3f} m but the solver's "
                                         r"z_ref bounds are \[0, 3\] m: steering could never engage"):
        _bridge(flying_solver, traj)


def test_extent_check_uses_the_guaranteed_range_of_an_endless_random_path():
    traj = RandomSmoothTrajectory(seed=3)
    lo, hi = traj.extent()["z"]
    check_trajectory_extent(traj, lo, hi)                   # inside its own bounds
    with pytest.raises(ValueError, match=r"^the trajectory spans z = "):
        check_trajectory_extent(traj, lo + 0.01, hi)


def test_rate_warning_compares_the_paths_climb_rate_with_the_solvers_rate_bound():
    # z ramps 0.5 m in 1 s (Hermite, velocity 0.5 m/s at the middle sample)
    traj = SampledTrajectory((0.0, 1.0, 2.0), (0.0, 0.0, 0.0), (1.0, 1.5, 2.0), vz=(0.5, 0.5, 0.5))
    assert trajectory_rate_warning(traj, 0.003, 200.0) is None            # 0.6 m/s allowed
    assert trajectory_rate_warning(traj, math.inf, 200.0) is None         # unbounded
    msg = trajectory_rate_warning(traj, 0.002, 200.0)                     # 0.4 m/s allowed
    assert msg == ("the trajectory climbs or sinks at up to 0.500 m/s but the solver moves z_ref by at most 0.002 m "
                   "per tick (0.400 m/s at 200 Hz): the steered reference lags the path there")
    # An endless path is sampled over its first RATE_CHECK_SPAN seconds (no hang on t1 = inf).
    assert trajectory_rate_warning(RandomSmoothTrajectory(seed=1), 1e-6, 200.0).startswith("the trajectory climbs")


# ----------------------------------------------------------------------------- over the link
def _fly(procs, tmp_path, name: str, bridge_args: list[str]) -> dict:
    port = free_port()
    truth, log, summ = tmp_path / f"{name}_truth.npz", tmp_path / f"{name}.npz", tmp_path / f"{name}.json"
    veh = procs.spawn("vehicle", f"udpout:127.0.0.1:{port}", "--lockstep", "--seed", "4", "--truth-log", str(truth),
                      name=f"{name}_vehicle")
    br = procs.spawn("bridge", f"udpin:127.0.0.1:{port}", "--lockstep", "--offboard", "--duration", str(FLIGHT),
                     "--log", str(log), "--summary", str(summ), "--timeout", "90", "--wait-heartbeat", "30",
                     "--frame", "world", *bridge_args, name=f"{name}_bridge")
    assert procs.wait(br, 150) == 0, procs.log(br)
    assert procs.terminate(veh) == 0, procs.log(veh)
    s = read_json(summ)
    s["truth"] = truth_rmse(log, truth)
    with np.load(truth) as z:
        s["truth_t"], s["truth_state"] = z["t"], z["state"]
    return s


@pytest.fixture(scope="module")
def flown(tmp_path_factory, flying_solver):  # noqa: F811
    """The figure eight passthrough and steered, random:3 passthrough and steered."""
    tmp = tmp_path_factory.mktemp("trajectories")
    eight = figure_eight_csv(tmp / "eight.csv")
    pr = Procs(tmp)
    out = {}
    try:
        for traj, tag in ((str(eight), "eight"), ("random:3", "random")):
            out[f"{tag}_base"] = _fly(pr, tmp, f"{tag}_base", ["--mode", "passthrough", "--trajectory", traj])
            out[tag] = _fly(pr, tmp, tag, ["--mode", "steer", "--solver", str(flying_solver), "--trajectory", traj])
    finally:
        pr.cleanup()
    out["eight_path"], out["tmp"] = eight, tmp
    return out


@pytest.mark.e2e
@pytest.mark.compiler
@pytest.mark.realtime
@pytest.mark.parametrize("tag", ["eight", "random"])
def test_file_and_random_paths_fly_steered_over_the_link(flown, tag):
    s, base = flown[tag], flown[f"{tag}_base"]
    ticks = load_ticklog(flown["tmp"] / f"{tag}.npz").ticks
    on = ticks["active"].astype(bool) & (np.nan_to_num(ticks["t_traj"], nan=-1.0) >= 3.0)
    steered = ticks["reason"][on] == REASONS.index("steered")
    assert steered.mean() > 0.95, s["fallback_reasons"]
    assert s["truth"]["flown_s"] >= FLIGHT - 0.1
    # The desired outputs are the trajectory's own (not the default ellipse).
    want = trajectory_from_arg(str(flown["eight_path"]) if tag == "eight" else "random:3")
    np.testing.assert_allclose(ticks["y_des"][on, 0], want.sample(ticks["t_traj"][on])["z"], atol=1e-9)
    # Steering beats the model-based controller alone on the true height.
    assert s["truth"]["rmse_z"] < 0.7 * base["truth"]["rmse_z"], (s["truth"], base["truth"])


@pytest.mark.e2e
@pytest.mark.compiler
@pytest.mark.realtime
def test_the_figure_eight_is_flown_in_3d(flown):
    """The vehicle's true horizontal position follows the file's x and y (the y column is flown)."""
    s = flown["eight"]
    traj = trajectory_from_arg(str(flown["eight_path"]))
    ticks = load_ticklog(flown["tmp"] / "eight.npz").ticks
    on = ticks["active"].astype(bool) & (np.nan_to_num(ticks["t_traj"], nan=-1.0) >= 3.0)
    tt, st = s["truth_t"], s["truth_state"]
    tv = ticks["t_vehicle"][on]
    want = traj.sample(ticks["t_traj"][on])
    for i, ax in enumerate("xy"):
        got = np.interp(tv, tt, st[:, i])
        err = got - want[ax]
        assert np.sqrt(np.mean(err ** 2)) < 0.1, (ax, np.sqrt(np.mean(err ** 2)))
        assert np.ptp(got) > 0.8 * np.ptp(want[ax])  # it really went there (not held on the x-z plane)
