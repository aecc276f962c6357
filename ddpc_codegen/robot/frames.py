"""Rotations and frame conversions of the robot side: one module, two paths.

Conventions:

* Quaternions are Hamilton ``(w, x, y, z)`` rotating body vectors into the world frame
  (``v_world = q ⊗ v_body ⊗ q*``).
* Euler angles are intrinsic Z-Y-X (yaw, then pitch, then roll), ``R = Rz(yaw) Ry(pitch) Rx(roll)``,
  radians: roll in (-π, π], pitch in [-π/2, π/2], yaw in (-π, π]. At gimbal lock (|pitch| = π/2)
  only yaw ∓ roll is defined: roll is returned as 0 and yaw carries the rest.
* Our side (controller, simulator) is world ENU / body FLU; the autopilots' side (PX4,
  ArduPilot, MAVLink, their logs) is world NED / body FRD. The MAVROS convention connects them:
  ``q_NED_FRD = q_(ENU->NED) ⊗ q_ENU_FLU ⊗ q_(FRD->FLU)``, so roll keeps its sign, pitch flips and
  ``yaw_NED = π/2 - yaw_ENU``. Every frame map here is its own inverse; both directions are named
  anyway so that call sites read the right way round.

Naming: ``<result>_from_<input>`` throughout (``p_enu = enu_from_ned(p_ned)``), with the quantity
as prefix where it is not a plain vector (``euler_enu_from_ned``, ``quat_enu_flu_from_ned_frd``,
``rates_flu_from_frd``). A vector, an Euler triple or a quaternion is always *one* argument
(a sequence); only :func:`quat_from_euler` takes the three angles separately.

Two paths:

* **Scalar** (the 200 Hz tick, plain ``math``, no numpy overhead per call and never
  ``scipy.spatial.transform``): one quantity in, a tuple (or, for the three historical functions
  :func:`quat_from_euler`, :func:`euler_from_quat`, :func:`quat_multiply`, a small ndarray) out.
* **Vectorised** (log importers, analysis): names end in ``_array``; arrays of shape (..., k) or
  (N, k) in and out.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np
from numpy.typing import ArrayLike

__all__ = [
    # scalar path
    "quat_from_euler",
    "euler_from_quat",
    "quat_multiply",
    "matrix_from_quat",
    "rotate",
    "rotate_inverse",
    "enu_from_ned",
    "ned_from_enu",
    "flu_from_frd",
    "frd_from_flu",
    "rates_flu_from_frd",
    "rates_frd_from_flu",
    "euler_enu_from_ned",
    "euler_ned_from_enu",
    "quat_enu_flu_from_ned_frd",
    "quat_ned_frd_from_enu_flu",
    "yaw_enu_from_ned",
    "wrap_pi",
    # vectorised path
    "quat_from_euler_array",
    "euler_from_quat_array",
    "enu_from_ned_array",
    "up_from_down_array",
    "yaw_enu_from_ned_array",
    "unwrap_angle",
]

_HALF_PI = 0.5 * math.pi
_S = math.sqrt(0.5)
# |sin(pitch)| above this is gimbal lock (|pitch| within ~1.4e-7 rad of 90 deg): roll and yaw are
# then computed from components of size ~cos(pitch), pure rounding noise.
_LOCK = 1.0 - 1e-14


# ============================================================================ scalar path
def quat_from_euler(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Quaternion (4,) (w, x, y, z) of R = Rz(yaw) Ry(pitch) Rx(roll); angles [rad]."""
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
    """(3,) roll, pitch, yaw [rad], Z-Y-X, of a unit quaternion (w, x, y, z)."""
    w, x, y, z = (float(v) for v in q)
    # clip: rounding can push |sin(pitch)| a hair above 1 near ±90°
    s = max(-1.0, min(1.0, 2.0 * (w * y - z * x)))
    pitch = math.asin(s)
    if abs(s) > _LOCK:
        # Gimbal lock: both atan2 below would divide ~0 by ~0. Only yaw ∓ roll is defined; put it in yaw.
        return np.array([0.0, pitch, wrap_pi(2.0 * math.atan2(z, w))])
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return np.array([roll, pitch, yaw])


