"""The bridge's command line and configuration: profiles and TOML overrides, defaults, and every bad
option, port, path, table or per-reference value refused before anything connects."""

from __future__ import annotations

import re

import numpy as np
import pytest

from ddpc_codegen.errors import ConfigError


def test_controller_toml_overrides_the_model(tmp_path):
    from firmware_bridge.cli import bridge_config_from_args, build_bridge_parser

    f = tmp_path / "robot.toml"
    f.write_text('[controller]\nmodel_mass = 3.3\nkp_z = 12.0\n\n[trajectory]\nperiod = 12.0\nradii = [0.5, 0.2]\n')
    cfg = bridge_config_from_args(build_bridge_parser().parse_args(
        ["udpin:127.0.0.1:14540", "--mode", "passthrough", "--controller", str(f), "--max-step", "none"]))
    assert cfg.controller.model_mass == 3.3 and cfg.controller.kp_z == 12.0 and cfg.controller.mode == "flying"
    assert cfg.trajectory.period == 12.0 and cfg.trajectory.radii == (0.5, 0.2)
    assert cfg.max_step is None and cfg.max_age == pytest.approx(0.05)
    f.write_text("[controller]\nmodel_mas = 3.3\n")
    with pytest.raises(ConfigError, match=r"\[controller\] model_mas is not a known key"):
        bridge_config_from_args(build_bridge_parser().parse_args(["--mode", "passthrough", "--controller", str(f)]))


def test_bad_frame_gap_fill_and_start_options_are_refused(capsys):
    from firmware_bridge.bridge import BridgeConfig
    from ddpc_codegen.testbed.vehicle_cli import vehicle_main
    from ddpc_codegen.testbed.vehicle import VehicleConfig

    with pytest.raises(ValueError, match="frame must be 'start' or 'world'; got 'body'"):
        BridgeConfig(mode="passthrough", frame="body")
    with pytest.raises(ValueError, match=r"--max-gap-fill must be an integer in \[0, 1000\]; got -1"):
        BridgeConfig(mode="passthrough", max_gap_fill=-1)
    for bad in (-1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match=r"^--guard-hold must be a finite number in \[0, 3600\]; got "):
            BridgeConfig(mode="passthrough", guard_hold=bad)
    with pytest.raises(ValueError, match=r"prefilter mode needs a prefilter JSON file \(--prefilter"):
        BridgeConfig(mode="prefilter")
    with pytest.raises(ValueError, match="mode must be one of steer, passthrough, collect, prefilter, feedforward; "
                                         "got 'ilc'"):
        BridgeConfig(mode="ilc")
    with pytest.raises(ValueError, match=r"start_offset must be two finite numbers \(x, y\) \[m\]; got \(1.0,\)"):
        VehicleConfig(start_offset=(1.0,))
    with pytest.raises(ValueError, match="start_yaw must be finite"):
        VehicleConfig(start_yaw=float("nan"))
    assert vehicle_main(["udpout:127.0.0.1:9", "--start-offset", "1,2,3"]) == 2
    assert "start_offset must be two finite numbers" in capsys.readouterr().err


def test_bridge_flag_defaults_are_the_config_dataclass_defaults():
    """The defaults live in BridgeConfig only: no flag, no difference."""
    import dataclasses

    from firmware_bridge.cli import bridge_config_from_args, build_bridge_parser
    from firmware_bridge.bridge_config import BridgeConfig

    got = bridge_config_from_args(build_bridge_parser().parse_args(["--mode", "passthrough"]))
    want = BridgeConfig(mode="passthrough")
    diff = {f.name: (getattr(got, f.name), getattr(want, f.name)) for f in dataclasses.fields(want)
            if getattr(got, f.name) != getattr(want, f.name)}
    assert not diff


@pytest.mark.parametrize("args, message", [
    (["udpin:127.0.0.1:99999"], "port 99999 is outside 1..65535"),
    (["udpin:127.0.0.1:14999", "--log", "/nonexistent-dir/x.npz"], "/nonexistent-dir/x.npz: --log: folder /nonexistent-dir does not exist"),
    (["udpin:127.0.0.1:14999", "--summary", "/proc/x.json"], "/proc/x.json: --summary: not writable"),
    (["/dev/ttyDOES-NOT-EXIST"], "serial device /dev/ttyDOES-NOT-EXIST does not exist"),
    (["udpin:127.0.0.1:14999", "--takeoff", "--approach-tolerance", "0"], "--approach-tolerance must be a finite number in (0, 10]; got 0.0"),
    (["udpin:127.0.0.1:14999", "--takeoff", "--approach-timeout", "-1"], "--approach-timeout must be a finite number in (0, 3600]; got -1.0"),
    # issue 28: command-line values out of their range, refused before anything connects
    (["udpin:127.0.0.1:14999", "--sysid", "300"], "--sysid must be an integer in [1, 255]; got 300"),
    (["udpin:127.0.0.1:14999", "--max-tilt-deg", "400"], "--max-tilt-deg must be a finite number in (0, 90); got 400.0"),
    (["udpin:127.0.0.1:14999", "--duration", "-1"], "--duration must be a finite number in (0, 86400]; got -1.0"),
    (["udpin:127.0.0.1:14999", "--max-age-ms", "nan"], "--max-age-ms must be a finite number in (0, 10000]; got nan"),
    (["udpin:127.0.0.1:14999", "--target-system", "256"], "--target-system must be an integer in [0, 255]; got 256"),
    (["udpin:127.0.0.1:14999", "--rate", "inf"], "--rate must be a finite number in (0, 1000]; got inf"),
])
def test_bad_ports_paths_and_devices_are_refused_before_anything_flies(capsys, args, message):
    """Issue 12: errors named at start (exit 2), not a traceback or a log lost after the flight."""
    from firmware_bridge.cli import bridge_main

    assert bridge_main([*args, "--mode", "passthrough", "--wait-heartbeat", "1"]) == 2
    assert message in capsys.readouterr().err


