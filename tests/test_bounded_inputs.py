"""Bounded inputs (issue #46 item 7, the input half of item 6), through the public readers and the command
lines: a FIFO, /dev/zero behind a symlink, a file over its cap, 100k-deep nesting, a 401-digit integer, a CSV
cell over 128 KiB, a self-referencing ULog format, a sweep too large to expand, ``codegen --out <file>`` --
each refused with one line ``<file>: <key>: <message>`` (exit 2 from the CLIs), never a traceback, a hang or
an unbounded read. The reader itself: tests/values/test_files.py."""

from __future__ import annotations

import json
import struct
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ddpc_codegen.cli.main import main as codegen_main
from ddpc_codegen.errors import DataError, ManifestError
from ddpc_codegen.experiments.sweep import read_results
from ddpc_codegen.experiments.sweep_spec import MAX_POINTS, SweepSpec
from ddpc_codegen.logs import import_ulog
from ddpc_codegen.robot.profile import load_profile
from ddpc_codegen.robot.trajectory_files import load_trajectory
from ddpc_codegen.runtime.baselines import FeedforwardPolicy, PrefilterPolicy
from ddpc_codegen.runtime.loader import load_solver
from ddpc_codegen.values.config import SteeringConfig
from ddpc_codegen.values.files import MAX_TEXT_BYTES
from firmware_bridge.baseline_modes import load_prefilter
from support.bounded import bounded_refusal, make_fifo, needs_dev_zero, needs_fifo, refusal, within

ROOT = Path(__file__).resolve().parent.parent
FLYING = ROOT / "configs" / "flying.toml"
BIG = "9" * 401  # a 401-digit integer: float() of it raises OverflowError
FAR = "an integer of 401 digits, beyond the range of any number a {} holds (±1.8e308)"
PREFILTER = {"prefilter": {"gain": [1.0, 1.0], "offset": [0.0, 0.0], "lead": [1, 1], "dt": 0.005}}


def _zero(path: Path) -> Path:
    path.symlink_to("/dev/zero")
    return path


def _sparse(path: Path, size: int) -> Path:
    """A file of ``size`` bytes that takes no disk (its size is all the check reads)."""
    with open(path, "wb") as f:
        f.truncate(size)
    return path


# ----------------------------------------------------------------------------- steering configs
@needs_fifo
@needs_dev_zero
def test_a_steering_config_that_is_no_file_is_refused_before_reading(tmp_path):
    fifo, unblock = make_fifo(tmp_path / "fifo.toml")
    assert bounded_refusal(SteeringConfig.from_toml, fifo, unblock=unblock) == \
        f"{fifo}: steering config: is a FIFO (named pipe), not a regular file"
    zero = _zero(tmp_path / "zero.toml")
    assert bounded_refusal(SteeringConfig.from_toml, zero) == \
        f"{zero}: steering config: is a character device, not a regular file"
    huge = _sparse(tmp_path / "huge.toml", MAX_TEXT_BYTES + 1)
    assert refusal(SteeringConfig.from_toml, huge) == \
        f"{huge}: steering config: {MAX_TEXT_BYTES + 1} bytes, more than a steering config may have ({MAX_TEXT_BYTES} bytes)"


@pytest.mark.parametrize("edit, message", [
    (lambda t: t + "\nx = " + "[" * 100_000 + "]" * 100_000 + "\n",
     "steering config: nested 100000 levels deep, more than a steering config may be (32)"),
    (lambda t: t.replace("R = [0.5, 20.0]", f"R = [{BIG}, 20.0]"), "cost.R[0]: " + FAR.format("steering config")),
    (lambda t: t.replace("ridge = 1e-4", f"ridge = -{BIG}"), "predictor.ridge: " + FAR.format("steering config")),
])
def test_steering_config_nesting_and_integers_are_bounded(tmp_path, edit, message):
    path = tmp_path / "cfg.toml"
    path.write_text(edit(FLYING.read_text()))
    assert refusal(SteeringConfig.from_toml, path) == f"{path}: {message}"


# ----------------------------------------------------------------------------- robot side
def test_robot_profile_probes(tmp_path):
    big = tmp_path / "big.toml"
    big.write_text(f'extends = "pogox"\n[controller]\nkp_z = {BIG}\n')
    assert refusal(load_profile, big) == f"{big}: controller.kp_z: " + FAR.format("robot profile")
    zero = _zero(tmp_path / "zero.toml")
    assert bounded_refusal(load_profile, zero) == f"{zero}: robot profile: is a character device, not a regular file"


