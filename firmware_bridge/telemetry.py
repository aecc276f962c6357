"""MAVLink telemetry <-> the controller's frames, and the bridge's view of the newest state.

MAVLink (PX4 and ArduPilot alike) speaks NED / FRD: LOCAL_POSITION_NED (x north, y east,
z down), ATTITUDE (Z-Y-X Euler of body FRD w.r.t. NED), ATTITUDE_QUATERNION and ODOMETRY
(quaternion w, x, y, z rotating NED into FRD, i.e. body FRD -> world NED), body rates FRD.
The companion controller (:mod:`ddpc_codegen.robot.controller`) is z-up: world ENU, body FLU. The
conversions are :mod:`ddpc_codegen.robot.frames`' scalar path (the MAVROS convention)::

    p_ENU = (y_ned, x_ned, -z_ned)                            enu_from_ned (same for velocities)
    roll_FLU = roll_FRD, pitch_ENU = -pitch_NED, yaw_ENU = pi/2 - yaw_NED     euler_enu_from_ned
    w_FLU = (p, -q, -r) of w_FRD                              rates_flu_from_frd

:class:`TelemetryState` keeps the newest sample of each stream (attitude, position) with its
sender time stamp and its receive time, so that a tick always uses the newest telemetry and
knows its age. A sample with a non-finite field (a NaN quaternion or position), a quaternion far from
unit norm, or one that :mod:`.plausibility` finds implausible (out of physical bounds, a jump from the
last accepted sample, a stamp off the stream's time line) is dropped and counted (``dropped``, by reason
in ``rejected``): it never reaches the frames or the setpoints; the stream's last good sample ages
instead, so a flood of them is stale telemetry.

A stream's time line is the vehicle's only once :data:`.plausibility.TIMELINE_SAMPLES` samples advanced on it:
until both streams' lines are (``has_data``), no stamp is anyone's reference (no tick, no vehicle clock). One
sample cannot make itself the reference for the good ones: an unconfirmed line is re-lined onto a run of
samples that advance together off it (a note for the caller's events), while a confirmed line leaves only on a
reboot's evidence (:class:`.vehicle_link.VehicleLink`).
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

from ddpc_codegen.robot.state import MeasuredState
from ddpc_codegen.robot.frames import (
    enu_from_ned,
    euler_enu_from_ned,
    euler_from_quat,
    quat_enu_flu_from_ned_frd,
    quat_from_euler,
    quat_multiply,
    rates_flu_from_frd,
    rotate,
    wrap_pi,
)
from firmware_bridge.plausibility import TIMELINE_SAMPLES, TelemetryLimits, on_timeline

__all__ = [
    "Sample",
    "TelemetryState",
    "TrajectoryFrame",
    "STREAMS",
]

# Stream choices: which MAVLink message feeds the attitude part and the position part of the state.
STREAMS = {
    "attitude": ("ATTITUDE", "ATTITUDE_QUATERNION", "ODOMETRY"),
    "position": ("LOCAL_POSITION_NED", "ODOMETRY"),
}


@dataclass
class Sample:
    """Newest sample of one stream.

    stamp: sender time [s] (time_boot_ms / time_usec); rx: local receive time [s, bridge clock];
    seq: how many samples this stream has delivered (a tick waits for every stream to advance);
    line_n: how many of them advanced the time line (confirmed at :data:`.plausibility.TIMELINE_SAMPLES`).
    """

    stamp: float = math.nan
    rx: float = -math.inf
    seq: int = 0
    line_n: int = 0
    # Samples off the time line that agree with each other: (stamp, rx) of the newest, how many, how many of
    # them advanced it.
    cand_stamp: float = math.nan
    cand_rx: float = -math.inf
    cand_n: int = 0
    cand_adv: int = 0
    # Every sample's (stamp, rx), kept across reboots: a burst of two is two rows, none is dropped.
    history: list[tuple[float, float]] = field(default_factory=list)

    @property
    def confirmed(self) -> bool:
        """Enough samples advanced on the time line for it to be the vehicle's."""
        return self.line_n >= TIMELINE_SAMPLES

    def candidate(self, limits: TelemetryLimits, stamp: float, rx: float) -> None:
        """A sample off the time line: it extends the candidate line, or starts a new one."""
        if self.cand_n > 0 and on_timeline(limits, self.cand_stamp, self.cand_rx, stamp, rx):
            self.cand_n, self.cand_adv = self.cand_n + 1, self.cand_adv + (stamp > self.cand_stamp)
        else:
            self.cand_n, self.cand_adv = 1, 1
        self.cand_stamp, self.cand_rx = stamp, rx

    def new_line(self) -> Sample:
        """This stream on its candidate time line (none: on no line), with nothing accepted yet."""
        if self.cand_n == 0:
            return Sample(history=self.history)
        return Sample(stamp=self.cand_stamp, rx=self.cand_rx, line_n=self.cand_adv, history=self.history)


