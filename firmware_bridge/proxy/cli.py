"""``ddpc-proxy``: the transparent MAVLink proxy as a command. Runs until SIGINT / SIGTERM (or
``--duration``), then prints the statistics as one JSON object and writes them to ``--stats``."""

from __future__ import annotations

import argparse
import json
import math
import signal
import sys
import time
from pathlib import Path

from ddpc_codegen.design.data import output_path
from ddpc_codegen.runtime.loader import load_solver
from firmware_bridge.cli_args import add_realtime_args, qos_request
from firmware_bridge.link import LinkError, MavLink
from firmware_bridge.mocap_input import MocapInput
from firmware_bridge.proxy.core import Proxy
from firmware_bridge.proxy.file_preview import FilePreview
from firmware_bridge.proxy.preview import make_preview
from firmware_bridge.proxy.record import ProxyRecord
from firmware_bridge.proxy.steering import ProxySteering
from firmware_bridge.proxy.vehicle_view import VehicleView
from firmware_bridge.realtime import setup_realtime

__all__ = ["build_proxy_parser", "main"]


def build_proxy_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="ddpc-proxy",
        description="A transparent MAVLink proxy between your own app(s) / ground station and the vehicle: "
                    "every message is forwarded both ways as the same bytes, in order; the counters and the "
                    "added latency are reported at the end. With --steer, the height of the app's position setpoints is "
                    "steered by a generated solver; --collect records the app's flights for ddpc-codegen.")
    p.add_argument("--app", action="append", default=None, metavar="URL",
                   help="where apps and ground stations connect (repeat for several): udpin:HOST:PORT, a UDP "
                        "server where each sender address is one client; udpout:HOST:PORT, an app listening "
                        "there (as PX4 sends to 14540); tcpin:HOST:PORT, a TCP server, one client per connection "
                        "(default udpin:127.0.0.1:14541)")
    p.add_argument("--vehicle", default="udpin:0.0.0.0:14540",
                   help="the vehicle link, as for ddpc-bridge: udpin:HOST:PORT (PX4 sends to 14540), "
                        "udpout:HOST:PORT, tcp:HOST:PORT (ArduPilot SITL 5760) or a serial device "
                        "(default %(default)s)")
    p.add_argument("--baud", type=int, default=None, help="serial baud rate (default from the string, else 921600)")
    p.add_argument("--between-clients", action="store_true",
                   help="also forward each client's messages to the other clients (as mavlink-router does)")
    p.add_argument("--client-timeout", type=float, default=5.0,
                   help="a client silent this long [s] is no longer the app whose setpoints are steered (a quiet "
                        "UDP client keeps receiving the vehicle's stream) (default %(default)s)")
    s = p.add_argument_group("steering the height of the app's SET_POSITION_TARGET_LOCAL_NED / _GLOBAL_INT")
    s.add_argument("--steer", type=Path, default=None, metavar="SOLVER",
                   help="a generated solver folder (inputs z_ref, outputs z, at the app's setpoint rate; "
                        "configs/proxy_*.toml): steer the height of the app's setpoints while the vehicle is armed "
                        "in off-board / guided")
    s.add_argument("--preview-delay", type=float, default=0.0, metavar="S",
                   help="play the app's setpoints S seconds late and steer with them as a true preview "
                        "(default 0: a local preview from the setpoint's velocity / acceleration, or its slope)")
    s.add_argument("--preview-file", type=Path, default=None, metavar="FILE",
                   help="the app's path given ahead as a trajectory file (.csv / .toml: t, x, z up, ...), matched to "
                        "the app's stream on the height (any start time and height): the file previews the steering "
                        "while it matches, the local preview otherwise (no delay; not with --preview-delay)")
    s.add_argument("--max-jerk", type=float, default=0.0, metavar="J",
                   help="the autopilot's vertical jerk limit J [m/s^3] (ArduCopter: PSC_JERK_Z, default 5), which its "
                        "guided mode applies to the app's setpoints: the steering pauses around the jumps of the "
                        "app's z acceleration it shapes (the loop is not the linear one fitted there), and with "
                        "--preview-delay those jumps are spread over the preview to J (default 0: neither)")
    s.add_argument("--collect", type=Path, default=None, metavar="FILE",
                   help="record the engaged stretches as a dataset for ddpc-codegen (.npz): heights sent in, "
                        "the vehicle's height out")
    s.add_argument("--dither", type=float, default=0.0, metavar="M",
                   help="without --steer: add a PRBS of +-M metres to the app's height (an excitation for "
                        "--collect; default 0)")
    s.add_argument("--dither-hold", type=int, default=3, metavar="N",
                   help="shortest hold of a dither level, setpoints (default %(default)s)")
    s.add_argument("--z-feedforward", choices=("keep", "zero"), default="keep",
                   help="a steered (or dithered) setpoint's z velocity / acceleration: the app's own, or zero (the "
                        "steered height then carries the lead; collect the same way) (default %(default)s)")
    s.add_argument("--coordinates", choices=("deviation", "absolute"), default="deviation",
                   help="what --collect records: deviation (the offset added to the app's height in, the tracking "
                        "error out: for an app that sends its own velocity / acceleration) or absolute (the height "
                        "sent in, the height flown out) (default %(default)s; a solver's signals say which it "
                        "steers)")
    s.add_argument("--max-step", type=float, default=None, metavar="M",
                   help="largest steering offset from the app's height [m] (the step guard; default none)")
    s.add_argument("--model-watch", type=float, default=8.0, metavar="RATIO",
                   help="while the steering's predictor misses the flight by more than RATIO times its held-out "
                        "error (its manifest), send the app's own setpoints (default %(default)s; 0: off)")
    s.add_argument("--max-age", type=float, default=0.2, metavar="S",
                   help="an older vehicle position is stale: the app's own setpoint goes out (default %(default)s)")
    s.add_argument("--position-source", choices=("autopilot", "mocap"), default="autopilot",
                   help="the measured height: the autopilot's estimate (LOCAL_POSITION_NED), or the lab's motion "
                        "capture received on --mocap, put into the autopilot's local frame where the vehicle "
                        "stands disarmed (default %(default)s)")
    s.add_argument("--mocap", default=None, metavar="URL",
                   help="where the motion capture's poses arrive (VISION_POSITION_ESTIMATE, ODOMETRY or "
                        "ATT_POS_MOCAP), e.g. udpin:127.0.0.1:14600")
    s.add_argument("--mocap-offset", type=float, default=None, metavar="M",
                   help="the autopilot's local height minus the motion capture's, where the vehicle stands [m] (a "
                        "lab's calibration, or the offset_m an earlier session's statistics give; default: measured "
                        "while the vehicle stands disarmed, so start the proxy before arming)")
    s.add_argument("--log", type=Path, default=None, help="write every tick and the summary here (.npz)")
    s.add_argument("--overwrite", action="store_true", help="replace an existing --collect / --log file")
    p.add_argument("--duration", type=float, default=None, help="stop after this many seconds")
    p.add_argument("--stats", type=Path, default=None, help="write the final statistics (JSON) here")
    add_realtime_args(p, "the proxy")
    return p


