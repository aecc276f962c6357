"""Console entry point ``ddpc-vehicle``: the PogoX simulator behind a PX4- or ArduCopter-like MAVLink
endpoint (``python -m ddpc_codegen.testbed.vehicle_cli ...`` without the console script)."""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

from firmware_bridge.cli_args import add_realtime_args, floats, push_spec, qos_request, time_window
from ddpc_codegen.testbed.vehicle import SimVehicle, VehicleConfig
from firmware_bridge.link import LinkError

__all__ = ["build_vehicle_parser", "vehicle_main"]


def build_vehicle_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="ddpc-vehicle",
        description="The PogoX simulator behind a MAVLink endpoint that behaves like PX4 (or ArduCopter) in "
                    "off-board: heartbeat, telemetry at requested rates, arm / mode commands, SET_ATTITUDE_TARGET and "
                    "SET_POSITION_TARGET_LOCAL_NED (its own cascaded position controller), off-board-loss "
                    "failsafe.",
    )
    p.add_argument("connection", nargs="?", default="udpout:127.0.0.1:14540",
                   help="connection string (default udpout:127.0.0.1:14540, to a bridge listening there)")
    p.add_argument("--baud", type=int, default=None)
    p.add_argument("--autopilot", choices=("px4", "ardupilot"), default="px4")
    p.add_argument("--sysid", type=int, default=1)
    p.add_argument("--compid", type=int, default=1)
    p.add_argument("--lockstep", action="store_true", help="advance one tick per setpoint (fast, deterministic)")
    p.add_argument("--lockstep-timeout", type=float, default=1.0, help="lockstep: max wall wait per tick [s]")
    p.add_argument("--peer-timeout", type=float, default=5.0,
                   help="lockstep: end when the companion, once heard, has been silent this long [s] (0: never)")
    p.add_argument("--scenario", choices=("flying", "hopping"), default="flying",
                   help="the simulator's robot and start point: flying (hover at the ellipse's start) or hopping "
                        "(hover at the 0.7 m release height; the bridge hops it with --scenario hopping)")
    p.add_argument("--contact-signal", nargs="?", const="CONTACT", default=None, metavar="NAME",
                   help="publish the foot-contact flag as NAMED_VALUE_INT NAME (default CONTACT; 1 = foot on the "
                        "ground) with every telemetry sample, as a leg sensor would")
    p.add_argument("--seed", type=int, default=0, help="sensor-noise seed")
    p.add_argument("--no-noise", action="store_true", help="no sensor noise (the delay stays)")
    p.add_argument("--start", choices=("hover", "disarmed"), default="hover",
                   help="hover: armed in HOLD at the start point; disarmed: parked there")
    p.add_argument("--start-offset", type=floats, default=(0.0, 0.0), metavar="X,Y",
                   help="start this far from the trajectory's start point [m, local ENU]")
    p.add_argument("--start-yaw-deg", type=float, default=0.0, help="initial heading [deg, ENU: 0 = east, 90 = north]")
    p.add_argument("--com-of-loss-t", type=float, default=1.0, help="off-board loss timeout [s] (PX4 COM_OF_LOSS_T)")
    p.add_argument("--loss-action", choices=("hold", "land"), default="hold", help="failsafe after off-board loss")
    p.add_argument("--guid-options", type=int, default=0, help="ArduPilot GUID_OPTIONS (8: thrust is a thrust)")
    p.add_argument("--hover-thrust", type=float, default=None, metavar="THR",
                   help="the autopilot's hover-thrust estimate for its position controller (MPC_THR_HOVER / "
                        "MOT_THST_HOVER, also what the parameter reads; default: the true one, 0.8). Lower: a "
                        "vehicle heavier than its autopilot believes")
    p.add_argument("--duration", type=float, default=None, help="stop after this much simulated time [s]")
    p.add_argument("--silence", type=time_window, action="append", default=[], metavar="T0:T1",
                   help="send nothing during this simulated-time window (repeatable)")
    p.add_argument("--truth-log", default=None, help="write the true state per tick to this .npz")
    p.add_argument("--setpoint-log", default=None, metavar="FILE",
                   help="write every SET_POSITION_TARGET_LOCAL_NED received (receive time, sender, sequence, fields) "
                        "to this .npz at exit")
    p.add_argument("--summary", default=None, help="write the summary JSON here")
    p.add_argument("--telemetry-pattern", choices=("regular", "px4-sih", "ardupilot"), default="regular",
                   help="which telemetry samples exist: regular (one per 5 ms tick, stamped with its time); "
                        "px4-sih (PX4 SITL/SIH defaults: stamps step 4/8/12/16 ms, ~118 distinct samples/s, "
                        "whole ms); ardupilot (ArduCopter SITL: ~171 samples/s, every ~6th missing, and "
                        "TCP-like bursts of two samples arriving < 0.5 ms apart)")
    p.add_argument("--telemetry-seed", type=int, default=0, help="seed of the telemetry pattern")
    p.add_argument("--push", type=push_spec, action="append", default=[], metavar="T:FX,FY,FZ[:DUR]",
                   help="push the robot with force (FX, FY, FZ) [N, world ENU] from plant time T [s] for DUR "
                        "[s] (default 0.1; repeatable)")
    add_realtime_args(p, "the vehicle")
    p.add_argument("-v", "--verbose", action="store_true")
    return p


def vehicle_main(argv: list[str] | None = None) -> int:
    """``ddpc-vehicle``: serve until SIGINT / SIGTERM or --duration; exit 0."""
    a = build_vehicle_parser().parse_args(argv)

    try:
        cfg = VehicleConfig(url=a.connection, baud=a.baud, sysid=a.sysid,
                            compid=a.compid, autopilot=a.autopilot, lockstep=a.lockstep, scenario=a.scenario,
                            contact_signal=a.contact_signal,
                            lockstep_timeout=a.lockstep_timeout, peer_timeout=a.peer_timeout, seed=a.seed, noise=not a.no_noise, start=a.start,
                            start_offset=a.start_offset, start_yaw=math.radians(a.start_yaw_deg),
                            com_of_loss_t=a.com_of_loss_t, loss_action=a.loss_action, guid_options=a.guid_options,
                            hover_thrust=a.hover_thrust,
                            duration=a.duration, silence=list(a.silence), truth_log=a.truth_log,
                            setpoint_log=a.setpoint_log,
                            rt_priority=a.rt_priority, cpu_latency_us=qos_request(a.cpu_latency_us), cpus=a.cpus,
                            verbose=a.verbose, telemetry_pattern=a.telemetry_pattern,
                            telemetry_seed=a.telemetry_seed, pushes=list(a.push))
        veh = SimVehicle(cfg)
    except (ValueError, OSError, LinkError) as e:
        print(f"ddpc-vehicle: error: {e}", file=sys.stderr)
        return 2
    summary = veh.run()
    if a.summary:
        Path(a.summary).parent.mkdir(parents=True, exist_ok=True)
        Path(a.summary).write_text(json.dumps(summary, indent=2, default=str) + "\n")
    if a.verbose:
        print(json.dumps(summary, default=str), file=sys.stderr)
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(vehicle_main(sys.argv[1:] if sys.argv[1:2] != ["vehicle"] else sys.argv[2:]))
