"""Functions that :func:`ddpc_codegen.testbed.sitl.run_isolated` runs in a child process (importable by
module name: tests/ is on the import path)."""

from __future__ import annotations

import os
import signal
import subprocess
import time
from collections.abc import Callable
from pathlib import Path


def netns_facts(tag: str) -> dict:
    """Which interfaces this process sees and whether it knows it is isolated."""
    from ddpc_codegen.testbed.sitl import in_private_netns

    with open("/proc/net/dev") as f:
        ifaces = [line.split(":")[0].strip() for line in f.readlines()[2:]]
    return {"tag": tag, "private": in_private_netns(), "interfaces": ifaces}


def sitl_heartbeat(autopilot: str) -> dict:
    """Start the SITL, wait for its heartbeat, read one parameter, stop it; what was seen."""
    from ddpc_codegen.testbed.sitl import make_sitl

    name = {"px4": "MPC_THR_HOVER", "ardupilot": "MOT_THST_HOVER"}[autopilot]
    sitl = make_sitl(autopilot)
    with sitl:
        conn = sitl.connect(timeout=60)
        t_hb = time.monotonic() - sitl.started_at
        hb = conn.recv_match(type="HEARTBEAT", blocking=True, timeout=5)
        conn.mav.param_request_read_send(conn.target_system, conn.target_component, name.encode(), -1)
        pv = conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=5)
        conn.close()
        workdir = str(sitl.workdir)
    return {"heartbeat_s": t_hb, "autopilot": hb.autopilot, "type": hb.type, "param": name,
            "value": None if pv is None else float(pv.param_value), "rc": sitl.proc is None, "workdir": workdir}


def flight_with_autopilot_log(autopilot: str, out_dir: str, duration: float = 6.0) -> dict:
    """A short passthrough flight from the ground (arm, take off, fly, land) by ``ddpc-bridge``,
    and the autopilot's side of it: PX4's own ULog (from its working directory ``log/``), or for
    ArduCopter (GUID_OPTIONS 8) a tlog recorded meanwhile by a GCS-like connection on SERIAL1
    (5762) that asks for ATTITUDE, LOCAL_POSITION_NED and ATTITUDE_TARGET at 50 Hz."""
    import shutil
    import sys
    import threading

    from ddpc_codegen.testbed.sitl import make_sitl
    from ddpc_codegen.testbed.sitl_flight import PROFILES

    out = Path(out_dir)
    sitl = make_sitl(autopilot, **({"params": {"GUID_OPTIONS": 8}} if autopilot == "ardupilot" else {}))
    sitl.keep = True
    stop = threading.Event()
    rec = None
    with sitl:
        if autopilot == "ardupilot":
            sitl.connect(timeout=60).close()
            rec = threading.Thread(target=_record_tlog, args=("tcp:127.0.0.1:5762", out / "ardupilot.tlog", stop),
                                   daemon=True)
            rec.start()
        cmd = [sys.executable, "-m", "firmware_bridge.cli", "bridge", sitl.url, "--autopilot", autopilot,
               "--profile", PROFILES[autopilot], "--mode", "passthrough", "--arm", "--offboard", "--takeoff", "--land",
               "--duration", f"{duration:g}", "--timeout", "150", "--wait-heartbeat", "60",
               "--log", str(out / "ticks.npz"), "--overwrite", "--summary", str(out / "summary.json"),
               "--target-system", str(sitl.sysid)]
        res = subprocess.run(cmd, capture_output=True, text=True, timeout=300, cwd=out)
        stop.set()
        if rec is not None:
            rec.join(5)
        workdir = sitl.workdir
    logs = []
    for p in sorted(workdir.glob("log/**/*.ulg")):
        logs.append(str(shutil.copy(p, out / p.name)))
    shutil.rmtree(workdir, ignore_errors=True)
    if autopilot == "ardupilot":
        logs.append(str(out / "ardupilot.tlog"))
    return {"rc": res.returncode, "stderr": res.stderr[-3000:], "logs": logs}


