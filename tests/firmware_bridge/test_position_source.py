"""The motion-capture position source: the poses as the bridge decodes them (NED -> ENU, stamps, latency, what is
dropped), the source's frames and freshness, its flags, and a bridge on a fake vehicle and a fake mocap stream
(collect steers on the mocap's height, stale poses make stale ticks, no pose means no engagement)."""

from __future__ import annotations

import math
import socket
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink
from support.bridge_helpers import FakeVehicle, Procs, free_port, read_json

from ddpc_codegen import IODataset
from ddpc_codegen.robot.frames import quat_from_euler
from ddpc_codegen.robot.state import MeasuredState
from firmware_bridge.bridge_config import BridgeConfig
from firmware_bridge.cli import bridge_config_from_args, build_bridge_parser
from firmware_bridge.events import EventLog
from firmware_bridge.link import MavLink
from firmware_bridge.mocap_input import MocapInput, decode_pose
from firmware_bridge.position_source import PositionSource
from firmware_bridge.telemetry import TrajectoryFrame
from firmware_bridge.ticklog import REASONS, load_ticklog

R = {r: i for i, r in enumerate(REASONS)}
_MAV = mavlink.MAVLink(None, srcSystem=1, srcComponent=197)


def _wire(msg):
    """``msg`` packed and parsed back, as it arrives."""
    return mavlink.MAVLink(None).parse_char(bytearray(msg.pack(_MAV)))


def vpe(t: float, north: float, east: float, down: float, yaw_ned: float = 0.0):
    return _wire(mavlink.MAVLink_vision_position_estimate_message(int(round(t * 1e6)), north, east, down, 0.0, 0.0,
                                                                  yaw_ned))


class _Link:
    """A link whose pending messages the test sets."""

    url = "udpin:127.0.0.1:0"

    def __init__(self) -> None:
        self.pending: list = []
        self.closed = False

    def drain(self) -> list:
        out, self.pending = self.pending, []
        return out

    def close(self) -> None:
        self.closed = True


# ----------------------------------------------------------------------------- decoding
def test_each_pose_message_becomes_local_enu_with_its_yaw():
    s, p, yaw = decode_pose(vpe(1.5, 2.0, -1.0, -0.8, yaw_ned=math.radians(30)))
    assert s == pytest.approx(1.5) and p == pytest.approx((-1.0, 2.0, 0.8)) and yaw == pytest.approx(math.radians(60))
    q = [float(v) for v in quat_from_euler(0.0, 0.0, math.radians(30))]  # FRD -> NED, yaw 30 deg east of north
    m = _wire(mavlink.MAVLink_att_pos_mocap_message(2_000_000, q, 2.0, -1.0, -0.8))
    s, p, yaw = decode_pose(m)
    assert s == pytest.approx(2.0) and p == pytest.approx((-1.0, 2.0, 0.8)) and yaw == pytest.approx(math.radians(60))
    nan = float("nan")
    for frame, ok in ((1, True), (20, True), (8, False)):  # LOCAL_NED, LOCAL_FRD (north-aligned); BODY_NED is not
        m = _wire(mavlink.MAVLink_odometry_message(3_000_000, frame, 12, 2.0, -1.0, -0.8, q, 0, 0, 0, nan, nan, nan,
                                                   [nan] * 21, [nan] * 21, 0, 6, 100))
        out = decode_pose(m)
        assert (out[1] == pytest.approx((-1.0, 2.0, 0.8))) if ok else out == "frame"
    assert decode_pose(vpe(1.0, nan, 0.0, 0.0)) == "nonfinite"
    assert decode_pose(_wire(mavlink.MAVLink_att_pos_mocap_message(1, [0.0, 0.0, 0.0, 0.0], 0, 0, 0))) == "nonfinite"


