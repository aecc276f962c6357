"""``ddpc-codegen import-ulog`` / ``import-tlog`` console commands."""

from __future__ import annotations

import argparse

import pytest
from tlog_writer import SyntheticMavlinkFlight
from ulog_writer import SyntheticFlight, write_ulog

from ddpc_codegen import IODataset
from ddpc_codegen.cli.logs import register


def _run(argv):
    """Run one of our subcommands through an argparse tree holding only this module's commands."""
    parser = argparse.ArgumentParser(prog="ddpc-codegen")
    register(parser.add_subparsers(dest="command"))
    args = parser.parse_args(argv)
    return args.func(args)


@pytest.fixture(scope="module")
def ulg(tmp_path_factory):
    return write_ulog(tmp_path_factory.mktemp("cli") / "flight.ulg", SyntheticFlight().topics())


def test_import_ulog_preset(ulg, tmp_path, capsys):
    out = tmp_path / "data.npz"
    assert _run(["import-ulog", str(ulg), "--preset", "pogox-flying", "--offboard-only", "-o", str(out)]) == 0
    ds = IODataset.load(out)
    assert ds.input_names == ("z_ref", "pitch_ref") and ds.n_trajectories == 2
    o = capsys.readouterr()
    assert f"wrote {out}: 2 trajectories, 1601 samples, dt=0.005 s (200 Hz)" in o.out
    assert "z_ref [m] <- trajectory_setpoint.z_up (hold)" in o.out
    assert "flight.ulg 8.000..11.000 s (601 samples, offboard)" in o.out
    assert "warning: flight.ulg:trajectory_setpoint.z_up is logged at ~50.0 Hz" in o.err


def test_import_ulog_explicit_channels_and_list(ulg, tmp_path, capsys):
    out = tmp_path / "p.npz"
    assert _run(["import-ulog", str(ulg), "--input", "pitch_ref=vehicle_attitude_setpoint.pitch",
                 "--output", "vehicle_attitude.pitch", "--rate", "100", "--time-range", "2", "5", "-o", str(out)]) == 0
    ds = IODataset.load(out)
    assert ds.dt == 0.01 and ds.input_names == ("pitch_ref",) and ds.output_names == ("pitch",)
    assert ds.metadata["time_range_s"] == [2.0, 5.0] and ds.lengths == (301,)
    capsys.readouterr()
    assert _run(["import-ulog", str(ulg), "--list"]) == 0
    assert "vehicle_attitude@0: 2501 samples, ~250.0 Hz: timestamp_sample, q[0]" in capsys.readouterr().out


def test_import_tlog_and_npz_passthrough(tmp_path, capsys):
    tl = SyntheticMavlinkFlight().writer().write(tmp_path / "f.tlog")
    out = tmp_path / "t.npz"
    assert _run(["import-tlog", str(tl), "--preset", "pogox-flying", "--sysid", "1", "-o", str(out)]) == 0
    assert IODataset.load(out).lengths == (2001,)
    assert _run(["import-tlog", str(out)]) == 0
    assert "already an IODataset (the bridge's log), no conversion needed" in capsys.readouterr().out
    assert _run(["import-tlog", str(tl), "--list"]) == 0
    assert "SET_ATTITUDE_TARGET@1 (component 191): 501 msgs, ~50.0 Hz" in capsys.readouterr().out


def test_errors_are_clean_messages_with_exit_code_2(ulg, tmp_path, capsys):
    from ddpc_codegen.cli.main import main

    rc = main(["import-ulog", str(ulg), "--input", "trajectory_setpoint.z_up", "--output", "vehicle_attitude.nope",
               "-o", str(tmp_path / "x.npz")])
    assert rc == 2
    err = capsys.readouterr().err
    assert err.startswith("ddpc-codegen import-ulog: error: field 'nope' not found in topic 'vehicle_attitude'")
    assert main(["import-ulog", str(ulg), "--preset", "pogox-flying"]) == 2
    assert "-o/--out DATA.npz is required" in capsys.readouterr().err
    assert not (tmp_path / "x.npz").exists()
