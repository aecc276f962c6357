"""Hopping over MAVLink: ``ddpc-vehicle --scenario hopping`` and ``ddpc-bridge --scenario hopping`` as
separate processes on UDP 127.0.0.1 (lock-step: fast and deterministic). One short collect flight,
its tick log refitted with ``ddpc-codegen codegen configs/hopping.toml``, then passthrough and steered
flights; phases against the simulator's true touchdown / liftoff times, with and without the
contact signal, clean and noisy."""

from __future__ import annotations

import subprocess
import sys
from types import SimpleNamespace

import numpy as np
import pytest

from ddpc_codegen.design.data import IODataset
from ddpc_codegen.values.phases import ASCENT, DESCENT, GROUND, ground_runs
from firmware_bridge.bridge_config import BridgeConfig
from ddpc_codegen.testbed.bridge_demo_hopping import link_metrics

from support.bridge_helpers import ROOT, Procs, _env, free_port, read_json

COLLECT = 20.0  # s of aerial PRBS: ~23 hops (enough for a solver: 2.4 mm apex error in-process)
FLIGHT = 8.0    # s per flight: ~9 hops, the first 3 not scored


def _fly(procs, tmp, name: str, bridge_args: list[str], vehicle_args: list[str] = (), duration: float = FLIGHT,
         seed: int = 2) -> dict:
    port = free_port()
    truth, log, summ = tmp / f"{name}_truth.npz", tmp / f"{name}.npz", tmp / f"{name}.json"
    veh = procs.spawn("vehicle", f"udpout:127.0.0.1:{port}", "--lockstep", "--scenario", "hopping", "--seed", str(seed),
                      "--contact-signal", "--truth-log", str(truth), *vehicle_args, name=f"{name}_vehicle")
    br = procs.spawn("bridge", f"udpin:127.0.0.1:{port}", "--lockstep", "--offboard", "--scenario", "hopping",
                     "--duration", str(duration), "--log", str(log), "--summary", str(summ), "--timeout", "120",
                     "--wait-heartbeat", "30", *bridge_args, name=f"{name}_bridge")
    assert procs.wait(br, 150) == 0, procs.log(br)
    assert procs.terminate(veh) == 0, procs.log(veh)
    with np.load(truth) as z:
        true = {"touchdowns": z["touchdowns"], "liftoffs": z["liftoffs"]}
    return {"summary": read_json(summ), "log": log, "truth": truth, "true": true,
            "metrics": link_metrics(log, truth)}


@pytest.fixture(scope="module")
def hops(tmp_path_factory):
    """collect -> codegen (the CLI, from the tick log) -> passthrough / steered (clean) -> passthrough (noisy)."""
    tmp = tmp_path_factory.mktemp("hop_e2e")
    pr = Procs(tmp)
    try:
        collect = _fly(pr, tmp, "collect", ["--mode", "collect"], ["--no-noise"], duration=COLLECT, seed=1)
        r = subprocess.run([sys.executable, "-m", "ddpc_codegen.cli.main", "codegen", str(ROOT / "configs" / "hopping.toml"),
                            "--dataset", str(collect["log"]), "--out", str(tmp / "generated")],
                           env=_env(), capture_output=True, text=True, timeout=600)
        assert r.returncode == 0, r.stderr
        solver = r.stdout.strip().splitlines()[-1]
        base = _fly(pr, tmp, "baseline", ["--mode", "passthrough"], ["--no-noise"])
        steer = _fly(pr, tmp, "steered", ["--mode", "steer", "--solver", solver, "--contact", "signal"], ["--no-noise"])
        noisy = _fly(pr, tmp, "noisy", ["--mode", "passthrough"], seed=3)
    finally:
        pr.cleanup()
    return SimpleNamespace(collect=collect, solver=solver, base=base, steer=steer, noisy=noisy)




