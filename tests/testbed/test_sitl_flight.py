"""One SITL flight from the ground and back (testbed/sitl_flight.py): a vehicle left armed by the last flight's
LAND is disarmed first (a fake autopilot over loopback UDP that disarms only on the forced command); a flight
that did not fly its duration is kept and flown again, never scored as flown."""

from __future__ import annotations

import json
import threading
import time

import pytest
from pymavlink import mavutil

from ddpc_codegen.testbed import sitl_flight
from ddpc_codegen.testbed.sitl_flight import ensure_disarmed, fly

from support.bridge_helpers import free_port


class _FakeAutopilot(threading.Thread):
    """Heartbeats at 20 Hz from system 1 to a UDP port, armed until a forced MAV_CMD_COMPONENT_ARM_DISARM."""

    def __init__(self, port: int, armed: bool, obey_plain_disarm: bool = False):
        super().__init__(daemon=True)
        self.conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=1)
        self.armed, self.obey_plain = armed, obey_plain_disarm
        self.commands: list[tuple[float, float]] = []
        self.stop = threading.Event()

    def run(self) -> None:
        mav = mavutil.mavlink
        while not self.stop.is_set():
            mode = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (mav.MAV_MODE_FLAG_SAFETY_ARMED if self.armed else 0)
            self.conn.mav.heartbeat_send(mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_PX4, mode, 0, 0)
            msg = self.conn.recv_match(type="COMMAND_LONG", blocking=True, timeout=0.05)
            if msg is not None and msg.command == mav.MAV_CMD_COMPONENT_ARM_DISARM:
                self.commands.append((msg.param1, msg.param2))
                if msg.param1 == 0 and (msg.param2 == 21196 or self.obey_plain):
                    self.armed = False


class _FakeSitl:
    autopilot = "px4"

    def __init__(self, port: int):
        self.port, self.url = port, f"udpin:127.0.0.1:{port}"

    def connect(self):
        conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{self.port}", source_system=255)
        hb = conn.recv_match(type="HEARTBEAT", blocking=True, timeout=5.0)
        assert hb is not None
        conn.target_system, conn.target_component = hb.get_srcSystem(), hb.get_srcComponent()
        return conn

    def log_tail(self) -> str:
        return "(fake)"


@pytest.fixture
def autopilot():
    made = []

    def make(armed: bool) -> tuple[_FakeSitl, _FakeAutopilot]:
        port = free_port()
        ap = _FakeAutopilot(port, armed)
        ap.start()
        made.append(ap)
        return _FakeSitl(port), ap

    yield make
    for ap in made:
        ap.stop.set()
        ap.join(2.0)
        ap.conn.close()


def test_a_disarmed_vehicle_is_left_alone(autopilot):
    sitl, ap = autopilot(armed=False)
    assert ensure_disarmed(sitl, wait=0.3) is False
    assert ap.commands == []


def test_a_vehicle_still_armed_after_land_is_force_disarmed_after_the_wait(autopilot):
    sitl, ap = autopilot(armed=True)
    t0 = time.monotonic()
    assert ensure_disarmed(sitl, wait=0.5, timeout=5.0) is True
    assert time.monotonic() - t0 >= 0.5  # it had its chance to disarm itself first
    assert ap.commands and all(c == (0.0, 21196.0) for c in ap.commands) and not ap.armed


def test_a_vehicle_that_refuses_the_disarm_is_an_error(autopilot, monkeypatch):
    sitl, ap = autopilot(armed=True)
    monkeypatch.setattr(sitl_flight, "_FORCE_DISARM", 0.0)  # a plain disarm, which the fake refuses
    with pytest.raises(RuntimeError, match="still armed after a forced disarm"):
        ensure_disarmed(sitl, wait=0.2, timeout=0.5)


def _fake_bridge(stops: list[str]):
    """subprocess.run for fly(): each call writes the next summary (its stop_reason) and a console file."""
    calls = []

    def run(cmd, stdout, **kw):
        out_json = cmd[cmd.index("--summary") + 1]
        reason = stops[len(calls)]
        calls.append(reason)
        stdout.write(f"bridge: {reason}\n")
        with open(out_json, "w") as f:
            json.dump({"stop_reason": reason, "rmse_z_measured": 0.01, "rmse_z_truth": None}, f)
        with open(cmd[cmd.index("--log") + 1], "wb") as f:
            f.write(reason.encode())

        class Done:
            returncode = 0
        return Done()

    return run, calls


def test_a_flight_that_timed_out_is_kept_and_flown_again(tmp_path, monkeypatch, capsys):
    run, calls = _fake_bridge(["timeout 150 s", "duration 20 s flown"])
    monkeypatch.setattr(sitl_flight.subprocess, "run", run)
    monkeypatch.setattr(sitl_flight, "ensure_disarmed", lambda sitl: True)
    s = fly(_FakeSitl(0), "px4", "passthrough", tmp_path, 20.0, tag="steps_r0")
    assert calls == ["timeout 150 s", "duration 20 s flown"] and s["stop_reason"] == "duration 20 s flown"
    # the failed attempt's files are kept under their own name; the scored ones are the retry's
    assert (tmp_path / "px4_steps_r0_attempt1.npz").read_bytes() == b"timeout 150 s"
    assert json.loads((tmp_path / "px4_steps_r0_attempt1.json").read_text())["stop_reason"] == "timeout 150 s"
    assert (tmp_path / "px4_steps_r0.npz").read_bytes() == b"duration 20 s flown"
    out = capsys.readouterr().out
    assert "still armed after the last flight: disarmed" in out
    assert "stopped before its 20 s (timeout 150 s): kept as px4_steps_r0_attempt1.*, flying it again" in out


def test_no_attempt_flying_its_duration_stops_the_run(tmp_path, monkeypatch):
    run, calls = _fake_bridge(["timeout 150 s", "vehicle lost"])
    monkeypatch.setattr(sitl_flight.subprocess, "run", run)
    monkeypatch.setattr(sitl_flight, "ensure_disarmed", lambda sitl: False)
    with pytest.raises(RuntimeError, match="2 attempts, none flew its 20 s"):
        fly(_FakeSitl(0), "px4", "passthrough", tmp_path, 20.0, tag="x")
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        f"px4_x_attempt{k}.{e}" for k in (1, 2) for e in ("json", "npz", "out")]
    run, calls = _fake_bridge(["timeout 150 s"])
    monkeypatch.setattr(sitl_flight.subprocess, "run", run)
    with pytest.raises(RuntimeError, match="1 attempts"):  # make sitl-adapt: one attempt (its change is timed)
        fly(_FakeSitl(0), "px4", "passthrough", tmp_path, 20.0, tag="y", attempts=1)
    with pytest.raises(ValueError, match=r"^attempts must be >= 1; got 0$"):
        fly(_FakeSitl(0), "px4", "passthrough", tmp_path, 20.0, tag="z", attempts=0)
