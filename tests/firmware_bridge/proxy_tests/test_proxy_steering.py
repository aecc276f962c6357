"""The steering proxy's tick (:class:`firmware_bridge.proxy.steering.ProxySteering`) against a known closed loop
(:mod:`lti_loop`): pass-through changes nothing, collect adds exactly its dither and records what was sent, the
generated solver fitted on that record steers the loop closer to the app's path than the app alone, and every
tick that is not steered (not engaged, stale, wrong frame or rate) sends the app's own setpoint."""

from __future__ import annotations

import json

import numpy as np
import pytest

from ddpc_codegen.pipeline.solver_build import build_solver
from ddpc_codegen.runtime.loader import load_solver
from ddpc_codegen.values.config import SteeringConfig
from firmware_bridge.proxy.preview import DelayedPreview, LocalPreview
from firmware_bridge.proxy.record import ProxyRecord
from firmware_bridge.proxy.rewrite import decode_frame
from firmware_bridge.proxy.steering import ProxySteering
from firmware_bridge.proxy.vehicle_view import VehicleView
from firmware_bridge.mocap_input import MocapInput
from lti_loop import DT, LoopSim, PoseLink, fly
from support.bridge_helpers import ROOT
from support.solver_cache import cache_root, shared_build

CONFIG = ROOT / "configs" / "proxy_px4.toml"  # the absolute loop: an app without feed-forward


def _hook(**kw) -> ProxySteering:
    return ProxySteering(VehicleView(), record=ProxyRecord(), **kw)


def _path(n: int, seed: int = 0) -> np.ndarray:
    """A smooth non-repeating height path around 2 m (sum of three sines of unrelated periods) [m]."""
    t = np.arange(n) * DT
    return 2.0 + 0.4 * np.sin(2 * np.pi * t / 3.1 + seed) + 0.25 * np.sin(2 * np.pi * t / 1.7 + 2 * seed) \
        + 0.15 * np.sin(2 * np.pi * t / 5.3)


def test_passthrough_sends_the_apps_own_setpoints():
    hook = _hook()
    out = fly(hook, _path(300))
    assert not out["rewritten"].any() and hook.counts["ticks"] == 300
    rows = hook.record.view()
    assert rows["engaged"][5:].all() and np.allclose(rows["u"], rows["r_nom"])


def test_collect_adds_exactly_its_dither_and_records_what_was_sent():
    hook = _hook(dither=0.2, seed=3)
    path = _path(1500)
    out = fly(hook, path)
    rows = hook.record.view()
    eng = rows["engaged"]
    assert np.allclose(np.abs(out["sent"][eng] - path[eng]), 0.2) and not out["rewritten"][~eng].any()
    ds = hook.record.dataset(hook.tick)
    assert ds.input_names == ("z_ref",) and ds.output_names == ("z",) and ds.dt == pytest.approx(DT)
    u = np.concatenate([a[:, 0] for a in ds.u])
    assert np.allclose(u, out["sent"][eng][:len(u)]) and len(u) >= 1400


def test_ordinary_flights_teach_the_absolute_loop_but_nothing_in_deviation_coordinates():
    """An app's own flights (no dither) excite z_ref with its path; the offset of deviation coordinates never moves,
    and the fit says so instead of learning a loop from nothing."""
    from ddpc_codegen.design.predictor import fit_predictor
    from ddpc_codegen.errors import ExcitationError

    hook = _hook()
    fly(hook, _path(1500))
    fit_predictor(hook.record.dataset(hook.tick, coordinates="absolute"), t_ini=10, t_f=30)
    with pytest.raises(ExcitationError, match="near-constant input channel.*z_offset"):
        fit_predictor(hook.record.dataset(hook.tick, coordinates="deviation"), t_ini=10, t_f=30)


def test_an_unarmed_vehicle_is_never_steered_and_collect_refuses_an_empty_record():
    hook = _hook(dither=0.2)
    out = fly(hook, _path(300), LoopSim(armed=False))
    assert not out["rewritten"].any()
    with pytest.raises(ValueError, match="no engaged stretch"):
        hook.record.dataset(DT)


