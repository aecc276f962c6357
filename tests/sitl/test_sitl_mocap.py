"""The motion-capture stand-in on the real autopilots (marked ``sitl``, skipped without the binaries): each
SITL starts with the lab parameters, takes the mocap stream as its position, height and yaw source, takes
off to 1 m in its own position control (ArduCopter GUIDED, PX4 OFFBOARD position set-points), hovers, and
its EKF height must stay within 5 mm RMS of the simulator's true height.

:func:`mocap_hover` runs in a private network namespace (:func:`~ddpc_codegen.testbed.sitl.run_isolated`);
with ``setup="outdoor"`` it flies the stock parameters without the stream (GPS and barometer), the figure
the lab setup is compared with.
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from ddpc_codegen.testbed.mocap import MocapConfig, MocapSampler, MocapStandIn
from ddpc_codegen.testbed.mocap_params import lab_params, px4_has_external_vision
from ddpc_codegen.testbed.sitl import SitlError, find_px4, make_sitl, missing_reason, run_isolated
from ddpc_codegen.testbed.sitl_adapt import second_link

pytestmark = pytest.mark.sitl

HOVER_M = 1.0
HOVER_S = 20.0
TARGET_RMS_M = 0.005
_LOCAL_POSITION_NED = 32
_ARDUCOPTER_GUIDED = 4
_PX4_OFFBOARD = 6
_ARMED = 128  # MAV_MODE_FLAG_SAFETY_ARMED


def _interval(conn, msg_id: int, hz: float) -> None:
    conn.mav.command_long_send(conn.target_system, conn.target_component, 511, 0, msg_id, int(1e6 / hz), 0, 0, 0, 0, 0)


class _Recorder:
    """The flight's own link: the EKF's local position and the truth (zero latency, no noise), paired."""

    def __init__(self, conn, autopilot: str):
        self.conn, self.autopilot = conn, autopilot
        self.truth = MocapSampler(MocapConfig(latency_s=0.0, pos_noise_m=0.0, att_noise_rad=0.0, vel_noise_mps=0.0))
        self.z_est: list[tuple[float, float, float]] = []  # (t, EKF down, true down)
        self.armed = False
        self.custom_mode = -1
        self.ground_down = math.nan  # the EKF's down on the ground before take-off [m]
        self.t_up = math.nan  # when the take-off began [s]

    def pump(self, duration: float) -> None:
        t_end = time.monotonic() + duration
        while True:
            msg = self.conn.recv_match(blocking=True, timeout=max(0.0, t_end - time.monotonic()))
            now = time.monotonic()
            if msg is not None:
                self._on(msg, now)
            if now >= t_end:
                return

    def _on(self, msg, now: float) -> None:
        typ = msg.get_type()
        if typ in ("SIM_STATE", "HIL_STATE_QUATERNION"):
            self.truth.feed(msg, now)
        elif typ == "LOCAL_POSITION_NED":
            pose = self.truth.buffer.at(now)
            self.z_est.append((now, msg.z, math.nan if pose is None else float(pose.position[2])))
        elif typ == "HEARTBEAT" and msg.get_srcSystem() == self.conn.target_system and msg.autopilot != 8:
            self.armed, self.custom_mode = bool(msg.base_mode & _ARMED), msg.custom_mode
        elif typ == "STATUSTEXT":
            print(f"[mocap] {self.autopilot}: {msg.text}", flush=True)

    def last_down(self) -> float:
        return self.z_est[-1][1] if self.z_est else math.nan


def _command(conn, cmd: int, *params: float) -> None:
    p = list(params) + [0.0] * (7 - len(params))
    conn.mav.command_long_send(conn.target_system, conn.target_component, cmd, 0, *p)


def _take_off_ardupilot(rec: _Recorder, timeout: float) -> None:
    """GUIDED, arm (retried until the EKF accepts), NAV_TAKEOFF to :data:`HOVER_M`."""
    conn, t_end = rec.conn, time.monotonic() + timeout
    while not rec.armed:
        if time.monotonic() > t_end:
            raise SitlError("ArduCopter did not arm")
        _command(conn, 176, 1, _ARDUCOPTER_GUIDED)  # MAV_CMD_DO_SET_MODE, custom mode
        _command(conn, 400, 1)  # MAV_CMD_COMPONENT_ARM_DISARM
        rec.pump(2.0)
    rec.t_up = time.monotonic()
    _command(conn, 22, 0, 0, 0, 0, 0, 0, HOVER_M)  # MAV_CMD_NAV_TAKEOFF, relative height


def _take_off_px4(rec: _Recorder, ground_down: float, timeout: float) -> None:
    """OFFBOARD position set-points :data:`HOVER_M` above the ground, armed (retried) and kept streaming."""
    conn, t_end = rec.conn, time.monotonic() + timeout
    rec.t_up = time.monotonic()
    while not (rec.armed and rec.custom_mode >> 16 & 0xFF == _PX4_OFFBOARD):
        if time.monotonic() > t_end:
            raise SitlError("PX4 did not arm in OFFBOARD")
        _px4_setpoint(rec, ground_down)
        _command(conn, 176, 1, _PX4_OFFBOARD)  # MAV_CMD_DO_SET_MODE: custom main mode OFFBOARD
        _command(conn, 400, 1)
        for _ in range(10):
            _px4_setpoint(rec, ground_down)
            rec.pump(0.05)


def _px4_setpoint(rec: _Recorder, ground_down: float) -> None:
    rec.conn.mav.set_position_target_local_ned_send(0, rec.conn.target_system, rec.conn.target_component, 1,
                                                    0b110111111000, 0.0, 0.0, ground_down - HOVER_M,
                                                    0, 0, 0, 0, 0, 0, 0, 0)


def _hold(rec: _Recorder, seconds: float) -> None:
    """Stay where the take-off left (PX4: keep streaming its set-point; ArduCopter holds on its own)."""
    t_end = time.monotonic() + seconds
    while time.monotonic() < t_end:
        if rec.autopilot == "px4":
            _px4_setpoint(rec, rec.ground_down)
        rec.pump(0.05)


def _figures(z: np.ndarray, ground: np.ndarray) -> dict:
    """Estimate - truth of the height (NED down) [m]: RMS, mean, std; and RMS after the on-ground offset."""
    e = z[:, 1] - z[:, 2]
    missing = int(np.count_nonzero(~np.isfinite(e)))  # no truth within 50 ms of the estimate
    e = e[np.isfinite(e)]
    off = float(np.nanmean(ground[:, 1] - ground[:, 2])) if len(ground) else 0.0
    return {"samples": int(e.size), "rms": float(np.sqrt(np.mean(e ** 2))), "mean": float(e.mean()),
            "std": float(e.std()), "ground_offset": off, "rms_from_ground": float(np.sqrt(np.mean((e - off) ** 2))),
            "height": float(-np.nanmean(z[:, 2])), "missing_truth": missing}


def mocap_hover(autopilot: str, setup: str = "lab", hover_s: float = HOVER_S, seed: int = 1,
                message: str = "vision_position") -> dict:
    """Start the SITL (``setup`` "lab": the lab parameters and the mocap stand-in sending ``message`` on its
    second link; "outdoor": stock, no stream), take off to :data:`HOVER_M`, hover ``hover_s`` s; the height
    figures (:func:`_figures`, [m]) and the stand-in's counts."""
    cfg = MocapConfig(seed=seed, message=message)
    lab = setup == "lab"
    sitl = make_sitl(autopilot, params=lab_params(autopilot, cfg) if lab else None)
    mocap = link = None
    with sitl:
        conn = sitl.connect(timeout=60)
        try:
            if lab:
                link = second_link(sitl).connect(timeout=30)
                mocap = MocapStandIn(link, autopilot, cfg)
                mocap.start()
            rec = _Recorder(conn, autopilot)
            _interval(conn, _LOCAL_POSITION_NED, 50)
            _interval(conn, 108 if autopilot == "ardupilot" else 115, 200)
            rec.pump(3.0)
            if autopilot == "ardupilot":
                _take_off_ardupilot(rec, timeout=100.0)
            else:
                t_end = time.monotonic() + 30.0
                while not math.isfinite(rec.last_down()) and time.monotonic() < t_end:
                    rec.pump(0.5)  # PX4 sends its local position once its EKF has one (on the mocap: once fused)
                rec.ground_down = rec.last_down()
                _take_off_px4(rec, rec.ground_down, timeout=60.0)
            # on the ground before the take-off: the EKF's offset to the truth there
            ground = np.array([s for s in rec.z_est if rec.t_up - 1.5 < s[0] < rec.t_up]).reshape(-1, 3)
            _hold(rec, 8.0)  # the climb and its settling
            n0 = len(rec.z_est)
            _hold(rec, hover_s)
            z = np.array(rec.z_est[n0:]).reshape(-1, 3)
            if mocap is not None:  # the truth in the mocap's frame (each link took its own first sample as origin)
                shift = mocap.sampler.truth.alt0 - rec.truth.truth.alt0
                z[:, 2] += shift
                ground[:, 2] += shift
        finally:
            if mocap is not None:
                mocap.stop()
            for c in (link, conn):
                if c is not None:
                    c.close()
    out = _figures(z, ground)
    if mocap is not None:
        out.update({"mocap_sent": mocap.stats.sent, "mocap_truth": mocap.stats.truth,
                    "mocap_skipped": mocap.stats.skipped, "mocap_errors": mocap.stats.errors})
    return out


@pytest.mark.parametrize("autopilot", ["ardupilot", "px4"])
def test_mocap_hover_holds_the_height_within_5mm_of_the_truth(autopilot):
    why = missing_reason(autopilot)
    if why:
        pytest.skip(why)
    if autopilot == "px4" and not px4_has_external_vision(find_px4()):
        pytest.skip(f"this PX4 build ({find_px4()}) has no EKF2 external vision (CONFIG_EKF2_EXTERNAL_VISION=n): "
                    "rebuild it with that option on (PX4's default) to fly it on the mocap")
    res = run_isolated("sitl.test_sitl_mocap:mocap_hover", {"autopilot": autopilot}, timeout=170)
    print(f"[mocap] {autopilot} lab: {res}")
    assert not res.get("mocap_errors"), res
    assert res["height"] > 0.7, res  # it flew
    assert res["rms"] <= TARGET_RMS_M, res
