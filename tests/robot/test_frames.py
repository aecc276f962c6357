"""robot/frames.py against an independent oracle: scipy.spatial.transform.Rotation.

Euler angles are intrinsic Z-Y-X: scipy's ``"ZYX"`` with angles (yaw, pitch, roll). scipy's
quaternions are scalar-last (x, y, z, w); ours are (w, x, y, z). The NED/FRD <-> ENU/FLU maps
are checked as coordinate changes: v_ned = M v_enu, v_flu = F v_frd, so an attitude body FLU ->
world ENU with matrix R is body FRD -> world NED with matrix M R F.
"""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from ddpc_codegen.robot import frames as fr

M_ENU_TO_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
F_FRD_TO_FLU = np.diag([1.0, -1.0, -1.0])
HALF_PI = math.pi / 2
S45 = math.sqrt(0.5)


def scipy_rot(q) -> Rotation:
    w, x, y, z = q
    return Rotation.from_quat([x, y, z, w])


def scipy_euler(roll: float, pitch: float, yaw: float) -> Rotation:
    return Rotation.from_euler("ZYX", [yaw, pitch, roll])


def same_rotation(q1, q2, atol: float = 1e-12) -> None:
    """q and -q are the same rotation: compare |<q1, q2>| with 1."""
    a, b = np.asarray(q1, float), np.asarray(q2, float)
    assert abs(abs(float(a @ b)) - 1.0) < atol, (a, b)


def wrap(a):
    return np.angle(np.exp(1j * np.asarray(a, float)))


def _angle_cases() -> list[tuple[float, float, float]]:
    rng = np.random.default_rng(11)
    cases = [tuple(v) for v in rng.uniform([-math.pi, -HALF_PI, -math.pi], [math.pi, HALF_PI, math.pi], (24, 3))]
    for eps in (1e-3, 1e-6):  # near gimbal lock
        cases += [(0.3, HALF_PI - eps, -1.2), (-2.5, -HALF_PI + eps, 0.7)]
    cases += [(0.0, 0.0, 0.0), (math.pi - 1e-9, 0.0, 0.0), (0.0, 0.0, -math.pi + 1e-9), (0.1, HALF_PI, 0.2),
              (-0.4, -HALF_PI, 2.0)]
    return cases


ANGLES = _angle_cases()
REGULAR = [a for a in ANGLES if abs(abs(a[1]) - HALF_PI) > 1e-2]


def _unit_quats(n: int = 20, seed: int = 5) -> list[np.ndarray]:
    q = np.random.default_rng(seed).normal(size=(n, 4))
    return list(q / np.linalg.norm(q, axis=1, keepdims=True))


QUATS = _unit_quats()


