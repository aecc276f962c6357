"""The bridge and the simulated vehicle as processes: a free port, the children's environment, one flight over
UDP loopback, the steering config and the report written (shared by the flying and the hopping demo)."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable

__all__ = ["ROOT", "free_udp_port", "python_m", "child_env", "stop_process", "write_toml", "fly", "write_report",
           "pin_args"]

ROOT = Path(__file__).resolve().parents[2]  # the repository (ddpc_codegen/testbed/ -> .)


def free_udp_port(host: str = "127.0.0.1") -> int:
    """An ephemeral UDP port that is free right now on ``host``."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def python_m() -> list[str]:
    """This interpreter's ``python -m`` (the child processes run the same environment)."""
    return [sys.executable, "-m"]


def child_env() -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    return env


def stop_process(proc: subprocess.Popen | None, timeout: float = 10.0, sig: int = signal.SIGTERM) -> int | None:
    """``sig`` (SIGTERM; SIGINT for a program that writes its statistics on it), then SIGKILL after ``timeout`` s
    (nothing for a process that has ended); its exit code (None: no process)."""
    if proc is None:
        return None
    if proc.poll() is None:
        proc.send_signal(sig)
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)
    return proc.returncode


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return repr(v)


def write_toml(raw: dict, path: Path) -> Path:
    """A flat TOML writer for the steering-config layout (top-level scalars, one level of tables)."""
    lines = [f"{k} = {_toml_value(v)}" for k, v in raw.items() if not isinstance(v, dict)]
    for k, v in raw.items():
        if isinstance(v, dict):
            lines += ["", f"[{k}]"] + [f"{kk} = {_toml_value(vv)}" for kk, vv in v.items()]
    path.write_text("\n".join(lines) + "\n")
    return path


def fly(name: str, work: Path, bridge_args: list[str], *, duration: float, seed: int, rt_priority: int,
        cpu_latency_us: int = 0, pin: bool = False, log=print, vehicle_args: list[str] = (),
        beside: Callable[[int], list[str]] | None = None) -> dict:
    """One flight: a fresh vehicle process + a bridge process over UDP loopback. Returns file paths, the bridge's
    summary and the vehicle's (``vehicle``: what reached it). ``vehicle_args``: more ``ddpc-vehicle`` flags (e.g.
    --scenario hopping --lockstep). ``beside(port)``: the ``python -m`` arguments of a third process (a peer on
    another address, e.g. :mod:`.proxy_flood`) started before the bridge and ended with SIGTERM after it."""
    port = free_udp_port()
    truth = work / f"{name}_truth.npz"
    ticks = work / f"{name}.npz"
    summ = work / f"{name}_summary.json"
    veh_summ = work / f"{name}_vehicle.json"
    for f in (truth, ticks, summ, veh_summ):
        f.unlink(missing_ok=True)
    veh = br = side = None
    veh_err = open(work / f"{name}_vehicle.log", "w")
    try:
        veh = subprocess.Popen(
            python_m() + ["ddpc_codegen.testbed.vehicle_cli", f"udpout:127.0.0.1:{port}", "--seed", str(seed),
                     "--truth-log", str(truth), "--summary", str(veh_summ), "--rt-priority", str(max(0, rt_priority - 10)),
                     "--cpu-latency-us", str(cpu_latency_us)] + pin_args(pin, "vehicle") + list(vehicle_args),
            env=child_env(), stdout=subprocess.DEVNULL, stderr=veh_err)
        if beside is not None:
            with open(work / f"{name}_beside.log", "w") as side_err:
                side = subprocess.Popen(python_m() + beside(port), env=child_env(), stdout=subprocess.DEVNULL,
                                        stderr=side_err)
        cmd = python_m() + ["firmware_bridge.cli", "bridge", f"udpin:127.0.0.1:{port}", "--offboard", "--duration",
                       str(duration), "--log", str(ticks), "--overwrite", "--summary", str(summ), "--rt-priority", str(rt_priority),
                       "--cpu-latency-us", str(cpu_latency_us), *pin_args(pin, "bridge"),
                       "--wait-heartbeat", "30", "--timeout", str(duration + 60)] + bridge_args
        log(f"  [{name}] {' '.join(cmd[2:])}")
        t0 = time.monotonic()
        br = subprocess.run(cmd, env=child_env(), capture_output=True, text=True, timeout=duration + 90)
        if br.returncode != 0:
            raise RuntimeError(f"bridge ({name}) failed with {br.returncode}:\n{br.stderr}\n{br.stdout}")
        log("    " + br.stdout.strip().replace("\n", "\n    ") + f"\n    ({time.monotonic() - t0:.1f} s wall)")
    finally:
        stop_process(side)
        stop_process(veh)
        veh_err.close()
    summary = json.loads(summ.read_text())
    vehicle = json.loads(veh_summ.read_text()) if veh_summ.is_file() else None
    return {"truth": truth, "ticks": ticks, "summary": summary, "vehicle": vehicle}


def write_report(report: dict, out: Path, t_start: float, table, log=print) -> dict:
    """Finish a demo: its wall time (since ``t_start``, monotonic) into ``report``, the JSON to
    ``out``, the README table (``table(report)``) to ``log``."""
    report["wall_s"] = time.monotonic() - t_start
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(report, indent=2, default=str) + "\n")
    log(table(report))
    log(f"wrote {out}")
    return report


def pin_args(pin: bool, who: str) -> list[str]:
    """--cpus for one process: the bridge on the last CPU this process may use, the vehicle on the first."""
    cpus = sorted(os.sched_getaffinity(0))
    if not pin or len(cpus) < 2:
        return []
    return ["--cpus", str(cpus[-1] if who == "bridge" else cpus[0])]
