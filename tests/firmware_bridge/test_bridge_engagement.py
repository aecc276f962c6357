"""Knowing the vehicle before engaging (preflight) and the flight phases around the steered flight:
arming retries, take-off ramp, bumpless blend -- units, then the bridge against the fake vehicle."""

from __future__ import annotations

import struct

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
import pytest
from support.bridge_helpers import FakeVehicle, Procs, free_port, read_json

from firmware_bridge.bridge_config import BridgeConfig
from firmware_bridge.link import mavlink
from firmware_bridge.engagement import Approach, ArmingRetry, Engagement, RefBlend
from firmware_bridge.events import EventLog
from firmware_bridge.preflight import PreflightError, check_autopilot, decode_param_value, resolve_guid_options
from firmware_bridge.profiles import make_profile


def test_the_heartbeat_must_name_the_profiles_autopilot():
    check_autopilot(12, make_profile("px4"))
    with pytest.raises(PreflightError, match=r"says ArduPilot \(autopilot 3\) but the bridge is set for px4: "
                                             r"refusing before any mode command; use --autopilot ardupilot"):
        check_autopilot(3, make_profile("px4"))


def test_param_values_decode_per_autopilot():
    bits_250 = struct.unpack("<f", struct.pack("<i", 250))[0]  # what PX4 sent for IMU_INTEG_RATE
    assert decode_param_value(bits_250, mavlink.MAV_PARAM_TYPE_INT32, 12) == 250.0
    assert decode_param_value(8.0, mavlink.MAV_PARAM_TYPE_INT32, 3) == 8.0      # ArduPilot: float values
    assert decode_param_value(0.5, mavlink.MAV_PARAM_TYPE_REAL32, 12) == 0.5


def test_guid_options_from_the_vehicle_a_cli_value_only_if_it_agrees_or_forced():
    assert resolve_guid_options(8.0, None, False) == 8
    assert resolve_guid_options(8.0, 8, False) == 8
    assert resolve_guid_options(0.0, 8, True) == 8 and resolve_guid_options(None, 8, True) == 8
    with pytest.raises(PreflightError, match="--guid-options 8 disagrees with the vehicle's GUID_OPTIONS 0"):
        resolve_guid_options(0.0, 8, False)
    with pytest.raises(PreflightError, match="could not read GUID_OPTIONS"):
        resolve_guid_options(None, None, False)


def test_arming_retries_until_the_timeout_and_reports_every_refusal():
    a = ArmingRetry(interval=2.0, timeout=10.0)
    assert not a.due(0.0, ready=False) and a.due(0.0, ready=True)
    a.sent(0.0)
    assert not a.due(1.0, True) and a.due(2.0, True)
    line = a.refused("MAV_RESULT_FAILED", "Arm: Gyros inconsistent")
    assert line == "arming refused (MAV_RESULT_FAILED): Arm: Gyros inconsistent -- attempt 1, retrying every 2 s"
    a.sent(2.0)
    assert not a.gave_up(9.9) and a.gave_up(10.1) and not a.due(10.1, True)
    assert a.failure().startswith("could not arm: 2 attempts in 10 s, last: arming refused (MAV_RESULT_FAILED)")


def test_takeoff_ramp_is_rate_limited_and_waits_for_the_vehicle():
    ap = Approach(target=0.9, climb_rate=0.5, tolerance=0.05, hold=1.0, max_extra=5.0)
    ap.start(0.0)
    dt = 0.005
    z = [ap.step(k * dt, dt, 0.0) for k in range(400)]
    assert np.max(np.diff([0.0] + z)) <= 0.5 * dt + 1e-12 and z[-1] == 0.9
    assert not ap.done                                  # the vehicle is not there yet
    k0 = 400
    for k in range(k0, k0 + 199):
        ap.step(k * dt, dt, 0.88)
    assert not ap.done
    ap.step((k0 + 201) * dt, dt, 0.88)
    assert ap.done and not ap.timed_out                 # held within 5 cm for 1 s
    assert ap.outcome() == pytest.approx({"held": True, "off_start": False, "target_m": 0.9, "error_at_start_m": -0.02,
                                          "waited_s": (k0 + 201) * dt - ap.t_ramp_end, "trim_m": 0.0,
                                          "tolerance_m": 0.05, "timeout_s": 5.0})
    late = Approach(target=0.9, max_extra=1.0)
    late.start(0.9)
    late.step(0.0, dt, 0.5)
    assert not late.done and not late.timed_out
    late.step(1.0, dt, 1.15)
    assert late.done and late.timed_out                 # gives up waiting: the trajectory starts anyway,
    assert late.last_error == pytest.approx(0.25)       # and says how far off the vehicle was
    assert late.outcome()["held"] is False and late.outcome()["waited_s"] == 1.0 and late.outcome()["off_start"]