def test_delayed_preview_plays_the_stream_late_and_previews_what_it_holds():
    sim, pv = LoopSim(), DelayedPreview(0.1)
    msgs = []
    for k in range(20):
        msg, _ = sim.setpoint(1.0 + 0.1 * k)
        pv.push(k * DT, msg)
        msgs.append(msg)
        cur = pv.current(k * DT)
        assert cur is msgs[max(k - 5, 0)]
    ahead = pv.desired(np.array([0.0, 0.04, 0.1, 0.5]))[:, 0]
    assert np.allclose(ahead, [1.0 + 0.1 * 14, 1.0 + 0.1 * 16, 1.0 + 0.1 * 19, 1.0 + 0.1 * 19])


def test_local_preview_follows_the_velocity_field_or_the_slope():
    sim, pv = LoopSim(), LocalPreview(reach=0.5)
    pv.push(0.0, sim.setpoint(1.0)[0])
    pv.push(DT, sim.setpoint(1.02)[0])  # slope 1 m/s
    assert np.allclose(pv.desired(np.array([0.0, 0.2, 1.0]))[:, 0], [1.02, 1.22, 1.52])
    pv.push(2 * DT, sim.setpoint(1.04, vz_up=-0.5)[0])  # the app's own velocity wins
    assert np.allclose(pv.desired(np.array([0.0, 0.2]))[:, 0], [1.04, 0.94])


@pytest.fixture(scope="module")
def solver(tmp_path_factory):
    """The generated solver fitted on a dithered flight of the known loop (built once per test run)."""
    def build(folder):
        hook = _hook(dither=0.3, dither_hold=3, seed=1)
        fly(hook, _path(6000, seed=5))
        hook.record.dataset(hook.tick).save(folder / "collect.npz")
        build_solver(SteeringConfig.from_toml(CONFIG), folder / "collect.npz", folder / "solver", holdout=0.2)

    folder = shared_build(cache_root(tmp_path_factory.getbasetemp()),
                          {"test": "proxy_lti", "config": CONFIG.read_text(), "holdout": 0.2}, build)
    return folder / "solver"


def _rmse(h: np.ndarray, target: np.ndarray, skip: int = 150) -> float:
    return float(np.sqrt(np.mean((h[skip:] - target[skip:]) ** 2)))


def _slow_path(n: int) -> np.ndarray:
    """A smooth path whose periods (5-11 s) are long against the loop's settling (0.8 s) [m]."""
    t = np.arange(n) * DT
    return 2.0 + 0.5 * np.sin(2 * np.pi * t / 8.0) + 0.3 * np.sin(2 * np.pi * t / 5.3 + 1) \
        + 0.2 * np.sin(2 * np.pi * t / 11.0)


@pytest.mark.compiler
def test_steering_tracks_the_apps_path_closer_than_the_app_alone(solver):
    """Local preview on a slow path; a 1.5 s delay on a fast one, where a local guess of the future is wrong
    (judged against the path played late; the shipped weights are gentler than this loop allows)."""
    slow, fast = _slow_path(3000), _path(1500, seed=2)  # neither is the collect's path
    local = _hook(solver=load_solver(solver))
    base, e_local = _rmse(fly(_hook(), slow)["h"], slow), _rmse(fly(local, slow)["h"], slow)
    delay = 1.5
    late = _hook(solver=load_solver(solver), preview=DelayedPreview(delay))
    lag = int(round(delay / DT))
    fast_late = np.concatenate((np.full(lag, fast[0]), fast[:-lag]))  # what the app declared the vehicle should fly
    base_fast, e_delay = _rmse(fly(_hook(), fast)["h"], fast), _rmse(fly(late, fast)["h"], fast_late, skip=150 + lag)
    print(json.dumps({"slow_mm": [base * 1e3, e_local * 1e3], "fast_mm": [base_fast * 1e3, e_delay * 1e3]}))
    assert local.counts["steered"] > 2800 and late.counts["steered"] > 1200
    assert e_local < 0.25 * base and e_delay < 0.4 * base_fast


