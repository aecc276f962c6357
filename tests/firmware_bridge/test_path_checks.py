"""Every input that defines the flown path is checked as a path before arming (exit 2, one line naming the
file or flag, the limit and the value), and the last gate clamps every applied reference to the envelope's
rate limits in flight (collect included) with one event per episode. The probes of issue #46 pass every
per-key check; each is refused here."""

from __future__ import annotations

import json
import math
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ddpc_codegen.robot.profile import Envelope, load_profile, shipped_profiles
from ddpc_codegen.robot.trajectory import EllipseTrajectory, RandomSmoothTrajectory
from ddpc_codegen.robot.trajectory_files import trajectory_from_arg
from ddpc_codegen.runtime.baselines import FeedforwardPolicy
from ddpc_codegen.values.prefilter import PrefilterModel
from firmware_bridge.bridge_config import BridgeConfig
from firmware_bridge.cli import bridge_main
from firmware_bridge.events import EventLog
from firmware_bridge.gate import GATE_FLAGS, SetpointGate
from firmware_bridge.path_checks import (MAX_HOVER_OFFSET_M, PathRefused, check_excitation, check_thrust_limits,
                                         check_trajectory_path, path_limits, path_times)
from firmware_bridge.preflight import EnvelopeRefusal, VehicleInfo, check_vehicle_thrust
from firmware_bridge.profiles import make_profile
from firmware_bridge.reference_stage import TickReference
from firmware_bridge.tick_gate import TickGate
from support.bridge_helpers import free_port

PX4 = make_profile("px4", prestream=1.0)


def _refused(capsys, *args: str) -> str:
    """The one line of a refused ``ddpc-bridge`` (exit 2, before anything connects: no vehicle needed)."""
    rc = bridge_main(["udpin:127.0.0.1:9", "--wait-heartbeat", "1", *args])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "\n" not in err, err
    return err


# ----------------------------------------------------------------------------- the probes, through the CLI
def test_a_prefilter_that_would_fly_high_or_into_the_ground_is_refused(tmp_path, capsys):
    for tag, gain in (("small", 0.001), ("negative", -1.0)):
        f = tmp_path / f"{tag}.json"
        PrefilterModel(gain=(gain, 1.0), offset=(0.0, 0.0), lead=(10, 0), dt=0.005).save(f)
        err = _refused(capsys, "--mode", "prefilter", "--prefilter", str(f))
        bound = "upper bound 10 m" if gain > 0 else "lower bound 0 m"
        assert re.fullmatch(rf"ddpc-bridge: error: --prefilter {f}: z_ref on the path reaches \S+ m, outside the "
                            rf"envelope's {bound}", err), err
    ok = tmp_path / "ok.json"
    PrefilterModel(gain=(0.95, 1.0), offset=(0.02, 0.0), lead=(10, 0), dt=0.005).save(ok)
    BridgeConfig(mode="prefilter", prefilter=str(ok))


def test_a_feedforward_table_outside_the_envelope_around_the_path_is_refused(tmp_path, capsys):
    for value in (20.0, -1.9):
        f = tmp_path / f"ff{value}.npz"
        FeedforwardPolicy(delta=np.tile([value, 0.0], (4000, 1)), dt=0.005).save(f)
        err = _refused(capsys, "--mode", "feedforward", "--feedforward", str(f))
        want = "21.5 m, outside the envelope's upper bound 10 m" if value > 0 else \
            "-1 m, outside the envelope's lower bound 0 m"
        assert err == f"ddpc-bridge: error: --feedforward {f}: z_ref on the path reaches {want}"
    FeedforwardPolicy(delta=np.tile([0.1, 0.02], (4000, 1)), dt=0.005).save(tmp_path / "ok.npz")
    BridgeConfig(mode="feedforward", feedforward=str(tmp_path / "ok.npz"))


def test_a_profile_trajectory_too_fast_and_a_file_with_a_step_are_refused(tmp_path, capsys):
    prof = tmp_path / "fast.toml"
    prof.write_text('extends = "pogox"\n[trajectory]\nradii = [1e4, 1e4]\nperiod = 1.0\n')
    err = _refused(capsys, "--mode", "passthrough", "--profile", str(prof))
    assert re.fullmatch(r"ddpc-bridge: error: the profile's \[trajectory\]: speed 6\d{4}\.?\d* m/s, outside the "
                        r"envelope's max_speed 3 m/s", err), err
    step = tmp_path / "step.csv"
    step.write_text("t,x,z\n0,0,1\n1,0,1\n1.01,0,1001\n2,0,1001\n")
    err = _refused(capsys, "--mode", "passthrough", "--trajectory", str(step))
    assert re.fullmatch(rf"ddpc-bridge: error: --trajectory {step}: speed \S+ m/s, outside the envelope's "
                        r"max_speed 3 m/s", err), err


