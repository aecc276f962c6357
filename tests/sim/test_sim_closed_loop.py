"""Closed loop: the model-to-real gap is real, the hook interface, datasets, PE, determinism."""

from __future__ import annotations

import numpy as np
import pytest

from ddpc_codegen import IODataset
from ddpc_codegen.values.phases import ASCENT, DESCENT, FLYING, GROUND
from ddpc_codegen.sim import Excitation, FlyingScenario, PogoXParams, Push, simulate
from ddpc_codegen.sim.scenarios import EllipseTrajectory


@pytest.fixture(scope="module")
def flying():
    return simulate("flying", 20.0)


@pytest.fixture(scope="module")
def hopping():
    return simulate("hopping", 15.0)


def test_hover_offset_matches_pd_with_wrong_model_mass():
    # A PD with no integrator and a 200 g light model settles kp*e = (m_true/m_model - 1) g below.
    p = PogoXParams(drag=0.0)
    sc = FlyingScenario(ellipse=EllipseTrajectory(center=(0.0, 1.0), radii=(0.0, 0.0)))
    r = simulate(sc, 8.0, params=p)
    e = r.y_true[-200:, 0] - r.y_des[-200:, 0]
    expect = -(p.mass / p.controller_model_mass - 1.0) * p.g / r.config.kp_z
    assert np.mean(e) == pytest.approx(expect, abs=1e-3)
    assert np.ptp(e) < 1e-3


def test_unsteered_flying_is_stable_with_visible_height_error(flying):
    m = flying.metrics()
    assert not m["crashed"]
    # Regression band of the baseline (model mass 200 g low, PD without integral).
    assert -0.075 < m["mean_z_error"] < -0.045
    assert 0.06 < m["rmse_z"] < 0.12
    assert m["rmse_pitch"] < np.radians(1.0)
    assert m["rmse_x"] < 0.05


def test_flying_error_comes_from_the_mass():
    r = simulate("flying", 20.0, params=PogoXParams(controller_mass_error=0.0))
    assert abs(r.metrics()["mean_z_error"]) < 0.01


def test_unsteered_hopping_is_stable_with_visible_apex_error(hopping):
    m = hopping.metrics()
    assert not m["crashed"]
    assert m["n_hops"] >= 15
    assert m["n_bottom_outs"] == 0
    assert -0.05 < m["apex_error_mean_signed"] < -0.015  # regression band of the baseline
    assert m["apex_error_max_abs"] < 0.06
    assert abs(m["velocity_error_mean_signed"][0]) < 0.05
    # Events alternate touchdown / liftoff.
    td, lo = hopping.touchdowns, hopping.liftoffs
    assert len(td) - len(lo) in (0, 1)
    assert np.all(lo[: len(td)] > td[: len(lo)])


def test_hopping_dataset_keeps_phases(hopping):
    ds = hopping.to_dataset()
    assert isinstance(ds, IODataset) and ds.m == 3 and ds.p == 3
    assert ds.n_trajectories >= 10
    for ph in ds.phases:
        # apex-to-apex: descent, ground, ascent, in that order
        assert ph[0] == DESCENT and ph[-1] == ASCENT and np.any(ph == GROUND)
        changes = ph[np.r_[True, np.diff(ph) != 0]]
        assert list(changes) == [DESCENT, GROUND, ASCENT]
    aerial = hopping.to_dataset("aerial")
    assert all(not np.any(ph == GROUND) for ph in aerial.phases)
    whole = hopping.to_dataset("none")
    assert whole.n_trajectories == 1 and whole.n_samples == hopping.n


def test_reference_hook_sees_context_and_steers(flying):
    seen = {}

    def hook(ctx):
        if ctx.k == 0:
            assert ctx.u_log.shape == (0, 2) and ctx.y_log.shape == (1, 2)
        if ctx.k == 1000:
            seen["ctx"] = ctx
            np.testing.assert_allclose(ctx.desired_ahead(1)[0], ctx.y_des)
            np.testing.assert_allclose(ctx.y_log[-1], ctx.y)
            assert ctx.desired_ahead(15).shape == (15, 2)
            assert ctx.phase == FLYING and ctx.phase_name == "flying"
        # A crude steering: lift the height reference by the known steady offset.
        return ctx.r_nom + np.array([0.057, 0.0])

    r = simulate("flying", 20.0, reference_hook=hook)
    assert "ctx" in seen
    np.testing.assert_allclose(r.u - r.r_nom, np.tile([0.057, 0.0], (r.n, 1)), atol=1e-12)
    assert abs(r.metrics()["mean_z_error"]) < abs(flying.metrics()["mean_z_error"]) / 4
    # A hook returning None is the unsteered loop.
    r0 = simulate("flying", 2.0, reference_hook=lambda ctx: None)
    np.testing.assert_array_equal(r0.y, flying.y[: r0.n])


