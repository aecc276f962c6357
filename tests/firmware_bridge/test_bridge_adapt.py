"""ddpc-bridge --adapt: online predictor updates from steered ticks only, every update and re-solve in the
tick log's ``adapt`` column and the summary, the norm of the output offset in use in ``adapt_offset`` (over
real UDP sockets with the simulated vehicle)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ddpc_codegen.runtime.adapt_loop import ADAPT_CODES, SNAP_BUSY, SNAP_TAKEN, UPDATE_CODES, VERDICT_CODES
from firmware_bridge.ticklog import REASONS, load_ticklog
from support.bridge_helpers import ROOT, free_port, read_json


@pytest.fixture(scope="module")
def adaptive_solver(tmp_path_factory) -> Path:
    """The bridge's flying solver recipe with [adapt] enabled and the output offset on (a re-solve every 100)."""
    from ddpc_codegen import SteeringConfig, SteeringProblem, fit_predictor, generate
    from ddpc_codegen.sim import simulate

    ds = simulate("flying", 30.0, excitation=True, seed=11, noise=True).to_dataset()
    cfg = SteeringConfig.from_toml(ROOT / "configs" / "flying.toml").replace(
        predictor={"method": "lsq", "ridge": 1e-4},
        adapt={"enabled": True, "forgetting": 0.9999, "period_ticks": 100, "window": 100, "dither": 0.002,
               "offset": True, "max_offset": [0.1, 0.05]})
    pred = fit_predictor(ds, cfg.t_ini, cfg.t_f, method="lsq", ridge=1e-4)
    return generate(SteeringProblem(pred, cfg), tmp_path_factory.mktemp("adapt") / "flying", name="bridge_adapt")


@pytest.mark.compiler  # flying_solver generates and compiles
def test_adapt_needs_a_solver_generated_with_adaptation(flying_solver):
    from ddpc_codegen.robot.profile import load_profile
    from firmware_bridge.bridge import Bridge, BridgeConfig

    cfg = BridgeConfig(mode="steer", solver=str(flying_solver), controller=load_profile("pogox").controller,
                       url=f"udpin:127.0.0.1:{free_port()}", adapt=True)
    with pytest.raises(ValueError, match=rf"^--adapt needs a solver generated with \[adapt\] enabled; "
                                         rf"{flying_solver} has no online update$"):
        Bridge(cfg)


@pytest.mark.slow
def test_steered_ticks_update_and_the_tick_log_records_every_update_verdict_and_offset(procs, tmp_path, adaptive_solver):
    port = free_port()
    veh = procs.spawn("vehicle", f"udpout:127.0.0.1:{port}", "--lockstep", "--lockstep-timeout", "0.3", name="veh")
    br = procs.spawn("bridge", f"udpin:127.0.0.1:{port}", "--lockstep", "--offboard", "--mode", "steer",
                     "--solver", str(adaptive_solver), "--adapt", "--duration", "6",
                     "--log", str(tmp_path / "a.npz"), "--summary", str(tmp_path / "a.json"), "--timeout", "90",
                     name="br")
    assert procs.wait(br, 120) == 0, procs.log(br)
    procs.terminate(veh)
    s = read_json(tmp_path / "a.json")["steering"]["adaptation"]
    t = load_ticklog(tmp_path / "a.npz").ticks
    code = t["adapt"]
    steered = t["reason"] == REASONS.index("steered")
    assert np.all(code[~steered] == 0) and np.all(t["adapt_snap"][~steered] == 0)  # only steered ticks update
    updates = np.isin(code, UPDATE_CODES)  # a column taken in (+ a verdict)
    verdicts = np.isin(code, VERDICT_CODES)
    assert not np.any(code == ADAPT_CODES.index("refused")) and s["counts"]["dropped"] == 0
    assert s["counts"]["updates"] == int(updates.sum()) > 200
    # the re-solves ran in the worker: each from a snapshot taken on one tick, its verdict and swap on a later one
    # (the first update tick after it returned); one at a time; one still running at the stop joined and dropped
    assert s["background"] and s["counts"]["resolves"] == len(s["events"]) == int(verdicts.sum()) + s["discarded"] >= 2
    snaps, busy = np.nonzero(t["adapt_snap"] == SNAP_TAKEN)[0], int(np.sum(t["adapt_snap"] == SNAP_BUSY))
    resolves = np.nonzero(verdicts)[0]
    assert len(snaps) == s["counts"]["resolves"] and busy == s["busy"]
    assert np.all(snaps[: len(resolves)] < resolves) and np.all(resolves[:-1] < snaps[1 : len(resolves)])
    landed = [e for e in s["events"] if e[0] >= 0]
    assert [e[1] for e in landed] == [ADAPT_CODES[c] for c in code[resolves]]
    assert all(e[4] < e[0] for e in landed) and all(e[5] > 0 for e in s["events"])
    assert s["counts"]["swaps"] == int((code == ADAPT_CODES.index("accepted")).sum())
    # (that the tick never waits for the re-solve is the gated test in tests/runtime/test_adapt_loop.py; how long
    # the ticks take is measured by `make bench`, not asserted here: a loaded machine's tick times say nothing)
    # the offset in use: one per re-solve, as the events record it, unchanged between re-solves
    off = t["adapt_offset"]
    assert np.all(np.isfinite(off[steered])) and np.isnan(off).any()  # nan: ticks the steering did not decide
    assert s["counts"]["offset_swaps"] == sum(e[7] for e in landed) >= 1  # the verified ones (issue 46)
    np.testing.assert_array_equal(off[resolves], [e[3] for e in landed])
    assert landed[-1][3] == s["counts"]["offset_norm"] > 0.0
    rows = np.nonzero(steered)[0]
    assert set(rows[1:][np.diff(off[rows]) != 0].tolist()) <= set(resolves.tolist())