def _sagging_takeoff(eng: Engagement, sag: float, seconds: float, dt: float = 0.005) -> tuple[list, list, list]:
    """Fly ``eng``'s take-off on a vehicle that hovers ``sag`` m below its reference (a controller without an
    integrator on a heavier vehicle: z follows r - sag at 3 1/s); (references, reasons, heights) per tick."""
    z, refs, reasons, zs = 0.0, [], [], []
    eng.update(True, 0.0, np.array([z, 0.0]), z, "OFFBOARD")
    for k in range(int(seconds / dt)):
        t = k * dt
        if k:
            eng.update(True, t, np.array([z, 0.0]), z, "OFFBOARD")
        r, why = eng.reference(np.array([1.0, 0.0]), np.array([z, 0.0]), t, dt, heard=True, engaged=True, fresh=True)
        z += 3.0 * (max(r[0] - sag, 0.0) - z) * dt
        refs.append(r.copy()), reasons.append(why), zs.append(z)
    return refs, reasons, zs


def test_a_take_off_that_hovers_low_is_trimmed_to_the_start_before_the_trajectory_starts():
    """A vehicle 0.35 m heavier than its model hovers 0.35 m below the start: the approach trims its reference
    until the vehicle holds the start, the trajectory starts there, and the trim is blended back to the
    trajectory's reference at the blend's rate (no step); a vehicle that holds the start unaided is not trimmed."""
    events = EventLog(verbose=False)
    eng = Engagement(events, blend_rates=(0.5, 0.5), takeoff=True, start_height=lambda: 1.0, timeout=20.0)
    refs, reasons, zs = _sagging_takeoff(eng, sag=0.35, seconds=16.0)
    first = reasons.index("blend")  # the tick after the approach ended
    assert set(reasons[:first]) == {"takeoff"} and eng.approach is None
    res = eng.approach_result
    assert res["held"] and not res["off_start"] and res["trim_m"] == pytest.approx(0.35, abs=0.03)
    assert abs(zs[first - 1] - 1.0) <= 0.05  # the steering starts where the trajectory does
    said = [e for _, e in events.events]
    assert said[-2].startswith("take-off: the reference trimmed +0.3") and "handed back" in said[-2]
    assert said[-1] == "at the trajectory's start height: trajectory starts"
    z_ref = np.array([r[0] for r in refs])
    assert np.max(np.abs(np.diff(z_ref))) <= 0.5 * 0.005 + 1e-9  # ramp, trim and hand-back: never a step
    assert z_ref[-1] == 1.0 and reasons[-1] == ""  # handed back: the trajectory's own reference, engaged
    plain = Engagement(EventLog(), blend_rates=(0.5, 0.5), takeoff=True, start_height=lambda: 1.0, timeout=20.0)
    _, reasons, _ = _sagging_takeoff(plain, sag=0.01, seconds=6.0)
    assert plain.approach_result["trim_m"] == 0.0 and "blend" not in reasons


def test_a_take_off_that_times_out_says_the_trajectory_started_off_its_start():
    events = EventLog()
    eng = Engagement(events, blend_rates=(0.5, 0.5), takeoff=True, start_height=lambda: 1.0, timeout=2.0)
    _sagging_takeoff(eng, sag=0.35, seconds=8.0)
    res = eng.approach_result
    assert not res["held"] and res["off_start"] and res["error_at_start_m"] < -0.05
    assert events.events[-1][1].startswith("WARNING: OFF ITS START: did not hold the start height within 0.05 m")
    assert events.events[-1][1].endswith("trajectory starts anyway")


