"""Real clients through ``ddpc-proxy`` in front of ArduCopter SITL, all at once (skipped without the SITL,
MAVSDK-Python < 4 or MAVProxy).

ArduCopter SITL (TCP 5760) <- ``ddpc-proxy --vehicle tcp:127.0.0.1:5760 --app udpin:127.0.0.1:14541
--app tcpin:127.0.0.1:5770`` <-

- MAVProxy, a ground station on TCP: it fetches every parameter and follows the mode and the arming;
- a MAVSDK-Python app on UDP (the offboard example's calls): arm, take-off, offboard start, position setpoints
  to a height above the take-off height, then SIGKILL of its process group (the app and its mavsdk_server);
- then a plain pymavlink app on UDP: it reads a parameter, holds the point with setpoints at 15 Hz once the
  proxy has let the dead app's setpoint role go, and is SIGKILLed after one of them;
- two quiet listeners of this test: one on TCP connected before the vehicle boots (every vehicle frame has
  somewhere to go, so none is dropped for want of a client) and one on UDP that sends one heartbeat and then
  only listens for the whole flight (it must keep the vehicle's stream).

An observer on the SITL's spare port (TCP 5762) records the true height (SIM_STATE), the estimate and the mode.
A position target in GUIDED has no off-board-loss timeout in ArduCopter (``GUID_TIMEOUT`` covers velocity /
acceleration / attitude targets): after each kill the copter holds the last point in GUIDED.

Killing only the MAVSDK app's Python process would leave its mavsdk_server running, and that keeps sending the
last offboard setpoint (MAVSDK's behaviour, with or without the proxy): the app's death here is its process
group's."""

from __future__ import annotations

import asyncio
import importlib.util
import json
import os
import select
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from importlib import metadata
from pathlib import Path

import numpy as np
import pytest

from ddpc_codegen.testbed.bridge_flights import stop_process
from ddpc_codegen.testbed.sitl import missing_reason, run_isolated
from ddpc_codegen.testbed.sitl_observer import Observer, wait_tcp_port, wait_udp_bound
from firmware_bridge.proxy.frames import split_frames
from firmware_bridge.proxy.stats import DirectionStats

pytestmark = [pytest.mark.sitl, pytest.mark.slow, pytest.mark.realtime]

APP_PORT, GCS_PORT = 14541, 5770
TAKEOFF_ALT = 2.0     # m, MAVSDK's take-off
TARGET_ALT = 3.0      # m, MAVSDK's offboard setpoints (local frame, up)
MAVSDK_SP = 100       # MAVSDK setpoint calls (20 Hz) before its kill
CLIENT_TIMEOUT = 2.0  # s, --client-timeout: the dead app's setpoint role is free after this
RATE_HZ = 15.0        # the pymavlink app's setpoints
HOLD_S = 3.0          # the pymavlink app streams this long before it is killed
AFTER_S = 3.0         # watched after its kill
GUIDED = 4
_HERE = Path(__file__).resolve()


def _log(path: str, **ev) -> None:
    """One JSON line, written unbuffered (the app may be SIGKILLed right after)."""
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        os.write(fd, (json.dumps({"t": time.time(), **ev}) + "\n").encode())
    finally:
        os.close(fd)


def _lines(path: Path) -> list[dict]:
    return [json.loads(s) for s in path.read_text().splitlines() if s.strip()] if path.exists() else []


def _clients_missing() -> str | None:
    """Why MAVSDK-Python (< 4, with its mavsdk_server) or MAVProxy cannot run here, or None."""
    try:
        v = metadata.version("mavsdk")
    except metadata.PackageNotFoundError:
        return "MAVSDK-Python not installed (pip install 'mavsdk<4', the dev extra)"
    if int(v.split(".")[0]) >= 4:
        return f"mavsdk {v} is the native API; this test drives the gRPC one (mavsdk<4)"
    spec = importlib.util.find_spec("mavsdk")
    server = Path(spec.origin).parent / "bin" / "mavsdk_server" if spec and spec.origin else None
    if server is None or not server.is_file():
        return "mavsdk's wheel brought no mavsdk_server binary for this platform"
    if _mavproxy() is None:
        return "MAVProxy not installed (make install: pip install --no-deps MAVProxy)"
    return None


