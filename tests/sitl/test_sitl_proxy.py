"""A real pymavlink app flies the real ArduCopter through ``ddpc-proxy`` (skipped without the SITL), and is
killed (SIGKILL) while it streams setpoints in the air.

ArduCopter SITL (TCP 5760) <- ``ddpc-proxy --vehicle tcp:127.0.0.1:5760 --app udpin:127.0.0.1:PORT`` <- an app
process (``udpout:127.0.0.1:PORT``): heartbeat, PARAM_REQUEST_READ, GUIDED, arm (retried until the EKF is
ready), MAV_CMD_NAV_TAKEOFF to 2 m, then SET_POSITION_TARGET_LOCAL_NED at 15 Hz holding that point. An
observer on the SITL's second port (TCP 5762) records SIM_STATE (ground truth), LOCAL_POSITION_NED and the
mode. The app logs each setpoint it sent; the proxy's statistics (SIGINT, ``--stats``) must count exactly
those setpoints and nothing after the kill (the proxy never sends on its own), with no frame dropped and no
sequence gap. A position target in GUIDED has no off-board-loss timeout in ArduCopter (``GUID_TIMEOUT``
covers velocity / acceleration / attitude targets): after the kill the copter holds the last point in
GUIDED, so there is no failsafe time to measure; the test records that it held."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from ddpc_codegen.testbed.sitl import missing_reason, run_isolated
from ddpc_codegen.testbed.sitl_observer import Observer, wait_tcp_port, wait_udp_bound

pytestmark = [pytest.mark.sitl, pytest.mark.slow, pytest.mark.realtime]

TAKEOFF_ALT = 2.0
RATE_HZ = 15.0
HOLD_S = 5.0     # the app streams this long before it is killed
AFTER_S = 4.0    # watched after the kill (GUID_TIMEOUT is 3 s)
APP_PORT = 14541
GUIDED = 4


def _log(path: str, **ev) -> None:
    """One JSON line, written unbuffered (the app may be SIGKILLed right after)."""
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        os.write(fd, (json.dumps(ev) + "\n").encode())
    finally:
        os.close(fd)


def _texts(c) -> list[str]:
    """The STATUSTEXTs received so far (what the autopilot said about a refusal)."""
    out = []
    while (m := c.recv_match(type="STATUSTEXT", blocking=False)) is not None:
        out.append(m.text)
    return out


def _app(url: str, log: str) -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "firmware_bridge" / "proxy_tests"))
    from mav_app import M, command, connect, read_param

    c = connect(url, sysid=250, timeout=30)
    _log(log, ev="heartbeat", sysid=c.target_system)
    _log(log, ev="param", name="GUID_TIMEOUT", value=read_param(c, "GUID_TIMEOUT", timeout=10))
    # GUIDED needs a position estimate (EKF using GPS, ~35-40 s after start), arming needs consistent sensors:
    # retry both until the heartbeat says GUIDED and armed
    end, res, tries, mode, armed = time.monotonic() + 100, None, 0, None, False
    while time.monotonic() < end:
        tries += 1
        c.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        hb = c.recv_match(type="HEARTBEAT", blocking=True, timeout=1.5)
        if hb is not None:
            mode, armed = hb.custom_mode, bool(hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED)
        if mode == GUIDED and armed:
            break
        if mode != GUIDED:
            res = command(c, M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, GUIDED, timeout=5)
        else:
            res = command(c, M.MAV_CMD_COMPONENT_ARM_DISARM, 1, timeout=5)
        time.sleep(0.5)
    res = M.MAV_RESULT_ACCEPTED if (mode == GUIDED and armed) else M.MAV_RESULT_FAILED
    _log(log, ev="arm", result=res, tries=tries, t=time.time())
    assert res == M.MAV_RESULT_ACCEPTED
    for tries in range(1, 11):  # right after arming the first one may be refused
        res = command(c, M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, TAKEOFF_ALT, timeout=5)
        if res == M.MAV_RESULT_ACCEPTED:
            break
        time.sleep(0.5)
    _log(log, ev="takeoff", result=res, tries=tries, text=_texts(c))
    end, pos, next_hb = time.monotonic() + 20, None, 0.0
    while time.monotonic() < end:
        if time.monotonic() > next_hb:  # keep the proxy's client alive (and ask for the position again)
            next_hb = time.monotonic() + 1.0
            c.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            c.mav.command_long_send(c.target_system, c.target_component, M.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                    32, 100_000, 0, 0, 0, 0, 0)  # LOCAL_POSITION_NED at 10 Hz on this link
        m = c.recv_match(type="LOCAL_POSITION_NED", blocking=True, timeout=0.2)
        if m is not None:
            pos = m
            if -m.z > TAKEOFF_ALT - 0.15:
                break
    _log(log, ev="airborne", z=None if pos is None else pos.z, t=time.time())
    x, y = (pos.x, pos.y) if pos is not None else (0.0, 0.0)
    mask = 0b0000_1111_1111_1000  # position only
    k, t0 = 0, time.monotonic()
    while True:  # until SIGKILL
        c.mav.set_position_target_local_ned_send(int(1000 * (time.monotonic() - t0)), c.target_system,
                                                 c.target_component, M.MAV_FRAME_LOCAL_NED, mask,
                                                 x, y, -TAKEOFF_ALT, 0, 0, 0, 0, 0, 0, 0, 0)
        k += 1
        _log(log, ev="sp", k=k, t=time.time())
        if k % int(RATE_HZ) == 0:
            c.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        while c.recv_match(blocking=False) is not None:
            pass
        time.sleep(max(0.0, t0 + k / RATE_HZ - time.monotonic()))


def _lines(path: Path) -> list[dict]:
    return [json.loads(s) for s in path.read_text().splitlines() if s.strip()] if path.exists() else []


def proxy_flight(out_dir: str) -> dict:
    """Runs in a private network namespace (:func:`run_isolated`): SITL, proxy, observer, app; the kill."""
    from ddpc_codegen.testbed.sitl import make_sitl

    out = Path(out_dir)
    applog, stats = out / "app.jsonl", out / "proxy.json"
    env = {**os.environ}
    sitl = make_sitl("ardupilot").start()
    proxy = app = obs = None
    res: dict = {}
    try:
        proxy = subprocess.Popen([sys.executable, "-m", "firmware_bridge.proxy.cli", "--app",
                                  f"udpin:127.0.0.1:{APP_PORT}", "--vehicle", "tcp:127.0.0.1:5760",
                                  "--stats", str(stats)], env=env, stdout=open(out / "proxy.out", "w"),
                                 stderr=subprocess.STDOUT, cwd=out)
        # the app starts once the proxy's UDP port is bound: pymavlink counts on its sequence number even when a
        # send fails (nobody on the port yet), which the proxy would rightly count as a gap
        wait_udp_bound(APP_PORT)
        code = f"import sys; sys.path.insert(0, {str(Path(__file__).resolve().parents[1])!r}); " \
               f"from sitl.test_sitl_proxy import _app; _app({f'udpout:127.0.0.1:{APP_PORT}'!r}, {str(applog)!r})"
        # MAVLink 2 from the first frame: pymavlink switching over on the autopilot's first MAVLink 2 frame builds a
        # new encoder, whose sequence number restarts at 0 (a gap the proxy would rightly count)
        app = subprocess.Popen([sys.executable, "-c", code], env={**env, "MAVLINK20": "1"}, stdout=open(out / "app.out", "w"),
                               stderr=subprocess.STDOUT, cwd=out)
        end = time.monotonic() + 20
        while not sitl._port_ready() and time.monotonic() < end:
            time.sleep(0.2)
        time.sleep(1.0)
        # the 5762 port is served once 5760 has its client (the proxy)
        wait_tcp_port(5762)
        obs = Observer("tcp:127.0.0.1:5762", rate_hz=10.0)
        # wait for HOLD_S of setpoints (bounded), then SIGKILL the app right after one was logged
        end = time.monotonic() + 140
        n_sp = 0
        while time.monotonic() < end and app.poll() is None:
            ev = _lines(applog)
            n_sp = sum(e["ev"] == "sp" for e in ev)
            if n_sp >= HOLD_S * RATE_HZ:
                break
            time.sleep(0.2)
        assert app.poll() is None, f"the app ended early: {(out / 'app.out').read_text()[-3000:]}"
        assert n_sp >= HOLD_S * RATE_HZ, f"the app did not reach the hold: {_lines(applog)}"
        while sum(e["ev"] == "sp" for e in _lines(applog)) == n_sp:  # just after a setpoint: kill in its sleep
            time.sleep(0.005)
        os.kill(app.pid, signal.SIGKILL)
        t_kill = time.time()
        app.wait(5)
        time.sleep(AFTER_S)
        os.kill(proxy.pid, signal.SIGINT)
        proxy.wait(15)
        t_end = time.time()
        obs.stop()
        ev = _lines(applog)
        sps = [e for e in ev if e["ev"] == "sp"]
        res = {"events": [e for e in ev if e["ev"] != "sp"], "sp_count": len(sps), "sp_first": sps[0]["t"],
               "sp_last": sps[-1]["t"], "t_kill": t_kill, "t_end": t_end, "sim": obs.sim, "lpos": obs.lpos,
               "hb": obs.hb, "texts": obs.texts, "stats": json.loads(stats.read_text()), "proxy_rc": proxy.returncode}
        (out / "result.json").write_text(json.dumps(res))
    finally:
        for p in (app, proxy):
            if p is not None and p.poll() is None:
                os.kill(p.pid, signal.SIGKILL)
                p.wait(5)
        if obs is not None and obs.is_alive():
            obs.stop()
        sitl.stop()
    return res


def test_an_app_flies_arducopter_through_the_proxy_and_is_killed_in_flight(tmp_path):
    why = missing_reason("ardupilot")
    if why:
        pytest.skip(why)
    r = run_isolated("sitl.test_sitl_proxy:proxy_flight", {"out_dir": str(tmp_path)}, timeout=170)
    ev = {e["ev"]: e for e in r["events"]}
    assert ev["param"]["value"] > 0  # GUID_TIMEOUT read through the proxy
    assert ev["arm"]["result"] == 0 and ev["takeoff"]["result"] == 0
    s = r["stats"]
    up, down = s["app_to_vehicle"], s["vehicle_to_app"]

    # the vehicle flew: ground truth near 2 m while the app streamed
    during = [a for t, a in r["sim"] if r["sp_first"] + 1.0 <= t <= r["sp_last"]]
    assert len(during) >= 20, len(during)
    assert all(1.5 < a < 2.5 for a in during), (min(during), max(during))
    lp = [a for t, a in r["lpos"] if r["sp_first"] + 1.0 <= t <= r["sp_last"]]
    assert lp and all(1.5 < a < 2.5 for a in lp), lp[:5]

    # the proxy forwarded exactly the app's setpoints: none of its own, none after the kill
    assert s["setpoints"]["count"] == r["sp_count"], (s["setpoints"], r["sp_count"])
    assert s["events"]["foreign_setpoints"] == 0 and s["rewrite_hook"] is False
    assert up["rewritten"] == 0 and up["forwarded"] == up["received"]
    # nothing dropped, nothing out of order, both ways
    for d in (up, down):
        assert d["dropped"] == 0 and d["seq_gaps"] == 0 and d["send_errors"] == 0, d
    # ArduCopter's TCP stream holds some bytes the proxy does not take for frames (53-164 B per run here, not
    # diagnosed); nothing of the app's
    assert up["garbage_bytes"] == 0
    assert r["proxy_rc"] == 0

    # after the kill: ArduCopter holds the last position target in GUIDED (no off-board-loss failsafe for it)
    after = [a for t, a in r["sim"] if t > r["t_kill"] + 0.5]
    assert after and all(1.5 < a < 2.5 for a in after), after[:5]
    modes = {(m, armed) for t, m, armed in r["hb"] if t > r["t_kill"] + 0.5}
    assert modes == {(GUIDED, True)}, modes

    lat = up["latency_us"]
    print(f"\nsetpoints {r['sp_count']} (proxy {s['setpoints']['count']}), period {s['setpoints']['period_s']:.4f} s, "
          f"max gap {s['setpoints']['max_gap_s']:.3f} s; kill {1e3 * (r['t_kill'] - r['sp_last']):.1f} ms after the "
          f"last; app->vehicle recv {up['received']} fwd {up['forwarded']} p50 {lat['p50']:.0f} us p99 {lat['p99']:.0f} "
          f"us max {lat['max']:.0f} us; vehicle->app recv {down['received']} fwd {down['forwarded']} "
          f"p50 {down['latency_us']['p50']:.0f} us p99 {down['latency_us']['p99']:.0f} us; "
          f"alt during {min(during):.2f}..{max(during):.2f} m, after kill {min(after):.2f}..{max(after):.2f} m; "
          f"arm tries {ev['arm']['tries']}; vehicle->app garbage {down['garbage_bytes']} B")
