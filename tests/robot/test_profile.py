"""Robot profiles: the shipped PogoX profile equals the simulator's flying setup; bad files are
refused with messages naming the file, the table, the key and the value."""

from __future__ import annotations

import dataclasses
import json
import math

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ddpc_codegen.errors import ConfigError
from ddpc_codegen.robot.controller import ControllerConfig
from ddpc_codegen.robot.phases import ContactConfig
from ddpc_codegen.robot.profile import PROFILE_RANGES, Envelope, SteeringGuards, load_profile, shipped_profiles
from ddpc_codegen.robot.signals import REFERENCES
from ddpc_codegen.robot.trajectory import EllipseTrajectory
from ddpc_codegen.robot.validate import check_table
from support.fuzz import fuzz_examples


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
    ("[controller]\nmodel_mass = -1.0\n", r"\[controller\] model_mass must be a finite number in \(0, 10000\]; got -1.0"),
    ("[controller]\nkp_z = nan\n", r"bad.toml: \[controller\] kp_z must be a finite number in \(0, 10000\]; got nan"),
    ("[controller]\nkp_z = \"10\"\n", r"bad.toml: \[controller\] kp_z must be a finite number in \(0, 10000\]; got '10'"),
    ("[controller]\nmax_tilt = 2.0\n", r"\[controller\] max_tilt must be a finite number in \(0, 1.5708\); got 2.0"),
    ("[controller]\ntarget_velocity = [0.3]\n", r"\[controller\] target_velocity must be 2 numbers"),
    ("[trajectory]\nperiod = inf\n", r"\[trajectory\] period must be a finite number in \(0, 1e\+06\]; got inf"),
    ("[contact]\nsignal_name = 'CONTACT_SENSOR'\n", r"\[contact\] signal_name must be a string of 1 to 10"),
    ("[contact]\nmin_air_ticks = 2.5\n", r"\[contact\] min_air_ticks must be an integer in \[0, 10000\]; got 2.5"),
    ("[envelope]\nz_min = 2.0\nz_max = 1.0\n", r"\[envelope\] needs z_min < z_max; got z_min 2.0, z_max 1.0"),
    ("[envelope]\noffset_rate = [1.0]\n", r"\[envelope\] offset_rate needs 2 values on the flying loop"),
    ("[envelope]\nz_max = 'high'\n", r"\[envelope\] z_max must be a finite number"),
    ("[envelope]\ncolour = 1\n", r"\[envelope\] colour is not a known key"),
    # The envelope is physical: never below the ground, positive limits, one rate per reference
    ("[envelope]\nz_min = -1.0\n", r"\[envelope\] z_min -1.0 is below the ground: at least 0 m from the take-off point "
                                    r"on the flying loop"),
    ("extends = 'pogox_hopping'\n[envelope]\nz_min = -0.5\n", r"z_min -0.5 is below the ground: at least -0.4 m"),
    ("[envelope]\nmax_speed = 0.0\n", r"\[envelope\] max_speed must be a finite number in \(0, 100\]; got 0.0"),
    ("[envelope]\nradius = inf\n", r"\[envelope\] radius must be a finite number"),
    ("[envelope]\nref_rate = [1.0]\n", r"\[envelope\] ref_rate needs 2 values on the flying loop"),
    ("[envelope]\nref_rate = [1.0, 2e3]\n", r"\[envelope\] ref_rate must be at most 1000 per second"),
    ("extends = 'pogox'\n[controller]\nmode = 'hopping'\n", r"ref_rate of the base profile has 2 values; the hopping "
                                                           r"loop needs 3: set it here"),
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


def test_envelope_defaults_and_bounds(tmp_path):
    f = tmp_path / "env.toml"
    f.write_text('extends = "pogox"\n[envelope]\nz_min = 0.2\nz_max = 3.0\noffset_rate = [1.0, 2.0]\n')
    prof = load_profile(f)
    lo, hi = prof.envelope.reference_bounds("flying", prof.controller.max_tilt)
    assert lo.tolist() == [0.2, -prof.controller.max_tilt] and hi.tolist() == [3.0, prof.controller.max_tilt]
    assert prof.envelope.offset_rates("flying").tolist() == [1.0, 2.0]
    assert load_profile("pogox_hopping").envelope.offset_rates("hopping").tolist() == [5.0, 5.0, 5.0]


