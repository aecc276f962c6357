"""``ddpc-vehicle`` behaves like PX4 in off-board (a separate process, real time, UDP on 127.0.0.1):
the test itself plays the companion computer with a raw MAVLink link."""

from __future__ import annotations

import time

import numpy as np
import pytest
from support.bridge_helpers import free_port

from firmware_bridge.link import MavLink, mavlink
from firmware_bridge.profiles import PX4Profile, px4_decode
from ddpc_codegen.robot.frames import quat_ned_frd_from_enu_flu

pytestmark = pytest.mark.e2e

ACK = {v.name: k for k, v in mavlink.enums["MAV_RESULT"].items()}


class Companion:
    def __init__(self, port: int) -> None:
        self.link = MavLink(f"udpin:127.0.0.1:{port}", source_system=1, source_component=191)
        self.msgs: list[tuple[float, object]] = []
        self.mode = None

    def pump(self, seconds: float, setpoints: bool = False, until=None) -> None:
        t_end = time.monotonic() + seconds
        k = 0
        while time.monotonic() < t_end:
            self.link.wait(0.005)
            for m, rx in self.link.drain():
                self.msgs.append((rx, m))
                if m.get_type() == "HEARTBEAT":
                    self.mode = PX4Profile().decode(m.base_mode, m.custom_mode)
            if setpoints and self.link.peer is not None:
                q = quat_ned_frd_from_enu_flu((1.0, 0.0, 0.0, 0.0))
                self.link.send(self.link.mav.set_attitude_target_encode(k, 1, 1, 7, list(q), 0, 0, 0, 0.7))
                k += 5
            if until is not None and until():
                return

    def command(self, cmd: int, *params: float, setpoints: bool = False) -> int:
        n0 = len(self.msgs)
        self.link.command_long(cmd, params)

        def acks() -> list:
            return [m for _, m in self.msgs[n0:] if m.get_type() == "COMMAND_ACK" and m.command == cmd]

        self.pump(5.0, setpoints, until=lambda: bool(acks()))
        assert acks(), f"no COMMAND_ACK for {cmd}"
        return acks()[0].result

    def count(self, typ: str, since: float) -> int:
        return sum(1 for rx, m in self.msgs if rx >= since and m.get_type() == typ)


def test_vehicle_speaks_px4_offboard(procs):
    port = free_port()
    veh = procs.spawn("vehicle", f"udpout:127.0.0.1:{port}", "--com-of-loss-t", "0.3", name="vehicle")
    c = Companion(port)
    try:
        c.pump(20.0, until=lambda: c.mode is not None)
        assert c.mode is not None, procs.log(veh)
        hb = [m for _, m in c.msgs if m.get_type() == "HEARTBEAT"][-1]
        assert hb.autopilot == mavlink.MAV_AUTOPILOT_PX4 and c.mode.armed and c.mode.name == "AUTO.LOITER"
        # Streams at the requested rates.
        assert c.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 30.0, 5000.0) == ACK["MAV_RESULT_ACCEPTED"]
        assert c.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 331.0, 20000.0) == ACK["MAV_RESULT_ACCEPTED"]
        assert c.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 24.0, 5000.0) == ACK["MAV_RESULT_UNSUPPORTED"]
        t0 = time.monotonic()
        c.pump(0.5)
        assert 60 <= c.count("ATTITUDE", t0) <= 110 and 15 <= c.count("ODOMETRY", t0) <= 30
        att = [m for _, m in c.msgs if m.get_type() == "ATTITUDE"][-1]
        assert abs(att.yaw - np.pi / 2) < 0.05          # yaw 0 ENU is 90 deg in NED
        # PARAM_REQUEST_READ of the off-board loss timeout.
        c.link.send(c.link.mav.param_request_read_encode(1, 1, b"COM_OF_LOSS_T", -1))
        c.pump(1.0, until=lambda: any(m.get_type() == "PARAM_VALUE" for _, m in c.msgs))
        pv = [m for _, m in c.msgs if m.get_type() == "PARAM_VALUE"]
        assert pv and abs(pv[0].param_value - 0.3) < 1e-6
        # No setpoint stream -> OFFBOARD refused, like PX4.
        assert c.command(mavlink.MAV_CMD_DO_SET_MODE, 1.0, 6.0) == ACK["MAV_RESULT_TEMPORARILY_REJECTED"]
        # Stream setpoints, then switch: accepted, heartbeat says OFFBOARD.
        c.pump(0.5, setpoints=True)
        assert c.command(mavlink.MAV_CMD_DO_SET_MODE, 1.0, 6.0, setpoints=True) == ACK["MAV_RESULT_ACCEPTED"]
        c.pump(0.2, setpoints=True)
        assert c.mode.name == "OFFBOARD" and c.mode.offboard
        # Disarming in flight is refused unless forced.
        assert c.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0.0, setpoints=True) == ACK["MAV_RESULT_DENIED"]
        # Setpoints stop: after COM_OF_LOSS_T the vehicle fails over to HOLD on its own.
        t_stop = time.monotonic()
        c.pump(3.0, until=lambda: c.mode.name != "OFFBOARD")
        assert c.mode.name == "AUTO.LOITER" and c.mode.armed
        assert 0.25 < time.monotonic() - t_stop < 2.5
        main, sub = px4_decode([m for _, m in c.msgs if m.get_type() == "HEARTBEAT"][-1].custom_mode)
        assert (main, sub) == (4, 3)
        # Forced disarm is accepted.
        assert c.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0.0, 21196.0) == ACK["MAV_RESULT_ACCEPTED"]
        c.pump(0.3)
        assert not c.mode.armed
    finally:
        c.link.close()
    assert procs.terminate(veh) == 0


