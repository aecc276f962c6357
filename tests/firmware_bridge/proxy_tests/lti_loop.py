"""A known closed loop behind the steering proxy's hook, in simulated time: an autopilot whose height answers a
position setpoint as a damped second-order system (natural frequency ``wn``, damping ``zeta``) one setpoint
late, streaming LOCAL_POSITION_NED and an ArduCopter GUIDED + armed heartbeat (its estimate may drift off the true
height, ``drift``; the loop then flies its estimate, as an autopilot does, and a motion capture sees the truth), and
GLOBAL_POSITION_INT (home ``home`` above the local origin, which is ``origin_amsl`` above sea level); an app streaming
SET_POSITION_TARGET_LOCAL_NED (or SET_POSITION_TARGET_GLOBAL_INT above home or sea level) at ``DT``. Frames are real pymavlink encodings, fed to the hook as the proxy
would (the vehicle's through ``view.on_frame``, the app's through the hook's call)."""

from __future__ import annotations

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from firmware_bridge.profiles import ARDUCOPTER_MODES, MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, MAV_MODE_FLAG_SAFETY_ARMED
from firmware_bridge.proxy.rewrite import decode_frame

DT = 0.02
POS_ONLY = 0b0000_1111_1111_1000  # x, y, z used; velocity, acceleration, yaw, yaw rate ignored
LAT, LON = 473977418, 85455939  # a global setpoint's position [degE7]
GLOBAL_FRAMES = {"relative_alt": mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, "amsl": mavlink.MAV_FRAME_GLOBAL_INT}


class LoopSim:
    """The autopilot's height loop and the two MAVLink ends (see the module docstring)."""

    def __init__(self, wn: float = 4.0, zeta: float = 0.8, h0: float = 2.0, armed: bool = True,
                 sag: float = 0.0, drift=None, arm_at: int = 0, mocap_zero: float = 0.7, home: float = 0.3,
                 origin_amsl: float = 488.25) -> None:
        self.wn, self.zeta, self.sag = wn, zeta, sag  # sag: a constant downward acceleration (a heavier vehicle) [m/s^2]
        self.drift = drift or (lambda t: 0.0)  # the estimate's error at time t [s] -> [m]
        self.arm_at, self.mocap_zero = arm_at, mocap_zero  # armed from this tick; the mocap frame's height of 0 [m]
        self.vz_late = 0.0
        self.home, self.origin_amsl = home, origin_amsl  # [m] (see the module docstring)
        self.h, self.v = h0, 0.0
        self.u_late = h0  # the setpoint applied (one setpoint late)
        self.armed = armed
        self.veh = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        self.app = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
        self.k = 0

    def heartbeat(self) -> bytes:
        armed = self.armed and self.k >= self.arm_at
        base = MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (MAV_MODE_FLAG_SAFETY_ARMED if armed else 0)
        m = self.veh.heartbeat_encode(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, base,
                                      ARDUCOPTER_MODES["GUIDED"], 4)
        return bytes(m.pack(self.veh))

    def estimate(self) -> float:
        """The autopilot's estimated height [m]."""
        return self.h + self.drift(self.k * DT)

    def position(self) -> bytes:
        m = self.veh.local_position_ned_encode(int(self.k * DT * 1000), 0.0, 0.0, -self.estimate(), 0.0, 0.0, -self.v)
        return bytes(m.pack(self.veh))

    def global_position(self) -> bytes:
        """GLOBAL_POSITION_INT of the estimate (mm, cm/s, as the autopilot rounds them)."""
        h = self.estimate()
        m = self.veh.global_position_int_encode(int(self.k * DT * 1000), LAT, LON, round((h + self.origin_amsl) * 1e3),
                                                round((h - self.home) * 1e3), 0, 0, round(-self.v * 100), 0)
        return bytes(m.pack(self.veh))

    def frame_offset(self, frame: str) -> float:
        """The app frame's height minus the local frame's [m]: the autopilot's conversion."""
        return {"local": 0.0, "relative_alt": -self.home, "amsl": self.origin_amsl}[frame]

    def local_height(self, msg) -> float:
        """The height [m, local] the autopilot makes of a setpoint ``msg`` in either message."""
        if msg.get_type() == "SET_POSITION_TARGET_LOCAL_NED":
            return -float(msg.z)
        frame = next(k for k, v in GLOBAL_FRAMES.items() if v == msg.coordinate_frame)
        return float(msg.alt) - self.frame_offset(frame)

    def pose(self, t: float):
        """A motion capture's pose of the true height (in its own frame, ``mocap_zero`` below), stamped ``t`` [s]."""
        m = self.veh.vision_position_estimate_encode(int(t * 1e6), 0.0, 0.0, -(self.h - self.mocap_zero), 0.0, 0.0,
                                                     0.0)
        return decode_frame(bytes(m.pack(self.veh)))

    def setpoint(self, height: float, vz_up: float | None = None, frame: str = "local"):
        """(decoded message, frame) of the app's setpoint at ``height`` [m up, local] (with a velocity field if given),
        in the app's ``frame`` ("local", or a key of :data:`GLOBAL_FRAMES`: the height put into it)."""
        mask = POS_ONLY if vz_up is None else POS_ONLY & ~mavlink.POSITION_TARGET_TYPEMASK_VZ_IGNORE
        vz = 0.0 if vz_up is None else -vz_up
        if frame == "local":
            m = self.app.set_position_target_local_ned_encode(
                int(self.k * DT * 1000), 1, 1, mavlink.MAV_FRAME_LOCAL_NED, mask, 1.0, 2.0, -height, 0.0, 0.0, vz,
                0.0, 0.0, 0.0, 0.0, 0.0)
        else:
            m = self.app.set_position_target_global_int_encode(
                int(self.k * DT * 1000), 1, 1, GLOBAL_FRAMES[frame], mask, LAT, LON,
                height + self.frame_offset(frame), 0.0, 0.0, vz, 0.0, 0.0, 0.0, 0.0, 0.0)
        frame = bytes(m.pack(self.app))
        return decode_frame(frame), frame

    def step(self, u: float, substeps: int = 20, vz: float = 0.0) -> None:
        """One setpoint period with ``u`` [m] (and the velocity feed-forward ``vz`` [m/s, up]) arriving now (applied
        from the next period on)."""
        h_sp, self.u_late = self.u_late, u
        v_sp, self.vz_late = self.vz_late, vz
        d = DT / substeps
        for _ in range(substeps):
            a = self.wn ** 2 * (h_sp - self.estimate()) + 2.0 * self.zeta * self.wn * (v_sp - self.v) - self.sag
            self.v += a * d
            self.h += self.v * d
        self.k += 1


