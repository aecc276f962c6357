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
from firmware_bridge.sitl import missing_reason, run_isolated
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


def _engaged_thrust(tmp_path: Path) -> float:
    t = load_ticklog(tmp_path / "ticks.npz").ticks
    return float(np.mean(t["sp_field"][t["active"].astype(bool)]))


def test_px4_ulog_of_a_bridge_flight(tmp_path):
    ulg, summary = _fly("px4", tmp_path)
    ds = import_ulog(ulg, preset="px4-offboard-attitude", offboard_only=True)
    assert ds.n_trajectories >= 1 and sum(ds.lengths) > 200 * 5      # the ~6 s + take-off in OFFBOARD
    # PX4 logged the thrust the bridge sent: same mean over the off-board flight (take-off included in both)
    assert np.mean(np.concatenate([u[:, 3] for u in ds.u])) == pytest.approx(_engaged_thrust(tmp_path), abs=0.03)
    with pytest.raises(DataError, match="attitude off-board.*ddpc-bridge --log"):
        import_ulog(ulg, preset="pogox-flying", offboard_only=True)


def test_ardupilot_tlog_of_a_bridge_flight(tmp_path):
    tlog, summary = _fly("ardupilot", tmp_path)
    ds = import_tlog(tlog, preset="ardupilot-guided-attitude", offboard_only=True)
    assert ds.n_trajectories >= 1 and sum(ds.lengths) > 200 * 5
    # GUID_OPTIONS 8: ATTITUDE_TARGET.thrust is the throttle ArduCopter applied = the thrust the bridge sent
    assert np.mean(np.concatenate([u[:, 3] for u in ds.u])) == pytest.approx(_engaged_thrust(tmp_path), abs=0.03)
    with pytest.raises(DataError, match="attitude setpoints .*ATTITUDE_TARGET.*ddpc-bridge --log"):
        import_tlog(tlog, preset="pogox-flying")
