"""Robot profiles: the companion controller's model and gains and the trajectory it flies, as a
validated TOML file (``[controller]``: :class:`ControllerConfig` fields, ``[trajectory]``:
:class:`EllipseTrajectory` fields, ``[contact]``: :class:`ContactConfig` fields, hopping phase
detection, ``[steering]``: :class:`SteeringGuards`, the bridge's guards this robot needs when
steered, ``[envelope]``: :class:`Envelope`, where the vehicle may fly and how fast its references may move:
the bridge's path checks and its last gate; its defaults are PogoX's).
Shipped profiles live in ``ddpc_codegen/robot/profiles/`` and are named by their file stem
(``pogox``); any other profile is a path. Every number is checked for type, finiteness and range
(:mod:`.validate`) before anything is built from it; the file's size and nesting before it is parsed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ddpc_codegen.errors import ConfigError
from ddpc_codegen.robot.controller import ControllerConfig
from ddpc_codegen.robot.phases import ContactConfig
from ddpc_codegen.robot.signals import REFERENCES, check_per_reference
from ddpc_codegen.robot.trajectory import EllipseTrajectory
from ddpc_codegen.robot.validate import Range, check_table
from ddpc_codegen.values.files import load_toml_bounded
from ddpc_codegen.values.tomlconfig import check_keys, dataclass_from_table

__all__ = ["RobotProfile", "SteeringGuards", "Envelope", "default_envelope", "load_profile", "shipped_profiles", "PROFILE_DIR",
           "PROFILE_RANGES", "DEFAULT_REF_RATE"]

PROFILE_DIR = Path(__file__).resolve().parent / "profiles"
_TOP = ("name", "description", "extends", "controller", "trajectory", "contact", "steering", "envelope")
PROFILE_MAX_BYTES = 256_000  # a profile is about 2 kB; a hundred times that is no profile
_MAX_EXTENDS = 8  # a chain of profiles longer than this is a mistake, not a design
_POS = Range(lo=0.0, lo_open=True, hi=1e6)
_NONNEG = Range(lo=0.0, hi=1e6)
# Physical ranges of every number a profile holds (SI units): wide enough for any multirotor or hopper,
# narrow enough that a typo (a gain of 1e9, a negative mass, a tilt past 90 deg) is refused.
PROFILE_RANGES: dict[str, dict[str, Range]] = {
    "controller": {
        "dt": Range(lo=0.0, lo_open=True, hi=1.0), "model_mass": Range(lo=0.0, lo_open=True, hi=1e4),
        "max_thrust": _POS, "g": Range(lo=0.1, hi=100.0), "kp_z": Range(lo=0.0, lo_open=True, hi=1e4),
        "kd_z": Range(lo=0.0, hi=1e4), "ref_velocity_gain": Range(lo=0.0, hi=10.0, optional=True),
        "ref_velocity_tau": Range(lo=0.0, hi=10.0), "kp_xy": Range(lo=0.0, hi=1e4), "kd_xy": Range(lo=0.0, hi=1e4),
        "max_tilt": Range(lo=0.0, lo_open=True, hi=math.pi / 2, hi_open=True),
        "thrust_fraction": Range(lo=0.0, hi=1.0, hi_open=True), "apex_height": Range(lo=0.0, hi=100.0),
        "target_velocity": Range(lo=-50.0, hi=50.0, n=2), "stance_boost": Range(lo=0.0, hi=1e3),
        "raibert_gain": Range(lo=0.0, hi=10.0), "velocity_integral_gain": Range(lo=0.0, hi=100.0),
        "leg_length": Range(lo=0.0, lo_open=True, hi=10.0), "leg_stiffness": Range(lo=0.0, lo_open=True, hi=1e7),
        "initial_apex": Range(lo=0.0, hi=100.0, optional=True), "mode": Range(text=True, max_len=16),
    },
    "trajectory": {
        "center": Range(lo=-1e4, hi=1e4, n=2), "radii": Range(lo=0.0, hi=1e4, n=2),
        "period": Range(lo=0.0, lo_open=True, hi=1e6), "spin_up": Range(lo=0.0, lo_open=True, hi=1e4),
        "t_start": Range(lo=0.0, hi=1e6),
    },
    "contact": {
        "source": Range(text=True, max_len=16),
        "signal_name": Range(text=True, max_len=10),  # NAMED_VALUE_INT.name holds 10 characters
        "leg_length": Range(lo=0.0, lo_open=True, hi=10.0), "ground_z": Range(lo=-100.0, hi=100.0),
        "touchdown_margin": Range(lo=0.0, hi=1.0), "liftoff_margin": Range(lo=-1.0, hi=1.0),
        "vz_band": Range(lo=0.0, hi=10.0), "min_ground_ticks": Range(lo=0, hi=10_000, integer=True),
        "min_air_ticks": Range(lo=0, hi=10_000, integer=True), "backdate_ticks": Range(lo=0, hi=100, integer=True),
    },
    "envelope": {
        "z_min": Range(lo=-10.0, hi=1e4), "z_max": Range(lo=0.0, lo_open=True, hi=1e4),
        "radius": Range(lo=0.0, lo_open=True, hi=1e5), "max_speed": Range(lo=0.0, lo_open=True, hi=100.0),
        "max_accel": Range(lo=0.0, lo_open=True, hi=100.0),
    },  # ref_rate, offset_rate: check_per_reference (one per reference of the loop)
    "steering": {},  # max_step: check_per_reference (one per reference of the loop)
}


# Largest change per second of an applied reference when the profile sets none: a collect flight's PRBS
# steps (twice its amplitude in one tick) fit at 200 Hz, a hopper's leg angles may turn at lift-off.
DEFAULT_REF_RATE = {"z_ref": 30.0, "roll_ref": 100.0, "pitch_ref": 100.0}


@dataclass(frozen=True)
class SteeringGuards:
    """The bridge's guards this robot needs when steered (``[steering]``; unset: the bridge's defaults).

    Attributes:
        max_step: largest |steered - nominal| reference per channel (flying: z_ref [m], pitch_ref
            [rad]; hopping: z_ref, roll_ref, pitch_ref); a larger steering offset falls back to the
            nominal reference. A vehicle whose height estimate jumps (PX4 SIH's EKF) needs more room
            than the default 0.3 m, and a user flying it by hand should not have to know that.
    """

    max_step: tuple[float, ...] | None = None


@dataclass(frozen=True)
class Envelope:
    """Where the vehicle may be and how fast its references may move (``[envelope]``), whatever mode
    produced them: the bridge checks every input that defines the path against it before arming
    (:mod:`firmware_bridge.path_checks`) and its last gate clamps every applied reference to it.

    Attributes:
        z_min, z_max: the height range [m, from the take-off point]: the applied height reference and the
            path. Flying: ``z_min >= 0`` (never below the ground); hopping: ``z_min >= -leg_length`` (the
            body over a compressed leg in stance). The angle references are bounded by ``max_tilt``.
        radius: largest horizontal distance of the path from its start [m].
        max_speed, max_accel: largest speed [m/s] and acceleration [m/s^2] of the path.
        ref_rate: largest change per second of each applied reference, whatever the mode (flying: z
            [m/s], pitch [rad/s]; collect's PRBS steps included); None: :data:`DEFAULT_REF_RATE`.
        offset_rate: largest change per second of the correction on top of the nominal reference
            (applied - nominal), per reference (flying: z [m/s], pitch [rad/s]); None: 5 m/s and
            5 rad/s. A steered solver's own ``du_max`` is the bound when it is tighter.
    """

    z_min: float = 0.0
    z_max: float = 10.0
    radius: float = 10.0
    max_speed: float = 3.0
    max_accel: float = 3.0
    ref_rate: tuple[float, ...] | None = None
    offset_rate: tuple[float, ...] | None = None

    def reference_bounds(self, mode: str, max_tilt: float) -> tuple[np.ndarray, np.ndarray]:
        """(lo, hi) per reference of the ``mode`` loop: z in [z_min, z_max], angles within +-max_tilt."""
        refs = REFERENCES[mode]
        lo = np.array([self.z_min if r == "z_ref" else -max_tilt for r in refs])
        hi = np.array([self.z_max if r == "z_ref" else max_tilt for r in refs])
        return lo, hi

    def offset_rates(self, mode: str) -> np.ndarray:
        """Per-second bound of the correction's change per reference of the ``mode`` loop."""
        if self.offset_rate is not None:
            return np.array(self.offset_rate, dtype=float)
        return np.full(len(REFERENCES[mode]), 5.0)

    def ref_rates(self, mode: str) -> np.ndarray:
        """Per-second bound of each applied reference's change on the ``mode`` loop."""
        if self.ref_rate is not None:
            return np.array(self.ref_rate, dtype=float)
        return np.array([DEFAULT_REF_RATE[r] for r in REFERENCES[mode]])


@dataclass(frozen=True)
class RobotProfile:
    """What the companion computer needs to know about one robot.

    Attributes:
        name: short identifier (file stem for shipped profiles).
        description: one line for logs and ``--help``.
        controller: the model-based controller's model and gains (SI units).
        trajectory: the default desired trajectory (world ENU / trajectory frame, m, s).
        contact: how hopping phases are detected (``[contact]``; :class:`ContactConfig`).
        steering: the bridge's guards when steered (``[steering]``; :class:`SteeringGuards`).
        envelope: what the bridge's last gate lets through (``[envelope]``; :class:`Envelope`).
        source: where it was loaded from.
    """

    name: str
    description: str
    controller: ControllerConfig
    trajectory: EllipseTrajectory
    contact: ContactConfig = ContactConfig()
    steering: SteeringGuards = SteeringGuards()
    envelope: Envelope = Envelope()
    source: str = "<profile>"


def default_envelope(mode: str) -> Envelope:
    """The envelope of the shipped profile of a ``mode`` loop (pogox flying, pogox_hopping): what a bridge
    given no profile flies in."""
    return load_profile("pogox" if mode == "flying" else "pogox_hopping").envelope


def shipped_profiles() -> list[str]:
    """Names of the profiles shipped with the package."""
    return sorted(p.stem for p in PROFILE_DIR.glob("*.toml"))


def _resolve(name_or_path: str | Path) -> Path:
    p = Path(name_or_path)
    if p.suffix == ".toml" or p.exists():
        return p
    shipped = PROFILE_DIR / f"{name_or_path}.toml"
    if not shipped.is_file():
        raise ConfigError(f"no robot profile {str(name_or_path)!r}: not a file, and not one of the shipped "
                          f"profiles {shipped_profiles()}")
    return shipped


def _table(raw: dict, key: str, src: str) -> dict:
    """One table, its numbers checked against :data:`PROFILE_RANGES` (unknown keys: the caller's check)."""
    table = raw.get(key, {})
    if not isinstance(table, dict):
        raise ConfigError(f"{src}: [{key}] must be a table; got {table!r}")
    return check_table(table, PROFILE_RANGES[key], f"{src}: [{key}]")


def load_profile(name_or_path: str | Path, _chain: tuple[str, ...] = ()) -> RobotProfile:
    """Load and validate a robot profile (a shipped name such as ``"pogox"`` or a TOML path).

    ``extends = "<profile>"`` starts from another profile and overrides the keys given.

    Raises:
        ConfigError: naming the file and the key: unknown keys, values of the wrong type, non-finite or
            out of their physical range, an ``extends`` cycle or chain deeper than 8, a file too large.
    """
    path = _resolve(name_or_path)
    src = str(path)
    key = str(path.resolve())
    if key in _chain:
        names = " -> ".join(Path(p).name for p in (*_chain, key))
        raise ConfigError(f"{src}: extends cycle: {names}")
    if len(_chain) >= _MAX_EXTENDS:
        raise ConfigError(f"{src}: extends chain deeper than {_MAX_EXTENDS} profiles")
    raw = check_keys(load_toml_bounded(path, "robot profile", PROFILE_MAX_BYTES), _TOP, "top level:", src)
    base = None
    if "extends" in raw:
        if not isinstance(raw["extends"], str) or not raw["extends"] or Path(raw["extends"]).stem == path.stem:
            raise ConfigError(f"{src}: extends must name another profile; got {raw['extends']!r}")
        base = load_profile(raw["extends"], (*_chain, key))
    ctrl = dataclass_from_table(ControllerConfig, _table(raw, "controller", src), "[controller]", src,
                                base.controller if base else None)
    traj = dataclass_from_table(EllipseTrajectory, _table(raw, "trajectory", src), "[trajectory]", src,
                                base.trajectory if base else None)
    contact = dataclass_from_table(ContactConfig, _table(raw, "contact", src), "[contact]", src,
                                   base.contact if base else None)
    steering = dataclass_from_table(SteeringGuards, raw.get("steering", {}), "[steering]", src,
                                    base.steering if base else None)
    envelope = _envelope(raw, src, ctrl, base.envelope if base else None)
    try:  # one value per reference of this profile's loop: the bridge applies the same check
        steering = replace(steering, max_step=check_per_reference("max_step", steering.max_step, ctrl.mode))
    except ValueError as e:
        raise ConfigError(f"{src}: [steering] {e}") from None
    for k in ("name", "description"):
        if k in raw and (not isinstance(raw[k], str) or len(raw[k]) > 200):
            raise ConfigError(f"{src}: {k} must be a string of at most 200 characters; got {raw[k]!r}")
    return RobotProfile(name=raw.get("name", path.stem), description=raw.get("description", ""),
                        controller=ctrl, trajectory=traj, contact=contact, steering=steering, envelope=envelope,
                        source=src)


def _envelope(raw: dict, src: str, ctrl: ControllerConfig, base: Envelope | None) -> Envelope:
    """``[envelope]`` on top of the base profile's: z_min < z_max, the floor above the ground, one rate per
    reference."""
    mode = ctrl.mode
    table = dict(_table(raw, "envelope", src))
    for key in ("ref_rate", "offset_rate"):
        rate = table.get(key)
        if rate is None:
            continue
        try:
            table[key] = check_per_reference(key, rate, mode)
        except ValueError as e:
            raise ConfigError(f"{src}: [envelope] {e}") from None
        if max(table[key]) > 1e3:
            raise ConfigError(f"{src}: [envelope] {key} must be at most 1000 per second; got {rate!r}")
    env = dataclass_from_table(Envelope, table, "[envelope]", src, base)
    for key in ("ref_rate", "offset_rate"):
        v = getattr(env, key)
        if v is not None and len(v) != len(REFERENCES[mode]):
            raise ConfigError(f"{src}: [envelope] {key} of the base profile has {len(v)} values; "
                              f"the {mode} loop needs {len(REFERENCES[mode])}: set it here")
    if not env.z_min < env.z_max:
        raise ConfigError(f"{src}: [envelope] needs z_min < z_max; got z_min {env.z_min!r}, z_max {env.z_max!r}")
    # Heights count from the take-off point: a flyer's reference below it is in the ground; a hopper's body
    # sinks in stance, never by more than its leg.
    floor = 0.0 if mode == "flying" else -ctrl.leg_length
    if env.z_min < floor:
        leg = "" if mode == "flying" else f" (a [controller] leg_length of {ctrl.leg_length:g} m)"
        raise ConfigError(f"{src}: [envelope] z_min {env.z_min!r} is below the ground: at least {floor:g} m "
                          f"from the take-off point on the {mode} loop{leg}")
    return env