def test_the_input_measures_latency_on_this_clock_and_drops_what_it_cannot_use():
    link = _Link()
    m = MocapInput(link)
    assert not m.present and m.age(5.0) == math.inf
    link.pending = [(vpe(10.000, 0.0, 0.0, -1.0), 10.004), (_wire(_MAV.heartbeat_encode(18, 8, 0, 0, 0)), 10.004)]
    assert m.pump() == 1
    assert m.position == pytest.approx((0.0, 0.0, 1.0)) and m.latency == pytest.approx(0.004)
    assert m.age(10.010) == pytest.approx(0.006)
    # reordered (older stamp), a jump no vehicle flies in 5 ms, non-finite: dropped by reason, the last pose kept
    link.pending = [(vpe(9.990, 0.0, 0.0, -1.0), 10.009), (vpe(10.010, 0.0, 0.0, -9.0), 10.014),
                    (vpe(10.015, float("nan"), 0.0, -1.0), 10.019)]
    assert m.pump() == 0
    assert dict(m.rejected) == {"stamp": 1, "position_jump": 1, "nonfinite": 1} and m.dropped == 3
    assert m.position[2] == pytest.approx(1.0) and m.seq == 1
    # a stamp on another clock (a mocap server's): accepted, its latency unknown
    link.pending = [(vpe(500.0, 0.0, 0.0, -1.01), 10.024)]
    assert m.pump() == 1 and math.isnan(m.latency) and m.foreign_stamps == 1
    assert m.latencies() == pytest.approx([0.004])
    m.close()
    assert link.closed


# ----------------------------------------------------------------------------- the source
def _state(position, yaw: float = 0.0) -> MeasuredState:
    return MeasuredState(t=0.0, position=np.array(position, float), velocity=np.zeros(3),
                         euler=np.array([0.0, 0.0, yaw]), body_rates=np.zeros(3), contact=False)


def _source(kind: str = "mocap", mode: str = "start"):
    link = _Link()
    ev = EventLog()
    src = PositionSource(kind, TrajectoryFrame(mode, anchor=(1.0, 0.0)), ev, 0.05, MocapInput(link))
    return src, link, ev


def test_the_mocap_frame_is_captured_like_the_estimates_and_replaces_its_position():
    src, link, ev = _source()
    ekf = TrajectoryFrame("start", anchor=(1.0, 0.0))
    assert not src.captured and src.age(1.0, 0.002) == math.inf  # no pose: stale, said once
    assert any("no pose yet" in e for _, e in ev.events)
    # the lab's frame: the vehicle at east 3, north 4, 0.1 m up, heading north (yaw ENU 90 deg = 0 NED)
    link.pending = [(vpe(1.000, 4.0, 3.0, -0.1, yaw_ned=0.0), 1.003)]
    src.pump()
    assert src.age(1.005, 0.001) == pytest.approx(0.002) and src.fresh  # the older of the two
    assert any("mocap first pose" in e and "latency 3.0 ms" in e for _, e in ev.events)
    # the EKF's frame: elsewhere, another heading (its own origin and yaw); both captured disarmed
    ekf.capture(np.array([-2.0, 0.5, 0.3]), math.radians(80))
    ekf.z0 = 0.3
    src.capture(armed=False)
    assert src.captured and src.frame.z0 == pytest.approx(0.1)
    # 1 m north (the lab's), 0.5 m up: 1 m along the heading from the anchor, 0.5 m up in the trajectory frame
    link.pending = [(vpe(1.010, 5.0, 3.0, -0.6), 1.013)]
    src.pump()
    src.age(1.015, 0.002)
    st = src.measure(ekf.to_trajectory(_state([-2.0, 1.5, 0.78], yaw=math.radians(80))))
    np.testing.assert_allclose(st.position, [2.0, 0.0, 0.5], atol=1e-6)  # float32 on the wire
    assert src.estimate[2] == pytest.approx(0.48) and src.offset[2] == pytest.approx(0.02, abs=1e-6)
    cols = src.columns(1.015)
    np.testing.assert_allclose(cols["mocap_position"], [3.0, 5.0, 0.5], atol=1e-6)
    assert cols["mocap_age_ms"] == pytest.approx(2.0) and cols["mocap_latency_ms"] == pytest.approx(3.0)


def test_a_stale_pose_is_never_the_measurement_and_each_change_is_said():
    src, link, ev = _source()
    link.pending = [(vpe(1.000, 0.0, 0.0, -1.0), 1.001)]
    src.pump()
    src.age(1.002, 0.001)
    src.capture(armed=True)
    est = _state([0.0, 0.0, 0.95])
    assert src.measure(est).position[2] == pytest.approx(1.0)
    # 80 ms without a pose: the tick is as old as the pose; its position the estimate + the last offset
    assert src.age(1.081, 0.001) == pytest.approx(0.080) and not src.fresh
    st = src.measure(_state([0.0, 0.0, 0.90]))
    assert st.position[2] == pytest.approx(0.95)
    cols = src.columns(1.081)
    assert "mocap_position" not in cols and cols["estimate_position"][2] == pytest.approx(0.90)
    assert any(e.startswith("mocap stale: no pose for 80.0 ms") for _, e in ev.events)
    link.pending = [(vpe(1.100, 0.0, 0.0, -1.02), 1.101)]
    src.pump()
    assert src.age(1.102, 0.001) == pytest.approx(0.001) and src.fresh
    assert any(e.startswith("mocap fresh again after 0.021 s") for _, e in ev.events)
    s = src.summary()
    assert s["kind"] == "mocap" and s["poses"] == 2 and s["stale_events"] == 1 and s["stale_ticks"] == 1
    assert s["latency_ms"]["n"] == 2


