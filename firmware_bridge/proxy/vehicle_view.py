"""What the steering proxy knows of the vehicle: the autopilot's heartbeat (armed, off-board / guided, its
autopilot) and its local position, folded in from the frames the proxy forwards to the apps anyway (only
these few message ids are decoded; the bytes forwarded are never touched).

The position goes through the companion loop's :class:`~firmware_bridge.telemetry.TelemetryState` (plausibility,
time line, NED -> ENU), so the proxy judges a sample exactly as the bridge does. The profile is chosen from
the heartbeat's autopilot field (PX4 or ArduPilot); heartbeats of other components (a camera, a gimbal, a
ground station) are not the vehicle's.

With a motion capture (``ddpc-proxy --position-source mocap``, a :class:`~firmware_bridge.mocap_input.MocapInput`)
the measured height is the lab's: the pose's height put into the autopilot's local frame (the frame the app's
setpoints are in) by the offset between the two heights while the vehicle stands disarmed, frozen at arming. So the
steering follows the app's heights on the lab's measurement, not on the estimator's copy of it; with no offset yet
(the proxy started after arming) or no fresh pose, the height is stale and nothing is steered.

The vehicle's ``GLOBAL_POSITION_INT`` is folded in too, paired with its ``LOCAL_POSITION_NED``: the offset that puts
a global setpoint's altitude into the local frame (:class:`~firmware_bridge.proxy.setpoint_frames.FrameOffsets`).
The motion capture's offset stays a local one: a global setpoint goes into the local frame by the estimator's own
offset, and the steering measures it there on the lab's height.
"""

from __future__ import annotations

import math

from firmware_bridge.mocap_input import MocapInput
from firmware_bridge.plausibility import TelemetryLimits
from firmware_bridge.profiles import MAV_AUTOPILOT_ARDUPILOTMEGA, MAV_AUTOPILOT_PX4, Profile, make_profile
from firmware_bridge.proxy.rewrite import PROXY_COMPONENT, decode_frame, mavlink
from firmware_bridge.proxy.setpoint_frames import FrameOffsets
from firmware_bridge.telemetry import TelemetryState

__all__ = ["VehicleView", "VIEW_MSGIDS"]

VIEW_MSGIDS = frozenset((mavlink.MAVLINK_MSG_ID_HEARTBEAT, mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED,
                         mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT))
PROXY_SYSTEM = 254  # the proxy's own messages: neither the vehicle's (1) nor a ground station's (255)
_REQUEST_EVERY = 2.0  # s between stream requests while the position comes slower than asked
_GLOBAL_PERIOD = 0.1  # s: GLOBAL_POSITION_INT asked this often for a global app (the frames' offset, not per tick)
_AUTOPILOTS = {MAV_AUTOPILOT_PX4: "px4", MAV_AUTOPILOT_ARDUPILOTMEGA: "ardupilot"}


