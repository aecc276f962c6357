"""The simulated vehicle's autopilot with position setpoints, in-process over a scripted link: OFFBOARD
refused without them and kept while they arrive, the off-board-loss failsafe when they stop, frames and
force setpoints refused and logged, ArduPilot's GUIDED, the hover-thrust parameter, lock-step stamps."""

from __future__ import annotations

import logging
import math

import numpy as np
import pytest

from ddpc_codegen.robot.frames import euler_from_quat
from ddpc_codegen.testbed.vehicle import MODE_HOLD, MODE_OFFBOARD, SimVehicle, VehicleConfig
from firmware_bridge.link import mavlink
from firmware_bridge.profiles import ARDUCOPTER_MODES, PX4_MAIN

M = mavlink
_SENDER = M.MAVLink(None, 245, 190)


class _Link:
    """What the vehicle's MAVLink endpoint does, scripted: ``inbox`` is drained, sends are kept."""

    def __init__(self) -> None:
        self.mav = M.MAVLink(None, 1, 1)
        self.inbox: list = []
        self.sent: list = []
        self.stats = {"rx": 0}

    def put(self, msg) -> None:
        self.inbox.append(self.mav.decode(bytearray(msg.pack(_SENDER))))  # with its sender's header

    def drain(self):
        out, self.inbox = [(m, 0.0) for m in self.inbox], []
        return out

    def send(self, msg) -> bool:
        self.sent.append(msg)
        return True

    def send_many(self, msgs) -> bool:
        self.sent.extend(msgs)
        return True

    def send_heartbeat(self, *fields) -> None:
        pass

    def close(self) -> None:
        pass

    def acks(self, command: int) -> list[int]:
        return [m.result for m in self.sent if m.get_type() == "COMMAND_ACK" and m.command == command]


def _vehicle(**kw) -> tuple[SimVehicle, _Link]:
    link = _Link()
    return SimVehicle(VehicleConfig(noise=False, **kw), link=link), link


def _setpoint(ms: int, ned=(0.0, 0.0, 0.0), type_mask: int = 0b0000_1111_1111_1000, frame=M.MAV_FRAME_LOCAL_NED,
              yaw: float = 0.0):
    """Position only by default (velocity, acceleration, yaw, yaw rate ignored)."""
    return M.MAVLink_set_position_target_local_ned_message(ms, 1, 1, frame, type_mask, *ned, 0, 0, 0, 0, 0, 0, yaw, 0)


def _mode_cmd(link: _Link, *params: float) -> None:
    link.put(M.MAVLink_command_long_message(1, 1, M.MAV_CMD_DO_SET_MODE, 0, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                                            *params, *[0.0] * (6 - len(params))))


def _tick(veh: SimVehicle, n: int = 1) -> None:
    for _ in range(n):
        veh.autopilot.process()
        veh._tick_start(0.0)
        veh._advance()
        veh.k += 1


def _start_ned(veh: SimVehicle) -> np.ndarray:
    x, y, z = veh.plant.state[0:3]
    return np.array([y, x, -z])


def test_px4_offboard_needs_position_setpoints_flies_them_and_fails_safe_when_they_stop():
    veh, link = _vehicle(com_of_loss_t=0.5)
    ap, p0 = veh.autopilot, _start_ned(veh)
    _mode_cmd(link, PX4_MAIN["OFFBOARD"], 0)
    _tick(veh)
    assert link.acks(M.MAV_CMD_DO_SET_MODE) == [M.MAV_RESULT_TEMPORARILY_REJECTED] and ap.mode == MODE_HOLD
    target = p0 + [0.3, -0.2, -0.4]  # north, west, up
    for k in range(800):  # 4 s of setpoints at 200 Hz; OFFBOARD asked after 0.1 s
        link.put(_setpoint(5 * k, tuple(target), yaw=math.pi / 2))
        if k == 20:
            _mode_cmd(link, PX4_MAIN["OFFBOARD"], 0)
        _tick(veh)
    assert link.acks(M.MAV_CMD_DO_SET_MODE)[-1] == M.MAV_RESULT_ACCEPTED and ap.mode == MODE_OFFBOARD
    s = veh.plant.state
    assert np.allclose([s[1], s[0], -s[2]], target, atol=0.06)  # ENU back to NED
    assert euler_from_quat(s[6:10])[2] == pytest.approx(0.0, abs=0.02)  # yaw north (NED pi/2) = ENU 0
    assert ap.stats["position_setpoints"] == 800 and ap.stats["setpoints_ignored"] == 0
    _tick(veh, 90)  # silent for 0.45 s: still OFFBOARD
    assert ap.mode == MODE_OFFBOARD
    _tick(veh, 20)
    assert ap.mode == MODE_HOLD and "offboard setpoints lost" in ap.events[-1][1]


def test_velocity_only_setpoints_and_a_foreign_frame_which_is_refused_and_logged(caplog):
    veh, link = _vehicle()
    ap = veh.autopilot
    vel_only = 0b0000_1101_1100_0111  # velocity only (position, acceleration, yaw, yaw rate ignored)
    msg = M.MAVLink_set_position_target_local_ned_message(0, 1, 1, M.MAV_FRAME_LOCAL_NED, vel_only,
                                                          0, 0, 0, 0.5, 0, 0, 0, 0, 0, 0, 0)
    link.put(msg)
    _mode_cmd(link, PX4_MAIN["OFFBOARD"], 0)
    x0 = veh.plant.state[1]
    for k in range(1000):
        link.put(msg)
        _tick(veh)
    assert veh.plant.state[4] == pytest.approx(0.5, abs=0.04)  # north at 0.5 m/s (ENU y), the PI settling
    assert veh.plant.state[1] - x0 > 2.0
    with caplog.at_level(logging.WARNING, logger="ddpc_codegen.testbed.vehicle"):
        for _ in range(5):
            link.put(_setpoint(0, frame=M.MAV_FRAME_BODY_NED))
        _tick(veh)
    assert ap.stats["setpoints_ignored"] == 5
    # logged once per power of two, not per message
    assert sum("coordinate frame 8 unsupported" in r.message for r in caplog.records) == 3


def test_ardupilot_guided_takes_position_setpoints_and_reports_its_hover_thrust():
    veh, link = _vehicle(autopilot="ardupilot", hover_thrust=0.75)
    ap, p0 = veh.autopilot, _start_ned(veh)
    link.put(M.MAVLink_param_request_read_message(1, 1, b"MOT_THST_HOVER", -1))
    for k in range(1600):
        link.put(_setpoint(5 * k, tuple(p0 + [0.0, 0.5, 0.0])))
        if k == 1:
            _mode_cmd(link, ARDUCOPTER_MODES["GUIDED"])
        _tick(veh)
    assert ap.mode == MODE_OFFBOARD and ap.mode_name() == "GUIDED"
    assert veh.plant.state[0] - (p0[1]) == pytest.approx(0.5, abs=0.05)  # east
    hover = [m.param_value for m in link.sent if m.get_type() == "PARAM_VALUE"]
    assert hover == [pytest.approx(0.75)]


def test_lockstep_waits_for_the_position_setpoint_stamped_with_the_sample():
    veh, link = _vehicle(lockstep=True)
    ap = veh.autopilot
    ap.expect_stamp_ms = 40
    link.put(_setpoint(35))
    assert not ap.process()
    link.put(_setpoint(40))
    assert ap.process() and ap.sp_kind == "position"