def test_with_the_autopilot_as_source_the_poses_are_only_logged():
    src, link, ev = _source("autopilot")
    link.pending = [(vpe(1.000, 0.0, 0.0, -1.0), 1.001)]
    src.pump()
    assert src.age(1.002, 0.004) == 0.004 and src.captured  # the telemetry's age; engages without a pose
    src.capture(armed=True)
    st = src.measure(_state([0.0, 0.0, 0.9]))
    assert st.position[2] == pytest.approx(0.9) and src.columns(1.002)["mocap_position"][2] == pytest.approx(1.0)
    assert src.age(1.2, 0.004) == 0.004 and any("logged only" in e for _, e in ev.events)
    with pytest.raises(ValueError, match="needs the mocap stream"):
        PositionSource("mocap", TrajectoryFrame(), EventLog(), 0.05)
    assert PositionSource("autopilot", TrajectoryFrame(), EventLog(), 0.05).columns(0.0).keys() == {"estimate_position"}


# ----------------------------------------------------------------------------- flags
def test_the_flags_map_to_the_config_and_refuse_what_cannot_work():
    a = build_bridge_parser().parse_args(["udpin:127.0.0.1:14540", "--mode", "passthrough", "--position-source", "mocap",
                                          "--mocap", "udpin:127.0.0.1:14600"])
    c = bridge_config_from_args(a)
    assert c.position_source == "mocap" and c.mocap == "udpin:127.0.0.1:14600"
    assert BridgeConfig(mode="passthrough").position_source == "autopilot"
    for kw, msg in (({"position_source": "mocap"}, "needs the link the poses arrive on"),
                    ({"position_source": "gps"}, "must be one of autopilot, mocap"),
                    ({"mocap": "udpin:127.0.0.1"}, "--mocap: 'udpin:127.0.0.1': expected udpin:HOST:PORT"),
                    ({"mocap": "udpin:127.0.0.1:14540"}, "the vehicle's link"),
                    ({"position_source": "mocap", "mocap": "udpin:127.0.0.1:14600", "lockstep": True}, "--lockstep")):
        with pytest.raises(ValueError, match=msg):
            BridgeConfig(mode="passthrough", **kw)


# ----------------------------------------------------------------------------- a bridge on a fake mocap stream
class FakeMocap(threading.Thread):
    """Sends VISION_POSITION_ESTIMATE at 100 Hz (``up`` [m], stamped on this host's monotonic clock) to ``port``,
    nothing while ``paused`` is set."""

    def __init__(self, port: int, up: float) -> None:
        super().__init__(daemon=True)
        self.link = MavLink(f"udpout:127.0.0.1:{port}", source_system=1, source_component=197, target_system=None)
        self.up, self.paused, self.stop_flag, self.sent = up, threading.Event(), threading.Event(), 0

    def run(self) -> None:
        while not self.stop_flag.wait(0.01):
            if not self.paused.is_set():
                t = time.monotonic()
                self.link.send(self.link.mav.vision_position_estimate_encode(int(t * 1e6), 0.0, 0.0, -self.up, 0, 0, 0))
                self.sent += 1

    def close(self) -> None:
        self.stop_flag.set()
        self.join(5)
        self.link.close()


