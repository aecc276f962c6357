"""A motion-capture stand-in for the SITLs: the simulator's true pose, late and noisy like an optical
tracking system, sent to the autopilot as its external position source.

A lab flies a vehicle indoors on a motion-capture system (Vicon, OptiTrack, Qualisys): cameras see
markers on the frame, the system's software sends the pose at 100-200 Hz a few milliseconds after the
cameras exposed, with sub-millimetre to millimetre noise, and a companion forwards it to the autopilot
over MAVLink (VISION_POSITION_ESTIMATE or ODOMETRY), which fuses it as its position, height and yaw
source. :class:`MocapStandIn` does the same from a SITL's ground truth (ArduCopter SIM_STATE, PX4 SIH
HIL_STATE_QUATERNION, read through :class:`firmware_bridge.truth.SimTruth`):

* frame: local NED [m] from the first true position (where the vehicle stands: the floor's origin of
  the lab), north-aligned (a calibrated system's frame rotated to north, as both autopilots expect when
  they take the yaw from it);
* truth: refined below its message's grid and, on ArduCopter, placed on the autopilot's clock
  (:mod:`firmware_bridge.truth_refine`; PX4 SIH's on arrival);
* latency: every sent pose is the truth ``latency_s`` before the send, interpolated between the samples
  received;
* noise: white Gaussian on each position axis and attitude angle (and velocity, for ODOMETRY);
* rate: ``rate_hz`` sends per second from its own thread, whatever rate the truth arrives at.

The parameters that make each autopilot use it are in :mod:`.mocap_params`.
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ddpc_codegen.robot.frames import euler_ned_from_enu, ned_from_enu, quat_from_euler, rotate_inverse, wrap_pi
from firmware_bridge.truth import TRUTH_MESSAGES, SimTruth
from firmware_bridge.truth_refine import LinkClock

__all__ = ["MocapConfig", "MocapPose", "TruthBuffer", "MocapSampler", "MocapStandIn", "pose_from_truth",
           "vision_position_fields", "odometry_fields", "MESSAGES", "CLOCK_PARTNER"]

MESSAGES = ("vision_position", "odometry")
MAV_FRAME_LOCAL_NED = 1
_MAV_FRAME_BODY_FRD = 12
MAV_FRAME_LOCAL_FRD = 20  # ArduPilot takes ODOMETRY only in LOCAL_FRD / BODY_FRD (north-aligned here)
_ODOMETRY_FRAME = {"ardupilot": MAV_FRAME_LOCAL_FRD, "px4": MAV_FRAME_LOCAL_NED}
_MAV_ESTIMATOR_TYPE_MOCAP = 6
_ORIGIN_REPEATS = 60  # seconds over which SET_GPS_GLOBAL_ORIGIN is sent (once a second)
_TRUTH_INTERVAL_US = 5000  # ask for the truth at 200 Hz (each SITL sends what it has: 120-200/s)


@dataclass(frozen=True)
class MocapConfig:
    """How the stand-in measures and sends (defaults: a typical optical system).

    Attributes:
        rate_hz: poses sent per second.
        latency_s: age of each pose when sent [s] (camera exposure to the companion's send).
        pos_noise_m: standard deviation of each position axis [m].
        att_noise_rad: standard deviation of each Euler angle [rad].
        vel_noise_mps: standard deviation of each velocity axis [m/s] (ODOMETRY only).
        message: "vision_position" (VISION_POSITION_ESTIMATE) or "odometry" (ODOMETRY, with velocity).
        max_extrapolation_s: how far past the newest truth sample a pose may be extrapolated (its
            velocity); a longer truth gap sends nothing (a lab system that lost the markers).
        seed: the noise generator's seed (None: fresh entropy).
    """

    rate_hz: float = 120.0
    latency_s: float = 0.005
    pos_noise_m: float = 0.0005
    att_noise_rad: float = math.radians(0.1)
    vel_noise_mps: float = 0.005
    message: str = "vision_position"
    max_extrapolation_s: float = 0.05
    seed: int | None = None

    def __post_init__(self) -> None:
        if not self.rate_hz > 0:
            raise ValueError(f"rate_hz must be > 0; got {self.rate_hz}")
        if self.latency_s < 0 or self.pos_noise_m < 0 or self.att_noise_rad < 0 or self.vel_noise_mps < 0:
            raise ValueError("latency and noise must be >= 0")
        if self.message not in MESSAGES:
            raise ValueError(f"message must be one of {MESSAGES}; got {self.message!r}")


@dataclass(frozen=True)
class MocapPose:
    """One pose in the mocap frame (local NED from the first true position).

    Attributes:
        t: the instant it describes [s, the stand-in's monotonic clock].
        position: north, east, down [m]; velocity: NED [m/s]; euler: roll, pitch, yaw [rad] of body
            FRD w.r.t. NED.
    """

    t: float
    position: np.ndarray
    velocity: np.ndarray
    euler: np.ndarray


def pose_from_truth(truth: SimTruth, t: float) -> MocapPose:
    """The newest sample of ``truth`` (local ENU / FLU from its origin) as a NED / FRD pose at ``t`` [s]."""
    return MocapPose(t, np.array(ned_from_enu(truth.position)), np.array(ned_from_enu(truth.velocity)),
                     np.array(euler_ned_from_enu(truth.euler)))


class TruthBuffer:
    """The last ``horizon_s`` seconds of true poses, read at any instant by interpolation."""

    def __init__(self, horizon_s: float = 1.0, max_extrapolation_s: float = 0.05):
        self.horizon_s, self.max_extrapolation_s = horizon_s, max_extrapolation_s
        self._poses: deque[MocapPose] = deque()

    def __len__(self) -> int:
        return len(self._poses)

    def add(self, pose: MocapPose) -> None:
        """Append a pose (times non-decreasing; an older one is dropped) and forget those past the horizon."""
        if self._poses and pose.t < self._poses[-1].t:
            return
        self._poses.append(pose)
        while self._poses and self._poses[0].t < pose.t - self.horizon_s:
            self._poses.popleft()

    def at(self, t: float) -> MocapPose | None:
        """The pose at ``t`` [s]: interpolated between the samples around it, extrapolated along the newest
        sample's velocity up to ``max_extrapolation_s`` past it; None before the first sample or further on."""
        p = self._poses
        if not p or t < p[0].t or t > p[-1].t + self.max_extrapolation_s:
            return None
        if t >= p[-1].t:
            last = p[-1]
            return MocapPose(t, last.position + (t - last.t) * last.velocity, last.velocity.copy(), last.euler.copy())
        i = len(p) - 1
        while p[i - 1].t > t:  # newest first: the asked instant is a few samples back
            i -= 1
        a, b = p[i - 1], p[i]
        w = 0.0 if b.t == a.t else (t - a.t) / (b.t - a.t)
        d_euler = np.array([wrap_pi(v) for v in b.euler - a.euler])
        euler = np.array([wrap_pi(v) for v in a.euler + w * d_euler])
        return MocapPose(t, a.position + w * (b.position - a.position), a.velocity + w * (b.velocity - a.velocity),
                         euler)


# ArduCopter sends the truth in bursts (TCP; 0-23 ms after its loop sent them, measured); ATTITUDE, asked at the
# truth's rate, leaves in the same loop and arrives beside it (SIM_STATE within 0.3 ms of it): the stand-in places the
# truth on its time (:class:`~firmware_bridge.truth_refine.LinkClock`). PX4 SIH sends no such pair.
CLOCK_PARTNER = {"ardupilot": ("ATTITUDE", 30)}


class MocapSampler:
    """The stand-in's measurement, without I/O: truth messages in, late noisy poses out.

    Args:
        config: rate, latency, noise.
    """

    def __init__(self, config: MocapConfig):
        self.config = config
        self.truth = SimTruth()
        self.buffer = TruthBuffer(max_extrapolation_s=config.max_extrapolation_s)
        self.rng = np.random.default_rng(config.seed)

    def feed(self, msg: Any, rx: float) -> None:
        """Fold in one SIM_STATE / HIL_STATE_QUATERNION of the instant ``rx`` [s]; its position refined below the
        message's grid with its velocity (by :class:`~firmware_bridge.truth.SimTruth`, as the bridge logs it)."""
        seq = self.truth.seq
        self.truth.update(msg, rx)
        if self.truth.seq != seq:
            self.buffer.add(pose_from_truth(self.truth, rx))

    def sample(self, now: float) -> MocapPose | None:
        """The measurement sent at ``now`` [s]: the truth at ``now - latency_s`` plus noise (None without truth)."""
        c = self.config
        pose = self.buffer.at(now - c.latency_s)
        if pose is None:
            return None
        return MocapPose(pose.t, pose.position + self.rng.normal(0.0, c.pos_noise_m, 3) if c.pos_noise_m else pose.position,
                         pose.velocity + self.rng.normal(0.0, c.vel_noise_mps, 3) if c.vel_noise_mps else pose.velocity,
                         np.array([wrap_pi(v) for v in pose.euler + self.rng.normal(0.0, c.att_noise_rad, 3)])
                         if c.att_noise_rad else pose.euler)

    @property
    def origin(self) -> tuple[float, float, float] | None:
        """The mocap frame's origin: latitude, longitude [deg], altitude [m AMSL] (None before any truth)."""
        t = self.truth
        return (t.lat0, t.lon0, t.alt0) if t.present else None


def _covariance(variances: list[float]) -> list[float]:
    """Upper triangle (21,) of the diagonal 6x6 covariance with ``variances`` (6,) on its diagonal."""
    cov = [0.0] * 21
    for k, v in zip((0, 6, 11, 15, 18, 20), variances):
        cov[k] = v
    return cov


def _pose_covariance(config: MocapConfig) -> list[float]:
    return _covariance([config.pos_noise_m ** 2] * 3 + [config.att_noise_rad ** 2] * 3)


def vision_position_fields(pose: MocapPose, usec: int, config: MocapConfig, reset_counter: int = 0) -> dict:
    """The fields of VISION_POSITION_ESTIMATE (NED position [m], roll / pitch / yaw [rad], covariance)."""
    x, y, z = (float(v) for v in pose.position)
    r, p, yw = (float(v) for v in pose.euler)
    return {"usec": int(usec), "x": x, "y": y, "z": z, "roll": r, "pitch": p, "yaw": yw,
            "covariance": _pose_covariance(config), "reset_counter": reset_counter}


def odometry_fields(pose: MocapPose, usec: int, config: MocapConfig, frame_id: int = MAV_FRAME_LOCAL_FRD,
                    reset_counter: int = 0) -> dict:
    """The fields of ODOMETRY: position in ``frame_id`` (LOCAL_FRD, north-aligned, for ArduPilot, which takes
    no other; LOCAL_NED for PX4), attitude quaternion FRD -> NED, velocity in BODY_FRD (what both read with
    that child frame), rates unknown (nan)."""
    q = quat_from_euler(*pose.euler)
    v_body = rotate_inverse(q, pose.velocity)
    nan = float("nan")
    return {"time_usec": int(usec), "frame_id": frame_id, "child_frame_id": _MAV_FRAME_BODY_FRD,
            "x": float(pose.position[0]), "y": float(pose.position[1]), "z": float(pose.position[2]),
            "q": [float(v) for v in q], "vx": float(v_body[0]), "vy": float(v_body[1]), "vz": float(v_body[2]),
            "rollspeed": nan, "pitchspeed": nan, "yawspeed": nan, "pose_covariance": _pose_covariance(config),
            "velocity_covariance": _covariance([config.vel_noise_mps ** 2] * 3 + [nan] * 3), "reset_counter": reset_counter,
            "estimator_type": _MAV_ESTIMATOR_TYPE_MOCAP, "quality": 100}


@dataclass
class MocapStats:
    """What the stand-in did: poses sent, truth samples received, sends skipped for lack of truth, origins sent."""

    sent: int = 0
    truth: int = 0
    skipped: int = 0
    origin_sent: int = 0
    errors: list[str] = field(default_factory=list)


class MocapStandIn(threading.Thread):
    """Reads the SITL's truth on ``conn`` and sends the mocap stream back on it, at ``config.rate_hz``,
    until :meth:`stop`. ``conn``: a pymavlink connection of its own (the thread reads it), MAVLink 2,
    ``target_system`` / ``target_component`` the autopilot's; ``autopilot``: "ardupilot" or "px4" (which
    truth message to ask for). ``set_origin``: send SET_GPS_GLOBAL_ORIGIN at the first truth (the mocap
    frame's origin); None: for ArduPilot only, which needs it without GPS to arm in its position modes (PX4
    flies OFFBOARD on its local position without one). ``forward``: a second pymavlink connection the same
    poses also go to (a lab companion's own copy of the stream: ``ddpc-bridge --mocap``)."""

    def __init__(self, conn: Any, autopilot: str, config: MocapConfig | None = None, *,
                 set_origin: bool | None = None, forward: Any | None = None):
        super().__init__(daemon=True, name=f"mocap-{autopilot}")
        self.conn, self.autopilot, self.forward = conn, autopilot, forward
        self.config = config or MocapConfig()
        self.sampler = MocapSampler(self.config)
        self.set_origin = autopilot == "ardupilot" if set_origin is None else set_origin
        self.stats = MocapStats()
        self.clock_partner = CLOCK_PARTNER.get(autopilot)
        self.clock = LinkClock() if self.clock_partner is not None else None
        self._halt = threading.Event()
        self._admin_ticks = 0

    def stop(self, timeout: float = 2.0) -> None:
        """End the thread (the connection stays open: its owner closes it)."""
        self._halt.set()
        if self.is_alive():
            self.join(timeout)

    def run(self) -> None:
        msg_name, msg_id = TRUTH_MESSAGES[self.autopilot]
        types = [msg_name, *((self.clock_partner[0],) if self.clock is not None else ())]
        period = 1.0 / self.config.rate_hz
        next_send = next_admin = time.monotonic()
        try:
            while not self._halt.is_set():
                now = time.monotonic()
                if now >= next_admin:  # heartbeat and the truth stream request, each second
                    next_admin = now + 1.0
                    self._admin(msg_id)
                if now >= next_send:
                    next_send += period
                    if next_send < now:  # late (a loaded machine): skip, do not burst
                        next_send = now + period
                    self._send(now)
                msg = self.conn.recv_match(type=types, blocking=True, timeout=max(0.0, min(next_send, next_admin)
                                                                                 - time.monotonic()))
                if msg is not None:
                    self._receive(msg, time.monotonic())
        except Exception as e:  # noqa: BLE001 - a dead link ends the stream; the owner reads why
            self.stats.errors.append(f"{type(e).__name__}: {e}")

    def _receive(self, msg: Any, rx: float) -> None:
        """A truth or clock message received at ``rx`` [s]: the truth into the sampler, on the autopilot's clock where
        the link has one (:class:`LinkClock`)."""
        for m, t in [(msg, rx)] if self.clock is None else self.clock.place(msg, rx, self.clock_partner[0]):
            self.sampler.feed(m, t)
            self.stats.truth += 1
            if self.stats.origin_sent == 0:
                self._send_origin()  # at the first truth, not a second later

    def _admin(self, msg_id: int) -> None:
        mav = self.conn.mav
        mav.heartbeat_send(18, 8, 0, 0, 0)  # MAV_TYPE_ONBOARD_CONTROLLER, MAV_AUTOPILOT_INVALID
        if self.stats.truth == 0 or self._admin_ticks % 5 == 0:
            for mid in (msg_id, *((self.clock_partner[1],) if self.clock is not None else ())):
                mav.command_long_send(self.conn.target_system, self.conn.target_component, 511, 0, mid,
                                      _TRUTH_INTERVAL_US, 0, 0, 0, 0, 0)  # MAV_CMD_SET_MESSAGE_INTERVAL
        self._admin_ticks += 1
        self._send_origin()

    def _send_origin(self) -> None:
        """SET_GPS_GLOBAL_ORIGIN at the mocap frame's origin: ArduPilot each second for the first minute (an EKF
        still initialising drops it; it keeps the first it accepts), PX4 once (each one moves its local frame)."""
        origin = self.sampler.origin
        repeats = _ORIGIN_REPEATS if self.autopilot == "ardupilot" else 1
        if not self.set_origin or origin is None or self.stats.origin_sent >= repeats:
            return
        lat, lon, alt = origin
        if self.autopilot == "ardupilot":
            # whole metres: ArduPilot keeps the origin's height in centimetres and reads it back through a
            # float (584.09 m -> 584.08 m), which shifts its local height by a centimetre
            alt = float(round(alt))
        self.conn.mav.set_gps_global_origin_send(self.conn.target_system, int(round(lat * 1e7)),
                                                 int(round(lon * 1e7)), int(round(alt * 1e3)))
        self.stats.origin_sent += 1

    def _send(self, now: float) -> None:
        pose = self.sampler.sample(now)
        if pose is None:
            self.stats.skipped += 1
            return
        usec = int(round(pose.t * 1e6))  # the measurement instant on this clock (each autopilot maps it to its own)
        for conn in (self.conn, self.forward) if self.forward is not None else (self.conn,):
            if self.config.message == "odometry":
                conn.mav.odometry_send(**odometry_fields(pose, usec, self.config, _ODOMETRY_FRAME[self.autopilot]))
            else:
                conn.mav.vision_position_estimate_send(**vision_position_fields(pose, usec, self.config))
        self.stats.sent += 1
