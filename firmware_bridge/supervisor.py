"""The bridge's vehicle side: messages in (heartbeat, acks, parameters, status text), preflight,
engagement edges, arming and mode requests, the hand-back at exit (a mixin of :class:`.bridge.Bridge`)."""

from __future__ import annotations

import math
import time

from firmware_bridge.bridge_config import NoVehicleError
from firmware_bridge.link import mavlink
from firmware_bridge.engagement import Approach
from firmware_bridge.hopping_loop import completion_time_warning
from firmware_bridge.preflight import (VehicleInfo, check_autopilot, check_solver_loop, decode_param_value,
                                       hover_param, params_to_read, resolve_guid_options)
from firmware_bridge.profiles import ArduPilotProfile
from firmware_bridge.truth import TRUTH_MESSAGES

__all__ = ["Supervisor"]

_MSG_IDS = {
    "ATTITUDE": mavlink.MAVLINK_MSG_ID_ATTITUDE,
    "ATTITUDE_QUATERNION": mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION,
    "LOCAL_POSITION_NED": mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED,
    "ODOMETRY": mavlink.MAVLINK_MSG_ID_ODOMETRY,
}


class Supervisor:
    """Vehicle state, preflight, engagement, arming / modes (mixed into :class:`.bridge.Bridge`)."""

    def _on_message(self, msg, rx: float) -> None:
        typ = msg.get_type()
        if typ in self.telem.wanted:
            tel = self.telem
            before = (tel.att.stamp, tel.pos.stamp)
            if not tel.update(msg, rx):
                return  # the contact flag: kept, not a state sample
            self.last_heard = rx
            if before[0] - tel.att.stamp > 1.0 or before[1] - tel.pos.stamp > 1.0:
                # Vehicle clock went back: it rebooted. Forget its state and ask for the streams again.
                self.counts["reboots"] += 1
                self._event(f"vehicle time went back ({max(before):.3f} s -> {tel.newest_stamp():.3f} s): "
                            "reboot, re-requesting streams")
                self.telem.reset()
                self.telem.update(msg, rx)
                self._last_seq = (0, 0)
                self._t_offset = math.inf
                self._request_streams()
            new = self.telem.newest_stamp()
            off = rx - new
            # Vehicle clock estimate: minimum of (receive - stamp), slowly forgetting (clock drift).
            self._t_offset = min(self._t_offset + 1e-5, off) if math.isfinite(self._t_offset) else off
        elif typ == "HEARTBEAT":
            vm = self.profile.decode(msg.base_mode, msg.custom_mode)
            if not self.hb_seen:
                self.hb_autopilot, self.hb_type = int(msg.autopilot), int(msg.type)
                self._event(f"vehicle heartbeat: sysid {msg.get_srcSystem()}, autopilot {msg.autopilot}, "
                            f"{vm.name}, armed={vm.armed}")
            elif self._link_lost or rx - self.last_heard > self.cfg.link_timeout:
                self._event("vehicle heartbeat back: link restored, re-requesting streams")
                self._request_streams()
            if self.hb_seen and (vm.armed != self.armed or vm.name != self.mode_name):
                self._event(f"vehicle {vm.name}, armed={vm.armed}")
            self.hb_seen = True
            self.last_hb = self.last_heard = rx
            self.armed, self.offboard, self.mode_name = vm.armed, vm.offboard, vm.name
        elif typ == "COMMAND_ACK":
            pc = self.tracker.on_ack(msg)
            if pc is not None and pc.command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM and not pc.accepted:
                self._event(self.arming.refused(mavlink.enums["MAV_RESULT"][pc.result].name, self._last_text))
            elif pc is not None and (self.cfg.verbose or not pc.accepted):
                self._event(f"{pc.label}: {mavlink.enums['MAV_RESULT'][pc.result].name}")
        elif typ == "PARAM_VALUE":
            name = msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode(errors="ignore")
            name = name.rstrip("\x00")
            self.params[name] = decode_param_value(msg.param_value, msg.param_type, self.hb_autopilot or 0)
            if name == "COM_OF_LOSS_T":
                self.profile.offboard_loss_timeout = float(msg.param_value)
        elif typ in ("SIM_STATE", "HIL_STATE_QUATERNION"):
            self.truth.update(msg, rx)
        elif typ == "STATUSTEXT":
            self._last_text = str(msg.text).rstrip("\x00")  # the autopilot's reason for a refusal
            if self.cfg.verbose:
                self._event(f"vehicle says: {msg.text}")

    def _request_streams(self) -> None:
        us = int(round(1e6 / self.cfg.rate_hz))
        for name in sorted({self.cfg.attitude_stream, self.cfg.position_stream}):
            self.tracker.submit(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, (float(_MSG_IDS[name]), float(us)),
                                f"SET_MESSAGE_INTERVAL {name} {self.cfg.rate_hz:g} Hz")
        # The simulator's truth, logged beside the EKF (SITL only: a real vehicle refuses it or, PX4 without
        # ground truth, sends nothing): ArduPilot's SIM_STATE, PX4 SIH's HIL_STATE_QUATERNION.
        name, msg_id = TRUTH_MESSAGES["ardupilot" if isinstance(self.profile, ArduPilotProfile) else "px4"]
        self.tracker.submit(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, (float(msg_id), float(us)),
                            f"SET_MESSAGE_INTERVAL {name} {self.cfg.rate_hz:g} Hz (SITL truth)")
        self.counts["stream_requests"] += 1

    def _preflight(self, timeout: float = 3.0) -> None:
        """Before the first tick: the heartbeat's autopilot, the parameters, the thrust semantics.

        Raises:
            PreflightError: wrong autopilot, or a required parameter / a consistent GUID_OPTIONS missing.
        """
        c = self.cfg
        check_autopilot(self.hb_autopilot, self.profile)
        wanted = params_to_read(self.profile)
        t_end = time.monotonic() + timeout
        next_ask = 0.0
        while not self._stop and time.monotonic() < t_end and any(n not in self.params for n in wanted):
            if time.monotonic() >= next_ask:
                next_ask = time.monotonic() + 0.5
                for n in wanted:
                    if n not in self.params:
                        self._request_param(n)
            self.link.wait(0.05)
            for msg, rx in self.link.drain():
                self._on_message(msg, rx)
        missing = [n for n, req in wanted.items() if n not in self.params and not req]
        if missing:
            self._event(f"parameters not answered within {timeout:g} s: {', '.join(missing)} (not needed)")
        hover = self.params.get(hover_param(self.profile))
        self.vehicle = VehicleInfo(self.hb_autopilot, self.hb_type, dict(self.params), hover)
        if isinstance(self.profile, ArduPilotProfile):
            opt = resolve_guid_options(self.params.get("GUID_OPTIONS"), c.guid_options, c.force_guid_options)
            self.profile.guid_options = opt
            self._event(f"GUID_OPTIONS={opt}: thrust field is a "
                        + ("climb rate" if self.profile.climb_rate_thrust else "thrust"))
        solver = getattr(self, "solver", None)
        if solver is not None:
            field = "climb_rate" if self.profile.climb_rate_thrust else "thrust"
            warning = check_solver_loop(solver.manifest, self.profile.name, field)
            if warning:
                self._event(f"warning: {warning}")
        hop = getattr(self, "hop", None)
        if hop is not None and hop.steering is not None and hop.steering.window is not None:
            slow = completion_time_warning(hop.steering.window.art, c.rate_hz)
            if slow:
                self._event(f"warning: {slow}")
        self._event(f"vehicle: {self.profile.name}, hover thrust {hover_param(self.profile)}="
                    + ("?" if hover is None else f"{hover:.3f}")
                    + f", controller model hover thrust {self.hover_thrust:.3f}")

    def _request_param(self, name: str) -> None:
        self.link.send(self.link.mav.param_request_read_encode(self.link.target_system or 0,
                                                               self.link.target_component or 0, name.encode(), -1))

    def _wait_for_vehicle(self) -> None:
        c = self.cfg
        t_end = time.monotonic() + c.wait_heartbeat
        next_hb = 0.0
        while not self.hb_seen and not self._stop:
            now = time.monotonic()
            if now > t_end:
                raise NoVehicleError(f"no heartbeat from system {c.target_system} on {self.link.endpoint} "
                                     f"within {c.wait_heartbeat:g} s")
            if now >= next_hb:
                next_hb = now + 1.0
                self.link.send_heartbeat()  # udpout: lets a udpin vehicle learn our address
            self.link.poll(now)
            self.link.wait(0.05)
            for msg, rx in self.link.drain():
                self._on_message(msg, rx)

    def _check_staleness(self, now: float, age: float, fresh: bool, event: bool) -> bool:
        """Staleness bookkeeping; False when the stream limit says to go quiet (no setpoint)."""
        c = self.cfg
        if fresh:
            if self._stale_since is not None:
                self._event(f"telemetry fresh again after {now - self._stale_since:.3f} s")
                self._fresh_again = True  # resume bumplessly (see _update_engagement)
            self._stale_since = None
            return True
        if self._stale_since is None:
            self._stale_since = now
            self._event(f"telemetry stale (age {age * 1e3:.1f} ms > {c.max_age * 1e3:.0f} ms): fallback "
                        f"'{c.stale_action}'")
        if c.stale_stream_limit > 0 and now - self._stale_since > c.stale_stream_limit:
            if event:
                self._last_seq = (self.telem.att.seq, self.telem.pos.seq)
            self._last_send = now  # quiet: the autopilot's own failsafe takes over
            return False
        return True

    def _lockstep_gap(self, stamp: float) -> tuple[bool, int]:
        """Lock-step only (stamps are the tick clock there): (gap, ticks to bridge in the history)."""
        tel = self.telem
        self._last_seq = (tel.att.seq, tel.pos.seq)
        step = stamp - self._last_stamp
        self._last_stamp = stamp
        if not (math.isfinite(step) and abs(step - self.period) > 0.4 * self.period):
            return False, 0
        self.counts["telemetry_gaps"] += 1
        r = step / self.period
        n = int(round(r)) - 1
        if 1 <= n <= self.cfg.max_gap_fill and abs(r - round(r)) < 0.4:
            return True, n  # a few samples lost: bridged once this tick's y is known
        self._reset_steering()  # a long hole, or time went backwards: refill before steering again
        return True, 0

    def _update_engagement(self, engaged: bool, tclk: float, state) -> None:
        """Engagement edges. The first one starts the trajectory (or the take-off ramp); later ones
        continue the same trajectory, clock and frame. Each starts a bumpless blend."""
        c = self.cfg
        if engaged and not self._engaged:
            self._n_activations += 1
            self._was_engaged_ever = True
            self._reset_steering()
            if c.blend_rates:
                self.blend.start(self.ctrl.outputs(state))
            if not self._flown:
                self._flown = True
                self._traj_t0 = tclk
                if self.hop is not None:
                    self.hop.release(state)
                if c.takeoff:
                    self.approach = Approach(self.ctrl.trajectory.start_point()[1], climb_rate=c.climb_rate,
                                             tolerance=c.approach_tolerance, max_extra=c.approach_timeout)
                    self.approach.start(float(state.position[2]))
                self._event(f"engaged ({self.mode_name}, armed): "
                            + (f"take-off to z = {self.approach.target:.2f} m at {c.climb_rate:g} m/s, then "
                               if self.approach else "")
                            + f"trajectory starts, {c.mode}; {self.frame.describe()}")
            else:
                self._event(f"re-engaged ({self.mode_name}): trajectory continues at t = "
                            f"{tclk - self._traj_t0:.3f} s, same frame")
        elif engaged and self._fresh_again and self._flown:
            # Still engaged, but the telemetry was stale (a stall): the vehicle moved, or, frozen with
            # its autopilot, did not, while the trajectory clock ran on. Resume as at a re-engagement
            # (same clock and frame), the reference rate-limited from where it stood relative to the
            # measured outputs at the last fresh tick: a frozen vehicle gets its last fresh setpoint
            # again (no thrust kick from the tracking error it had), a moved one the same offset.
            self._reset_steering()  # hopping: its (u, y, phase) history too
            if c.blend_rates and self.approach is None:
                off = 0.0 if self._ref_offset is None else self._ref_offset
                self.blend.start(self.ctrl.outputs(state) + off)
            self._event(f"resumed after stale telemetry: trajectory continues at t = {tclk - self._traj_t0:.3f} s, "
                        "same frame")
        elif not engaged and self._engaged:
            self._event("disengaged: vehicle no longer armed + off-board (or link lost)")
        self._fresh_again = False
        self._engaged = engaged
        if engaged and self.approach is not None:
            self._traj_t0 = tclk  # the trajectory clock waits at its start until the vehicle is there

    # ------------------------------------------------------------------ arming / modes
    def _supervise(self, now: float) -> None:
        c = self.cfg
        if not self.hb_seen:
            return
        self._supervise_arming(now)
        streaming = math.isfinite(self._stream_since) and now - self._prev_stream_t < 0.1
        # Lockstep: "1 s of setpoints" in vehicle time (wall time runs much faster or slower there).
        streamed = (self.telem.newest_stamp() - self._stream_since_stamp) if c.lockstep else now - self._stream_since
        if (c.offboard and not self.offboard and not self._was_engaged_ever and streaming
                and streamed >= self.profile.prestream and (self.armed or not c.arm or not self.profile.arm_first)
                and now >= self._next_offboard_try and self._offboard_attempts < 5
                and not self.tracker.queues.get(mavlink.MAV_CMD_DO_SET_MODE)):
            self._offboard_attempts += 1
            self._next_offboard_try = now + 1.0
            params = self.profile.offboard_command()
            self._event(f"requesting {self.profile.mode_command_name(params)} after "
                        f"{streamed:.2f} s of setpoints (--offboard)")
            self.tracker.submit(mavlink.MAV_CMD_DO_SET_MODE, params, f"DO_SET_MODE {self.profile.mode_command_name(params)}")
        if c.duration is not None and self._engaged and self._traj_t0 is not None:
            if self._tick_t - self._traj_t0 >= c.duration - 1e-9:
                self.stop_reason = f"duration {c.duration:g} s flown"
                self._stop = True
        if c.timeout is not None and now - self.t0 > c.timeout:
            self.stop_reason = self.stop_reason or f"timeout {c.timeout:g} s"
            self._stop = True
        # The link lives while the vehicle is heard at all: PX4 sends its heartbeat once a second, so
        # after a 2 s stall the next one can be 4 s after the last, while telemetry is already back.
        if self.hb_seen and now - self.last_heard > c.link_timeout and not self._link_lost:
            self._link_lost = True
            self.counts["link_losses"] += 1
            self._event(f"vehicle silent (no heartbeat, no telemetry) for {c.link_timeout:g} s: link lost")
        elif now - self.last_heard <= c.link_timeout:
            self._link_lost = False
        if self._link_lost and now - self.last_heard > c.vehicle_lost_timeout:
            # Waiting on for --timeout would hide it: the flight is over, and the exit code says so (7).
            self._event(f"vehicle lost: nothing heard for {now - self.last_heard:.1f} s: stopping")
            self.stop_reason = "vehicle lost"
            self._stop = True

    def _supervise_arming(self, now: float) -> None:
        """--arm: once both telemetry streams arrive (and, for ArduPilot, in the guided mode), arm;
        retry while refused; give up with :class:`FlightError` after ``arm_timeout``."""
        c = self.cfg
        if not c.arm or self.armed or self._was_engaged_ever:
            return
        if self.arming.gave_up(now):
            self.failure = self.arming.failure()
            self.stop_reason = "arming failed"
            self._stop = True
            return
        ready = (self.telem.has_data and (self.profile.arm_first or self.offboard)
                 and not self.tracker.queues.get(mavlink.MAV_CMD_COMPONENT_ARM_DISARM))
        if self.arming.due(now, ready):
            self.arming.sent(now)
            self._event(f"arming (--arm), attempt {self.arming.attempts}")
            self.tracker.submit(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, (1.0,), "ARM")

    def _request_land(self) -> None:
        if self.cfg.offboard and not self._stale_mode_sent:
            self._stale_mode_sent = True
            params = self.profile.land_command()
            self._event(f"stale telemetry: requesting {self.profile.mode_command_name(params)}")
            self.tracker.submit(mavlink.MAV_CMD_DO_SET_MODE, params, f"DO_SET_MODE {self.profile.mode_command_name(params)}")

    def _shutdown(self) -> None:
        """With --offboard: hand the vehicle to HOLD before going quiet (setpoints keep flowing meanwhile)."""
        c = self.cfg
        if not (c.offboard and self.offboard and self.armed):
            return
        params = self.profile.land_command() if c.land else self.profile.hold_command()
        self._event(f"exit: requesting {self.profile.mode_command_name(params)}")
        pc = self.tracker.submit(mavlink.MAV_CMD_DO_SET_MODE, params, f"DO_SET_MODE {self.profile.mode_command_name(params)}")
        t_end = time.monotonic() + (60.0 if c.land else 1.5)
        self._stop = False
        # LAND: until the vehicle has landed and disarmed itself; HOLD: until acknowledged.
        while time.monotonic() < t_end and not ((not self.armed) if c.land else pc.done):
            now = time.monotonic()
            self.link.wait(max(0.0, min(0.05, self._last_send + self.period - now)))
            for msg, rx in self.link.drain():
                self._on_message(msg, rx)
            now = time.monotonic()
            if now - self._last_send >= self.period and self._last_msg is not None:
                self.link.send(self._last_msg)
                self._last_send = now
            self.tracker.poll(now)
        if c.land:
            self._event("landed and disarmed" if not self.armed else "LAND: still armed after 60 s")
        self._stop = True
