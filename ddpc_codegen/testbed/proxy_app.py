"""A user's own offboard app, as people write them with pymavlink: it knows nothing of the steering proxy (only
its connection string says where it connects). It takes the vehicle into GUIDED (ArduCopter) or OFFBOARD (PX4),
arms and takes off when on the ground, moves to the path's start, then streams ``SET_POSITION_TARGET_LOCAL_NED``
at a fixed rate along a named path, with its own velocity and acceleration feed-forward (``--feedforward``),
and holds the last point. Every setpoint it sends is logged (one JSON line: wall time, path time, position NED).

``--frame relative_alt`` / ``amsl``: after the take-off (home is set at arming) the app flies the same path as
``SET_POSITION_TARGET_GLOBAL_INT``, its altitude above home (``MAV_FRAME_GLOBAL_RELATIVE_ALT_INT``) or above sea
level (``MAV_FRAME_GLOBAL_INT``), as an app that thinks in latitude, longitude and altitude does: one
``GLOBAL_POSITION_INT`` beside the ``LOCAL_POSITION_NED`` of the same instant anchors the local frame (flat earth
over the few metres flown; its log stays in local NED).

``--write-path FILE``: instead of flying, write the named path as a trajectory CSV (t from 0 to the duration, x, y,
z the path's offsets [m], z up), the file a user gives ``ddpc-proxy --preview-file``.

``python -m ddpc_codegen.testbed.proxy_app --connect udpout:127.0.0.1:14541 --path helix --duration 30``
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
from pymavlink import mavutil

from ddpc_codegen.robot.trajectory_files import save_trajectory_csv
from firmware_bridge.truth import EARTH_RADIUS_M

__all__ = ["PATHS", "App", "PathTrajectory", "path_point", "write_path", "await_telemetry", "take_off", "fly", "main"]

M = mavutil.mavlink
GUIDED, PX4_OFFBOARD = 4, 6 << 16
_POS = M.POSITION_TARGET_TYPEMASK_VX_IGNORE | M.POSITION_TARGET_TYPEMASK_VY_IGNORE | \
    M.POSITION_TARGET_TYPEMASK_VZ_IGNORE
_ACC = M.POSITION_TARGET_TYPEMASK_AX_IGNORE | M.POSITION_TARGET_TYPEMASK_AY_IGNORE | \
    M.POSITION_TARGET_TYPEMASK_AZ_IGNORE
_YAW = M.POSITION_TARGET_TYPEMASK_YAW_IGNORE | M.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE
MASKS = {"none": _POS | _ACC | _YAW, "vel": _ACC | _YAW, "velacc": _YAW}
FRAMES = {"relative_alt": M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, "amsl": M.MAV_FRAME_GLOBAL_INT}  # --frame: global


def _helix(t: np.ndarray) -> np.ndarray:
    """A 2 m circle at 1 m/s while the height climbs 1.2 m and comes back (period 12 s) [m, up]."""
    w = 0.5
    return np.stack((2.0 * np.cos(w * t) - 2.0, 2.0 * np.sin(w * t), 0.6 - 0.6 * np.cos(2 * np.pi * t / 12.0)))


def _steps(t: np.ndarray) -> np.ndarray:
    """Height waypoints every 4 s (+0.8, +0.3, -0.5, +0.6 m ...), each reached along a 1.5 s smooth ramp."""
    levels = np.array([0.0, 0.8, 1.1, 0.6, 1.2, 0.4, 1.0, 0.2])
    k = np.clip((t // 4.0).astype(int), 0, len(levels) - 1)
    prev = levels[np.maximum(k - 1, 0)]
    s = np.clip((t - 4.0 * k) / 1.5, 0.0, 1.0)
    z = prev + (levels[k] - prev) * (0.5 - 0.5 * np.cos(np.pi * s))
    z = np.where(t < 4.0, 0.0, z)
    return np.stack((np.zeros_like(t), 0.5 * np.sin(2 * np.pi * t / 16.0), z))


def _wander(t: np.ndarray) -> np.ndarray:
    """A smooth 3-D path that never repeats (incommensurate periods 4.7-13.1 s, up to ~1.3 m/s)."""
    x = 1.2 * np.sin(2 * np.pi * t / 9.7) + 0.5 * np.sin(2 * np.pi * t / 4.7 + 1.0)
    y = 1.0 * np.sin(2 * np.pi * t / 7.3 + 0.5) + 0.4 * np.sin(2 * np.pi * t / 13.1)
    z = 0.5 * np.sin(2 * np.pi * t / 6.1) + 0.3 * np.sin(2 * np.pi * t / 4.3 + 2.0) + 0.2 * np.sin(2 * np.pi * t / 11.3)
    return np.stack((x, y, z + 0.6))


PATHS = {"helix": _helix, "steps": _steps, "wander": _wander}


def path_point(name: str, t: float, dt: float = 1e-3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(position, velocity, acceleration) (3,) each, ENU-like (x, y, up) offsets [m, m/s, m/s^2] of path ``name`` at
    ``t`` [s] (derivatives by central differences: any path function works)."""
    f = PATHS[name]
    p = f(np.array([t - dt, t, t + dt]))
    return p[:, 1], (p[:, 2] - p[:, 0]) / (2 * dt), (p[:, 2] - 2 * p[:, 1] + p[:, 0]) / (dt * dt)


