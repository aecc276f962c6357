"""Rotations and frame conversions of the robot side (scalar, for the 200 Hz tick).

Conventions: quaternions (w, x, y, z), body -> world; Euler angles intrinsic Z-Y-X (yaw, pitch,
roll), R = Rz(yaw) Ry(pitch) Rx(roll). World ENU / body FLU on our side, NED / FRD on the
autopilot's (PX4 and ArduPilot); the MAVROS convention connects them.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np

__all__ = ["quat_from_euler", "euler_from_quat", "quat_multiply", "enu_flu_to_ned_frd", "ned_frd_to_enu_flu"]


def quat_from_euler(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Quaternion (w, x, y, z) of R = Rz(yaw) Ry(pitch) Rx(roll)."""
    cr, sr = math.cos(0.5 * roll), math.sin(0.5 * roll)
    cp, sp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
    cy, sy = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
    return np.array(
        [
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        ]
    )


def euler_from_quat(q: Sequence[float]) -> np.ndarray:
    """(roll, pitch, yaw) in rad, Z-Y-X, from a quaternion (w, x, y, z)."""
    w, x, y, z = (float(v) for v in q)
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    s = max(-1.0, min(1.0, 2.0 * (w * y - z * x)))
    pitch = math.asin(s)
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return np.array([roll, pitch, yaw])


def quat_multiply(a: Sequence[float], b: Sequence[float]) -> np.ndarray:
    """Hamilton product a * b of quaternions (w, x, y, z)."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return np.array(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ]
    )


_S = math.sqrt(0.5)
_Q_ENU_TO_NED = np.array([0.0, _S, _S, 0.0])  # pi about (1, 1, 0)/sqrt(2): swaps x/y, flips z
_Q_FRD_TO_FLU = np.array([0.0, 1.0, 0.0, 0.0])  # pi about x: flips y and z


def enu_flu_to_ned_frd(q: Sequence[float]) -> np.ndarray:
    """Attitude quaternion body-FLU->world-ENU to body-FRD->world-NED (what PX4 expects)."""
    return quat_multiply(quat_multiply(_Q_ENU_TO_NED, q), _Q_FRD_TO_FLU)


def ned_frd_to_enu_flu(q: Sequence[float]) -> np.ndarray:
    """Inverse of :func:`enu_flu_to_ned_frd` (both constant rotations are involutions)."""
    return quat_multiply(quat_multiply(_Q_ENU_TO_NED, q), _Q_FRD_TO_FLU)