def test_blend_starts_at_the_measurement_and_hands_over_exactly():
    b = RefBlend((0.5, 0.5))
    assert np.array_equal(b.apply(np.array([1.0, 0.1]), 0.005), [1.0, 0.1])  # inactive: unchanged
    b.start(np.array([0.8, 0.0]))
    out = [b.apply(np.array([1.0, 0.1]), 0.005) for _ in range(100)]  # 0.2 m at 2.5 mm per tick
    steps = np.abs(np.diff(np.vstack([[0.8, 0.0]] + out), axis=0))
    assert np.all(steps <= 0.0025 + 1e-12)
    assert np.array_equal(out[-1], [1.0, 0.1]) and not b.active


@settings(max_examples=200, deadline=None)
@given(y0=st.floats(-2.0, 2.0), r0=st.floats(-2.0, 2.0), speed=st.floats(-3.0, 3.0), wiggle=st.floats(0.0, 2.0))
def test_blend_ends_on_a_path_faster_than_its_rate(y0, r0, speed, wiggle):
    """Whatever the path does (here up to 6x the 0.5 m/s rate), the offset to it shrinks by the rate per tick:
    the hand-over ends within |offset| / rate, and the applied reference moves with the path plus at most one
    rate step per tick (the gate's rule for a correction)."""
    dt, rate = 0.005, 0.5
    b = RefBlend((rate,))
    b.start(np.array([y0]))
    t = np.arange(0, 2000) * dt
    r = r0 + speed * t + wiggle * np.sin(7.0 * t)
    out = np.array([b.apply(np.array([ri]), dt)[0] for ri in r])
    n_end = int(np.ceil(abs(y0 - r0) / (rate * dt) + 1e-9)) + 1
    assert not b.active and np.array_equal(out[n_end:], r[n_end:])
    corr = np.concatenate([[y0 - r0], out - r])
    assert np.all(np.abs(np.diff(corr)) <= rate * dt + 1e-12)


def _fly_against(tmp_path, veh: FakeVehicle, port: int, *args: str) -> tuple[int, str]:
    """Start the fake vehicle, run one bridge on ``port`` with ``args`` until it exits; (exit code, output)."""
    pr = Procs(tmp_path)
    try:
        veh.start()
        br = pr.spawn("bridge", f"udpin:127.0.0.1:{port}", *args, name="bridge")
        return pr.wait(br, 60), pr.log(br)
    finally:
        veh.close()
        pr.cleanup()


@pytest.mark.e2e
def test_wrong_autopilot_is_refused_before_any_command(tmp_path):
    port = free_port()
    veh = FakeVehicle(port)  # PX4 heartbeat
    rc, out = _fly_against(tmp_path, veh, port, "--autopilot", "ardupilot", "--mode", "passthrough", "--offboard", "--arm",
                           "--timeout", "30")
    assert rc == 4, out
    assert "heartbeat says PX4 (autopilot 12) but the bridge is set for ardupilot" in out
    assert veh.commands == [] and veh.setpoints == []


@pytest.mark.e2e
def test_a_disarmed_vehicle_left_in_offboard_gets_idle_thrust_until_it_reports_armed(tmp_path):
    # PX4 returns to OFFBOARD after LAND and disarm: the next flight's ARM puts it straight into
    # off-board flight, a heartbeat before the bridge knows. Until then it must get idle thrust.
    pr = Procs(tmp_path)
    port = free_port()
    veh = FakeVehicle(port, z=0.0)
    veh.armed = False
    # armed 0.3 s after the accepted ARM: >= 60 setpoints at 200 Hz before its heartbeat can say so (without the
    # delay, an ARM accepted just before a heartbeat left two, and the window tested nothing)
    veh.arm_delay = 0.3
    try:
        veh.start()
        # (the vehicle stays on the ground: the approach times out, the sooner the better)
        br = pr.spawn("bridge", f"udpin:127.0.0.1:{port}", "--mode", "passthrough", "--arm", "--takeoff",
                      "--approach-timeout", "0.5", "--duration", "1", "--log", str(tmp_path / "t.npz"),
                      "--timeout", "30", name="bridge")
        assert pr.wait(br, 60) == 0, pr.log(br)
    finally:
        veh.close()
        pr.cleanup()
    assert veh.armed_hb_at is not None
    before = [m.thrust for rx, m in veh.setpoints if rx < veh.armed_hb_at]
    after = [m.thrust for rx, m in veh.setpoints if rx > veh.armed_hb_at + 0.1]
    assert len(before) > 20 and max(before) == 0.0
    assert min(after) > 0.2  # then the take-off: the controller's thrust
    from firmware_bridge.ticklog import load_ticklog

    t = load_ticklog(tmp_path / "t.npz").ticks
    assert np.all(t["sp_thrust"][~t["armed"].astype(bool)] == 0.0)