def test_the_default_envelope_is_the_shipped_pogox_one_and_every_profile_keeps_above_the_ground():
    """A bridge given no profile flies in Envelope()'s defaults: they are pogox.toml's (ref_rate: the same
    values through DEFAULT_REF_RATE)."""
    env = load_profile("pogox").envelope
    assert dataclasses.replace(env, ref_rate=None, offset_rate=None) == Envelope()
    assert env.ref_rates("flying").tolist() == Envelope().ref_rates("flying").tolist() == [30.0, 100.0]
    for name in shipped_profiles():
        prof = load_profile(name)
        floor = 0.0 if prof.controller.mode == "flying" else -prof.controller.leg_length
        assert prof.envelope.z_min >= floor and len(prof.envelope.ref_rates(prof.controller.mode)) == \
            len(REFERENCES[prof.controller.mode])


def test_extends_cycle_is_a_precise_error_not_recursion(tmp_path):
    (tmp_path / "a.toml").write_text('extends = "%s"\n' % (tmp_path / "b.toml"))
    (tmp_path / "b.toml").write_text('extends = "%s"\n' % (tmp_path / "a.toml"))
    with pytest.raises(ConfigError, match=r"a.toml: extends cycle: a.toml -> b.toml -> a.toml"):
        load_profile(tmp_path / "a.toml")


def test_extends_chain_depth_is_bounded(tmp_path):
    for i in range(12):
        (tmp_path / f"p{i}.toml").write_text('extends = "%s"\n' % (tmp_path / f"p{i + 1}.toml") if i < 11 else "")
    with pytest.raises(ConfigError, match=r"extends chain deeper than 8 profiles"):
        load_profile(tmp_path / "p0.toml")


def test_deep_and_huge_profiles_are_refused_before_parsing(tmp_path):
    deep = tmp_path / "deep.toml"
    deep.write_text("x = " + "[" * 100_000 + "]" * 100_000 + "\n")
    with pytest.raises(ConfigError, match=r"deep.toml: robot profile: nested 100000 levels deep, more than a robot profile may be \(32\)"):
        load_profile(deep)
    huge = tmp_path / "huge.toml"
    huge.write_text("# padding\n" * 30_000)
    with pytest.raises(ConfigError, match=r"huge.toml: robot profile: 300000 bytes, more than a robot profile may have \(256000"):
        load_profile(huge)
    nested = tmp_path / "nested.toml"
    nested.write_text("x = " + "[" * 50 + "]" * 50 + "\n")
    with pytest.raises(ConfigError, match=r"nested.toml: x\[0\]\[0\].*: nested more than 32 levels deep, more than a "
                                          r"robot profile may be$"):
        load_profile(nested)


# ----------------------------------------------------------------------------- property: mutate every field
def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return "nan" if v != v else ("inf" if v == float("inf") else "-inf" if v == -float("inf") else repr(v))
    if isinstance(v, int):
        return str(v)
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return "{}"


_FIELDS = [(t, f.name) for t, cls in (("controller", ControllerConfig), ("trajectory", EllipseTrajectory),
                                      ("contact", ContactConfig), ("steering", SteeringGuards), ("envelope", Envelope))
           for f in dataclasses.fields(cls)]
_VALUES = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**20, 10**20), st.booleans(),
                    st.text(max_size=12), st.lists(st.floats(allow_nan=True), max_size=4),
                    st.lists(st.integers(-5, 5), max_size=4), st.just({}))


def _all_numbers(obj) -> list[float]:
    out = []
    for v in dataclasses.asdict(obj).values():
        for x in (v if isinstance(v, (tuple, list)) else (v,)):
            if isinstance(x, (int, float)) and not isinstance(x, bool):
                out.append(float(x))
    return out


@settings(max_examples=fuzz_examples(400), deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(field=st.sampled_from(_FIELDS), value=_VALUES, base=st.sampled_from(["pogox", "pogox_hopping"]))
def test_mutated_profiles_are_refused_or_finite(tmp_path, field, value, base):
    """Any value in any field: a ConfigError naming the table, or a profile whose numbers are all finite
    and inside their physical ranges -- never a traceback of another kind."""
    table, key = field
    f = tmp_path / "mut.toml"
    f.write_text(f'extends = "{base}"\n[{table}]\n{key} = {_toml_value(value)}\n')
    try:
        prof = load_profile(f)
    except ConfigError as e:
        # (a string our serializer could not write as TOML is the parser's precise error)
        assert "mut.toml" in str(e) and (f"[{table}]" in str(e) or "not valid TOML" in str(e)), str(e)
        return
    for part in (prof.controller, prof.trajectory, prof.contact, prof.steering, prof.envelope):
        assert all(math.isfinite(x) for x in _all_numbers(part)), part
    for name, ranges in PROFILE_RANGES.items():
        obj = getattr(prof, name)
        check_table({k: getattr(obj, k) for k in ranges}, ranges, name)  # raises if out of range
