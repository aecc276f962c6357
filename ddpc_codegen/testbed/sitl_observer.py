"""A watcher on a SITL's spare MAVLink port, independent of whatever flies the vehicle: the simulator's ground
truth (ArduCopter's ``SIM_STATE`` on its TCP 5762 / 5763, PX4 SIH's ``HIL_STATE_QUATERNION`` on the link it
keeps for the simulator, :data:`SPARE_PORT`), the autopilot's own estimate (``LOCAL_POSITION_NED``), its
heartbeats and status texts, each stamped on arrival (``time.time()``). A flight is then judged on the true
height, not on what the flying side believed.

The true height is refined below the grid the message reports it on (ArduCopter: whole centimetres, truncated;
PX4: millimetres) with its vertical velocity, by the :class:`~firmware_bridge.truth_refine.Dequantizer` that the
motion-capture stand-in and the bridge's tick log (:class:`~firmware_bridge.truth.SimTruth`) use: on the raw
centimetres a moving flight's estimate - truth carries the grid's ~2.9 mm RMS, and a hover up to 5 mm of offset,
that neither estimate nor steering has. On the ground both refine to the same cell's middle, so the frames' offset
measured there (:meth:`Observer.ground`) is the mocap's origin in flight. On ArduCopter truth and estimate are
placed on the autopilot's clock (:class:`~firmware_bridge.truth_refine.LinkClock`, by the LOCAL_POSITION_NED sent
from the same loop: its bursts lag that clock by 0-23 ms); PX4's keep their arrival.
:meth:`Observer.estimate_lag` measures what lag is left between them.
"""

from __future__ import annotations

import socket
import threading
import time
from pathlib import Path

import numpy as np

from firmware_bridge.truth_refine import TRUTH_GRID, Dequantizer, LinkClock

__all__ = ["Observer", "HOME_ALT", "SPARE_PORT", "wait_tcp_port", "wait_udp_bound", "estimate_lag"]

HOME_ALT = 584.0  # m AMSL, the ArduCopter SITL's --home altitude (SIM_STATE.alt is AMSL)
_LOCAL_POSITION_NED = 32
_HEARTBEAT = 0  # asked at the streams' rate: ArduPilot honours it; PX4 keeps 1 Hz ...
_CURRENT_MODE = 436  # ... but streams CURRENT_MODE once asked, and sends one more on each change
_TRUTH = {"ardupilot": ("SIM_STATE", 108), "px4": ("HIL_STATE_QUATERNION", 115)}
# PX4 SITL's SIH link (UDP 19450 -> 19410, 400 kB/s) answers SET_MESSAGE_INTERVAL like any link; nothing else uses it
SPARE_PORT = {"ardupilot": "tcp:127.0.0.1:5763", "px4": "udpin:127.0.0.1:19410"}


def wait_tcp_port(port: int, timeout: float = 20.0) -> bool:
    """Until a TCP server accepts on 127.0.0.1:``port`` (ArduCopter serves its spare ports once its first has a
    client), at most ``timeout`` [s]; whether it did."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        try:
            socket.create_connection(("127.0.0.1", port), timeout=0.5).close()
            return True
        except OSError:
            time.sleep(0.5)
    return False


def wait_udp_bound(port: int, timeout: float = 15.0) -> bool:
    """Until a UDP socket is bound on ``port`` in this network namespace (a proxy is up), at most ``timeout`` [s]."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if f":{port:04X} " in Path("/proc/net/udp").read_text():
            return True
        time.sleep(0.1)
    return False


def estimate_lag(t: np.ndarray, truth: tuple[np.ndarray, np.ndarray], est: tuple[np.ndarray, np.ndarray],
                 max_lag: float = 0.1, step: float = 0.001, min_motion: float = 0.05) -> tuple[float, float]:
    """The lag [s] of an estimate behind the truth over the instants ``t`` [s] (n,): the shift of the truth that
    leaves the least spread (std) of estimate - truth, searched over +-``max_lag`` [s] in ``step`` [s]; positive: the
    estimate is late. ``truth`` / ``est``: (times (m,), values (m,)) each. Returns (lag [s], that spread [m]); the lag
    is nan where the truth moved less than ``min_motion`` [m] (a hover: no lag to see)."""
    ok = (t - max_lag >= truth[0][0]) & (t + max_lag <= truth[0][-1]) & (t >= est[0][0]) & (t <= est[0][-1])
    t = t[ok]
    if t.size < 3:
        return float("nan"), float("nan")
    if np.ptp(np.interp(t, *truth)) < min_motion:
        return float("nan"), float(np.std(np.interp(t, *est) - np.interp(t, *truth)))
    e = np.interp(t, *est)
    lags = np.arange(-max_lag, max_lag + step / 2, step)
    spread = np.array([np.std(e - np.interp(t - lag, *truth)) for lag in lags])
    k = int(np.argmin(spread))
    return float(lags[k]), float(spread[k])


