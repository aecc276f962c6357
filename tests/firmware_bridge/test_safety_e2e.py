"""The bridge's safety glue (firmware_bridge/safety.py) against the simulated vehicle (``ddpc_codegen.testbed``)
in real time, as separate processes over UDP: a bridge stopped by SIGSTOP for 2 s mid-steer (what CPU
starvation or a GC pause does) is a stall -- an event, a refilled window, a bumpless resume -- and no
applied reference ever steps by more than the gate's rate bound, through injected solver failures, guard
trips, the stall and the hand-back at the end. Also: the exit codes and logs of an interrupted or
vehicle-lost flight, and an existing log is never overwritten without --overwrite."""

from __future__ import annotations

import signal
import time

import numpy as np
import pytest

from firmware_bridge.gate import GATE_FLAGS
from firmware_bridge.ticklog import REASONS, load_ticklog

from support.bridge_helpers import Procs, free_port, read_json

pytestmark = [pytest.mark.e2e, pytest.mark.compiler, pytest.mark.realtime]
R = {r: i for i, r in enumerate(REASONS)}


def _wait_for(path_text, what: str, timeout: float) -> None:
    t_end = time.monotonic() + timeout
    while what not in path_text():
        if time.monotonic() > t_end:
            raise AssertionError(f"timed out waiting for {what!r}:\n{path_text()[-3000:]}")
        time.sleep(0.05)


@pytest.fixture(scope="module")
def stalled(tmp_path_factory, flying_solver):
    """Steer the simulated PX4 (real time); solver calls 600..639 fail, the step guard is tight (0.02 m:
    guard trips), the correction may move 1 mm per tick ([envelope] offset_rate 0.2 m/s); 5 s after
    engaging the bridge is SIGSTOPped for 2 s, then it flies on to 12 s of trajectory (about 5 s: the resume,
    steering again, the hand-back at the end). (Not 4 s as in issue 46's ArduCopter probe: this vehicle takes
    attitude and thrust setpoints and holds the last one through the stall, so after 4 s it has fallen and
    tilted beyond anything a resume can be judged on; ArduCopter's guided mode holds its position.)"""
    tmp = tmp_path_factory.mktemp("stall")
    prof = tmp / "slow_gate.toml"
    prof.write_text('extends = "pogox"\n[envelope]\noffset_rate = [0.2, 0.2]\n')
    pr = Procs(tmp)
    port = free_port()
    try:
        # the autopilot keeps OFFBOARD through the stall (its loss timeout 5 s): the bridge must resume itself
        veh = pr.spawn("vehicle", f"udpout:127.0.0.1:{port}", "--seed", "3", "--com-of-loss-t", "5", name="vehicle")
        br = pr.spawn("bridge", f"udpin:127.0.0.1:{port}", "--mode", "steer", "--solver", str(flying_solver),
                      "--profile", str(prof), "--offboard", "--duration", "12", "--timeout", "60",
                      "--max-step", "0.02,0.5", "--inject-solver-failure", "600:40", "--verbose",
                      "--log", str(tmp / "ticks.npz"), "--summary", str(tmp / "summary.json"), name="bridge")
        _wait_for(lambda: pr.log(br), "engaged (", 40)
        time.sleep(5.0)
        br.send_signal(signal.SIGSTOP)
        time.sleep(2.0)
        br.send_signal(signal.SIGCONT)
        rc = pr.wait(br, 60)
        out = pr.log(br)
        pr.terminate(veh)
    finally:
        pr.cleanup()
    return {"rc": rc, "out": out, "s": read_json(tmp / "summary.json"), "log": load_ticklog(tmp / "ticks.npz")}


def test_a_sigstop_is_a_stall_with_an_event_and_a_refilled_window(stalled):
    assert stalled["rc"] == 0, stalled["out"]
    s, t = stalled["s"], stalled["log"].ticks
    # one stall of the SIGSTOP's 2 s; a loaded CI machine may hold the bridge off for tens of ms besides: real
    # stalls too, detected and recorded the same way, but never long
    big = [i for i, x in enumerate(s["stalls"]) if x["gap_s"] >= 1.9]
    assert len(big) == 1 and s["stalls"][big[0]]["gap_s"] <= 3.0, s["stalls"]
    assert all(x["gap_s"] < 0.5 for i, x in enumerate(s["stalls"]) if i != big[0]), s["stalls"]
    ev = [e for _, e in s["events"]]
    assert any(e.startswith("bridge stalled: no tick for 2.") for e in ev), ev
    # the bridge's pause, not the vehicle's silence: no link loss, no restore, no extra stream requests
    assert not [e for e in ev if "link lost" in e or "link restored" in e], ev
    assert s["link_losses"] == 0 and s["stream_requests"] == 1
    assert stalled["log"].metadata["stalls"] == s["stalls"]  # in the tick log too, with its time
    k = np.nonzero(t["gate"] & GATE_FLAGS["stall"])[0]
    assert k.size == len(s["stalls"])  # each stall flags the tick after it, in time order
    after = t["reason"][k[big[0]]:]
    # refilled: never steered on the window with the hole; (after the backlog of telemetry that arrived
    # stale is drained) blended back in, then steered again
    assert after[after != R["stale"]][0] in (R["blend"], R["warmup"]), after[:20]
    steering = (after == R["steered"]) | (after == R["guard_clamped"])  # a clamped tick is steered too
    first_steered = np.argmax(steering)
    assert first_steered > 0 and not np.any(steering[:first_steered]), np.unique(after, return_counts=True)


