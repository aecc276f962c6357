"""Desired trajectories from files (CSV or TOML), for in-process runs and the MAVLink bridge.

Both formats give samples of trajectory time ``t`` [s] (0 = start of the run / of off-board
flight; strictly increasing, >= 0) and position ``x``, ``z`` [m] (trajectory frame: x forward,
y left, z up), and optionally ``y`` [m] (a 3-D path; without it y = 0, the sagittal plane),
``yaw`` [rad] (heading in the trajectory frame, 0 = the heading at the start; without it 0) and
velocities ``vx``, ``vy``, ``vz`` [m/s] (each alone; without them the spline chooses them).
Between samples a cubic spline (:class:`SampledTrajectory`) gives continuous position and velocity
(natural spline: acceleration too; Hermite where velocities are given); the controller uses the
horizontal accelerations as its tilt feed-forward and the yaw as the commanded heading. Before
the first sample the first point is held, after the last the last.

CSV: a header row naming the columns (any order, ``t,x,z`` and any optional ones), one sample per
row; blank lines and lines starting with ``#`` are skipped::

    # t [s], x [m], y [m], z [m]: the start of a figure eight
    t,x,y,z
    0.0,0.0,0.0,1.0
    0.5,0.1,0.05,1.02

TOML: an array of tables ``[[point]]`` with keys t, x, z and any optional ones (the same set in
every point; optional top-level ``description``)::

    description = "a hop over the table"
    [[point]]
    t = 0.0
    x = 0.0
    z = 1.0

Every problem is a :class:`~ddpc_codegen.errors.ConfigError` that names the file, the row
(CSV line number) or the point index and key, and the offending value.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from ddpc_codegen.errors import ConfigError
from ddpc_codegen.robot.trajectory import EllipseTrajectory, RandomSmoothTrajectory, SampledTrajectory
from ddpc_codegen.values.files import MiB, checked_input_path, load_toml_bounded, read_text_bounded
from ddpc_codegen.values.tomlconfig import check_keys

__all__ = ["load_trajectory", "save_trajectory_csv", "trajectory_from_arg", "COLUMNS", "OPTIONAL_COLUMNS", "RANGES",
           "MIN_SPACING"]

COLUMNS = ("t", "x", "z")
OPTIONAL_COLUMNS = ("y", "yaw", "vx", "vy", "vz")
_ALL = COLUMNS + OPTIONAL_COLUMNS
# Physical ranges of the columns (a finite 1e308 still overflows the spline): time [s], positions [m],
# yaw [rad, unwrapped], velocities [m/s]; and the closest two samples may be [s].
RANGES = {"t": (0.0, 1e6, "s"), "x": (-1e4, 1e4, "m"), "y": (-1e4, 1e4, "m"), "z": (-1e4, 1e4, "m"),
          "yaw": (-1e3, 1e3, "rad"), "vx": (-100.0, 100.0, "m/s"), "vy": (-100.0, 100.0, "m/s"),
          "vz": (-100.0, 100.0, "m/s")}
MIN_SPACING = 1e-3
MAX_SAMPLES = 1_000_000
MAX_BYTES = 256 * MiB  # MAX_SAMPLES rows of every column at full precision (about 250 bytes a row)


def load_trajectory(path: str | Path) -> SampledTrajectory:
    """A :class:`SampledTrajectory` from a ``.csv`` or ``.toml`` file (format: module docstring)."""
    path = checked_input_path(path, "trajectory file", MAX_BYTES)
    suffix = path.suffix.lower()
    if suffix == ".csv":
        rows = _read_csv(path)
    elif suffix == ".toml":
        rows = _read_toml(path)
    else:
        raise ConfigError(f"trajectory file {path}: unknown format {path.suffix!r}; use .csv or .toml")
    return _build(rows, str(path))


def trajectory_from_arg(text: str):
    """A trajectory from a command-line value (e.g. the bridge's ``--trajectory``): ``ellipse`` (the
    default ellipse), ``random`` or ``random:SEED`` (:class:`RandomSmoothTrajectory`), or a .csv /
    .toml file path (:func:`load_trajectory`)."""
    name = text.strip()
    if name == "ellipse":
        return EllipseTrajectory()
    if name == "random" or name.startswith("random:"):
        seed = name.partition(":")[2] or "0"
        if not seed.lstrip("-").isdigit():
            raise ConfigError(f"trajectory {text!r}: the seed after 'random:' must be an integer; got {seed!r}")
        return RandomSmoothTrajectory(seed=int(seed))
    if Path(name).suffix.lower() in (".csv", ".toml") or Path(name).exists():
        return load_trajectory(name)
    raise ConfigError(f"trajectory {text!r}: expected 'ellipse', 'random[:SEED]' or a .csv / .toml file")


def save_trajectory_csv(path: str | Path, trajectory, t_end: float, dt: float = 0.05,
                        columns: tuple[str, ...] = COLUMNS) -> Path:
    """Write ``trajectory.sample`` on [0, t_end] every ``dt`` seconds as a trajectory CSV with
    ``columns`` (t, x, z and any of :data:`OPTIONAL_COLUMNS`)."""
    if not (dt > 0 and t_end > dt):
        raise ConfigError(f"save_trajectory_csv needs t_end > dt > 0; got t_end={t_end!r}, dt={dt!r}")
    bad = [c for c in columns if c not in _ALL]
    if bad or any(c not in columns for c in COLUMNS):
        raise ConfigError(f"save_trajectory_csv columns must include {list(COLUMNS)} and only {list(_ALL)}; "
                          f"got {list(columns)}")
    t = np.arange(0.0, t_end + 0.5 * dt, dt)
    d = {**trajectory.sample(t), "t": t}
    path = Path(path)
    with path.open("w", newline="") as f:
        f.write(f"# sampled from {type(trajectory).__name__}; t [s], positions [m], yaw [rad], velocities [m/s]\n")
        w = csv.writer(f)
        w.writerow(columns)
        for k in range(t.size):
            w.writerow([repr(float(d[c][k])) for c in columns])
    return path


# ----------------------------------------------------------------------------- parsing
def _number(text: object, where: str) -> float:
    """A finite float from a CSV cell or TOML value; ConfigError naming ``where`` otherwise."""
    if isinstance(text, bool):
        raise ConfigError(f"{where}: {text!r} is not a number")
    try:
        v = float(text.strip()) if isinstance(text, str) else float(text)  # type: ignore[arg-type]
    except (TypeError, ValueError, OverflowError):
        raise ConfigError(f"{where}: {text!r} is not a number") from None
    if not math.isfinite(v):
        raise ConfigError(f"{where}: {text!r} is not a finite number")
    return v


def _read_csv(path: Path) -> list[tuple[str, dict[str, float]]]:
    """[(where, {column: value})] per data row; ``where`` = 'FILE row N' (N = line number)."""
    lines = read_text_bounded(path, "trajectory file", MAX_BYTES).splitlines()
    header: list[str] | None = None
    rows = []
    for lineno, line in enumerate(lines, start=1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        try:
            cells = next(csv.reader([line]))
        except csv.Error as e:  # a cell longer than csv.field_size_limit() (128 KiB)
            raise ConfigError(f"{path} row {lineno}: {e}") from None
        if header is None:
            header = [c.strip().lower() for c in cells]
            missing = [c for c in COLUMNS if c not in header]
            unknown = [c for c in header if c not in _ALL]
            if unknown or missing or len(set(header)) != len(header):
                raise ConfigError(f"{path} row {lineno}: the header must name the columns {list(COLUMNS)} once each "
                                  f"(any order; optional: {list(OPTIONAL_COLUMNS)}); got {cells!r}"
                                  + (f"; unknown {unknown}" if unknown else "")
                                  + (f"; missing {missing}" if missing else ""))
            continue
        if len(cells) != len(header):
            raise ConfigError(f"{path} row {lineno}: expected {len(header)} values ({','.join(header)}); "
                              f"got {len(cells)}: {line.strip()!r}")
        vals = {h: _number(c, f"{path} row {lineno}, column {h!r}") for h, c in zip(header, cells)}
        rows.append((f"{path} row {lineno}", vals))
        if len(rows) > MAX_SAMPLES:
            raise ConfigError(f"{path}: more than {MAX_SAMPLES} samples; resample the trajectory")
    if header is None:
        raise ConfigError(f"{path}: empty; expected a header row {','.join(COLUMNS)} and samples")
    return rows


def _read_toml(path: Path) -> list[tuple[str, dict[str, float]]]:
    """[(where, {key: value})] per [[point]] table; ``where`` = 'FILE point[i]'."""
    raw = check_keys(load_toml_bounded(path, "trajectory file", MAX_BYTES), ("description", "point"), "top level:",
                     str(path))
    pts = raw.get("point")
    if not isinstance(pts, list) or not all(isinstance(p, dict) for p in pts):
        raise ConfigError(f"{path}: expected [[point]] tables with keys {list(COLUMNS)}; got point = {pts!r}")
    rows = []
    for i, p in enumerate(pts):
        where = f"{path} point[{i}]"
        unknown = [k for k in p if k not in _ALL]
        if unknown:
            raise ConfigError(f"{where}: unknown key(s) {unknown}; a point has {list(COLUMNS)} and optionally "
                              f"{list(OPTIONAL_COLUMNS)} (roll and pitch follow from the path through the controller)")
        missing = [c for c in COLUMNS if c not in p]
        if missing:
            raise ConfigError(f"{where}: missing key(s) {missing}; each point needs {list(COLUMNS)}")
        if i and set(p) != set(pts[0]):
            raise ConfigError(f"{where}: has keys {sorted(p)} but point[0] has {sorted(pts[0])}; "
                              "every point needs the same keys")
        rows.append((where, {c: _number(p[c], f"{where} key {c!r}") for c in p}))
    return rows


def _build(rows: list[tuple[str, dict[str, float]]], src: str) -> SampledTrajectory:
    if len(rows) < 2:
        raise ConfigError(f"{src}: a trajectory needs at least 2 samples; got {len(rows)}")
    prev_t, prev_where = -math.inf, ""
    for where, vals in rows:
        t = vals["t"]
        if t < 0:
            raise ConfigError(f"{where}: t = {t!r} is negative; trajectory time starts at 0")
        if t <= prev_t:
            raise ConfigError(f"{where}: t = {t!r} is not after t = {prev_t!r} (at {prev_where}); "
                              "times must be strictly increasing")
        if t - prev_t < MIN_SPACING:
            raise ConfigError(f"{where}: t = {t!r} is less than {MIN_SPACING:g} s after t = {prev_t!r} "
                              f"(at {prev_where}); resample the trajectory")
        for col, v in vals.items():
            lo, hi, unit = RANGES[col]
            if not lo <= v <= hi:
                raise ConfigError(f"{where}: {col} = {v!r} is outside [{lo:g}, {hi:g}] {unit}")
        prev_t, prev_where = t, where
    cols = {c: tuple(r[1][c] for r in rows) for c in _ALL if c in rows[0][1]}
    return SampledTrajectory(source=src, **cols)
