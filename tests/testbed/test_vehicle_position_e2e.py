"""A plain pymavlink app flies ``ddpc-vehicle`` (PX4 emulation, a separate real-time process, UDP on
127.0.0.1) with position setpoints: it arms it, is refused OFFBOARD until it streams, flies a climb and
a sideways step, stops, and the off-board-loss failsafe takes the vehicle back to HOLD."""

from __future__ import annotations

import importlib.util
import sys
import time

import numpy as np
import pytest

from firmware_bridge.profiles import PX4_MAIN, px4_custom_mode
from support.bridge_helpers import ROOT, Procs, free_port, read_json

pytestmark = [pytest.mark.e2e]


def _mav_app():
    """The proxy tests' pymavlink app helpers (connect, command, read_param, drain), one copy."""
    if "mav_app" not in sys.modules:
        spec = importlib.util.spec_from_file_location(
            "mav_app", ROOT / "tests" / "firmware_bridge" / "proxy_tests" / "mav_app.py")
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        sys.modules["mav_app"] = mod
    return sys.modules["mav_app"]


app_lib = _mav_app()
M = app_lib.M
OFFBOARD, MAIN_MODE = px4_custom_mode(PX4_MAIN["OFFBOARD"]), 0xFF << 16
POSITION_ONLY = 0b0000_1101_1111_1000  # velocity, acceleration, yaw rate ignored; yaw kept


def _fly_to(app, target_ned, seconds: float, log: list) -> None:
    """Stream the position setpoint at 20 Hz for ``seconds``, keeping the LOCAL_POSITION_NED received."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        app.mav.set_position_target_local_ned_send(0, app.target_system, app.target_component, M.MAV_FRAME_LOCAL_NED,
                                                   POSITION_ONLY, *target_ned, 0, 0, 0, 0, 0, 0, 0.0, 0)
        for _, m in app_lib.drain(app, 0.05, {"LOCAL_POSITION_NED", "HEARTBEAT"}):
            if m.get_type() == "LOCAL_POSITION_NED":
                log.append((m.x, m.y, m.z))


def test_a_pymavlink_app_flies_position_setpoints_in_offboard(tmp_path):
    port = free_port()
    procs = Procs(tmp_path)
    try:
        veh = procs.spawn("vehicle", f"udpout:127.0.0.1:{port}", "--start", "disarmed", "--com-of-loss-t", "0.5",
                          "--summary", str(tmp_path / "vehicle.json"), name="vehicle")
        app = app_lib.connect(f"udpin:127.0.0.1:{port}", 245)
        try:
            assert app_lib.read_param(app, "COM_OF_LOSS_T") == pytest.approx(0.5)
            assert app_lib.command(app, M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_LOCAL_POSITION_NED,
                                   20000) == M.MAV_RESULT_ACCEPTED
            assert app_lib.command(app, M.MAV_CMD_COMPONENT_ARM_DISARM, 1) == M.MAV_RESULT_ACCEPTED
            set_offboard = (M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, PX4_MAIN["OFFBOARD"], 0)
            assert app_lib.command(app, *set_offboard) == M.MAV_RESULT_TEMPORARILY_REJECTED  # no setpoints yet
            m = app.recv_match(type="LOCAL_POSITION_NED", blocking=True, timeout=5)
            start = np.array([m.x, m.y, m.z])
            log: list = []
            _fly_to(app, start, 0.5, log)                                # the stream first, as PX4 wants
            assert app_lib.command(app, *set_offboard) == M.MAV_RESULT_ACCEPTED
            for step in ([0.0, 0.0, -0.5], [0.5, 0.0, -0.5]):            # up 0.5 m, then 0.5 m north
                log.clear()
                _fly_to(app, start + step, 4.0, log)
                assert len(log) > 120                                   # ~50 Hz, as asked
                assert np.allclose(log[-1], start + step, atol=0.1), (log[-1], start + step)
            hb = [(t, m.custom_mode & MAIN_MODE) for t, m in app_lib.drain(app, 1.5, {"HEARTBEAT"})]
            assert hb and hb[-1][1] != OFFBOARD                         # the app stopped: failsafe
        finally:
            app.close()
            assert procs.terminate(veh) == 0, procs.log(veh)
    finally:
        procs.cleanup()
    s = read_json(tmp_path / "vehicle.json")
    assert s["position_setpoints"] > 120 and s["setpoints_ignored"] == 0 and s["armed"]
    assert [e for _, e in s["events"] if e.startswith("mode")][-2:] == [
        "mode OFFBOARD (command)", "mode AUTO.LOITER (offboard setpoints lost for > 0.5 s)"]