def test_no_applied_reference_steps_beyond_the_rate_bound(stalled):
    """|u[k] - u[k-1]| <= rate + |r_nom[k] - r_nom[k-1]| on every pair of consecutive ticks: the correction
    on top of the nominal reference moves at most 1 mm per tick, fallbacks and the stall included."""
    s, t = stalled["s"], stalled["log"].ticks
    rate = np.array(s["gate"]["rate_per_tick"])
    assert rate == pytest.approx([0.001, 0.001])
    du = np.abs(np.diff(t["u"], axis=0))
    dr = np.abs(np.diff(t["r_nom"], axis=0))
    assert np.all(du <= rate + dr + 1e-9), np.max(du - rate - dr)
    reasons = s["reasons"]
    assert reasons.get("solver_failed", 0) >= 20 and s["fallbacks"] >= 20  # the injected failures fell back
    assert s["gate"]["rate_limited"] > 0  # ... and were blended, not stepped
    # a clamp at the guard is a clamp (its own reason, the solver's proposal logged), not a fallback
    clamped = (t["gate"] & GATE_FLAGS["guard_clamped"]) != 0
    assert s["gate"]["guard_clamped"] == reasons.get("guard_clamped", 0) == clamped.sum() > 0
    assert "step_too_large" not in reasons and np.all(t["reason"][clamped] == R["guard_clamped"])
    assert np.all(np.isfinite(t["u_proposed"][clamped])) and np.all(np.isnan(t["u_proposed"][~clamped]))
    assert not any(e.startswith("fallback: step_too_large") for _, e in s["events"])
    ev = [e for _, e in s["events"]]
    assert any(e.startswith("fallback: solver_injected_failure") for e in ev), ev
    assert np.all(np.isfinite(t["u"])) and np.all(np.isfinite(t["sp_q"]))


def test_an_existing_log_is_refused_without_overwrite(tmp_path):
    from firmware_bridge.cli import bridge_main

    log = tmp_path / "flight.npz"
    log.write_bytes(b"precious")
    args = ["udpin:127.0.0.1:%d" % free_port(), "--mode", "passthrough", "--log", str(log), "--wait-heartbeat", "1"]
    assert bridge_main(args) == 2
    assert log.read_bytes() == b"precious"


def _wait_until_bound(port: int, timeout: float = 30.0) -> None:
    """Until a process listens on UDP ``port`` (binding it ourselves then fails)."""
    import socket

    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                return
        time.sleep(0.05)
    raise AssertionError(f"nothing bound UDP port {port} within {timeout} s")


def test_sigint_before_the_first_tick_leaves_a_log_and_exit_6(tmp_path):
    pr = Procs(tmp_path)
    try:
        port = free_port()
        br = pr.spawn("bridge", f"udpin:127.0.0.1:{port}", "--mode", "passthrough", "--wait-heartbeat", "30",
                      "--log", str(tmp_path / "t.npz"), "--summary", str(tmp_path / "s.json"), name="bridge")
        _wait_until_bound(port)  # imported, configured and waiting for a heartbeat
        br.send_signal(signal.SIGINT)
        rc = pr.wait(br, 20)
    finally:
        pr.cleanup()
    assert rc == 6, pr.log(br)
    assert "interrupted before the first tick" in pr.log(br)
    log = load_ticklog(tmp_path / "t.npz")
    assert log.n == 0 and read_json(tmp_path / "s.json")["stop_reason"] == "signal"


def test_a_vehicle_that_dies_ends_the_flight_with_exit_7(tmp_path):
    pr = Procs(tmp_path)
    port = free_port()
    try:
        veh = pr.spawn("vehicle", f"udpout:127.0.0.1:{port}", name="vehicle")
        br = pr.spawn("bridge", f"udpin:127.0.0.1:{port}", "--mode", "passthrough", "--offboard",
                      "--link-timeout", "1", "--vehicle-lost-timeout", "2", "--timeout", "60", "--verbose",
                      "--log", str(tmp_path / "t.npz"), "--summary", str(tmp_path / "s.json"), name="bridge")
        _wait_for(lambda: pr.log(br), "engaged (", 40)
        veh.kill()
        rc = pr.wait(br, 30)
    finally:
        pr.cleanup()
    assert rc == 7, pr.log(br)
    assert "vehicle lost: nothing heard for 2 s" in pr.log(br)
    s = read_json(tmp_path / "s.json")
    assert s["stop_reason"] == "vehicle lost" and load_ticklog(tmp_path / "t.npz").n == s["ticks"] > 0