@pytest.mark.e2e
@pytest.mark.compiler
@pytest.mark.slow
def test_collect_log_keeps_phases_and_refits(hops):
    ds = IODataset.load(hops.collect["log"])
    assert ds.metadata["fit_ok"] and ds.phases is not None
    ph = np.concatenate(ds.phases)
    assert set(np.unique(ph)) == {DESCENT, GROUND, ASCENT}
    # one labelled ground phase per true touchdown of the flight (the log's hops are the robot's)
    n_ground = sum(int(np.sum(np.diff((p == GROUND).astype(int)) == 1)) for p in ds.phases)
    assert abs(n_ground - len(hops.collect["true"]["touchdowns"])) <= 1
    # PRBS only in the air: no excitation on a ground sample, except on the <= 2 samples of each
    # stance that were relabelled ground when the touchdown was confirmed (back-dated)
    tl = np.load(hops.collect["log"])
    act = tl["tick_active"]
    exc, ph = tl["tick_excitation"][act], tl["tick_phase"][act]
    runs = ground_runs(ph)
    assert len(runs) >= 15 and all(np.all(exc[a + 2 : b] == 0.0) for a, b in runs)
    assert np.any(exc[ph != GROUND] != 0.0)
    from ddpc_codegen.runtime.loader import load_solver

    s = load_solver(hops.solver)
    assert s.artificial_io is not None and s.manifest["dims"]["m"] == 3


@pytest.mark.e2e
@pytest.mark.compiler
@pytest.mark.slow
def test_steering_lowers_the_apex_error_over_the_link(hops):
    b, s = hops.base["metrics"], hops.steer["metrics"]
    assert not b["crashed"] and not s["crashed"] and s["n_hops"] >= 6
    assert b["apex_error_mean_abs"] > 0.015  # the 200 g model error: hops ~2.5 cm low
    assert s["apex_error_mean_abs"] * 3 <= b["apex_error_mean_abs"], (b, s)
    # the steering offset from the tick log: none in passthrough, a z_ref offset that moves when steered
    assert b["offset_step_rms"] == [0.0, 0.0, 0.0] and 0.0 < s["offset_step_rms"][0] < 0.025  # du_max: 25 mm/tick
    # the thrust setpoints the bridge sent: never clamped in passthrough (as in-process), rarely when steered
    assert b["thrust_limit_share"] == 0.0 and 0.0 <= s["thrust_limit_share"] < 0.2
    sm = hops.steer["summary"]
    assert sm["fallbacks"] == 0 and sm["steering"]["steered"] > 0.5 * FLIGHT / 0.005
    assert sm["reasons"]["ground"] > 0 and sm["hopping"]["contact_source"] == "signal"


@pytest.mark.e2e
@pytest.mark.compiler
@pytest.mark.slow
def test_phase_detection_against_the_true_events(hops):
    est = []
    for run in (hops.base, hops.steer):
        pd = run["metrics"]["phase_detection"]
        n_true = len(run["true"]["touchdowns"]) + len(run["true"]["liftoffs"])
        assert pd["estimate"]["events"] == pd["signal"]["events"] >= n_true - 2  # events after the last tick dropped
        est += pd["estimate"]["touchdown"] + pd["estimate"]["liftoff"]
        assert pd["estimate"]["spurious"] == 0, pd["estimate"]
        # the leg sensor's flag arrives with the sample it belongs to: exactly the one-tick measurement delay
        assert set(pd["signal"]["touchdown"] + pd["signal"]["liftoff"]) == {1}
    # telemetry alone: every event found, within 2 ticks (one of them the measurement delay) on >= 95 % of
    # them (a slow liftoff right after the release may take a third tick)
    assert all(d is not None and 0 <= d <= 3 for d in est), est
    assert np.mean([d <= 2 for d in est]) >= 0.95, est
    # the bridge's own estimator saw as many touchdowns as the robot made (the flight with it online)
    h = hops.base["summary"]["hopping"]
    assert h["contact_source"] == "estimate"
    assert abs(h["touchdowns"] - len(hops.base["true"]["touchdowns"])) <= 1
    # where the profile's thresholds come from: the foot height the estimate sees when the sensor's flag
    # changes (touchdown at h <= 0, liftoff a few mm below the rest length, the leg still extending)
    fh = hops.base["metrics"]["foot_height_at_contact_changes"]
    assert fh["touchdown"]["n"] >= 5 and fh["touchdown"]["max"] <= 0.0005, fh
    assert -0.005 < fh["liftoff"]["min"] < 0.0 < fh["liftoff"]["max"], fh


@pytest.mark.e2e
@pytest.mark.compiler
@pytest.mark.slow
def test_noisy_telemetry_does_not_chatter(hops):
    pd = hops.noisy["metrics"]["phase_detection"]["estimate"]
    h = hops.noisy["summary"]["hopping"]
    td = hops.noisy["true"]["touchdowns"]
    assert h["touchdowns"] in (len(td), len(td) - 1) and pd["spurious"] == 0
    assert pd["within_2_ticks"] >= 0.95, pd


