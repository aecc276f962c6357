"""The SITL harness: discovery through the environment, command lines, network isolation, and
(marked ``sitl``, skipped without the binaries) a real start -> heartbeat -> stop per autopilot."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from firmware_bridge import sitl as h


def test_discovery_reads_the_environment(tmp_path):
    binary = tmp_path / "arducopter"
    binary.write_text("#!/bin/sh\n")
    binary.chmod(0o755)
    (tmp_path / "px4" / "bin").mkdir(parents=True)
    (tmp_path / "px4" / "etc").mkdir()
    (tmp_path / "px4" / "bin" / "px4").write_text("")
    env = {h.ARDUPILOT_ENV: str(binary), h.PX4_ENV: str(tmp_path / "px4")}
    assert h.find_ardupilot(env) == binary
    assert h.find_px4(env) == tmp_path / "px4"
    assert h.find_ardupilot({}) is None and h.find_px4({h.PX4_ENV: str(tmp_path)}) is None


def test_missing_sitl_names_the_variable(monkeypatch):
    monkeypatch.delenv(h.ARDUPILOT_ENV, raising=False)
    monkeypatch.delenv(h.PX4_ENV, raising=False)
    assert h.ARDUPILOT_ENV in h.missing_reason("ardupilot")
    with pytest.raises(h.SitlError, match=h.PX4_ENV):
        h.make_sitl("px4")
    with pytest.raises(ValueError, match="unknown autopilot"):
        h.missing_reason("inav")


def test_command_lines(tmp_path):
    binary = tmp_path / "arducopter"
    (tmp_path / "copter.parm").write_text("FRAME_CLASS 1\n")
    s = h.Sitl.ardupilot(binary, params={"GUID_OPTIONS": 8}, instance=2)
    assert s.url == "tcp:127.0.0.1:5780" and "-I2" in s.argv and "-w" in s.argv
    assert s.argv[s.argv.index("--defaults") + 1].endswith("copter.parm,extra.parm")
    assert s.files["extra.parm"] == "GUID_OPTIONS 8\n"
    p = h.Sitl.px4(tmp_path, params={"MPC_THR_HOVER": 0.45, "IMU_INTEG_RATE": 400}, instance=1)
    assert p.url == "udpin:127.0.0.1:14541" and p.argv[-2:] == ["-i", "1"]
    assert p.env["PX4_PARAM_MPC_THR_HOVER"] == "0.45" and p.env["PX4_PARAM_IMU_INTEG_RATE"] == "400"
    assert p.env["PX4_SIM_MODEL"] == "sihsim_quadx"


def test_px4_link_farm_replaces_lost_symlinks(tmp_path):
    src = tmp_path / "bin"
    src.mkdir()
    (src / "px4").write_text("binary")
    (src / "px4-param").write_text("px4")  # a copy that lost its symlink
    (src / "px4-alias.sh").write_text("alias")
    h._px4_bin(src, tmp_path / "farm")
    assert os.readlink(tmp_path / "farm" / "px4-param") == "px4"
    assert (tmp_path / "farm" / "px4").resolve() == (src / "px4").resolve()
    assert (tmp_path / "farm" / "px4-alias.sh").read_text() == "alias"


def test_stop_ends_the_process_group_and_removes_the_workdir():
    s = h.Sitl("test", ["sh", "-c", "sleep 30 & sleep 30"], "udpin:127.0.0.1:1", 0)
    s.start()
    workdir = s.workdir
    assert s.proc.poll() is None
    rc = s.stop(grace=2.0)
    assert rc is not None and rc != 0 and not Path(workdir).exists()


def test_run_isolated_gives_a_private_loopback():
    if h.netns_command() is None:
        pytest.skip("no private network namespace on this machine (unshare -n / -rn not permitted)")
    res = h.run_isolated("sitl.isolated_funcs:netns_facts", {"tag": "x"}, timeout=30)
    assert res == {"tag": "x", "private": True, "interfaces": ["lo"]}
    assert not h.in_private_netns()


@pytest.mark.sitl
@pytest.mark.parametrize("autopilot", ["px4", "ardupilot"])
def test_sitl_starts_answers_and_stops(autopilot):
    why = h.missing_reason(autopilot)
    if why:
        pytest.skip(why)
    res = h.run_isolated("sitl.isolated_funcs:sitl_heartbeat", {"autopilot": autopilot}, timeout=120)
    assert res["autopilot"] == {"px4": 12, "ardupilot": 3}[autopilot] and res["type"] == 2
    assert res["heartbeat_s"] < 30
    assert 0.2 < res["value"] < 0.8  # hover thrust parameter
    assert res["rc"] and not Path(res["workdir"]).exists()
