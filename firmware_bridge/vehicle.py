"""A simulated PX4-like vehicle behind a MAVLink endpoint (``ddpc-vehicle``).

The physics and inner loops are the simulator's (:class:`ddpc_codegen.sim.PogoXPlant` at 1 kHz,
:class:`ddpc_codegen.sim.flight_controller.PX4LikeFlightController`: attitude loop 250 Hz, rate
loop 1 kHz), scheduled exactly as in :func:`ddpc_codegen.sim.simulate`; the companion computer's
part is *not* here, it comes over the link. What the endpoint does, like PX4 in off-board:

* HEARTBEAT at 1 Hz (and at once on every mode / arming change) with PX4's custom-mode
  encoding (main << 16 | sub << 24) and MAV_MODE_FLAG_SAFETY_ARMED; ``--autopilot ardupilot``
  uses ArduCopter's mode numbers instead (GUIDED / GUIDED_NOGPS take the setpoints, and
  SET_ATTITUDE_TARGET.thrust is a climb rate unless GUID_OPTIONS bit 3 is set).
* Telemetry at the rates asked for with MAV_CMD_SET_MESSAGE_INTERVAL: ATTITUDE,
  ATTITUDE_QUATERNION, LOCAL_POSITION_NED, ODOMETRY (NED / FRD; the state is the simulator's
  measured state: delayed by ``meas_delay`` and with the sensor noise). Time stamps are the
  vehicle's boot time; one control tick is 5 ms, so telemetry at 200 Hz is one sample per tick.
* COMMAND_LONG: COMPONENT_ARM_DISARM, DO_SET_MODE, SET_MESSAGE_INTERVAL, each answered with a
  COMMAND_ACK; PARAM_REQUEST_READ / PARAM_SET for COM_OF_LOSS_T and GUID_OPTIONS.
* SET_ATTITUDE_TARGET (quaternion FRD -> NED + thrust) is applied at the next 1 ms physics step
  after it arrives while armed in OFFBOARD. OFFBOARD is refused unless setpoints are arriving.
  If they stop for COM_OF_LOSS_T seconds the vehicle leaves OFFBOARD for its failsafe (HOLD at
  the current position, or LAND), as PX4 does.
* Outside OFFBOARD, armed, the vehicle flies itself: HOLD keeps a position (true-mass PD, as
  PX4's position controller with a good hover-thrust estimate), LAND descends at 0.5 m/s and
  disarms on touchdown. A disarmed vehicle is parked: its state is frozen (no physics).

Timing: real time by default. The vehicle wakes once per 5 ms tick: at the boundary it
simulates the elapsed 5 ms in 1 ms physics steps, each received setpoint taking effect from the
first step that starts after its (kernel) receive time -- i.e. within 1 ms of arrival, like
PX4's 1 kHz rate loop -- and then publishes the telemetry of the new tick. ``lockstep``: after publishing the
telemetry of tick k the vehicle waits for the SET_ATTITUDE_TARGET stamped with tick k's
time (``time_boot_ms``) before simulating the next 5 ms (at most ``lockstep_timeout`` seconds
of wall time, then it goes on with the setpoint it has) -- fast, deterministic tests that
reproduce :func:`ddpc_codegen.sim.simulate` over the link.
"""

from __future__ import annotations

import gc
import math
import signal
import sys
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ddpc_codegen.robot.frames import (
    euler_from_quat,
    euler_ned_from_enu,
    quat_enu_flu_from_ned_frd,
    quat_from_euler,
    quat_ned_frd_from_enu_flu,
    rotate_inverse,
)
from ddpc_codegen.sim.flight_controller import PX4LikeFlightController
from ddpc_codegen.sim.params import PogoXParams, SensorNoise
from ddpc_codegen.sim.plant import STANCE, PogoXPlant
from ddpc_codegen.sim.scenarios import get_scenario

from firmware_bridge.link import MavLink, mavlink
from firmware_bridge.realtime import setup_realtime
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

__all__ = ["VehicleConfig", "SimVehicle", "MODE_OFFBOARD", "MODE_HOLD", "MODE_LAND"]