# ----------------------------------------------------------------------------- configuration
def test_hopping_config_replaces_the_flying_defaults():
    from ddpc_codegen.robot.profile import load_profile

    ctrl = load_profile("pogox_hopping").controller
    c = BridgeConfig(mode="collect", controller=ctrl)
    assert c.scenario == "hopping" and c.max_step is None and c.blend_rates is None
    assert c.excitation == (0.01, 0.02, 0.02)
    with pytest.raises(ValueError, match="max_step needs 3 values"):
        BridgeConfig(mode="passthrough", controller=ctrl, max_step=(0.1, 0.2, 0.3, 0.4))
    with pytest.raises(ValueError, match="takeoff is for flying"):
        BridgeConfig(mode="passthrough", controller=ctrl, takeoff=True)


def test_cli_scenario_and_contact_flags():
    from firmware_bridge.cli import bridge_config_from_args, build_bridge_parser

    p = build_bridge_parser()
    c = bridge_config_from_args(p.parse_args(["--mode", "passthrough", "--scenario", "hopping", "--contact", "signal",
                                              "--contact-name", "LEG"]))
    assert c.controller.mode == "hopping" and c.trajectory is None
    assert c.contact.source == "signal" and c.contact.signal_name == "LEG"
    with pytest.raises(ValueError, match="--contact / --contact-name are for hopping"):
        bridge_config_from_args(p.parse_args(["--mode", "passthrough", "--contact", "signal"]))
    with pytest.raises(ValueError, match="has controller mode 'flying'"):
        bridge_config_from_args(p.parse_args(["--mode", "passthrough", "--scenario", "hopping", "--profile", "pogox"]))


def test_steering_needs_the_artificial_io_operator():
    from firmware_bridge.hopping_loop import hopping_window

    solver = SimpleNamespace(manifest={"dims": {"m": 3, "p": 3}, "artificial_io": None}, artificial_io=None)
    with pytest.raises(ValueError, match="no artificial-IO operator"):
        hopping_window(solver, 20)
    # With one: the window the operator was generated with (as the in-process loop builds it).
    settings = {"t_d": 0, "min_ascent": 7, "noise_level": 2e-3, "denoise": True}
    art = SimpleNamespace(m=3, p=3, depth=60, noise_level=2e-3, window_settings=lambda: settings)
    win = hopping_window(SimpleNamespace(manifest={"dims": {"m": 3, "p": 3}}, artificial_io=art), 20)
    assert (win.t_ini, win.t_d, win.min_ascent, win.noise_level, win.denoise) == (20, 0, 7, 2e-3, True)


class _Steerer:
    """A stand-in steerer that never steers (warm-up)."""

    t_ini, t_f, m, p = 4, 6, 3, 3

    def observe(self, u, y) -> None:
        pass

    def reset(self) -> None:
        pass

    def set_window(self, u, y) -> None:
        pass

    def step(self, y_des, u_nom):
        from ddpc_codegen.runtime.steerer import SteerOutcome

        return SteerOutcome(np.asarray(u_nom[0]), False, "warmup")


def _loop(source: str = "estimate"):
    from ddpc_codegen.robot.controller import HeightLegAngleController
    from ddpc_codegen.robot.phases import ContactConfig
    from ddpc_codegen.robot.profile import load_profile
    from ddpc_codegen.runtime.policy import SteeringPolicy
    from firmware_bridge.hopping_loop import HoppingLoop

    ctrl = HeightLegAngleController(load_profile("pogox_hopping").controller)
    return HoppingLoop(ctrl, ContactConfig(source=source), SteeringPolicy(_Steerer()), None)


def _state(z: float, vz: float):
    from ddpc_codegen.robot.state import MeasuredState

    return MeasuredState(0.0, np.array([0.0, 0.0, z]), np.array([0.0, 0.0, vz]), np.zeros(3), np.zeros(3))


def test_hopping_loop_history_resets_on_a_hole_and_phases_drive_the_controller():
    hop = _loop()
    tel = SimpleNamespace(contact=None, contact_stamp=float("nan"), newest_stamp=lambda: 0.0)
    hop.release(_state(0.7, 0.0))
    ahead = 0.005 * np.arange(6)
    for k, z in enumerate((0.45, 0.43, 0.41, 0.3915, 0.383)):  # falling; the foot 8.5 mm below the plane: touchdown
        st = hop.observe(_state(z, -1.7), tel)
        hop.ctrl.nominal_reference(st)
        hop.steer(np.zeros(3), np.zeros(3), 0.005 * k, ahead)
    assert st.contact and hop.ctrl.phase == GROUND and hop.summary()["touchdowns"] == 1
    assert hop.excitation(np.ones(3)).tolist() == [0.0, 0.0, 0.0]  # no PRBS on the ground
    assert hop.steering.history.views()[0].shape[0] == 5
    hop.lost(1)  # one lost sample: the hopping history starts over
    assert hop.steering.history.views()[0].shape[0] == 0


