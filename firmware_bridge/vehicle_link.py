"""The companion loop's vehicle side: one MAVLink vehicle as the loop sees it.

:class:`VehicleLink` wraps an open :class:`.link.MavLink` and folds every message into typed state:
telemetry (:class:`.telemetry.TelemetryState`), the simulator's truth, the heartbeat's arming and mode
(:class:`VehicleStatus`), parameters, command acknowledgements (with the arming retries' refusals), the
vehicle clock estimate. It requests the telemetry streams, reads the preflight parameters, notices a
reboot and a lost link (nothing heard).

A reboot needs consistent evidence, never one stamp: the telemetry's samples agree on a new time line
(:meth:`.telemetry.TelemetryState.new_timeline`) *and* the heartbeat says something happened to the
vehicle since its last accepted sample (it was silent past the link timeout, it moved to a new address,
or its armed state or mode changed). Then the telemetry is reset and the streams asked for again; a new
time line without that evidence stays dropped (stale telemetry, one event).
It knows nothing of trajectories or steering: any front end that talks to one vehicle can own one.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

from firmware_bridge.bridge_config import NoVehicleError
from firmware_bridge.engagement import ArmingRetry
from firmware_bridge.events import EventLog
from firmware_bridge.link import CommandTracker, MavLink, PendingCommand, mavlink
from firmware_bridge.preflight import VehicleInfo, check_autopilot, decode_param_value, hover_param, \
    params_to_read, resolve_guid_options
from firmware_bridge.profiles import ArduPilotProfile, Profile
from firmware_bridge.telemetry import TelemetryState
from firmware_bridge.truth import TRUTH_MESSAGES, SimTruth

__all__ = ["VehicleLink", "VehicleStatus"]

_MSG_IDS = {
    "ATTITUDE": mavlink.MAVLINK_MSG_ID_ATTITUDE,
    "ATTITUDE_QUATERNION": mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION,
    "LOCAL_POSITION_NED": mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED,
    "ODOMETRY": mavlink.MAVLINK_MSG_ID_ODOMETRY,
}


@dataclass
class VehicleStatus:
    """What the vehicle's heartbeats said (times on the bridge's monotonic clock [s])."""

    armed: bool = False
    offboard: bool = False
    mode_name: str = "?"
    autopilot: int | None = None
    vehicle_type: int = 0
    last_hb: float = -math.inf
    last_heard: float = -math.inf  # last heartbeat or telemetry sample
    seen: bool = False             # a heartbeat arrived


class VehicleLink:
    """One vehicle over MAVLink (see the module docstring).

    Args:
        link: the open connection; profile: the autopilot's mode and thrust conventions.
        telem: the telemetry state the samples are folded into.
        events: where events are recorded.
        rate_hz: the rate the telemetry streams are asked for [Hz].
        link_timeout: nothing heard for this long: the link is lost [s].
        arm_timeout: the arming retries give up after this long [s].
        verbose: report every acknowledgement and status text.
        on_reboot: called after a reboot was detected (the telemetry was reset).
    """

    def __init__(self, link: MavLink, profile: Profile, telem: TelemetryState, events: EventLog, *,
                 rate_hz: float, link_timeout: float, arm_timeout: float = 120.0, verbose: bool = False,
                 on_reboot: Callable[[], None] | None = None) -> None:
        self.link = link
        self.tracker = CommandTracker(link)
        self.profile = profile
        self.telem = telem
        self.events = events
        self.rate_hz = rate_hz
        self.link_timeout = link_timeout
        self.arm_timeout = arm_timeout
        self.verbose = verbose
        self.on_reboot = on_reboot
        self.params: dict[str, float] = {}
        self.counts: dict = {"reboots": 0, "stream_requests": 0, "link_losses": 0,
                             "telemetry_rejected": telem.rejected}
        self.reset()

    def reset(self) -> None:
        """Forget the vehicle's state (a new run)."""
        self.status = VehicleStatus()
        # the SITL's true state, when it sends one (logged, not used), on ArduCopter's clock through its position stream
        self.truth = SimTruth.for_link("ardupilot" if isinstance(self.profile, ArduPilotProfile) else "px4",
                                       self.telem.wanted)
        self.arming = ArmingRetry(timeout=self.arm_timeout)
        self.link_lost = False
        self.t_offset = math.inf  # receive time - vehicle time stamp (clock sync estimate) [s]
        self.last_text = ""
        self.reboot_evidence = ""  # what the heartbeat said since the last accepted sample ("": nothing)
        self._timeline_said = False
        self._foreign_said = False
        self._streams_asked = False  # the streams were asked for since the reboot evidence
        self._peer_changes = self.link.stats.get("peer_changes", 0)

    # ------------------------------------------------------------------ receive
    def pump(self) -> None:
        """Fold every pending message in."""
        for msg, rx in self.link.drain():
            self.on_message(msg, rx)
        if self.link.stats.get("foreign_heartbeats", 0) and not self._foreign_said:
            self._foreign_said = True
            self.events(f"heartbeat with the vehicle's ids from {self.link.pin.foreign_address} (the link is pinned to "
                        f"{self.link.peer}): ignored; a second vehicle or a spoofer (--vehicle-address, --signing-key)")

    def on_message(self, msg, rx: float) -> None:
        """Fold one message received at ``rx`` [s] in."""
        typ = msg.get_type()
        if typ == self.truth.partner:
            self.truth.update(msg, rx)  # its time_boot_ms places the truth sent in the same loop
        if typ in self.telem.wanted:
            self._on_telemetry(msg, rx)
        elif typ == "HEARTBEAT":
            self._on_heartbeat(msg, rx)
        elif typ == "COMMAND_ACK":
            pc = self.tracker.on_ack(msg)
            if pc is not None and pc.command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM and not pc.accepted:
                self.events(self.arming.refused(mavlink.enums["MAV_RESULT"][pc.result].name, self.last_text))
            elif pc is not None and (self.verbose or not pc.accepted):
                self.events(f"{pc.label}: {mavlink.enums['MAV_RESULT'][pc.result].name}")
        elif typ == "PARAM_VALUE":
            name = msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode(errors="ignore")
            name = name.rstrip("\x00")
            self.params[name] = decode_param_value(msg.param_value, msg.param_type, self.status.autopilot or 0)
            if name == "COM_OF_LOSS_T":
                self.profile.offboard_loss_timeout = float(msg.param_value)
        elif typ in ("SIM_STATE", "HIL_STATE_QUATERNION"):
            self.truth.update(msg, rx)
        elif typ == "STATUSTEXT":
            self.last_text = str(msg.text).rstrip("\x00")  # the autopilot's reason for a refusal
            if self.verbose:
                self.events(f"vehicle says: {msg.text}")

    def _on_telemetry(self, msg, rx: float) -> None:
        tel = self.telem
        used = tel.update(msg, rx)
        for note in tel.take_notes():  # a start-up time line re-lined onto the samples' own
            self.events(note)
        if not used:
            if tel.new_timeline():
                self._new_timeline(msg, rx)
            return  # dropped, or the contact flag (kept, not a state sample)
        self.status.last_heard = rx
        self.reboot_evidence, self._timeline_said = "", False  # the old time line goes on
        self._clock(rx)

    def _clock(self, rx: float) -> None:
        off = rx - self.telem.newest_stamp()
        # Vehicle clock estimate: minimum of (receive - stamp), slowly forgetting (clock drift).
        self.t_offset = min(self.t_offset + 1e-5, off) if math.isfinite(self.t_offset) else off

    def _new_timeline(self, msg, rx: float) -> None:
        """Samples agree on a new vehicle time line: a reboot if the heartbeat agrees, else dropped."""
        tel = self.telem
        old = tel.newest_stamp()
        new = max((s.cand_stamp for s in (tel.att, tel.pos) if s.cand_n), default=math.nan)
        if not self.reboot_evidence:
            if not self._timeline_said:
                self._timeline_said = True
                self.events(f"vehicle time left its time line ({old:.3f} s -> {new:.3f} s) without a reboot's "
                            "heartbeat evidence: samples dropped")
            return
        self.counts["reboots"] += 1
        self.events(f"vehicle time went from {old:.3f} s to {new:.3f} s after {self.reboot_evidence}: "
                    "reboot, re-requesting streams")
        self.reboot_evidence, self._timeline_said = "", False
        tel.restart(msg, rx)
        self.status.last_heard = rx
        self.t_offset = math.inf
        if self.on_reboot is not None:
            self.on_reboot()
        if not self._streams_asked:  # not yet when its heartbeat came back
            self.request_streams()
        if tel.has_data:
            self._clock(rx)

    def _on_heartbeat(self, msg, rx: float) -> None:
        st = self.status
        vm = self.profile.decode(msg.base_mode, msg.custom_mode)
        self._reboot_evidence(vm, rx)
        if not st.seen:
            st.autopilot, st.vehicle_type = int(msg.autopilot), int(msg.type)
            self.events(f"vehicle heartbeat: sysid {msg.get_srcSystem()}, autopilot {msg.autopilot}, "
                        f"{vm.name}, armed={vm.armed}")
        elif self.link_lost or rx - st.last_heard > self.link_timeout:
            self.events("vehicle heartbeat back: link restored, re-requesting streams")
            self.request_streams()
            self.link_lost = False  # restored once: the next heartbeats of the same read are no news
        if st.seen and (vm.armed != st.armed or vm.name != st.mode_name):
            self.events(f"vehicle {vm.name}, armed={vm.armed}")
        st.seen = True
        st.last_hb = st.last_heard = rx
        st.armed, st.offboard, st.mode_name = vm.armed, vm.offboard, vm.name

    def _reboot_evidence(self, vm, rx: float) -> None:
        """Note what in this heartbeat could mean the vehicle restarted (see the module docstring)."""
        st, changes = self.status, self.link.stats.get("peer_changes", 0)
        moved, self._peer_changes = changes != self._peer_changes, changes
        if not st.seen:
            return
        if moved:
            self.reboot_evidence = "a heartbeat from a new address"
        elif self.link_lost or rx - st.last_heard > self.link_timeout:
            self.reboot_evidence = "a silence"
        elif vm.armed != st.armed or vm.name != st.mode_name:
            self.reboot_evidence = "a change of the heartbeat's state"
        else:
            return
        self._streams_asked = False

    # ------------------------------------------------------------------ state
    def bridge_paused(self, now: float, paused: float) -> None:
        """The bridge's own process was paused for ``paused`` s until ``now`` (its clock jumped while the vehicle
        went on talking into the socket): a silence of the bridge, not of the vehicle. Only the silence the
        bridge was awake for counts toward a link loss (and a restore, and a reboot's evidence)."""
        if self.status.seen:
            self.status.last_heard = min(now, self.status.last_heard + paused)

    def heard(self, now: float) -> bool:
        """A heartbeat arrived and the vehicle was heard within the link timeout."""
        return self.status.seen and now - self.status.last_heard <= self.link_timeout

    def vehicle_now(self, now: float, lockstep: bool) -> float:
        """Vehicle time [s] now: the newest stamp in lockstep, else the clock estimate."""
        if lockstep or not math.isfinite(self.t_offset):
            return self.telem.newest_stamp()
        return now - self.t_offset

    def watch(self, now: float, lost_after: float) -> bool:
        """Link-loss bookkeeping; True when nothing was heard for ``lost_after`` s after the link was lost."""
        st = self.status
        # The link lives while the vehicle is heard at all: PX4 sends its heartbeat once a second, so
        # after a 2 s stall the next one can be 4 s after the last, while telemetry is already back.
        if st.seen and now - st.last_heard > self.link_timeout and not self.link_lost:
            self.link_lost = True
            self.counts["link_losses"] += 1
            self.events(f"vehicle silent (no heartbeat, no telemetry) for {self.link_timeout:g} s: link lost")
        elif now - st.last_heard <= self.link_timeout:
            self.link_lost = False
        return self.link_lost and now - st.last_heard > lost_after

    # ------------------------------------------------------------------ send
    def command(self, command: int, params: tuple[float, ...], label: str) -> PendingCommand:
        """A COMMAND_LONG, retried until acknowledged."""
        return self.tracker.submit(command, params, label)

    def pending(self, command: int) -> bool:
        """A command of this kind waits for its acknowledgement."""
        return bool(self.tracker.queues.get(command))

    def request_streams(self) -> None:
        """Ask for the telemetry streams (and the simulator's truth) at the loop rate."""
        us = int(round(1e6 / self.rate_hz))
        for name in sorted({self.telem.attitude_msg, self.telem.position_msg}):
            self.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, (float(_MSG_IDS[name]), float(us)),
                         f"SET_MESSAGE_INTERVAL {name} {self.rate_hz:g} Hz")
        # The simulator's truth, logged beside the EKF (SITL only: a real vehicle refuses it or, PX4 without
        # ground truth, sends nothing): ArduPilot's SIM_STATE, PX4 SIH's HIL_STATE_QUATERNION.
        name, msg_id = TRUTH_MESSAGES["ardupilot" if isinstance(self.profile, ArduPilotProfile) else "px4"]
        self.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, (float(msg_id), float(us)),
                     f"SET_MESSAGE_INTERVAL {name} {self.rate_hz:g} Hz (SITL truth)")
        self.counts["stream_requests"] += 1
        self._streams_asked = True

    def housekeeping(self, now: float, heartbeat: bool) -> None:
        """Off the tick path: our heartbeat (when due), command retries, reopening a closed link."""
        if heartbeat:
            self.link.send_heartbeat()
        self.tracker.poll(now)
        if self.link.poll(now):
            self.events(f"link reopened ({self.link.endpoint})")
            self.request_streams()

    # ------------------------------------------------------------------ before the first tick
    def wait_for_heartbeat(self, timeout: float, stopped: Callable[[], bool]) -> None:
        """Send our heartbeat once a second until the vehicle's arrives.

        Raises:
            NoVehicleError: none within ``timeout`` s.
        """
        t_end = time.monotonic() + timeout
        target = self.link.target_system  # as asked for (target 0 locks onto the first system heard)
        next_hb = 0.0
        while not self.status.seen and not stopped():
            now = time.monotonic()
            if now > t_end:
                raise NoVehicleError(f"no heartbeat from system {target} on {self.link.endpoint} "
                                     f"within {timeout:g} s")
            if now >= next_hb:
                next_hb = now + 1.0
                self.link.send_heartbeat()  # udpout: lets a udpin vehicle learn our address
            self.link.poll(now)
            self.link.wait(0.05)
            self.pump()

    def preflight(self, guid_options: int | None, force_guid_options: bool, stopped: Callable[[], bool],
                  timeout: float = 3.0) -> VehicleInfo:
        """The heartbeat's autopilot, the parameters, the thrust semantics (ArduPilot's GUID_OPTIONS).

        Raises:
            PreflightError: wrong autopilot, or a required parameter / a consistent GUID_OPTIONS missing.
        """
        check_autopilot(self.status.autopilot, self.profile)
        wanted = params_to_read(self.profile)
        t_end = time.monotonic() + timeout
        next_ask = 0.0
        while not stopped() and time.monotonic() < t_end and any(n not in self.params for n in wanted):
            if time.monotonic() >= next_ask:
                next_ask = time.monotonic() + 0.5
                for n in wanted:
                    if n not in self.params:
                        self.request_param(n)
            self.link.wait(0.05)
            self.pump()
        missing = [n for n, req in wanted.items() if n not in self.params and not req]
        if missing:
            self.events(f"parameters not answered within {timeout:g} s: {', '.join(missing)} (not needed)")
        if isinstance(self.profile, ArduPilotProfile):
            opt = resolve_guid_options(self.params.get("GUID_OPTIONS"), guid_options, force_guid_options)
            self.profile.guid_options = opt
            self.events(f"GUID_OPTIONS={opt}: thrust field is a "
                        + ("climb rate" if self.profile.climb_rate_thrust else "thrust"))
        return VehicleInfo(self.status.autopilot, self.status.vehicle_type, dict(self.params),
                           self.params.get(hover_param(self.profile)))

    def request_param(self, name: str) -> None:
        """Ask for one parameter by name (the answer arrives as PARAM_VALUE)."""
        self.link.send(self.link.mav.param_request_read_encode(self.link.target_system or 0,
                                                               self.link.target_component or 0, name.encode(), -1))

    def close(self) -> None:
        """Close the connection."""
        self.link.close()