def _mavproxy() -> str | None:
    beside = Path(sys.executable).parent / "mavproxy.py"
    return str(beside) if beside.is_file() else shutil.which("mavproxy.py")


# ---------------------------------------------------------------------------------------------- the apps
async def _mavsdk_flight(url: str, log: str) -> None:
    from mavsdk import System
    from mavsdk.action import ActionError
    from mavsdk.offboard import OffboardError, PositionNedYaw

    drone = System()
    await drone.connect(system_address=url)
    async for s in drone.core.connection_state():
        if s.is_connected:
            break
    async for h in drone.telemetry.health():
        if h.is_global_position_ok and h.is_home_position_ok:
            break
    _log(log, ev="healthy")
    await drone.action.set_takeoff_altitude(TAKEOFF_ALT)
    for tries in range(1, 80):  # arming needs consistent gyros, take-off an EKF using GPS (~40 s after boot)
        try:
            await drone.action.arm()
            await drone.action.takeoff()
            break
        except ActionError as e:
            why = str(e)
            await asyncio.sleep(1.0)
    else:
        _log(log, ev="takeoff_refused", why=why)
        return
    _log(log, ev="takeoff", tries=tries)
    async for p in drone.telemetry.position():
        if p.relative_altitude_m > TAKEOFF_ALT - 0.3:
            break
    _log(log, ev="airborne")
    sp = PositionNedYaw(0.0, 0.0, -TARGET_ALT, 0.0)
    await drone.offboard.set_position_ned(sp)  # the example: a setpoint before the start
    try:
        await drone.offboard.start()
    except OffboardError as e:
        _log(log, ev="offboard_refused", why=str(e._result.result))
        return
    _log(log, ev="offboard")
    k = 0
    while True:  # until killed
        await drone.offboard.set_position_ned(sp)
        k += 1
        _log(log, ev="sp", k=k)
        await asyncio.sleep(0.05)


def _mavsdk_app(url: str, log: str) -> None:
    asyncio.run(_mavsdk_flight(url, log))


def _pymavlink_app(url: str, log: str, go: float) -> None:
    """Read GUID_TIMEOUT (and the vehicle's parameter count), then from ``go`` [s, time.time()] hold the point
    with setpoints at RATE_HZ until killed; each line logs every frame sent so far."""
    sys.path.insert(0, str(_HERE.parents[1] / "firmware_bridge" / "proxy_tests"))
    from mav_app import M, connect

    c = connect(url, sysid=250, timeout=20)
    value = count = None
    end = time.monotonic() + 10
    while value is None and time.monotonic() < end:
        c.mav.param_request_read_send(c.target_system, c.target_component, b"GUID_TIMEOUT", -1)
        m = c.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.5)
        if m is not None and m.param_id.rstrip("\x00") == "GUID_TIMEOUT":
            value, count = m.param_value, m.param_count
    _log(log, ev="param", value=value, param_count=count, port=c.port.getsockname()[1])
    next_hb = 0.0
    while time.time() < go:
        if time.monotonic() > next_hb:
            next_hb = time.monotonic() + 1.0
            c.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        c.recv_match(blocking=True, timeout=0.05)
    mask = 0b0000_1111_1111_1000  # position only
    k, t0 = 0, time.monotonic()
    while True:  # until SIGKILL
        c.mav.set_position_target_local_ned_send(int(1000 * (time.monotonic() - t0)), c.target_system,
                                                 c.target_component, M.MAV_FRAME_LOCAL_NED, mask,
                                                 0, 0, -TARGET_ALT, 0, 0, 0, 0, 0, 0, 0, 0)
        k += 1
        if k % int(RATE_HZ) == 0:
            c.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        _log(log, ev="sp", k=k, sent=c.mav.total_packets_sent)
        while c.recv_match(blocking=False) is not None:
            pass
        time.sleep(max(0.0, t0 + k / RATE_HZ - time.monotonic()))