@pytest.mark.compiler
@pytest.mark.parametrize("kw", [{}, {"dither": 0.2}, {"steer": True}, {"steer": True, "delay": 0.1}],
                         ids=["passthrough", "collect", "steer", "steer_delayed"])
def test_the_proxys_split_tick_sends_and_records_what_the_whole_tick_does(solver, kw):
    """The proxy decides the bytes, sends, then settles (a passthrough's whole tick after the send): the same
    frames and the same record as one whole tick per setpoint (the solve's own time aside)."""
    def run(split: bool):
        k = dict(kw)
        if k.pop("steer", False):
            k["solver"] = load_solver(solver)
        if "delay" in k:
            k["preview"] = DelayedPreview(k.pop("delay"))
        hook = _hook(**k)
        out = fly(hook, _path(600, seed=3), LoopSim(h0=2.0, arm_at=50), split=split)
        rows = hook.record.view()
        return hook, out["frames"], {f: rows[f] for f in rows.dtype.names if f != "solve_us"}

    whole, split = run(False), run(True)
    assert split[0].passive == (kw == {}) and split[1] == whole[1]
    assert all(np.array_equal(whole[2][f], split[2][f]) for f in whole[2])
    assert kw == {} or any(a != b for a, b in split[1])  # (something was rewritten)


@pytest.mark.compiler
def test_a_loop_the_predictor_does_not_describe_gets_the_apps_own_setpoints_until_it_is_back(solver):
    """The vehicle's height loop turns slow and underdamped for 20 s (wn 4 -> 1.5 rad/s, zeta 0.8 -> 0.15): the
    prediction watch trips, says so, and the app's own setpoints go out; the loop back, the steering resumes. With
    the watch off the same flight is steered throughout, and its error in the changed part is over twice as large."""
    path = _slow_path(3000)
    runs = {}
    for ratio in (8.0, 0.0):
        hook, sim, h = _hook(solver=load_solver(solver), model_watch=ratio), LoopSim(h0=float(path[0])), []
        for k0, k1, wn, zeta in ((0, 1000, 4.0, 0.8), (1000, 2000, 1.5, 0.15), (2000, 3000, 4.0, 0.8)):
            sim.wn, sim.zeta = wn, zeta
            out = fly(hook, path[k0:k1], sim, t0=1000.0 + k0 * DT)
            h.append(out["h"])
            runs.setdefault(ratio, []).append(out["rewritten"].mean())
        runs[ratio].append(_rmse(np.concatenate(h)[1000:2000], path[1000:2000], skip=0))
        if ratio:
            watch = hook.stage.summary()["steering"]["prediction_watch"]
            said = [e for _, e in hook.events.events if "predictor" in e]
            assert watch["trips"] >= 1 and watch["resumes"] >= 1 and watch["ok"], watch
            assert "the app's own setpoints go out" in said[0] and "steering" in said[-1]
            reasons = hook.stage.summary()["steering"]["fallback_reasons"]
            assert reasons.get("model_mismatch", 0) > 300, reasons
    watched, blind = runs[8.0], runs[0.0]
    print(json.dumps({"rewritten_share": {"watch": watched[:3], "no_watch": blind[:3]},
                      "changed_part_mm": {"watch": watched[3] * 1e3, "no_watch": blind[3] * 1e3}}))
    assert watched[0] > 0.9 and watched[2] > 0.5 and watched[1] < 0.7  # steered, handed back, steered again
    assert min(blind[:3]) > 0.9 and watched[3] < 0.5 * blind[3]


