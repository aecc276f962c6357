"""The motion-capture stand-in on the real autopilots (marked ``sitl``, skipped without the binaries): each
SITL starts with the lab parameters, takes the mocap stream as its position, height and yaw source, takes
off to 1 m in its own position control (ArduCopter GUIDED, PX4 OFFBOARD position set-points), hovers, then moves
up and down by :data:`MOVE_M` (about 1 m/s at its fastest); its EKF height must stay within 5 mm RMS of the
simulator's true height in both, and not run ahead or behind it (the lag that maximises their agreement, which was
36-40 ms on ArduCopter while its SERIAL1 declared 57600 baud: :data:`~.mocap_params.ARDUPILOT_SITL_LINK`).
Truth and estimate are recorded by the :class:`~ddpc_codegen.testbed.sitl_observer.Observer` that judges the demos'
flights (the true height refined below its grid, both on the autopilot's clock).

:func:`mocap_hover` runs in a private network namespace (:func:`~ddpc_codegen.testbed.sitl.run_isolated`);
with ``setup="outdoor"`` it flies the stock parameters without the stream (GPS and barometer), the figure
the lab setup is compared with.
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from ddpc_codegen.testbed.mocap import MocapConfig, MocapStandIn
from ddpc_codegen.testbed.mocap_params import lab_params, px4_has_external_vision
from ddpc_codegen.testbed.sitl import SitlError, find_px4, make_sitl, missing_reason, run_isolated
from ddpc_codegen.testbed.sitl_adapt import second_link
from ddpc_codegen.testbed.sitl_observer import Observer

pytestmark = pytest.mark.sitl

HOVER_M = 1.0
HOVER_S = 20.0
MOVE_M = 1.0  # up and back along a cosine, twice: 0.52 m/s at its fastest (the proxy demo's helix climbs at 0.3)
MOVE_PERIOD_S = 6.0
TARGET_RMS_M = 0.005
MAX_LAG_S = 0.010
_LOCAL_POSITION_NED = 32
_ARDUCOPTER_GUIDED = 4
_PX4_OFFBOARD = 6
_ARMED = 128  # MAV_MODE_FLAG_SAFETY_ARMED


def _interval(conn, msg_id: int, hz: float) -> None:
    conn.mav.command_long_send(conn.target_system, conn.target_component, 511, 0, msg_id, int(1e6 / hz), 0, 0, 0, 0, 0)


class _Recorder:
    """The flight's own link: the vehicle's state, and truth and estimate into an :class:`Observer` (both asked at
    50 Hz: sent in the same loop, the truth takes the estimate's time_boot_ms)."""

    def __init__(self, conn, autopilot: str):
        self.conn, self.autopilot = conn, autopilot
        self.obs = Observer("", autopilot=autopilot, connect=False)
        self.armed = False
        self.custom_mode = -1
        self.ground_down = math.nan  # the EKF's down on the ground before take-off [m]
        self.ground = 0.0  # the frames' offset there: true height - estimate [m]
        self.t_up = math.nan  # when the take-off began [s, time.time()]

    def pump(self, duration: float) -> None:
        t_end = time.monotonic() + duration
        while True:
            msg = self.conn.recv_match(blocking=True, timeout=max(0.0, t_end - time.monotonic()))
            if msg is not None:
                self._on(msg, time.time())
            if time.monotonic() >= t_end:
                return

    def _on(self, msg, now: float) -> None:
        typ = msg.get_type()
        if typ in ("SIM_STATE", "HIL_STATE_QUATERNION", "LOCAL_POSITION_NED"):
            self.obs.record(msg, now)
        elif typ == "HEARTBEAT" and msg.get_srcSystem() == self.conn.target_system and msg.autopilot != 8:
            self.armed, self.custom_mode = bool(msg.base_mode & _ARMED), msg.custom_mode
        elif typ == "STATUSTEXT":
            print(f"[mocap] {self.autopilot}: {msg.text}", flush=True)

    def last_down(self) -> float:
        return -self.obs.lpos[-1][1] if self.obs.lpos else math.nan


def _command(conn, cmd: int, *params: float) -> None:
    p = list(params) + [0.0] * (7 - len(params))
    conn.mav.command_long_send(conn.target_system, conn.target_component, cmd, 0, *p)


def _take_off_ardupilot(rec: _Recorder, timeout: float) -> None:
    """GUIDED, arm (retried until the EKF accepts), the frames' offset on the ground, NAV_TAKEOFF to :data:`HOVER_M`."""
    conn, t_end = rec.conn, time.monotonic() + timeout
    while not rec.armed:
        if time.monotonic() > t_end:
            raise SitlError("ArduCopter did not arm")
        _command(conn, 176, 1, _ARDUCOPTER_GUIDED)  # MAV_CMD_DO_SET_MODE, custom mode
        _command(conn, 400, 1)  # MAV_CMD_COMPONENT_ARM_DISARM
        rec.pump(2.0)
    rec.ground_down, rec.ground = rec.last_down(), rec.obs.ground(1.5)
    rec.t_up = time.time()
    _command(conn, 22, 0, 0, 0, 0, 0, 0, HOVER_M)  # MAV_CMD_NAV_TAKEOFF, relative height


def _take_off_px4(rec: _Recorder, timeout: float) -> None:
    """The frames' offset on the ground, then OFFBOARD position set-points :data:`HOVER_M` above it, armed
    (retried) and kept streaming."""
    conn, t_end = rec.conn, time.monotonic() + timeout
    rec.ground_down, rec.ground = rec.last_down(), rec.obs.ground(1.5)
    rec.t_up = time.time()
    while not (rec.armed and rec.custom_mode >> 16 & 0xFF == _PX4_OFFBOARD):
        if time.monotonic() > t_end:
            raise SitlError("PX4 did not arm in OFFBOARD")
        _setpoint(rec, 0.0)
        _command(conn, 176, 1, _PX4_OFFBOARD)  # MAV_CMD_DO_SET_MODE: custom main mode OFFBOARD
        _command(conn, 400, 1)
        for _ in range(10):
            _setpoint(rec, 0.0)
            rec.pump(0.05)


def _setpoint(rec: _Recorder, up: float, climb: float | None = None) -> None:
    """A position set-point :data:`HOVER_M` + ``up`` [m] above the ground where the take-off began (and a climb rate
    [m/s] to follow, where given)."""
    mask = 0b110111111000 if climb is None else 0b110111000000  # position (and velocity) only
    rec.conn.mav.set_position_target_local_ned_send(0, rec.conn.target_system, rec.conn.target_component, 1,
                                                    mask, 0.0, 0.0, rec.ground_down - HOVER_M - up,
                                                    0, 0, -(climb or 0.0), 0, 0, 0, 0, 0)


def _hold(rec: _Recorder, seconds: float, up: float | None = None) -> None:
    """Stream set-points ``up`` [m] above the hover for ``seconds`` (None: stay where the take-off left; PX4 keeps
    streaming its set-point, ArduCopter holds on its own)."""
    t_end = time.monotonic() + seconds
    while time.monotonic() < t_end:
        if up is not None or rec.autopilot == "px4":
            _setpoint(rec, up or 0.0)
        rec.pump(0.05)


def _figures(obs: Observer, ground: float, t0: float, t1: float) -> dict:
    """Estimate - truth of the height between ``t0`` and ``t1`` [s, time.time()], the truth counted from the ground
    the estimate started on (``ground``: the frames' offset there [m]): RMS, mean, std [m], the estimate's lag
    behind the truth [ms] (:meth:`Observer.estimate_lag`: where the motion shows it) and the mean height [m]."""
    truth, est = obs.series()
    k = (est[:, 0] >= t0) & (est[:, 0] <= t1)
    e = est[k, 1] - (np.interp(est[k, 0], truth[:, 0], truth[:, 1], left=np.nan, right=np.nan) - ground)
    missing = int(np.count_nonzero(~np.isfinite(e)))
    e = e[np.isfinite(e)]
    lag, spread = obs.estimate_lag(t0, t1)
    return {"samples": int(e.size), "rms": float(np.sqrt(np.mean(e ** 2))), "mean": float(e.mean()),
            "std": float(e.std()), "lag_ms": lag * 1e3, "spread_at_lag": spread, "height": float(est[k, 1].mean()),
            "missing_truth": missing}


def _move(rec: _Recorder) -> tuple[float, float]:
    """Up by :data:`MOVE_M` and back along a cosine of :data:`MOVE_PERIOD_S`, twice (set-points at 20 Hz with their
    climb rate), then a second's hold; its start and end [s, time.time()]."""
    t0, w = time.time(), 2.0 * math.pi / MOVE_PERIOD_S
    while (s := time.time() - t0) < 2.0 * MOVE_PERIOD_S:
        _setpoint(rec, 0.5 * MOVE_M * (1.0 - math.cos(w * s)), 0.5 * MOVE_M * w * math.sin(w * s))
        rec.pump(0.05)
    _hold(rec, 1.0, 0.0)
    return t0, time.time()


def mocap_hover(autopilot: str, setup: str = "lab", hover_s: float = HOVER_S, seed: int = 1,
                message: str = "vision_position") -> dict:
    """Start the SITL (``setup`` "lab": the lab parameters and the mocap stand-in sending ``message`` on its
    second link; "outdoor": stock, no stream), take off to :data:`HOVER_M`, hover ``hover_s`` s, then move
    (:func:`_move`); the height figures of each (:func:`_figures`) and the stand-in's counts."""
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
            _interval(conn, _LOCAL_POSITION_NED, 50)  # both at one rate: sent in the same loop, paired
            _interval(conn, 108 if autopilot == "ardupilot" else 115, 50)
            rec.pump(3.0)
            if autopilot == "ardupilot":
                _take_off_ardupilot(rec, timeout=100.0)
            else:
                t_end = time.monotonic() + 30.0
                while not math.isfinite(rec.last_down()) and time.monotonic() < t_end:
                    rec.pump(0.5)  # PX4 sends its local position once its EKF has one (on the mocap: once fused)
                _take_off_px4(rec, timeout=60.0)
            _hold(rec, 8.0)  # the climb and its settling
            t0 = time.time()
            _hold(rec, hover_s)
            hover = _figures(rec.obs, rec.ground, t0, time.time())
            moving = _figures(rec.obs, rec.ground, *_move(rec))
        finally:
            if mocap is not None:
                mocap.stop()
            for c in (link, conn):
                if c is not None:
                    c.close()
    out = {**hover, "ground_offset": rec.ground, "moving": moving}
    if mocap is not None:
        out.update({"mocap_sent": mocap.stats.sent, "mocap_truth": mocap.stats.truth,
                    "mocap_skipped": mocap.stats.skipped, "mocap_errors": mocap.stats.errors,
                    "mocap_clock_paired": getattr(mocap.clock, "paired", None),
                    "mocap_clock_unpaired": getattr(mocap.clock, "unpaired", None)})
    return out


@pytest.mark.parametrize("autopilot", ["ardupilot", "px4"])
def test_mocap_hover_holds_the_height_within_5mm_of_the_truth(autopilot):
    why = missing_reason(autopilot)
    if why:
        pytest.skip(why)
    if autopilot == "px4" and not px4_has_external_vision(find_px4()):
        pytest.skip(f"this PX4 build ({find_px4()}) has no EKF2 external vision (CONFIG_EKF2_EXTERNAL_VISION=n): "
                    "rebuild it with that option on (PX4's default) to fly it on the mocap")
    res = run_isolated("sitl.test_sitl_mocap:mocap_hover", {"autopilot": autopilot}, timeout=200)
    print(f"[mocap] {autopilot} lab: {res}")
    assert not res.get("mocap_errors"), res
    assert res["height"] > 0.7, res  # it flew
    assert res["rms"] <= TARGET_RMS_M, res
    moving = res["moving"]
    assert moving["height"] > 1.2, res  # it moved
    assert moving["rms"] <= TARGET_RMS_M, res
    assert abs(moving["lag_ms"]) <= MAX_LAG_S * 1e3, res  # neither ahead of the truth nor behind it
