"""``ddpc-proxy``'s steering options refuse bad input before anything is opened: exit 2 and one line naming the
option (the proxy never starts forwarding on a half-checked command line)."""

from __future__ import annotations

import re

import pytest

from firmware_bridge.proxy.cli import main
from firmware_bridge.proxy.steering import check_proxy_solver


def _refused(capsys, *argv: str) -> str:
    assert main(["--app", "udpin:127.0.0.1:0", "--vehicle", "udpout:127.0.0.1:9", *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("ddpc-proxy: "), err
    return err


@pytest.mark.parametrize("argv, says", [
    (["--preview-delay", "-1"], "--preview-delay must be a finite number >= 0"),
    (["--preview-delay", "nan"], "--preview-delay must be a finite number >= 0"),
    (["--dither", "-0.1"], "--dither must be a finite number >= 0"),
    (["--dither", "inf"], "--dither must be a finite number >= 0"),
    (["--dither", "0.1", "--max-age", "0"], "--max-age must be a finite number of seconds > 0"),
    (["--dither", "0.1", "--dither-hold", "0"], "--dither-hold must be at least 1 setpoint"),
    (["--dither", "0.1", "--max-step", "-1"], "--max-step must be a finite number of metres > 0"),
    (["--dither", "0.1", "--model-watch=-1"], "--model-watch must be 0 (off) or a finite ratio > 1"),
    (["--dither", "0.1", "--model-watch", "1"], "--model-watch must be 0 (off) or a finite ratio > 1"),
    (["--dither", "0.1", "--model-watch", "inf"], "--model-watch must be 0 (off) or a finite ratio > 1"),
    (["--dither", "0.1", "--model-watch", "nan"], "--model-watch must be 0 (off) or a finite ratio > 1"),
    (["--mocap", "udpin:127.0.0.1:0"], "they go with --position-source mocap"),
    (["--mocap-offset", "0.3"], "they go with --position-source mocap"),
    (["--position-source", "mocap"], "--position-source mocap needs the link the poses arrive on"),
    (["--position-source", "mocap", "--mocap", "udpout:127.0.0.1:9"], "the vehicle's link"),
    (["--position-source", "mocap", "--mocap", "udpin:127.0.0.1:0", "--mocap-offset", "nan"],
     "--mocap-offset must be a finite number"),
    (["--position-source", "mocap", "--mocap", "bogus:x"], "--mocap bogus:x"),
    (["--max-jerk=-5"], "--max-jerk must be a finite number of m/s^3 > 0"),
    (["--max-jerk", "nan"], "--max-jerk must be a finite number of m/s^3 > 0"),
    (["--max-jerk", "5", "--dither", "0.1", "--z-feedforward", "zero"], "--z-feedforward zero sends none"),
])
def test_bad_values_are_refused_with_the_option_named(capsys, argv, says):
    assert says in _refused(capsys, *argv)


def test_dither_with_steer_and_an_existing_collect_file_are_refused(capsys, tmp_path):
    assert "does not go with --steer" in _refused(capsys, "--steer", str(tmp_path), "--dither", "0.1")
    kept = tmp_path / "collect.npz"
    kept.write_bytes(b"a flight")
    assert "pass --overwrite" in _refused(capsys, "--collect", str(kept))
    assert kept.read_bytes() == b"a flight"  # nothing recorded is lost


def test_a_folder_without_a_solver_is_refused(capsys, tmp_path):
    err = _refused(capsys, "--steer", str(tmp_path))
    assert err == f"ddpc-proxy: {tmp_path} has no manifest.json: not a generated solver (run `ddpc-codegen codegen` first)"


class _Manifest:
    """A solver as the proxy reads it before steering: its manifest only."""

    def __init__(self, inputs, outputs, dt=0.02):
        self.manifest = {"dims": {"m": len(inputs), "p": len(outputs)},
                         "signals": {"inputs": inputs, "outputs": outputs, "dt": dt}}


@pytest.mark.parametrize("inputs, outputs, dt, says", [
    (["z_ref", "pitch_ref"], ["z", "pitch"], 0.005, "this one has inputs ['z_ref', 'pitch_ref']"),
    (["z_ref"], ["z_error"], 0.02, "outputs ['z_error']"),
    (["z_offset"], ["z_error"], None, "no signals.dt"),
])
def test_a_solver_that_does_not_steer_a_height_loop_is_refused(inputs, outputs, dt, says):
    with pytest.raises(ValueError, match=re.escape(says)):
        check_proxy_solver(_Manifest(inputs, outputs, dt))


def test_the_solver_names_its_coordinates():
    assert check_proxy_solver(_Manifest(["z_ref"], ["z"])) == (0.02, "absolute")
    assert check_proxy_solver(_Manifest(["z_offset"], ["z_error"], 0.01)) == (0.01, "deviation")
