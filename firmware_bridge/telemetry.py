"""MAVLink telemetry <-> the controller's frames, and the bridge's view of the newest state.

MAVLink (PX4 and ArduPilot alike) speaks NED / FRD: LOCAL_POSITION_NED (x north, y east,
z down), ATTITUDE (Z-Y-X Euler of body FRD w.r.t. NED), ATTITUDE_QUATERNION and ODOMETRY
(quaternion w, x, y, z rotating NED into FRD, i.e. body FRD -> world NED), body rates FRD.
The companion controller (:mod:`ddpc_codegen.robot.controller`) is z-up: world ENU, body FLU. The
conversions here are the MAVROS ones and agree with :func:`ddpc_codegen.robot.controller.enu_flu_to_ned_frd`::

    p_ENU = (p_N..E swapped) = (y_ned, x_ned, -z_ned)        (same for velocities)
    roll_FLU = roll_FRD, pitch_ENU = -pitch_NED, yaw_ENU = pi/2 - yaw_NED
    w_FLU = (p, -q, -r) of w_FRD

:class:`TelemetryState` keeps the newest sample of each stream (attitude, position) with its
sender time stamp and its receive time, so that a tick always uses the newest telemetry and
knows its age.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ddpc_codegen.robot.controller import MeasuredState
from ddpc_codegen.robot.frames import euler_from_quat, quat_from_euler, quat_multiply

__all__ = [
    "swap_frames",
    "ned_to_enu",
    "frd_to_flu",
    "euler_ned_to_enu",
    "euler_enu_to_ned",
    "wrap_pi",
    "Sample",
    "TelemetryState",
    "STREAMS",
]

_HALF_PI = 0.5 * math.pi

# Stream choices: which MAVLink message feeds the attitude part and the position part of the state.
STREAMS = {
    "attitude": ("ATTITUDE", "ATTITUDE_QUATERNION", "ODOMETRY"),
    "position": ("LOCAL_POSITION_NED", "ODOMETRY"),
}


def wrap_pi(a: float) -> float:
    """Angle wrapped to (-pi, pi]."""
    return math.atan2(math.sin(a), math.cos(a))


_S = math.sqrt(0.5)


def swap_frames(w: float, x: float, y: float, z: float) -> tuple[float, float, float, float]:
    """Attitude quaternion body FLU -> world ENU to body FRD -> world NED, or back (the map is an
    involution): closed form of q_(ENU->NED) * q * q_(FRD->FLU), as
    :func:`ddpc_codegen.robot.controller.enu_flu_to_ned_frd` computes it, without numpy (tick path)."""
    return (-_S * (w + z), -_S * (x + y), _S * (y - x), _S * (z - w))


def ned_to_enu(x: float, y: float, z: float) -> tuple[float, float, float]:
    """A NED vector as ENU (the map is its own inverse)."""
    return (y, x, -z)


def frd_to_flu(p: float, q: float, r: float) -> tuple[float, float, float]:
    """Body rates FRD -> FLU (its own inverse)."""
    return (p, -q, -r)


def euler_ned_to_enu(roll: float, pitch: float, yaw: float) -> tuple[float, float, float]:
    """Z-Y-X Euler angles of FRD w.r.t. NED -> of FLU w.r.t. ENU [rad]."""
    return (roll, -pitch, wrap_pi(_HALF_PI - yaw))


def euler_enu_to_ned(roll: float, pitch: float, yaw: float) -> tuple[float, float, float]:
    """Inverse of :func:`euler_ned_to_enu`."""
    return (roll, -pitch, wrap_pi(_HALF_PI - yaw))


@dataclass
class Sample:
    """Newest sample of one stream.

    stamp: sender time [s] (time_boot_ms / time_usec); rx: local receive time [s, bridge clock];
    seq: how many samples this stream has delivered (a tick waits for every stream to advance).
    """

    stamp: float = math.nan
    rx: float = -math.inf
    seq: int = 0
    # Every sample's (stamp, rx), kept across reboots: a burst of two is two rows, none is dropped.
    history: list[tuple[float, float]] = field(default_factory=list)


@dataclass
class TelemetryState:
    """The newest attitude and position telemetry, already in ENU / FLU.

    Args:
        attitude_msg: "ATTITUDE", "ATTITUDE_QUATERNION" or "ODOMETRY".
        position_msg: "LOCAL_POSITION_NED" or "ODOMETRY".
    """

    attitude_msg: str = "ATTITUDE_QUATERNION"
    position_msg: str = "LOCAL_POSITION_NED"
    att: Sample = field(default_factory=Sample)
    pos: Sample = field(default_factory=Sample)
    position: np.ndarray = field(default_factory=lambda: np.zeros(3))
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    euler: np.ndarray = field(default_factory=lambda: np.zeros(3))
    rates: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        if self.attitude_msg not in STREAMS["attitude"]:
            raise ValueError(f"attitude stream must be one of {STREAMS['attitude']}; got {self.attitude_msg!r}")
        if self.position_msg not in STREAMS["position"]:
            raise ValueError(f"position stream must be one of {STREAMS['position']}; got {self.position_msg!r}")
        self.wanted = {self.attitude_msg, self.position_msg}

    @property
    def has_data(self) -> bool:
        return self.att.seq > 0 and self.pos.seq > 0

    def update(self, msg, rx: float) -> bool:
        """Fold one message in (it is newer by arrival). Returns True if it was a state stream."""
        typ = msg.get_type()
        if typ not in self.wanted:
            return False
        if typ == "ODOMETRY":
            stamp = msg.time_usec * 1e-6
            e = euler_from_quat(swap_frames(*msg.q))
            vel = (msg.vx, msg.vy, msg.vz)
            if msg.child_frame_id == 12:  # MAV_FRAME_BODY_FRD: velocity in the body frame (PX4 >= 1.14)
                vel = tuple(_rotate(msg.q, vel))
            if self.attitude_msg == "ODOMETRY":
                self.euler[:] = e
                self.rates[:] = frd_to_flu(msg.rollspeed, msg.pitchspeed, msg.yawspeed)
                self._tick(self.att, stamp, rx)
            if self.position_msg == "ODOMETRY":
                self.position[:] = ned_to_enu(msg.x, msg.y, msg.z)
                self.velocity[:] = ned_to_enu(*vel)
                self._tick(self.pos, stamp, rx)
            return True
        stamp = msg.time_boot_ms * 1e-3
        if typ == "LOCAL_POSITION_NED":
            self.position[:] = ned_to_enu(msg.x, msg.y, msg.z)
            self.velocity[:] = ned_to_enu(msg.vx, msg.vy, msg.vz)
            self._tick(self.pos, stamp, rx)
        elif typ == "ATTITUDE":
            self.euler[:] = euler_ned_to_enu(msg.roll, msg.pitch, msg.yaw)
            self.rates[:] = frd_to_flu(msg.rollspeed, msg.pitchspeed, msg.yawspeed)
            self._tick(self.att, stamp, rx)
        else:  # ATTITUDE_QUATERNION
            self.euler[:] = euler_from_quat(swap_frames(msg.q1, msg.q2, msg.q3, msg.q4))
            self.rates[:] = frd_to_flu(msg.rollspeed, msg.pitchspeed, msg.yawspeed)
            self._tick(self.att, stamp, rx)
        return True

    @staticmethod
    def _tick(s: Sample, stamp: float, rx: float) -> None:
        s.stamp, s.rx, s.seq = stamp, rx, s.seq + 1
        s.history.append((stamp, rx))

    @property
    def seq_total(self) -> int:
        """Samples received on both streams so far (grows by 2 for a burst of two)."""
        return self.att.seq + self.pos.seq

    def newest_stamp(self) -> float:
        """Sender time of the newest sample [s] (nan before any)."""
        return max(self.att.stamp, self.pos.stamp) if self.has_data else math.nan

    def oldest_rx(self) -> float:
        """Receive time of the older of the two streams' newest samples (what limits freshness)."""
        return min(self.att.rx, self.pos.rx)

    def newest_rx(self) -> float:
        return max(self.att.rx, self.pos.rx)

    def oldest_stamp(self) -> float:
        return min(self.att.stamp, self.pos.stamp)

    def measured_state(self, t: float) -> MeasuredState:
        """A copy as the controller's :class:`MeasuredState` at controller time t [s]."""
        return MeasuredState(t=t, position=self.position.copy(), velocity=self.velocity.copy(),
                             euler=self.euler.copy(), body_rates=self.rates.copy(), contact=False)

    def reset(self) -> None:
        """Forget the newest samples (vehicle reboot: its clock restarted); the history stays."""
        self.att, self.pos = Sample(history=self.att.history), Sample(history=self.pos.history)


