"""Helpers of the proxy tests: an in-process proxy in a thread, raw loopback sockets that collect what
they receive, and MAVLink 1 / 2 frames encoded by pymavlink. Every wait is bounded."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import threading
import time

from pymavlink.dialects.v10 import common as mavlink1
from pymavlink.dialects.v20 import common as mavlink2

from firmware_bridge.proxy import Proxy

from support.bridge_helpers import ROOT, Procs, free_port


class RunningProxy:
    """A :class:`Proxy` running in a daemon thread until :meth:`stop`."""

    def __init__(self, app: str, vehicle: str, **kw) -> None:
        self.proxy = Proxy(app, vehicle, **kw)
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self.proxy.run, kwargs={"stop": self._stop.is_set}, daemon=True)
        self.thread.start()

    def wait_vehicle(self, timeout: float = 10.0) -> None:
        """Until the proxy has heard the vehicle's first datagram (its udpin link pinned): a proxy thread starved
        under load would otherwise read the app's first datagrams before the vehicle's and drop them, as it must
        while no vehicle is heard."""
        end = time.monotonic() + timeout
        while not self.proxy.vehicle.ready:
            assert time.monotonic() < end, f"the proxy did not hear the vehicle within {timeout} s"
            time.sleep(0.005)

    def stop(self) -> dict:
        self._stop.set()
        self.thread.join(5)
        assert not self.thread.is_alive()
        self.proxy.close()
        return self.proxy.summary()


class Peer(threading.Thread):
    """A raw UDP socket on 127.0.0.1 that records every datagram it receives (bytes, source)."""

    def __init__(self, port: int = 0) -> None:
        super().__init__(daemon=True)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 21)
        self.sock.bind(("127.0.0.1", port))
        self.sock.settimeout(0.05)
        self.port = self.sock.getsockname()[1]
        self.got: list[bytes] = []
        self.sources: set = set()
        self._halt = threading.Event()
        self.start()

    def run(self) -> None:
        while not self._halt.is_set():
            try:
                data, addr = self.sock.recvfrom(65535)
            except (TimeoutError, socket.timeout):
                continue
            except OSError:
                return
            self.got.append(data)
            self.sources.add(addr)

    def send(self, data: bytes, port: int) -> None:
        self.sock.sendto(data, ("127.0.0.1", port))

    def wait_for(self, n: int, timeout: float = 10.0) -> list[bytes]:
        end = time.monotonic() + timeout
        while len(self.got) < n and time.monotonic() < end:
            time.sleep(0.01)
        return list(self.got)

    def close(self) -> None:
        self._halt.set()
        self.join(2)
        self.sock.close()


def spawn_proxy(procs: Procs, *args: str, name: str = "proxy") -> subprocess.Popen:
    """``ddpc-proxy ARGS`` (``python -m firmware_bridge.proxy.cli``) as a child that ``procs`` stops."""
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    log = procs.tmp / f"{name}.out"
    p = subprocess.Popen([sys.executable, "-m", "firmware_bridge.proxy.cli", *args], env=env,
                         stdout=open(log, "w"), stderr=subprocess.STDOUT, cwd=str(procs.tmp))
    p._log = log  # type: ignore[attr-defined]
    procs.procs.append(p)
    return p


def mav(version: int, sysid: int, compid: int):
    """A pymavlink encoder of MAVLink ``version`` (1 or 2) as (sysid, compid)."""
    mod = mavlink1 if version == 1 else mavlink2
    return mod.MAVLink(None, srcSystem=sysid, srcComponent=compid)


POS_ONLY = 0b0000_1111_1111_1000        # x, y, z used; velocity, acceleration, yaw ignored
VEL_ONLY = 0b0000_1111_1100_0111        # x, y, z ignored


def setpoint(m, k: int, mask: int) -> bytes:
    """A SET_POSITION_TARGET_LOCAL_NED frame from encoder ``m`` (x = 0.1 k, z = -1 - 0.01 k [m])."""
    msg = m.set_position_target_local_ned_encode(k, 1, 1, mavlink2.MAV_FRAME_LOCAL_NED, mask,
                                                  0.1 * k, 0.2, -1.0 - 0.01 * k, 0.5, 0, 0, 0, 0, 0, 0.3, 0)
    f = bytes(msg.pack(m))
    m.seq = (m.seq + 1) % 256
    return f


def frames(m, n: int, start: int = 0) -> list[bytes]:
    """``n`` distinct frames from encoder ``m`` (heartbeats, attitude, named values), seq counting on."""
    out = []
    for k in range(start, start + n):
        if k % 3 == 0:
            msg = m.heartbeat_encode(2, 12, 0, k, 4)
        elif k % 3 == 1:
            msg = m.attitude_encode(k, 0.1 * k, -0.2, 0.3, 0.0, 0.0, 0.0)
        else:
            msg = m.named_value_int_encode(k, b"K", k)
        out.append(bytes(msg.pack(m)))
        m.seq = (m.seq + 1) % 256  # pymavlink counts on in send(), not in pack()
    return out


__all__ = ["RunningProxy", "Peer", "spawn_proxy", "mav", "frames", "setpoint", "POS_ONLY", "VEL_ONLY", "free_port",
           "mavlink2"]


def until(cond, timeout: float = 5.0) -> None:
    """Wait until ``cond()`` holds (polled every 5 ms), at most ``timeout`` [s]; fails if it never does."""
    end = time.monotonic() + timeout
    while not cond() and time.monotonic() < end:
        time.sleep(0.005)
    assert cond()
