"""Helpers and fixtures for the MAVLink bridge tests: free loopback ports, process spawning that
always cleans up, a small generated solver, an in-process fake vehicle. (No conftest.py here:
other test modules import the top-level ``conftest`` by name, so a second one would shadow it.
Test modules import the fixtures they use from this module.)

Everything talks UDP on 127.0.0.1 only; every wait is bounded.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _env() -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    return env


class Procs:
    """Spawns bridge (``firmware_bridge.cli``) and vehicle (``ddpc_codegen.testbed.vehicle_cli``) processes; kills whatever is left at teardown."""

    def __init__(self, tmp: Path) -> None:
        self.tmp = tmp
        self.procs: list[subprocess.Popen] = []

    def spawn(self, *args: str, name: str = "proc") -> subprocess.Popen:
        out = open(self.tmp / f"{name}.out", "w")
        module = "ddpc_codegen.testbed.vehicle_cli" if args[:1] == ("vehicle",) else "firmware_bridge.cli"
        p = subprocess.Popen([sys.executable, "-m", module, *args], env=_env(), stdout=out,
                             stderr=subprocess.STDOUT, cwd=str(self.tmp))
        p._log = self.tmp / f"{name}.out"  # type: ignore[attr-defined]
        self.procs.append(p)
        return p

    def wait(self, p: subprocess.Popen, timeout: float) -> int:
        try:
            return p.wait(timeout)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait(5)
            raise AssertionError(f"process did not finish in {timeout} s:\n{Path(p._log).read_text()[-3000:]}")

    def terminate(self, p: subprocess.Popen, timeout: float = 15.0) -> int:
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
        return self.wait(p, timeout)

    def log(self, p: subprocess.Popen) -> str:
        return Path(p._log).read_text()

    def cleanup(self) -> None:
        for p in self.procs:
            if p.poll() is None:
                p.kill()
                try:
                    p.wait(5)
                except subprocess.TimeoutExpired:  # pragma: no cover
                    pass


def px4_params() -> dict[str, float]:
    """What the fake vehicle answers: PX4's off-board loss timeout (its default) and a hover thrust estimate that
    agrees with the bridge's default controller model (as ``ddpc-vehicle``'s does: the bridge refuses a vehicle
    whose hover thrust its model is far from)."""
    from firmware_bridge.bridge_config import default_controller_config

    c = default_controller_config()
    return {"MPC_THR_HOVER": c.model_mass * c.g / c.max_thrust, "COM_OF_LOSS_T": 1.0}


def wait_until(cond, timeout: float, what: str) -> None:
    """Poll ``cond()`` every 10 ms until it holds; AssertionError naming ``what`` after ``timeout`` s."""
    t_end = time.monotonic() + timeout
    while not cond():
        if time.monotonic() > t_end:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(0.01)


def read_json(path: Path) -> dict:
    return json.loads(Path(path).read_text())


class FakeVehicle(threading.Thread):
    """A scripted PX4 stand-in in a thread (udpout to the bridge): heartbeat (armed, OFFBOARD),
    hover telemetry at 200 Hz in one datagram per tick, COMMAND_ACKs; records every setpoint.

    ``telemetry`` and ``heartbeat`` switch the two streams on and off while running. ``pattern``
    imitates a real autopilot's telemetry (measured against the SITLs): "px4" -- 1 ms stamps,
    attitude steps 4/8/12 ms, position every 8 ms (~125 samples/s per stream); "burst" -- 5 ms
    stamps delivered two per datagram every 10 ms (ArduCopter over TCP). ``sent`` counts samples.

    ``params`` answers PARAM_REQUEST_READ by name, as PX4 does: the bridge's preflight reads them before its
    first tick and waits 3 s for an unanswered one (set ``params = {}`` to test that wait).
    """

    def __init__(self, port: int, sysid: int = 1, z: float = 0.9, pattern: str = "regular") -> None:
        super().__init__(daemon=True)
        from firmware_bridge.link import MavLink

        self.link = MavLink(f"udpout:127.0.0.1:{port}", source_system=sysid, source_component=1, target_system=None)
        self.z = z
        self.telemetry = True
        self.heartbeat = True
        self.extra: list = []  # callables run once per tick (garbage injection ...)
        self.setpoints: list[tuple[float, object]] = []
        self.first_setpoint = threading.Event()
        self.bridge_seen = threading.Event()  # any message from the bridge arrived (it is listening)
        self.stop_flag = threading.Event()
        self.k = 0
        self.pattern = pattern
        self.armed = True
        self.arm_refusals = 0  # refuse this many ARM commands (TEMPORARILY_REJECTED) before accepting; -1: always
        self.arm_delay = 0.0  # seconds from an accepted ARM to being armed (a real autopilot's arming checks)
        self._arm_at: float | None = None
        self.commands: list[int] = []  # COMMAND_LONG ids received
        self.armed_hb_at: float | None = None  # just before the first heartbeat saying "armed" went out (monotonic)
        self.sent = {"attitude": 0, "position": 0}
        self.params: dict[str, float] = px4_params()

    def run(self) -> None:
        from firmware_bridge.link import mavlink
        from firmware_bridge.profiles import MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, MAV_MODE_FLAG_SAFETY_ARMED, px4_custom_mode

        from ddpc_codegen.robot.frames import quat_ned_frd_from_enu_flu

        q_level = quat_ned_frd_from_enu_flu((1.0, 0.0, 0.0, 0.0))  # level, yaw 0 ENU (= 90 deg NED), as PX4 would send it
        mav = self.link.mav
        t0 = time.monotonic()
        hb_next = 0.0
        while not self.stop_flag.is_set():
            target = t0 + self.k * 0.005
            d = target - time.monotonic()
            if d > 0:
                time.sleep(d)
            now = time.monotonic()
            if self._arm_at is not None and now >= self._arm_at:
                self.armed, self._arm_at = True, None
            for msg, rx in self.link.drain():
                self.bridge_seen.set()
                if msg.get_type() == "SET_ATTITUDE_TARGET":
                    self.setpoints.append((rx, msg))
                    self.first_setpoint.set()
                elif msg.get_type() == "COMMAND_LONG":
                    self.commands.append(msg.command)
                    self.link.send(mav.command_ack_encode(msg.command, self._answer(msg)))
                elif msg.get_type() == "PARAM_REQUEST_READ":
                    self._answer_param(mav, msg)
            if self.heartbeat and now >= hb_next:
                hb_next = now + 0.5
                t_hb = time.monotonic()  # before the send: an answer to it can only be received after this
                self.link.send_heartbeat(mavlink.MAV_TYPE_QUADROTOR, 12,
                                         MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
                                         | (MAV_MODE_FLAG_SAFETY_ARMED if self.armed else 0),
                                         px4_custom_mode(6), mavlink.MAV_STATE_ACTIVE)
                if self.armed and self.armed_hb_at is None:
                    self.armed_hb_at = t_hb
            if self.telemetry:
                self._send_telemetry(mav, q_level)
            for f in list(self.extra):
                f(self)
            self.k += 1

    def _answer(self, msg) -> int:
        """MAV_RESULT for a command: ARM is refused ``arm_refusals`` times, everything else accepted."""
        from firmware_bridge.link import mavlink

        if msg.command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM and msg.param1 == 1.0:
            if self.arm_refusals != 0:
                self.arm_refusals -= 1 if self.arm_refusals > 0 else 0
                return mavlink.MAV_RESULT_TEMPORARILY_REJECTED
            if self.arm_delay > 0:
                self._arm_at = self._arm_at or time.monotonic() + self.arm_delay
            else:
                self.armed = True
        return mavlink.MAV_RESULT_ACCEPTED

    def _answer_param(self, mav, msg) -> None:
        """PARAM_VALUE for a known name (REAL32, as PX4 sends these two); an unknown one goes unanswered."""
        from firmware_bridge.link import mavlink

        name = msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode(errors="ignore")
        name = name.rstrip("\x00")
        if name in self.params:
            names = list(self.params)
            self.link.send(mav.param_value_encode(name.encode(), self.params[name], mavlink.MAV_PARAM_TYPE_REAL32,
                                                  len(names), names.index(name)))

    def _send_telemetry(self, mav, q_level) -> None:
        """This 5 ms tick's samples per ``pattern`` (stamps in ms of vehicle time)."""
        def att(ms):
            return mav.attitude_quaternion_encode(ms, *q_level, 0.0, 0.0, 0.0, (0, 0, 0, 0))

        def pos(ms):
            return mav.local_position_ned_encode(ms, 0.0, 0.0, -self.z, 0.0, 0.0, 0.0)

        k = self.k
        if self.pattern == "regular":
            msgs = [att(k * 5), pos(k * 5)]
        elif self.pattern == "burst":
            msgs = [] if k % 2 == 0 else [att((k - 1) * 5), pos((k - 1) * 5), att(k * 5), pos(k * 5)]
        else:  # px4: within [5k, 5k+5) ms, attitude at 4/8/12 ms steps, position every 8 ms
            att_ms = [m for m in range(k * 5, k * 5 + 5) if m % 24 in (0, 4, 12)]
            msgs = [att(m) for m in att_ms] + [pos(m) for m in range(k * 5, k * 5 + 5) if m % 8 == 0]
        for m in msgs:
            self.sent["attitude" if m.get_type() == "ATTITUDE_QUATERNION" else "position"] += 1
        if msgs:
            self.link.send_many(msgs)

    def setpoint_times(self) -> np.ndarray:
        return np.array([t for t, _ in self.setpoints])

    def close(self) -> None:
        self.stop_flag.set()
        self.join(5)
        self.link.close()