def _rotate(q, v) -> np.ndarray:
    """Rotate vector v by the unit quaternion q (w, x, y, z): R(q) v."""
    w, x, y, z = q
    vx, vy, vz = v
    # v' = v + 2 w (u x v) + 2 u x (u x v), u = (x, y, z)
    cx, cy, cz = y * vz - z * vy, z * vx - x * vz, x * vy - y * vx
    dx, dy, dz = y * cz - z * cy, z * cx - x * cz, x * cy - y * cx
    return np.array([vx + 2 * (w * cx + dx), vy + 2 * (w * cy + dy), vz + 2 * (w * cz + dz)])


class TrajectoryFrame:
    """The controller's frame versus the autopilot's local ENU frame.

    The controller flies its trajectory in a frame whose x axis is the robot's heading (yaw 0)
    and whose start point is where the robot is. ``"start"`` makes that true on a real robot:
    while the bridge is not engaged, :meth:`capture` follows the vehicle (heading ``yaw0`` and
    horizontal position), and at engagement the frame freezes, so the robot neither turns nor
    jumps when it enters off-board; the trajectory's start point ``anchor`` (x, y) maps to where
    it was. ``"world"`` uses the autopilot's frame as is (the trajectory's coordinates are local
    ENU positions and the commanded heading is east). Heights are measured from ``z0``: the
    take-off point's EKF height when the bridge saw the vehicle on the ground (the EKF's origin is
    not the ground: PX4 SIH reads 0.5-0.85 m while landed), else 0 (the EKF origin).
    """

    def __init__(self, mode: str = "start", anchor: tuple[float, float] = (0.0, 0.0)) -> None:
        if mode not in ("start", "world"):
            raise ValueError(f"frame must be 'start' or 'world'; got {mode!r}")
        self.mode = mode
        self.anchor = np.asarray(anchor, dtype=float)
        self.origin = self.anchor.copy()  # local ENU (x, y) that maps to the anchor
        self.yaw0 = 0.0
        self.z0 = 0.0
        self.captured = mode == "world"  # "start": known once :meth:`capture` saw the vehicle
        self._c, self._s = 1.0, 0.0
        self._q_yaw = np.array([1.0, 0.0, 0.0, 0.0])

    def capture(self, position: np.ndarray, yaw: float) -> None:
        """Follow the vehicle (call while not engaged): position (3,) local ENU [m], yaw ENU [rad]."""
        if self.mode != "start":
            return
        self.captured = True
        self.origin = np.asarray(position[:2], dtype=float).copy()
        self.yaw0 = float(yaw)
        self._c, self._s = math.cos(self.yaw0), math.sin(self.yaw0)
        self._q_yaw = quat_from_euler(0.0, 0.0, self.yaw0)

    def to_trajectory(self, st: MeasuredState) -> MeasuredState:
        """A local-ENU state in the trajectory frame (in place; returns it)."""
        st.position[2] -= self.z0
        if self.mode == "world":
            return st
        c, s = self._c, self._s
        dx, dy = st.position[0] - self.origin[0], st.position[1] - self.origin[1]
        st.position[0], st.position[1] = self.anchor[0] + c * dx + s * dy, self.anchor[1] - s * dx + c * dy
        vx, vy = st.velocity[0], st.velocity[1]
        st.velocity[0], st.velocity[1] = c * vx + s * vy, -s * vx + c * vy
        st.euler[2] = wrap_pi(st.euler[2] - self.yaw0)
        return st

    def to_world(self, q_enu) -> np.ndarray:
        """An attitude (w, x, y, z) body FLU -> trajectory frame, as body FLU -> local ENU."""
        if self.mode == "world":
            return np.asarray(q_enu, dtype=float)
        return quat_multiply(self._q_yaw, q_enu)

    def as_dict(self) -> dict:
        """JSON-friendly: mode, heading yaw0 [rad, ENU], origin (local ENU x, y) [m] -> anchor [m]."""
        return {"mode": self.mode, "yaw0": self.yaw0, "origin": self.origin.tolist(), "anchor": self.anchor.tolist(),
                "z0": self.z0}

    def describe(self) -> str:
        z = f", heights from z0 = {self.z0:.2f} m (EKF)"
        if self.mode == "world":
            return "frame world (local ENU)" + z
        return (f"frame start: heading {math.degrees(self.yaw0):.1f} deg ENU, start point at "
                f"({self.origin[0]:.2f}, {self.origin[1]:.2f}) m" + z)