def test_collect_excitation_beyond_the_rate_limits_or_the_envelope_is_refused(capsys):
    err = _refused(capsys, "--mode", "collect", "--excitation", "1e308,1e308")
    assert err == ("ddpc-bridge: error: --excitation: z_ref amplitude 1e+308 m, outside the envelope's ref_rate 30 m/s "
                   "(a PRBS step is twice the amplitude in one tick: at most 0.075 m at 200 Hz)")
    env = Envelope()
    nominal = np.array([[0.05, 0.0], [1.5, 0.1]])  # a path starting 5 cm above the take-off point
    with pytest.raises(PathRefused, match=r"^--excitation: z_ref on the path reaches -0.02 m, outside the envelope's "
                                          r"lower bound 0 m$"):
        check_excitation((0.07, 0.03), nominal, env, "flying", 0.5, 200.0)
    with pytest.raises(PathRefused, match=r"^--excitation: pitch_ref amplitude 0.4 rad, outside the envelope's ref_rate"):
        check_excitation((0.01, 0.4), nominal, env, "flying", 0.5, 200.0)
    BridgeConfig(mode="collect")  # the defaults fit
    check_excitation((0.01, 0.02, 0.02), None, load_profile("pogox_hopping").envelope, "hopping", 0.5, 200.0)


def test_thrust_limits_must_bracket_the_hover_thrust(capsys):
    err = _refused(capsys, "--mode", "passthrough", "--thrust-min", "0.9")
    assert err == ("ddpc-bridge: error: --thrust-min 0.9 is not below the hover thrust 0.756 (the controller "
                   "model's): the vehicle could only climb")
    info = VehicleInfo(autopilot=12, vehicle_type=2, hover_thrust=0.5)
    with pytest.raises(EnvelopeRefusal, match=r"^--thrust-max 0.45 is not above the hover thrust 0.500 \(the "
                                              r"vehicle's MPC_THR_HOVER\): the vehicle could only sink$"):
        check_vehicle_thrust(info, 0.756, 0.0, 0.45, PX4)
    with pytest.raises(EnvelopeRefusal, match=r"hover thrust 0.756 \(the controller model's; the vehicle did not"):
        check_vehicle_thrust(VehicleInfo(12, 2), 0.756, 0.8, 1.0, PX4)
    check_vehicle_thrust(info, 0.756, 0.1, 0.9, PX4)
    check_thrust_limits(math.nan, 0.9, 1.0, "unknown")  # nothing known: nothing to check


def test_a_controller_model_far_from_the_vehicles_hover_thrust_is_refused_before_arming():
    # make fuzz: a profile with max_thrust 4x the vehicle's (model hover 0.18 vs 0.80) sank into the ground with
    # every reference inside the envelope; its PD height loop settles g / kp_z * (0.8 / 0.18 - 1) = 3.4 m low
    vehicle = VehicleInfo(autopilot=12, vehicle_type=2, hover_thrust=0.8)
    flying, hopping = load_profile("pogox").controller, load_profile("pogox_hopping").controller  # kp_z 10
    with pytest.raises(EnvelopeRefusal, match=r"^the controller model's hover thrust 0.181 \(model_mass g / "
                                              r"max_thrust\) is far from the vehicle's MPC_THR_HOVER 0.800: its height "
                                              r"loop would settle 3.35 m below every reference \(at most 0.25 m; "):
        check_vehicle_thrust(vehicle, 0.181, 0.0, 1.0, PX4, flying)
    with pytest.raises(EnvelopeRefusal, match=r"settle 0.27 m above every reference"):
        check_vehicle_thrust(VehicleInfo(12, 2, hover_thrust=0.55), 0.756, 0.0, 1.0, PX4, flying)
    check_vehicle_thrust(vehicle, 0.756, 0.0, 1.0, PX4, flying)              # the shipped model: 0.06 m
    assert 0.981 * (0.8 / 0.756 - 1) < MAX_HOVER_OFFSET_M
    check_vehicle_thrust(vehicle, 0.181, 0.0, 1.0, PX4, hopping)             # hopping: no height-loop check
    check_vehicle_thrust(VehicleInfo(12, 2), 0.181, 0.0, 1.0, PX4, flying)   # not read: nothing to compare


