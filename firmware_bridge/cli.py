"""Console entry point ``ddpc-bridge`` (:func:`bridge_main`); ``python -m firmware_bridge.cli bridge ...``
without the console script. The simulated vehicle (``ddpc-vehicle``) lives in :mod:`ddpc_codegen.testbed.vehicle_cli`.

Typical use (loopback)::

    ddpc-vehicle udpout:127.0.0.1:14540 &                       # simulated PX4, hovering in HOLD
    ddpc-bridge udpin:127.0.0.1:14540 --mode collect --offboard --duration 60 --log flight.npz
    ddpc-codegen codegen configs/flying.toml --dataset flight.npz --out generated
    ddpc-bridge udpin:127.0.0.1:14540 --solver generated/flying --offboard --duration 20

On the robot: ``ddpc-bridge /dev/ttyAMA0:921600 --solver generated/flying --controller robot.toml``
(arming and the OFFBOARD switch stay with the pilot unless --arm / --offboard are given).
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import sys
import textwrap
from dataclasses import fields, replace

from ddpc_codegen.errors import DDPCError
from ddpc_codegen.robot.profile import load_profile
from ddpc_codegen.robot.trajectory_files import trajectory_from_arg

from firmware_bridge.bridge import Bridge, FlightError, NoVehicleError
from firmware_bridge.bridge_config import BRIDGE_MODES, BridgeConfig
from firmware_bridge.cli_args import (
    ATTITUDE_STREAMS,
    POSITION_STREAMS,
    add_realtime_args,
    host_port,
    margin_us,
    signing_key_file,
    fault_spec,
    floats,
    floats_or_none,
    qos_request,
)
from firmware_bridge.exit_status import exit_codes_epilog
from firmware_bridge.link import LinkError
from firmware_bridge.position_source import POSITION_SOURCES
from firmware_bridge.preflight import EnvelopeRefusal, PreflightError

__all__ = ["bridge_main", "build_bridge_parser", "main"]

# ----------------------------------------------------------------------------- bridge
def _bridge_defaults() -> dict:
    """BridgeConfig's field defaults: the flags' defaults are written once, in the dataclass."""
    return {f.name: f.default for f in fields(BridgeConfig)}


def _bridge_modes() -> tuple[str, ...]:
    return BRIDGE_MODES


_D = _bridge_defaults()


def build_bridge_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="ddpc-bridge",
        description="Run the generated steering solver and the height / leg-angle controller in the loop over "
                    "MAVLink: telemetry in, SET_ATTITUDE_TARGET out at 200 Hz.",
        epilog=textwrap.fill(
            "Modes: steer (DDPC on), passthrough (model-based controller alone, the baseline), collect (PRBS "
            "on the references; the --log file is an IODataset for `ddpc-codegen codegen --dataset`), "
            "prefilter (the static gain + offset + lead baseline fitted from a collect log), feedforward "
            "(r_nom + a learned ILC table, row = trajectory tick).", 100) + "\n\n" + exit_codes_epilog(),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("connection", nargs="?", default=_D["url"],
                   help="pymavlink-style connection: udpin:HOST:PORT, udpout:HOST:PORT, tcp:HOST:PORT or a serial "
                        "device (/dev/ttyACM0[:BAUD]) (default udpin:127.0.0.1:14540)")
    p.add_argument("--baud", type=int, default=None, help="serial baud rate (default 921600)")
    p.add_argument("--mode", choices=_bridge_modes(), default=_D["mode"])
    p.add_argument("--solver", default=None, help="generated solver folder (steer mode), e.g. generated/flying")
    p.add_argument("--scenario", choices=("flying", "hopping"), default=None,
                   help="flying (default) or hopping: the profile's controller mode; hopping without --profile is the "
                        "shipped pogox_hopping (phases from telemetry or a contact signal, see --contact)")
    p.add_argument("--prefilter", default=None,
                   help="prefilter JSON (prefilter mode; PrefilterModel.save, e.g. written by make sitl-demo)")
    p.add_argument("--feedforward", default=None,
                   help="feed-forward table npz (feedforward mode; FeedforwardPolicy.save with clock 'trajectory' "
                        "and dt = 1 / --rate, e.g. an ILC iteration of make sitl-demo)")
    _bridge_autopilot_args(p.add_argument_group("autopilot"))
    _bridge_loop_args(p.add_argument_group("loop"))
    _bridge_safety_args(p.add_argument_group("safety"))
    _bridge_logging_args(p.add_argument_group("logging"))
    return p


def _bridge_autopilot_args(g) -> None:
    g.add_argument("--autopilot", choices=("px4", "ardupilot"), default=_D["autopilot"])
    g.add_argument("--guid-options", type=int, default=None,
                   help="ArduPilot GUID_OPTIONS expected (bit 3 = thrust field is a thrust); default: the vehicle's "
                        "value, read before the first setpoint; refused if it disagrees with the vehicle")
    g.add_argument("--force-guid-options", action="store_true",
                   help="encode the thrust field for --guid-options even if the vehicle says otherwise")
    g.add_argument("--sysid", type=int, default=_D["sysid"], help="our system id (default 1: the vehicle's companion)")
    g.add_argument("--compid", type=int, default=_D["compid"], help="our component id (default 191, onboard computer)")
    g.add_argument("--target-system", type=int, default=_D["target_system"], help="vehicle system id (0: the first autopilot heard)")
    g.add_argument("--target-component", type=int, default=_D["target_component"], help="vehicle component id (0: any)")
    g.add_argument("--vehicle-address", type=host_port, default=None, metavar="HOST:PORT",
                   help="udpin: only the vehicle at this address counts and is answered (default: the first address "
                        "whose heartbeat carries the vehicle's ids)")
    g.add_argument("--signing-key", type=signing_key_file, default=None, metavar="FILE",
                   help="MAVLink 2 signing key (32 bytes, raw or 64 hex digits): sign what is sent, drop every packet "
                        "not signed with it")
    g.add_argument("--arm", action="store_true",
                   help="arm the vehicle once its telemetry arrives, retrying while refused (otherwise arming is left "
                        "to the pilot)")
    g.add_argument("--arm-timeout", type=float, default=_D["arm_timeout"],
                   help="give up arming after this many seconds: exit 5 with the autopilot's last refusal (default 120)")
    g.add_argument("--offboard", action="store_true",
                   help="switch to OFFBOARD (PX4) / GUIDED_NOGPS (ArduPilot) after --prestream s of setpoints, HOLD at "
                        "exit, LAND on stale telemetry with --stale-action land (otherwise no mode changes)")
    g.add_argument("--prestream", type=float, default=_D["prestream"], help="seconds of setpoints before the mode switch")
    g.add_argument("--takeoff", action="store_true",
                   help="at the first engagement ramp the height reference from where the vehicle is to the "
                        "trajectory's start height (heights count from the take-off point), then fly the trajectory")
    g.add_argument("--climb-rate", type=float, default=_D["climb_rate"], help="--takeoff ramp rate [m/s] (default 0.5)")
    g.add_argument("--approach-tolerance", type=float, default=_D["approach_tolerance"],
                   help="--takeoff: the trajectory starts once the height held within this of its start for 1 s "
                        "[m] (default 0.1)")
    g.add_argument("--approach-timeout", type=float, default=_D["approach_timeout"],
                   help="--takeoff: ... or, with a warning, this many seconds after the ramp (default 5)")
    g.add_argument("--land", action="store_true",
                   help="at exit hand back with LAND and wait for the vehicle to disarm (default: HOLD)")
    g.add_argument("--blend-rates", type=floats_or_none, default=",".join(map(str, _D["blend_rates"])), metavar="Z,PITCH|none",
                   help="bumpless (re-)engagement: the references start at the measured outputs and move toward the "
                        "nominal ones at most this fast [m/s, rad/s] (default 0.5,0.5; none: off)")


def _bridge_loop_args(g) -> None:
    g.add_argument("--rate", type=float, default=_D["rate_hz"], help="control rate [Hz] (default 200)")
    g.add_argument("--attitude-stream", choices=tuple(ATTITUDE_STREAMS), default="quaternion")
    g.add_argument("--position-stream", choices=tuple(POSITION_STREAMS), default="local")
    g.add_argument("--position-source", choices=POSITION_SOURCES, default=_D["position_source"],
                   help="the measured position the loop steers on: the autopilot's estimate (default) or the motion "
                        "capture's poses received on --mocap (a lab's measurement; stale poses make stale ticks)")
    g.add_argument("--mocap", default=None, metavar="URL",
                   help="where the motion-capture poses arrive (udpin:HOST:PORT; VISION_POSITION_ESTIMATE, "
                        "ATT_POS_MOCAP or ODOMETRY, local NED); logged beside the estimate, steered on with "
                        "--position-source mocap")
    g.add_argument("--lockstep", action="store_true", help="tick only on telemetry, vehicle time (ddpc-vehicle --lockstep)")
    g.add_argument("--tick-margin-us", type=margin_us, default=round(_D["tick_margin"] * 1e6, 3), metavar="US|free",
                   help="lock the tick grid's phase to this long after the position samples' late edge of arrivals (their "
                        "median plus three half interquartile ranges) "
                        "(the period is unchanged; free: the grid keeps its first tick's phase; default %(default)g)")
    g.add_argument("--duration", type=float, default=None, help="stop after this many seconds in off-board")
    g.add_argument("--timeout", type=float, default=None, help="stop after this many seconds of wall time")
    g.add_argument("--wait-heartbeat", type=float, default=_D["wait_heartbeat"], help="give up if no vehicle heartbeat [s]")
    g.add_argument("--trajectory", default=None, metavar="ellipse|random[:SEED]|FILE",
                   help="the desired trajectory: the profile's ellipse (default), a seeded random smooth path, or a "
                        ".csv / .toml trajectory file (columns t, x, z; see the README)")
    g.add_argument("--profile", "--controller", dest="controller", default=None, metavar="NAME|TOML",
                   help="robot profile: a shipped name (pogox) or a TOML with [controller] (ControllerConfig "
                        "fields: model_mass, max_thrust, kp_z, ...) and [trajectory] (EllipseTrajectory fields); "
                        "default: pogox, the simulated PogoX")
    g.add_argument("--contact", choices=("estimate", "signal"), default=None,
                   help="hopping phase detection: estimate (from height, vertical velocity and leg angles) or signal "
                        "(the robot's NAMED_VALUE_INT contact flag); default: the profile's [contact] source")
    g.add_argument("--contact-name", default=None, metavar="NAME",
                   help="NAMED_VALUE_INT name of the contact flag (default: the profile's, CONTACT)")


def _bridge_safety_args(g) -> None:
    g.add_argument("--max-age-ms", type=float, default=_D["max_age"] * 1e3, help="telemetry older than this stops steering")
    g.add_argument("--stale-action", choices=("reference", "hover", "land"), default=_D["stale_action"],
                   help="on stale telemetry: unsteered reference on the newest telemetry, level hover setpoint, or "
                        "hover + the autopilot's LAND mode (with --offboard)")
    g.add_argument("--stale-stream-limit", type=float, default=_D["stale_stream_limit"],
                   help="stop streaming after this long stale so the autopilot's offboard-loss failsafe acts [s] "
                        "(0: stream forever)")
    g.add_argument("--link-timeout", type=float, default=_D["link_timeout"], help="nothing heard from the vehicle (heartbeat or telemetry) for this long = link lost [s]")
    g.add_argument("--vehicle-lost-timeout", type=float, default=_D["vehicle_lost_timeout"],
                   help="the link lost this long ends the flight: log written, exit 7 (default 10 s)")
    g.add_argument("--frame", choices=("start", "world"), default=_D["frame"],
                   help="start: fly the trajectory from where the robot is, along its heading, when it enters "
                        "off-board (no turn, no jump); world: trajectory in the autopilot's local ENU, heading east")
    g.add_argument("--max-tilt-deg", type=float, default=_D["max_tilt_deg"], help="clamp on commanded roll and pitch")
    g.add_argument("--thrust-min", type=float, default=_D["thrust_min"])
    g.add_argument("--thrust-max", type=float, default=_D["thrust_max"])
    g.add_argument("--max-step", type=floats_or_none, default=argparse.SUPPRESS, metavar="Z,PITCH|none",
                   help="largest |steered - nominal| per reference, comma-separated, or 'none' (default: the "
                        "profile's [steering] max_step, else 0.3,0.5 flying / none hopping)")
    g.add_argument("--guard-hold", type=float, default=_D["guard_hold"], metavar="S",
                   help="steer: the correction clamped at the --max-step guard this long [s] hands the reference back "
                        "to the nominal one at the rate bound and refills the steering (the predictor no longer "
                        "explains the vehicle); 0: never (default %(default)s)")
    g.add_argument("--adapt", action="store_true",
                   help="steer: update the predictor online from steered ticks (a solver generated with [adapt] enabled)")
    g.add_argument("--max-gap-fill", type=int, default=_D["max_gap_fill"],
                   help="bridge up to this many lost telemetry samples in the steering history instead of "
                        "resetting it (0: always reset)")
    g.add_argument("--inject-solver-failure", type=fault_spec, default=None, metavar="START:COUNT[:fail|nan]",
                   help="testing: make solver calls START..START+COUNT-1 fail")


def _bridge_logging_args(g) -> None:
    g.add_argument("--log", default=None, help="tick log (.npz, loads as an IODataset; X or X.log writes X.npz); an "
                                               "existing file is refused unless --overwrite")
    g.add_argument("--overwrite", action="store_true", help="replace an existing --log or --summary file")
    g.add_argument("--summary", default=None, help="write the summary JSON here (an existing file is refused unless "
                                                   "--overwrite; never the --log file)")
    g.add_argument("--dataset-skip", type=float, default=_D["dataset_skip"], help="seconds after activation left out of the dataset")
    g.add_argument("--settle", type=float, default=_D["settle"], help="seconds after activation left out of the RMSE")
    g.add_argument("--excitation", type=floats, default=_D["excitation"], help="collect: PRBS amplitude per reference")
    g.add_argument("--excitation-hold", type=int, default=_D["excitation_hold"], help="collect: ticks per PRBS bit")
    g.add_argument("--seed", type=int, default=_D["seed"])
    add_realtime_args(g, "the loop")
    g.add_argument("--json", action="store_true", help="print the summary as JSON")
    g.add_argument("-v", "--verbose", action="store_true", help="print events as they happen")


def _profile_from_args(a: argparse.Namespace):
    """(ControllerConfig, EllipseTrajectory, ContactConfig, SteeringGuards, Envelope) of the robot profile
    named by --profile / --scenario (all None: the flying default), with --contact / --contact-name applied."""
    name = a.controller or ("pogox_hopping" if a.scenario == "hopping" else None)
    if name is None:
        if a.contact or a.contact_name:
            raise ValueError("--contact / --contact-name are for hopping (--scenario hopping)")
        return None, None, None, None, None
    prof = load_profile(name)
    if a.scenario and prof.controller.mode != a.scenario:
        raise ValueError(f"--scenario {a.scenario} but profile {prof.name} has controller mode {prof.controller.mode!r}")
    contact = prof.contact
    if a.contact:
        contact = replace(contact, source=a.contact)
    if a.contact_name:
        contact = replace(contact, signal_name=a.contact_name)
    traj = prof.trajectory if prof.controller.mode == "flying" else None  # hopping: the hop cycle, no path
    return prof.controller, traj, contact, prof.steering, prof.envelope


def _max_step(a: argparse.Namespace, guards) -> tuple | None:
    """--max-step if given, else the profile's [steering] max_step, else the bridge's default."""
    if hasattr(a, "max_step"):
        return a.max_step
    if guards is not None and guards.max_step is not None:
        return guards.max_step
    return _D["max_step"]


def bridge_config_from_args(a: argparse.Namespace) -> BridgeConfig:
    ctrl, traj, contact, guards, envelope = _profile_from_args(a)
    if a.trajectory:
        traj = trajectory_from_arg(a.trajectory)
    return BridgeConfig(
        url=a.connection, baud=a.baud, mode=a.mode, solver=a.solver, prefilter=a.prefilter, feedforward=a.feedforward,
        autopilot=a.autopilot,
        guid_options=a.guid_options, force_guid_options=a.force_guid_options, sysid=a.sysid, compid=a.compid, target_system=a.target_system,
        target_component=a.target_component, vehicle_address=a.vehicle_address, signing_key=a.signing_key,
        rate_hz=a.rate, attitude_stream=ATTITUDE_STREAMS[a.attitude_stream],
        position_stream=POSITION_STREAMS[a.position_stream], position_source=a.position_source, mocap=a.mocap,
        max_age=a.max_age_ms * 1e-3, stale_action=a.stale_action,
        stale_stream_limit=a.stale_stream_limit, link_timeout=a.link_timeout,
        vehicle_lost_timeout=a.vehicle_lost_timeout, max_tilt_deg=a.max_tilt_deg,
        thrust_min=a.thrust_min, thrust_max=a.thrust_max, max_step=_max_step(a, guards), guard_hold=a.guard_hold,
        max_gap_fill=a.max_gap_fill,
        adapt=a.adapt,
        arm=a.arm, offboard=a.offboard, arm_timeout=a.arm_timeout, takeoff=a.takeoff, climb_rate=a.climb_rate,
        approach_timeout=a.approach_timeout, approach_tolerance=a.approach_tolerance,
        land=a.land, blend_rates=a.blend_rates,
        prestream=a.prestream, duration=a.duration, timeout=a.timeout, wait_heartbeat=a.wait_heartbeat,
        lockstep=a.lockstep, tick_margin=None if a.tick_margin_us is None else a.tick_margin_us / 1e6, log=a.log, overwrite=a.overwrite, summary=a.summary, dataset_skip=a.dataset_skip, settle=a.settle,
        excitation=a.excitation, excitation_hold=a.excitation_hold, seed=a.seed,
        inject_solver_failure=a.inject_solver_failure, controller=ctrl, contact=contact, trajectory=traj, frame=a.frame, rt_priority=a.rt_priority,
        cpu_latency_us=qos_request(a.cpu_latency_us), cpus=a.cpus,
        verbose=a.verbose, envelope=envelope)


def format_summary(s: dict) -> str:
    """A few human-readable lines of a bridge summary."""
    lat = s.get("latency_us") or {}
    f = lambda v, fmt="{:.0f}": "-" if v is None or (isinstance(v, float) and math.isnan(v)) else fmt.format(v)  # noqa: E731
    lines = [
        f"ddpc-bridge {s['mode']} ({s['autopilot']}): {s['stop_reason'] or 'stopped'}",
        f"  ticks {s['ticks']}  setpoints {s['setpoints_sent']}  rate {f(s['rate_hz'], '{:.1f}')} Hz  "
        f"missed {s['missed_ticks']}  max gap {f(s['max_gap_ms'], '{:.1f}')} ms",
        f"  latency us p50 {f(lat.get('p50'))}  p99 {f(lat.get('p99'))}  max {f(lat.get('max'))}",
        f"  fallbacks {s['fallbacks']} {s['fallback_reasons'] or ''}  telemetry gaps {s['telemetry_gaps']}  "
        f"clamps tilt {s['tilt_clamped']} thrust {s['thrust_clamped']}",
        f"  rmse z (telemetry, every trajectory tick after settle) {f(s['rmse_z_measured'], '{:.4f}')} m  engaged "
        f"{f(None if s.get('engaged_share') is None else 1e2 * s['engaged_share'], '{:.1f}')} %  "
        f"link rx {s['link'].get('rx', 0)} bad {s['link'].get('bad_data', 0)} foreign {s['link'].get('foreign', 0)}",
    ]
    g = s.get("gate")
    if g is not None:
        lines.append(f"  gate: rate-limited {g['rate_limited']}  envelope {g['envelope']}  non-finite "
                     f"{g['nonfinite_reference'] + g['nonfinite_setpoint']}  guard clamped {g['guard_clamped']}  "
                     f"stalls {len(s.get('stalls', []))}  guard saturations {len(s.get('guard_saturations', []))}  "
                     f"telemetry dropped {s.get('telemetry_dropped', 0)}")
    if "hopping" in s:
        h = s["hopping"]
        lines.append(f"  hopping: phases from {h['contact_source']}, touchdowns {h['touchdowns']} liftoffs {h['liftoffs']}"
                     + (f", windows completed {h['artificial_io']['filled']}" if "artificial_io" in h else ""))
    if "steering" in s:
        st = s["steering"]
        lines.append(f"  steering: steered {st['steered']} warmup {st['warmup']} fallbacks {st['fallbacks']}  "
                     f"solve us median {f(st['solve_us']['p50'], '{:.1f}')} p99 {f(st['solve_us']['p99'], '{:.1f}')}")
    return "\n".join(lines)


def bridge_main(argv: list[str] | None = None) -> int:
    """``ddpc-bridge``: the exit code of :data:`.exit_status.EXIT_CODES` (0: flown; 2: a configuration error;
    3: no vehicle; 4: preflight; 5: arming failed; 6: interrupted before the first tick; 7: vehicle lost;
    8: never engaged; 9: the vehicle's own failsafe; 10: --timeout before the --duration was flown), with one
    line saying why. The log is written in every case that got past the configuration."""
    args = build_bridge_parser().parse_args(argv)
    # An interrupt while the bridge is being set up (the link may already be open) is an interrupt before
    # the first tick: remembered here, handed to the bridge, which then writes its empty log and exits 6.
    early: list[int] = []
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda signum, _frame: early.append(signum))
    try:
        bridge = Bridge(bridge_config_from_args(args))
    except (ValueError, DDPCError, OSError, LinkError) as e:
        print(f"ddpc-bridge: error: {e}", file=sys.stderr)
        return 2
    try:
        summary = bridge.run(interrupted=early)  # read after run() has its own handlers
    except NoVehicleError as e:
        print(f"ddpc-bridge: {e}", file=sys.stderr)
        return 3
    except PreflightError as e:
        print(f"ddpc-bridge: error: {e}", file=sys.stderr)
        return 2 if isinstance(e, EnvelopeRefusal) else 4
    except FlightError as e:
        print(f"ddpc-bridge: error: {e}", file=sys.stderr)
        return 5
    print(json.dumps(summary, indent=2, default=str) if args.json else format_summary(summary), flush=True)
    code, why = summary["exit"]["code"], summary["exit"]["reason"]
    if code:
        print(f"ddpc-bridge: error: {why}" if code != 6 else f"ddpc-bridge: {why}", file=sys.stderr)
    return code


def main(argv: list[str] | None = None) -> int:
    """``python -m firmware_bridge.cli bridge ...`` (the ``bridge`` word is optional)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    return bridge_main(argv[1:] if argv[:1] == ["bridge"] else argv)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
