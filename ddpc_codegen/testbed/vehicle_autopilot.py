"""Autopilot emulation of the simulated vehicle: what PX4 (or ArduCopter) does in off-board.

* HEARTBEAT with PX4's custom-mode encoding (main << 16 | sub << 24) and
  MAV_MODE_FLAG_SAFETY_ARMED; ``autopilot="ardupilot"`` uses ArduCopter's mode numbers (GUIDED /
  GUIDED_NOGPS take the setpoints, and SET_ATTITUDE_TARGET.thrust is a climb rate unless
  GUID_OPTIONS bit 3 is set).
* COMMAND_LONG: COMPONENT_ARM_DISARM, DO_SET_MODE, SET_MESSAGE_INTERVAL, REQUEST_MESSAGE
  (HEARTBEAT), each answered with a COMMAND_ACK; PARAM_REQUEST_LIST / PARAM_REQUEST_READ / PARAM_SET for
  COM_OF_LOSS_T and MPC_THR_HOVER (PX4), GUID_OPTIONS, MOT_THST_HOVER and GUID_TIMEOUT (ArduPilot; the hover
  thrusts are the position controller's estimate, the true one unless configured; read-only).
* SET_ATTITUDE_TARGET (quaternion FRD -> NED + thrust) goes to the flight controller while armed in
  OFFBOARD. OFFBOARD is refused unless setpoints are arriving; if they stop for COM_OF_LOSS_T
  seconds the vehicle leaves OFFBOARD for its failsafe (HOLD or LAND), as PX4 does.
* SET_POSITION_TARGET_LOCAL_NED (MAV_FRAME_LOCAL_NED; position / velocity / acceleration / yaw /
  yaw rate as ``type_mask`` enables them, read as PX4 does) is flown by the autopilot's own cascaded
  position controller (:mod:`ddpc_codegen.testbed.vehicle_position`, PX4's or ArduCopter's gains and
  limits) while armed in OFFBOARD / GUIDED; other frames and force setpoints are refused and logged.
  Position setpoints count as the off-board signal exactly as attitude setpoints do. With
  ``setpoint_log`` every one received (anyone's, before any check) is kept as a row of
  :data:`SETPOINT_LOG_FIELDS` (a proxy's soak compares them with what the app sent).
* Outside OFFBOARD, armed, the vehicle flies itself on the same position controller: HOLD brakes
  and holds where it stopped, LAND descends at the land speed holding its horizontal position and
  disarms on touchdown.

The physics is not here (no simulator import): it is reached through :class:`Body`.
"""

from __future__ import annotations

import logging
import math
from array import array
from collections import deque
from pathlib import Path
from typing import Any, Callable, Protocol

import numpy as np

from ddpc_codegen.robot.frames import euler_from_quat, quat_enu_flu_from_ned_frd

from firmware_bridge.link import MavLink, mavlink
from firmware_bridge.profiles import (
    ARDUCOPTER_MODES,
    MAV_AUTOPILOT_ARDUPILOTMEGA,
    MAV_AUTOPILOT_PX4,
    MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
    MAV_MODE_FLAG_SAFETY_ARMED,
    PX4_AUTO_SUB,
    PX4_MAIN,
    ArduPilotProfile,
    px4_custom_mode,
    px4_mode_name,
)
from ddpc_codegen.testbed.vehicle_config import MODE_HOLD, MODE_LAND, MODE_OFFBOARD, VehicleConfig
from ddpc_codegen.testbed.vehicle_position import (
    ARDUCOPTER_POSITION,
    PX4_POSITION,
    PositionController,
    PositionFlight,
    target_from_local_ned,
)
from ddpc_codegen.testbed.vehicle_telemetry import TelemetryPublisher

__all__ = ["Body", "AutopilotEmulator", "SETPOINT_LOG_FIELDS"]

# a received SET_POSITION_TARGET_LOCAL_NED: receive time [s, time.monotonic()], its header, then its fields
SETPOINT_LOG_FIELDS = ("rx", "sysid", "compid", "seq", "time_boot_ms", "target_system", "target_component",
                       "coordinate_frame", "type_mask", "x", "y", "z", "vx", "vy", "vz", "afx", "afy", "afz", "yaw",
                       "yaw_rate")

