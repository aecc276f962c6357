"""Autopilot profiles: how PX4 and ArduPilot Copter encode modes and read SET_ATTITUDE_TARGET.

PX4
    HEARTBEAT.custom_mode = (main_mode << 16) | (sub_mode << 24) with MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    in base_mode; OFFBOARD is main mode 6. Mode change: MAV_CMD_DO_SET_MODE(param1 = 1 (custom
    mode enabled), param2 = main mode, param3 = sub mode). PX4 only accepts OFFBOARD while an
    offboard setpoint stream is alive, so setpoints are streamed (here >= 1 s) before switching.
    If the stream stops for COM_OF_LOSS_T seconds (default 1 s) PX4 leaves OFFBOARD for its
    failsafe (COM_OBL_RC_ACT: position / hold / land ...). SET_ATTITUDE_TARGET.thrust is the
    normalized collective thrust in [0, 1].
ArduPilot Copter
    HEARTBEAT.custom_mode is the flight-mode number; offboard-equivalent modes are GUIDED (4)
    and GUIDED_NOGPS (20); DO_SET_MODE(param1 = 1, param2 = mode number). In those modes
    SET_ATTITUDE_TARGET.thrust is a *climb rate* (0.5 = hold altitude, 0 = full descent speed,
    1 = full climb speed) unless bit 3 (value 8) of GUID_OPTIONS is set; then it is a
    normalized thrust like PX4's. Both are supported; with the climb-rate semantics the
    bridge turns the height reference into a climb rate ``kp (z_ref - z)`` (ArduPilot's own
    altitude loop then closes height).

Arming (MAV_CMD_COMPONENT_ARM_DISARM) is the same for both. The bridge only arms or changes
modes when asked by an explicit CLI flag.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import math
from dataclasses import dataclass

__all__ = [
    "PX4_MAIN",
    "PX4_AUTO_SUB",
    "px4_custom_mode",
    "px4_decode",
    "px4_mode_name",
    "ARDUCOPTER_MODES",
    "VehicleMode",
    "Profile",
    "PX4Profile",
    "ArduPilotProfile",
    "make_profile",
    "MAV_AUTOPILOT_PX4",
    "MAV_AUTOPILOT_ARDUPILOTMEGA",
    "MAV_MODE_FLAG_SAFETY_ARMED",
    "MAV_MODE_FLAG_CUSTOM_MODE_ENABLED",
    "GUID_OPTIONS_SET_ATTITUDE_TARGET_THRUST",
]

MAV_AUTOPILOT_ARDUPILOTMEGA = 3
MAV_AUTOPILOT_PX4 = 12
MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1
MAV_MODE_FLAG_SAFETY_ARMED = 128
GUID_OPTIONS_SET_ATTITUDE_TARGET_THRUST = 8  # bit 3

PX4_MAIN = {"MANUAL": 1, "ALTCTL": 2, "POSCTL": 3, "AUTO": 4, "ACRO": 5, "OFFBOARD": 6, "STABILIZED": 7}
PX4_AUTO_SUB = {"READY": 1, "TAKEOFF": 2, "LOITER": 3, "MISSION": 4, "RTL": 5, "LAND": 6}
_PX4_MAIN_NAMES = {v: k for k, v in PX4_MAIN.items()}
_PX4_AUTO_NAMES = {v: k for k, v in PX4_AUTO_SUB.items()}

ARDUCOPTER_MODES = {
    "STABILIZE": 0, "ACRO": 1, "ALT_HOLD": 2, "AUTO": 3, "GUIDED": 4, "LOITER": 5, "RTL": 6,
    "CIRCLE": 7, "LAND": 9, "DRIFT": 11, "SPORT": 13, "POSHOLD": 16, "BRAKE": 17, "GUIDED_NOGPS": 20,
}
_ARDU_NAMES = {v: k for k, v in ARDUCOPTER_MODES.items()}


def px4_custom_mode(main: int, sub: int = 0) -> int:
    """PX4's HEARTBEAT.custom_mode for a main / sub mode pair."""
    return ((int(main) & 0xFF) << 16) | ((int(sub) & 0xFF) << 24)


