"""What goes out each tick: the attitude setpoints the loop makes besides the controller's (the level hover
setpoint of the stale action, the idle ground setpoint), and the SET_ATTITUDE_TARGET stream (send times, the
last message for repeats, how long the stream has run: PX4 wants a live stream before it accepts OFFBOARD)."""

from __future__ import annotations

import math
import time

from ddpc_codegen.robot.frames import quat_ned_frd_from_enu_flu

from firmware_bridge.link import mavlink
from firmware_bridge.profiles import Profile
from firmware_bridge.telemetry import TrajectoryFrame
from firmware_bridge.vehicle_link import VehicleLink

__all__ = ["AttitudeSetpoints", "SetpointStream"]

# Body rates ignored: attitude + thrust (= 7).
_TYPE_MASK = (mavlink.ATTITUDE_TARGET_TYPEMASK_BODY_ROLL_RATE_IGNORE
              | mavlink.ATTITUDE_TARGET_TYPEMASK_BODY_PITCH_RATE_IGNORE
              | mavlink.ATTITUDE_TARGET_TYPEMASK_BODY_YAW_RATE_IGNORE)

Setpoint = tuple[tuple, float, float]  # (q NED/FRD (w, x, y, z), thrust [0..1], the message's thrust field)


class AttitudeSetpoints:
    """Attitude setpoints in the vehicle's frame.

    Args:
        frame: the trajectory frame (its heading turns a trajectory-frame attitude into the world's).
        profile: the autopilot's thrust-field semantics.
        hover_thrust: the controller model's hover thrust [0..1].
        thrust_min, thrust_max: the thrust clamps [0..1].
    """

    def __init__(self, frame: TrajectoryFrame, profile: Profile, hover_thrust: float, thrust_min: float,
                 thrust_max: float) -> None:
        self.frame = frame
        self.profile = profile
        self.hover_thrust = hover_thrust
        self.thrust_min, self.thrust_max = thrust_min, thrust_max

    def to_vehicle(self, q_enu) -> tuple:
        """A trajectory-frame ENU/FLU attitude as the world's NED/FRD quaternion."""
        return quat_ned_frd_from_enu_flu(self.frame.to_world(q_enu))

    def level(self) -> Setpoint:
        """Level attitude at the trajectory frame's heading and hover thrust / zero climb rate."""
        thrust = min(max(self.hover_thrust, self.thrust_min), self.thrust_max)
        return self.to_vehicle((1.0, 0.0, 0.0, 0.0)), thrust, self.profile.hover_field(thrust)

    def ground(self, z: float) -> Setpoint:
        """Level, idle thrust (the lower clamp) / zero climb rate: what a disarmed vehicle is sent.
        A vehicle left in OFFBOARD by the previous flight (PX4 returns to it after LAND and disarm)
        flies the streamed setpoint the moment our ARM is accepted, up to a heartbeat (1 s) before
        we know it is armed; the controller's thrust toward the trajectory start then throws it up
        (seen on PX4 SIH, with the heights' origin captured in the air)."""
        thrust = self.thrust_min
        return self.to_vehicle((1.0, 0.0, 0.0, 0.0)), thrust, self.profile.thrust_field(thrust, z, z)


class SetpointStream:
    """SET_ATTITUDE_TARGET out, with the stream's times.

    The stream's length is what the vehicle has seen: it starts again after a pause of the stream and after a
    reboot of the vehicle (its reboot count moved), which a lock-stepped stream need never pause for, and whose
    stamps are on a new time line.

    Args:
        vehicle: the link the setpoints go out on.
        lockstep: the stream's length counts in vehicle time (a lock-stepped vehicle's clock is not the wall's).
    """

    def __init__(self, vehicle: VehicleLink, lockstep: bool) -> None:
        self.vehicle = vehicle
        self.lockstep = lockstep
        self.send_times: list[float] = []   # monotonic [s] of each setpoint sent
        self.send_stamps: list[float] = []  # vehicle time of each (the clock that counts in lock-step) [s]
        self.last_msg = None                # last SET_ATTITUDE_TARGET (repeated by the hand-back)
        self.repeats = 0                    # repeats of it sent (not setpoints of a tick: not in send_times)
        self.last_send = -math.inf
        self.since = math.inf               # start of the current uninterrupted stream [s]
        self.since_stamp = math.nan         # ... in vehicle time [s], on the time line of ...
        self.since_boot = -1                # ... the vehicle's boot (its reboot count) the stream started in
        self.prev_t = -math.inf

    def send(self, q_ned: tuple, field: float, stamp_ms: int) -> bool:
        """Send one setpoint; True when it went out."""
        lk = self.vehicle.link
        msg = lk.mav.set_attitude_target_encode(
            stamp_ms & 0xFFFFFFFF, lk.target_system or 0, lk.target_component or 0, _TYPE_MASK,
            list(q_ned), 0.0, 0.0, 0.0, float(field))
        ok = lk.send(msg)
        self.last_msg = msg
        self.last_send = t = time.monotonic()
        if ok:
            self.send_times.append(t)
            self.send_stamps.append(self.vehicle.vehicle_now(t, self.lockstep))
            # Continuous streaming since when (PX4 wants a live stream before it accepts OFFBOARD).
            if (not math.isfinite(self.since) or t - self.prev_t > 0.5 or self._rebooted()
                    or (self.lockstep and not math.isfinite(self.since_stamp))):
                self.since = t
                self.since_stamp = self.vehicle.telem.newest_stamp()
                self.since_boot = self.vehicle.counts["reboots"]
            self.prev_t = t
        return ok

    def repeat_if_due(self, now: float, period: float) -> None:
        """Send the last setpoint again when a period has passed since the last send."""
        if now - self.last_send >= period and self.last_msg is not None:
            self.repeats += self.vehicle.link.send(self.last_msg)
            self.last_send = now

    def streaming(self, now: float) -> bool:
        """Setpoints flow now (the last within 0.1 s)."""
        return math.isfinite(self.since) and now - self.prev_t < 0.1

    def streamed(self, now: float) -> float:
        """How long the current stream has run [s] (lock-step: in vehicle time); 0 after a reboot until the
        next setpoint (none reached the vehicle since it came back)."""
        if self._rebooted():
            return 0.0
        if self.lockstep:
            return self.vehicle.telem.newest_stamp() - self.since_stamp
        return now - self.since

    def _rebooted(self) -> bool:
        """The vehicle rebooted since the current stream started (its time line is another)."""
        return math.isfinite(self.since) and self.vehicle.counts["reboots"] != self.since_boot