class PathTrajectory:
    """Path ``name`` as a trajectory (``sample``: its x, y, z offsets [m, z up] at times t [s])."""

    def __init__(self, name: str) -> None:
        self.f = PATHS[name]

    def sample(self, t) -> dict[str, np.ndarray]:
        x, y, z = self.f(np.asarray(t, dtype=float))
        return {"x": x, "y": y, "z": z}


def write_path(name: str, duration: float, path: Path, dt: float = 0.02) -> Path:
    """Path ``name`` over [0, ``duration``] [s] as a trajectory CSV (t, x, y, z every ``dt`` [s]) at ``path``."""
    return save_trajectory_csv(path, PathTrajectory(name), duration, dt, columns=("t", "x", "y", "z"))


class App:
    """The app's MAVLink side (every wait bounded)."""

    def __init__(self, url: str, log: Path | None, sysid: int = 245) -> None:
        self.c = mavutil.mavlink_connection(url, source_system=sysid, source_component=M.MAV_COMP_ID_ONBOARD_COMPUTER)
        self.log = open(log, "a") if log else None
        self.hb = None
        self.lpos = None
        self.gpos = None
        # a global frame: (MAV_FRAME, lat0, lon0 [deg] of the local origin, the frame's altitude of it [m])
        self.anchor: tuple[int, float, float, float] | None = None
        self.t0 = time.monotonic()

    def beat(self) -> None:
        self.c.mav.heartbeat_send(M.MAV_TYPE_ONBOARD_CONTROLLER, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)

    def pump(self, timeout: float = 0.0) -> None:
        m = self.c.recv_match(blocking=timeout > 0, timeout=timeout)
        while m is not None:
            typ = m.get_type()
            if typ == "HEARTBEAT" and m.autopilot != M.MAV_AUTOPILOT_INVALID:
                self.hb = m
                self.c.target_system, self.c.target_component = m.get_srcSystem(), m.get_srcComponent()
            elif typ == "LOCAL_POSITION_NED":
                self.lpos = m
            elif typ == "GLOBAL_POSITION_INT":
                self.gpos = m
            m = self.c.recv_match(blocking=False)

    def wait(self, what, timeout: float, every=None, period: float = 1.0) -> bool:
        """Pump until ``what()`` (calling ``every()`` each ``period`` [s]) or ``timeout`` [s]."""
        end, nxt, beat = time.monotonic() + timeout, 0.0, 0.0
        while time.monotonic() < end:
            now = time.monotonic()
            if now >= beat:
                beat = now + 1.0
                self.beat()
            if now >= nxt:
                nxt = now + period
                if every is not None:
                    every()
            self.pump(min(0.1, period))
            if what():
                return True
        return False

    @property
    def px4(self) -> bool:
        return self.hb is not None and self.hb.autopilot == M.MAV_AUTOPILOT_PX4

    def armed_in_mode(self) -> bool:
        hb = self.hb
        mode = PX4_OFFBOARD if self.px4 else GUIDED
        return hb is not None and bool(hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED) and (
            (hb.custom_mode & 0xFFFF0000) == mode if self.px4 else hb.custom_mode == mode)

    def command(self, cmd: int, *p: float) -> None:
        p = list(p) + [0.0] * (7 - len(p))
        self.c.mav.command_long_send(self.c.target_system, self.c.target_component, cmd, 0, *p)

    def setpoint(self, pos_up: np.ndarray, vel_up: np.ndarray, acc_up: np.ndarray, mask: int,
                 t_path: float | None) -> None:
        """One setpoint at ``pos_up`` (x, y, up) [m] (NED on the wire), logged (with its path time ``t_path`` [s]
        where it has one: a scored point)."""
        ned = lambda v: (float(v[0]), float(v[1]), -float(v[2]))  # noqa: E731 (x north, y east here)
        (x, y, z), (vx, vy, vz), (ax, ay, az) = ned(pos_up), ned(vel_up), ned(acc_up)
        ms = int(1e3 * (time.monotonic() - self.t0))
        if self.anchor is None:
            self.c.mav.set_position_target_local_ned_send(ms, self.c.target_system, self.c.target_component,
                                                          M.MAV_FRAME_LOCAL_NED, mask, x, y, z, vx, vy, vz, ax, ay, az,
                                                          0.0, 0.0)
        else:
            mav_frame, lat0, lon0, alt0 = self.anchor
            lat = lat0 + math.degrees(x / EARTH_RADIUS_M)
            lon = lon0 + math.degrees(y / (EARTH_RADIUS_M * math.cos(math.radians(lat0))))
            self.c.mav.set_position_target_global_int_send(ms, self.c.target_system, self.c.target_component,
                                                           mav_frame, mask,
                                                           int(round(lat * 1e7)), int(round(lon * 1e7)), alt0 - z,
                                                           vx, vy, vz, ax, ay, az, 0.0, 0.0)
        if self.log is not None:
            row = {"t": time.time(), "x": x, "y": y, "z": z}
            self.log.write(json.dumps(row if t_path is None else {**row, "tp": round(t_path, 4)}) + "\n")