MODE_OFFBOARD, MODE_HOLD, MODE_LAND = "offboard", "hold", "land"
_FORCE_DISARM = 21196.0  # PX4 / ArduPilot magic number: disarm even in flight
_ATT_MASK_OK = 7  # body rates ignored, attitude and thrust used

_STREAM_IDS = {
    mavlink.MAVLINK_MSG_ID_ATTITUDE: "ATTITUDE",
    mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: "ATTITUDE_QUATERNION",
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: "LOCAL_POSITION_NED",
    mavlink.MAVLINK_MSG_ID_ODOMETRY: "ODOMETRY",
}


@dataclass
class VehicleConfig:
    """Options of the simulated vehicle (see the module docstring).

    Attributes:
        url: MAVLink connection string (e.g. ``udpout:127.0.0.1:14540``, the bridge listening);
            baud: serial baud rate.
        sysid, compid: the vehicle's MAVLink identity.
        autopilot: "px4" or "ardupilot".
        lockstep: advance one tick per setpoint (see module docstring); lockstep_timeout [s wall].
        scenario: where the vehicle starts (the scenario's start point; "flying").
        seed, noise: sensor-noise seed and switch (the simulator's SensorNoise defaults).
        start: "hover" (armed, HOLD at the start point) or "disarmed" (parked at the start point).
        start_offset: (x, y) added to the scenario's start point [m, local ENU] (a robot that is
            not where the trajectory starts). start_yaw: initial heading [rad, ENU: 0 = east];
            the vehicle's own HOLD / LAND keep the heading they start with.
        com_of_loss_t: off-board setpoint-loss timeout [s] (PX4 COM_OF_LOSS_T).
        loss_action: failsafe after the loss: "hold" or "land".
        guid_options: ArduPilot GUID_OPTIONS (bit 3: thrust field is a thrust, else a climb rate).
        duration: stop after this much simulated time [s] (None: run until signalled).
        default_rates: telemetry rates [Hz] before anyone asks (message name -> Hz).
        silence: simulated-time windows [(t0, t1), ...] [s] in which the vehicle sends nothing
            (a link-drop / vehicle-silent test).
        truth_log: write the true state per tick to this .npz at exit.
        params: true robot parameters (default PogoXParams()).
        rt_priority: >0: SCHED_FIFO at this priority, memory locked, PM QoS ``cpu_latency_us``
            held (each if permitted; steadier real-time pacing, see :mod:`.realtime`).
        cpu_latency_us: PM QoS CPU wake-up latency bound [us] while real time (None: no request).
        cpus: pin the vehicle to these CPUs (None: any).
    """

    url: str = "udpout:127.0.0.1:14540"
    baud: int | None = None
    sysid: int = 1
    compid: int = 1
    autopilot: str = "px4"
    lockstep: bool = False
    lockstep_timeout: float = 1.0
    scenario: str = "flying"
    seed: int = 0
    noise: bool = True
    start: str = "hover"
    start_offset: tuple = (0.0, 0.0)
    start_yaw: float = 0.0
    com_of_loss_t: float = 1.0
    loss_action: str = "hold"
    guid_options: int = 0
    duration: float | None = None
    default_rates: dict = field(default_factory=lambda: {"ATTITUDE": 10.0, "LOCAL_POSITION_NED": 10.0})
    silence: list = field(default_factory=list)
    truth_log: str | None = None
    params: PogoXParams | None = None
    rt_priority: int = 0
    cpu_latency_us: int | None = 0
    cpus: tuple | None = None
    verbose: bool = False

    def __post_init__(self) -> None:
        if self.autopilot not in ("px4", "ardupilot"):
            raise ValueError(f"autopilot must be 'px4' or 'ardupilot'; got {self.autopilot!r}")
        if self.start not in ("hover", "disarmed"):
            raise ValueError(f"start must be 'hover' or 'disarmed'; got {self.start!r}")
        off = tuple(float(v) for v in self.start_offset)
        if len(off) != 2 or not all(math.isfinite(v) for v in off):
            raise ValueError(f"start_offset must be two finite numbers (x, y) [m]; got {self.start_offset!r}")
        if not math.isfinite(self.start_yaw):
            raise ValueError(f"start_yaw must be finite; got {self.start_yaw!r}")
        if self.loss_action not in (MODE_HOLD, MODE_LAND):
            raise ValueError(f"loss_action must be 'hold' or 'land'; got {self.loss_action!r}")