def test_hopping_desired_outputs_are_available_ahead(hopping):
    # During an aerial phase the predicted z_des equals what is later logged as y_des.
    checks = 0

    def hook(ctx):
        nonlocal checks
        if ctx.phase != GROUND and 400 < ctx.k < 2500 and ctx.k % 37 == 0:
            ahead = ctx.desired_ahead(25)
            ph = ctx.phases_ahead(25)
            store.append((ctx.k, ahead[:, 0].copy(), ph.copy()))
            checks += 1
        return None

    store: list = []
    r = simulate("hopping", 13.0, reference_hook=hook)
    n_ok = 0
    for k, z_ahead, ph in store:
        j = np.arange(25)
        same_air = (ph != GROUND) & np.cumprod(ph != GROUND).astype(bool) & (r.phase[k + j] != GROUND)
        if same_air.sum() > 1:
            np.testing.assert_allclose(z_ahead[same_air], r.y_des[k + j][same_air, 0], atol=1e-9)
            n_ok += 1
    assert checks > 10 and n_ok > 5


def test_prbs_excited_data_is_persistently_exciting():
    from ddpc_codegen.design.hankel import persistency_of_excitation

    r = simulate("flying", 25.0, excitation=Excitation(amplitude=(0.05, 0.03), min_hold=4), seed=3)
    assert not r.crashed
    assert np.all(np.abs(r.u - r.r_nom - r.excitation) < 1e-12)
    ds = r.to_dataset()
    order = 20 + 15 + 10  # Tini + Tf + a generous state dimension
    rep = persistency_of_excitation(list(ds.u), order)
    assert rep.ok and rep.rank == rep.required_rank == 2 * order
    s = np.asarray(rep.singular_values)
    # Not only numerically full rank: the smallest direction is far above round-off (the largest
    # is the mean height of z_ref, ~1.2 m, hence the modest ratio).
    assert s[-1] / s[0] > 1e-5
    # Hopping: aerial-only excitation, mosaic over the apex-to-apex segments.
    rh = simulate("hopping", 15.0, excitation=True, seed=4)
    assert not rh.crashed
    assert np.all(rh.excitation[rh.phase == GROUND] == 0.0)
    dh = rh.to_dataset()
    rep_h = persistency_of_excitation(list(dh.u), 20 + 25 + 6)
    assert rep_h.ok


def test_seeded_runs_are_deterministic():
    kw = dict(noise=True, excitation=True, pushes=[Push(1.0, (5.0, 0.0, 0.0), 0.1)])
    a = simulate("hopping", 3.0, seed=11, **kw)
    b = simulate("hopping", 3.0, seed=11, **kw)
    c = simulate("hopping", 3.0, seed=12, **kw)
    for name in ("state", "u", "y", "y_des", "phase", "setpoint_q", "touchdowns", "liftoffs"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert not np.array_equal(a.y, c.y)


def test_lost_robot_is_reported_with_reason_and_time():
    # A hard sideways shove at the body top tips the robot over: the run ends, crashed, saying why.
    r = simulate("flying", 6.0, pushes=[Push(t=4.0, force=(0.0, 400.0, 0.0), duration=0.2, point=(0.0, 0.0, 0.2))])
    assert r.crashed and r.t[-1] < 5.9
    assert r.crash_reason.startswith(("tilt above 70 deg at t=", "body below 0.1 m at t="))
    assert r.metrics()["crash_reason"] == r.crash_reason


def test_hybrid_event_chattering_ends_the_run_as_a_crash(monkeypatch):
    # The plant refusing to advance (foot chattering) must not escape simulate() as an exception:
    # the run ends there, crashed, with the plant's explanation.
    from ddpc_codegen.sim import plant as plant_mod

    step = plant_mod.PogoXPlant.step

    def failing_step(self, h, cmd, ext=None):
        if self.t >= 2.0:
            raise plant_mod.HybridEventError(f"too many hybrid events within one step at t={self.t:.6f} s")
        return step(self, h, cmd, ext) if ext is not None else step(self, h, cmd)

    monkeypatch.setattr(plant_mod.PogoXPlant, "step", failing_step)
    r = simulate("hopping", 5.0, stop_on_crash=False)
    assert r.crashed and "too many hybrid events" in r.crash_reason
    assert 1.99 <= r.t[-1] <= 2.01
