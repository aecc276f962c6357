"""Robot profiles: the companion controller's model and gains and the trajectory it flies, as a
validated TOML file (``[controller]``: :class:`ControllerConfig` fields, ``[trajectory]``:
:class:`EllipseTrajectory` fields, ``[contact]``: :class:`ContactConfig` fields, hopping phase
detection, ``[steering]``: :class:`SteeringGuards`, the bridge's guards this robot needs when
steered). Shipped profiles live in ``ddpc_codegen/robot/profiles/``
and are named by their file stem (``pogox``); any other profile is a path.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

from ddpc_codegen.errors import ConfigError
from ddpc_codegen.robot.controller import ControllerConfig
from ddpc_codegen.robot.signals import check_per_reference
from ddpc_codegen.robot.phases import ContactConfig
from ddpc_codegen.robot.trajectory import EllipseTrajectory
from ddpc_codegen.tomlconfig import check_keys, dataclass_from_table, load_toml

__all__ = ["RobotProfile", "SteeringGuards", "load_profile", "shipped_profiles", "PROFILE_DIR"]

PROFILE_DIR = Path(__file__).resolve().parent / "profiles"
_TOP = ("name", "description", "extends", "controller", "trajectory", "contact", "steering")


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
class RobotProfile:
    """What the companion computer needs to know about one robot.

    Attributes:
        name: short identifier (file stem for shipped profiles).
        description: one line for logs and ``--help``.
        controller: the model-based controller's model and gains (SI units).
        trajectory: the default desired trajectory (world ENU / trajectory frame, m, s).
        contact: how hopping phases are detected (``[contact]``; :class:`ContactConfig`).
        steering: the bridge's guards when steered (``[steering]``; :class:`SteeringGuards`).
        source: where it was loaded from.
    """

    name: str
    description: str
    controller: ControllerConfig
    trajectory: EllipseTrajectory
    contact: ContactConfig = ContactConfig()
    steering: SteeringGuards = SteeringGuards()
    source: str = "<profile>"


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


def load_profile(name_or_path: str | Path) -> RobotProfile:
    """Load and validate a robot profile (a shipped name such as ``"pogox"`` or a TOML path).

    ``extends = "<profile>"`` starts from another profile and overrides the keys given.
    """
    path = _resolve(name_or_path)
    src = str(path)
    raw = check_keys(load_toml(path), _TOP, "top level:", src)
    base = None
    if "extends" in raw:
        if not isinstance(raw["extends"], str) or Path(raw["extends"]).stem == path.stem:
            raise ConfigError(f"{src}: extends must name another profile; got {raw['extends']!r}")
        base = load_profile(raw["extends"])
    ctrl = dataclass_from_table(ControllerConfig, raw.get("controller", {}), "[controller]", src,
                                base.controller if base else None)
    traj = dataclass_from_table(EllipseTrajectory, raw.get("trajectory", {}), "[trajectory]", src,
                                base.trajectory if base else None)
    contact = dataclass_from_table(ContactConfig, raw.get("contact", {}), "[contact]", src,
                                   base.contact if base else None)
    steering = dataclass_from_table(SteeringGuards, raw.get("steering", {}), "[steering]", src,
                                    base.steering if base else None)
    try:  # one value per reference of this profile's loop: the bridge applies the same check
        steering = replace(steering, max_step=check_per_reference("max_step", steering.max_step, ctrl.mode))
    except ValueError as e:
        raise ConfigError(f"{src}: [steering] {e}") from None
    for key in ("name", "description"):
        if key in raw and not isinstance(raw[key], str):
            raise ConfigError(f"{src}: {key} must be a string; got {raw[key]!r}")
    return RobotProfile(name=raw.get("name", path.stem), description=raw.get("description", ""),
                        controller=ctrl, trajectory=traj, contact=contact, steering=steering, source=src)