def test_thrust_max_below_the_vehicles_own_hover_thrust_is_refused_before_arming(procs, tmp_path):
    """ddpc-vehicle reports its true hover thrust (0.800), the model's is 0.756: 0.78 passes the check before
    connecting and is refused once the vehicle said, exit 2, before any arming or mode command."""
    port = free_port()
    veh = procs.spawn("vehicle", f"udpout:127.0.0.1:{port}", name="veh")
    br = subprocess.run([sys.executable, "-m", "firmware_bridge.cli", f"udpin:127.0.0.1:{port}", "--mode", "passthrough", "--arm", "--offboard",
                         "--thrust-max", "0.78", "--timeout", "30", "--summary", str(tmp_path / "s.json")],
                        capture_output=True, text=True, timeout=60, cwd=str(tmp_path))
    procs.terminate(veh)
    lines = br.stderr.strip().splitlines()
    assert br.returncode == 2, br.stderr
    assert re.fullmatch(r"ddpc-bridge: error: --thrust-max 0.78 is not above the hover thrust 0.8\d\d \(the "
                        r"vehicle's MPC_THR_HOVER\): the vehicle could only sink", lines[-1]), lines
    ev = " | ".join(e for _, e in json.loads((tmp_path / "s.json").read_text())["events"])
    assert "arming" not in ev.lower() and "requesting OFFBOARD" not in ev


# ----------------------------------------------------------------------------- what ships still flies
def test_every_shipped_profile_and_trajectory_passes_its_envelope():
    for name in shipped_profiles():
        prof = load_profile(name)
        traj = prof.trajectory if prof.controller.mode == "flying" else None
        BridgeConfig(mode="passthrough", controller=prof.controller, trajectory=traj, envelope=prof.envelope,
                     contact=prof.contact)
        BridgeConfig(mode="collect", controller=prof.controller, trajectory=traj, envelope=prof.envelope,
                     contact=prof.contact)
    for seed in range(30):
        BridgeConfig(mode="passthrough", trajectory=trajectory_from_arg(f"random:{seed}"))
    BridgeConfig(mode="passthrough", trajectory=trajectory_from_arg("ellipse"))


def test_every_trajectory_the_repo_ships_passes():
    files = subprocess.run(["git", "ls-files", "*.csv", "*traj*.toml"], capture_output=True, text=True,
                           cwd=str(Path(__file__).resolve().parents[2])).stdout.split()
    for f in files:
        if f.endswith((".csv", ".toml")) and "traj" in f:
            BridgeConfig(mode="passthrough", trajectory=trajectory_from_arg(f))


# ----------------------------------------------------------------------------- properties of the path checks
_ENV = Envelope(z_min=0.0, z_max=10.0, radius=10.0, max_speed=3.0, max_accel=3.0)


@settings(max_examples=40, deadline=None)
@given(rx=st.floats(0.0, 2.0), rz=st.floats(0.0, 0.5), period=st.floats(8.0, 30.0), cz=st.floats(1.0, 5.0))
def test_a_path_inside_the_limits_passes_and_scaled_beyond_one_is_refused_naming_it(rx, rz, period, cz):
    traj = EllipseTrajectory(center=(0.0, cz), radii=(rx, rz), period=period, spin_up=2.0)
    lim = check_trajectory_path(traj, _ENV, 200.0)  # inside: passes
    for key, limit, name in (("speed", "max_speed", "speed"), ("accel", "max_accel", "acceleration"),
                             ("radius", "radius", "horizontal distance from the start")):
        if lim[key] < 1e-6:
            continue
        tight = Envelope(**{**_ENV.__dict__, limit: lim[key] / 1.05})
        with pytest.raises(PathRefused, match=rf"^trajectory: {name} [\d.e+-]+ m(/s\^2|/s)?, outside the envelope's "
                                              rf"{limit} "):
            check_trajectory_path(traj, tight, 200.0)
    high = Envelope(**{**_ENV.__dict__, "z_max": lim["z_hi"] - 0.01})
    with pytest.raises(PathRefused, match=r"^trajectory: highest height [\d.]+ m, outside the envelope's z_max"):
        check_trajectory_path(traj, high, 200.0)


