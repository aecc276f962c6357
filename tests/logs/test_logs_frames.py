"""Derived log fields, channel specs, and the resampling rule (the frame math: tests/robot/test_frames.py)."""

from __future__ import annotations


import numpy as np
import pytest

from ddpc_codegen.errors import DataError
from ddpc_codegen.logs.fields import derive_field
from ddpc_codegen.robot.frames import quat_from_euler_array
from ddpc_codegen.logs.resample import (
    Notes,
    Series,
    build_segments,
    clean_series,
    covered_intervals,
    intersect_intervals,
    parse_channel_spec,
    resample_series,
    state_windows,
    uniform_grid,
)

pytestmark = pytest.mark.filterwarnings("ignore::ddpc_codegen.logs.LogImportWarning")

def test_derive_field_rules():
    q = quat_from_euler_array(0.1, -0.2, 0.3)[None, :]
    f = {"timestamp": np.array([1]), "q_d[0]": q[:, 0], "q_d[1]": q[:, 1], "q_d[2]": q[:, 2], "q_d[3]": q[:, 3],
         "position[2]": np.array([-2.5]), "thrust_body[2]": np.array([-0.6])}
    assert derive_field(f, "pitch", "t")[0][0] == pytest.approx(-0.2)
    assert derive_field(f, "z_up", "t")[0][0] == 2.5            # alias z -> position[2], then up
    assert derive_field(f, "thrust_body[2]_up", "t")[0][0] == pytest.approx(0.6)
    with pytest.raises(DataError, match=r"field 'foo' not found in t; fields: .*position\[2\].*derived: roll, pitch, yaw"):
        derive_field(f, "foo", "t")


def test_channel_spec_syntax():
    s = parse_channel_spec("trajectory_setpoint.z_up", "input")
    assert (s.name, s.source, s.instance, s.field, s.unit) == ("z_ref", "trajectory_setpoint", None, "z_up", "m")
    s = parse_channel_spec("vehicle_attitude.pitch", "output")
    assert (s.name, s.unit) == ("pitch", "rad")
    s = parse_channel_spec("h=vehicle_local_position@1.z_up:cm", "output")
    assert (s.name, s.instance, s.unit) == ("h", 1, "cm")
    s = parse_channel_spec("SET_ATTITUDE_TARGET@2.q[0]", "input")
    assert (s.name, s.source, s.instance, s.field, s.unit) == ("q0_ref", "SET_ATTITUDE_TARGET", 2, "q[0]", "")
    with pytest.raises(DataError, match="expected \\[NAME=\\]SOURCE"):
        parse_channel_spec("no_field_here", "input")


# ------------------------------------------------------------------ resampling rule
def _series(t, x, rule="linear", angle=False):
    return Series("c", "", "topic.c", np.asarray(t, np.int64), np.asarray(x, float), rule, angle)


def test_hold_takes_latest_sample_at_or_before_grid_time():
    s = _series([0, 10_000, 20_000], [1.0, 2.0, 3.0], "hold")
    g = uniform_grid(0, 20_001, 200.0)  # 0, 5000, ..., 20000 µs
    np.testing.assert_array_equal(g, [0, 5000, 10_000, 15_000, 20_000])
    np.testing.assert_array_equal(resample_series(s, g), [1, 1, 2, 2, 3])  # a tie takes the new value


def test_linear_interpolation_between_bracketing_samples():
    s = _series([0, 10_000, 20_000], [0.0, 1.0, 0.0])
    np.testing.assert_allclose(resample_series(s, np.array([0, 2500, 10_000, 17_500])), [0, 0.25, 1, 0.25])
    with pytest.raises(DataError, match="extrapolate"):
        resample_series(s, np.array([25_000]))


def test_intervals_and_windows():
    assert covered_intervals(np.array([0, 10, 20, 100, 110]), 30) == [(0, 21), (100, 111)]
    assert intersect_intervals([(0, 50), (60, 100)], [(10, 70)]) == [(10, 50), (60, 70)]
    w = state_windows(np.array([0, 10, 20, 30]), np.array([14, 14, 2, 14]), t_end_us=50)
    assert w == [(0, 20, 14), (20, 30, 2), (30, 51, 14)]
    w = state_windows(np.array([0, 10, 20, 30]), np.array([14, 14, 2, 14]), t_end_us=50, keep=lambda v: v == 14,
                      until_next=False)
    assert w == [(0, 11, 14), (30, 31, 14)]


def test_clean_series_errors_and_drops():
    notes = Notes()
    with pytest.raises(DataError, match=r"topic.c: timestamps go backwards: 0.020 s -> 0.015 s \(samples 2 -> 3\)"):
        clean_series(_series([0, 10_000, 20_000, 15_000], [0, 1, 2, 3]), origin_us=0, on_nan="drop", notes=notes)
    with pytest.warns(UserWarning, match=r"dropped 2 NaN/inf sample\(s\) at 0.010 s..0.020 s"):
        s = clean_series(_series([0, 10_000, 20_000, 30_000], [0, np.nan, np.inf, 3]), origin_us=0,
                         on_nan="drop", notes=notes)
    np.testing.assert_array_equal(s.t_us, [0, 30_000])
    with pytest.raises(DataError, match=r"2 NaN/inf value\(s\) at 0.010 s..0.020 s"):
        clean_series(_series([0, 10_000, 20_000, 30_000], [0, np.nan, np.inf, 3]), origin_us=0,
                     on_nan="error", notes=notes)
    with pytest.warns(UserWarning, match="repeated timestamp"):
        s = clean_series(_series([0, 10_000, 10_000], [0, 1, 2]), origin_us=0, on_nan="drop", notes=notes)
    np.testing.assert_array_equal(s.x, [0, 2])
    s = clean_series(_series([0, 1, 2], [3.0, -3.0, -2.9], angle=True), origin_us=0, on_nan="drop", notes=notes)
    assert s.x[1] == pytest.approx(2 * np.pi - 3.0)  # unwrapped, continuous through ±π


def test_build_segments_splits_at_gaps_and_drops_short_pieces():
    t = np.arange(0, 3_000_001, 10_000)
    keep = (t < 1_000_000) | (t > 1_500_000)  # a 0.5 s gap in the output
    u = _series(t, np.ones(t.size), "hold")
    y = _series(t[keep], np.arange(keep.sum()))
    with pytest.warns(UserWarning, match=r"1 gap\(s\) without samples, split there: 0.990 s..1.510 s"):
        segs = build_segments([u], [y], rate_hz=100, origin_us=0, notes=Notes())
    assert [(int(s.t_us[0]), int(s.t_us[-1])) for s in segs] == [(0, 990_000), (1_510_000, 3_000_000)]
    with pytest.raises(DataError, match=r"no usable segment in log: dropped 2 segment\(s\).*shorter than min_duration=5 s"):
        build_segments([u], [y], rate_hz=100, origin_us=0, notes=Notes(), min_duration_s=5)
