"""``ddpc-codegen front`` end to end: a dataset of a known loop, a config, a trajectory file -> the table,
the JSON, and precise refusals."""

from __future__ import annotations

import json

import numpy as np
import pytest

from support.lti import height_loop
from ddpc_codegen.cli.main import main
from ddpc_codegen.design.data import IODataset, prbs


def _files(tmp_path):
    u = prbs(1500, 2, amplitude=[0.3, 0.2], min_hold=3, seed=5) + [1.0, 0.0]
    y, _ = height_loop().simulate(u, np.array([1.0, 1.0, 0.0]))
    ds = IODataset(u, y, 0.005, input_names=["z_ref", "pitch_ref"], output_names=["z", "pitch"]).save(tmp_path / "d.npz")
    cfg = tmp_path / "c.toml"
    cfg.write_text('name = "loop"\n[horizon]\nt_ini = 6\nt_f = 30\n[signals]\ninputs = ["z_ref", "pitch_ref"]\n'
                   'outputs = ["z", "pitch"]\noutput_units = ["m", "rad"]\ninput_units = ["m", "rad"]\n'
                   '[cost]\nQ = [10.0, 1.0]\nR = [0.01, 1.0]\nR_du = [3.0, 0.0]\n[predictor]\nmethod = "lsq"\n')
    traj = tmp_path / "t.csv"
    t = np.arange(0.0, 3.0, 0.05)
    z = 1.0 + 0.2 * (t >= 1.0) * np.clip((t - 1.0) / 0.3, 0, 1)
    traj.write_text("t,x,z\n" + "".join(f"{a:.3f},0.0,{b:.4f}\n" for a, b in zip(t, z)))
    return cfg, ds, traj


def test_front_prints_the_table_and_writes_the_json(tmp_path, capsys):
    cfg, ds, traj = _files(tmp_path)
    out = tmp_path / "f.json"
    assert main(["front", str(cfg), "--dataset", str(ds), "--trajectory", str(traj), "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "z error RMS [m]" in text and "passthrough 1.00" in text and "steered " in text
    assert "step gain of the predictor as the plant" in text and "far apart" not in text  # exact: consistent
    rep = json.loads(out.read_text())
    front = rep["front"]
    assert rep["samples"] == 590 and len(front) == 31
    assert rep["step_gain"]["chained"] == pytest.approx(1.0, abs=1e-6) == rep["step_gain"]["predicted"]
    assert all(a["rate_ratio"] > b["rate_ratio"] and a["error_rms"] < b["error_rms"] for a, b in zip(front, front[1:]))
    pt, st = rep["passthrough"], rep["steered"]
    assert pt["rate_ratio"] == 1.0 and st["error_rms"] < 0.5 * pt["error_rms"]
    # neither beats the least error at its activity (the front interpolated between its points: 1 % slack)
    for p in (pt, st):
        assert p["error_rms"] >= 0.99 * p["front_error_at_this_rate"], p


def test_front_refuses_what_it_cannot_do(tmp_path, capsys):
    cfg, ds, traj = _files(tmp_path)
    assert main(["front", str(cfg), "--dataset", str(ds), "--trajectory", str(traj), "--output", "x"]) == 2
    assert "--output 'x' is not one of the config's outputs ['z', 'pitch']" in capsys.readouterr().err
    assert main(["front", str(cfg), "--dataset", str(ds), "--trajectory", str(traj), "--duration", "40"]) == 2
    assert "the front is dense" in capsys.readouterr().err
    assert main(["front", str(cfg), "--dataset", str(ds), "--trajectory", str(traj), "--duration", "-1"]) == 2
    assert "the trajectory's time span is 0 .. 2.95 s: give --duration (s, > 0)" in capsys.readouterr().err
    assert main(["front", str(cfg), "--dataset", str(ds), "--trajectory", str(traj), "--output", "pitch"]) == 2
    assert "the trajectory has no channel 'pitch'" in capsys.readouterr().err
