"""Steering in the simulated loop: generated solver vs baseline, the hook's timing, the report schema, the CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest

from ddpc_codegen.cli.main import build_parser
from ddpc_codegen.experiments.demo import format_robustness, format_table, summary_block
from ddpc_codegen.experiments.pipeline import CollectSpec, build_setup, collect
from ddpc_codegen.experiments.evaluate import InterpretedSolver, run
from ddpc_codegen.experiments.policy_hook import PolicyHook
from ddpc_codegen.runtime.policy import SteeringPolicy
from ddpc_codegen.sim import simulate

pytestmark = pytest.mark.compiler  # slow comes from tests/durations.json (the tests that fly flying_setup)


@pytest.fixture(scope="module")
def flying_setup(tmp_path_factory):
    raw = collect("flying", CollectSpec(duration=45.0, seed=1, noise=False, amplitude=(0.05, 0.03)))
    out = tmp_path_factory.mktemp("generated")
    return build_setup("flying", raw=raw, generate_dir=out, solver_name="test_flying", save_data=False)


@pytest.fixture(scope="module")
def flying_runs(flying_setup):
    base = run(None, "flying", 10.0, steer=False)
    steered = run(flying_setup, "flying", 10.0)  # the generated C solver in the loop
    return base, steered


def test_generated_solver_steers_height_error_down_3x(flying_setup, flying_runs):
    base, steered = flying_runs
    assert flying_setup.solver is not None and steered.steering["solver"] == "generated:daqp"
    b, s = base.metrics["rmse_z"], steered.metrics["rmse_z"]
    assert b > 0.05  # the -200 g model mass error
    assert s * 3 <= b, (b, s)
    assert steered.metrics["rmse_pitch"] <= base.metrics["rmse_pitch"]  # leg angle not worse
    st = steered.steering
    assert st["fallbacks"] == 0 and st["steered"] == st["ticks"] - st["warmup"]
    assert st["solver_us"]["p50"] < 1000.0  # microseconds in C


def test_interpreted_path_agrees_with_the_generated_solver(flying_setup, flying_runs):
    _, steered = flying_runs
    r = steered.sim
    interp = InterpretedSolver(flying_setup.problem, "exact")
    Ti, Tf = flying_setup.config.t_ini, flying_setup.config.t_f
    for k in (700, 1200, 1900):
        yd = r.y_des[k : k + Tf]
        a = flying_setup.solver.solve(r.u[k - Ti : k], r.y[k - Ti : k], yd, r.r_nom[k : k + Tf])
        b = interp.solve(r.u[k - Ti : k], r.y[k - Ti : k], yd, r.r_nom[k : k + Tf])
        assert a.ok and b.ok
        np.testing.assert_allclose(a.u, b.u, atol=1e-6)


class _Recorder:
    """A stand-in steerer that records what the hook feeds it."""

    t_ini, t_f, m, p = 3, 4, 2, 2

    def __init__(self) -> None:
        self.pairs: list[tuple[np.ndarray, np.ndarray]] = []
        self.steps = 0

    def observe(self, u, y) -> None:
        self.pairs.append((np.array(u), np.array(y)))

    def step(self, y_des, u_nom):
        from ddpc_codegen.runtime.steerer import SteerOutcome

        self.steps += 1
        assert y_des.shape == (self.t_f, self.p) and u_nom.shape == (self.t_f, self.m)
        return SteerOutcome(np.asarray(u_nom[0]), False, "warmup")


def test_hook_pairs_u_and_y_like_the_logged_data():
    rec = _Recorder()
    res = simulate("flying", 0.3, reference_hook=PolicyHook(SteeringPolicy(rec, max_gap_fill=0), "flying"), seed=0, noise=True)
    # At tick k, once decided, the policy pushes (u[k], y[k]): the pairing of the dataset's Hankel columns.
    assert len(rec.pairs) == res.n and rec.steps == res.n
    for k in (0, 17, res.n - 1):
        np.testing.assert_array_equal(rec.pairs[k][0], res.u[k])
        np.testing.assert_array_equal(rec.pairs[k][1], res.y[k])
    np.testing.assert_array_equal(res.u, res.r_nom)  # the fallback is exactly the nominal reference


def test_summary_block_is_the_stable_json_schema(flying_runs):
    base, steered = flying_runs
    blk = summary_block("flying", base, steered)
    assert set(blk["baseline"]) >= {"rmse_z", "rmse_pitch"} and set(blk["steered"]) >= {"rmse_z", "rmse_pitch"}
    assert set(blk["solve_us"]) >= {"median", "p99"} and isinstance(blk["fallbacks"], int)
    json.dumps(blk)  # JSON-serialisable as is
    table = format_table({"flying": blk})
    assert "flying" in table and "steered" in table
    rob = format_robustness({"flying": {"noise": {k: blk[k] for k in ("baseline", "steered", "fallbacks")}}})
    assert "RMSE z" in rob and "z_ref offset step rms" in rob and "thrust at 0 or 1 [% of ticks]" in rob
    # The steering offset's tick-to-tick jitter: none without steering; with it, the definition on the run's arrays.
    assert blk["baseline"]["offset_step_rms"] == [0.0, 0.0]
    r = steered.sim
    keep = r.t >= 3.0  # the flying scenario's settle time
    d = np.diff(r.u - r.r_nom, axis=0)[keep[1:] & keep[:-1]]
    np.testing.assert_allclose(blk["steered"]["offset_step_rms"], np.sqrt(np.mean(d**2, axis=0)), rtol=1e-12)
    assert blk["steered"]["offset_step_rms"][0] > 0.0
    # The clamped-thrust share over the same ticks, from the run's thrust setpoints.
    for rr, key in ((base, "baseline"), (steered, "steered")):
        th = rr.sim.setpoint_thrust[rr.sim.t >= 3.0]
        assert blk[key]["thrust_limit_share"] == pytest.approx(np.mean((th <= 1e-6) | (th >= 1 - 1e-6)), abs=1e-15)


def test_cli_has_demo_and_evaluate():
    p = build_parser()
    a = p.parse_args(["evaluate", "--scenario", "hopping", "--noise", "--push", "6,3,0,-8", "--interpreted"])
    assert a.func.__name__ == "_cmd_evaluate" and a.interpreted == "fast" and a.noise
    d = p.parse_args(["demo", "--no-robustness", "--interpreted", "exact"])
    assert d.func.__name__ == "_cmd_demo" and d.interpreted == "exact"
