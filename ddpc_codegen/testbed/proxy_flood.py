"""A hostile or buggy client of ``ddpc-proxy``'s app port (the soak's flood, :mod:`.proxy_soak`): garbage and
valid-but-foreign MAVLink at a fixed rate from several source ports, each its own system id.

``python -m ddpc_codegen.testbed.proxy_flood PORT --hz 10000 --seconds 120 [--ports 4] [--stats FILE]``
(SIGTERM ends it early; the counts are written either way.)
"""

from __future__ import annotations

import argparse
import json
import signal
import socket
import sys
import time
from pathlib import Path

import numpy as np
from pymavlink.dialects.v10 import common as v1
from pymavlink.dialects.v20 import common as v2

__all__ = ["flood", "main"]

M = v2
POS_ONLY = 0b0000_1111_1111_1000


def flood(port: int, hz: float, seconds: float, ports: int = 4, stats: str | None = None) -> dict:
    """Send ``hz`` datagrams/s for ``seconds`` to 127.0.0.1:``port`` from ``ports`` sockets, each a foreign system
    (ids 100 ... 100 + ports - 1, at most 140 ports: none is the vehicle's, an app's or a GCS's): garbage (no MAVLink start byte in it), heartbeats, commands, parameter reads and position setpoints
    aimed at system 99, MAVLink 1 and 2, each socket's sequence gap-free. Counts (also to ``stats``, JSON); ``received``:
    the datagrams that came back to the sockets (a proxy's vehicle stream; from a bridge: none)."""
    if not 1 <= ports <= 140:
        raise ValueError(f"ports must be 1 ... 140 (each its own system id); got {ports}")
    rng = np.random.default_rng(0)
    socks, cycles = [], []
    for i in range(ports):
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind(("127.0.0.1", 0))
        s.setblocking(False)
        socks.append(s)
        m2, m1 = v2.MAVLink(None, 100 + i, 1), v1.MAVLink(None, 100 + i, 1)
        kinds = [lambda m: m.heartbeat_encode(6, 8, 0, 0, 4),
                 lambda m: m.command_long_encode(99, 1, M.MAV_CMD_REQUEST_MESSAGE, 0, 0, 0, 0, 0, 0, 0, 0),
                 lambda m: m.param_request_read_encode(99, 1, b"COM_OF_LOSS_T", -1),
                 lambda m: m.set_position_target_local_ned_encode(0, 99, 1, 1, POS_ONLY, 5, 5, -5, 0, 0, 0, 0, 0, 0, 0, 0)]
        cycle = []
        for k in range(256):  # one whole sequence turn: the cycle repeats gap-free
            m = m1 if k % 5 == 4 else m2
            m.seq = k
            cycle.append(bytes(kinds[k % 4](m).pack(m)))
            if k % 3 == 0:  # garbage: random bytes without a start byte (so never a frame by chance)
                cycle.append(bytes(int(b) if b < 0xFD else 0 for b in rng.integers(0, 256, 24 + 8 * (k % 7))))
        cycles.append(cycle)
    halt = []
    signal.signal(signal.SIGTERM, lambda *_: halt.append(1))
    sent = frames_sent = garbage = received = 0
    t0 = time.monotonic()
    while not halt and (now := time.monotonic()) - t0 < seconds:
        due = min(int((now - t0) * hz) - sent, int(hz * 0.05) + 1)
        for _ in range(due):
            i, j = sent % ports, sent // ports
            d = cycles[i][j % len(cycles[i])]
            socks[i].sendto(d, ("127.0.0.1", port))
            sent += 1
            if d[0] in (0xFD, 0xFE):
                frames_sent += 1
            else:
                garbage += len(d)
        for s in socks:  # what comes back (a proxy's vehicle stream) is read and counted: no kernel drops to count
            try:
                while s.recv(65536):
                    received += 1
            except OSError:
                pass
        time.sleep(0.001)
    res = {"rate_hz": hz, "ports": ports, "seconds": time.monotonic() - t0, "datagrams": sent,
           "frames": frames_sent, "garbage_bytes": garbage, "received": received}
    if stats:
        Path(stats).write_text(json.dumps(res))
    return res


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m ddpc_codegen.testbed.proxy_flood", description=__doc__.split("\n\n")[0])
    p.add_argument("port", type=int, help="the proxy's UDP app port on 127.0.0.1")
    p.add_argument("--hz", type=float, required=True, help="datagrams per second, all ports together")
    p.add_argument("--seconds", type=float, required=True)
    p.add_argument("--ports", type=int, default=4, help="source ports, each its own system id 100... (1-140; default %(default)s)")
    p.add_argument("--stats", default=None, help="write the counts (JSON) here")
    a = p.parse_args(argv)
    print(json.dumps(flood(a.port, a.hz, a.seconds, a.ports, a.stats)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