@pytest.mark.e2e
@pytest.mark.parametrize("z", [0.5, 0.9])
def test_the_approach_holds_or_times_out_as_configured_and_says_so(tmp_path, z):
    # The fake vehicle does not move. At 0.5 m the take-off ramp ends at 0.9 m, the height never
    # holds, and after --approach-timeout the trajectory starts with a warning; at 0.9 m it holds for
    # 1 s. The summary says how the approach ended.
    port = free_port()
    veh = FakeVehicle(port, z=z)
    rc, out = _fly_against(tmp_path, veh, port, "--mode", "passthrough", "--takeoff", "--approach-timeout", "1.5",
                           "--duration", "1", "--summary", str(tmp_path / "s.json"), "--timeout", "30", "--verbose")
    assert rc == 0, out
    ap = read_json(tmp_path / "s.json")["approach"]
    assert ap["timeout_s"] == 1.5 and ap["target_m"] == pytest.approx(0.9)
    assert ap["error_at_start_m"] == pytest.approx(z - 0.9, abs=1e-6)
    if z == 0.5:
        assert ap["held"] is False and ap["waited_s"] == pytest.approx(1.5, abs=0.011)   # to a tick or two
        assert ap["off_start"] is True and ap["trim_m"] == pytest.approx(0.0, abs=0.005)  # timed out as the trim began
        assert ("WARNING: OFF ITS START: did not hold the start height within 0.1 m for 1 s in 1.5 s (height error "
                "now -0.400 m") in out
    else:
        assert ap["held"] is True and ap["waited_s"] == pytest.approx(1.0, abs=0.011)
        assert "at the trajectory's start height: trajectory starts" in out and "WARNING" not in out
    for key, msg in (("approach_timeout", r"--approach-timeout must be a finite number in \(0, 3600\]; got nan"),
                     ("approach_tolerance", r"--approach-tolerance must be a finite number in \(0, 10\]; got nan")):
        with pytest.raises(ValueError, match=msg):
            BridgeConfig(mode="passthrough", takeoff=True, **{key: float("nan")})


@pytest.mark.e2e
@pytest.mark.parametrize("refusals", [2, -1])
def test_arming_refused_then_accepted_or_refused_forever(tmp_path, refusals):
    port = free_port()
    veh = FakeVehicle(port)
    veh.armed, veh.arm_refusals = False, refusals
    rc, out = _fly_against(tmp_path, veh, port, "--mode", "passthrough", "--arm", "--arm-timeout", "5", "--duration", "1",
                           "--summary", str(tmp_path / "s.json"), "--timeout", "30")
    s = read_json(tmp_path / "s.json")
    arms = veh.commands.count(mavlink.MAV_CMD_COMPONENT_ARM_DISARM)
    if refusals > 0:
        assert rc == 0, out
        assert s["arming"]["attempts"] == 3 == arms and len(s["arming"]["refusals"]) == 2
        assert s["stop_reason"].startswith("duration")
    else:
        assert rc == 5, out
        assert "could not arm: 3 attempts in 5 s, last: arming refused (MAV_RESULT_TEMPORARILY_REJECTED)" in out
        assert s["stop_reason"] == "arming failed" and arms == 3


