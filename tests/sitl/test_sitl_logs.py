"""The autopilots' own logs of a real SITL flight flown by ddpc-bridge (attitude off-board) go
through the importers with the presets made for them, and the presets that need the companion's
references refuse with the advice to use the bridge's tick log (skipped without the SITLs)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from ddpc_codegen.errors import DataError
from ddpc_codegen.logs import import_tlog, import_ulog
from ddpc_codegen.testbed.sitl import missing_reason, run_isolated
from firmware_bridge.ticklog import load_ticklog

pytestmark = [pytest.mark.sitl, pytest.mark.slow, pytest.mark.realtime,
              pytest.mark.filterwarnings("ignore::ddpc_codegen.logs.LogImportWarning")]


def _fly(autopilot: str, tmp_path: Path) -> tuple[Path, dict]:
    why = missing_reason(autopilot)
    if why:
        pytest.skip(why)
    res = run_isolated("isolated_funcs:flight_with_autopilot_log", {"autopilot": autopilot, "out_dir": str(tmp_path)},
                       timeout=400)
    assert res["rc"] == 0 and res["logs"], res
    return Path(res["logs"][0]), json.loads((tmp_path / "summary.json").read_text())


def _airborne_thrust(tmp_path: Path, ds) -> tuple[float, float]:
    """Median thrust while > 0.5 m above the take-off point: as the autopilot logged it (dataset: input 3,
    output 0 = height) and as the bridge sent it (its tick log). On the ground both differ for good
    reasons (ArduCopter reports zero throttle for ~3 s after arming while it spools up)."""
    u, y = np.concatenate(ds.u), np.concatenate(ds.y)
    logged = u[y[:, 0] > y[0, 0] + 0.5, 3]
    t = load_ticklog(tmp_path / "ticks.npz").ticks
    on = t["active"].astype(bool) & (t["y"][:, 0] > 0.5)
    return float(np.median(logged)), float(np.median(t["sp_field"][on]))


def test_px4_ulog_of_a_bridge_flight(tmp_path):
    ulg, summary = _fly("px4", tmp_path)
    ds = import_ulog(ulg, preset="px4-offboard-attitude", offboard_only=True)
    assert ds.n_trajectories >= 1 and sum(ds.lengths) > 200 * 5      # the ~6 s + take-off in OFFBOARD
    logged, sent = _airborne_thrust(tmp_path, ds)   # PX4 logged the thrust the bridge sent
    assert logged == pytest.approx(sent, abs=0.01)
    with pytest.raises(DataError, match="attitude off-board.*ddpc-bridge --log"):
        import_ulog(ulg, preset="pogox-flying", offboard_only=True)
    assert summary["truth_samples"] > 0 and summary["rmse_z_truth"] is not None  # SIH's HIL_STATE_QUATERNION


def test_ardupilot_tlog_of_a_bridge_flight(tmp_path):
    tlog, summary = _fly("ardupilot", tmp_path)
    ds = import_tlog(tlog, preset="ardupilot-guided-attitude", offboard_only=True)
    assert ds.n_trajectories >= 1 and sum(ds.lengths) > 200 * 5
    # GUID_OPTIONS 8: ATTITUDE_TARGET.thrust is the throttle ArduCopter applied = the thrust the bridge sent
    logged, sent = _airborne_thrust(tmp_path, ds)
    assert logged == pytest.approx(sent, abs=0.01)
    with pytest.raises(DataError, match="attitude setpoints .*ATTITUDE_TARGET.*ddpc-bridge --log"):
        import_tlog(tlog, preset="pogox-flying")
    # The bridge kept ArduCopter's SIM_STATE as truth: the true height (from where it stood disarmed)
    # agrees with the EKF's (from the same point) to centimetres in flight; the RMSEs are close.
    t = load_ticklog(tmp_path / "ticks.npz").ticks
    on = t["active"].astype(bool)
    assert summary["truth_samples"] > 0 and np.isfinite(t["truth_position"][on]).all()
    assert np.max(np.abs(t["truth_position"][on, 2] - t["y"][on, 0])) < 0.05
    assert summary["rmse_z_truth"] == pytest.approx(summary["rmse_z_measured"], abs=0.01)