class _Listeners(threading.Thread):
    """Two quiet clients of the proxy: TCP (connected now) and UDP (one heartbeat at :meth:`hello`). Each counts
    the frames it gets and their sequence gaps per sender; the UDP one keeps its last receive time."""

    def __init__(self, tcp_port: int, udp_port: int) -> None:
        super().__init__(daemon=True)
        end = time.monotonic() + 10
        while True:  # (the proxy binds its TCP port right after its UDP one)
            try:
                self.tcp = socket.create_connection(("127.0.0.1", tcp_port), timeout=5)
                break
            except OSError:
                if time.monotonic() > end:
                    raise
                time.sleep(0.05)
        self.udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.udp.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 21)
        self.udp.bind(("127.0.0.1", 0))
        self.udp_port, self.local_port, self.t_hello = udp_port, self.udp.getsockname()[1], None
        self.stats = {"tcp": DirectionStats(16), "udp": DirectionStats(16)}
        self.frames = {"tcp": 0, "udp": 0}
        self.udp_last = 0.0
        self.halt = threading.Event()
        self.start()

    def hello(self) -> None:
        from pymavlink.dialects.v20 import common as mavlink2

        m = mavlink2.MAVLink(None, srcSystem=253, srcComponent=190)
        self.udp.sendto(bytes(m.heartbeat_encode(6, 8, 0, 0, 4).pack(m)), ("127.0.0.1", self.udp_port))
        self.t_hello = time.time()

    def _count(self, kind: str, buf: bytes | bytearray, final: bool) -> int:
        spans, _garbage, used = split_frames(buf, final=final)
        for i, _n in spans:
            self.stats[kind].see(buf, i)
        self.frames[kind] += len(spans)
        return used

    def run(self) -> None:
        buf, tcp_open = bytearray(), True
        while not self.halt.is_set() or tcp_open:
            socks = [self.udp] + ([self.tcp] if tcp_open else [])
            ready, _, _ = select.select(socks, [], [], 0.1)
            if self.udp in ready:
                data = self.udp.recv(65535)
                self.udp_last = time.time()
                self._count("udp", data, True)
            if self.tcp in ready:
                try:
                    data = self.tcp.recv(65536)
                except OSError:
                    data = b""
                tcp_open = bool(data)
                buf += data
                del buf[:self._count("tcp", buf, False)]
            if self.halt.is_set() and not ready:
                break

    def summary(self) -> dict:
        return {k: {"frames": self.frames[k], "seq_gaps": self.stats[k].c["seq_gaps"]} for k in self.frames} | {
            "udp_last": self.udp_last, "t_hello": self.t_hello, "udp_local_port": self.local_port}

    def stop(self) -> None:
        self.halt.set()
        self.join(5)
        self.tcp.close()
        self.udp.close()


# ---------------------------------------------------------------------------------------------- the flight
def _wait(cond, timeout: float, what: str, poll: float = 0.1) -> None:
    end = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < end, f"timed out after {timeout} s waiting for {what}"
        time.sleep(poll)


def _spawn(out: Path, name: str, argv: list[str], **kw) -> subprocess.Popen:
    return subprocess.Popen(argv, stdout=open(out / f"{name}.out", "w"), stderr=subprocess.STDOUT, cwd=out,
                            env={**os.environ, "MAVLINK20": "1"}, **kw)


def _app_cmd(func: str, *args) -> list[str]:
    code = (f"import sys; sys.path.insert(0, {str(_HERE.parents[1])!r}); "
            f"from sitl.test_sitl_proxy_clients import {func}; {func}(*{list(args)!r})")
    return [sys.executable, "-W", "ignore::FutureWarning", "-c", code]


