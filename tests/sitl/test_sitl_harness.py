"""The SITL harness: discovery through the environment, command lines, network isolation, and
(marked ``sitl``, skipped without the binaries) a real start -> heartbeat -> stop per autopilot."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from ddpc_codegen.testbed import sitl as h


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
    # PX4's rcS sets MAV_SYS_ID to instance + 1: every flight's bridge is told that system id.
    assert p.sysid == 2 and s.sysid == 1
    from ddpc_codegen.testbed.sitl_flight import bridge_command

    cmd = bridge_command(p, "px4", "passthrough", tmp_path, 5.0, 60.0)
    assert cmd[cmd.index("--target-system") + 1] == "2" and cmd[cmd.index("bridge") + 1] == p.url


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


def test_fly_ilc_learns_each_table_from_the_previous_flight(tmp_path, monkeypatch):
    """The ILC iterations of the SITL demo without a SITL: ``fly`` replaced by a loop whose height
    error is e0(t) + delta_z[j] (gain 1, no lead: the prefilter below is exact), so the table after
    the passthrough flight is -Q(e0) and the error left is what the 1 Hz Q-filter does not pass."""
    import numpy as np

    from ddpc_codegen.values.prefilter import PrefilterModel
    from ddpc_codegen.runtime.baselines import FeedforwardPolicy
    from ddpc_codegen.testbed import sitl_demo
    from firmware_bridge.ticklog import TickRecorder

    dt, dur = 0.005, 6.0
    e0 = lambda t: 0.05 + 0.03 * np.sin(2 * np.pi * 0.2 * t)  # noqa: E731

    def write_flight(name: str, delta) -> None:
        rec = TickRecorder(2, 2)
        for j in range(int(round(dur / dt)) + 1):
            i, a = rec.new_row(), rec.arrays
            a["t_traj"][i] = j * dt
            a["y_des"][i] = (1.0, 0.0)
            a["y"][i] = (1.0 + e0(j * dt) + (0.0 if delta is None else delta[j, 0]), 0.0)
            a["u"][i] = a["r_nom"][i] = (1.0, 0.0)
            a["sp_thrust"][i] = 0.4
            a["active"][i] = a["fresh"][i] = a["valid"][i] = True
        rec.to_log(dt=dt, input_names=("z_ref", "pitch_ref"), output_names=("z", "pitch")).save(
            tmp_path / f"ap_{name}.npz")

    calls = []

    def fake_fly(sitl, autopilot, mode, out, duration, *, extra=(), tag=None, **kw):
        calls.append((mode, duration, extra, tag))
        write_flight(tag, FeedforwardPolicy.load(extra[1]).delta)
        return {}

    monkeypatch.setattr(sitl_demo, "fly", fake_fly)
    write_flight("passthrough", None)
    pf = PrefilterModel((1.0, 1.0), (0.0, 0.0), (0, 0), dt).save(tmp_path / "pf.json")
    res = sitl_demo.fly_ilc(None, "ap", tmp_path, dur, pf, iterations=2)
    assert [(c[0], c[1], c[3]) for c in calls] == [("feedforward", dur, "ilc1"), ("feedforward", dur, "ilc2")]
    assert [c[2] for c in calls] == [("--feedforward", str(tmp_path / f"ilc_{i}.npz")) for i in (1, 2)]
    r = res["rmse_z_per_iteration"]
    assert r[0] == pytest.approx(np.sqrt(np.mean(e0(np.arange(600, 1201) * dt) ** 2)))  # after the 3 s settle
    assert r[1] < 0.02 * r[0] and r[2] <= r[1]
    assert res["rmse_z"] == r[2] and res["iterations_run"] == 2 and res["rmse_z_truth_per_iteration"] == [None] * 3
    with pytest.raises(ValueError, match="at least one iteration"):
        sitl_demo.fly_ilc(None, "ap", tmp_path, dur, pf, iterations=0)


@pytest.mark.parametrize("autopilot", ["px4", "ardupilot"])
def test_ctrl_ff_profile_is_the_autopilot_profile_with_velocity_feed_forward(tmp_path, autopilot):
    """The ctrl_ff flight flies the autopilot's own profile with only ref_velocity_gain changed."""
    import dataclasses

    from ddpc_codegen.robot.profile import load_profile
    from ddpc_codegen.testbed.sitl_demo import format_baselines
    from ddpc_codegen.testbed.sitl_flight import ctrl_ff_profile
    from ddpc_codegen.testbed.sitl_flight import PROFILES

    base, ff = load_profile(PROFILES[autopilot]), load_profile(ctrl_ff_profile(autopilot, tmp_path))
    assert ff.controller.ref_velocity_gain == 1.0 and base.controller.ref_velocity_gain in (None, 0.0)
    assert dataclasses.replace(ff.controller, ref_velocity_gain=base.controller.ref_velocity_gain) == base.controller
    assert ff.trajectory == base.trajectory
    b = {"rmse_z": {"passthrough": 0.08, "ctrl_ff": 0.05, "prefilter": 0.01, "ilc": 0.002, "steered": 0.005},
         "rmse_z_truth": {"passthrough": None},
         "ilc": {"rmse_z_per_iteration": [0.08, 0.002], "rmse_z_truth_per_iteration": [None, None],
                 "iterations_to_settle": 1, "iterations_run": 1}}
    assert "passthrough 80.0, ctrl ff 50.0, prefilter 10.0, ilc 2.0, steered 5.0 mm" in format_baselines(autopilot, b)


def test_free_px4_instance_skips_served_sockets_and_reuses_stale_ones(tmp_path):
    import socket

    pattern = str(tmp_path / "sock-{}")
    assert h.free_px4_instance(socket_path=pattern) == 0                  # nothing there
    live = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    live.bind(pattern.format(0))
    live.listen(1)
    stale = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    stale.bind(pattern.format(1))
    stale.close()                                                          # the file stays, nobody serves it
    try:
        assert h.free_px4_instance(socket_path=pattern) == 1
        with pytest.raises(h.SitlError, match=r"every PX4 instance 0\.\.0 is running on this machine"):
            h.free_px4_instance(limit=1, socket_path=pattern)
    finally:
        live.close()
