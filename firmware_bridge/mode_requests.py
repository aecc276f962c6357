"""The commands the companion loop sends the vehicle on its own: ARM once it can be armed (``--arm``), the
off-board / guided mode once the setpoints stream (``--offboard``), LAND on stale telemetry (stale action
"land"), and at exit the hand-back to HOLD or LAND. A vehicle that leaves off-board by itself (pilot,
failsafe) is not pulled back."""

from __future__ import annotations

import time

from firmware_bridge.link import mavlink
from firmware_bridge.setpoints import SetpointStream
from firmware_bridge.vehicle_link import VehicleLink

__all__ = ["ModeRequests"]


class ModeRequests:
    """When to arm and switch modes.

    Args:
        vehicle: the link; stream: the setpoint stream (its length gates the mode request).
        arm, offboard, land: the ``--arm`` / ``--offboard`` / ``--land`` flags.
    """

    def __init__(self, vehicle: VehicleLink, stream: SetpointStream, *, arm: bool, offboard: bool,
                 land: bool) -> None:
        self.vehicle = vehicle
        self.stream = stream
        self.arm, self.offboard, self.land = arm, offboard, land
        self.offboard_attempts = 0
        self.next_offboard_try = 0.0
        self.stale_mode_sent = False

    def _set_mode(self, params: tuple[float, ...], why: str):
        name = self.vehicle.profile.mode_command_name(params)
        self.vehicle.events(f"{why}: requesting {name}" if why else f"requesting {name}")
        return self.vehicle.command(mavlink.MAV_CMD_DO_SET_MODE, params, f"DO_SET_MODE {name}")

    def supervise(self, now: float, engaged_before: bool) -> str | None:
        """Arming and the mode request, off the tick path; the failure when arming gave up (else None).
        ``engaged_before``: the loop was engaged once (nothing is requested after that)."""
        v = self.vehicle
        st = v.status
        if not st.seen:
            return None
        failure = self._supervise_arming(now, engaged_before)
        streamed = self.stream.streamed(now)
        if (self.offboard and not st.offboard and not engaged_before and self.stream.streaming(now)
                and streamed >= v.profile.prestream and (st.armed or not self.arm or not v.profile.arm_first)
                and now >= self.next_offboard_try and self.offboard_attempts < 5
                and not v.pending(mavlink.MAV_CMD_DO_SET_MODE)):
            self.offboard_attempts += 1
            self.next_offboard_try = now + 1.0
            params = v.profile.offboard_command()
            v.events(f"requesting {v.profile.mode_command_name(params)} after {streamed:.2f} s of setpoints "
                     "(--offboard)")
            v.command(mavlink.MAV_CMD_DO_SET_MODE, params, f"DO_SET_MODE {v.profile.mode_command_name(params)}")
        return failure

    def _supervise_arming(self, now: float, engaged_before: bool) -> str | None:
        """--arm: once both telemetry streams arrive (and, for ArduPilot, in the guided mode), arm;
        retry while refused; the failure after ``arm_timeout``."""
        v = self.vehicle
        if not self.arm or v.status.armed or engaged_before:
            return None
        if v.arming.gave_up(now):
            return v.arming.failure()
        ready = (v.telem.has_data and (v.profile.arm_first or v.status.offboard)
                 and not v.pending(mavlink.MAV_CMD_COMPONENT_ARM_DISARM))
        if v.arming.due(now, ready):
            v.arming.sent(now)
            v.events(f"arming (--arm), attempt {v.arming.attempts}")
            v.command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, (1.0,), "ARM")
        return None

    def land_on_stale(self) -> None:
        """Stale action "land": ask for LAND once (with ``--offboard``)."""
        if self.offboard and not self.stale_mode_sent:
            self.stale_mode_sent = True
            self._set_mode(self.vehicle.profile.land_command(), "stale telemetry")

    def hand_back(self, period: float) -> None:
        """With --offboard: hand the vehicle to HOLD (LAND with --land) before going quiet; the last setpoint
        keeps flowing meanwhile."""
        v = self.vehicle
        if not (self.offboard and v.status.offboard and v.status.armed):
            return
        params = v.profile.land_command() if self.land else v.profile.hold_command()
        pc = self._set_mode(params, "exit")
        t_end = time.monotonic() + (60.0 if self.land else 1.5)
        # LAND: until the vehicle has landed and disarmed itself; HOLD: until acknowledged.
        while time.monotonic() < t_end and not ((not v.status.armed) if self.land else pc.done):
            now = time.monotonic()
            v.link.wait(max(0.0, min(0.05, self.stream.last_send + period - now)))
            v.pump()
            now = time.monotonic()
            self.stream.repeat_if_due(now, period)
            v.tracker.poll(now)
        if self.land:
            v.events("landed and disarmed" if not v.status.armed else "LAND: still armed after 60 s")