def _steering(args) -> ProxySteering | None:
    """The rewrite hook the options ask for (None: a transparent proxy)."""
    if args.steer is None and args.collect is None and args.log is None and not args.dither \
            and not args.preview_delay and args.preview_file is None and not args.max_jerk \
            and args.position_source == "autopilot" \
            and not args.mocap and args.mocap_offset is None:
        return None
    if args.steer is not None and args.dither:
        raise ValueError("--dither excites a collect flight; it does not go with --steer")
    for name, v, lo in (("--preview-delay", args.preview_delay, 0.0), ("--dither", args.dither, 0.0)):
        if not (v >= lo and v < float("inf")):
            raise ValueError(f"{name} must be a finite number >= {lo:g}; got {v}")
    if args.preview_file is not None and args.preview_delay > 0:
        raise ValueError(f"--preview-file and --preview-delay {args.preview_delay:g} are two previews: give one (the "
                         "file's path is matched to the app's stream without a delay)")
    if not (0.0 < args.max_age < float("inf")):
        raise ValueError(f"--max-age must be a finite number of seconds > 0; got {args.max_age}")
    if args.dither_hold < 1:
        raise ValueError(f"--dither-hold must be at least 1 setpoint; got {args.dither_hold}")
    if not (args.model_watch == 0.0 or 1.0 < args.model_watch < float("inf")):
        raise ValueError(f"--model-watch must be 0 (off) or a finite ratio > 1; got {args.model_watch}")
    if args.max_step is not None and not (0.0 < args.max_step < float("inf")):
        raise ValueError(f"--max-step must be a finite number of metres > 0; got {args.max_step}")
    for path in (args.collect, args.log):
        if path is not None:
            output_path(path, args.overwrite)  # refused now, not after the flight
    preview = make_preview(args.preview_delay) if args.preview_file is None else \
        FilePreview.from_file(args.preview_file)
    solver = None
    if args.steer is not None:
        solver = load_solver(args.steer)
    hook = ProxySteering(VehicleView(mocap=_mocap(args), mocap_offset=args.mocap_offset), solver=solver,
                         preview=preview, max_age=args.max_age, max_step=args.max_step, dither=args.dither,
                         dither_hold=args.dither_hold, record=ProxyRecord(), z_feedforward=args.z_feedforward,
                         coordinates=args.coordinates, model_watch=args.model_watch, max_jerk=args.max_jerk)
    if args.preview_file is not None and hook.mode == "steer" and hook.deviation:
        print("ddpc-proxy: --preview-file: this solver steers in deviation coordinates (z_offset -> z_error), whose "
              "desired error is 0 whatever the path ahead: the match is reported, the steering does not use it",
              file=sys.stderr)
    return hook


