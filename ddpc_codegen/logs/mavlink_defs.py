"""What the MAVLink definitions say, as pymavlink ships them: field units (the XML ``units``
attribute, ``fieldunits_by_name``) and flight modes per autopilot and vehicle type
(``mavutil.mode_mapping_bynumber``). The tlog importer takes both from here, never from names."""

from __future__ import annotations

import dataclasses

from pymavlink import mavutil

from ddpc_codegen.errors import DataError
from ddpc_codegen.logs.channels import ChannelSpec
from ddpc_codegen.logs.fields import ANGLE_FIELDS

__all__ = ["mavlink_unit", "with_mavlink_units", "heartbeat_mode", "PX4_MAIN_MODES", "ARDUPILOT_OFFBOARD_MODES"]

PX4_MAIN_MODES = {1: "manual", 2: "altctl", 3: "posctl", 4: "auto", 5: "acro", 6: "offboard",
                  7: "stabilized", 8: "rattitude", 9: "termination"}
PX4_MAIN_MODE_OFFBOARD = 6
# ArduPilot's off-board modes (setpoints from a companion computer), by name in every vehicle type's map
ARDUPILOT_OFFBOARD_MODES = ("GUIDED", "GUIDED_NOGPS")
MAV_AUTOPILOT_ARDUPILOTMEGA = 3
MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1
MAV_MODE_FLAG_SAFETY_ARMED = 128

# Unit spellings that mean the same (MAVLink XML writes m/s/s)
_SAME_UNIT = {"m/s/s": "m/s^2", "rad/s/s": "rad/s^2", "m/s2": "m/s^2"}


def mavlink_unit(cls, field: str) -> str | None:
    """Unit of a raw or derived field of MAVLink message class ``cls`` from its XML definition
    (pymavlink's ``fieldunits_by_name``): "" when the definition gives none, None when ``field``
    is not a field of the message (derived Euler angles of ``q`` are "rad"; ``F_up`` has F's unit).
    """
    base = field[:-3] if field.endswith("_up") and len(field) > 3 else field
    raw = base.split("[")[0]
    if raw in cls.fieldnames:
        return getattr(cls, "fieldunits_by_name", {}).get(raw, "")
    if base in ANGLE_FIELDS and "q" in cls.fieldnames:
        return "rad"  # derived here from the quaternion (robot.frames.euler_from_quat_array)
    return None


def with_mavlink_units(specs: list[ChannelSpec], mod) -> list[ChannelSpec]:
    """Specs with units from the MAVLink definitions; a stated unit that contradicts them is an error."""
    classes = {c.msgname: c for c in mod.mavlink_map.values()}
    out = []
    for s in specs:
        cls = classes.get(s.source)
        unit = mavlink_unit(cls, s.field) if cls is not None else None
        if unit is None:  # unknown message or field: reported with the fields when the data is read
            out.append(s if s.unit_given else dataclasses.replace(s, unit=""))
        elif not s.unit_given:
            out.append(dataclasses.replace(s, unit=unit))
        elif unit and _SAME_UNIT.get(unit, unit) != _SAME_UNIT.get(s.unit, s.unit):
            raise DataError(f"channel {s.text!r}: {s.source}.{s.field} is in {unit!r} by the MAVLink definition, "
                            f"not {s.unit!r}; the importer does not convert units: drop ':{s.unit}' "
                            f"(or state ':{unit}') and convert in the config / data")
        else:
            out.append(s)
    return out


def heartbeat_mode(msg) -> tuple[int, str, bool]:
    """(state code, mode name, is off-board) of one autopilot HEARTBEAT.

    ArduPilot (MAV_AUTOPILOT_ARDUPILOTMEGA): custom_mode is the mode number of the vehicle type
    (pymavlink's per-type maps: ArduCopter, ArduPlane, ArduSub, Rover...); off-board = GUIDED or
    GUIDED_NOGPS. PX4 and others: PX4's main mode in bits 16..23 (6 = offboard). Code -1 = no
    custom mode reported.
    """
    if not msg.base_mode & MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
        return -1, "no_custom_mode", False
    v = int(msg.custom_mode)
    if msg.autopilot == MAV_AUTOPILOT_ARDUPILOTMEGA:
        name = (mavutil.mode_mapping_bynumber(msg.type) or {}).get(v, f"mode_{v}")
        return v, name, name in ARDUPILOT_OFFBOARD_MODES
    mm, sub = (v >> 16) & 0xFF, (v >> 24) & 0xFF
    if mm == 0:
        return -1, "no_custom_mode", False
    name = PX4_MAIN_MODES.get(mm, f"main_mode_{mm}")
    return v, f"{name}.{sub}" if mm == 4 else name, mm == PX4_MAIN_MODE_OFFBOARD
