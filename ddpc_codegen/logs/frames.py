"""Frame and unit conversions for PX4 / MAVLink logs.

Conventions (PX4 and MAVLink agree):

- Quaternions are Hamilton ``[w, x, y, z]`` rotating body FRD (front-right-down) vectors into
  the local NED (north-east-down) frame: ``v_ned = q ⊗ v_frd ⊗ q*``.
- Euler angles are the intrinsic Z-Y-X (yaw, then pitch, then roll) sequence, in radians:
  roll in (-π, π], pitch in [-π/2, π/2], yaw in (-π, π].
- Positions/velocities are NED; the datasets use "up" for heights (``z_up = -z_ned``), because
  a height controller's reference and output are heights.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np
from numpy.typing import ArrayLike

from ddpc_codegen.errors import DataError

__all__ = [
    "quat_to_euler",
    "euler_to_quat",
    "ned_to_enu",
    "down_to_up",
    "yaw_ned_to_enu",
    "unwrap_angle",
    "derive_field",
    "ANGLE_FIELDS",
]

ANGLE_FIELDS = ("roll", "pitch", "yaw")


def quat_to_euler(q: ArrayLike) -> np.ndarray:
    """Quaternion(s) ``[w, x, y, z]`` (N, 4) or (4,) -> Euler ZYX ``[roll, pitch, yaw]`` in rad.

    Quaternions are normalised first (logged floats drift from unit norm); a zero or non-finite
    quaternion yields a NaN row, never a made-up attitude. At gimbal lock (|pitch| = π/2) roll
    and yaw are not separable; the split returned is the formula's, as in any ZYX extraction.

    Returns:
        array (N, 3) (or (3,) for a single quaternion), radians.
    """
    a = np.asarray(q, dtype=float)
    single = a.ndim == 1
    a = np.atleast_2d(a)
    if a.shape[-1] != 4:
        raise ValueError(f"quaternions must have 4 components [w, x, y, z]; got shape {a.shape}")
    norm = np.linalg.norm(a, axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        a = a / norm
    bad = ~np.isfinite(a).all(axis=1) | (norm[:, 0] < 1e-9)
    w, x, y, z = a.T
    roll = np.arctan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    # clip: rounding can push |sin(pitch)| a hair above 1 near ±90°
    pitch = np.arcsin(np.clip(2.0 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    out = np.stack([roll, pitch, yaw], axis=1)
    out[bad] = np.nan
    return out[0] if single else out


def euler_to_quat(roll: ArrayLike, pitch: ArrayLike, yaw: ArrayLike) -> np.ndarray:
    """Euler ZYX angles (rad, broadcastable arrays) -> unit quaternions ``[w, x, y, z]`` (..., 4)."""
    r, p, y = (np.asarray(v, dtype=float) / 2.0 for v in (roll, pitch, yaw))
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.stack(
        [
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        ],
        axis=-1,
    )


def ned_to_enu(v: ArrayLike) -> np.ndarray:
    """NED vector(s) (..., 3) -> ENU (..., 3): ``[east, north, up] = [y, x, -z]``."""
    a = np.asarray(v, dtype=float)
    if a.shape[-1] != 3:
        raise ValueError(f"NED vectors must have 3 components; got shape {a.shape}")
    return np.stack([a[..., 1], a[..., 0], -a[..., 2]], axis=-1)


def down_to_up(z: ArrayLike) -> np.ndarray:
    """A down-pointing coordinate (NED z, FRD z: position, velocity, thrust) -> up-pointing."""
    return -np.asarray(z, dtype=float)


def yaw_ned_to_enu(yaw: ArrayLike) -> np.ndarray:
    """Heading from north, clockwise (NED) -> from east, counter-clockwise (ENU), in (-π, π]."""
    return np.angle(np.exp(1j * (np.pi / 2 - np.asarray(yaw, dtype=float))))


def unwrap_angle(a: ArrayLike) -> np.ndarray:
    """Remove 2π jumps so an angle signal is continuous (interpolation across ±π is wrong,
    and an LTI model of the closed loop sees a continuous yaw, not a sawtooth)."""
    return np.unwrap(np.asarray(a, dtype=float))


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
        return down_to_up(v), f"-({how}) [NED/FRD down -> up]"
    if name in ANGLE_FIELDS:
        for qn in _QUAT_FIELDS:
            keys = [f"{qn}[{i}]" for i in range(4)]
            if all(k in fields for k in keys):
                q = np.column_stack([np.asarray(fields[k], dtype=float) for k in keys])
                return quat_to_euler(q)[:, ANGLE_FIELDS.index(name)], f"{name} of Euler ZYX({qn}[0..3])"
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