def _record_tlog(url: str, path, stop) -> None:
    """A GCS on ``url``: asks for the streams at 50 Hz and writes every message it receives as a tlog."""
    from pymavlink import mavutil

    conn = mavutil.mavlink_connection(url, source_system=254, autoreconnect=False)
    conn.setup_logfile(str(path), mode="wb")
    conn.wait_heartbeat(timeout=30)
    for msg_id in (30, 32, 83):  # ATTITUDE, LOCAL_POSITION_NED, ATTITUDE_TARGET
        conn.mav.command_long_send(conn.target_system, conn.target_component, 511, 0, msg_id, 20000, 0, 0, 0, 0, 0)
    next_hb = 0.0
    while not stop.is_set():
        if time.monotonic() >= next_hb:
            next_hb = time.monotonic() + 1.0
            conn.mav.heartbeat_send(6, 8, 0, 0, 0)  # MAV_TYPE_GCS, MAV_AUTOPILOT_INVALID
        conn.recv_match(blocking=True, timeout=0.2)
    conn.close()


def _stopped_mid_flight(cmd: list[str], console: Path, cwd: Path, pid: Callable[[subprocess.Popen], int],
                        stall_after: float, stall_s: float, timeout: float) -> tuple[int, float]:
    """Run the bridge command ``cmd`` (console to ``console``); ``stall_after`` s after its trajectory starts, stop
    the process ``pid(bridge)`` (the SITL's or the bridge's own) with SIGSTOP for ``stall_s`` s, then SIGCONT it;
    wait for the bridge to exit within ``timeout`` s. Returns (its exit code, the stall's length as timed here [s]).
    The bridge's process group is killed (SIGKILL) if it is still running at the end.

    Raises:
        RuntimeError: the trajectory never started (within 80 s).
    """
    with open(console, "w") as f:
        br = subprocess.Popen(cmd, stdout=f, stderr=subprocess.STDOUT, cwd=cwd, start_new_session=True)
        try:
            t_end = time.monotonic() + 80.0
            while time.monotonic() < t_end and br.poll() is None:
                text = console.read_text()  # started at the start height, or after the approach's timeout
                if "at the trajectory's start height: trajectory starts" in text or "trajectory starts anyway" in text:
                    break
                time.sleep(0.05)
            else:
                raise RuntimeError(f"the trajectory never started:\n{console.read_text()[-3000:]}")
            time.sleep(stall_after)
            target = pid(br)
            t0 = time.monotonic()
            os.kill(target, signal.SIGSTOP)
            try:
                time.sleep(stall_s)
            finally:
                os.kill(target, signal.SIGCONT)
            stall = time.monotonic() - t0
            rc = br.wait(timeout=timeout)
        finally:
            if br.poll() is None:
                os.killpg(br.pid, signal.SIGKILL)
                br.wait()
    return rc, stall


def px4_stall_flight(out_dir: str, stall_after: float = 3.0, stall_s: float = 2.0, duration: float = 9.0) -> dict:
    """A passthrough PX4 flight from the ground in which the PX4 daemon is frozen (SIGSTOP) for
    ``stall_s`` seconds, ``stall_after`` seconds into the trajectory, then continued (SIGCONT).

    Returns the bridge's exit code, the stall's length as timed here [s], the paths of the bridge's
    tick log and summary and the tail of its console.
    """
    from ddpc_codegen.testbed.sitl import make_sitl
    from ddpc_codegen.testbed.sitl_flight import bridge_command

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    console = out / "px4_passthrough.out"
    with make_sitl("px4") as sitl:
        cmd = bridge_command(sitl, "px4", "passthrough", out, duration, timeout=90.0)
        rc, stall = _stopped_mid_flight(cmd, console, out, lambda _br: sitl.proc.pid, stall_after, stall_s, 120.0)
    return {"rc": rc, "stall_s": stall, "log": str(out / "px4_passthrough.npz"),
            "summary": str(out / "px4_passthrough.json"), "console": console.read_text()[-4000:]}


