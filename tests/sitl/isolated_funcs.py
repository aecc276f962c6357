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