def px4_decode(custom_mode: int) -> tuple[int, int]:
    """(main, sub) from PX4's custom_mode."""
    return (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF


def px4_mode_name(custom_mode: int) -> str:
    main, sub = px4_decode(custom_mode)
    name = _PX4_MAIN_NAMES.get(main, f"MAIN{main}")
    if main == PX4_MAIN["AUTO"]:
        name += "." + _PX4_AUTO_NAMES.get(sub, f"SUB{sub}")
    return name


@dataclass(frozen=True)
class VehicleMode:
    """What a HEARTBEAT says: armed flag, whether the mode takes our setpoints, a readable name."""

    armed: bool
    offboard: bool
    name: str


@dataclass
class Profile(ABC):
    """Common interface (see :class:`PX4Profile`, :class:`ArduPilotProfile`).

    Attributes:
        prestream: seconds of setpoints to stream before requesting the off-board mode [s].
        arm_first: with arming by the bridge, arm before the mode request (else after).
        offboard_loss_timeout: the autopilot's own setpoint-loss timeout [s] (PX4 COM_OF_LOSS_T).
    """

    prestream: float = 1.0
    offboard_loss_timeout: float = 1.0
    name: str = "generic"
    autopilot: int = 0
    # With --arm: arm before requesting the off-board mode (PX4 refuses arming in OFFBOARD unless
    # setpoints stream; ArduCopter arms in GUIDED_NOGPS, so it gets the mode first).
    arm_first: bool = True

    @abstractmethod
    def decode(self, base_mode: int, custom_mode: int) -> VehicleMode: ...

    @abstractmethod
    def offboard_command(self) -> tuple[float, float, float]:
        """DO_SET_MODE params 1..3 that enter the off-board / guided mode."""
        ...

    @abstractmethod
    def hold_command(self) -> tuple[float, float, float]: ...

    @abstractmethod
    def land_command(self) -> tuple[float, float, float]: ...

    @property
    def climb_rate_thrust(self) -> bool:
        """True when SET_ATTITUDE_TARGET.thrust means a climb rate (ArduPilot default)."""
        return False

    def thrust_field(self, thrust: float, z_ref: float, z: float) -> float:
        """Value for SET_ATTITUDE_TARGET.thrust from the controller's normalized thrust [0, 1]
        (and, for climb-rate semantics, the height reference and measured height [m])."""
        return thrust

    def hover_field(self, hover_thrust: float) -> float:
        """The thrust field that holds height (open loop for normalized thrust)."""
        return hover_thrust

    def mode_command_name(self, params: tuple[float, float, float]) -> str:
        return str(params)


@dataclass
class PX4Profile(Profile):
    """PX4: OFFBOARD (main mode 6), normalized thrust."""

    name: str = "px4"
    autopilot: int = MAV_AUTOPILOT_PX4

    def decode(self, base_mode: int, custom_mode: int) -> VehicleMode:
        armed = bool(base_mode & MAV_MODE_FLAG_SAFETY_ARMED)
        main, _ = px4_decode(custom_mode)
        custom = bool(base_mode & MAV_MODE_FLAG_CUSTOM_MODE_ENABLED)
        return VehicleMode(armed, custom and main == PX4_MAIN["OFFBOARD"], px4_mode_name(custom_mode))

    def offboard_command(self) -> tuple[float, float, float]:
        return (float(MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), float(PX4_MAIN["OFFBOARD"]), 0.0)

    def hold_command(self) -> tuple[float, float, float]:
        return (float(MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), float(PX4_MAIN["AUTO"]), float(PX4_AUTO_SUB["LOITER"]))

    def land_command(self) -> tuple[float, float, float]:
        return (float(MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), float(PX4_MAIN["AUTO"]), float(PX4_AUTO_SUB["LAND"]))

    def mode_command_name(self, params: tuple[float, float, float]) -> str:
        return px4_mode_name(px4_custom_mode(int(params[1]), int(params[2])))


@dataclass
class ArduPilotProfile(Profile):
    """ArduPilot Copter: GUIDED / GUIDED_NOGPS; thrust = climb rate unless GUID_OPTIONS bit 3.

    Attributes:
        guided_mode: 20 (GUIDED_NOGPS, default: attitude control needs no position source) or 4 (GUIDED).
        guid_options: the vehicle's GUID_OPTIONS parameter (bit 3 set -> thrust is a thrust).
        climb_kp: climb-rate semantics: climb rate = climb_kp (z_ref - z) [1/s].
        speed_up, speed_down: the climb / descent rates that thrust 1 / 0 stand for [m/s]
            (ArduPilot's WPNAV_SPEED_UP / WPNAV_SPEED_DN, defaults 2.5 / 1.5 m/s).
    """

    name: str = "ardupilot"
    autopilot: int = MAV_AUTOPILOT_ARDUPILOTMEGA
    arm_first: bool = False
    guided_mode: int = ARDUCOPTER_MODES["GUIDED_NOGPS"]
    guid_options: int = 0
    climb_kp: float = 1.5
    speed_up: float = 2.5
    speed_down: float = 1.5

    def __post_init__(self) -> None:
        if self.guided_mode not in (ARDUCOPTER_MODES["GUIDED"], ARDUCOPTER_MODES["GUIDED_NOGPS"]):
            raise ValueError(f"guided_mode must be 4 (GUIDED) or 20 (GUIDED_NOGPS); got {self.guided_mode}")

    def decode(self, base_mode: int, custom_mode: int) -> VehicleMode:
        armed = bool(base_mode & MAV_MODE_FLAG_SAFETY_ARMED)
        guided = custom_mode in (ARDUCOPTER_MODES["GUIDED"], ARDUCOPTER_MODES["GUIDED_NOGPS"])
        return VehicleMode(armed, guided, _ARDU_NAMES.get(custom_mode, f"MODE{custom_mode}"))

    def offboard_command(self) -> tuple[float, float, float]:
        return (float(MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), float(self.guided_mode), 0.0)

    def hold_command(self) -> tuple[float, float, float]:
        # LOITER needs a position estimate; ALT_HOLD would need RC sticks. BRAKE is the safe stop.
        return (float(MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), float(ARDUCOPTER_MODES["BRAKE"]), 0.0)

    def land_command(self) -> tuple[float, float, float]:
        return (float(MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), float(ARDUCOPTER_MODES["LAND"]), 0.0)

    @property
    def climb_rate_thrust(self) -> bool:
        return not (self.guid_options & GUID_OPTIONS_SET_ATTITUDE_TARGET_THRUST)

    def climb_rate_to_field(self, vz: float) -> float:
        """Climb rate [m/s, up] -> the thrust field in [0, 1] (0.5 = hold)."""
        if vz >= 0.0:
            f = 0.5 + 0.5 * min(vz / self.speed_up, 1.0)
        else:
            f = 0.5 - 0.5 * min(-vz / self.speed_down, 1.0)
        return f

    def field_to_climb_rate(self, f: float) -> float:
        """Inverse of :meth:`climb_rate_to_field` (what ArduPilot does with the field) [m/s]."""
        f = min(max(f, 0.0), 1.0)
        return (f - 0.5) * 2.0 * (self.speed_up if f >= 0.5 else self.speed_down)

    def thrust_field(self, thrust: float, z_ref: float, z: float) -> float:
        if not self.climb_rate_thrust:
            return thrust
        vz = self.climb_kp * (z_ref - z)
        return self.climb_rate_to_field(vz if math.isfinite(vz) else 0.0)

    def hover_field(self, hover_thrust: float) -> float:
        return 0.5 if self.climb_rate_thrust else hover_thrust

    def mode_command_name(self, params: tuple[float, float, float]) -> str:
        return _ARDU_NAMES.get(int(params[1]), f"MODE{int(params[1])}")


def make_profile(name: str, **kw) -> Profile:
    """A profile by name: "px4" or "ardupilot" (keyword arguments set its fields)."""
    name = name.lower()
    if name == "px4":
        return PX4Profile(**kw)
    if name in ("ardupilot", "arducopter", "apm"):
        return ArduPilotProfile(**kw)
    raise ValueError(f"unknown autopilot profile {name!r}; choose 'px4' or 'ardupilot'")
