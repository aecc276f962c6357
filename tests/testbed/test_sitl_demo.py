"""make sitl-demo / make sitl-adapt's command-line plumbing: comma lists, the autopilots a run can fly, rescoring a
stored run from its tick logs."""

from __future__ import annotations

import json

import numpy as np
import pytest

from ddpc_codegen.testbed.sitl_demo import available_autopilots, comma_list, main


def test_comma_lists_drop_blanks_and_spaces():
    assert comma_list(" steps, wind,,heavy ") == ["steps", "wind", "heavy"] and comma_list(" , ") == []


def test_a_missing_sitl_is_said_and_skipped(monkeypatch, tmp_path, capsys):
    monkeypatch.setenv("DDPC_PX4_SITL", str(tmp_path / "no_px4"))
    monkeypatch.setenv("DDPC_ARDUPILOT_SITL", str(tmp_path / "no_arducopter"))
    assert available_autopilots(None, "sitl-x") == [] and available_autopilots(["px4"], "sitl-x") == []
    out = capsys.readouterr().out.splitlines()
    assert [ln.split(":")[0] for ln in out] == ["[sitl-x] px4", "[sitl-x] ardupilot", "[sitl-x] px4"]
    assert all(": skipped: " in ln for ln in out)


def test_rescore_without_a_run_names_the_missing_report(tmp_path, capsys):
    with pytest.raises(SystemExit) as e:
        main(["--rescore", "--out", str(tmp_path)])
    assert e.value.code == 2 and f"{tmp_path / 'sitl.json'} not found" in capsys.readouterr().err


def _steered_log(path, solve_us: float):
    """A 4 s tick log of steered ticks whose solver call took ``solve_us``."""
    from firmware_bridge.ticklog import TickRecorder, reason_code

    rec = TickRecorder(2, 2, capacity=800)
    for k in range(800):
        i = rec.new_row()
        a = rec.arrays
        a["t_traj"][i] = a["t_vehicle"][i] = 0.005 * k
        a["y"][i], a["y_des"][i] = (1.0 + 0.01 * np.sin(k), 0.0), (1.0, 0.0)
        a["u"][i] = a["r_nom"][i] = (1.0, 0.0)
        a["truth_position"][i] = (0.0, 0.0, 1.0 + 0.012 * np.cos(k))
        a["reason"][i], a["solve_us"][i] = reason_code("steered"), solve_us
        a["active"][i] = a["event"][i] = True
    rec.to_log(dt=0.005, input_names=("z_ref", "pitch_ref"), output_names=("z", "pitch")).save(path)


def test_rescore_scores_each_condition_flight_again_from_its_tick_log(tmp_path, capsys):
    """A stored run from before a figure existed: --rescore recomputes the rounds from the tick logs that are there
    (the steered flights' solve time appears; a flight without its log keeps its stored figures) and writes back."""
    from ddpc_codegen.testbed.sitl_conditions import METHODS

    folder = tmp_path / "sitl_ardupilot"
    folder.mkdir()
    for k, us in enumerate((200.0, 900.0)):
        _steered_log(folder / f"ardupilot_steps_steered_r{k}.npz", us)
    old = {"rmse_z": 0.01, "rmse_z_truth": 0.02, "estimator_rms": 0.008, "thrust_step_rms": 0.001,
           "max_ref_step": 0.004, "max_offset_step": 0.003, "fallbacks": 0}
    rounds = [{m: dict(old) for m in METHODS} for _ in range(2)]
    report = {"ardupilot": {"rmse_z": {"baseline": 0.08, "steered": 0.005}, "rmse_z_truth": {"baseline": None, "steered": None},
                            "engaged_fraction": 1.0, "rate_hz": 200.0, "fallbacks": 0, "wall_s": 1.0, "approach": {},
                            "conditions": {"steps": {"rounds": rounds}}}}
    (tmp_path / "sitl.json").write_text(json.dumps(report))
    assert main(["--rescore", "--out", str(tmp_path)]) == 0
    steps = json.loads((tmp_path / "sitl.json").read_text())["ardupilot"]["conditions"]["steps"]
    assert steps["solve_us_p99"]["steered"] == pytest.approx(900.0)  # the worst round's
    assert steps["solve_us_p99"]["prefilter"] is None  # no log: the stored figures, which had none
    assert steps["rounds"][0]["steered"]["rmse_z"] == pytest.approx(np.sqrt(np.mean(np.sin(np.arange(600, 800)) ** 2)) * 0.01,
                                                                    rel=1e-9)
    assert steps["rmse_z"]["passthrough"] == pytest.approx(0.01)
    assert "solve p99 in flight 0.90 ms" in capsys.readouterr().out
    assert steps["rounds"][0]["steered"]["ref_rate_ratio"] is None  # a path that does not move: no activity ratio
    assert steps["front"]["skipped"].startswith("not found: ")  # no collect flight and steps file in the folder


def test_steps_front_from_a_collect_tick_log_and_a_steps_file(tmp_path):
    """A collect flight of a known loop as the bridge logs it and the demo's steps file: the steering flown on
    the fitted predictor sits at or above the front, and the flown activity is looked up on it."""
    from support.lti import height_loop

    from ddpc_codegen.design.data import prbs
    from ddpc_codegen.testbed.sitl_conditions import write_steps_trajectory
    from ddpc_codegen.testbed.sitl_front import steps_front
    from firmware_bridge.ticklog import TickRecorder, reason_code

    n = 3000
    u = prbs(n, 2, amplitude=[0.3, 0.05], min_hold=4, seed=2) + [1.0, 0.0]
    y, _ = height_loop().simulate(u, np.array([1.0, 1.0, 0.0]))
    rec = TickRecorder(2, 2, capacity=n)
    for k in range(n):
        i = rec.new_row()
        a = rec.arrays
        a["t_traj"][i] = a["t_vehicle"][i] = 0.005 * k
        a["y"][i], a["u"][i], a["r_nom"][i], a["y_des"][i] = y[k], u[k], (1.0, 0.0), (1.0, 0.0)
        a["reason"][i] = reason_code("collect")
        a["active"][i] = a["event"][i] = a["valid"][i] = True  # valid: a dataset row (engaged, fresh, collecting)
    rec.to_log(dt=0.005, input_names=("z_ref", "pitch_ref"), output_names=("z", "pitch")).save(
        tmp_path / "ardupilot_collect.npz")
    write_steps_trajectory(tmp_path / "steps.csv")
    cfg = tmp_path / "c.toml"
    cfg.write_text('name = "loop"\n[horizon]\nt_ini = 6\nt_f = 30\n[signals]\ninputs = ["z_ref", "pitch_ref"]\n'
                   'outputs = ["z", "pitch"]\n[cost]\nQ = [10.0, 1.0]\nR = [0.01, 1.0]\nR_du = [30.0, 0.0]\n'
                   '[predictor]\nmethod = "lsq"\n')
    f = steps_front(tmp_path, "ardupilot", cfg, 0.9, duration=6.0)
    st = f["model"]["steered"]
    assert f["model"]["samples"] == 1200 and st["error_rms"] < 0.5 * f["model"]["passthrough"]["error_rms"]
    assert st["error_rms"] >= 0.99 * st["front_error_at_this_rate"]
    assert f["flown_rate_ratio"] == 0.9 and 0 < f["front_at_flown"] < f["model"]["passthrough"]["error_rms"]