@settings(max_examples=12, deadline=None)
@given(seed=st.integers(0, 10_000), scale=st.floats(2.5, 50.0))
def test_a_random_path_scaled_in_speed_is_refused_for_its_speed_or_acceleration(seed, scale):
    """Sampled at 50 Hz (the check's rate is the bridge's; an endless path is sampled over 600 s)."""
    base = RandomSmoothTrajectory(seed=seed)
    check_trajectory_path(base, Envelope(), 50.0)
    fast = RandomSmoothTrajectory(seed=seed, band=(0.05 * scale, 0.2 * scale), max_accel=1.5 * scale ** 2)
    lim = path_limits(fast, path_times(fast, 50.0))
    with pytest.raises(PathRefused, match=r"^--trajectory random:\d+: (speed|acceleration) "):
        check_trajectory_path(fast, Envelope(max_speed=lim["speed"] / 1.01, max_accel=lim["accel"] / 1.01), 50.0,
                              f"--trajectory random:{seed}")


# ----------------------------------------------------------------------------- the in-flight clamp
def _tick_gate(rate=None, events=None) -> TickGate:
    gate = SetpointGate(np.array([0.0, -0.5]), np.array([10.0, 0.5]), rate)
    return TickGate(gate, events or EventLog(), max_step=None, max_tilt=0.5, thrust_min=0.0, thrust_max=1.0,
                    hover_thrust=0.5, max_age=None, guard_hold=0.0, ref_rate=np.array([30.0, 100.0]), period=0.005)


def _ref(u, r=(1.0, 0.0)) -> TickReference:
    return TickReference(r_nom=np.array(r, float), y=np.array(r, float), u=np.array(u, float), reason="collect")


def test_collect_references_are_clamped_to_the_envelope_and_its_rate_with_one_event_per_episode():
    events = EventLog()
    g = _tick_gate(events=events)
    u, flags = g.reference(_ref([1.0, 0.0]))
    assert u.tolist() == [1.0, 0.0] and flags == 0
    seen = []
    for k in range(40):  # a PRBS of +-1e308: each tick at most 0.15 m / 0.5 rad from the last, inside the box
        amp = 1e308 if k % 2 else -1e308
        u, flags = g.reference(_ref([amp, amp]))
        seen.append(u.copy())
        assert flags & GATE_FLAGS["rate_limited"] or flags & GATE_FLAGS["envelope"]
    seen = np.array([[1.0, 0.0], *seen])
    assert np.all(np.abs(np.diff(seen, axis=0)) <= np.array([0.15, 0.5]) + 1e-12)
    assert np.all(seen[:, 0] >= 0.0) and np.all(seen[:, 0] <= 10.0) and np.all(np.abs(seen[:, 1]) <= 0.5)
    clamp_events = [e for _, e in events.events if e.startswith("envelope: reference")]
    assert len(clamp_events) == 1 and g.gate.counts["ref_clamped"] == 40
    for _ in range(200):  # a quiet second: the next clamp is a new episode
        g.reference(_ref(seen[-1]))
    g.reference(_ref([9.0, 0.0]))
    assert len([e for _, e in events.events if e.startswith("envelope: reference")]) == 2
    assert g.summary()["ref_clamped"] == 41


def test_a_steered_reference_inside_the_rate_is_never_altered():
    g = _tick_gate(rate=np.array([0.05, 0.05]))
    for k in range(50):
        z = 1.0 + 0.02 * k
        u, flags = g.reference(_ref([z + 0.01, 0.0], r=(z, 0.0)))
        assert u.tolist() == pytest.approx([z + 0.01, 0.0]) and flags == 0
    assert g.gate.counts["ref_clamped"] == 0



@pytest.mark.parametrize("autopilot", ["px4", "ardupilot"])
def test_the_sitl_demo_flights_pass_their_profiles_envelope(tmp_path, autopilot):
    """Every flight command ``make sitl-demo`` builds (collect with its excitation, passthrough, the velocity
    feed-forward profile, steered on the ellipse, the steps file and a random path) passes the path checks."""
    from types import SimpleNamespace

    from ddpc_codegen.testbed.sitl_demo import COLLECT
    from ddpc_codegen.testbed.sitl_conditions import write_steps_trajectory
    from ddpc_codegen.testbed.sitl_flight import bridge_command, ctrl_ff_profile
    from firmware_bridge.cli import bridge_config_from_args, build_bridge_parser

    sitl = SimpleNamespace(url="udpin:127.0.0.1:14550", sysid=1)
    steps = str(write_steps_trajectory(tmp_path / "steps.csv"))
    ff = str(ctrl_ff_profile(autopilot, tmp_path))
    flights = [("collect", COLLECT[autopilot]), ("passthrough", ()), ("passthrough", ("--profile", ff)),
               ("steer", ("--solver", "s")), ("steer", ("--solver", "s", "--trajectory", steps)),
               ("passthrough", ("--trajectory", steps)), ("steer", ("--solver", "s", "--trajectory", "random:3"))]
    for mode, extra in flights:
        cmd = bridge_command(sitl, autopilot, mode, tmp_path, 20.0, 60.0, extra)
        cfg = bridge_config_from_args(build_bridge_parser().parse_args(cmd[4:]))
        assert cfg.envelope is not None and cfg.mode == mode