@pytest.mark.e2e
@pytest.mark.realtime
@pytest.mark.parametrize("mode", ["passthrough", "feedforward"])
def test_a_stall_in_flight_never_restarts_or_reanchors_the_trajectory(tmp_path, mode):
    # The fake vehicle is armed and in OFFBOARD from the start (engaged on the first tick: the frame
    # is captured on that tick, before anything is commanded); then it goes silent for 2 s.
    # feedforward: the table's row follows the trajectory clock across the re-engagement.
    from ddpc_codegen.runtime.baselines import FeedforwardPolicy
    from firmware_bridge.ticklog import REASONS, load_ticklog

    delta = np.column_stack([0.01 * np.sin(2 * np.pi * np.arange(4000) / 400), np.zeros(4000)])
    table = FeedforwardPolicy(delta, 0.005).save(tmp_path / "ff.npz")
    extra = ["--feedforward", str(table)] if mode == "feedforward" else []
    pr = Procs(tmp_path)
    port = free_port()
    veh = FakeVehicle(port, z=1.0)
    try:
        veh.start()
        br = pr.spawn("bridge", f"udpin:127.0.0.1:{port}", "--mode", mode, *extra, "--link-timeout", "1.0",
                      "--log", str(tmp_path / "t.npz"), "--summary", str(tmp_path / "s.json"), "--timeout", "30",
                      name="bridge")
        assert veh.first_setpoint.wait(30), pr.log(br)
        import time

        time.sleep(2.0)
        veh.telemetry = veh.heartbeat = False
        time.sleep(2.0)
        veh.telemetry = veh.heartbeat = True
        time.sleep(2.0)
        assert pr.terminate(br) == 0, pr.log(br)
    finally:
        veh.close()
        pr.cleanup()
    s = read_json(tmp_path / "s.json")
    ev = [e for _, e in s["events"]]
    assert s["activations"] == 2 and sum(e.startswith("engaged (OFFBOARD") for e in ev) == 1
    assert any(e.startswith("re-engaged (OFFBOARD): trajectory continues at t = ") and e.endswith("same frame")
               for e in ev)
    assert s["frame"]["origin"] == [0.0, 0.0] and s["frame"]["yaw0"] == pytest.approx(0.0, abs=1e-6)
    t = load_ticklog(tmp_path / "t.npz").ticks
    has = np.isfinite(t["t_traj"])
    lag = t["t_wall"][has] - t["t_traj"][has]   # one trajectory clock, never restarted (also across the
    assert np.ptp(lag) < 0.1                      # quiet second after 1 s of stale telemetry: no ticks logged)
    # Between consecutive engaged ticks the reference moves by at most the blend rate plus the
    # trajectory's own rate over the time between them (a loaded machine skips grid ticks: the trajectory
    # clock then moves 10-25 ms at once): the re-engagement starts from the measured height, no jump.
    act = t["active"].astype(bool)
    both = act[1:] & act[:-1]
    bound = 0.5 * 0.005 + 0.19 * np.diff(t["t_traj"]) * 2
    assert np.all(np.abs(np.diff(t["u"][:, 0]))[both] < bound[both])
    assert (t["reason"] == REASONS.index("blend")).sum() > 0
    if mode == "feedforward":
        k = np.flatnonzero(t["reason"] == REASONS.index("feedforward"))
        row = np.rint(t["t_traj"][k] / 0.005).astype(int)
        np.testing.assert_allclose(t["u"][k], t["r_nom"][k] + delta[row], atol=1e-12)
        step = np.diff(row)  # the stall: the rows skip the stalled time, never go back to 0
        assert step.min() >= 1 and step.max() > 300 and row[0] < 100


@pytest.mark.compiler  # flying_solver generates and compiles
def test_a_trajectory_outside_the_solver_bounds_is_refused_at_start(flying_solver):
    from ddpc_codegen.robot.profile import load_profile
    from ddpc_codegen.robot.trajectory import EllipseTrajectory
    from firmware_bridge.bridge import Bridge, BridgeConfig
    from firmware_bridge.preflight import check_trajectory_bounds

    check_trajectory_bounds(np.array([0.9, 1.5]), 0.0, 3.0)
    high = EllipseTrajectory(center=(0.0, 3.8), radii=(1.0, 0.3))
    cfg = BridgeConfig(mode="steer", solver=str(flying_solver), controller=load_profile("pogox").controller,
                       trajectory=high, url=f"udpin:127.0.0.1:{free_port()}")
    with pytest.raises(ValueError, match=r"the trajectory spans z = 3.500 .. 4.100 m but the solver's z_ref bounds "
                                         r"are \[0, 3\] m: steering could never engage"):
        Bridge(cfg)
