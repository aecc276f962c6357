"""Options of the simulated vehicle ``ddpc-vehicle`` (see :mod:`ddpc_codegen.testbed.vehicle`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from ddpc_codegen.testbed.vehicle_telemetry import TELEMETRY_PATTERNS

__all__ = ["VehicleConfig", "MODE_OFFBOARD", "MODE_HOLD", "MODE_LAND"]

MODE_OFFBOARD, MODE_HOLD, MODE_LAND = "offboard", "hold", "land"


@dataclass
class VehicleConfig:
    """Options of the simulated vehicle (see the module docstring).

    Attributes:
        url: MAVLink connection string (e.g. ``udpout:127.0.0.1:14540``, the bridge listening);
            baud: serial baud rate.
        sysid, compid: the vehicle's MAVLink identity.
        autopilot: "px4" or "ardupilot".
        lockstep: advance one tick per setpoint (see module docstring); lockstep_timeout [s wall].
        peer_timeout: lockstep: once a companion has been heard, end the run when nothing has
            arrived from it for this long [s wall] (the bridge is gone; 0: never).
        scenario: the simulator's scenario whose robot and start point the vehicle is: "flying"
            (hover at the ellipse's start) or "hopping" (hover at the release height; the plant
            models the leg's ground contact either way).
        contact_signal: publish the foot-contact flag as a NAMED_VALUE_INT of this name with every
            telemetry sample (1 = foot on the ground, from the same delayed measurement as the
            sample; what a leg sensor would send); None: not published.
        seed, noise: sensor-noise seed and switch (the simulator's SensorNoise defaults).
        start: "hover" (armed, HOLD at the start point) or "disarmed" (parked at the start point).
        start_offset: (x, y) added to the scenario's start point [m, local ENU] (a robot that is
            not where the trajectory starts). start_yaw: initial heading [rad, ENU: 0 = east];
            the vehicle's own HOLD / LAND keep the heading they start with.
        com_of_loss_t: off-board setpoint-loss timeout [s] (PX4 COM_OF_LOSS_T).
        loss_action: failsafe after the loss: "hold" or "land".
        guid_options: ArduPilot GUID_OPTIONS (bit 3: thrust field is a thrust, else a climb rate).
        hover_thrust: the autopilot's hover-thrust estimate (MPC_THR_HOVER / MOT_THST_HOVER) its
            position controller uses and the parameter reports [normalized thrust, (0, 1)]; None:
            the true one. Below the truth: a vehicle heavier than its autopilot believes.
        duration: stop after this much simulated time [s] (None: run until signalled).
        default_rates: telemetry rates [Hz] before anyone asks (message name -> Hz).
        silence: simulated-time windows [(t0, t1), ...] [s] in which the vehicle sends nothing
            (a link-drop / vehicle-silent test).
        truth_log: write the true state per tick to this .npz at exit.
        setpoint_log: write every SET_POSITION_TARGET_LOCAL_NED received to this .npz at exit.
        params: true robot parameters (a :class:`ddpc_codegen.sim.PogoXParams`; default PogoXParams()).
        pushes: external force impulses on the robot (:class:`ddpc_codegen.sim.Push` or tuples
            (t, force(3), duration[, point(3)]); plant time [s], which stands still while parked).
        telemetry_pattern: which telemetry samples exist: "regular" (one per 5 ms tick),
            "px4-sih" or "ardupilot" (real autopilots' irregular stamps, see
            :mod:`ddpc_codegen.testbed.vehicle_telemetry`); telemetry_seed seeds the pattern.
        rt_priority: >0: SCHED_FIFO at this priority, memory locked, PM QoS ``cpu_latency_us``
            held (each if permitted; steadier real-time pacing, see :mod:`.realtime`).
        cpu_latency_us: PM QoS CPU wake-up latency bound [us] while real time (None: no request).
        cpus: pin the vehicle to these CPUs (None: any).
        verbose: print mode / arming events on stderr.
    """

    url: str = "udpout:127.0.0.1:14540"
    baud: int | None = None
    sysid: int = 1
    compid: int = 1
    autopilot: str = "px4"
    lockstep: bool = False
    lockstep_timeout: float = 1.0
    peer_timeout: float = 5.0
    scenario: str = "flying"
    contact_signal: str | None = None
    seed: int = 0
    noise: bool = True
    start: str = "hover"
    start_offset: tuple = (0.0, 0.0)
    start_yaw: float = 0.0
    com_of_loss_t: float = 1.0
    loss_action: str = "hold"
    guid_options: int = 0
    hover_thrust: float | None = None
    duration: float | None = None
    default_rates: dict = field(default_factory=lambda: {"ATTITUDE": 10.0, "LOCAL_POSITION_NED": 10.0})
    silence: list = field(default_factory=list)
    truth_log: str | None = None
    setpoint_log: str | None = None
    params: Any = None
    pushes: list = field(default_factory=list)
    telemetry_pattern: str = "regular"
    telemetry_seed: int = 0
    rt_priority: int = 0
    cpu_latency_us: int | None = 0
    cpus: tuple | None = None
    verbose: bool = False

    def __post_init__(self) -> None:
        if self.autopilot not in ("px4", "ardupilot"):
            raise ValueError(f"autopilot must be 'px4' or 'ardupilot'; got {self.autopilot!r}")
        if self.scenario not in ("flying", "hopping"):
            raise ValueError(f"scenario must be 'flying' or 'hopping'; got {self.scenario!r}")
        if self.contact_signal is not None and not (0 < len(self.contact_signal) <= 10
                                                    and self.contact_signal.isascii()):
            raise ValueError("contact_signal must be an ASCII name of 1-10 characters (NAMED_VALUE_INT.name); "
                             f"got {self.contact_signal!r}")
        if self.start not in ("hover", "disarmed"):
            raise ValueError(f"start must be 'hover' or 'disarmed'; got {self.start!r}")
        off = tuple(float(v) for v in self.start_offset)
        if len(off) != 2 or not all(math.isfinite(v) for v in off):
            raise ValueError(f"start_offset must be two finite numbers (x, y) [m]; got {self.start_offset!r}")
        if not math.isfinite(self.start_yaw):
            raise ValueError(f"start_yaw must be finite; got {self.start_yaw!r}")
        if self.hover_thrust is not None and not 0.0 < self.hover_thrust < 1.0:
            raise ValueError(f"hover_thrust must be in (0, 1); got {self.hover_thrust!r}")
        if self.loss_action not in (MODE_HOLD, MODE_LAND):
            raise ValueError(f"loss_action must be 'hold' or 'land'; got {self.loss_action!r}")
        if self.telemetry_pattern not in TELEMETRY_PATTERNS:
            raise ValueError(f"telemetry_pattern must be one of {', '.join(TELEMETRY_PATTERNS)}; "
                             f"got {self.telemetry_pattern!r}")