@pytest.mark.compiler
def test_a_stale_position_or_a_foreign_rate_sends_the_apps_own_setpoint(solver):
    hook = _hook(solver=load_solver(solver))
    sim, path = LoopSim(), _path(400)
    out = fly(hook, path[:200], sim)
    assert out["rewritten"][-50:].all()
    # the vehicle's position stops: stale after max_age; the app's own setpoint from then on
    rewritten = []
    for k, z in enumerate(path[200:]):
        msg, frame = sim.setpoint(float(z))
        rewritten.append(hook(msg, frame, 1000.0 + (200 + k) * DT) is not None)
    stale_ticks = int(np.ceil(hook.max_age / DT))
    assert all(not r for r in rewritten[stale_ticks + 1:])
    # an app at half the solver's rate is never steered (said once)
    slow = _hook(solver=load_solver(solver))
    sim2 = LoopSim()
    for k in range(200):
        t = 1000.0 + 2 * k * DT
        slow.view.on_frame(sim2.heartbeat(), t - 0.002)
        slow.view.on_frame(sim2.position(), t - 0.001)
        msg, frame = sim2.setpoint(2.0 + 0.01 * k)
        assert slow(msg, frame, t) is None
        sim2.k += 2
    assert slow.counts["period_mismatch"] > 0 and any("not steering" in e for _, e in slow.events.events)


def test_a_setpoint_in_another_frame_or_without_z_is_never_touched():
    hook = _hook(dither=0.2)
    fly(hook, _path(100))
    sim = LoopSim()
    m = sim.app.set_position_target_local_ned_encode(0, 1, 1, 8, 0b1111_1111_1000, 0, 0, -2, 0, 0, 0, 0, 0, 0, 0, 0)
    frame = bytes(m.pack(sim.app))
    assert hook(decode_frame(frame), frame, 1002.0) is None and hook.counts["not_steerable"] == 1


@pytest.mark.parametrize("ff", ["zero", "keep"])
def test_a_rewritten_setpoint_keeps_or_zeroes_the_apps_z_feedforward(ff):
    hook = _hook(dither=0.2, z_feedforward=ff)
    sim = LoopSim()
    fly(hook, _path(50), sim)
    msg, frame = sim.setpoint(2.0, vz_up=0.7)
    out = decode_frame(hook(msg, frame, 1000.0 + 50 * DT))
    assert out.vz == (0.0 if ff == "zero" else pytest.approx(-0.7)) and out.x == msg.x and out.yaw == msg.yaw
    assert out.get_srcComponent() == 192 and out.type_mask == msg.type_mask


@pytest.fixture(scope="module")
def deviation_solver(tmp_path_factory):
    """A deviation-coordinates solver (the shipped ArduCopter config) fitted on a dithered flight of an app that
    sends its own velocity, on the known loop with a sag (built once per test run)."""
    def build(folder):
        hook = _hook(dither=0.15, dither_hold=10, seed=2, coordinates="deviation")
        path = _slow_path(6000)
        fly(hook, path, LoopSim(h0=2.0, sag=1.0), vz=np.gradient(path, DT))
        hook.record.dataset(hook.tick, coordinates="deviation").save(folder / "collect.npz")
        build_solver(SteeringConfig.from_toml(ROOT / "configs" / "proxy_ardupilot.toml"), folder / "collect.npz",
                     folder / "solver", holdout=0.2)

    folder = shared_build(cache_root(tmp_path_factory.getbasetemp()),
                          {"test": "proxy_lti_deviation", "config": (ROOT / "configs" / "proxy_ardupilot.toml").read_text(),
                           "holdout": 0.2},
                          build)
    return folder / "solver"


@pytest.mark.compiler
def test_deviation_steering_removes_what_the_apps_own_feedforward_leaves(deviation_solver):
    """An app with its own velocity feed-forward on a vehicle that sags (1 m/s^2 too heavy): its error is the sag's
    steady offset; steering the offset around the app's height (z_offset -> z_error) removes it."""
    path = _slow_path(2500)
    vz = np.gradient(path, DT)
    alone = _rmse(fly(_hook(), path, LoopSim(h0=2.0, sag=1.0), vz=vz)["h"], path, skip=500)
    hook = _hook(solver=load_solver(deviation_solver))
    steered = _rmse(fly(hook, path, LoopSim(h0=2.0, sag=1.0), vz=vz)["h"], path, skip=500)
    print(json.dumps({"app_alone_mm": alone * 1e3, "steered_mm": steered * 1e3}))
    assert hook.coordinates == "deviation" and hook.counts["steered"] > 2000
    assert steered < 0.5 * alone


