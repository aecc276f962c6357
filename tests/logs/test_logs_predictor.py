"""An imported flight log feeds the data-driven pipeline: PE check and fit_predictor."""

from __future__ import annotations

import numpy as np
import pytest
from ulog_writer import write_ulog

from ddpc_codegen import prbs
from ddpc_codegen.logs import import_ulog
from ddpc_codegen.robot.frames import quat_from_euler_array

hankel = pytest.importorskip("ddpc_codegen.design.hankel")
predictor = pytest.importorskip("ddpc_codegen.design.predictor")

pytestmark = pytest.mark.filterwarnings("ignore::ddpc_codegen.logs.LogImportWarning")

T0, DT_US, N = 2_000_000, 5_000, 1600  # 8 s logged at the 200 Hz controller rate


def _closed_loop(seed: int = 4):
    """Setpoints (PRBS) and the response of a stable 4-state LTI closed loop, sample by sample."""
    rng = np.random.default_rng(seed)
    Q, _ = np.linalg.qr(rng.standard_normal((4, 4)))
    A = Q @ np.diag([0.95, 0.9, 0.8, 0.6]) @ Q.T
    B = 0.3 * rng.standard_normal((4, 2))
    C = rng.standard_normal((2, 4))
    u = np.column_stack([1.0, 0.0]) + prbs(N, 2, amplitude=[0.25, 0.1], min_hold=3, seed=seed)
    x = np.linalg.solve(np.eye(4) - A, B @ np.array([1.0, 0.0]))  # at rest at z_ref = 1
    y = np.empty((N, 2))
    for k in range(N):
        y[k] = C @ x
        x = A @ x + B @ u[k]
    return u, 0.1 * y


def test_imported_log_is_exciting_and_fits_an_exact_predictor(tmp_path):
    u, y = _closed_loop()
    t = T0 + DT_US * np.arange(N)
    pos = np.zeros((N, 3))
    pos[:, 2] = -u[:, 0]
    topics = {
        "trajectory_setpoint": {"timestamp": t, "position": pos},
        "vehicle_attitude_setpoint": {"timestamp": t, "q_d": quat_from_euler_array(0.0, u[:, 1], 0.0)},
        "vehicle_local_position": {"timestamp": t, "z": -y[:, 0]},
        "vehicle_attitude": {"timestamp": t, "q": quat_from_euler_array(0.0, y[:, 1], 0.0)},
    }
    ds = import_ulog(write_ulog(tmp_path / "excited.ulg", topics), preset="pogox-flying")
    assert ds.lengths == (N,)
    np.testing.assert_allclose(ds.u[0], u, atol=1e-6)  # float32 in the log
    np.testing.assert_allclose(ds.y[0], y, atol=1e-6)

    t_ini, t_f, n = 6, 10, 4
    pe = hankel.persistency_of_excitation(ds.u, t_ini + t_f + n)
    assert pe.ok and pe.rank == pe.required_rank == 2 * (t_ini + t_f + n)

    pred = predictor.fit_predictor(ds, t_ini, t_f, method="lsq")
    assert (pred.m, pred.p) == (2, 2) and pred.input_names == ("z_ref", "pitch_ref")
    k = 900  # a window of the log: predict the next t_f outputs from the past t_ini
    y_hat, sigma = pred.predict(ds.u[0][k - t_ini:k], ds.y[0][k - t_ini:k], ds.u[0][k:k + t_f])
    scale = np.abs(ds.y[0]).max()
    assert np.abs(y_hat - ds.y[0][k:k + t_f]).max() < 1e-5 * scale  # exact but for float32 logging
    assert np.abs(sigma).max() == 0.0
    pem = predictor.fit_predictor(ds, t_ini, t_f, method="pem")
    y_pem, _ = pem.predict(ds.u[0][k - t_ini:k], ds.y[0][k - t_ini:k], ds.u[0][k:k + t_f])
    assert np.abs(y_pem - ds.y[0][k:k + t_f]).max() < 0.05 * scale