def test_signal_source_holds_the_phase_until_the_first_flag():
    hop = _loop("signal")
    tel = SimpleNamespace(contact=None, contact_stamp=float("nan"), newest_stamp=lambda: 1.0)
    assert not hop.observe(_state(0.3, -1.0), tel).contact and hop.counts["contact_missing"] == 1
    tel.contact, tel.contact_value, tel.contact_stamp = True, 1, 0.995  # one sample older than the state: used, counted
    for _ in range(3):
        st = hop.observe(_state(0.3, -1.0), tel)
    assert st.contact and hop.counts["contact_old"] == 3


@pytest.mark.parametrize("value, z, why", [
    (7, 0.6, "contact signal refused: contact value 7 (a contact flag is 0 or 1); phases from the telemetry estimate"),
    (-1, 0.6, "contact signal refused: contact value -1 (a contact flag is 0 or 1)"),
    (1, 0.6, "contact signal refused: contact reported with the foot 0.200 m above the ground (more than 0.05 m)"),
])
def test_implausible_contact_signals_fall_back_to_the_estimate(value, z, why):
    """Issue 28: values other than 0 / 1, or a touchdown the hop's dynamics cannot have made (the foot high
    above the ground), are refused once: the phases come from the telemetry estimate from then on."""
    hop = _loop("signal")
    tel = SimpleNamespace(contact=value != 0, contact_value=value, contact_stamp=1.0, newest_stamp=lambda: 1.0)
    st = hop.observe(_state(z, -1.0), tel)
    assert not st.contact and hop.contact.source == "estimate" and hop.counts["contact_refused"] == 1
    assert len(hop.notes) == 1 and hop.notes[0].startswith(why)
    for _ in range(20):  # the flag keeps saying "ground": ignored, the foot is in the air
        st = hop.observe(_state(0.6, -1.0), tel)
    assert not st.contact and hop.counts["contact_refused"] == 1 and hop.summary()["contact_source"] == "estimate"



@pytest.mark.e2e
@pytest.mark.compiler
@pytest.mark.slow
def test_the_generated_completion_is_timed_before_the_loop(hops):
    """The preflight times the real generated operator on its longest windows: against a tick it cannot
    meet (10 us) and one it easily meets (1 s); its counters are left alone."""
    from ddpc_codegen.runtime.loader import load_solver
    from firmware_bridge.hopping_loop import completion_time_warning

    art = load_solver(hops.solver).artificial_io
    before = dict(art.counts)
    assert "ms tick: hopping ticks will run late" in completion_time_warning(art, 1e5)
    assert completion_time_warning(art, 1.0) is None
    assert art.counts == before


def test_a_completion_slower_than_half_a_tick_is_reported():
    """Both longest windows are timed (all known; the first third filled), inside the bounds."""
    import time

    from firmware_bridge.hopping_loop import completion_time_warning

    class _Slow:
        depth, m, p, counts = 30, 3, 3, {"calls": 7}
        lo, hi = [0.2, -0.3, -0.3, 0.0, -1.0, -np.inf], [1.5, 0.3, 0.3, np.inf, 1.0, np.inf]

        def __init__(self) -> None:
            self.windows = []

        def complete(self, u, y, missing, *, replace_known=False):
            self.windows.append((u.shape[0], int(np.sum(missing)), float(u[0, 0]), float(y[0, 0]), float(y[0, 2])))
            self.counts["calls"] += 1
            time.sleep(0.004)

    slow = _Slow()
    msg = completion_time_warning(slow, 200.0)
    assert msg is not None and "30-sample window" in msg and "5.0 ms tick" in msg
    assert {w[:2] for w in slow.windows} == {(30, 0), (30, 10)}  # all known, then the first third missing
    assert {w[2:] for w in slow.windows} == {(0.85, 0.0, 0.0)}  # bound midpoints, a one-sided bound, none
    assert slow.counts == {"calls": 7}
    assert completion_time_warning(slow, 50.0) is None  # 4 ms of a 20 ms tick