def test_feedforward_mode_checks_its_table_before_flying(tmp_path):
    from ddpc_codegen.robot.profile import load_profile
    from ddpc_codegen.runtime.baselines import FeedforwardPolicy
    from firmware_bridge.bridge_config import BridgeConfig

    with pytest.raises(ValueError, match=r"feedforward mode needs a feed-forward table \(--feedforward table.npz\)"):
        BridgeConfig(mode="feedforward")
    ok = FeedforwardPolicy(np.zeros((10, 2)), 0.005).save(tmp_path / "ok.npz")
    assert BridgeConfig(mode="feedforward", feedforward=str(ok)).feedforward == str(ok)
    bad_dt = FeedforwardPolicy(np.zeros((10, 2)), 0.01).save(tmp_path / "dt.npz")
    with pytest.raises(ValueError, match=r"dt.npz: table tick 0.01 s does not match the bridge rate 200 Hz \(0.005 s\)"):
        BridgeConfig(mode="feedforward", feedforward=str(bad_dt))
    with pytest.raises(ValueError, match=r"ok.npz: table tick 0.005 s does not match the bridge rate 100 Hz"):
        BridgeConfig(mode="feedforward", feedforward=str(ok), rate_hz=100.0)
    cols = FeedforwardPolicy(np.zeros((10, 3)), 0.005).save(tmp_path / "cols.npz")
    with pytest.raises(ValueError, match=r"cols.npz: table has 3 columns \(shape \(10, 3\)\); the loop has m=2"):
        BridgeConfig(mode="feedforward", feedforward=str(cols))
    hop = FeedforwardPolicy(np.zeros((10, 2)), 0.005, "liftoff").save(tmp_path / "hop.npz")
    with pytest.raises(ValueError, match=r"hop.npz: table clock 'liftoff'; .* needs clock 'trajectory'"):
        BridgeConfig(mode="feedforward", feedforward=str(hop))
    (tmp_path / "junk.npz").write_bytes(b"not an npz")
    with pytest.raises(ValueError, match=r"--feedforward .*junk.npz: not a feed-forward table"):
        BridgeConfig(mode="feedforward", feedforward=str(tmp_path / "junk.npz"))
    with pytest.raises(ValueError, match="feedforward mode flies the flying scenario"):
        BridgeConfig(mode="feedforward", feedforward=str(ok),
                     controller=load_profile("pogox_hopping").controller)


@pytest.mark.parametrize("flags, message", [
    (["--max-step", "abc"], "argument --max-step: expected comma-separated numbers"),
    (["--max-step", "0.6"], r"max_step needs 2 values on the flying loop \(z_ref, pitch_ref\)"),
    (["--max-step=-1,0.5"], r"max_step must be finite and > 0 per reference"),
    (["--max-step", "nan,0.5"], r"max_step must be finite and > 0 per reference"),
    (["--blend-rates", "0,0.5"], r"blend_rates must be finite and > 0 per reference"),
    (["--excitation", "0.05,-0.01"], r"excitation must be finite and >= 0 per reference"),
])
def test_bad_channel_values_are_refused_before_connecting(flags, message, capsys):
    """A step guard of 0 or below would refuse every steered tick, NaN would never trip: refused with
    the key and the rule (exit 2 from the command line)."""
    from firmware_bridge.cli import bridge_config_from_args, build_bridge_parser

    p = build_bridge_parser()
    try:
        a = p.parse_args(["udpin:127.0.0.1:14540", "--mode", "passthrough", *flags])
    except SystemExit as e:
        assert e.code == 2 and re.search(message, capsys.readouterr().err)
        return
    with pytest.raises(ValueError, match=message):
        bridge_config_from_args(a)


def _parsed(*flags):
    from firmware_bridge.cli import bridge_config_from_args, build_bridge_parser

    return bridge_config_from_args(build_bridge_parser().parse_args(["udpin:127.0.0.1:14540", "--mode", "passthrough", *flags]))


def test_step_guard_comes_from_the_flag_then_the_profile_then_the_default():
    """PX4's profile carries the 0.6 m guard its shipped config needs ([steering] max_step), so a user
    flying it by hand gets it, and so does ArduCopter's; --max-step (numbers or none) overrides; other profiles keep 0.3 m."""
    assert _parsed("--profile", "px4_sih").max_step == (0.6, 0.5)
    assert _parsed("--profile", "px4_sih", "--max-step", "0.4,0.2").max_step == (0.4, 0.2)
    assert _parsed("--profile", "px4_sih", "--max-step", "none").max_step is None
    assert _parsed("--profile", "arducopter_sitl").max_step == (0.6, 0.5)
    assert _parsed().max_step == (0.3, 0.5)
    assert _parsed("--scenario", "hopping").max_step is None  # hopping's default: no guard