def _anchor(app: App, frame: str) -> None:
    """The global ``frame`` ("relative_alt", "amsl") from one ``GLOBAL_POSITION_INT`` and the ``LOCAL_POSITION_NED``
    of its instant (the vehicle hovering): the local origin's latitude, longitude and altitude in that frame."""
    app.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, 33, 20_000)
    app.gpos = None
    paired = lambda: (app.gpos is not None and app.lpos is not None  # noqa: E731
                      and abs(app.gpos.time_boot_ms - app.lpos.time_boot_ms) <= 30)
    if not app.wait(paired, 10.0):
        raise SystemExit(f"proxy_app: no GLOBAL_POSITION_INT beside LOCAL_POSITION_NED within 10 s (--frame {frame})")
    g, lp = app.gpos, app.lpos
    lat, lon = g.lat * 1e-7, g.lon * 1e-7
    lat0 = lat - math.degrees(lp.x / EARTH_RADIUS_M)
    lon0 = lon - math.degrees(lp.y / (EARTH_RADIUS_M * math.cos(math.radians(lat0))))
    alt = g.relative_alt if frame == "relative_alt" else g.alt
    app.anchor = (FRAMES[frame], lat0, lon0, alt * 1e-3 + lp.z)  # the altitude at the vehicle minus its local height


def take_off(app: App, home: np.ndarray, height: float) -> None:
    """GUIDED / OFFBOARD, armed, at ``height`` [m] above ``home``; raises on a refusal that does not pass."""
    zero = np.zeros(3)
    target = home + np.array([0.0, 0.0, height])
    mode = (M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 6, 0) if app.px4 else (M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, GUIDED)

    asked = [0.0]

    def ask() -> None:
        if app.px4:  # PX4 takes OFFBOARD only while setpoints stream (and leaves it when they stop): 20 Hz
            app.setpoint(target, zero, zero, MASKS["none"], -1.0)
        if (app.hb is None or not app.armed_in_mode()) and time.monotonic() - asked[0] > 1.0:
            asked[0] = time.monotonic()
            app.command(M.MAV_CMD_DO_SET_MODE, *mode)
            app.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)

    if not app.wait(app.armed_in_mode, 120.0, ask, period=0.05):
        raise SystemExit("proxy_app: the vehicle did not arm in GUIDED / OFFBOARD within 120 s")
    if not app.px4:
        app.wait(lambda: False, 1.0)
        app.command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, height)
    climbed = lambda: app.lpos is not None and -app.lpos.z > home[2] + height - 0.2  # noqa: E731
    if not app.wait(climbed, 30.0, lambda: app.setpoint(target, zero, zero, MASKS["none"], -1.0) if app.px4 else None,
                    period=0.05):
        raise SystemExit("proxy_app: the take-off did not reach its height within 30 s")