def _drift(t: float) -> float:
    """An estimator's height error wandering over tens of seconds once airborne (from 4 s), as PX4 SIH's
    barometer-fed EKF does [m]; none on the ground, where the local frame is the truth's."""
    t = max(t - 4.0, 0.0)
    return 0.08 * np.sin(2 * np.pi * t / 23.0) + 0.05 * np.sin(2 * np.pi * t / 9.0)


@pytest.mark.compiler
def test_steering_on_a_motion_capture_takes_out_the_estimators_own_error(deviation_solver):
    """The autopilot flies its estimate, which drifts off the truth: the app alone is off by the drift, whatever its
    feed-forward. Measured on the motion capture (its own frame, put into the local frame while disarmed), the
    steering brings the true height to the app's path; measured on the estimate it cannot see the drift."""
    path = _slow_path(3000)
    path[:200] = path[200]  # on the ground (disarmed) for the first 200 ticks: the frames' offset is measured
    vz = np.gradient(path, DT)

    def flight(view: VehicleView, solver=None) -> float:
        hook = ProxySteering(view, record=ProxyRecord(), solver=solver and load_solver(solver))
        sim = LoopSim(h0=float(path[0]), drift=_drift, arm_at=200)
        return _rmse(fly(hook, path, sim, vz=vz)["h"], path, skip=600), hook

    alone, _ = flight(VehicleView())
    on_estimate, _ = flight(VehicleView(), deviation_solver)
    on_mocap, hook = flight(VehicleView(mocap=MocapInput(PoseLink())), deviation_solver)
    print(json.dumps({"app_alone_mm": alone * 1e3, "on_estimate_mm": on_estimate * 1e3, "on_mocap_mm": on_mocap * 1e3}))
    src = hook.summary()["position_source"]
    assert src["kind"] == "mocap" and src["offset_m"] == pytest.approx(0.7, abs=1e-6)
    assert hook.counts["steered"] > 2500
    assert on_mocap < 0.4 * alone and on_estimate > 0.8 * alone


def test_a_motion_capture_without_the_frames_offset_is_never_steered():
    """The proxy started with the vehicle already armed: no offset to the local frame, so no measured height."""
    view = VehicleView(mocap=MocapInput(PoseLink()))
    hook = ProxySteering(view, record=ProxyRecord(), dither=0.2)
    out = fly(hook, _path(200))
    assert not out["rewritten"].any() and view.position_age(2000.0) == float("inf")
    assert view.source_summary()["offset_m"] is None and view.mocap.seq == 200


def test_a_collect_keeps_only_the_stretches_streamed_at_its_tick():
    """PX4's take-off streams at 20 Hz before the app's 50 Hz path: those rows are not on the tick's grid."""
    rec = ProxyRecord()
    t = np.concatenate((np.arange(100) * 0.05, 5.0 + np.arange(1, 301) * DT))  # 5 s at 20 Hz, then 6 s at 50 Hz
    for k, tk in enumerate(t):
        rec.add(float(tk), 2.0, 2.0, 2.0, "collect", 0, 0.01, True, 0.0, k)
    (idx,) = rec.stretches(DT)
    assert idx[0] == 101 and idx[-1] == 399  # the first 50 Hz row still follows a 20 Hz gap
    assert len(rec.dataset(DT).u[0]) == 299


@pytest.mark.compiler
def test_a_solver_without_a_held_out_error_steers_without_a_watch_and_says_so(solver):
    s = load_solver(solver)
    s.manifest["dataset"].pop("holdout")  # as `ddpc-codegen codegen --holdout 0` writes it
    hook = _hook(solver=s)
    assert hook.steerer.watch is None
    assert any("no held-out prediction error: no prediction watch" in e for _, e in hook.events.events)
    off = _hook(solver=load_solver(solver), model_watch=0.0)
    assert off.steerer.watch is None and not any("prediction watch" in e for _, e in off.events.events)
    assert _hook(solver=load_solver(solver)).steerer.watch.ratio == 8.0