@dataclass
class TelemetryState:
    """The newest attitude and position telemetry, already in ENU / FLU.

    Args:
        attitude_msg: "ATTITUDE", "ATTITUDE_QUATERNION" or "ODOMETRY".
        position_msg: "LOCAL_POSITION_NED" or "ODOMETRY".
        contact_name: hopping with a leg sensor: the NAMED_VALUE_INT name carrying foot contact
            (value != 0: on the ground); the newest flag is ``contact`` (None before the first one)
            with its stamp ``contact_stamp`` [s]. None: not read.
        limits: what a plausible sample satisfies (:class:`.plausibility.TelemetryLimits`).
    """

    attitude_msg: str = "ATTITUDE_QUATERNION"
    position_msg: str = "LOCAL_POSITION_NED"
    contact_name: str | None = None
    att: Sample = field(default_factory=Sample)
    pos: Sample = field(default_factory=Sample)
    position: np.ndarray = field(default_factory=lambda: np.zeros(3))
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(3))
    euler: np.ndarray = field(default_factory=lambda: np.zeros(3))
    rates: np.ndarray = field(default_factory=lambda: np.zeros(3))
    limits: TelemetryLimits = field(default_factory=TelemetryLimits)

    def __post_init__(self) -> None:
        if self.attitude_msg not in STREAMS["attitude"]:
            raise ValueError(f"attitude stream must be one of {STREAMS['attitude']}; got {self.attitude_msg!r}")
        if self.position_msg not in STREAMS["position"]:
            raise ValueError(f"position stream must be one of {STREAMS['position']}; got {self.position_msg!r}")
        self.wanted = {self.attitude_msg, self.position_msg}
        self.contact: bool | None = None
        self.contact_value: int | None = None  # the flag as sent (0 / 1; anything else is implausible)
        self.contact_stamp = math.nan
        self.dropped = 0  # samples never used (non-finite, non-unit quaternion, implausible)
        self.rejected: Counter = Counter()  # the dropped samples by reason
        self.relines = 0  # unconfirmed time lines replaced by the samples' own
        self.notes: list[str] = []  # what the owner should log (see :meth:`take_notes`)
        if self.contact_name:
            self.wanted.add("NAMED_VALUE_INT")

    @property
    def has_data(self) -> bool:
        """Both streams delivered a sample on a confirmed time line (their stamps may be used)."""
        return self.att.seq > 0 and self.pos.seq > 0 and self.att.confirmed and self.pos.confirmed

    def update(self, msg, rx: float) -> bool:
        """Fold one message in (it is newer by arrival). Returns True if it was a state stream."""
        typ = msg.get_type()
        if typ not in self.wanted:
            return False
        if typ == "NAMED_VALUE_INT":
            name = msg.name if isinstance(msg.name, str) else msg.name.decode(errors="ignore")
            if name.rstrip("\x00") == self.contact_name:
                self.contact, self.contact_stamp = msg.value != 0, msg.time_boot_ms * 1e-3
                self.contact_value = int(msg.value)
            return False  # not a state stream: it never triggers a tick
        if not _plausible(msg, typ):
            return self._reject("nonfinite")
        if typ == "ODOMETRY":
            stamp = msg.time_usec * 1e-6
            vel = (msg.vx, msg.vy, msg.vz)
            if msg.child_frame_id == 12:  # MAV_FRAME_BODY_FRD: velocity in the body frame (PX4 >= 1.14)
                vel = rotate(msg.q, vel)
            att = (euler_from_quat(quat_enu_flu_from_ned_frd(msg.q)),
                   rates_flu_from_frd((msg.rollspeed, msg.pitchspeed, msg.yawspeed))) \
                if self.attitude_msg == "ODOMETRY" else None
            pos = (enu_from_ned((msg.x, msg.y, msg.z)), enu_from_ned(vel)) if self.position_msg == "ODOMETRY" else None
        elif typ == "LOCAL_POSITION_NED":
            stamp, att = msg.time_boot_ms * 1e-3, None
            pos = (enu_from_ned((msg.x, msg.y, msg.z)), enu_from_ned((msg.vx, msg.vy, msg.vz)))
        else:
            stamp, pos = msg.time_boot_ms * 1e-3, None
            e = euler_enu_from_ned((msg.roll, msg.pitch, msg.yaw)) if typ == "ATTITUDE" else \
                euler_from_quat(quat_enu_flu_from_ned_frd((msg.q1, msg.q2, msg.q3, msg.q4)))
            att = (e, rates_flu_from_frd((msg.rollspeed, msg.pitchspeed, msg.yawspeed)))
        names = (("att",) if att is not None else ()) + (("pos",) if pos is not None else ())
        fault = self._stamp_fault(names, stamp, rx) or self._fault(att, pos, stamp, rx)
        if fault is not None:
            return self._reject(fault)
        if att is not None:
            self.euler[:], self.rates[:] = att
            self._tick(self.att, stamp, rx)
        if pos is not None:
            self.position[:], self.velocity[:] = pos
            self._tick(self.pos, stamp, rx)
        return True

    def _stamp_fault(self, names: tuple[str, ...], stamp: float, rx: float) -> str | None:
        """"stamp" when the stamp [s] received at ``rx`` [s] is off the time line of a stream ``names`` it feeds.

        Off it, the sample extends each stream's candidate line (a reboot, if the heartbeat agrees). A stream whose
        own line is unconfirmed moves onto a candidate that advanced :data:`.plausibility.TIMELINE_SAMPLES` times
        (its first samples, or a forged one, were the odd ones out) and the sample is used on it."""
        lim = self.limits
        streams = [getattr(self, n) for n in names]
        if all(on_timeline(lim, s.stamp, s.rx, stamp, rx) for s in streams):
            for s in streams:
                if not stamp <= s.stamp:  # advanced (or the first): the old line goes on
                    s.cand_n = s.cand_adv = 0
            return None
        for n, s in zip(names, streams):
            s.candidate(lim, stamp, rx)
            if not s.confirmed and s.cand_adv >= TIMELINE_SAMPLES:
                self._reline(n)
        if all(on_timeline(lim, s.stamp, s.rx, stamp, rx) for s in (getattr(self, n) for n in names)):
            return None
        return "stamp"

    def _reline(self, name: str) -> None:
        """Move stream ``name`` onto its candidate time line (its line was never confirmed), with a note."""
        old = getattr(self, name)
        setattr(self, name, old.new_line())
        self.relines += 1
        which = "attitude" if name == "att" else "position"
        self.notes.append(f"{which} telemetry re-lined from {old.stamp:.3f} s to {old.cand_stamp:.3f} s: "
                          f"{old.cand_adv} samples advanced together off a time line that never was the vehicle's "
                          f"({old.line_n} sample(s) advanced on it); the samples before were dropped")

    def _fault(self, att, pos, stamp: float, rx: float) -> str | None:
        """Why the decoded sample ((euler, rates) and / or (position, velocity)) is implausible."""
        lim = self.limits
        if att is not None and (f := lim.rates_fault(att[1])) is not None:
            return f
        if pos is not None:
            s = self.pos
            last = (self.position, self.velocity) if s.seq > 0 else None  # none yet on this line
            return lim.state_fault(pos[0], pos[1], last, max(rx - s.rx, stamp - s.stamp, 0.0))
        return None

    def _reject(self, reason: str) -> bool:
        self.dropped += 1
        self.rejected[reason] += 1
        return False

    def new_timeline(self) -> bool:
        """A stream's last :data:`.plausibility.TIMELINE_SAMPLES` samples agree on a time line that is not its own."""
        return max(self.att.cand_n, self.pos.cand_n) >= TIMELINE_SAMPLES

    def take_notes(self) -> list[str]:
        """The notes since the last call (re-lined time lines), for the owner's events."""
        notes, self.notes = self.notes, []
        return notes

    @staticmethod
    def _tick(s: Sample, stamp: float, rx: float) -> None:
        if not stamp <= s.stamp:  # advanced (or the first): one more sample for the line
            s.line_n += 1
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

    def restart(self, msg, rx: float) -> bool:
        """A reboot: forget the newest samples, each stream on its candidate time line (what its samples agreed on,
        confirmed as far as they advanced), and fold ``msg`` (the sample that completed the new time line, counted
        as dropped a moment ago: uncounted) in as the first of it."""
        self.dropped -= 1
        self.rejected["stamp"] -= 1
        self.att, self.pos = self.att.new_line(), self.pos.new_line()
        self.contact, self.contact_value, self.contact_stamp = None, None, math.nan
        return self.update(msg, rx)


