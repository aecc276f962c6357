"""Issue 46 item 5: honest exit codes (firmware_bridge/exit_status.py). A run that never engaged, that ended in
the vehicle's own failsafe, or that timed out before its --duration was flown exits non-zero with one line
saying why; the codes are listed in the CLI's help and the bridge guide. Unit level (the outcome of a run's end
and the engagement's record of it), then against ``ddpc-vehicle``: a run it never lets engage, and a flight
whose vehicle failsafes out of off-board."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from firmware_bridge.cli import build_bridge_parser
from firmware_bridge.engagement import Engagement
from firmware_bridge.events import EventLog
from firmware_bridge.exit_status import EXIT_CODES, RunEnd, run_outcome

from support.bridge_helpers import Procs, free_port, read_json

FLOWN = dict(ticks=4000, activations=1, engaged=True, flown_s=20.0)


@pytest.mark.parametrize("end, code, says", [
    (RunEnd("duration 20 s flown", duration=20.0, **FLOWN), 0, ""),
    (RunEnd("signal", **FLOWN), 0, ""),
    (RunEnd("timeout 30 s", **FLOWN), 0, ""),  # no --duration: the timeout is the end asked for
    (RunEnd("vehicle lost", **FLOWN), 7, "vehicle lost: nothing heard for 10 s"),
    (RunEnd("signal", ticks=0, activations=0, engaged=False), 6, "interrupted before the first tick"),
    (RunEnd("timeout 30 s", ticks=0, activations=0, engaged=False), 8,
     "never engaged (timeout 30 s): no telemetry arrived (0 ticks); nothing flown"),
    (RunEnd("timeout 30 s", ticks=6000, activations=0, engaged=False), 8,
     "never engaged (timeout 30 s): the vehicle was never armed + off-board; nothing flown"),
    (RunEnd("signal", ticks=6000, activations=0, engaged=False), 8, "never engaged (signal)"),
    (RunEnd("timeout 30 s", ticks=6000, activations=1, engaged=False, left_mode="AUTO.LOITER", flown_s=3.2,
            duration=20.0), 9, "ended in the vehicle's own mode AUTO.LOITER (timeout 30 s): it left off-board by "
                               "itself (failsafe or pilot) after 3.2 s of the trajectory"),
    (RunEnd("signal", ticks=6000, activations=2, engaged=False, left_mode="LAND"), 9, "own mode LAND (signal)"),
    (RunEnd("timeout 30 s", ticks=6000, activations=1, engaged=True, flown_s=12.5, duration=20.0), 10,
     "timeout 30 s before the --duration was flown (12.5 of 20 s)"),
])
def test_each_end_of_a_run_has_its_code_and_one_line(end, code, says):
    got, why = run_outcome(end)
    assert got == code and says in why and "\n" not in why
    assert code in EXIT_CODES


def test_the_codes_are_in_the_help_and_the_guide():
    epilog = build_bridge_parser().epilog
    guide = (Path(__file__).parents[2] / "docs" / "guides" / "bridge.md").read_text()
    for code in EXIT_CODES:
        assert f"\n  {code:>2}  {EXIT_CODES[code]}" in epilog
        assert f"| {code} |" in guide, f"exit code {code} is not in docs/guides/bridge.md"


def test_the_engagement_keeps_the_mode_the_vehicle_went_to():
    e = Engagement(EventLog(t0=0.0))
    y = np.array([1.0, 0.0])
    e.update(False, 0.0, y, 1.0, "POSCTL")
    assert e.left_mode == ""  # never engaged: nothing left
    e.update(True, 1.0, y, 1.0, "OFFBOARD")
    e.update(False, 2.0, y, 1.0, "OFFBOARD")  # the link dropped first: its last known mode ...
    e.update(False, 2.5, y, 1.0, "AUTO.LOITER")  # ... then the failsafe's
    assert e.left_mode == "AUTO.LOITER" and not e.engaged
    e.update(True, 3.0, y, 1.0, "OFFBOARD")
    assert e.left_mode == ""  # back: the run may end flown


@pytest.mark.e2e
def test_a_run_the_vehicle_never_lets_engage_exits_8(tmp_path):
    """ddpc-vehicle hovers in HOLD; the bridge may not switch it (no --offboard): a --timeout later, exit 8."""
    pr = Procs(tmp_path)
    port = free_port()
    try:
        veh = pr.spawn("vehicle", f"udpout:127.0.0.1:{port}", name="vehicle")
        br = pr.spawn("bridge", f"udpin:127.0.0.1:{port}", "--mode", "passthrough", "--timeout", "4",
                      "--summary", str(tmp_path / "s.json"), "--wait-heartbeat", "30", name="bridge")
        rc = pr.wait(br, 60)
        pr.terminate(veh)
    finally:
        pr.cleanup()
    out = pr.log(br)
    assert rc == 8, out
    assert "ddpc-bridge: error: never engaged (timeout 4 s): the vehicle was never armed + off-board" in out
    s = read_json(tmp_path / "s.json")
    assert s["ticks"] > 0 and s["activations"] == 0 and s["exit"] == {"code": 8, "reason": s["exit"]["reason"]}


@pytest.mark.e2e
@pytest.mark.slow
def test_a_flight_that_ends_in_the_vehicles_failsafe_exits_9(tmp_path):
    """ddpc-vehicle goes silent for 1.5 s (simulated 4..5.5 s, the bridge engaged about 2 s before); the bridge, stale,
    stops streaming after 0.2 s, the vehicle's off-board loss (0.5 s) holds it: the flight ends at --timeout (some
    3 s after the vehicle left off-board) with the vehicle in its own mode."""
    pr = Procs(tmp_path)
    port = free_port()
    try:
        veh = pr.spawn("vehicle", f"udpout:127.0.0.1:{port}", "--com-of-loss-t", "0.5", "--silence", "4:5.5",
                       name="vehicle")
        br = pr.spawn("bridge", f"udpin:127.0.0.1:{port}", "--mode", "passthrough", "--offboard", "--timeout", "9",
                      "--duration", "30", "--stale-stream-limit", "0.2", "--summary", str(tmp_path / "s.json"),
                      "--wait-heartbeat", "30", name="bridge")
        rc = pr.wait(br, 60)
        pr.terminate(veh)
    finally:
        pr.cleanup()
    out = pr.log(br)
    assert rc == 9, out
    assert "ddpc-bridge: error: ended in the vehicle's own mode" in out and "failsafe or pilot" in out
    s = read_json(tmp_path / "s.json")
    assert s["activations"] >= 1 and s["exit"]["code"] == 9