def quat_multiply(a: Sequence[float], b: Sequence[float]) -> np.ndarray:
    """Hamilton product a ⊗ b (4,) of quaternions (w, x, y, z)."""
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


def matrix_from_quat(q: Sequence[float]) -> tuple[tuple[float, float, float], ...]:
    """Rotation matrix R(q) (3 rows of 3) body -> world of a unit quaternion (w, x, y, z)."""
    qw, qx, qy, qz = q
    return (
        (1.0 - 2.0 * (qy * qy + qz * qz), 2.0 * (qx * qy - qw * qz), 2.0 * (qx * qz + qw * qy)),
        (2.0 * (qx * qy + qw * qz), 1.0 - 2.0 * (qx * qx + qz * qz), 2.0 * (qy * qz - qw * qx)),
        (2.0 * (qx * qz - qw * qy), 2.0 * (qy * qz + qw * qx), 1.0 - 2.0 * (qx * qx + qy * qy)),
    )


def _rotate(w: float, x: float, y: float, z: float, v: Sequence[float]) -> tuple[float, float, float]:
    # v' = v + 2 w (u x v) + 2 u x (u x v), u = (x, y, z): 18 multiplications, no matrix
    vx, vy, vz = v
    cx, cy, cz = y * vz - z * vy, z * vx - x * vz, x * vy - y * vx
    dx, dy, dz = y * cz - z * cy, z * cx - x * cz, x * cy - y * cx
    return (vx + 2 * (w * cx + dx), vy + 2 * (w * cy + dy), vz + 2 * (w * cz + dz))


def rotate(q: Sequence[float], v: Sequence[float]) -> tuple[float, float, float]:
    """R(q) v: a body vector (3,) in the world frame, for a unit quaternion q (w, x, y, z)."""
    w, x, y, z = (float(a) for a in q)
    return _rotate(w, x, y, z, v)


def rotate_inverse(q: Sequence[float], v: Sequence[float]) -> tuple[float, float, float]:
    """R(q)^T v: a world vector (3,) in the body frame, for a unit quaternion q (w, x, y, z)."""
    w, x, y, z = (float(a) for a in q)
    return _rotate(w, -x, -y, -z, v)


def enu_from_ned(v: Sequence[float]) -> tuple[float, float, float]:
    """A NED vector (north, east, down) as ENU (east, north, up); positions and velocities."""
    x, y, z = v
    return (y, x, -z)


def ned_from_enu(v: Sequence[float]) -> tuple[float, float, float]:
    """An ENU vector as NED (the same swap as :func:`enu_from_ned`)."""
    x, y, z = v
    return (y, x, -z)


def flu_from_frd(v: Sequence[float]) -> tuple[float, float, float]:
    """A body FRD vector (front, right, down) as FLU (front, left, up)."""
    x, y, z = v
    return (x, -y, -z)


def frd_from_flu(v: Sequence[float]) -> tuple[float, float, float]:
    """A body FLU vector as FRD (the same flip as :func:`flu_from_frd`)."""
    x, y, z = v
    return (x, -y, -z)


rates_flu_from_frd = flu_from_frd  # body rates (p, q, r) are body vectors
rates_frd_from_flu = frd_from_flu


def wrap_pi(a: float) -> float:
    """Angle [rad] wrapped to (-π, π]."""
    return math.atan2(math.sin(a), math.cos(a))


def yaw_enu_from_ned(yaw: float) -> float:
    """Heading from north, clockwise (NED) -> from east, counter-clockwise (ENU) [rad], in (-π, π]."""
    return wrap_pi(_HALF_PI - yaw)