def await_telemetry(app: App, url: str, timeout: float = 60.0) -> None:
    """Until the vehicle's heartbeat and its ``LOCAL_POSITION_NED`` (asked at 50 Hz) arrive through ``url``;
    raises SystemExit after ``timeout`` [s]."""
    if not app.wait(lambda: app.hb is not None and app.lpos is not None, timeout,
                    lambda: app.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, 32, 20_000) if app.hb else None):
        raise SystemExit(f"proxy_app: no heartbeat and position through {url} within {timeout:g} s")


def fly(url: str, path: str, duration: float, rate: float = 50.0, feedforward: str = "velacc",
        height: float = 2.5, log: Path | None = None, lead_in: float = 6.0, hold: float = 1.0,
        frame: str = "local") -> int:
    """Fly ``path`` for ``duration`` [s] at ``rate`` [Hz] around ``height`` [m] above the local origin (taking off
    first when on the ground), then hold its end for ``hold`` [s] (zero velocity and acceleration: the stream's last
    setpoint, also after a proxy's preview delay shorter than ``hold``; logged without a path time). ``frame``
    "relative_alt" / "amsl": from the lead-in on, as ``SET_POSITION_TARGET_GLOBAL_INT`` (the module docstring)."""
    app = App(url, log)
    await_telemetry(app, url)
    origin = np.array([0.0, 0.0, height])  # the local frame's origin is the take-off point
    if not (app.armed_in_mode() and -app.lpos.z > 0.5):
        take_off(app, np.array([app.lpos.x, app.lpos.y, 0.0]), height)
    if frame != "local":
        _anchor(app, frame)
    start = origin + path_point(path, 0.0)[0]
    pos = np.array([app.lpos.x, app.lpos.y, -app.lpos.z])
    zero, period, k, t0 = np.zeros(3), 1.0 / rate, 0, time.monotonic()
    total = lead_in + duration
    while (tk := k * period) <= total:  # lead-in: a straight line to the start, then the path
        if tk < lead_in:
            s = min(tk / (0.6 * lead_in), 1.0)
            app.setpoint(pos + (start - pos) * (0.5 - 0.5 * math.cos(math.pi * s)), zero, zero, MASKS["none"], tk - lead_in)
        else:
            p, v, a = path_point(path, tk - lead_in)
            app.setpoint(origin + p, v, a, MASKS[feedforward], tk - lead_in)
        if k % int(rate) == 0:
            app.beat()
        app.pump()
        k += 1
        time.sleep(max(0.0, t0 + k * period - time.monotonic()))
    end = origin + path_point(path, duration)[0]
    for j in range(int(round(hold * rate))):  # the end: a hold (ArduCopter flies on along the last setpoint's
        app.setpoint(end, zero, zero, MASKS[feedforward], None)  # velocity and acceleration for GUID_TIMEOUT)
        time.sleep(max(0.0, t0 + (k + j + 1) * period - time.monotonic()))
    if app.log is not None:
        app.log.close()
    return 0


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m ddpc_codegen.testbed.proxy_app", description=__doc__.split("\n\n")[0])
    p.add_argument("--connect", default=None,
                   help="pymavlink connection string (udpout:HOST:PORT, tcp:HOST:PORT; required to fly)")
    p.add_argument("--path", choices=sorted(PATHS), default="helix")
    p.add_argument("--duration", type=float, default=30.0, help="seconds of the path (after a 6 s lead-in)")
    p.add_argument("--rate", type=float, default=50.0, help="setpoints per second (default %(default)s)")
    p.add_argument("--feedforward", choices=sorted(MASKS), default="velacc",
                   help="the app's own feed-forward fields (default %(default)s)")
    p.add_argument("--height", type=float, default=2.5, help="the path's base height above the local origin (the take-off point) [m]")
    p.add_argument("--log", type=Path, default=None, help="append each setpoint sent as a JSON line here")
    p.add_argument("--frame", choices=("local", *FRAMES), default="local",
                   help="local: SET_POSITION_TARGET_LOCAL_NED; relative_alt / amsl: SET_POSITION_TARGET_GLOBAL_INT "
                        "above home / sea level after the take-off (default %(default)s)")
    p.add_argument("--write-path", type=Path, default=None, metavar="FILE",
                   help="write the path as a trajectory CSV (t, x, y, z up, from 0 to --duration) and exit")
    a = p.parse_args(argv)
    if a.write_path is not None:
        print(write_path(a.path, a.duration, a.write_path))
        return 0
    if a.connect is None:
        p.error("--connect is required to fly (or --write-path FILE)")
    return fly(a.connect, a.path, a.duration, a.rate, a.feedforward, a.height, a.log, frame=a.frame)


if __name__ == "__main__":
    sys.exit(main())
