"""Issue 46 item 6: the bridge's outputs are never lost. The overwrite check looks at the file actually written
(``--log X``, ``X.log`` and ``X.NPZ`` write ``X.npz``), guards ``--summary`` alike, refuses ``--log`` and
``--summary`` naming one file, and refuses a FIFO, a device or a directory as an output -- each with exit 2 and
one line, before the link is opened (no vehicle contact)."""

from __future__ import annotations

import os

import pytest

import firmware_bridge.bridge as bridge_module
from ddpc_codegen.values.prefilter import PrefilterModel
from firmware_bridge.cli import bridge_main


@pytest.fixture
def no_link(monkeypatch):
    """Opening the link fails the test: every refusal below must come first."""
    class Refuse:
        def __init__(self, *_a, **_k):
            raise AssertionError("the link was opened")

        @classmethod
        def for_bridge(cls, *_a, **_k):
            raise AssertionError("the link was opened")
    monkeypatch.setattr(bridge_module, "MavLink", Refuse)


def _refused(capsys, *args: str) -> str:
    rc = bridge_main(["udpin:127.0.0.1:14999", "--mode", "passthrough", "--wait-heartbeat", "1", *args])
    err = capsys.readouterr().err
    assert rc == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("ddpc-bridge: error: "), err
    return lines[0]


@pytest.mark.parametrize("given", ["flight", "flight.log", "flight.NPZ", "flight.npz"])
def test_every_log_name_that_writes_an_existing_npz_is_refused(tmp_path, capsys, no_link, given):
    log = tmp_path / "flight.npz"
    log.write_bytes(b"precious")
    line = _refused(capsys, "--log", str(tmp_path / given))
    assert f"{log}: --log" in line and "exists; pass --overwrite" in line
    assert log.read_bytes() == b"precious"


def test_an_existing_summary_is_refused_without_overwrite(tmp_path, capsys, no_link):
    flight = tmp_path / "flight.npz"
    flight.write_bytes(b"precious")
    line = _refused(capsys, "--summary", str(flight))
    assert f"{flight}: --summary: exists; pass --overwrite" in line
    assert flight.read_bytes() == b"precious"


@pytest.mark.parametrize("log, summary", [("a.npz", "a.npz"), ("a", "a.npz"), ("a.log", "./a.npz")])
def test_log_and_summary_may_not_name_one_file(tmp_path, capsys, no_link, monkeypatch, log, summary):
    monkeypatch.chdir(tmp_path)
    line = _refused(capsys, "--log", log, "--summary", summary, "--overwrite")
    assert "--summary: the same file as --log" in line
    assert not (tmp_path / "a.npz").exists()


def test_fifos_devices_and_directories_are_refused_as_outputs(tmp_path, capsys, no_link):
    fifo = tmp_path / "pipe.json"
    os.mkfifo(fifo)
    (tmp_path / "dir.npz").mkdir()
    assert "is a FIFO (named pipe), not a regular file" in _refused(capsys, "--summary", str(fifo), "--overwrite")
    assert "is a directory, not a regular file" in _refused(capsys, "--log", str(tmp_path / "dir.npz"), "--overwrite")
    assert "is a character device, not a regular file" in _refused(capsys, "--summary", "/dev/null", "--overwrite")
    os.mkfifo(tmp_path / "pipe.npz")  # --log pipe.log writes pipe.npz: that is the path checked
    assert "is a FIFO (named pipe), not a regular file" in _refused(capsys, "--log", str(tmp_path / "pipe.log"),
                                                                     "--overwrite")


def test_a_fresh_log_and_summary_pass_and_leave_nothing_behind(tmp_path):
    from firmware_bridge.bridge_config import check_output_paths

    check_output_paths(str(tmp_path / "x.log"), str(tmp_path / "x.json"), overwrite=False)
    assert list(tmp_path.iterdir()) == []


def test_an_input_is_never_an_output(tmp_path, capsys, no_link):
    """``--summary pf.json`` beside ``--prefilter pf.json`` would replace the run's own input, --overwrite or not."""
    pf = PrefilterModel((1.0, 1.0), (0.0, 0.0), (0, 0), 0.005, ("z_ref", "pitch_ref")).save(tmp_path / "pf.json")
    before = pf.read_bytes()
    line = _refused(capsys, "--mode", "prefilter", "--prefilter", str(pf), "--summary", str(pf), "--overwrite")
    assert f"{pf}: --summary: the --prefilter file" in line and pf.read_bytes() == before
