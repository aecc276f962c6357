"""Trajectories: the random smooth path's bounds and determinism, the spline through samples,
trajectory files (CSV / TOML) with errors that name the file, the row or point and the value,
and both new kinds flown by the simulator through the unchanged controller."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ddpc_codegen.errors import ConfigError
from ddpc_codegen.robot.trajectory import EllipseTrajectory, RandomSmoothTrajectory, SampledTrajectory
from ddpc_codegen.robot.trajectory_files import load_trajectory, save_trajectory_csv, trajectory_from_arg

DT = 0.005


def _derivatives_consistent(traj, t: np.ndarray) -> None:
    d = traj.sample(t)
    for ax in "xz":
        np.testing.assert_allclose(np.gradient(d[ax], DT)[2:-2], d[f"v{ax}"][2:-2], atol=2e-4)
        np.testing.assert_allclose(np.gradient(d[f"v{ax}"], DT)[2:-2], d[f"a{ax}"][2:-2], atol=2e-3)


@pytest.mark.parametrize("seed", [0, 1, 7, 11])
def test_random_path_honours_its_bounds(seed):
    """|x'' |, |z''| <= max_accel and |x - cx| <= 2 amplitude over 300 s; starts at rest at the start point."""
    tr = RandomSmoothTrajectory(seed=seed)
    t = np.arange(0.0, 300.0, DT)
    d = tr.sample(t)
    assert np.max(np.abs(d["ax"])) <= tr.max_accel and np.max(np.abs(d["az"])) <= tr.max_accel
    assert np.max(np.abs(d["x"] - tr.center[0])) <= 2 * tr.amplitude[0] + 1e-12
    assert np.max(np.abs(d["z"] - tr.center[1])) <= 2 * tr.amplitude[1] + 1e-12
    early = t <= tr.t_start
    assert np.all(d["x"][early] == tr.center[0]) and np.all(d["vz"][early] == 0) and np.all(d["az"][early] == 0)
    _derivatives_consistent(tr, t[: 40 * 200])


def test_random_path_is_seeded_and_does_not_repeat():
    t = np.arange(0.0, 120.0, DT)
    a, b, c = (RandomSmoothTrajectory(seed=s).sample(t)["z"] for s in (3, 3, 4))
    np.testing.assert_array_equal(a, b)
    assert np.max(np.abs(a - c)) > 0.05
    # No period up to 60 s: the path shifted by any lag differs somewhere by > 1 cm.
    k0 = int(10 / DT)
    for lag in range(int(2 / DT), int(60 / DT), 20):
        assert np.max(np.abs(a[k0 : k0 + 4000] - a[k0 + lag : k0 + lag + 4000])) > 0.01


def test_random_path_validates_its_fields():
    with pytest.raises(ValueError, match="band"):
        RandomSmoothTrajectory(band=(0.3, 0.1))
    with pytest.raises(ValueError, match="max_accel"):
        RandomSmoothTrajectory(max_accel=0.0)


def test_spline_through_samples():
    ts = np.linspace(0.0, 10.0, 101)
    tr = SampledTrajectory(tuple(ts), tuple(np.sin(ts)), tuple(0.5 * ts + 1.0))
    d = tr.sample(ts)
    np.testing.assert_allclose(d["x"], np.sin(ts), atol=1e-12)  # interpolates the knots
    q = np.linspace(1.0, 9.0, 333)
    d = tr.sample(q)
    np.testing.assert_allclose(d["x"], np.sin(q), atol=1e-4)
    np.testing.assert_allclose(d["vx"], np.cos(q), atol=2e-3)
    np.testing.assert_allclose(d["ax"], -np.sin(q), atol=2e-2)
    np.testing.assert_allclose(d["z"], 0.5 * q + 1.0, atol=1e-12)  # a line stays a line
    np.testing.assert_allclose(d["vz"], 0.5, atol=1e-12)
    before, after = tr.sample(np.array([-1.0, 12.0]))["x"]
    assert before == 0.0 and after == pytest.approx(np.sin(10.0))
    assert tr.start_point() == (0.0, 1.0)


def test_csv_and_toml_files_round_trip(tmp_path):
    ell = EllipseTrajectory()
    path = save_trajectory_csv(tmp_path / "ellipse.csv", ell, 12.0, dt=0.05)
    tr = load_trajectory(path)
    t = np.linspace(1.5, 11.5, 200)
    np.testing.assert_allclose(tr.sample(t)["z"], ell.sample(t)["z"], atol=1e-5)
    np.testing.assert_allclose(tr.sample(t)["ax"], ell.sample(t)["ax"], atol=2e-3)
    toml = tmp_path / "hop.toml"
    toml.write_text('description = "three points"\n' + "".join(
        f"[[point]]\nt = {t_}\nx = {x}\nz = {z}\n" for t_, x, z in ((0, 0, 1), (1.0, 0.5, 1.2), (2.5, 1, 1))))
    tr = load_trajectory(toml)
    assert tr.t == (0.0, 1.0, 2.5) and tr.sample(1.0)["z"] == pytest.approx(1.2)


@pytest.mark.parametrize("text, message", [
    ("t,x,z\n0,0,1\n1,abc,1.1\n", r"bad.csv row 3, column 'x': 'abc' is not a number"),
    ("t,x,z\n0,0,1\n1,0,nan\n", r"bad.csv row 3, column 'z': 'nan' is not a finite number"),
    ("# c\nt,x,z\n0,0,1\n1,0,1\n0.5,0,1\n", r"bad.csv row 5: t = 0.5 is not after t = 1.0 \(at .*bad.csv row 4\)"),
    ("t,x,z\n-1,0,1\n1,0,1\n", r"bad.csv row 2: t = -1.0 is negative"),
    ("t,x,q\n0,0,1\n", r"bad.csv row 1: the header must name the columns .*unknown \['q'\]; missing \['z'\]"),
    ("t,x,z\n0,0,1\n1,0\n", r"bad.csv row 3: expected 3 values \(t,x,z\); got 2"),
    ("t,x,z\n0,0,1\n", r"bad.csv: a trajectory needs at least 2 samples; got 1"),
    ("\n# nothing\n", r"bad.csv: empty"),
])
def test_csv_errors_name_file_row_and_value(tmp_path, text, message):
    (tmp_path / "bad.csv").write_text(text)
    with pytest.raises(ConfigError, match=message):
        load_trajectory(tmp_path / "bad.csv")


@pytest.mark.parametrize("text, message", [
    ("[[point]]\nt = 0\nx = 0\nz = 1\n[[point]]\nt = 1\nx = 0\nz = 'high'\n",
     r"bad.toml point\[1\] key 'z': 'high' is not a number"),
    ("[[point]]\nt = 0\nx = 0\n", r"bad.toml point\[0\]: missing key\(s\) \['z'\]"),
    ("[[point]]\nt = 0\nx = 0\nz = 1\npitch = 0.1\n", r"bad.toml point\[0\]: unknown key\(s\) \['pitch'\]"),
    ("speed = 3\n", r"bad.toml: top level: speed is not a known key"),
    ("point = 3\n", r"bad.toml: expected \[\[point\]\] tables"),
    ("[[point\n", r"bad.toml: trajectory file: is not valid TOML"),
])
def test_toml_errors_name_file_point_key_and_value(tmp_path, text, message):
    (tmp_path / "bad.toml").write_text(text)
    with pytest.raises(ConfigError, match=message):
        load_trajectory(tmp_path / "bad.toml")


def test_unknown_format_and_missing_file(tmp_path):
    (tmp_path / "traj.json").write_text("{}")
    with pytest.raises(ConfigError, match=r"traj.json: unknown format '.json'; use .csv or .toml"):
        load_trajectory(tmp_path / "traj.json")
    with pytest.raises(ConfigError, match="does not exist"):
        load_trajectory(tmp_path / "none.csv")


def test_new_trajectories_fly_in_the_simulator(tmp_path):
    """The controller and the look-ahead (TickContext.desired_ahead) take any trajectory type."""
    from ddpc_codegen.sim import FlyingScenario, simulate

    path = save_trajectory_csv(tmp_path / "r.csv", RandomSmoothTrajectory(seed=5), 8.0, dt=0.02)
    seen = []

    def hook(ctx):
        if ctx.k == 600:
            seen.append((ctx.t, ctx.desired_ahead(15)))
        return None

    for tr in (RandomSmoothTrajectory(seed=5), load_trajectory(path)):
        res = simulate(FlyingScenario(ellipse=tr), 6.0, reference_hook=hook)
        assert not res.crashed
        np.testing.assert_allclose(res.y_des[:, 0], tr.sample(res.t)["z"], atol=1e-12)
        np.testing.assert_allclose(res.extras["z_des"], tr.sample(res.t)["z"], atol=1e-12)
        t, ahead = seen[-1]
        np.testing.assert_allclose(ahead[:, 0], tr.sample(t + DT * np.arange(15))["z"], atol=1e-12)
        # The height loop's offset (mass error, no integrator) dominates the error, not the path.
        assert 0.02 < res.metrics()["rmse_z"] < 0.2


def test_trajectory_from_a_command_line_value(tmp_path):
    assert trajectory_from_arg("ellipse") == EllipseTrajectory()
    assert trajectory_from_arg("random:4") == RandomSmoothTrajectory(seed=4)
    assert trajectory_from_arg("random") == RandomSmoothTrajectory(seed=0)
    path = save_trajectory_csv(tmp_path / "p.csv", EllipseTrajectory(), 3.0)
    assert isinstance(trajectory_from_arg(str(path)), SampledTrajectory)
    with pytest.raises(ConfigError, match=r"seed after 'random:' must be an integer; got 'x'"):
        trajectory_from_arg("random:x")
    with pytest.raises(ConfigError, match=r"trajectory 'spiral': expected 'ellipse', 'random\[:SEED\]'"):
        trajectory_from_arg("spiral")
    with pytest.raises(ConfigError, match="does not exist"):
        trajectory_from_arg(str(tmp_path / "missing.csv"))


# ----------------------------------------------------------------------------- one protocol, 3-D files
def test_every_kind_follows_the_trajectory_protocol():
    from ddpc_codegen.robot.trajectory import Trajectory

    kinds = [EllipseTrajectory(), RandomSmoothTrajectory(seed=2),
             SampledTrajectory((0.0, 1.0, 2.0), (0.0, 0.5, 1.0), (1.0, 1.1, 1.0), y=(0.0, 0.2, 0.0))]
    keys = {f"{p}{ax}" for p in ("", "v", "a") for ax in "xyz"} | {"yaw"}
    for tr in kinds:
        assert isinstance(tr, Trajectory)
        d = tr.sample(np.linspace(0.0, 3.0, 7))
        assert set(d) == keys and all(v.shape == (7,) for v in d.values())
        x, y, z = tr.start_position()
        assert (x, z) == tr.start_point()
        np.testing.assert_allclose([tr.sample(0.0)[a] for a in "xyz"], (x, y, z), atol=1e-12)
    assert EllipseTrajectory(t_start=2.0, spin_up=0.5, period=8.0).time_span() == (2.0, 12.5)
    assert RandomSmoothTrajectory(t_start=1.5).time_span() == (1.5, float("inf"))
    assert kinds[2].time_span() == (0.0, 2.0)
    assert EllipseTrajectory(center=(0.5, 1.2), radii=(1.0, 0.3)).extent() == {
        "x": (-0.5, 1.5), "y": (0.0, 0.0), "z": (pytest.approx(0.9), pytest.approx(1.5))}


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(-2.0, 2.0), min_size=2, max_size=12), st.lists(st.floats(0.05, 2.0), min_size=11, max_size=11),
       st.booleans())
def test_a_files_extent_is_the_exact_range_of_its_spline(values, steps, with_velocity):
    """Against dense sampling: never narrower (the overshoot between samples counts), barely wider."""
    n = len(values)
    t = np.concatenate([[0.0], np.cumsum(steps[: n - 1])])
    vz = tuple(np.cos(np.arange(n))) if with_velocity else None
    tr = SampledTrajectory(tuple(t), tuple(np.zeros(n)), tuple(values), vz=vz)
    lo, hi = tr.extent()["z"]
    grid = np.linspace(t[0], t[-1], 200_001)
    dense = tr.sample(grid)["z"]
    assert lo <= dense.min() + 1e-12 and hi >= dense.max() - 1e-12
    # The grid's extremes, refined around each (a grid point can miss a peak by ~ curvature * spacing^2).
    h = grid[1] - grid[0]
    fine = lambda k: tr.sample(np.linspace(grid[k] - h, grid[k] + h, 2001).clip(t[0], t[-1]))["z"]  # noqa: E731
    assert lo >= fine(int(np.argmin(dense))).min() - 1e-9 and hi <= fine(int(np.argmax(dense))).max() + 1e-9


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 10_000))
def test_the_random_paths_extent_bounds_it_for_all_time(seed):
    tr = RandomSmoothTrajectory(seed=seed)
    d = tr.sample(np.linspace(0.0, 400.0, 40_001))
    for ax in "xz":
        lo, hi = tr.extent()[ax]
        assert lo <= d[ax].min() and d[ax].max() <= hi


def test_velocity_columns_give_a_hermite_spline_through_them():
    t = (0.0, 1.0, 2.5)
    tr = SampledTrajectory(t, (0.0, 1.0, 1.5), (1.0, 1.0, 1.0), vx=(0.0, 2.0, 0.0))
    d = tr.sample(np.array([1e-9, 1.0, 2.5 - 1e-9]))
    np.testing.assert_allclose(d["vx"], (0.0, 2.0, 0.0), atol=1e-6)  # the given velocities
    np.testing.assert_allclose(tr.sample(np.array(t))["x"], (0.0, 1.0, 1.5), atol=1e-12)
    for seg in (np.arange(0.01, 0.98, DT), np.arange(1.02, 2.49, DT)):  # acceleration jumps at a sample
        _derivatives_consistent(tr, seg)
    assert tr.sample(0.5)["vz"] == 0.0  # the other axes keep the natural spline


def test_3d_files_with_yaw_and_velocities_round_trip(tmp_path):
    src = SampledTrajectory(tuple(np.linspace(0, 6, 31)), tuple(np.sin(np.linspace(0, 6, 31))),
                            tuple(1.0 + 0.1 * np.linspace(0, 6, 31)), y=tuple(np.sin(2 * np.linspace(0, 6, 31))),
                            yaw=tuple(0.3 * np.linspace(0, 6, 31)))
    cols = ("t", "x", "y", "z", "yaw", "vx", "vy", "vz")
    path = save_trajectory_csv(tmp_path / "eight.csv", src, 6.0, dt=0.1, columns=cols)
    tr = load_trajectory(path)
    assert tr.y is not None and tr.yaw is not None and tr.vz is not None
    q = np.linspace(0.2, 5.8, 57)
    for k in ("x", "y", "z", "yaw", "vx", "vy"):
        np.testing.assert_allclose(tr.sample(q)[k], src.sample(q)[k], atol=5e-3, err_msg=k)
    toml = tmp_path / "eight.toml"
    toml.write_text("".join(f"[[point]]\nt = {a}\nx = {b}\ny = {c}\nz = 1.0\nyaw = 0.1\n"
                            for a, b, c in ((0, 0, 0), (1, 0.5, 0.3), (2, 1.0, 0.0))))
    tr = load_trajectory(toml)
    assert tr.y == (0.0, 0.3, 0.0) and tr.sample(1.0)["yaw"] == pytest.approx(0.1)
    with pytest.raises(ConfigError, match=r"save_trajectory_csv columns must include \['t', 'x', 'z'\] and only"):
        save_trajectory_csv(tmp_path / "x.csv", src, 6.0, columns=("t", "x", "z", "pitch"))


@pytest.mark.parametrize("text, message", [
    ("[[point]]\nt = 0\nx = 0\nz = 1\ny = 0\n[[point]]\nt = 1\nx = 0\nz = 1\n",
     r"bad.toml point\[1\]: has keys \['t', 'x', 'z'\] but point\[0\] has \['t', 'x', 'y', 'z'\]; every point needs "
     r"the same keys"),
    ("[[point]]\nt = 0\nx = 0\nz = 1\nroll = 0.1\n",
     r"bad.toml point\[0\]: unknown key\(s\) \['roll'\]; a point has \['t', 'x', 'z'\] and optionally "
     r"\['y', 'yaw', 'vx', 'vy', 'vz'\]"),
])
def test_toml_optional_keys_errors(tmp_path, text, message):
    (tmp_path / "bad.toml").write_text(text)
    with pytest.raises(ConfigError, match=message):
        load_trajectory(tmp_path / "bad.toml")


def test_csv_with_optional_columns_and_bad_header(tmp_path):
    (tmp_path / "ok.csv").write_text("z,t,y,x,vz\n1,0,0,0,0\n1.2,1,0.5,0.2,0\n")
    tr = load_trajectory(tmp_path / "ok.csv")
    assert tr.start_position() == (0.0, 0.0, 1.0) and tr.sample(0.5)["y"] > 0.0
    (tmp_path / "bad.csv").write_text("t,x,z,pitch\n0,0,1,0\n")
    with pytest.raises(ConfigError, match=r"bad.csv row 1: the header must name the columns \['t', 'x', 'z'\] once "
                                          r"each \(any order; optional: \['y', 'yaw', 'vx', 'vy', 'vz'\]\); got "
                                          r".*; unknown \['pitch'\]$"):
        load_trajectory(tmp_path / "bad.csv")


def test_the_controller_flies_y_and_yaw_of_the_path():
    """y: roll from the lateral PD + the path's lateral acceleration; yaw: the commanded heading, pitch and
    roll along and across it (yaw 0: today's x-z law unchanged)."""
    from ddpc_codegen.robot.controller import HeightLegAngleController
    from ddpc_codegen.robot.profile import load_profile
    from ddpc_codegen.robot.frames import euler_from_quat
    from ddpc_codegen.robot.state import MeasuredState

    cfg = load_profile("pogox").controller
    t = tuple(np.linspace(0.0, 4.0, 41))
    ay_path = SampledTrajectory(t, (0.0,) * 41, (1.0,) * 41, y=tuple(0.2 * np.sin(np.linspace(0.0, 4.0, 41))))
    turned = SampledTrajectory(t, tuple(0.3 * np.sin(np.linspace(0.0, 4.0, 41))), (1.0,) * 41,
                               yaw=(np.pi / 2,) * 41)
    st0 = MeasuredState(t=2.0, position=np.array([0.0, 0.0, 1.0]), velocity=np.zeros(3), euler=np.zeros(3),
                        body_rates=np.zeros(3), contact=False)
    c = HeightLegAngleController(cfg, ay_path)
    off = MeasuredState(t=2.0, position=np.array([0.0, -0.3, 1.0]), velocity=np.zeros(3), euler=np.zeros(3),
                        body_rates=np.zeros(3), contact=False)
    r = c.nominal_reference(off)
    d = ay_path.sample(2.0)
    want_roll = -np.arctan2(d["ay"] + cfg.kp_xy * (d["y"] + 0.3) + cfg.kd_xy * d["vy"], cfg.g)
    sp = c.track(r, off)
    assert sp.euler[0] == pytest.approx(np.clip(want_roll, -cfg.max_tilt, cfg.max_tilt)) and abs(sp.euler[0]) > 0.01
    c = HeightLegAngleController(cfg, turned)
    r = c.nominal_reference(st0)
    sp = c.track(r, st0)
    d = turned.sample(2.0)
    e_x = d["ax"] + cfg.kp_xy * d["x"] + cfg.kd_xy * d["vx"]
    # Heading +90 deg (facing +y): the x motion is across the heading, a roll (x = -left), pitch 0.
    assert r[1] == pytest.approx(0.0, abs=1e-12) and sp.euler[2] == pytest.approx(np.pi / 2)
    assert sp.euler[0] == pytest.approx(np.clip(np.arctan2(e_x, cfg.g), -cfg.max_tilt, cfg.max_tilt))
    np.testing.assert_allclose(euler_from_quat(sp.q), sp.euler, atol=1e-12)