@pytest.mark.parametrize("pattern, lo, hi", [("px4-sih", 100, 135), ("ardupilot", 150, 190)])
def test_vehicle_imitates_real_autopilots_telemetry_stamps(procs, pattern, lo, hi):
    port = free_port()
    veh = procs.spawn("vehicle", f"udpout:127.0.0.1:{port}", "--telemetry-pattern", pattern, name="vehicle")
    c = Companion(port)
    try:
        c.pump(20.0, until=lambda: c.mode is not None)
        assert c.mode is not None, procs.log(veh)
        assert c.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 30.0, 5000.0) == ACK["MAV_RESULT_ACCEPTED"]
        t0 = time.monotonic()
        c.pump(2.0)
        stamps = [m.time_boot_ms for rx, m in c.msgs if rx >= t0 and m.get_type() == "ATTITUDE"]
        span = (stamps[-1] - stamps[0]) * 1e-3
        assert lo < (len(stamps) - 1) / span < hi  # distinct samples per second of vehicle time
        steps = set(np.diff(stamps).tolist())
        if pattern == "px4-sih":
            assert steps <= {4, 8, 12, 16} and all(s % 4 == 0 for s in stamps)
        else:
            assert 10 in steps or 15 in steps  # missing samples
    finally:
        c.link.close()
    assert procs.terminate(veh) == 0


def test_lockstep_vehicle_ends_when_the_companion_is_gone(procs):
    """Issue 12: a lock-step vehicle whose bridge has gone stops by itself (it used to wait forever)."""
    port = free_port()
    veh = procs.spawn("vehicle", f"udpout:127.0.0.1:{port}", "--lockstep", "--lockstep-timeout", "0.2",
                      "--peer-timeout", "1.0", "--summary", str(procs.tmp / "veh.json"), name="vehicle")
    c = Companion(port)
    try:
        c.pump(10.0, until=lambda: c.mode is not None)
        assert c.mode is not None, procs.log(veh)
        c.pump(1.0, setpoints=True)                      # heard by the vehicle: setpoints reach it
    finally:
        c.link.close()                                   # the companion goes away
    assert procs.wait(veh, 20.0) == 0, procs.log(veh)
    assert "it is gone, stopping" in (procs.tmp / "veh.json").read_text()
