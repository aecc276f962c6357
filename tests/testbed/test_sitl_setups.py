"""make sitl-demo's two estimation setups (testbed/sitl_setups.py, sitl_demo's --setups): the SITL parameters and
bridge arguments of each, the folders and the report's entry per autopilot, without a SITL."""

from __future__ import annotations

import json

import pytest

from ddpc_codegen.testbed import sitl_demo
from ddpc_codegen.testbed.mocap import MocapConfig
from ddpc_codegen.testbed.mocap_params import lab_params
from ddpc_codegen.testbed.sitl_flight import bridge_command
from ddpc_codegen.testbed.sitl_setups import (LAB_SOURCE, SETUPS, SetupSitl, describe_setup, flown_setup,
                                              setup_folder, setup_params)


class _Sitl:
    autopilot, url, sysid = "px4", "udpin:127.0.0.1:14540", 1

    def log_tail(self) -> str:
        return "(fake)"


def test_each_setup_starts_the_sitl_with_its_parameters():
    base = {"GUID_OPTIONS": 8}
    assert setup_params("ardupilot", "outdoor", base) == base and setup_params("px4", "outdoor", {}) == {}
    # ArduCopter's EKF fuses the mocap: the lab set at boot; PX4's build cannot, so its EKF keeps its own sensors
    assert setup_params("ardupilot", "lab", base) == {**base, **lab_params("ardupilot", MocapConfig())}
    assert setup_params("px4", "lab", {}) == {} and LAB_SOURCE == {"ardupilot": "autopilot", "px4": "mocap"}
    with pytest.raises(ValueError, match=r"unknown setup 'indoor'; choose from \('outdoor', 'lab'\)"):
        setup_params("px4", "indoor", {})


def test_the_setups_bridge_arguments_go_on_every_flight(tmp_path):
    fake = _Sitl()
    with flown_setup(fake, "px4", "outdoor") as sitl:  # outdoors: the SITL as it is, no stream
        assert sitl.mocap is None and sitl.bridge_args == () and sitl.url == fake.url and sitl.log_tail() == "(fake)"
        plain = bridge_command(sitl, "px4", "steer", tmp_path, 13.0, 150.0)
    assert plain == bridge_command(fake, "px4", "steer", tmp_path, 13.0, 150.0)
    lab = SetupSitl(fake, ("--mocap", "udpin:127.0.0.1:14600", "--position-source", "mocap"))
    cmd = bridge_command(lab, "px4", "steer", tmp_path, 13.0, 150.0, extra=("--trajectory", "s.csv"))
    assert cmd[-6:] == ["--trajectory", "s.csv", "--mocap", "udpin:127.0.0.1:14600", "--position-source", "mocap"]


def test_the_report_says_what_each_setup_measures_with():
    assert describe_setup("px4", "outdoor") == {"name": "outdoor", "position_source": "autopilot",
                                                "estimator": "PX4 EKF2 on its GPS, barometer and magnetometer"}
    lab = describe_setup("px4", "lab")
    assert lab["position_source"] == "mocap" and lab["estimator"].startswith("the motion capture itself")
    assert describe_setup("ardupilot", "lab")["position_source"] == "autopilot"
    assert [setup_folder("px4", s) for s in SETUPS] == ["sitl_px4", "sitl_px4_lab"]


def test_run_setups_flies_the_pipeline_once_per_setup_in_its_folder(monkeypatch, tmp_path):
    calls = []
    monkeypatch.setattr(sitl_demo, "run_pipeline", lambda ap, out, setup, **kw: calls.append((ap, out, setup, kw))
                        or {"setup": {"name": setup}})
    res = sitl_demo.run_setups("ardupilot", str(tmp_path), ["outdoor", "lab"], conditions=["steps"], rounds=1)
    assert list(res) == ["outdoor", "lab"] and res["lab"] == {"setup": {"name": "lab"}}
    assert calls == [("ardupilot", str(tmp_path / "sitl_ardupilot"), "outdoor", {"conditions": ["steps"], "rounds": 1}),
                     ("ardupilot", str(tmp_path / "sitl_ardupilot_lab"), "lab", {"conditions": ["steps"], "rounds": 1})]


def test_a_setup_not_flown_keeps_its_stored_figures():
    old = {"rmse_z": {"steered": 0.005}, "lab": {"rmse_z": {"steered": 0.002}}}
    assert sitl_demo.merge_setups(old, {"lab": {"rmse_z": {"steered": 0.001}}}) == {
        "rmse_z": {"steered": 0.005}, "lab": {"rmse_z": {"steered": 0.001}}}
    assert sitl_demo.merge_setups(old, {"outdoor": {"rmse_z": {"steered": 0.004}}}) == {
        "rmse_z": {"steered": 0.004}, "lab": {"rmse_z": {"steered": 0.002}}}
    assert sitl_demo.merge_setups(None, {"outdoor": {"x": 1}}) == {"x": 1}  # no lab yet: none added
    assert sitl_demo.merge_setups(None, {"lab": {"x": 1}}) == {"lab": {"x": 1}}


def test_the_demo_flies_the_chosen_setups_and_merges_them_into_the_report(monkeypatch, tmp_path, capsys):
    (tmp_path / "sitl.json").write_text(json.dumps({"px4": {"rmse_z": 1, "kept": True}, "adaptation": {"a": 1}}))
    jobs = {}

    def fly_autopilots(j, tag):
        jobs.update(j)
        return {"px4": {"lab": {"setup": {"name": "lab"}}}}, []

    monkeypatch.setattr(sitl_demo, "available_autopilots", lambda req, tag: ["px4"])
    monkeypatch.setattr(sitl_demo, "fly_autopilots", fly_autopilots)
    monkeypatch.setattr(sitl_demo, "print_result", lambda ap, res: print(f"result {ap}"))
    assert sitl_demo.main(["--out", str(tmp_path), "--setups", "lab", "--conditions", "none"]) == 0
    fn, kw, timeout = jobs["px4"]
    assert fn == "ddpc_codegen.testbed.sitl_demo:run_setups" and kw["setups"] == ["lab"]
    assert kw["out_dir"] == str(tmp_path) and timeout == 900
    report = json.loads((tmp_path / "sitl.json").read_text())
    assert report == {"px4": {"rmse_z": 1, "kept": True, "lab": {"setup": {"name": "lab"}}}, "adaptation": {"a": 1}}
    assert capsys.readouterr().out.splitlines()[-2:] == ["result px4", "result px4 lab"]
    with pytest.raises(SystemExit):
        sitl_demo.main(["--out", str(tmp_path), "--setups", "lab,indoor"])
    assert "--setups: choose from outdoor, lab; got 'lab,indoor'" in capsys.readouterr().err


def test_the_pipeline_refuses_an_unknown_setup_before_starting_a_sitl(tmp_path):
    with pytest.raises(ValueError, match="unknown setup 'attic'"):
        sitl_demo.run_pipeline("px4", str(tmp_path / "x"), setup="attic")
    assert not (tmp_path / "x").exists()
