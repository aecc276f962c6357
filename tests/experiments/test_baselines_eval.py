"""Baselines in the loop: short seeded runs with their metric in a regression band; the demo's
reuse of its own runs is valid (same pushes and masses); scheduled apex targets per hop."""

from __future__ import annotations

import types

import numpy as np
import pytest

from ddpc_codegen.experiments.baselines_eval import (
    METHODS,
    ApexSchedule,
    ScheduledHoppingScenario,
    _metric,
    _policy_run,
    conditions,
    fit_scenario_prefilter,
    format_baselines,
    learn_ilc,
    reuse_from_summary,
)
from ddpc_codegen.experiments.demo import ROBUSTNESS
from ddpc_codegen.experiments.pipeline import CollectSpec, collect
from ddpc_codegen.runtime.baselines import PassthroughPolicy, PrefilterPolicy


@pytest.mark.parametrize("scenario", ["flying", "hopping"])
def test_reused_demo_runs_are_the_same_conditions(scenario):
    conds = conditions(scenario)
    assert conds["push"]["pushes"] == ROBUSTNESS[scenario]["push"]["pushes"]
    assert conds["mass -300 g"]["params"] == ROBUSTNESS[scenario]["mass -300 g"]["params"]
    assert ROBUSTNESS[scenario]["sensor noise"] == {"noise": True} and conds["sensor noise"]["noise"] is True
    assert not any(c["noise"] for name, c in conds.items() if name != "sensor noise")
    first = next(iter(conds.values()))
    assert first["periodic"] and first["pushes"] is None and first["params"].controller_mass_error == -0.2


def _block(v):
    return {"baseline": {"rmse_z": v}, "steered": {"rmse_z": v / 10}, "fallbacks": 2,
            "crashed": {"baseline": False, "steered": False}}


def test_reuse_from_summary_and_table():
    summary = {"flying": _block(0.09), "robustness": {"flying": {"push": _block(0.1), "mass -300 g": {"error": "x"}}}}
    reuse = reuse_from_summary(summary)["flying"]
    assert set(reuse) == {"ellipse (periodic)", "push"}
    assert reuse["push"]["ddpc"] == {"rmse_z": 0.01, "fallbacks": 2}
    row = {m: {"rmse_z": 0.004} for m in METHODS}
    row.update(ddpc={"rmse_z": 0.001}, ilc={"crashed": True}, ilc_learned_here=False)
    text = format_baselines({"flying": {"metric": "rmse_z", "conditions": {"push": row}}})
    assert "| flying   | push" in text and "crash*" in text and "4.0x" in text
    # Hopping: the velocity each method leaves and how much its z_ref offset jumps per tick.
    hop = {m: {"apex_error_mean_abs": 0.03, "vx_error_mean_abs": 0.004, "offset_step_rms": [0.0, 0.0, 0.0]}
           for m in METHODS}
    hop["ilc"]["offset_step_rms"] = [0.0002, 0.0, 0.0]
    hop["ddpc"] = {"apex_error_mean_abs": 0.001, "vx_error_mean_abs": 0.0057, "offset_step_rms": [0.011, 0.0, 0.0]}
    del hop["prefilter"]["offset_step_rms"]  # a summary written before the metric existed
    hop["ilc_learned_here"] = False
    text = format_baselines({"hopping": {"metric": "apex_error_mean_abs", "conditions": {"sensor noise": hop}}})
    assert ("mean |vx err| [mm/s] hopping, sensor noise: passthrough 4.0, prefilter 4.0, ilc 4.0, ddpc 5.7; "
            "z_ref offset step rms [mm]: passthrough 0.00, prefilter -, ilc 0.20, ddpc 11.00") in text


@pytest.mark.slow
def test_flying_baselines_in_the_loop_regression_band():
    """40 s of PRBS data, 15 s on the ellipse (seed 0, noise-free). Measured when written:
    prefilter lead 102 / 31 ticks, gain 0.98 / 0.99, RMSE z 6.7 mm; ILC 95.9 -> 2.15 -> 0.66 mm."""
    spec = CollectSpec(duration=40.0, amplitude=(0.05, 0.03))
    raw = collect("flying", spec).to_dataset("none", t_min=3.0)
    setup = types.SimpleNamespace(scenario="flying", raw=raw, dataset=raw)
    pf = fit_scenario_prefilter(setup)
    assert 95 <= pf.lead[0] <= 110 and 0.95 < pf.gain[0] < 1.0 and -0.045 < pf.offset[0] < -0.03
    c = conditions("flying")["ellipse (periodic)"]
    m = _metric(_policy_run(PrefilterPolicy(pf), c["scenario"], 15.0, c["params"], None, 0))
    assert 0.005 < m["rmse_z"] < 0.009
    ilc = learn_ilc(setup, pf, duration=15.0, iterations=2)
    assert ilc.metric[0] > 0.08 and ilc.metric[1] < 0.004 and ilc.metric[2] < 0.0012