def _bridge(tmp_path, *args: str, mocap: FakeMocap | None = None, pause: tuple[float, float] | None = None):
    """One bridge (collect, the fake vehicle hovering at 0.9 m on its estimate) with ``args``; (exit code, output)."""
    port = free_port()
    veh = FakeVehicle(port, z=0.9)
    pr = Procs(tmp_path)
    try:
        veh.start()
        if mocap is not None:
            mocap.start()
        br = pr.spawn("bridge", f"udpin:127.0.0.1:{port}", "--mode", "collect", "--log", str(tmp_path / "t.npz"),
                      "--summary", str(tmp_path / "s.json"), "--verbose", *args, name="bridge")
        if pause is not None:  # seconds after the first setpoint (the ticks begin after the preflight)
            wait_s, pause_s = pause
            assert veh.first_setpoint.wait(30), pr.log(br)
            time.sleep(wait_s)
            mocap.paused.set()
            time.sleep(pause_s)
            mocap.paused.clear()
        return pr.wait(br, 60), pr.log(br)
    finally:
        veh.close()
        if mocap is not None:
            mocap.close()
        pr.cleanup()


@pytest.mark.e2e
def test_collect_on_the_mocap_records_its_height_and_a_gap_in_it_is_stale(tmp_path):
    mport = free_port()
    mocap = FakeMocap(mport, up=1.0)
    rc, out = _bridge(tmp_path, "--position-source", "mocap", "--mocap", f"udpin:127.0.0.1:{mport}", "--duration", "3",
                      "--timeout", "30", "--dataset-skip", "0", mocap=mocap, pause=(1.5, 0.3))
    assert rc == 0, out
    log = load_ticklog(tmp_path / "t.npz")
    t = log.ticks
    valid = t["valid"].astype(bool)
    # the measured height is the mocap's (1.0 m), not the estimate's (0.9 m): the data the fit gets
    np.testing.assert_allclose(t["y"][valid, 0], 1.0, atol=1e-6)
    np.testing.assert_allclose(t["estimate_position"][valid, 2], 0.9, atol=1e-6)
    np.testing.assert_allclose(t["mocap_position"][valid, 2], 1.0, atol=1e-6)
    assert np.all(t["mocap_age_ms"][valid] <= 50.0) and np.nanmedian(t["mocap_latency_ms"][valid]) < 5.0
    ds = IODataset.load(tmp_path / "t.npz")
    np.testing.assert_allclose(np.concatenate(ds.y)[:, 0], 1.0, atol=1e-6)
    # the pause: stale ticks (not data, no pose logged), the estimate shifted to the mocap's height, said twice
    stale = t["reason"] == R["stale"]
    # (a tick stale with a pose logged is stale on the autopilot's own telemetry, a sample late under load)
    assert (stale & np.isnan(t["mocap_position"][:, 2])).sum() >= 30
    np.testing.assert_allclose(t["y"][stale, 0], 1.0, atol=1e-6)
    assert len(ds.y) >= 2  # the gap split the dataset
    s = read_json(tmp_path / "s.json")
    events = [e for _, e in s["events"]]
    assert any(e.startswith("mocap stale: no pose for") for e in events)
    assert any(e.startswith("mocap fresh again after") for e in events)
    ps = s["position_source"]
    assert ps["kind"] == "mocap" and ps["poses"] > 250 and ps["stale_events"] == 1
    assert log.samples["mocap"].shape == (ps["poses"], 2) and log.metadata["position_source"]["kind"] == "mocap"
    cols = log.metadata["columns"]  # each frame said: the measured state in the start frame, the mocap in its own
    assert "the bridge's start frame" in cols["position"] and "motion capture's own frame" in cols["mocap_position"]


@pytest.mark.e2e
def test_without_a_pose_the_bridge_never_engages_and_says_why(tmp_path):
    rc, out = _bridge(tmp_path, "--position-source", "mocap", "--mocap", f"udpin:127.0.0.1:{free_port()}",
                      "--duration", "1", "--timeout", "3")
    assert rc != 0, out
    t = load_ticklog(tmp_path / "t.npz").ticks
    assert not t["active"].any() and not np.isfinite(t["t_traj"]).any()
    events = [e for _, e in read_json(tmp_path / "s.json")["events"]]
    assert any("position source mocap: no pose yet on udpin:127.0.0.1:" in e for e in events)


def test_a_mocap_port_that_cannot_be_bound_is_one_line_naming_the_flag(tmp_path):
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
        r = subprocess.run([sys.executable, "-m", "firmware_bridge.cli", "bridge", f"udpin:127.0.0.1:{free_port()}",
                            "--mode", "passthrough", "--position-source", "mocap", "--mocap", f"udpin:127.0.0.1:{port}"],
                           capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert r.returncode == 2 and r.stderr.strip().splitlines()[-1].startswith(
        f"ddpc-bridge: error: --mocap udpin:127.0.0.1:{port}: "), r.stderr