def _stop_all(sdk, pym, proxy, gcs, obs, lis, sitl) -> None:
    """Every process this flight started, by its pid (the MAVSDK app with its group), and the threads."""
    if sdk is not None and sdk.poll() is None:
        os.killpg(sdk.pid, signal.SIGKILL)
        sdk.wait(5)
    for p in (pym, proxy):
        stop_process(p, 5, signal.SIGKILL)
    stop_process(gcs, 5, signal.SIGINT)
    for t in (obs, lis):
        if t is not None and t.is_alive():
            t.stop()
    if sitl is not None:
        sitl.stop()


def clients_flight(out_dir: str) -> dict:
    """Runs in a private network namespace (:func:`run_isolated`): proxy, listeners, SITL, observer, MAVProxy,
    MAVSDK (killed), the pymavlink app (killed); the results as JSON."""
    from ddpc_codegen.testbed.sitl import make_sitl

    out = Path(out_dir)
    sdklog, pymlog, stats = out / "mavsdk.jsonl", out / "pymavlink.jsonl", out / "proxy.json"
    t_start = time.time()
    proxy = gcs = sdk = pym = obs = lis = sitl = None
    try:
        # the proxy first: its vehicle link is retried once a second until the SITL is up
        proxy = _spawn(out, "proxy", [sys.executable, "-m", "firmware_bridge.proxy.cli",
                                      "--app", f"udpin:127.0.0.1:{APP_PORT}", "--app", f"tcpin:127.0.0.1:{GCS_PORT}",
                                      "--vehicle", "tcp:127.0.0.1:5760", "--client-timeout", str(CLIENT_TIMEOUT),
                                      "--stats", str(stats)])
        assert wait_udp_bound(APP_PORT), "the proxy did not bind its UDP port"
        lis = _Listeners(GCS_PORT, APP_PORT)
        sitl = make_sitl("ardupilot").start()
        _wait(lambda: lis.frames["tcp"] > 0, 30, "the vehicle's first frame through the proxy")
        # every client from here on talks to a vehicle that is heard (nothing of theirs is dropped)
        assert wait_tcp_port(5762), "ArduCopter's spare port 5762 never served"
        obs = Observer("tcp:127.0.0.1:5762", rate_hz=10.0)
        lis.hello()
        gcs = _spawn(out, "mavproxy", [sys.executable, _mavproxy(), f"--master=tcp:127.0.0.1:{GCS_PORT}",
                                       "--non-interactive", "--daemon", "--source-system=252", "--state-basedir", str(out)])
        sdk = _spawn(out, "mavsdk", _app_cmd("_mavsdk_app", f"udpout://127.0.0.1:{APP_PORT}", str(sdklog)),
                     start_new_session=True)  # its own group: the app and its mavsdk_server die together

        def sdk_sp() -> int:
            ev = _lines(sdklog)
            assert sdk.poll() is None, f"the MAVSDK app ended: {(out / 'mavsdk.out').read_text()[-3000:]} {ev}"
            assert gcs.poll() is None, f"MAVProxy ended: {(out / 'mavproxy.out').read_text()[-3000:]}"
            return sum(e["ev"] == "sp" for e in ev)

        _wait(lambda: sdk_sp() >= MAVSDK_SP, 90, "the MAVSDK app's offboard setpoints", poll=0.05)
        os.killpg(sdk.pid, signal.SIGKILL)
        t_kill = time.time()
        sdk.wait(5)
        pym = _spawn(out, "pymavlink", _app_cmd("_pymavlink_app", f"udpout:127.0.0.1:{APP_PORT}", str(pymlog),
                                                t_kill + CLIENT_TIMEOUT + 0.5))
        n_sp = int(HOLD_S * RATE_HZ)

        def pym_sp() -> int:
            assert pym.poll() is None, f"the pymavlink app ended: {(out / 'pymavlink.out').read_text()[-3000:]}"
            return sum(e["ev"] == "sp" for e in _lines(pymlog))

        _wait(lambda: pym_sp() >= n_sp, 30, "the pymavlink app's setpoints", poll=0.05)
        n = pym_sp()
        while pym_sp() == n:  # just after a setpoint: killed in its sleep
            time.sleep(0.005)
        pym.send_signal(signal.SIGKILL)
        t_kill2 = time.time()
        pym.wait(5)
        time.sleep(AFTER_S)
        gcs_alive = gcs.poll() is None
        t_sig = time.time()
        proxy_rc = stop_process(proxy, 15, signal.SIGINT)
        lis.stop()
        obs.stop()
        sdk_ev, pym_ev = _lines(sdklog), _lines(pymlog)
        res = {"t_start": t_start, "t_kill": t_kill, "t_kill2": t_kill2, "t_sig": t_sig,
               "sdk_events": [e for e in sdk_ev if e["ev"] != "sp"], "sdk_sp": [e["t"] for e in sdk_ev if e["ev"] == "sp"],
               "pym_events": [e for e in pym_ev if e["ev"] != "sp"], "pym_sp": [e for e in pym_ev if e["ev"] == "sp"],
               "sim": obs.sim, "lpos": obs.lpos, "hb": obs.hb, "listeners": lis.summary(), "gcs_alive": gcs_alive,
               "stats": json.loads(stats.read_text()), "proxy_rc": proxy_rc}
    finally:
        _stop_all(sdk, pym, proxy, gcs, obs, lis, sitl)
    res["gcs_out"] = (out / "mavproxy.out").read_text()
    parm = out / "mav.parm"
    res["gcs_params"] = len([s for s in parm.read_text().splitlines() if s.strip()]) if parm.exists() else 0
    res["t_end"] = time.time()
    (out / "result.json").write_text(json.dumps(res))
    return res