# ----------------------------------------------------------------------------- fixtures
@pytest.fixture
def procs(tmp_path):
    pr = Procs(tmp_path)
    try:
        yield pr
    finally:
        pr.cleanup()


@pytest.fixture(scope="session")
def flying_solver(tmp_path_factory) -> Path:
    """A steering solver for the flying loop: 30 s of PRBS-excited in-process data, lsq predictor,
    configs/flying.toml otherwise, DAQP backend (~3-5 s; built once per test run, shared by every
    xdist worker and both phases of ``make test`` through :mod:`solver_cache`)."""
    from support.solver_cache import cache_root, shared_build

    toml = ROOT / "configs" / "flying.toml"
    recipe = {"what": "bridge flying solver", "sim": ["flying", 30.0, True, 11, True], "predictor": "lsq",
              "backend": "daqp", "name": "bridge_test_flying", "config": toml.read_text()}
    return shared_build(cache_root(tmp_path_factory.getbasetemp()), recipe, _build_flying_solver) / "flying"


def _build_flying_solver(folder: Path) -> None:
    from ddpc_codegen import SteeringConfig, SteeringProblem, fit_predictor, generate
    from ddpc_codegen.sim import simulate

    ds = simulate("flying", 30.0, excitation=True, seed=11, noise=True).to_dataset()
    cfg = SteeringConfig.from_toml(ROOT / "configs" / "flying.toml").replace(predictor={"method": "lsq"})
    pred = fit_predictor(ds, cfg.t_ini, cfg.t_f, method="lsq")
    generate(SteeringProblem(pred, cfg), folder / "flying", backend="daqp", name="bridge_test_flying")


@pytest.fixture
def fake_vehicle_factory():
    made: list[FakeVehicle] = []

    def make(port: int, **kw) -> FakeVehicle:
        v = FakeVehicle(port, **kw)
        made.append(v)
        return v

    try:
        yield make
    finally:
        for v in made:
            v.close()
