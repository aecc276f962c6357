"""Which SITL flights can judge the steering (testbed/sitl_health.py), on synthetic tick logs whose
simulator and estimator are known: a constant EKF offset is judged, a wandering EKF or a frozen
simulator is not, and the diagnosis reproduces errors computed here by hand."""

from __future__ import annotations

import numpy as np
import pytest

from ddpc_codegen.testbed.sitl_health import ESTIMATOR_DEPARTURE_M, flight_diagnosis, sitl_fault
from firmware_bridge.ticklog import TickRecorder, reason_code

DT = 0.005


def _flight(tmp_path, *, ekf_offset=lambda t: 0.05 + 0 * t, error=0.01, freeze=None, name="f.npz"):
    """20 s of steered hover at 1 m: the true height sits ``error`` m above the path, the EKF reads the
    truth plus ``ekf_offset(t)``; ``freeze`` = (t0, t1): the simulator stands still at thrust 0 then."""
    n = int(20.0 / DT)
    rec = TickRecorder(4, 2, capacity=n)
    rng = np.random.default_rng(0)
    for i in range(n):
        k, t = rec.new_row(), i * DT
        a = rec.arrays
        z_des = 1.0 + 0.2 * np.sin(0.6 * t)
        z, vz, thrust = z_des + error, 0.12 * np.cos(0.6 * t), 0.5 + 0.01 * rng.standard_normal()
        if freeze and freeze[0] <= t < freeze[1]:
            z, vz, thrust = 1.3, 0.0, 0.0
        a["t_wall"][k] = a["t_traj"][k] = t
        a["active"][k] = True
        a["reason"][k] = reason_code("steered")
        a["truth_position"][k] = (0.0, 0.0, z)
        a["truth_velocity"][k] = (0.0, 0.0, vz)
        a["position"][k] = (0.0, 0.0, z + ekf_offset(t))
        a["y"][k] = (z + ekf_offset(t), 0.0)
        a["y_des"][k] = (z_des, 0.0)
        a["r_nom"][k] = (z_des, 0.0, 0.0, 0.0)
        a["u"][k] = (z_des - 0.02, 0.0, 0.0, 0.0)
        a["sp_thrust"][k] = thrust
    path = tmp_path / name
    rec.to_log(dt=DT, input_names=("z", "x", "y", "yaw"), output_names=("z", "x")).save(path)
    return path


def test_a_constant_estimator_offset_is_judged_and_diagnosed(tmp_path):
    log = _flight(tmp_path, ekf_offset=lambda t: 0.57 + 0 * t)  # PX4 SIH once stood 0.57 m off for a flight
    assert sitl_fault(log) is None
    d = flight_diagnosis(log, settle=3.0)
    assert d["ticks"] == int(17.0 / DT)
    assert d["reasons"] == {"steered": int(20.0 / DT)}
    assert d["max_offset"] == pytest.approx(20.0)
    assert d["rmse_z_truth_thirds"] == pytest.approx([10.0] * 3)
    assert d["rmse_z_thirds"] == pytest.approx([580.0] * 3)
    assert d["estimator"]["mean"] == pytest.approx(570.0) and d["estimator"]["departure"] == pytest.approx(0.0)
    assert d["simulator_froze"] is False


def test_a_wandering_estimator_is_not_judged(tmp_path):
    ramp = 1.5 * ESTIMATOR_DEPARTURE_M / 10.0  # m/s: 1.5x the bound away from the median within 20 s
    why = sitl_fault(_flight(tmp_path, ekf_offset=lambda t: ramp * t))
    assert why is not None and "EKF height wandered" in why
    # within the bound: judged
    assert sitl_fault(_flight(tmp_path, ekf_offset=lambda t: 0.9 * ramp / 1.5 * t, name="g.npz")) is None


def test_a_frozen_simulator_is_not_judged(tmp_path):
    why = sitl_fault(_flight(tmp_path, freeze=(8.0, 11.0)))
    assert why is not None and "stood still" in why
    # shorter than 2 s: a hover, not a freeze
    assert sitl_fault(_flight(tmp_path, freeze=(8.0, 9.5), name="g.npz")) is None
    assert flight_diagnosis(_flight(tmp_path, freeze=(8.0, 11.0), name="h.npz"))["simulator_froze"] is True
