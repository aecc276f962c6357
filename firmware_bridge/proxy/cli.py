"""``ddpc-proxy``: the transparent MAVLink proxy as a command. Runs until SIGINT / SIGTERM (or
``--duration``), then prints the statistics as one JSON object and writes them to ``--stats``."""

from __future__ import annotations

import argparse
import json
import signal
import sys
from pathlib import Path

from firmware_bridge.cli_args import add_realtime_args, qos_request
from firmware_bridge.proxy.core import Proxy
from firmware_bridge.realtime import setup_realtime

__all__ = ["build_proxy_parser", "main"]


def build_proxy_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="ddpc-proxy",
        description="A transparent MAVLink proxy between your own app(s) / ground station and the vehicle: "
                    "every message is forwarded both ways as the same bytes, in order; the counters and the "
                    "added latency are reported at the end. (Steering of the app's setpoints comes next.)")
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
                   help="forget a client silent this long [s] (default %(default)s)")
    p.add_argument("--duration", type=float, default=None, help="stop after this many seconds")
    p.add_argument("--stats", type=Path, default=None, help="write the final statistics (JSON) here")
    add_realtime_args(p, "the proxy")
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_proxy_parser().parse_args(argv)
    vehicle, apps = args.vehicle, args.app or ["udpin:127.0.0.1:14541"]
    try:
        proxy = Proxy(apps, vehicle, baud=args.baud, between_clients=args.between_clients,
                      client_timeout=args.client_timeout)
    except (ValueError, OSError) as e:
        print(f"ddpc-proxy: {e}", file=sys.stderr)
        return 2
    stopping = []

    def _stop(signum, _frame) -> None:
        stopping.append(signal.Signals(signum).name)

    signal.signal(signal.SIGINT, _stop)
    signal.signal(signal.SIGTERM, _stop)
    rt = setup_realtime(args.rt_priority, cpus=args.cpus, cpu_latency_us=qos_request(args.cpu_latency_us))
    print(f"ddpc-proxy: apps on {', '.join(apps)}, vehicle on {vehicle} ({rt.describe()})", file=sys.stderr, flush=True)
    try:
        with rt:
            proxy.run(args.duration, stop=lambda: bool(stopping))
    finally:
        proxy.close()
    summary = proxy.summary()
    summary["stop_reason"] = stopping[0] if stopping else "duration"
    summary["realtime"] = rt.describe()
    text = json.dumps(summary, indent=1)
    if args.stats is not None:
        args.stats.write_text(text + "\n")
    print(text, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
