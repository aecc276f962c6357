"""The bridge's tick log is an IODataset: collect over the link -> load -> fit, no glue."""

from __future__ import annotations

import numpy as np
import pytest
from support.bridge_helpers import ROOT, free_port, read_json

from ddpc_codegen import IODataset, SteeringConfig
from firmware_bridge.ticklog import REASONS, TickRecorder, load_ticklog

pytestmark = pytest.mark.e2e

R = {r: i for i, r in enumerate(REASONS)}


def test_collect_log_reloads_as_an_iodataset(procs, tmp_path):
    port = free_port()
    log, summ = tmp_path / "flight.npz", tmp_path / "s.json"
    # The vehicle starts disarmed: the bridge arms it (--arm) and then switches to OFFBOARD (--offboard).
    veh = procs.spawn("vehicle", f"udpout:127.0.0.1:{port}", "--lockstep", "--start", "disarmed", name="vehicle")
    # ODOMETRY alone carries the whole state here (the other tests use ATTITUDE[_QUATERNION] + LOCAL_POSITION_NED).
    br = procs.spawn("bridge", f"udpin:127.0.0.1:{port}", "--lockstep", "--arm", "--offboard", "--mode", "collect",
                     "--attitude-stream", "odometry", "--position-stream", "odometry",
                     "--duration", "4", "--dataset-skip", "0.5", "--log", str(log), "--summary", str(summ),
                     "--timeout", "60", name="bridge")
    assert procs.wait(br, 90) == 0, procs.log(br)
    procs.terminate(veh)

    ds = IODataset.load(log)
    assert (ds.m, ds.p, ds.dt) == (2, 2, 0.005)
    assert ds.input_names == ("z_ref", "pitch_ref") and ds.output_names == ("z", "pitch")
    assert ds.input_units == ("m", "rad")
    assert ds.metadata["closed_loop"] is True and ds.metadata["source"] == "firmware_bridge.ticklog"
    # 4 s flown, 0.5 s skipped; the vehicle starts on the ground, so the first ticks are the bumpless
    # hand-over (blend, not data) from where it stands to the trajectory
    n_blend = int((load_ticklog(log).ticks["reason"] == R["blend"]).sum())
    assert n_blend > 0
    assert ds.n_samples == pytest.approx((4.0 - 0.5) / 0.005 - max(n_blend - 100, 0), abs=3)

    t = load_ticklog(log).ticks
    rows = np.concatenate([np.arange(a, b) for a, b in ds.metadata["segments_ticks"]])
    np.testing.assert_array_equal(np.concatenate(ds.u), t["u"][rows])
    np.testing.assert_array_equal(np.concatenate(ds.y), t["y"][rows])
    # u = nominal + PRBS, y is what the telemetry said, every sample a fresh off-board tick.
    np.testing.assert_allclose(t["u"][rows] - t["r_nom"][rows], t["excitation"][rows], atol=1e-12)
    assert np.all(np.abs(t["excitation"][rows]) > 0)
    assert np.all(t["reason"][rows] == R["collect"]) and np.all(t["active"][rows])
    assert np.allclose(np.diff(t["t_vehicle"][rows]), 0.005)
    # Everything else of the run is in the log as well (e.g. the pre-stream before OFFBOARD).
    assert np.any(t["reason"] == R["inactive"]) and np.all(np.isfinite(t["latency_us"][t["event"]]))

    # ... and the codegen front end fits a steering predictor on it as is.
    from ddpc_codegen.pipeline.solver_build import build_from_config

    cfg = SteeringConfig.from_toml(ROOT / "configs" / "flying.toml").replace(predictor={"method": "lsq"})
    prob = build_from_config(cfg, log)
    assert prob.predictor.n_columns > 0
    s = read_json(summ)
    assert s["reasons"]["collect"] >= ds.n_samples
    ev = [e for _, e in s["events"]]
    assert ev.index("arming (--arm), attempt 1") < min(i for i, e in enumerate(ev) if e.startswith("requesting OFFBOARD"))


def _log(reasons, *, gaps=(), t_traj=None):
    rec = TickRecorder(1, 1, capacity=4)
    for k, r in enumerate(reasons):
        i = rec.new_row()
        a = rec.arrays
        a["u"][i], a["y"][i] = k, -k
        a["reason"][i] = R[r]
        a["event"][i] = r != "hold"
        a["active"][i] = r in ("collect", "hold", "steered")
        a["valid"][i] = r in ("collect", "steered")
        a["gap"][i] = k in gaps
        a["t_traj"][i] = k * 0.005 if t_traj is None else t_traj[k]
    return rec.to_log(dt=0.005, input_names=("u",), output_names=("y",))


def test_segments_skip_hold_ticks_and_split_at_gaps_and_fallbacks():
    rs = ["inactive"] * 3 + ["collect"] * 10 + ["hold"] + ["collect"] * 10 + ["stale"] + ["collect"] * 12
    log = _log(rs, gaps=(30,))
    segs = log.segments(min_segment=5)
    # hold is transparent; the stale tick ends a run; the time-stamp gap at row 30 splits one.
    assert [list(s[[0, -1]]) for s in segs] == [[3, 23], [25, 29], [30, 36]]
    assert 13 not in segs[0]
    ds = log.to_dataset(min_segment=5)
    assert ds.lengths == (20, 5, 7)
    assert log.to_dataset(min_segment=6).lengths == (20, 7)
    assert log.to_dataset(skip=0.1, min_segment=1).lengths == (4, 5, 7)  # rows with t_traj < 0.1 s dropped


def test_a_log_without_closed_loop_data_still_saves_and_says_so(tmp_path):
    log = _log(["inactive"] * 20)
    path = log.save(tmp_path / "idle.npz")
    ds = IODataset.load(path)
    assert ds.metadata["closed_loop"] is False and ds.metadata["fit_ok"] is False
    assert "no closed-loop segment of >= 50 ticks" in ds.metadata["unfit_reason"]
    assert load_ticklog(path).n == 20


def test_codegen_refuses_a_log_marked_unfit(tmp_path):
    from ddpc_codegen.pipeline.solver_build import build_from_config
    from ddpc_codegen.errors import DataError

    path = _log(["inactive"] * 20).save(tmp_path / "idle.npz")
    cfg = SteeringConfig.from_toml(ROOT / "configs" / "flying.toml")
    with pytest.raises(DataError, match=r"idle.npz is marked unfit for fitting: the tick log has no closed-loop"):
        build_from_config(cfg, path)


def test_samples_are_saved_and_reloaded(tmp_path):
    log = _log(["collect"] * 60)
    log.samples = {"attitude": np.array([[0.004, 1.0], [0.008, 1.0001]]), "position": np.zeros((0, 2))}
    back = load_ticklog(log.save(tmp_path / "s.npz"))
    np.testing.assert_array_equal(back.samples["attitude"], log.samples["attitude"])
    assert back.samples["position"].shape == (0, 2)
