"""Robot profiles: the shipped PogoX profile equals the simulator's flying setup; bad files are
refused with messages naming the file, the table, the key and the value."""

from __future__ import annotations

import pytest

from ddpc_codegen.errors import ConfigError
from ddpc_codegen.robot.profile import load_profile, shipped_profiles
from ddpc_codegen.robot.trajectory import EllipseTrajectory


def test_pogox_profile_is_the_simulated_flying_robot():
    from ddpc_codegen.sim.params import PogoXParams
    from ddpc_codegen.sim.scenarios import FlyingScenario

    prof = load_profile("pogox")
    assert prof.controller == FlyingScenario().controller_config(PogoXParams())
    assert prof.trajectory == EllipseTrajectory()
    assert "pogox" in shipped_profiles()
    assert prof.contact.source == "estimate" and prof.contact.leg_length == PogoXParams().leg_rest_length


def test_pogox_hopping_profile_is_the_simulated_hopping_robot():
    from ddpc_codegen.sim.params import PogoXParams
    from ddpc_codegen.sim.scenarios import HoppingScenario

    prof = load_profile("pogox_hopping")
    assert prof.controller == HoppingScenario().controller_config(PogoXParams())
    assert prof.contact.source == "estimate" and prof.contact.signal_name == "CONTACT"
    assert prof.contact.leg_length == PogoXParams().leg_rest_length


def test_extends_overrides_only_given_keys(tmp_path):
    f = tmp_path / "heavy.toml"
    f.write_text('extends = "pogox"\n[controller]\nmodel_mass = 3.65\n[trajectory]\nperiod = 12.0\n')
    prof = load_profile(f)
    base = load_profile("pogox")
    assert prof.controller.model_mass == 3.65 and prof.controller.kp_z == base.controller.kp_z
    assert prof.trajectory.period == 12.0 and prof.trajectory.radii == base.trajectory.radii
    assert prof.name == "heavy"


@pytest.mark.parametrize("text, match", [
    ("[controller]\nmodel_mas = 3.0\n", r"\[controller\] model_mas is not a known key"),
    ("[controller]\nmodel_mass = -1.0\n", r"\[controller\] .*model_mass, max_thrust and dt must be positive"),
    ("[trajectory]\nradii = 'x'\n", r"\[trajectory\]"),
    ("colour = 'red'\n", r"top level: colour is not a known key"),
    ("controller = 3\n", r"\[controller\] must be a table; got 3"),
    ("[controller\n", r"not valid TOML"),
    ("extends = 'nosuch'\n", r"no robot profile 'nosuch'"),
    # [steering] max_step: the bridge's step guard, one finite value > 0 per reference of the loop (the
    # bridge's own --max-step check, same messages)
    ("extends = 'px4_sih'\n[steering]\nmax_step = [0.6]\n", r"\[steering\] max_step needs 2 values on the flying loop"),
    ("extends = 'px4_sih'\n[steering]\nmax_step = 0.6\n", r"\[steering\] max_step needs 2 values on the flying loop"),
    ("extends = 'px4_sih'\n[steering]\nmax_step = [0.6, 0]\n", r"\[steering\] max_step must be finite and > 0 per reference"),
    ("extends = 'px4_sih'\n[steering]\nmax_step = [0.6, nan]\n", r"\[steering\] max_step must be finite and > 0 per reference"),
    ("extends = 'px4_sih'\n[steering]\nmax_step = [true, 0.5]\n", r"\[steering\] max_step must be finite and > 0 per reference"),
    ("extends = 'pogox_hopping'\n[steering]\nmax_step = [0.6, 0.5]\n", r"max_step needs 3 values on the hopping loop"),
])
def test_bad_profiles_are_refused_precisely(tmp_path, text, match):
    f = tmp_path / "bad.toml"
    f.write_text(text)
    with pytest.raises(ConfigError, match=match):
        load_profile(f)


def test_unknown_profile_name_lists_the_shipped_ones():
    with pytest.raises(ConfigError, match=r"no robot profile 'pogo'.*pogox"):
        load_profile("pogo")