def _mocap(args) -> MocapInput | None:
    """The motion capture's input when the height is measured on it (its link opened; poses carry no ids)."""
    if args.position_source != "mocap":
        if args.mocap or args.mocap_offset is not None:
            raise ValueError("--mocap and --mocap-offset are the measured height's source: they go with "
                             "--position-source mocap")
        return None
    if args.mocap_offset is not None and not math.isfinite(args.mocap_offset):
        raise ValueError(f"--mocap-offset must be a finite number of metres; got {args.mocap_offset}")
    if not args.mocap:
        raise ValueError("--position-source mocap needs the link the poses arrive on (--mocap udpin:HOST:PORT)")
    if args.mocap == args.vehicle:
        raise ValueError(f"--mocap {args.mocap}: the vehicle's link (the poses need a port of their own)")
    try:
        return MocapInput(_WallClock(MavLink(args.mocap, target_system=None)))
    except (LinkError, OSError, ValueError) as e:
        raise ValueError(f"--mocap {args.mocap}: {e}") from None


class _WallClock:
    """A link whose arrival stamps are on the proxy's clock (``time.time()``; a MavLink stamps on the monotonic one)."""

    def __init__(self, link: MavLink) -> None:
        self.link, self.url = link, link.url

    def drain(self) -> list:
        shift = time.time() - time.monotonic()
        return [(msg, rx + shift) for msg, rx in self.link.drain()]

    def close(self) -> None:
        self.link.close()


def _said(preview: dict) -> str:
    """The preview in words (the start line)."""
    if preview["kind"] == "file":
        return f"from the trajectory file {preview['file']}, matched to the app's stream"
    return f"delayed {preview['delay_s']:g} s" if preview["kind"] == "delay" else "local"


def _save(hook: ProxySteering, args) -> dict:
    """Write the --log and --collect files; what was written (or why not)."""
    out: dict = {}
    summary = hook.summary()
    if args.log is not None:
        out["log"] = str(hook.record.save_log(args.log, summary, args.overwrite))
    if args.collect is not None:
        try:
            ds = hook.record.dataset(hook.tick, {"steering": hook.mode}, hook.coordinates)
            out["collect"] = str(ds.save(output_path(args.collect, args.overwrite), overwrite=True))
        except ValueError as e:
            out["collect_error"] = str(e)
            print(f"ddpc-proxy: --collect: {e}", file=sys.stderr)
    return out


def main(argv: list[str] | None = None) -> int:
    args = build_proxy_parser().parse_args(argv)
    vehicle, apps = args.vehicle, args.app or ["udpin:127.0.0.1:14541"]
    try:
        hook = _steering(args)
        proxy = Proxy(apps, vehicle, baud=args.baud, between_clients=args.between_clients,
                      client_timeout=args.client_timeout, rewrite=hook, view=hook.view if hook else None)
    except (ValueError, OSError) as e:
        print(f"ddpc-proxy: {e}", file=sys.stderr)
        return 2
    stopping = []

    def _stop(signum, _frame) -> None:
        stopping.append(signal.Signals(signum).name)

    signal.signal(signal.SIGINT, _stop)
    signal.signal(signal.SIGTERM, _stop)
    rt = setup_realtime(args.rt_priority, cpus=args.cpus, cpu_latency_us=qos_request(args.cpu_latency_us))
    print(f"ddpc-proxy: apps on {', '.join(apps)}, vehicle on {vehicle} ({rt.describe()})"
          + (f"; {hook.mode}, preview {_said(hook.preview.summary())}" if hook else ""), file=sys.stderr, flush=True)
    try:
        with rt:
            proxy.pacer.start()
            proxy.run(args.duration, stop=lambda: bool(stopping))
    finally:
        proxy.pacer.stop()
        proxy.close()
    summary = proxy.summary()
    summary["stop_reason"] = stopping[0] if stopping else "duration"
    summary["realtime"] = rt.describe()
    if hook is not None:
        summary["steering"] = hook.summary()
        summary["files"] = _save(hook, args)
    text = json.dumps(summary, indent=1)
    if args.stats is not None:
        args.stats.write_text(text + "\n")
    print(text, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