def test_a_hopper_above_the_envelope_or_too_fast_and_a_takeoff_too_fast_are_refused(tmp_path, capsys):
    prof = tmp_path / "hop.toml"
    prof.write_text('extends = "pogox_hopping"\n[controller]\napex_height = 8.0\n')
    err = _refused(capsys, "--mode", "passthrough", "--profile", str(prof))
    assert err == ("ddpc-bridge: error: the profile's [controller]: apex_height 8 m, outside the envelope's z_max 5 m")
    prof.write_text('extends = "pogox_hopping"\n[controller]\ntarget_velocity = [4.0, 3.0]\n')
    err = _refused(capsys, "--mode", "passthrough", "--profile", str(prof))
    assert err == ("ddpc-bridge: error: the profile's [controller]: target_velocity speed 5 m/s, outside the "
                   "envelope's max_speed 3 m/s")
    err = _refused(capsys, "--mode", "passthrough", "--takeoff", "--climb-rate", "5")
    assert err == "ddpc-bridge: error: --climb-rate: take-off speed 5 m/s, outside the envelope's max_speed 3 m/s"
    # make fuzz: a hopper at 1.36 m/s in a 0.55 m radius left it within its 1 s flight
    prof.write_text('extends = "pogox_hopping"\n[controller]\ntarget_velocity = [1.2, 0.0]\n[envelope]\nradius = 1.0\n')
    err = _refused(capsys, "--mode", "passthrough", "--profile", str(prof), "--duration", "1.5")
    assert err == ("ddpc-bridge: error: the profile's [controller] target_velocity over --duration 1.5 s: distance "
                   "from the start 1.8 m, outside the envelope's radius 1 m")
    hop = load_profile(prof)
    BridgeConfig(mode="passthrough", controller=hop.controller, envelope=hop.envelope, duration=0.5)  # 0.6 m: inside


@settings(max_examples=30, deadline=None)
@given(gain=st.floats(0.05, 3.0), offset=st.floats(-2.0, 2.0))
def test_a_prefilter_passes_exactly_when_its_references_on_the_path_stay_inside(tmp_path_factory, gain, offset):
    """The default ellipse spans z 0.9 .. 1.5 m: the prefilter's z_ref (z - offset) / gain spans
    (0.9 - offset) / gain .. (1.5 - offset) / gain, which must lie in [0, 10] m; refusals name that bound."""
    f = tmp_path_factory.mktemp("pf") / "pf.json"
    PrefilterModel(gain=(gain, 1.0), offset=(offset, 0.0), lead=(5, 0), dt=0.005).save(f)
    lo, hi = sorted(((0.9 - offset) / gain, (1.5 - offset) / gain))
    inside = lo >= -1e-9 and hi <= 10.0 + 1e-9
    margin = min(abs(lo), abs(hi - 10.0))
    if margin < 1e-3:
        return  # on the bound: sampling decides
    if inside:
        BridgeConfig(mode="prefilter", prefilter=str(f))
    else:
        with pytest.raises(PathRefused, match=rf"^--prefilter {re.escape(str(f))}: z_ref on the path reaches \S+ m, "
                                              r"outside the envelope's (lower bound 0|upper bound 10) m$"):
            BridgeConfig(mode="prefilter", prefilter=str(f))



def test_a_path_whose_nominal_height_moves_faster_than_the_reference_rate_is_refused(tmp_path, capsys):
    """The ellipse climbs at up to 0.19 m/s: a profile allowing z_ref 0.1 m/s could only fly it clamped."""
    prof = tmp_path / "slow.toml"
    prof.write_text('extends = "pogox"\n[envelope]\nref_rate = [0.1, 100.0]\n')
    err = _refused(capsys, "--mode", "passthrough", "--profile", str(prof))
    assert re.fullmatch(r"ddpc-bridge: error: the profile's \[trajectory\]: z_ref on the path moves at 0\.1\d+ m/s, "
                        r"outside the envelope's ref_rate 0\.1 m/s", err), err