def ardupilot_bridge_stall_flight(out_dir: str, collect_s: float = 12.0, stall_after: float = 2.5,
                                  stall_s: float = 4.0, duration: float = 10.0) -> dict:
    """Issue 46's probe re-flown on ArduCopter: a short collect flight from the ground and ``ddpc-codegen codegen``
    on it (as ``make sitl-demo`` does, shorter), then a steered flight from the ground in which the *bridge*
    process is stopped (SIGSTOP) for ``stall_s`` s, ``stall_after`` s into the trajectory, then continued.

    Returns the steered flight's exit code, the stall's length as timed here [s], the paths of its tick log and
    summary, the tail of its console and the wall time of each part [s].
    """
    from ddpc_codegen.testbed.sitl import make_sitl
    from ddpc_codegen.testbed.sitl_demo import COLLECT, CONFIGS, ROOT, SITL_PARAMS, codegen
    from ddpc_codegen.testbed.sitl_flight import bridge_command, ensure_disarmed, fly

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    console = out / "ardupilot_steer.out"
    wall = {"start": time.monotonic()}
    with make_sitl("ardupilot", params=SITL_PARAMS["ardupilot"]) as sitl:
        fly(sitl, "ardupilot", "collect", out, collect_s, extra=("--dataset-skip", "1.0", *COLLECT["ardupilot"]))
        wall["collect"] = time.monotonic()
        solver = codegen(ROOT / "configs" / CONFIGS["ardupilot"], out / "ardupilot_collect.npz", out / "generated")
        wall["codegen"] = time.monotonic()
        ensure_disarmed(sitl)
        cmd = bridge_command(sitl, "ardupilot", "steer", out, duration, timeout=90.0, extra=("--solver", str(solver)))
        rc, stall = _stopped_mid_flight(cmd, console, out, lambda br: br.pid, stall_after, stall_s, 120.0)
        wall["steer"] = time.monotonic()
    marks = list(wall.values())
    return {"rc": rc, "stall_s": stall, "log": str(out / "ardupilot_steer.npz"),
            "summary": str(out / "ardupilot_steer.json"), "console": console.read_text()[-4000:],
            "wall_s": {k: round(b - a, 1) for k, a, b in zip(list(wall)[1:], marks, marks[1:])}}


def sitl_conditions_and_truth(autopilot: str) -> dict:
    """Start the SITL; set each unseen change of the demo (:data:`CONDITIONS`) and undo it, as the demo
    does between flights; then ask for the SITL's ground-truth message as the bridge does and read a
    few, through :class:`firmware_bridge.truth.SimTruth`; what was echoed and seen."""
    from firmware_bridge.truth import TRUTH_MESSAGES, SimTruth

    from ddpc_codegen.testbed.sitl import SitlError, make_sitl
    from ddpc_codegen.testbed.sitl_conditions import CONDITIONS

    echoed, refused = {}, None
    with make_sitl(autopilot) as sitl:
        sitl.connect(timeout=60).close()
        for name, spec in CONDITIONS[autopilot].items():
            if not isinstance(spec, str):
                echoed[name] = (sitl.set_params(spec[0]), sitl.set_params(spec[1]))
        try:
            sitl.set_params({"NO_SUCH_PARAM_X": 1.0}, timeout=3.0)
        except SitlError as e:
            refused = str(e)
        conn = sitl.connect(timeout=30)
        # make sitl-adapt's mid-flight change: over the SITL's second link while the first one is held
        from ddpc_codegen.testbed.sitl_adapt import second_link, send_params

        spec, link2 = CONDITIONS[autopilot]["heavy"], second_link(sitl).connect(timeout=10)
        try:
            second = [send_params(link2, spec[0]), send_params(link2, spec[1])]
        finally:
            link2.close()
        msg_name, msg_id = TRUTH_MESSAGES[autopilot]
        conn.mav.command_long_send(conn.target_system, conn.target_component, 511, 0, msg_id, 20000, 0, 0, 0, 0, 0)
        truth = SimTruth()
        t_end = time.monotonic() + 60.0  # ArduCopter fills SIM_STATE's position once its simulation runs
        while truth.seq < 20 and time.monotonic() < t_end:
            m = conn.recv_match(type=msg_name, blocking=True, timeout=1.0)
            if m is not None:
                truth.update(m, time.monotonic())
                if truth.seq == 1:
                    truth.capture_ground()
        conn.close()
    return {"echoed": echoed, "refused": refused, "truth_samples": truth.seq, "source": truth.source,
            "truth_position": truth.position.tolist(), "second_link_s": [t1 - t0 for t0, t1 in second]}
