"""Field derivation for PX4 / MAVLink logs (the frame math is :mod:`ddpc_codegen.robot.frames`).

Conventions (PX4 and MAVLink agree): quaternions ``[w, x, y, z]`` rotate body FRD into local NED,
Euler angles are Z-Y-X, positions/velocities are NED; the datasets use "up" for heights
(``z_up = -z_ned``), because a height controller's reference and output are heights.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from ddpc_codegen.errors import DataError
from ddpc_codegen.robot.frames import euler_from_quat_array, unwrap_angle, up_from_down_array

__all__ = ["derive_field", "ANGLE_FIELDS", "unwrap_angle"]

ANGLE_FIELDS = ("roll", "pitch", "yaw")


# Field aliases across PX4 versions: trajectory_setpoint had x/y/z until v1.13, then arrays.
_ALIASES = {
    "x": "position[0]", "y": "position[1]", "z": "position[2]",
    "vx": "velocity[0]", "vy": "velocity[1]", "vz": "velocity[2]",
    "ax": "acceleration[0]", "ay": "acceleration[1]", "az": "acceleration[2]",
}
_QUAT_FIELDS = ("q", "q_d")  # vehicle_attitude / MAVLink: q; vehicle_attitude_setpoint: q_d


def derive_field(fields: Mapping[str, np.ndarray], name: str, where: str) -> tuple[np.ndarray, str]:
    """Values (N,) of a raw or derived field of one topic/message, and how they were obtained.

    Resolution order: the raw field; ``F_up`` = -F (NED/FRD down -> up); ``roll``/``pitch``/
    ``yaw`` = Euler ZYX of the quaternion ``q[0..3]`` or ``q_d[0..3]`` (else the legacy
    ``roll_body`` etc.); PX4 version aliases (``z`` -> ``position[2]`` ...).

    Args:
        fields: field name -> (N,) array (arrays flattened as ``q[0]``..).
        name: the field asked for.
        where: "topic X in FILE", quoted in the error.
    Raises:
        DataError naming the field, the topic and the fields that exist.
    """
    if name in fields:
        return np.asarray(fields[name], dtype=float), name
    if name.endswith("_up") and len(name) > 3:
        v, how = derive_field(fields, name[:-3], where)
        return up_from_down_array(v), f"-({how}) [NED/FRD down -> up]"
    if name in ANGLE_FIELDS:
        for qn in _QUAT_FIELDS:
            keys = [f"{qn}[{i}]" for i in range(4)]
            if all(k in fields for k in keys):
                q = np.column_stack([np.asarray(fields[k], dtype=float) for k in keys])
                return euler_from_quat_array(q)[:, ANGLE_FIELDS.index(name)], f"{name} of Euler ZYX({qn}[0..3])"
        if f"{name}_body" in fields:
            return np.asarray(fields[f"{name}_body"], dtype=float), f"{name}_body"
    if name in _ALIASES and _ALIASES[name] in fields:
        return np.asarray(fields[_ALIASES[name]], dtype=float), _ALIASES[name]
    raw = sorted(k for k in fields if k != "timestamp")
    derived = []
    if any(f"{qn}[0]" in fields for qn in _QUAT_FIELDS):
        derived += list(ANGLE_FIELDS)
    derived.append("<field>_up")
    raise DataError(
        f"field {name!r} not found in {where}; fields: {', '.join(raw)}; derived: {', '.join(derived)}"
    )