_FIELDS = {
    "ODOMETRY": ("x", "y", "z", "vx", "vy", "vz", "rollspeed", "pitchspeed", "yawspeed"),
    "LOCAL_POSITION_NED": ("x", "y", "z", "vx", "vy", "vz"),
    "ATTITUDE": ("roll", "pitch", "yaw", "rollspeed", "pitchspeed", "yawspeed"),
    "ATTITUDE_QUATERNION": ("q1", "q2", "q3", "q4", "rollspeed", "pitchspeed", "yawspeed"),
}


def _plausible(msg, typ: str) -> bool:
    """Every field the state uses is finite, and a quaternion has (nearly) unit norm."""
    vals = [getattr(msg, k) for k in _FIELDS[typ]]
    q = list(msg.q) if typ == "ODOMETRY" else vals[:4] if typ == "ATTITUDE_QUATERNION" else None
    if q is not None:
        vals += q
    if not all(math.isfinite(v) for v in vals):
        return False
    return q is None or abs(math.sqrt(sum(v * v for v in q)) - 1.0) < 0.1


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
        self.point(st.position)
        if self.mode == "world":
            return st
        c, s = self._c, self._s
        vx, vy = st.velocity[0], st.velocity[1]
        st.velocity[0], st.velocity[1] = c * vx + s * vy, -s * vx + c * vy
        st.euler[2] = wrap_pi(st.euler[2] - self.yaw0)
        return st

    def point(self, p: np.ndarray) -> np.ndarray:
        """A local-ENU position (3,) [m] in the trajectory frame (in place; returns it)."""
        p[2] -= self.z0
        if self.mode == "world":
            return p
        c, s = self._c, self._s
        dx, dy = p[0] - self.origin[0], p[1] - self.origin[1]
        p[0], p[1] = self.anchor[0] + c * dx + s * dy, self.anchor[1] - s * dx + c * dy
        return p

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