@pytest.mark.slow
def test_hopping_baselines_in_the_loop_regression_band():
    """40 s of aerial-PRBS hopping, 10 s runs. Measured when written: the static prefilter makes
    the apex worse (59.7 mm vs 31.2 mm unsteered: the apex is set at liftoff, which an aerial static
    map cannot see); ILC on the hops 31.2 -> 4.1 -> 7.3 mm."""
    spec = CollectSpec(duration=40.0, amplitude=(0.01, 0.02, 0.02))
    raw = collect("hopping", spec).to_dataset("none", t_min=0.0)
    setup = types.SimpleNamespace(scenario="hopping", raw=raw, dataset=raw)
    pf = fit_scenario_prefilter(setup)
    assert pf.lead[0] <= 5 and 0.8 < pf.gain[0] < 0.9
    c = conditions("hopping")["apex 0.7 m (periodic)"]
    m = _metric(_policy_run(PrefilterPolicy(pf), c["scenario"], 10.0, c["params"], None, 0))
    assert 0.045 < m["apex_error_mean_abs"] < 0.075
    ilc = learn_ilc(setup, pf, duration=10.0, iterations=2)
    assert 0.025 < ilc.metric[0] < 0.04 and min(ilc.metric[1:]) < 0.01


def test_scheduled_apex_changes_per_hop():
    from ddpc_codegen.sim import simulate

    sched = ApexSchedule(seed=2)
    assert sched.apex(1) != sched.apex(2) and sched.low <= sched.apex(5) <= sched.high
    assert ApexSchedule(seed=2, hold=3).apex(1) == ApexSchedule(seed=2, hold=3).apex(3)
    res = simulate(ScheduledHoppingScenario(schedule=sched), 4.0)
    assert not res.crashed and len(res.liftoffs) >= 3
    # The desired apex of each arc after a liftoff is that hop's target.
    for j, t_lo in enumerate(res.liftoffs[:3], start=1):
        k = int(np.searchsorted(res.t, t_lo)) + 3
        seg = res.y_des[k : k + 150, 0]
        assert np.max(seg) == pytest.approx(sched.apex(j), abs=2e-3)


def test_long_horizon_flying_config_loads():
    """configs/flying_tf30.toml: the measured alternative for disturbances (see its header)."""
    from ddpc_codegen.values.config import SteeringConfig
    from ddpc_codegen.experiments.pipeline import ROOT

    cfg = SteeringConfig.from_toml(ROOT / "configs" / "flying_tf30.toml")
    assert (cfg.t_ini, cfg.t_f, cfg.name) == (20, 30, "flying_tf30") and cfg.R[1, 1] == 10.0


def test_controller_feed_forward_baseline():
    """The controller's own velocity feed-forward removes the flying loop's lag but not its offset
    (measured when written, 15 s on the ellipse: RMSE z 95.9 -> 58.8 mm, mean error -58 mm), and
    hopping's controller already has it (the column repeats passthrough)."""
    from ddpc_codegen.experiments.baselines_eval import _controller_ff_metric, controller_ff_scenario

    c = conditions("flying")["ellipse (periodic)"]
    sc = controller_ff_scenario(c["scenario"])
    assert sc.controller["ref_velocity_gain"] == 1.0 and c["scenario"].controller == {}
    pt = _metric(_policy_run(PassthroughPolicy(), c["scenario"], 15.0, c["params"], None, 0))
    ff = _controller_ff_metric("flying", c, {"passthrough": pt}, 15.0, 0)
    assert pt["rmse_z"] > 0.085 and 0.045 < ff["rmse_z"] < 0.075 and -0.07 < ff["mean_z_error"] < -0.045
    hop = _controller_ff_metric("hopping", conditions("hopping")["push"], {"passthrough": {"apex_error_mean_abs": 0.03}},
                                10.0, 0)
    assert hop == {"apex_error_mean_abs": 0.03, "same_as_passthrough": True}