def _between(rec, t0: float, t1: float) -> list[float]:
    return [a for t, a in rec if t0 <= t <= t1]


def test_mavproxy_mavsdk_and_a_pymavlink_app_fly_arducopter_through_the_proxy(tmp_path):
    why = missing_reason("ardupilot") or _clients_missing()
    if why:
        pytest.skip(why)
    r = run_isolated("sitl.test_sitl_proxy_clients:clients_flight", {"out_dir": str(tmp_path)}, timeout=150)
    s = r["stats"]
    up, down = s["app_to_vehicle"], s["vehicle_to_app"]
    sdk_ev = {e["ev"]: e for e in r["sdk_events"]}
    pym_ev = {e["ev"]: e for e in r["pym_events"]}
    assert "offboard" in sdk_ev, r["sdk_events"]
    clients = {c["address"][1]: c for c in s["clients"] if c["app"].startswith("udpin")}
    pym = clients.pop(pym_ev["param"]["port"])
    quiet = clients.pop(r["listeners"]["udp_local_port"])
    (sdk,) = clients.values()

    # the ground station: every parameter, the mode and the arming, through the proxy
    count = pym_ev["param"]["param_count"]
    assert count > 0 and r["gcs_params"] == count and f"Received {count} parameters" in r["gcs_out"], \
        (count, r["gcs_params"], r["gcs_out"][-2000:])
    assert "Mode GUIDED" in r["gcs_out"] and "ARMED" in r["gcs_out"] and r["gcs_alive"]

    # MAVSDK's offboard flight reached its target height: the truth, above where the copter stood (ArduCopter
    # sends no local position before its EKF uses GPS, so the origin's true height is not known before take-off)
    assert "takeoff" in sdk_ev, r["sdk_events"]
    stood = _between(r["sim"], sdk_ev["takeoff"]["t"] - 5.0, sdk_ev["takeoff"]["t"] - 0.5)
    assert len(stood) >= 10 and max(stood) - min(stood) < 0.1, stood
    target = TARGET_ALT + float(np.median(stood))
    held = _between(r["sim"], r["t_kill"] - 1.5, r["t_kill"])
    assert len(held) >= 10 and all(abs(a - target) < 0.2 for a in held), (target, held)
    # ... and after its kill nothing of it reached the vehicle: its client silent since, the copter holds in GUIDED
    # (a datagram sent just before the kill may be read a little later on this loaded machine; MAVSDK sends at 20 Hz)
    assert sdk["silent_s"] >= r["t_sig"] - r["t_kill"] - 0.25, (sdk, r["t_sig"] - r["t_kill"])
    sp2 = r["pym_sp"]
    after = _between(r["sim"], r["t_kill"] + 0.5, sp2[0]["t"])
    assert after and all(abs(a - target) < 0.3 for a in after), after
    assert {(m, armed) for t, m, armed in r["hb"] if r["t_kill"] + 0.5 < t < sp2[0]["t"]} == {(GUIDED, True)}

    # the pymavlink app: a parameter read, its setpoints hold the point, exactly its frames reached the vehicle
    assert pym_ev["param"]["value"] > 0  # GUID_TIMEOUT
    during = _between(r["sim"], sp2[0]["t"] + 1.0, sp2[-1]["t"])
    assert len(during) >= 15 and all(abs(a - target) < 0.3 for a in during), during
    lp = _between(r["lpos"], sp2[0]["t"] + 1.0, sp2[-1]["t"])
    assert lp and all(abs(a - TARGET_ALT) < 0.3 for a in lp), lp[:5]
    assert pym["datagrams_in"] == sp2[-1]["sent"], (pym, sp2[-1])       # nothing after its kill
    assert s["setpoints"]["count"] - len(sp2) >= len(r["sdk_sp"]) + 1  # each MAVSDK call (+ its resends)
    assert s["events"]["foreign_setpoints"] == 0 and s["rewrite_hook"] is False
    assert up["rewritten"] == 0 and up["forwarded"] == up["received"]
    after2 = _between(r["sim"], r["t_kill2"] + 0.5, r["t_sig"])
    assert after2 and all(abs(a - target) < 0.3 for a in after2), after2
    assert {(m, armed) for t, m, armed in r["hb"] if t > r["t_kill2"] + 0.5} == {(GUIDED, True)}

    # nothing dropped, nothing out of order, both ways; nothing garbled of the clients'
    for d in (up, down):
        assert d["dropped"] == 0 and d["seq_gaps"] == 0 and d["send_errors"] == 0, d
    assert up["garbage_bytes"] == 0 and r["proxy_rc"] == 0
    # the quiet listeners: the TCP one got every vehicle frame, the UDP one (one heartbeat, then silence) kept
    # the stream to the end, with no gap
    lis = r["listeners"]
    assert lis["tcp"]["frames"] == down["received"] and lis["tcp"]["seq_gaps"] == 0, (lis, down)
    assert lis["udp"]["seq_gaps"] == 0 and lis["udp_last"] > r["t_sig"] - 1.0, lis
    assert quiet["datagrams_in"] == 1 and quiet["silent_s"] > r["t_sig"] - lis["t_hello"] - 0.5, quiet

    lat = up["latency_us"]
    print(f"\nwall {r['t_end'] - r['t_start']:.1f} s; params {count}; MAVSDK held {min(held):.2f}..{max(held):.2f} m "
          f"(target {target:.2f}), {len(r['sdk_sp'])} calls, proxy setpoints {s['setpoints']['count']}; pymavlink "
          f"{len(sp2)} setpoints, {pym['datagrams_in']} frames; app->vehicle recv {up['received']} p50 "
          f"{lat['p50']:.0f} us p99 {lat['p99']:.0f} us max {lat['max']:.0f} us; vehicle->app recv {down['received']} "
          f"fwd {down['forwarded']} p50 {down['latency_us']['p50']:.0f} us p99 {down['latency_us']['p99']:.0f} us; "
          f"quiet UDP listener {lis['udp']['frames']} frames, silent {quiet['silent_s']:.0f} s; "
          f"vehicle->app garbage {down['garbage_bytes']} B")