def fly(hook, path: np.ndarray, sim: LoopSim | None = None, vz: np.ndarray | None = None, frame: str = "local",
        global_every: int = 1, t0: float = 1000.0, split: bool = False) -> dict:
    """Fly the app's heights ``path`` (n,) [m, local] through ``hook``, its setpoints in ``frame`` (see
    :meth:`LoopSim.setpoint`): each tick the vehicle's position (and each second a heartbeat; for a global app every
    ``global_every`` ticks its GLOBAL_POSITION_INT) reaches the proxy, then the app's setpoint. Returns arrays: ``h``
    the vehicle's height after each setpoint's period, ``sent`` the height sent (local), ``rewritten`` whether the
    hook replaced the frame, and ``frames`` the (app's, sent) frames. The first tick is at ``t0`` [s]. ``split``: the
    hook is driven as the proxy drives it (``decide``, the send, ``settle``; a passive hook's whole call after it)."""
    sim = sim or LoopSim(h0=float(path[0]))
    h, sent, rewritten, frames = [], [], [], []
    for k, z in enumerate(path):
        t = t0 + k * DT
        if k % 25 == 0:
            hook.view.on_frame(sim.heartbeat(), t - 0.002)
        hook.view.on_frame(sim.position(), t - 0.001)
        if frame != "local" and k % global_every == 0:
            hook.view.on_frame(sim.global_position(), t - 0.001)
        if hook.view.mocap is not None:
            hook.view.mocap.link.pending.append((sim.pose(t - 0.003), t - 0.001))
        msg, app_frame = sim.setpoint(float(z), None if vz is None else float(vz[k]), frame)
        if not split:
            out = hook(msg, app_frame, t)
        elif hook.passive:
            out = hook(msg, app_frame, t) and None  # (after the send: its answer is never a replacement)
        else:
            out = hook.decide(msg, app_frame, t)
            hook.settle()
        sp = msg if out is None else decode_frame(out)
        u = sim.local_height(sp)
        sent.append(u)
        rewritten.append(out is not None)
        frames.append((app_frame, app_frame if out is None else out))
        sim.step(u, vz=0.0 if vz is None else -float(sp.vz))
        h.append(sim.h)
    return {"h": np.array(h), "sent": np.array(sent), "rewritten": np.array(rewritten), "frames": frames}


class PoseLink:
    """A motion capture's link in simulated time: the poses :func:`fly` queues, drained as a link would."""

    def __init__(self) -> None:
        self.pending: list = []

    def drain(self) -> list:
        out, self.pending = self.pending, []
        return out

    def close(self) -> None:
        pass