class Observer(threading.Thread):
    """Records the SITL's truth and estimate (see the module docstring) until :meth:`stop`.

    Args:
        url: the spare port (``tcp:127.0.0.1:5762``); rate_hz: the rate asked for both streams.
        autopilot: whose truth message to ask for (PX4's true height counts from its first sample); sysid: the
            vehicle's system id.
        connect: False: no connection and no thread (feed :meth:`record` yourself).
    """

    def __init__(self, url: str, rate_hz: float = 50.0, autopilot: str = "ardupilot", sysid: int = 1,
                 connect: bool = True) -> None:
        super().__init__(daemon=True)
        self.interval_us = 1e6 / rate_hz
        self.autopilot = autopilot
        self.truth_type, self.truth_id = _TRUTH[autopilot]
        self._alt0: float | None = None
        # the true height refined below its grid (truncated: the truth lies in [q, q + grid) above a reported q)
        self._fine = Dequantizer(TRUTH_GRID[self.truth_type], (0.0, 1.0))
        # ArduCopter: truth and estimate on its clock (LOCAL_POSITION_NED's time_boot_ms; PX4 sends them apart)
        self.clock = LinkClock() if autopilot == "ardupilot" else None
        self.sysid = sysid
        self.sim: list[tuple[float, float]] = []   # (t, true height above home [m], refined)
        self.lpos: list[tuple[float, float]] = []  # (t, estimated height -z [m])
        self.hb: list[tuple[float, int, bool]] = []  # (t, custom_mode, armed)
        self.texts: list[tuple[float, str]] = []
        self.modes: list[tuple[float, int]] = []  # (t, custom_mode) of CURRENT_MODE (PX4: sent on each change)
        self.halt = threading.Event()
        self.c = None
        if connect:
            from pymavlink import mavutil  # the testbed's optional dependency, as the SITL harness's

            self.c = mavutil.mavlink_connection(url, source_system=251, autoreconnect=False)
            self.start()

    def run(self) -> None:
        next_req = 0.0
        while not self.halt.is_set():
            if time.monotonic() > next_req:  # (re)request until it streams
                next_req = time.monotonic() + (5.0 if self.sim else 1.0)
                for msg_id in (self.truth_id, _LOCAL_POSITION_NED, _HEARTBEAT, _CURRENT_MODE):
                    self.c.mav.command_long_send(self.sysid, 1, 511, 0, msg_id, self.interval_us, 0, 0, 0, 0, 0)
            m = self.c.recv_match(blocking=True, timeout=0.2)
            if m is not None:
                self.record(m, time.time())

    def record(self, m, t: float) -> None:
        """Fold in one message ``m`` received at ``t`` [s, time.time()]."""
        typ = m.get_type()
        if typ == "SIM_STATE":
            for msg, ts in self.clock.truth(m, t) if self.clock is not None else [(m, t)]:
                self.sim.append((ts, self._fine.update(msg.alt - HOME_ALT, -msg.vd, ts)))
        elif typ == "HIL_STATE_QUATERNION":
            self._alt0 = m.alt * 1e-3 if self._alt0 is None else self._alt0
            self.sim.append((t, self._fine.update(m.alt * 1e-3 - self._alt0, -m.vz * 0.01, t)))
        elif typ == "LOCAL_POSITION_NED":
            if self.clock is not None:
                for msg, ts in self.clock.stamped(m.time_boot_ms * 1e-3, t):
                    self.sim.append((ts, self._fine.update(msg.alt - HOME_ALT, -msg.vd, ts)))
                t = self.clock.at(m.time_boot_ms * 1e-3)
            self.lpos.append((t, -m.z))
        elif typ == "CURRENT_MODE" and m.get_srcSystem() == self.sysid:
            self.modes.append((t, m.custom_mode))
        elif typ == "STATUSTEXT":
            self.texts.append((t, m.text))
        elif typ == "HEARTBEAT" and m.get_srcSystem() == self.sysid and m.get_srcComponent() == 1:
            self.hb.append((t, m.custom_mode, bool(m.base_mode & 128)))

    def series(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(truth, estimate) as time-ordered (n, 2) arrays of (t [s, time.time()], height [m]); None without both (a
        truth sample left unpaired keeps its arrival, later than its neighbours' send times)."""
        sim, est = list(self.sim), list(self.lpos)
        if len(sim) < 2 or len(est) < 2:
            return None
        a, b = np.array(sim), np.array(est)
        return a[np.argsort(a[:, 0], kind="stable")], b[np.argsort(b[:, 0], kind="stable")]

    def heights(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(true, estimated) heights [m] at the times ``t`` [s, time.time()], interpolated (nan outside)."""
        s = self.series()
        if s is None:
            return np.full(len(t), np.nan), np.full(len(t), np.nan)
        return tuple(np.interp(t, a[:, 0], a[:, 1], left=np.nan, right=np.nan) for a in s)

    def estimate_lag(self, t0: float, t1: float, max_lag: float = 0.1) -> tuple[float, float]:
        """:func:`estimate_lag` of the estimate behind the truth between ``t0`` and ``t1`` [s, time.time()], on a
        5 ms grid: (lag [s], the spread of estimate - truth left at that lag [m]); nan without both streams."""
        s = self.series()
        if s is None:
            return float("nan"), float("nan")
        a, b = s
        return estimate_lag(np.arange(t0, t1, 0.005), (a[:, 0], a[:, 1]), (b[:, 0], b[:, 1]), max_lag)

    def ground(self, seconds: float = 3.0) -> float:
        """The true height where the local frame's origin is: median of truth - estimate over the last ``seconds``
        (call it with the vehicle on the ground, before take-off) [m]; 0 without both streams."""
        s = self.series()
        if s is None:
            return 0.0
        a, b = s
        t = b[b[:, 0] > b[-1, 0] - seconds, 0]
        truth = np.interp(t, a[:, 0], a[:, 1])
        return float(np.median(truth - np.interp(t, b[:, 0], b[:, 1])))

    def mode_name(self, custom_mode: int) -> str:
        """A heartbeat's ``custom_mode`` in the autopilot's words (``OFFBOARD``, ``GUIDED``, ``LOITER``)."""
        from pymavlink import mavutil

        if self.autopilot == "px4":
            return mavutil.interpret_px4_mode(1, custom_mode)  # 1: MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        return mavutil.mode_mapping_acm.get(custom_mode, str(custom_mode))

    def stop(self) -> None:
        self.halt.set()
        if self.c is not None:
            self.join(3)
            self.c.close()