def euler_enu_from_ned(e: Sequence[float]) -> tuple[float, float, float]:
    """Z-Y-X Euler angles (roll, pitch, yaw) of FRD w.r.t. NED -> of FLU w.r.t. ENU [rad]."""
    roll, pitch, yaw = e
    return (roll, -pitch, wrap_pi(_HALF_PI - yaw))


def euler_ned_from_enu(e: Sequence[float]) -> tuple[float, float, float]:
    """Z-Y-X Euler angles of FLU w.r.t. ENU -> of FRD w.r.t. NED [rad] (same map)."""
    roll, pitch, yaw = e
    return (roll, -pitch, wrap_pi(_HALF_PI - yaw))


def quat_ned_frd_from_enu_flu(q: Sequence[float]) -> tuple[float, float, float, float]:
    """Attitude body FLU -> world ENU as body FRD -> world NED (what MAVLink carries): closed
    form of q_(ENU->NED) ⊗ q ⊗ q_(FRD->FLU), both constant rotations by π."""
    w, x, y, z = q
    return (-_S * (w + z), -_S * (x + y), _S * (y - x), _S * (z - w))


def quat_enu_flu_from_ned_frd(q: Sequence[float]) -> tuple[float, float, float, float]:
    """Attitude body FRD -> world NED as body FLU -> world ENU (same closed form: an involution
    up to the quaternion sign, which is the same rotation)."""
    w, x, y, z = q
    return (-_S * (w + z), -_S * (x + y), _S * (y - x), _S * (z - w))


# ============================================================================ vectorised path
def quat_from_euler_array(roll: ArrayLike, pitch: ArrayLike, yaw: ArrayLike) -> np.ndarray:
    """Euler Z-Y-X angles [rad] (broadcastable arrays) -> unit quaternions (..., 4) (w, x, y, z)."""
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


def euler_from_quat_array(q: ArrayLike) -> np.ndarray:
    """Quaternions (N, 4) or (4,) (w, x, y, z) -> Euler Z-Y-X (N, 3) or (3,) [rad].

    Quaternions are normalised first (logged floats drift from unit norm); a zero or non-finite
    quaternion yields a NaN row, never a made-up attitude.
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
    s = np.clip(2.0 * (w * y - z * x), -1.0, 1.0)
    lock = np.abs(s) > _LOCK  # gimbal lock: only yaw ∓ roll is defined; put it in yaw (as the scalar path)
    roll = np.where(lock, 0.0, np.arctan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y)))
    pitch = np.arcsin(s)
    yaw = np.where(lock, np.angle(np.exp(2j * np.arctan2(z, w))),
                   np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)))
    out = np.stack([roll, pitch, yaw], axis=1)
    out[bad] = np.nan
    return out[0] if single else out


def enu_from_ned_array(v: ArrayLike) -> np.ndarray:
    """NED vectors (..., 3) -> ENU (..., 3): ``[east, north, up] = [y, x, -z]``."""
    a = np.asarray(v, dtype=float)
    if a.shape[-1] != 3:
        raise ValueError(f"NED vectors must have 3 components; got shape {a.shape}")
    return np.stack([a[..., 1], a[..., 0], -a[..., 2]], axis=-1)


def up_from_down_array(z: ArrayLike) -> np.ndarray:
    """Down-pointing coordinates (NED z, FRD z: position, velocity, thrust) -> up-pointing."""
    return -np.asarray(z, dtype=float)


def yaw_enu_from_ned_array(yaw: ArrayLike) -> np.ndarray:
    """Headings from north, clockwise (NED) -> from east, counter-clockwise (ENU) [rad], in (-π, π]."""
    return np.angle(np.exp(1j * (np.pi / 2 - np.asarray(yaw, dtype=float))))


def unwrap_angle(a: ArrayLike) -> np.ndarray:
    """An angle signal (N,) [rad] without 2π jumps (interpolation across ±π is wrong, and an LTI
    model of the closed loop sees a continuous yaw, not a sawtooth)."""
    return np.unwrap(np.asarray(a, dtype=float))
