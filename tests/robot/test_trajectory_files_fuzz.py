"""Trajectory files mutated cell by cell (issue 28's fuzzing of every file kind the bridge flies on):
each is refused with a ConfigError naming the file, or loads into a trajectory whose samples are all
finite -- never a traceback, never a NaN flown. ``make fuzz`` draws 10 000 files."""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ddpc_codegen.errors import ConfigError
from ddpc_codegen.robot.trajectory_files import load_trajectory
from support.fuzz import fuzz_examples

_HEADER = ["t", "x", "y", "z", "yaw", "vz"]
_GOOD = [[0.0, 0.0, 0.0, 1.0, 0.0, 0.0], [1.0, 0.5, 0.1, 1.1, 0.2, 0.0],
         [2.0, 1.0, 0.2, 1.3, 0.4, 0.0], [3.0, 1.5, 0.0, 1.2, 0.0, 0.0]]
_CELLS = st.one_of(st.floats(allow_nan=True, allow_infinity=True).map(repr),
                   st.sampled_from(["", "nan", "inf", "-inf", "1e308", "-1e308", "abc", "0x10", "1,2", '"3"', "  "]),
                   st.text(max_size=6))


@settings(max_examples=fuzz_examples(400), deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(row=st.integers(-1, len(_GOOD)), col=st.integers(0, len(_HEADER) - 1), cell=_CELLS,
       drop_column=st.booleans())
def test_mutated_trajectory_files_are_refused_or_finite(tmp_path, row, col, cell, drop_column):
    rows = [list(map(repr, r)) for r in _GOOD]
    header = list(_HEADER)
    if row == -1:
        header[col] = cell            # a damaged header
    elif row == len(_GOOD):
        rows.append([cell] * (len(header) - 1))  # a short row
    else:
        rows[row][col] = cell
    if drop_column:
        header.pop(col)
        rows = [r[:col] + r[col + 1:] for r in rows]
    path = tmp_path / "traj.csv"
    path.write_text("\n".join(",".join(r) for r in [header, *rows]) + "\n")
    try:
        traj = load_trajectory(path)
    except ConfigError as e:
        assert str(path) in str(e) or "traj.csv" in str(e)
        return
    d = traj.sample(np.linspace(0.0, 3.0, 61))
    for key, v in d.items():
        assert np.all(np.isfinite(np.asarray(v, dtype=float))), (key, cell)


def test_out_of_range_values_and_too_close_samples_are_refused_with_the_row(tmp_path):
    path = tmp_path / "far.csv"
    path.write_text("t,x,z\n0,0,1\n1,1e308,1\n")
    try:
        load_trajectory(path)
        raise AssertionError("accepted x = 1e308")
    except ConfigError as e:
        assert str(e) == f"{path} row 3: x = 1e+308 is outside [-10000, 10000] m"
    path.write_text("t,x,z\n0,0,1\n0.0001,0,1.3\n")
    try:
        load_trajectory(path)
        raise AssertionError("accepted samples 0.1 ms apart")
    except ConfigError as e:
        assert str(e) == f"{path} row 3: t = 0.0001 is less than 0.001 s after t = 0.0 (at {path} row 2); " \
                         "resample the trajectory"
