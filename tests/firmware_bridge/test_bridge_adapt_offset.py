"""ddpc-bridge --adapt with ``[adapt] offset``: the tick log's ``adapt_offset`` column carries the norm of the output
offset in use, changing only at re-solves, as the summary's events record it (real UDP, the simulated vehicle)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ddpc_codegen.runtime.adapt_loop import ADAPT_CODES
from firmware_bridge.ticklog import REASONS, load_ticklog
from support.bridge_helpers import ROOT, free_port, read_json


@pytest.fixture(scope="module")
def offset_solver(tmp_path_factory) -> Path:
    """The bridge's flying solver recipe with [adapt] enabled and the output offset on (a re-solve every 100)."""
    from ddpc_codegen import SteeringConfig, SteeringProblem, fit_predictor, generate
    from ddpc_codegen.sim import simulate

    ds = simulate("flying", 30.0, excitation=True, seed=11, noise=True).to_dataset()
    cfg = SteeringConfig.from_toml(ROOT / "configs" / "flying.toml").replace(
        predictor={"method": "lsq", "ridge": 1e-4},
        adapt={"enabled": True, "forgetting": 0.9999, "period_ticks": 100, "window": 100, "dither": 0.002,
               "offset": True, "max_offset": [0.1, 0.05]})
    pred = fit_predictor(ds, cfg.t_ini, cfg.t_f, method="lsq", ridge=1e-4)
    return generate(SteeringProblem(pred, cfg), tmp_path_factory.mktemp("adapt_off") / "flying", name="bridge_off")


@pytest.mark.slow
def test_the_tick_log_records_the_offset_in_use(procs, tmp_path, offset_solver):
    port = free_port()
    veh = procs.spawn("vehicle", f"udpout:127.0.0.1:{port}", "--lockstep", "--lockstep-timeout", "0.3", name="veh")
    br = procs.spawn("bridge", f"udpin:127.0.0.1:{port}", "--lockstep", "--offboard", "--mode", "steer",
                     "--solver", str(offset_solver), "--adapt", "--duration", "6",
                     "--log", str(tmp_path / "a.npz"), "--summary", str(tmp_path / "a.json"), "--timeout", "90",
                     name="br")
    assert procs.wait(br, 120) == 0, procs.log(br)
    procs.terminate(veh)
    s = read_json(tmp_path / "a.json")["steering"]["adaptation"]
    t = load_ticklog(tmp_path / "a.npz").ticks
    steered = t["reason"] == REASONS.index("steered")
    off = t["adapt_offset"]
    assert np.all(np.isfinite(off[steered])) and np.isnan(off).any()  # nan: ticks the steering did not decide
    resolves = np.nonzero(t["adapt"] >= ADAPT_CODES.index("accepted"))[0]
    assert s["counts"]["offset_swaps"] == len(resolves) == len(s["events"]) >= 2  # one offset per re-solve
    np.testing.assert_array_equal(off[resolves], [e[3] for e in s["events"]])
    assert s["events"][-1][3] == s["counts"]["offset_norm"] > 0.0
    # between re-solves the offset in use does not change
    rows = np.nonzero(steered)[0]
    changed = rows[1:][np.diff(off[rows]) != 0]
    assert set(changed.tolist()) <= set(resolves.tolist())