class VehicleView:
    """The vehicle's state as the proxy sees it (times in seconds on the ``time.time()`` clock).

    Args:
        limits: what a plausible position sample satisfies (the profile's envelope).
        link_timeout: no heartbeat for this long: the vehicle is not heard [s].
        mocap: the lab's poses, the measured height's source (None: the autopilot's estimate).
        mocap_offset: the local frame's height minus the pose's [m], when known (a lab's calibration, or what an
            earlier session measured); None: measured while the vehicle stands disarmed.
    """

    def __init__(self, limits: TelemetryLimits | None = None, link_timeout: float = 1.5,
                 mocap: MocapInput | None = None, mocap_offset: float | None = None) -> None:
        self.telem = TelemetryState("ATTITUDE", "LOCAL_POSITION_NED", limits=limits or TelemetryLimits())
        self.link_timeout = link_timeout
        self.profile: Profile | None = None
        self.sysid: int | None = None
        self.armed = self.offboard = False
        self.mode_name = "?"
        self.last_hb = -math.inf
        self.requests = 0
        self._next_request: dict[int, float] = {}  # message id -> earliest next stream request [s]
        self.offsets = FrameOffsets()
        self._mav = mavlink.MAVLink(None, srcSystem=PROXY_SYSTEM, srcComponent=PROXY_COMPONENT)
        self.mocap = mocap
        self.mocap_offset = math.nan if mocap_offset is None else float(mocap_offset)  # [m] (nan: not yet)
        self._fixed = mocap_offset is not None
        self._offsets: list[float] = []

    def on_frame(self, frame: bytes, t_rx: float) -> None:
        """Fold one frame (of :data:`VIEW_MSGIDS`) received at ``t_rx`` in."""
        msg = decode_frame(frame)
        if msg is None:
            return
        kind = msg.get_type()
        if kind == "HEARTBEAT":
            self._heartbeat(msg, t_rx)
        elif self.sysid is None or msg.get_srcSystem() != self.sysid:
            return
        elif kind == "GLOBAL_POSITION_INT":
            self.offsets.global_position(msg, t_rx)
        else:
            if self.telem.update(msg, t_rx):  # (a sample the telemetry rejects pairs with no global report)
                self.offsets.local(msg)

    def _heartbeat(self, msg, t_rx: float) -> None:
        name = _AUTOPILOTS.get(int(msg.autopilot))
        if name is None or (self.sysid is not None and msg.get_srcSystem() != self.sysid):
            return  # a ground station, a camera, another vehicle
        if self.profile is None:
            self.profile, self.sysid = make_profile(name), msg.get_srcSystem()
        vm = self.profile.decode(msg.base_mode, msg.custom_mode)
        self.armed, self.offboard, self.mode_name = vm.armed, vm.offboard, vm.name
        self.last_hb = t_rx

    def heard(self, now: float) -> bool:
        """A heartbeat within the link timeout."""
        return now - self.last_hb <= self.link_timeout

    def pump(self, now: float, max_age: float = 0.05) -> None:
        """Fold the pending poses in; while disarmed, with a fresh pose and a fresh estimate (younger than
        ``max_age`` [s]), the offset between their heights is measured (the median of the last 50)."""
        if self.mocap is None:
            return
        self.mocap.pump()
        if self._fixed or self.armed or self.mocap.age(now) > max_age or self._estimate_age(now) > max_age:
            return
        self._offsets = [*self._offsets[-49:], float(self.telem.position[2]) - float(self.mocap.position[2])]
        self.mocap_offset = float(sorted(self._offsets)[len(self._offsets) // 2])

    def height(self, now: float | None = None, max_advance: float = 0.05) -> float:
        """The local height, up [m] (the setpoints' frame: LOCAL_NED's -z). The estimate's newest sample, advanced by
        its own vertical velocity to ``now`` (at most ``max_advance`` [s]): a stream that arrives in bursts (TCP) would
        otherwise sample a climbing vehicle up to a few ticks late, which the steering reads as noise. With a
        motion capture, the newest pose's height in the same frame (nan before the offset is known)."""
        if self.mocap is not None:
            return float(self.mocap.position[2]) + self.mocap_offset
        z = float(self.telem.position[2])
        if now is None or not self.telem.pos.seq:
            return z
        return z + float(self.telem.velocity[2]) * min(max(now - self.telem.pos.rx, 0.0), max_advance)

    def _estimate_age(self, now: float) -> float:
        return now - self.telem.pos.rx if self.telem.pos.seq else math.inf

    def position_age(self, now: float) -> float:
        """Seconds since the measured height's newest sample arrived (inf: none yet; with a motion capture, also
        before the offset to the local frame is known)."""
        if self.mocap is not None:
            return self.mocap.age(now) if math.isfinite(self.mocap_offset) else math.inf
        return self._estimate_age(now)

    def position_period(self, n: int = 20) -> float:
        """The mean gap of the last ``n`` position samples' arrivals [s] (inf before two; a mean, since a byte stream
        delivers them in bursts)."""
        h = self.telem.pos.history[-n:]
        return (h[-1][1] - h[0][1]) / (len(h) - 1) if len(h) > 1 else math.inf

    def source_summary(self) -> dict:
        """What the measured height came from (JSON-ready)."""
        m = self.mocap
        if m is None:
            return {"kind": "autopilot"}
        return {"kind": "mocap", "url": getattr(m.link, "url", None), "poses": m.seq, "dropped": m.dropped,
                "rejected": dict(m.rejected), "offset_m": None if math.isnan(self.mocap_offset) else self.mocap_offset,
                "offset_given": self._fixed}

    def frame_offset(self, kind: str, now: float) -> float:
        """The height of the setpoint frame ``kind`` (:mod:`.setpoint_frames`) minus the local one [m] (nan: unknown)."""
        return self.offsets.offset(kind, now)

    def stream_request(self, now: float, period: float, global_too: bool = False) -> list[bytes]:
        """SET_MESSAGE_INTERVALs (from the proxy's own ids) asking for LOCAL_POSITION_NED every ``period`` [s] (and,
        ``global_too``, GLOBAL_POSITION_INT every :data:`_GLOBAL_PERIOD`), each when the vehicle is heard and the
        message comes slower than that (every few seconds at most)."""
        if self.sysid is None or not self.heard(now):
            return []
        want = [(mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED, period, self.position_period())]
        if global_too:
            want.append((mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, _GLOBAL_PERIOD, self.offsets.period()))
        out = []
        for mid, p, got in want:
            if now < self._next_request.get(mid, -math.inf) or got <= 1.2 * p:
                continue
            self._next_request[mid] = now + _REQUEST_EVERY
            self.requests += 1
            msg = self._mav.command_long_encode(self.sysid, 1, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0, mid, p * 1e6,
                                                0, 0, 0, 0, 0)
            out.append(bytes(msg.pack(self._mav)))
        return out