log = logging.getLogger("ddpc_codegen.testbed.vehicle")

_FORCE_DISARM = 21196.0  # PX4 / ArduPilot magic number: disarm even in flight
_PX4_MODES = {MODE_OFFBOARD: (PX4_MAIN["OFFBOARD"], 0), MODE_HOLD: (PX4_MAIN["AUTO"], PX4_AUTO_SUB["LOITER"]),
              MODE_LAND: (PX4_MAIN["AUTO"], PX4_AUTO_SUB["LAND"])}
_ARDU_MODES = {MODE_OFFBOARD: ARDUCOPTER_MODES["GUIDED_NOGPS"], MODE_HOLD: ARDUCOPTER_MODES["LOITER"],
               MODE_LAND: ARDUCOPTER_MODES["LAND"]}
_ARDU_HOLD_MODES = tuple(ARDUCOPTER_MODES[n] for n in ("LOITER", "BRAKE", "ALT_HOLD", "POSHOLD"))


class Body(Protocol):
    """What the autopilot reads of and commands to the physical vehicle."""

    g: float  # gravity [m/s^2]
    mass: float  # true mass [kg] (a well-tuned autopilot knows its hover thrust)
    max_thrust: float  # collective thrust at normalized thrust 1 [N]
    tilt_max: float  # the flight controller's limit on the attitude setpoint's tilt [rad]

    def state(self) -> np.ndarray:
        """True state (19,) (see :mod:`ddpc_codegen.sim.plant`): position, velocity, quaternion, rates, ..."""

    def in_contact(self) -> bool:
        """Foot on the ground."""

    def airborne(self) -> bool:
        """Clearly in the air (PX4 refuses to disarm then)."""

    def set_attitude_target(self, q_enu: Any, thrust: float) -> None:
        """Flight-controller setpoint: attitude (w, x, y, z) body FLU -> world ENU, normalized thrust."""