# ----------------------------------------------------------------------------- scalar path
@pytest.mark.parametrize("rpy", ANGLES)
def test_quat_from_euler_matches_scipy(rpy):
    q = fr.quat_from_euler(*rpy)
    np.testing.assert_allclose(scipy_rot(q).as_matrix(), scipy_euler(*rpy).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(fr.quat_from_euler_array(*rpy), q, atol=1e-15)


@pytest.mark.parametrize("rpy", ANGLES)
def test_euler_from_quat_reproduces_the_rotation_even_near_gimbal_lock(rpy):
    R = scipy_euler(*rpy)
    x, y, z, w = R.as_quat()
    e = fr.euler_from_quat((w, x, y, z))
    # At gimbal lock roll and yaw are not separable and asin loses half the digits: compare rotations.
    np.testing.assert_allclose(scipy_euler(*e).as_matrix(), R.as_matrix(), atol=1e-6)
    assert -HALF_PI <= e[1] <= HALF_PI


@pytest.mark.parametrize("rpy", REGULAR)
def test_euler_from_quat_matches_scipy_angles(rpy):
    x, y, z, w = scipy_euler(*rpy).as_quat()
    yaw, pitch, roll = scipy_rot((w, x, y, z)).as_euler("ZYX")
    np.testing.assert_allclose(wrap(fr.euler_from_quat((w, x, y, z)) - (roll, pitch, yaw)), 0.0, atol=1e-9)


@pytest.mark.parametrize("q", QUATS)
def test_matrix_rotate_and_product_match_scipy(q):
    R = scipy_rot(q)
    np.testing.assert_allclose(np.array(fr.matrix_from_quat(q)), R.as_matrix(), atol=1e-12)
    v = np.array([0.3, -1.2, 2.0])
    np.testing.assert_allclose(fr.rotate(q, v), R.apply(v), atol=1e-12)
    np.testing.assert_allclose(fr.rotate_inverse(q, v), R.inv().apply(v), atol=1e-12)
    q2 = QUATS[0]
    prod = fr.quat_multiply(q, q2)
    np.testing.assert_allclose(scipy_rot(prod).as_matrix(), (R * scipy_rot(q2)).as_matrix(), atol=1e-12)


@pytest.mark.parametrize("q", QUATS)
def test_attitude_enu_flu_to_ned_frd_is_the_coordinate_change(q):
    R = scipy_rot(q).as_matrix()
    q_ned = fr.quat_ned_frd_from_enu_flu(q)
    np.testing.assert_allclose(scipy_rot(q_ned).as_matrix(), M_ENU_TO_NED @ R @ F_FRD_TO_FLU, atol=1e-12)
    same_rotation(fr.quat_enu_flu_from_ned_frd(q_ned), q)
    np.testing.assert_allclose(np.linalg.norm(q_ned), 1.0, atol=1e-15)


@pytest.mark.parametrize("rpy", REGULAR)
def test_euler_enu_flu_to_ned_frd_matches_the_rotated_attitude(rpy):
    R_ned = M_ENU_TO_NED @ scipy_euler(*rpy).as_matrix() @ F_FRD_TO_FLU
    yaw, pitch, roll = Rotation.from_matrix(R_ned).as_euler("ZYX")
    np.testing.assert_allclose(wrap(np.array(fr.euler_ned_from_enu(rpy)) - (roll, pitch, yaw)), 0.0, atol=1e-9)
    np.testing.assert_allclose(wrap(np.array(fr.euler_enu_from_ned((roll, pitch, yaw))) - rpy), 0.0, atol=1e-9)
    assert fr.yaw_enu_from_ned(yaw) == pytest.approx(float(wrap(rpy[2])), abs=1e-9)


def test_vector_maps_are_the_coordinate_changes():
    v = np.array([1.0, 2.0, 3.0])
    np.testing.assert_array_equal(fr.enu_from_ned(v), M_ENU_TO_NED.T @ v)
    np.testing.assert_array_equal(fr.ned_from_enu(v), M_ENU_TO_NED @ v)
    np.testing.assert_array_equal(fr.flu_from_frd(v), F_FRD_TO_FLU @ v)
    np.testing.assert_array_equal(fr.frd_from_flu(v), F_FRD_TO_FLU.T @ v)
    np.testing.assert_array_equal(fr.rates_flu_from_frd(v), F_FRD_TO_FLU @ v)
    np.testing.assert_array_equal(fr.enu_from_ned_array(np.tile(v, (4, 1))), np.tile(M_ENU_TO_NED @ v, (4, 1)))


def test_hand_values():
    # NED: +30 deg pitch puts the nose north and up (negative down); +90 deg yaw points it east.
    q = fr.quat_from_euler(0.0, math.pi / 6, 0.0)
    np.testing.assert_allclose(fr.rotate(q, (1, 0, 0)), [math.cos(math.pi / 6), 0, -0.5], atol=1e-12)
    np.testing.assert_allclose(fr.rotate(fr.quat_from_euler(0, 0, HALF_PI), (1, 0, 0)), [0, 1, 0], atol=1e-12)
    # ENU yaw 0 faces east = NED yaw +90 deg; roll keeps its sign, pitch flips.
    e = fr.euler_from_quat(fr.quat_ned_frd_from_enu_flu(fr.quat_from_euler(0.1, 0.2, 0.0)))
    np.testing.assert_allclose(e, [0.1, -0.2, HALF_PI], atol=1e-12)
    for q, rpy in [([S45, 0, 0, S45], (0, 0, HALF_PI)), ([S45, S45, 0, 0], (HALF_PI, 0, 0)),
                   ([0, 0, 0, 1], (0, 0, math.pi)), ([2, 0, 0, 0], (0, 0, 0))]:
        np.testing.assert_allclose(fr.euler_from_quat_array(q), rpy, atol=1e-12)


# ----------------------------------------------------------------------------- vectorised path
def test_vectorised_euler_matches_scipy_and_the_scalar_path():
    rpy = np.array(REGULAR)
    q = fr.quat_from_euler_array(rpy[:, 0], rpy[:, 1], rpy[:, 2])
    assert q.shape == (len(rpy), 4)
    R = Rotation.from_euler("ZYX", rpy[:, ::-1])
    np.testing.assert_allclose(Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_matrix(), R.as_matrix(), atol=1e-12)
    e = fr.euler_from_quat_array(q * 3.0)  # not normalised: same attitude
    np.testing.assert_allclose(wrap(e - rpy), 0.0, atol=1e-9)
    np.testing.assert_allclose(e, np.array([fr.euler_from_quat(v) for v in q]), atol=1e-12)


def test_vectorised_invalid_quaternions_give_nan_rows_and_shapes_are_checked():
    bad = fr.euler_from_quat_array([[0, 0, 0, 0], [np.nan, 0, 0, 1], [1, 0, 0, 0]])
    assert np.isnan(bad[:2]).all() and np.array_equal(bad[2], [0, 0, 0])
    with pytest.raises(ValueError, match="4 components"):
        fr.euler_from_quat_array(np.zeros((3, 3)))
    with pytest.raises(ValueError, match="3 components"):
        fr.enu_from_ned_array(np.zeros((3, 4)))


def test_vectorised_heading_height_and_unwrap():
    np.testing.assert_allclose(fr.yaw_enu_from_ned_array([0.0, HALF_PI, math.pi]), [HALF_PI, 0.0, -HALF_PI], atol=1e-12)
    np.testing.assert_array_equal(fr.up_from_down_array([-1.5, 2.0]), [1.5, -2.0])
    np.testing.assert_allclose(fr.unwrap_angle([3.0, -3.0]), [3.0, 2 * math.pi - 3.0])


# ----------------------------------------------------------------------------- properties
angle = st.floats(-math.pi, math.pi, allow_nan=False)
pitch_angle = st.floats(-HALF_PI + 1e-3, HALF_PI - 1e-3, allow_nan=False)
component = st.floats(-1.0, 1.0, allow_nan=False)


@settings(max_examples=200, deadline=None)
@given(roll=angle, pitch=pitch_angle, yaw=angle)
def test_property_euler_round_trip_agrees_with_scipy(roll, pitch, yaw):
    q = fr.quat_from_euler(roll, pitch, yaw)
    np.testing.assert_allclose(scipy_rot(q).as_matrix(), scipy_euler(roll, pitch, yaw).as_matrix(), atol=1e-12)
    np.testing.assert_allclose(wrap(fr.euler_from_quat(q) - (roll, pitch, yaw)), 0.0, atol=1e-7)


@settings(max_examples=200, deadline=None)
@given(q=st.tuples(component, component, component, component), v=st.tuples(component, component, component))
def test_property_rotations_and_frame_change_agree_with_scipy(q, v):
    n = math.sqrt(sum(c * c for c in q))
    if n < 1e-3:
        return
    q = tuple(c / n for c in q)
    R = scipy_rot(q)
    np.testing.assert_allclose(fr.rotate(q, v), R.apply(v), atol=1e-12)
    np.testing.assert_allclose(fr.rotate_inverse(q, v), R.inv().apply(v), atol=1e-12)
    q_ned = fr.quat_ned_frd_from_enu_flu(q)
    np.testing.assert_allclose(scipy_rot(q_ned).as_matrix(), M_ENU_TO_NED @ R.as_matrix() @ F_FRD_TO_FLU, atol=1e-12)
    np.testing.assert_allclose(scipy_euler(*fr.euler_from_quat(q)).as_matrix(), R.as_matrix(), atol=1e-6)
    # A body vector seen in NED equals the ENU result mapped to NED.
    np.testing.assert_allclose(fr.rotate(q_ned, fr.frd_from_flu(v)), fr.ned_from_enu(fr.rotate(q, v)), atol=1e-12)


def test_scalar_path_loads_no_scipy():
    code = "import sys, ddpc_codegen.robot.frames; print(any(m.startswith('scipy') for m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == "False"