class SimVehicle:
    """The simulated PX4-like vehicle. ``run()`` serves until stopped / ``duration``."""

    def __init__(self, config: VehicleConfig, link: MavLink | None = None) -> None:
        self.cfg = c = config
        self.params = p = c.params or PogoXParams()
        self.link = link or MavLink(c.url, baud=c.baud, source_system=c.sysid, source_component=c.compid,
                                    target_system=None)
        self.dt = p.control_dt
        self.h = p.physics_dt
        self.nsub = p.substeps
        self.plant = PogoXPlant(p)
        sc = get_scenario(c.scenario)
        self.start_position = np.array(sc.initial_position(p), dtype=float)
        self.start_position[:2] += np.asarray(c.start_offset, dtype=float)
        self.plant.reset(self.start_position, quaternion=quat_from_euler(0.0, 0.0, float(c.start_yaw)))
        self.fc = PX4LikeFlightController(p)
        self.att_every = max(1, int(round(p.fc.rate_hz / p.fc.att_hz)))
        self.rate_every = max(1, int(round(1.0 / (p.fc.rate_hz * self.h))))
        self.rng = np.random.default_rng(c.seed)
        self.noise = SensorNoise() if c.noise else None
        d_steps = int(round(p.meas_delay / self.h))
        self._buf: deque = deque(maxlen=d_steps + 1)
        self._buf.append((0.0, self.plant.state.tolist(), self.plant.mode))
        self.ardu = ArduPilotProfile(guid_options=c.guid_options) if c.autopilot == "ardupilot" else None
        # Vehicle state machine.
        self.armed = c.start == "hover"
        self.mode = MODE_HOLD
        self.ardu_mode = ARDUCOPTER_MODES["LOITER"]  # what HEARTBEAT says on ArduPilot
        self.px4_mode = (PX4_MAIN["AUTO"], PX4_AUTO_SUB["LOITER"])
        self.hold_point = self.start_position.copy()
        self.hold_yaw = float(c.start_yaw)
        self.com_of_loss_t = float(c.com_of_loss_t)
        self.guid_options = int(c.guid_options)
        self._landed_since: float | None = None
        # Setpoint from the link.
        self.sp_q_enu = np.array([1.0, 0.0, 0.0, 0.0])
        self.sp_field = 0.0
        self.sp_stamp = -1
        self.last_sp_time = -math.inf  # vehicle time of the newest SET_ATTITUDE_TARGET [s]
        # Streams: name -> interval [s] (0 = off), next due time.
        self.intervals: dict[str, float] = {n: 0.0 for n in _STREAM_IDS.values()}
        for name, hz in c.default_rates.items():
            self.intervals[name] = 1.0 / hz if hz > 0 else 0.0
        self._next_due: dict[str, float] = {n: 0.0 for n in self.intervals}
        self.k = 0
        self._step_count = 0
        self._stop = False
        self.events: list[tuple[float, str]] = []
        self.stats = {"overruns": 0, "setpoints": 0, "setpoints_ignored": 0, "commands": 0, "lockstep_timeouts": 0}
        self._truth = np.empty((4096, 27))
        self._truth_n = 0
        self._meas = None
        self._sp_queue: deque = deque()
        self._hb_wall = -math.inf

    # ------------------------------------------------------------------ time
    @property
    def t(self) -> float:
        """Vehicle (simulated) time of the current tick [s]."""
        return self.k * self.dt

    def stop(self, *_args) -> None:
        self._stop = True

    def _event(self, what: str) -> None:
        self.events.append((self.t, what))
        if self.cfg.verbose:
            print(f"[vehicle t={self.t:7.3f}] {what}", file=sys.stderr, flush=True)

    def _silent(self) -> bool:
        t = self.t
        return any(a <= t < b for a, b in self.cfg.silence)

    # ------------------------------------------------------------------ mode encoding
    def heartbeat_fields(self) -> tuple[int, int, int, int, int]:
        base = MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
        if self.armed:
            base |= MAV_MODE_FLAG_SAFETY_ARMED
        if self.ardu is not None:
            custom = self.ardu_mode
            ap = MAV_AUTOPILOT_ARDUPILOTMEGA
        else:
            custom = px4_custom_mode(*self.px4_mode)
            ap = MAV_AUTOPILOT_PX4
        status = mavlink.MAV_STATE_ACTIVE if self.armed else mavlink.MAV_STATE_STANDBY
        return mavlink.MAV_TYPE_QUADROTOR, ap, base, custom, status

    def mode_name(self) -> str:
        if self.ardu is not None:
            return {v: k for k, v in ARDUCOPTER_MODES.items()}.get(self.ardu_mode, str(self.ardu_mode))
        return px4_mode_name(px4_custom_mode(*self.px4_mode))

    def _send_heartbeat(self) -> None:
        if not self._silent():
            self.link.send_heartbeat(*self.heartbeat_fields())

    def _set_mode(self, mode: str, px4: tuple[int, int] | None = None, ardu: int | None = None, why: str = "") -> None:
        if mode == MODE_HOLD:
            self._hold_here()
        if mode == MODE_LAND:
            self._landed_since = None
        self.mode = mode
        if px4 is None:
            px4 = {MODE_OFFBOARD: (PX4_MAIN["OFFBOARD"], 0), MODE_HOLD: (PX4_MAIN["AUTO"], PX4_AUTO_SUB["LOITER"]),
                   MODE_LAND: (PX4_MAIN["AUTO"], PX4_AUTO_SUB["LAND"])}[mode]
        if ardu is None:
            ardu = {MODE_OFFBOARD: ARDUCOPTER_MODES["GUIDED_NOGPS"], MODE_HOLD: ARDUCOPTER_MODES["LOITER"],
                    MODE_LAND: ARDUCOPTER_MODES["LAND"]}[mode]
        self.px4_mode, self.ardu_mode = px4, ardu
        self._event(f"mode {self.mode_name()}" + (f" ({why})" if why else ""))
        self._send_heartbeat()  # tell the companion at once, not at the next 1 Hz beat

    def _hold_here(self) -> None:
        self.hold_point = self.plant.state[0:3].copy()
        self.hold_yaw = float(euler_from_quat(self.plant.state[6:10])[2])

    def _set_armed(self, armed: bool, why: str = "") -> None:
        if armed == self.armed:
            return
        self.armed = armed
        if armed and self.mode != MODE_OFFBOARD:
            self._hold_here()
        self._event(("armed" if armed else "disarmed") + (f" ({why})" if why else ""))
        self._send_heartbeat()

    # ------------------------------------------------------------------ incoming
    def _process(self, now_wall: float) -> bool:
        """Handle everything pending. Returns True if a setpoint stamped with the current tick arrived."""
        got = False
        for msg, rx in self.link.drain():
            typ = msg.get_type()
            if typ == "SET_ATTITUDE_TARGET":
                got |= self._on_setpoint(msg, rx)
            elif typ == "COMMAND_LONG":
                self._on_command(msg)
            elif typ in ("PARAM_REQUEST_READ", "PARAM_SET"):
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
        self.sp_stamp = int(msg.time_boot_ms)
        self.last_sp_time = self.t
        self.stats["setpoints"] += 1
        if self.cfg.lockstep:
            self._take_setpoint(q_enu, float(msg.thrust))
        else:
            self._sp_queue.append((rx, q_enu, float(msg.thrust)))  # takes effect at its arrival time
        return self.sp_stamp == self._stamp_ms()

    def _take_setpoint(self, q_enu, field: float) -> None:
        self.sp_q_enu, self.sp_field = q_enu, field
        if self.mode == MODE_OFFBOARD and self.armed:
            self._apply_offboard()

    def _apply_offboard(self) -> None:
        """Hand the link's setpoint to the flight controller (thrust semantics per autopilot)."""
        if self.ardu is not None and self.ardu.climb_rate_thrust:
            # ArduPilot: thrust field = climb rate; its own altitude loop makes the thrust.
            vz_sp = self.ardu.field_to_climb_rate(self.sp_field)
            thrust = self._climb_thrust(vz_sp, self.sp_q_enu)
            self.fc.set_attitude_target(self.sp_q_enu, thrust)
        else:
            self.fc.set_attitude_target(self.sp_q_enu, self.sp_field)

    def _climb_thrust(self, vz_sp: float, q_enu) -> float:
        s = self.plant.state
        r, p, _ = euler_from_quat(q_enu)
        acc = self.params.g + 4.0 * (vz_sp - s[5])
        tilt = max(math.cos(r) * math.cos(p), 0.5)
        return min(max(self.params.mass * acc / tilt / self.params.max_thrust, 0.0), 1.0)

    def _ack(self, msg, result: int) -> None:
        self.stats["commands"] += 1
        if self._silent():
            return
        self.link.send(self.link.mav.command_ack_encode(msg.command, result, 0, 0, msg.get_srcSystem(),
                                                        msg.get_srcComponent()))

    def _on_command(self, msg) -> None:
        if not self._for_me(msg):
            return
        cmd = msg.command
        R = mavlink
        if cmd == R.MAV_CMD_SET_MESSAGE_INTERVAL:
            name = _STREAM_IDS.get(int(msg.param1))
            if name is None:
                self._ack(msg, R.MAV_RESULT_UNSUPPORTED)
                return
            iv = msg.param2
            if iv == -1:
                self.intervals[name] = 0.0
            elif iv == 0:
                hz = self.cfg.default_rates.get(name, 0.0)
                self.intervals[name] = 1.0 / hz if hz > 0 else 0.0
            else:
                self.intervals[name] = max(iv * 1e-6, 0.0)
            self._next_due[name] = self.t
            self._ack(msg, R.MAV_RESULT_ACCEPTED)
        elif cmd == R.MAV_CMD_COMPONENT_ARM_DISARM:
            if msg.param1 >= 0.5:
                if self.mode == MODE_OFFBOARD and self.t - self.last_sp_time > self.com_of_loss_t:
                    self._ack(msg, R.MAV_RESULT_DENIED)
                    return
                self._set_armed(True, "command")
                self._ack(msg, R.MAV_RESULT_ACCEPTED)
            else:
                airborne = self.plant.mode != STANCE and self.plant.state[2] > self.params.leg_rest_length + 0.05
                if airborne and msg.param2 != _FORCE_DISARM:
                    self._ack(msg, R.MAV_RESULT_DENIED)  # PX4 refuses to disarm in flight unless forced
                    return
                self._set_armed(False, "command")
                self._ack(msg, R.MAV_RESULT_ACCEPTED)
        elif cmd == R.MAV_CMD_DO_SET_MODE:
            self._ack(msg, self._set_mode_cmd(msg))
        elif cmd == R.MAV_CMD_REQUEST_MESSAGE and int(msg.param1) == R.MAVLINK_MSG_ID_HEARTBEAT:
            self._ack(msg, R.MAV_RESULT_ACCEPTED)
            self._send_heartbeat()
        else:
            self._ack(msg, R.MAV_RESULT_UNSUPPORTED)

    def _set_mode_cmd(self, msg) -> int:
        R = mavlink
        if not int(msg.param1) & MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return R.MAV_RESULT_UNSUPPORTED
        if self.ardu is not None:
            num = int(msg.param2)
            if num in (ARDUCOPTER_MODES["GUIDED"], ARDUCOPTER_MODES["GUIDED_NOGPS"]):
                mode = MODE_OFFBOARD
            elif num in (ARDUCOPTER_MODES["LOITER"], ARDUCOPTER_MODES["BRAKE"], ARDUCOPTER_MODES["ALT_HOLD"],
                         ARDUCOPTER_MODES["POSHOLD"]):
                mode = MODE_HOLD
            elif num == ARDUCOPTER_MODES["LAND"]:
                mode = MODE_LAND
            else:
                return R.MAV_RESULT_UNSUPPORTED
            self._set_mode(mode, ardu=num, why="command")
            if mode == MODE_OFFBOARD and self.t - self.last_sp_time <= self.com_of_loss_t:
                self._apply_offboard()
            return R.MAV_RESULT_ACCEPTED
        main, sub = int(msg.param2), int(msg.param3)
        if main == PX4_MAIN["OFFBOARD"]:
            if self.t - self.last_sp_time > self.com_of_loss_t:
                return R.MAV_RESULT_TEMPORARILY_REJECTED  # PX4: no offboard signal, no OFFBOARD
            self._set_mode(MODE_OFFBOARD, px4=(main, 0), why="command")
            if self.armed:
                self._apply_offboard()
            return R.MAV_RESULT_ACCEPTED
        if main == PX4_MAIN["AUTO"] and sub == PX4_AUTO_SUB["LAND"]:
            self._set_mode(MODE_LAND, px4=(main, sub), why="command")
            return R.MAV_RESULT_ACCEPTED
        loiter = main == PX4_MAIN["AUTO"] and sub == PX4_AUTO_SUB["LOITER"]
        if loiter or main in (PX4_MAIN["POSCTL"], PX4_MAIN["ALTCTL"]):
            self._set_mode(MODE_HOLD, px4=(main, sub), why="command")
            return R.MAV_RESULT_ACCEPTED
        return R.MAV_RESULT_UNSUPPORTED

    def _params(self) -> dict[str, tuple[float, int]]:
        if self.ardu is not None:
            return {"GUID_OPTIONS": (float(self.guid_options), mavlink.MAV_PARAM_TYPE_INT32)}
        return {"COM_OF_LOSS_T": (self.com_of_loss_t, mavlink.MAV_PARAM_TYPE_REAL32)}

    def _on_param(self, msg) -> None:
        if not self._for_me(msg):
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
        if name in table and not self._silent():
            val, typ = table[name]
            idx = list(table).index(name)
            self.link.send(self.link.mav.param_value_encode(name.encode(), val, typ, len(table), idx))

    # ------------------------------------------------------------------ outgoing
    def _stamp_ms(self) -> int:
        return int(round(self.t * 1000.0))

    def _measure(self):
        """The measured state of this tick (delayed, noisy), as loop.py builds it."""
        _tm, sm, _mode = self._buf[0]
        pos = np.array(sm[0:3])
        vel = np.array(sm[3:6])
        eul = euler_from_quat(sm[6:10])
        rates = np.array(sm[10:13])
        n = self.noise
        if n is not None:
            rng = self.rng
            pos = pos + rng.normal(0.0, n.position, 3)
            vel = vel + rng.normal(0.0, n.velocity, 3)
            eul = eul + rng.normal(0.0, n.angle, 3)
            rates = rates + rng.normal(0.0, n.rate, 3)
        return pos, vel, eul, rates

    def _publish(self, meas) -> None:
        if self._silent():
            return
        t = self.t
        due = [name for name, iv in self.intervals.items() if iv > 0.0 and t + 1e-9 >= self._next_due[name]]
        if not due:
            return
        pos, vel, eul, rates = meas
        ms = self._stamp_ms()
        mav = self.link.mav
        p_ned = (float(pos[1]), float(pos[0]), float(-pos[2]))
        v_ned = (float(vel[1]), float(vel[0]), float(-vel[2]))
        w_frd = (float(rates[0]), float(-rates[1]), float(-rates[2]))
        q_ned = None
        out = []
        for name in due:
            iv = self.intervals[name]
            nd = self._next_due[name] + iv
            self._next_due[name] = nd if nd > t else t + iv
            if name == "ATTITUDE":
                r, p, y = euler_ned_from_enu(eul)
                msg = mav.attitude_encode(ms, r, p, y, *w_frd)
            elif name in ("ATTITUDE_QUATERNION", "ODOMETRY"):
                if q_ned is None:
                    q_ned = quat_ned_frd_from_enu_flu(quat_from_euler(*eul))
                if name == "ATTITUDE_QUATERNION":
                    msg = mav.attitude_quaternion_encode(ms, *(float(v) for v in q_ned), *w_frd, (0.0, 0.0, 0.0, 0.0))
                else:
                    v_body = rotate_inverse(q_ned, v_ned)
                    nan21 = [math.nan] * 21
                    msg = mav.odometry_encode(ms * 1000, mavlink.MAV_FRAME_LOCAL_NED, mavlink.MAV_FRAME_BODY_FRD,
                                              *p_ned, [float(v) for v in q_ned], *v_body, *w_frd, nan21, nan21,
                                              0, mavlink.MAV_ESTIMATOR_TYPE_MOCAP, 100)
            else:
                msg = mav.local_position_ned_encode(ms, *p_ned, *v_ned)
            out.append(msg)
        self.link.send_many(out)  # one datagram per tick

    # ------------------------------------------------------------------ own flight modes
    def _autopilot_setpoint(self) -> None:
        """HOLD / LAND: the vehicle's own position controller (true mass, true state)."""
        s = self.plant.state
        p, v = s[0:3], s[3:6]
        g = self.params.g
        kp_xy, kd_xy = 2.0, 2.5
        ax = kp_xy * (self.hold_point[0] - p[0]) - kd_xy * v[0]
        ay = kp_xy * (self.hold_point[1] - p[1]) - kd_xy * v[1]
        if self.mode == MODE_LAND:
            az = 3.0 * (-0.5 - v[2])
            if self.plant.mode == STANCE and abs(v[2]) < 0.2:
                if self._landed_since is None:
                    self._landed_since = self.t
                elif self.t - self._landed_since > 0.5:
                    self._set_armed(False, "landed")
                    return
            else:
                self._landed_since = None
        else:
            az = 6.0 * (self.hold_point[2] - p[2]) - 4.0 * v[2]
        lim = math.tan(math.radians(20.0)) * (g + az)
        # World accelerations in the heading frame (forward, left): pitch drives forward, roll left.
        cy, sy = math.cos(self.hold_yaw), math.sin(self.hold_yaw)
        af, al = cy * ax + sy * ay, -sy * ax + cy * ay
        af, al = max(-lim, min(lim, af)), max(-lim, min(lim, al))
        pitch = math.atan2(af, g + az)
        roll = math.atan2(-al * math.cos(pitch), g + az)
        thrust = self.params.mass * (g + az) / max(math.cos(roll) * math.cos(pitch), 0.5) / self.params.max_thrust
        self.fc.set_attitude_target(quat_from_euler(roll, pitch, self.hold_yaw), min(max(thrust, 0.0), 1.0))

    def _failsafe_check(self) -> None:
        if self.mode == MODE_OFFBOARD and self.armed and self.t - self.last_sp_time > self.com_of_loss_t:
            self._set_mode(self.cfg.loss_action, why=f"offboard setpoints lost for > {self.com_of_loss_t:g} s")

    # ------------------------------------------------------------------ physics
    def _substep(self) -> None:
        if not self.armed:
            return  # parked: frozen state
        plant, fc = self.plant, self.fc
        s = plant.state
        if self._step_count % self.att_every == 0:
            fc.attitude_update(s[6:10])
        if self._step_count % self.rate_every == 0:
            self._cmd = fc.rate_update(s[10:13], self.h * self.rate_every)
        plant.step(self.h, self._cmd)
        self._step_count += 1
        self._buf.append((plant.t, plant.state.tolist(), plant.mode))

    def _log_truth(self) -> None:
        if not self.cfg.truth_log:
            return
        # Preallocated float rows (doubling): a growing list of tuples would make the garbage
        # collector's full passes longer and longer -- multi-ms stalls of the real-time loop.
        if self._truth_n == self._truth.shape[0]:
            self._truth = np.concatenate([self._truth, np.empty_like(self._truth)])
        row = self._truth[self._truth_n]
        row[0] = self.t
        row[1:20] = self.plant.state
        row[20] = self.armed
        row[21] = self.mode == MODE_OFFBOARD
        row[22:26] = self.fc.q_sp
        row[26] = self.fc.thrust_sp
        self._truth_n += 1

    # ------------------------------------------------------------------ main loop
    def run(self, install_signals: bool = True) -> dict:
        """Serve until stopped (signal, :meth:`stop`) or ``duration``; returns a summary."""
        if install_signals:
            signal.signal(signal.SIGINT, self.stop)
            signal.signal(signal.SIGTERM, self.stop)
        self._cmd = [self.params.hover_omega] * 4
        rt = setup_realtime(self.cfg.rt_priority, cpus=self.cfg.cpus, cpu_latency_us=self.cfg.cpu_latency_us)
        self.scheduling = rt.describe()
        # The loop allocates short-lived objects only; collect the young generation often (cheap)
        # and never let a full collection land in the middle of a tick.
        gc.collect()
        gc.freeze()
        gc.set_threshold(5000, 1000, 1_000_000)
        try:
            if self.cfg.lockstep:
                self._run_lockstep()
            else:
                self._run_realtime()
        finally:
            rt.release()
            gc.set_threshold(700, 10, 10)
            gc.unfreeze()
            self._write_truth()
            self.link.close()
        return self.summary()

    def _tick_start(self, now: float) -> None:
        """At a tick boundary: heartbeat, failsafe, own-mode setpoint, measure, log, publish."""
        if now - self._hb_wall >= 1.0:
            # 1 Hz of wall time: the companion's link monitor runs on wall time.
            self._hb_wall = now
            self._send_heartbeat()
        self._failsafe_check()
        if self.armed and self.mode != MODE_OFFBOARD:
            self._autopilot_setpoint()
        self._meas = self._measure()
        self._log_truth()
        self._publish(self._meas)

    def _run_lockstep(self) -> None:
        c = self.cfg
        while not self._stop and not (c.duration is not None and self.t >= c.duration - 1e-9):
            self._process(time.monotonic())
            self._tick_start(time.monotonic())
            self._wait_lockstep()  # the setpoint stamped with this tick is applied on arrival
            for _ in range(self.nsub):
                self._substep()
            self.k += 1

    def _run_realtime(self) -> None:
        """One wake-up per 5 ms tick. At the boundary W_(k+1) the physics of tick k is simulated
        (1 ms steps), each setpoint taking effect at the first step that starts after its kernel
        receive time, and then the telemetry of tick k+1 goes out. So the vehicle never computes
        while the bridge does, and the physics never runs ahead of the wall clock."""
        c = self.cfg
        wall0 = time.monotonic()
        lag = 0.0  # added after a stall: real time resumes, it never races to catch up
        self._process(wall0)
        self._tick_start(wall0)
        while not self._stop and not (c.duration is not None and self.t >= c.duration - 1e-9):
            w_k = wall0 + lag + self.k * self.dt
            target = w_k + self.dt
            now = time.monotonic()
            if now - target > 0.05:
                # More than 50 ms late (machine stalled): resume real time from here.
                lag += now - target
                self.stats["overruns"] += 1
                w_k, target = now - self.dt, now
            elif target > now:
                time.sleep(target - now)
            self._process(time.monotonic())
            queue = self._sp_queue
            for j in range(self.nsub):
                t_j = w_k + j * self.h
                while queue and queue[0][0] <= t_j:
                    _rx, q, f = queue.popleft()
                    self._take_setpoint(q, f)
                self._substep()
            self.k += 1
            self._tick_start(time.monotonic())

    def _wait_lockstep(self) -> None:
        deadline = time.monotonic() + self.cfg.lockstep_timeout
        if self._process(time.monotonic()):
            return
        while not self._stop:
            rem = deadline - time.monotonic()
            if rem <= 0:
                self.stats["lockstep_timeouts"] += 1
                return
            if self.link.wait(min(rem, 0.05)) and self._process(time.monotonic()):
                return

    def summary(self) -> dict:
        return {"sim_time": self.t, "ticks": self.k, "mode": self.mode_name(), "armed": self.armed,
                "scheduling": getattr(self, "scheduling", ""),
                "events": [[round(t, 3), e] for t, e in self.events], **self.stats, "link": dict(self.link.stats)}

    def _write_truth(self) -> None:
        if not self.cfg.truth_log or not self._truth_n:
            return
        a = self._truth[: self._truth_n]
        path = Path(self.cfg.truth_log)
        path.parent.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(path, t=a[:, 0], state=a[:, 1:20], armed=a[:, 20].astype(bool),
                            offboard=a[:, 21].astype(bool), fc_q_sp=a[:, 22:26], fc_thrust_sp=a[:, 26],
                            dt=self.dt)