class AutopilotEmulator:
    """Modes, arming, parameters and setpoints of the simulated vehicle (see the module docstring).

    Args:
        cfg: the vehicle's options; link: its MAVLink endpoint; body: the physics.
        clock: vehicle time now [s]; telemetry: the stream publisher (SET_MESSAGE_INTERVAL).
        start: position (3,) [m, ENU] and heading [rad, ENU] HOLD starts with.
        dt: the position controller's period (the vehicle's tick) [s].
    """

    def __init__(self, cfg: VehicleConfig, link: MavLink, body: Body, clock: Callable[[], float],
                 telemetry: TelemetryPublisher, start: tuple[np.ndarray, float], dt: float = 0.005) -> None:
        self.cfg, self.link, self.body, self.clock, self.telemetry = cfg, link, body, clock, telemetry
        self.ardu = ArduPilotProfile(guid_options=cfg.guid_options) if cfg.autopilot == "ardupilot" else None
        self.armed = cfg.start == "hover"
        self.mode = MODE_HOLD
        self.ardu_mode = ARDUCOPTER_MODES["LOITER"]  # what HEARTBEAT says on ArduPilot
        self.px4_mode = (PX4_MAIN["AUTO"], PX4_AUTO_SUB["LOITER"])
        hover = cfg.hover_thrust if cfg.hover_thrust is not None else body.mass * body.g / body.max_thrust
        self.flight = PositionFlight(PositionController(ARDUCOPTER_POSITION if self.ardu else PX4_POSITION, hover,
                                                        dt, body.g, body.tilt_max), start)
        self.com_of_loss_t, self.guid_options = float(cfg.com_of_loss_t), int(cfg.guid_options)
        self.sp_q_enu = np.array([1.0, 0.0, 0.0, 0.0])
        self.sp_field = 0.0
        self.sp_kind = "attitude"  # what OFFBOARD flies: the newest setpoint's kind ("attitude", "position")
        self.last_sp_time = -math.inf  # vehicle time of the newest setpoint (attitude or position) [s]
        self.sp_queue: deque = deque()  # real time: (rx, q_enu, field), applied at the arrival time
        self.expect_stamp_ms = -1  # lockstep: the setpoint stamp the vehicle waits for
        self.events: list[tuple[float, str]] = []
        self.stats = {"setpoints": 0, "setpoints_ignored": 0, "position_setpoints": 0, "commands": 0}
        # flat rows of SETPOINT_LOG_FIELDS (doubles: no per-row objects for the collector to walk)
        self.setpoint_log = array("d") if cfg.setpoint_log else None

    # ------------------------------------------------------------------ state
    def event(self, what: str) -> None:
        """Record (and log) a mode / arming event at the current vehicle time."""
        t = self.clock()
        self.events.append((t, what))
        log.info("[vehicle t=%7.3f] %s", t, what)

    def silent(self) -> bool:
        """Inside a configured silence window: send nothing."""
        t = self.clock()
        return any(a <= t < b for a, b in self.cfg.silence)

    def heartbeat_fields(self) -> tuple[int, int, int, int, int]:
        """(type, autopilot, base_mode, custom_mode, system_status) of the HEARTBEAT."""
        base = MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
        if self.armed:
            base |= MAV_MODE_FLAG_SAFETY_ARMED
        if self.ardu is not None:
            custom, ap = self.ardu_mode, MAV_AUTOPILOT_ARDUPILOTMEGA
        else:
            custom, ap = px4_custom_mode(*self.px4_mode), MAV_AUTOPILOT_PX4
        status = mavlink.MAV_STATE_ACTIVE if self.armed else mavlink.MAV_STATE_STANDBY
        return mavlink.MAV_TYPE_QUADROTOR, ap, base, custom, status

    def mode_name(self) -> str:
        """The autopilot's own name of the mode (e.g. "AUTO.LOITER", "GUIDED_NOGPS")."""
        if self.ardu is not None:
            return {v: k for k, v in ARDUCOPTER_MODES.items()}.get(self.ardu_mode, str(self.ardu_mode))
        return px4_mode_name(px4_custom_mode(*self.px4_mode))

    def send_heartbeat(self) -> None:
        if not self.silent():
            self.link.send_heartbeat(*self.heartbeat_fields())

    def set_mode(self, mode: str, px4: tuple[int, int] | None = None, ardu: int | None = None, why: str = "") -> None:
        """Enter ``mode`` (MODE_*), reported with the given (or the default) autopilot mode numbers."""
        self.mode = mode
        self._own_mode_from_here()
        self.px4_mode = px4 if px4 is not None else _PX4_MODES[mode]
        self.ardu_mode = ardu if ardu is not None else _ARDU_MODES[mode]
        self.event(f"mode {self.mode_name()}" + (f" ({why})" if why else ""))
        self.send_heartbeat()  # tell the companion at once, not at the next 1 Hz beat

    def _yaw(self) -> float:
        return float(euler_from_quat(self.body.state()[6:10])[2])

    def _own_mode_from_here(self) -> None:  # HOLD / LAND start from where the vehicle is now
        if self.mode == MODE_HOLD:
            self.flight.hold(self._yaw())
        elif self.mode == MODE_LAND:
            self.flight.land(self.body.state()[0:3], self._yaw())

    def set_armed(self, armed: bool, why: str = "") -> None:
        if armed == self.armed:
            return
        self.armed = armed
        if armed:
            self._own_mode_from_here()
        self.event(("armed" if armed else "disarmed") + (f" ({why})" if why else ""))
        self.send_heartbeat()

    # ------------------------------------------------------------------ incoming
    def process(self) -> bool:
        """Handle everything pending. Returns True if the setpoint stamped ``expect_stamp_ms`` arrived."""
        got = False
        for msg, rx in self.link.drain():
            typ = msg.get_type()
            if typ == "SET_ATTITUDE_TARGET":
                got |= self._on_setpoint(msg, rx)
            elif typ == "SET_POSITION_TARGET_LOCAL_NED":
                if self.setpoint_log is not None:
                    self.setpoint_log.extend((rx, msg.get_srcSystem(), msg.get_srcComponent(), msg.get_seq(),
                                              *(getattr(msg, f) for f in SETPOINT_LOG_FIELDS[4:])))
                got |= self._on_position_target(msg)
            elif typ == "COMMAND_LONG":
                self._on_command(msg)
            elif typ in ("PARAM_REQUEST_READ", "PARAM_SET", "PARAM_REQUEST_LIST"):
                self._on_param(msg)
        return got

    def _for_me(self, msg) -> bool:
        ts = getattr(msg, "target_system", 0)
        tc = getattr(msg, "target_component", 0)
        return ts in (0, self.cfg.sysid) and tc in (0, self.cfg.compid)

    def _on_setpoint(self, msg, rx: float) -> bool:
        if not self._for_me(msg):
            self.stats["setpoints_ignored"] += 1
            return False
        ignored = mavlink.ATTITUDE_TARGET_TYPEMASK_ATTITUDE_IGNORE | mavlink.ATTITUDE_TARGET_TYPEMASK_THROTTLE_IGNORE
        if msg.type_mask & ignored:
            self.stats["setpoints_ignored"] += 1
            return False
        q = np.asarray(msg.q, dtype=float)
        n = float(np.linalg.norm(q))
        if not (math.isfinite(n) and n > 1e-6 and math.isfinite(msg.thrust)):
            self.stats["setpoints_ignored"] += 1  # PX4 drops invalid setpoints
            return False
        q_enu = np.array(quat_enu_flu_from_ned_frd(q / n))
        self.last_sp_time = self.clock()
        self.stats["setpoints"] += 1
        if self.cfg.lockstep:
            self.take_setpoint(q_enu, float(msg.thrust))
        else:
            self.sp_queue.append((rx, q_enu, float(msg.thrust)))  # takes effect at its arrival time
        return int(msg.time_boot_ms) == self.expect_stamp_ms

    def _on_position_target(self, msg) -> bool:
        """SET_POSITION_TARGET_LOCAL_NED: the position controller's setpoint from the next tick on."""
        if not self._for_me(msg):
            self.stats["setpoints_ignored"] += 1
            return False
        try:
            target = target_from_local_ned(msg)
        except ValueError as e:
            self.stats["setpoints_ignored"] += 1
            if self.stats["setpoints_ignored"] & (self.stats["setpoints_ignored"] - 1) == 0:
                log.warning("[vehicle t=%7.3f] %s (ignored)", self.clock(), e)  # 1st, 2nd, 4th, 8th, ...
            return False
        self.flight.link, self.sp_kind = target, "position"
        self.last_sp_time = self.clock()
        self.stats["position_setpoints"] += 1
        return int(msg.time_boot_ms) == self.expect_stamp_ms

    def take_setpoint(self, q_enu: np.ndarray, field: float) -> None:
        """The link's newest attitude setpoint; the flight controller gets it while armed in OFFBOARD."""
        self.sp_q_enu, self.sp_field, self.sp_kind = q_enu, field, "attitude"
        if self.mode == MODE_OFFBOARD and self.armed:
            self._apply_offboard()

    def _apply_offboard(self) -> None:
        """Hand the link's attitude setpoint to the flight controller (thrust semantics per autopilot);
        position setpoints are flown by :meth:`control_tick`."""
        if self.sp_kind == "position":
            return
        if self.ardu is not None and self.ardu.climb_rate_thrust:
            # ArduPilot: thrust field = climb rate; its own altitude loop makes the thrust.
            vz_sp = self.ardu.field_to_climb_rate(self.sp_field)
            self.body.set_attitude_target(self.sp_q_enu, self._climb_thrust(vz_sp, self.sp_q_enu))
        else:
            self.body.set_attitude_target(self.sp_q_enu, self.sp_field)

    def _climb_thrust(self, vz_sp: float, q_enu) -> float:
        b = self.body
        r, p, _ = euler_from_quat(q_enu)
        acc = b.g + 4.0 * (vz_sp - b.state()[5])
        tilt = max(math.cos(r) * math.cos(p), 0.5)
        return min(max(b.mass * acc / tilt / b.max_thrust, 0.0), 1.0)

    def _ack(self, msg, result: int) -> None:
        self.stats["commands"] += 1
        if self.silent():
            return
        self.link.send(self.link.mav.command_ack_encode(msg.command, result, 0, 0, msg.get_srcSystem(),
                                                        msg.get_srcComponent()))

    def _offboard_signal_lost(self) -> bool:
        return self.clock() - self.last_sp_time > self.com_of_loss_t

    def _on_command(self, msg) -> None:
        if not self._for_me(msg):
            return
        cmd = msg.command
        R = mavlink
        if cmd == R.MAV_CMD_SET_MESSAGE_INTERVAL:
            ok = self.telemetry.set_interval(int(msg.param1), msg.param2, self.clock())
            self._ack(msg, R.MAV_RESULT_ACCEPTED if ok else R.MAV_RESULT_UNSUPPORTED)
        elif cmd == R.MAV_CMD_COMPONENT_ARM_DISARM:
            self._ack(msg, self._arm_cmd(msg))
        elif cmd == R.MAV_CMD_DO_SET_MODE:
            self._ack(msg, self._set_mode_cmd(msg))
        elif cmd == R.MAV_CMD_REQUEST_MESSAGE and int(msg.param1) == R.MAVLINK_MSG_ID_HEARTBEAT:
            self._ack(msg, R.MAV_RESULT_ACCEPTED)
            self.send_heartbeat()
        else:
            self._ack(msg, R.MAV_RESULT_UNSUPPORTED)

    def _arm_cmd(self, msg) -> int:
        R = mavlink
        if msg.param1 >= 0.5:
            if self.mode == MODE_OFFBOARD and self._offboard_signal_lost():
                return R.MAV_RESULT_DENIED
            self.set_armed(True, "command")
            return R.MAV_RESULT_ACCEPTED
        if self.body.airborne() and msg.param2 != _FORCE_DISARM:
            return R.MAV_RESULT_DENIED  # PX4 refuses to disarm in flight unless forced
        self.set_armed(False, "command")
        return R.MAV_RESULT_ACCEPTED

    def _set_mode_cmd(self, msg) -> int:
        R = mavlink
        if not int(msg.param1) & MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return R.MAV_RESULT_UNSUPPORTED
        if self.ardu is not None:
            num = int(msg.param2)
            if num in (ARDUCOPTER_MODES["GUIDED"], ARDUCOPTER_MODES["GUIDED_NOGPS"]):
                mode = MODE_OFFBOARD
            elif num in _ARDU_HOLD_MODES:
                mode = MODE_HOLD
            elif num == ARDUCOPTER_MODES["LAND"]:
                mode = MODE_LAND
            else:
                return R.MAV_RESULT_UNSUPPORTED
            self.set_mode(mode, ardu=num, why="command")
            if mode == MODE_OFFBOARD and not self._offboard_signal_lost():
                self._apply_offboard()
            return R.MAV_RESULT_ACCEPTED
        main, sub = int(msg.param2), int(msg.param3)
        if main == PX4_MAIN["OFFBOARD"]:
            if self._offboard_signal_lost():
                return R.MAV_RESULT_TEMPORARILY_REJECTED  # PX4: no offboard signal, no OFFBOARD
            self.set_mode(MODE_OFFBOARD, px4=(main, 0), why="command")
            if self.armed:
                self._apply_offboard()
            return R.MAV_RESULT_ACCEPTED
        if main == PX4_MAIN["AUTO"] and sub == PX4_AUTO_SUB["LAND"]:
            self.set_mode(MODE_LAND, px4=(main, sub), why="command")
            return R.MAV_RESULT_ACCEPTED
        loiter = main == PX4_MAIN["AUTO"] and sub == PX4_AUTO_SUB["LOITER"]
        if loiter or main in (PX4_MAIN["POSCTL"], PX4_MAIN["ALTCTL"]):
            self.set_mode(MODE_HOLD, px4=(main, sub), why="command")
            return R.MAV_RESULT_ACCEPTED
        return R.MAV_RESULT_UNSUPPORTED

    def _params(self) -> dict[str, tuple[float, int]]:
        # What the bridge reads before its first tick, as the real autopilots answer it (the hover thrust:
        # its position controller's, the true one unless configured); unanswered, the bridge waits 3 s.
        hover = (self.flight.ctl.hover_thrust, mavlink.MAV_PARAM_TYPE_REAL32)
        if self.ardu is not None:
            return {"GUID_OPTIONS": (float(self.guid_options), mavlink.MAV_PARAM_TYPE_INT32),
                    "MOT_THST_HOVER": hover, "GUID_TIMEOUT": (3.0, mavlink.MAV_PARAM_TYPE_REAL32)}
        return {"COM_OF_LOSS_T": (self.com_of_loss_t, mavlink.MAV_PARAM_TYPE_REAL32), "MPC_THR_HOVER": hover}

    def _on_param(self, msg) -> None:
        if not self._for_me(msg):
            return
        if msg.get_type() == "PARAM_REQUEST_LIST":  # every parameter, in index order
            table = self._params()
            if not self.silent():
                for idx, (name, (val, typ)) in enumerate(table.items()):
                    self.link.send(self.link.mav.param_value_encode(name.encode(), val, typ, len(table), idx))
            return
        name = msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode(errors="ignore")
        name = name.rstrip("\x00")
        table = self._params()
        if msg.get_type() == "PARAM_SET" and name in table:
            if name == "COM_OF_LOSS_T":
                self.com_of_loss_t = float(msg.param_value)
            elif name == "GUID_OPTIONS":
                self.guid_options = int(msg.param_value)
                if self.ardu is not None:
                    self.ardu = ArduPilotProfile(guid_options=self.guid_options)
            table = self._params()
        if msg.get_type() == "PARAM_REQUEST_READ" and msg.param_index >= 0 and not name:
            names = list(table)
            name = names[msg.param_index] if msg.param_index < len(names) else ""
        if name in table and not self.silent():
            val, typ = table[name]
            idx = list(table).index(name)
            self.link.send(self.link.mav.param_value_encode(name.encode(), val, typ, len(table), idx))

    def save_setpoint_log(self) -> Path | None:
        """Write the received setpoints to ``cfg.setpoint_log`` (.npz, one array per field of
        :data:`SETPOINT_LOG_FIELDS`, each (n,)); the path, None without a log."""
        if self.setpoint_log is None:
            return None
        rows = np.frombuffer(self.setpoint_log, dtype=np.float64).reshape(-1, len(SETPOINT_LOG_FIELDS))
        path = Path(self.cfg.setpoint_log)
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez(path, **{f: rows[:, i] for i, f in enumerate(SETPOINT_LOG_FIELDS)})
        return path

    # ------------------------------------------------------------------ own flight modes
    def failsafe_check(self) -> None:
        """Leave OFFBOARD for the loss action when setpoints stopped for COM_OF_LOSS_T."""
        if self.mode == MODE_OFFBOARD and self.armed and self._offboard_signal_lost():
            self.set_mode(self.cfg.loss_action, why=f"offboard setpoints lost for > {self.com_of_loss_t:g} s")

    def control_tick(self) -> None:
        """Once per tick while armed: the position controller flies HOLD, LAND and OFFBOARD's position
        setpoints (OFFBOARD's attitude setpoints go to the flight controller as they arrive)."""
        if self.mode == MODE_OFFBOARD and (self.sp_kind != "position" or self.flight.link is None):
            return
        b, t, s = self.body, self.clock(), self.body.state()
        if self.mode == MODE_LAND and self.flight.landed(b.in_contact(), s[5], t):
            self.set_armed(False, "landed")
            return
        b.set_attitude_target(*self.flight.step(self.mode, s, t, self._yaw()))
