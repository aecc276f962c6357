"""The motion-capture stream the companion receives: a lab's measurement of the vehicle's pose, as the bridge
reads it beside the autopilot's telemetry (``ddpc-bridge --mocap URL``).

A lab's companion gets the pose from the motion-capture system's software (VRPN, NatNet, a ROS topic) and
forwards it to the autopilot over MAVLink. Here the companion's bridge takes the same MAVLink messages on a
link of its own (``udpin:HOST:PORT``: whatever forwards the poses sends them there too; the SITL stand-in
:class:`ddpc_codegen.testbed.mocap.MocapStandIn` does with ``forward=``):

* VISION_POSITION_ESTIMATE: ``usec``, ``x`` / ``y`` / ``z`` local NED [m], ``roll`` / ``pitch`` / ``yaw``;
* ATT_POS_MOCAP: ``time_usec``, quaternion (w, x, y, z; body FRD -> NED), ``x`` / ``y`` / ``z`` NED;
* ODOMETRY in ``frame_id`` MAV_FRAME_LOCAL_NED (1) or the north-aligned MAV_FRAME_LOCAL_FRD (20).

Each accepted pose becomes local ENU (:mod:`ddpc_codegen.robot.frames`, as the telemetry does) with its yaw.
A pose with a non-finite field, a stamp older than the last one's (UDP reordering), or one
:class:`.plausibility.TelemetryLimits` finds implausible (a jump no vehicle flies) is dropped and counted by
reason; the newest good pose then ages, and the bridge treats an old one as missing
(:mod:`.position_source`).

Time. ``rx`` is the receive time (kernel stamp, bridge clock). The message's stamp is the measurement
instant; when it lies 0..``MAX_LATENCY_S`` before the arrival on this host's monotonic clock (a companion
that stamps the poses on its own clock, as the stand-in does) ``latency`` = rx - stamp is the measurement's
transport delay; otherwise the stamps are another clock's (a mocap server's) and the latency is unknown
(nan, counted in ``foreign_stamps``): only the age since arrival is then measured.
"""

from __future__ import annotations

import math
from collections import Counter
from typing import Any

import numpy as np

from ddpc_codegen.robot.frames import enu_from_ned, euler_enu_from_ned, euler_from_quat, quat_enu_flu_from_ned_frd
from firmware_bridge.plausibility import TelemetryLimits

__all__ = ["MocapInput", "MOCAP_MESSAGES", "MAX_LATENCY_S", "decode_pose"]

MOCAP_MESSAGES = ("VISION_POSITION_ESTIMATE", "ATT_POS_MOCAP", "ODOMETRY")
# A stamp further than this before its arrival is not on this host's clock (no link delays a pose a second).
MAX_LATENCY_S = 1.0
_ODOMETRY_FRAMES = (1, 20)  # MAV_FRAME_LOCAL_NED, MAV_FRAME_LOCAL_FRD (north-aligned: what ArduPilot takes)
_ZERO3 = (0.0, 0.0, 0.0)


def decode_pose(msg: Any) -> tuple[float, tuple[float, float, float], float] | str:
    """(stamp [s], position local ENU (3,) [m], yaw ENU [rad]) of a mocap message, or why it is unusable
    ("type", "frame", "nonfinite")."""
    typ = msg.get_type()
    if typ == "VISION_POSITION_ESTIMATE":
        stamp, ned = msg.usec * 1e-6, (msg.x, msg.y, msg.z)
        yaw = euler_enu_from_ned((msg.roll, msg.pitch, msg.yaw))[2]
    elif typ in ("ATT_POS_MOCAP", "ODOMETRY"):
        if typ == "ODOMETRY" and msg.frame_id not in _ODOMETRY_FRAMES:
            return "frame"
        stamp, ned = msg.time_usec * 1e-6, (msg.x, msg.y, msg.z)
        q = tuple(float(v) for v in msg.q)
        norm = math.sqrt(sum(v * v for v in q))
        if not (math.isfinite(norm) and abs(norm - 1.0) < 0.1):
            return "nonfinite"
        yaw = float(euler_from_quat(quat_enu_flu_from_ned_frd(q))[2])
    else:
        return "type"
    pos = enu_from_ned(tuple(float(v) for v in ned))
    if not all(math.isfinite(v) for v in (*pos, yaw)):
        return "nonfinite"
    return stamp, pos, float(yaw)


class MocapInput:
    """The newest motion-capture pose (see the module docstring), from ``link`` (an open
    :class:`.link.MavLink`, or anything with ``drain()`` -> [(msg, rx)] and ``close()``).

    Attributes:
        position: east, north, up [m] in the mocap's frame (nan before a pose); yaw: ENU [rad].
        stamp: the pose's measurement instant [s, its sender's clock]; rx: its arrival [s, bridge clock].
        latency: rx - stamp [s] when the stamp is on this host's clock, else nan.
        seq: poses accepted; dropped / rejected: poses dropped (by reason); foreign_stamps: accepted poses
            whose stamp is not on this host's clock; history: (stamp, rx) of every accepted pose.
    """

    def __init__(self, link: Any, limits: TelemetryLimits | None = None) -> None:
        self.link = link
        self.limits = limits or TelemetryLimits()
        self.position = np.full(3, np.nan)
        self.yaw = math.nan
        self.stamp = math.nan
        self.rx = -math.inf
        self.latency = math.nan
        self.seq = 0
        self.dropped = 0
        self.rejected: Counter = Counter()
        self.foreign_stamps = 0
        self.history: list[tuple[float, float]] = []

    def pump(self) -> int:
        """Fold every pending message in; the poses accepted."""
        n = 0
        for msg, rx in self.link.drain():
            n += self.update(msg, rx)
        return n

    def update(self, msg: Any, rx: float) -> bool:
        """Fold one message received at ``rx`` [s] in; True if it was an accepted pose."""
        if msg.get_type() not in MOCAP_MESSAGES:
            return False  # a heartbeat of the sender, anything else on the port: not a pose
        pose = decode_pose(msg)
        if isinstance(pose, str):
            return self._reject(pose)
        stamp, pos, yaw = pose
        if self.seq and stamp < self.stamp:
            return self._reject("stamp")
        # a pose carries no velocity: bounds and the position's jump only
        last = (tuple(self.position), _ZERO3) if self.seq else None
        fault = self.limits.state_fault(pos, _ZERO3, last, max(rx - self.rx, 0.0) if self.seq else 0.0)
        if fault is not None:
            return self._reject(fault)
        self.position[:], self.yaw, self.stamp, self.rx = pos, yaw, stamp, rx
        delay = rx - stamp
        local = 0.0 <= delay <= MAX_LATENCY_S
        self.latency = delay if local else math.nan
        self.foreign_stamps += 0 if local else 1
        self.seq += 1
        self.history.append((stamp, rx))
        return True

    def _reject(self, reason: str) -> bool:
        self.dropped += 1
        self.rejected[reason] += 1
        return False

    @property
    def present(self) -> bool:
        """A pose was accepted."""
        return self.seq > 0

    def age(self, now: float) -> float:
        """Seconds since the newest pose arrived (inf before any)."""
        return now - self.rx

    def latencies(self) -> np.ndarray:
        """rx - stamp of every accepted pose [s] whose stamp is on this host's clock."""
        h = np.array(self.history, dtype=float).reshape(-1, 2)
        d = h[:, 1] - h[:, 0]
        return d[(d >= 0.0) & (d <= MAX_LATENCY_S)]

    def close(self) -> None:
        """Close the link."""
        self.link.close()
