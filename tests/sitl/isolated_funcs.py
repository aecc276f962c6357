"""Functions that :func:`firmware_bridge.sitl.run_isolated` runs in a child process (importable by
module name: tests/ is on the import path)."""

from __future__ import annotations

import time


def netns_facts(tag: str) -> dict:
    """Which interfaces this process sees and whether it knows it is isolated."""
    from firmware_bridge.sitl import in_private_netns

    with open("/proc/net/dev") as f:
        ifaces = [line.split(":")[0].strip() for line in f.readlines()[2:]]
    return {"tag": tag, "private": in_private_netns(), "interfaces": ifaces}


def sitl_heartbeat(autopilot: str) -> dict:
    """Start the SITL, wait for its heartbeat, read one parameter, stop it; what was seen."""
    from firmware_bridge.sitl import make_sitl

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


def ardupilot_climb_rate_refusal(out_dir: str) -> dict:
    """ArduCopter SITL with GUID_OPTIONS 0: ``ddpc-bridge --mode collect --arm --offboard`` must
    exit 4 right after reading the parameter, before any mode or arming command."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    from firmware_bridge.sitl import make_sitl

    out = Path(out_dir)
    with make_sitl("ardupilot", params={"GUID_OPTIONS": 0}) as sitl:
        cmd = [sys.executable, "-m", "firmware_bridge.cli", "bridge", sitl.url, "--autopilot", "ardupilot",
               "--profile", "arducopter_sitl", "--mode", "collect", "--arm", "--offboard", "--takeoff",
               "--wait-heartbeat", "60", "--timeout", "60", "--summary", str(out / "s.json")]
        t0 = time.monotonic()
        res = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
        wall = time.monotonic() - t0
    return {"rc": res.returncode, "stderr": res.stderr[-3000:], "wall_s": wall,
            "events": [e for _, e in json.loads((out / "s.json").read_text())["events"]]}