@settings(max_examples=5, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(extra=st.integers(1, 64 * 1024))
def test_a_csv_cell_over_128_kib_is_a_row_error(tmp_path, extra):
    path = tmp_path / "cell.csv"
    path.write_text("t,x,z\n0,0,0\n0.1,0," + "1" * (128 * 1024 + extra) + "\n")
    assert refusal(load_trajectory, path) == f"{path} row 3: field larger than field limit (131072)"


def test_trajectory_numbers_beyond_float_range(tmp_path):
    csv = tmp_path / "big.csv"
    csv.write_text(f"t,x,z\n0,0,0\n0.1,0,{BIG}\n")
    assert refusal(load_trajectory, csv) == f"{csv} row 3, column 'z': '{BIG}' is not a finite number"
    toml = tmp_path / "big.toml"
    toml.write_text(f"[[point]]\nt = 0\nx = 0\nz = 0\n[[point]]\nt = 0.1\nx = 0\nz = {BIG}\n")
    assert refusal(load_trajectory, toml) == f"{toml}: point[1].z: " + FAR.format("trajectory file")


@needs_fifo
def test_a_trajectory_fifo_is_refused_without_waiting(tmp_path):
    fifo, unblock = make_fifo(tmp_path / "path.csv")
    assert bounded_refusal(load_trajectory, fifo, unblock=unblock) == \
        f"{fifo}: trajectory file: is a FIFO (named pipe), not a regular file"


def test_prefilter_probes(tmp_path):
    big = tmp_path / "big.json"
    big.write_text(json.dumps(PREFILTER).replace("[1.0, 1.0]", f"[{BIG}, 1.0]", 1))
    assert refusal(PrefilterPolicy.load, big) == f"{big}: prefilter.gain[0]: " + FAR.format("prefilter")
    assert refusal(load_prefilter, str(big), 200.0, 2, error=ValueError) == \
        f"--prefilter {big}: prefilter.gain[0]: " + FAR.format("prefilter")
    deep = tmp_path / "deep.json"
    deep.write_text('{"prefilter": ' + "[" * 100_000 + "]" * 100_000 + "}")
    assert refusal(PrefilterPolicy.load, deep) == \
        f"{deep}: prefilter: nested 100001 levels deep, more than a prefilter may be (32)"


@needs_fifo
@needs_dev_zero
def test_feedforward_tables_that_are_no_file(tmp_path):
    zero = _zero(tmp_path / "zero.npz")
    assert bounded_refusal(FeedforwardPolicy.load, zero) == \
        f"{zero}: feed-forward table: is a character device, not a regular file"
    fifo, unblock = make_fifo(tmp_path / "ff.npz")
    assert bounded_refusal(FeedforwardPolicy.load, fifo, unblock=unblock) == \
        f"{fifo}: feed-forward table: is a FIFO (named pipe), not a regular file"


@needs_fifo
@needs_dev_zero
def test_a_manifest_that_is_no_file_is_refused(tmp_path):
    zero = _zero(tmp_path / "manifest.json")
    assert bounded_refusal(load_solver, tmp_path, error=ManifestError) == \
        f"{zero}: manifest: is a character device, not a regular file"
    zero.unlink()
    fifo, unblock = make_fifo(tmp_path / "manifest.json")
    assert bounded_refusal(load_solver, tmp_path, error=ManifestError, unblock=unblock) == \
        f"{fifo}: manifest: is a FIFO (named pipe), not a regular file"


# ----------------------------------------------------------------------------- logs
def _selfref_ulog(path: Path) -> Path:
    """A ULog whose one format has a field of its own type (pyulog expands formats recursively)."""
    def msg(kind: str, payload: bytes) -> bytes:
        return struct.pack("<HB", len(payload), ord(kind)) + payload

    path.write_bytes(b"ULog\x01\x12\x35\x01" + struct.pack("<Q", 0) + msg("B", bytes(40))
                     + msg("F", b"loop:uint64_t timestamp;loop x;") + msg("A", struct.pack("<BH", 0, 1) + b"loop")
                     + msg("D", struct.pack("<H", 1) + bytes(16)))
    return path


def test_a_self_referencing_ulog_format_is_refused(tmp_path):
    path = _selfref_ulog(tmp_path / "loop.ulg")
    assert refusal(import_ulog, path, preset="pogox-flying", error=DataError) == \
        f"{path}: ULog format: a message format contains itself (directly or through others); not a readable ULog file"


# ----------------------------------------------------------------------------- sweeps
def _spec(tmp_path: Path, sweep: str = "", space: str = "") -> Path:
    path = tmp_path / "spec.toml"
    path.write_text(f'[sweep]\nconfig = "{FLYING}"\n{sweep}\n[space]\n{space}\n')
    return path


def test_a_grid_too_large_to_expand_is_refused_before_expanding(tmp_path):
    values = "[" + ", ".join(str(1e-4 * (i + 1)) for i in range(10**4)) + "]"
    path = _spec(tmp_path, space=f'"predictor.ridge" = {values}\n"predictor.rcond" = {values}\n'
                                 f'"cost.R_du" = [[1.0, 1.0], [2.0, 2.0], [3.0, 3.0]]')
    msg = within(10.0, refusal, SweepSpec.from_toml, path)
    assert msg == (f"{path}: [space] makes 300000001 points ((300000000 configurations + the baseline) x 1 conditions "
                   f"x 1 seeds), more than a sweep may have ({MAX_POINTS}); split the sweep or use search = \"random\"")


@settings(max_examples=6, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(seeds=st.integers(1, 2 * MAX_POINTS), samples=st.integers(1, 10**9), baseline=st.booleans())
def test_random_sweep_point_count_is_checked_from_the_spec(tmp_path, seeds, samples, baseline):
    path = _spec(tmp_path, f'search = "random"\nsamples = {samples}\nbaseline = {str(baseline).lower()}\n'
                           f"seeds = [{', '.join(map(str, range(seeds)))}]", '"predictor.ridge" = [1e-4, 1e-3]')
    total = (samples + baseline) * seeds
    if total <= MAX_POINTS:
        assert len(SweepSpec.from_toml(path).points()) == total
    else:
        key = "[sweep] seeds" if seeds >= samples else "[sweep] samples"
        assert refusal(SweepSpec.from_toml, path).startswith(f"{path}: {key} makes {total} points")


@needs_fifo
def test_a_resumed_sweep_reads_its_table_bounded(tmp_path):
    table = tmp_path / "results.csv"
    table.write_text("index,variant\n0," + "x" * (128 * 1024 + 1) + "\n")
    assert refusal(read_results, table) == \
        f"{table}: sweep results: field larger than field limit (131072); choose another --out"
    table.unlink()
    fifo, unblock = make_fifo(table)
    assert bounded_refusal(read_results, fifo, unblock=unblock) == \
        f"{fifo}: sweep results: is a FIFO (named pipe), not a regular file"


# ----------------------------------------------------------------------------- command lines
def _cli(args: list[str], capsys) -> tuple[int, str]:
    rc = within(20.0, codegen_main, args)
    err = capsys.readouterr().err.strip()
    return rc, err


@needs_fifo
@needs_dev_zero
def test_ddpc_codegen_refuses_with_exit_2_and_one_line(tmp_path, capsys):
    afile = tmp_path / "afile"
    afile.write_text("")
    assert _cli(["codegen", str(FLYING), "--out", str(afile)], capsys) == \
        (2, f"ddpc-codegen codegen: error: {afile}: --out: is a regular file, not a folder")
    assert _cli(["codegen", str(FLYING), "--out", str(afile / "sub")], capsys) == \
        (2, f"ddpc-codegen codegen: error: {afile / 'sub'}: --out: {afile} is a regular file, not a folder")
    assert _cli(["sweep", str(_spec(tmp_path)), "--out", str(afile)], capsys) == \
        (2, f"ddpc-codegen sweep: error: {afile}: --out: is a regular file, not a folder")
    zero = _zero(tmp_path / "zero.toml")
    assert _cli(["codegen", str(zero)], capsys) == \
        (2, f"ddpc-codegen codegen: error: {zero}: steering config: is a character device, not a regular file")
    fifo, unblock = make_fifo(tmp_path / "fifo.toml")
    try:
        assert _cli(["sweep", str(fifo)], capsys) == \
            (2, f"ddpc-codegen sweep: error: {fifo}: sweep spec: is a FIFO (named pipe), not a regular file")
    finally:
        unblock()
    ulog = _selfref_ulog(tmp_path / "loop.ulg")
    rc, err = _cli(["import-ulog", str(ulog), "--preset", "pogox-flying", "-o", str(tmp_path / "d.npz")], capsys)
    assert rc == 2 and err.endswith(f"{ulog}: ULog format: a message format contains itself (directly or through "
                                    "others); not a readable ULog file") and "\n" not in err, err


@needs_fifo
@needs_dev_zero
@pytest.mark.parametrize("flag, name, message", [
    ("--profile", "fifo.toml", "robot profile: is a FIFO (named pipe), not a regular file"),
    ("--trajectory", "zero.csv", "trajectory file: is a character device, not a regular file"),
    ("--prefilter", "fifo.json", "prefilter: is a FIFO (named pipe), not a regular file"),
    ("--feedforward", "zero.npz", "feed-forward table: is a character device, not a regular file"),
    ("--solver", "solver", "manifest: is a FIFO (named pipe), not a regular file"),
])
def test_ddpc_bridge_refuses_files_that_are_no_file_with_exit_2(tmp_path, flag, name, message):
    """A process of its own: a regression would block in open(), and the timeout ends it."""
    path = tmp_path / name
    if name.startswith("zero"):
        _zero(path)
    elif name == "solver":
        path.mkdir()
        make_fifo(path / "manifest.json")
    else:
        make_fifo(path)
    mode = {"--prefilter": ["--mode", "prefilter"], "--feedforward": ["--mode", "feedforward"],
            "--solver": ["--mode", "steer"]}.get(flag, ["--mode", "passthrough"])
    res = subprocess.run([sys.executable, "-m", "firmware_bridge.cli", "udpin:127.0.0.1:14999", flag, str(path), *mode,
                          "--wait-heartbeat", "1"], capture_output=True, text=True, timeout=60, cwd=tmp_path)
    where = path / "manifest.json" if name == "solver" else path
    prefix = f"{flag} " if flag in ("--prefilter", "--feedforward") else ""
    assert (res.returncode, res.stderr.strip()) == (2, f"ddpc-bridge: error: {prefix}{where}: {message}")


@pytest.mark.parametrize("flag, name, text, message", [
    ("--prefilter", "big.json", json.dumps(PREFILTER).replace("[1.0, 1.0]", f"[{BIG}, 1.0]", 1),
     "prefilter.gain[0]: " + FAR.format("prefilter")),
    ("--profile", "big.toml", f'extends = "pogox"\n[controller]\nkp_z = {BIG}\n',
     "controller.kp_z: " + FAR.format("robot profile")),
    ("--trajectory", "cell.csv", "t,x,z\n0,0,0\n0.1,0," + "1" * (128 * 1024 + 1) + "\n",
     "row 3: field larger than field limit (131072)"),
    ("--trajectory", "deep.toml", "x = " + "[" * 100_000 + "]" * 100_000,
     "trajectory file: nested 100000 levels deep, more than a trajectory file may be (32)"),
])
def test_ddpc_bridge_refuses_file_contents_with_exit_2_and_one_line(tmp_path, capsys, flag, name, text, message):
    from firmware_bridge.cli import bridge_main  # the bridge's own entry point, in this (main) thread

    path = tmp_path / name
    path.write_text(text)
    mode = ["--mode", "prefilter"] if flag == "--prefilter" else ["--mode", "passthrough"]
    assert bridge_main(["udpin:127.0.0.1:14999", flag, str(path), *mode, "--wait-heartbeat", "1"]) == 2
    prefix = f"{flag} " if flag == "--prefilter" else ""
    sep = " " if message.startswith("row") else ": "
    assert capsys.readouterr().err.strip() == f"ddpc-bridge: error: {prefix}{path}{sep}{message}"


def test_caps_are_generous_for_real_files():
    """The shipped configs and profiles are far inside their caps."""
    for path in [*ROOT.glob("configs/*.toml"), *(ROOT / "ddpc_codegen" / "robot" / "profiles").glob("*.toml")]:
        assert path.stat().st_size < MAX_TEXT_BYTES // 100
