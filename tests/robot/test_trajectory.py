"""Trajectories: the random smooth path's bounds and determinism, the spline through samples,
trajectory files (CSV / TOML) with errors that name the file, the row or point and the value,
and both new kinds flown by the simulator through the unchanged controller."""

from __future__ import annotations

import numpy as np
import pytest

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
    ("[[point\n", r"bad.toml: not valid TOML"),
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
