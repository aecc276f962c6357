"""The simulated vehicle's parts in-process: telemetry sample patterns, the publisher, and the
physics through the shared sim Stepper (pushes, a stuck hybrid integration)."""

from __future__ import annotations

import numpy as np
import pytest
from support.bridge_helpers import free_port

from ddpc_codegen.robot.controller import MeasuredState
from ddpc_codegen.sim import plant as plant_mod
from firmware_bridge.link import mavlink
from ddpc_codegen.testbed.vehicle import SimVehicle, VehicleConfig
from ddpc_codegen.testbed.vehicle_telemetry import SamplePattern, TelemetryPublisher


def _stamps(kind: str, seconds: float = 20.0, seed: int = 0) -> list[list[int]]:
    pat = SamplePattern(kind, seed)
    return [pat.samples(5 * k) for k in range(int(seconds * 200))]


def test_px4_sih_pattern_steps_4_to_16_ms_at_about_118_samples_per_second():
    per_tick = _stamps("px4-sih")
    flat = [s for tick in per_tick for s in tick]
    assert all(len(t) <= 2 for t in per_tick) and sum(not t for t in per_tick) > len(per_tick) / 3
    steps = np.diff(flat)
    assert set(steps) == {4, 8, 12, 16}
    assert 110 < len(flat) / 20.0 < 126
    assert all(s % 4 == 0 for s in flat)  # whole ms, on the 4 ms grid
    assert all(s <= 5 * k for k, tick in enumerate(per_tick) for s in tick)  # never from the future


def test_ardupilot_pattern_misses_every_sixth_or_so_and_bursts():
    per_tick = _stamps("ardupilot")
    flat = [s for tick in per_tick for s in tick]
    assert 160 < len(flat) / 20.0 < 180
    assert len(set(flat)) == len(flat) and flat == sorted(flat)
    bursts = [t for t in per_tick if len(t) == 2]
    assert bursts and all(b[1] > b[0] for b in bursts)  # a held sample goes out with the next one


def test_regular_pattern_and_bad_names():
    assert _stamps("regular", 0.02) == [[0], [5], [10], [15]]
    with pytest.raises(ValueError, match="px4-sih"):
        SamplePattern("px5")
    with pytest.raises(ValueError, match="telemetry_pattern"):
        VehicleConfig(telemetry_pattern="px5")


class _Link:
    def __init__(self) -> None:
        self.mav = mavlink.MAVLink(None, 1, 1)
        self.sent: list[list] = []

    def send_many(self, msgs) -> bool:
        self.sent.append(list(msgs))
        return True


def _state() -> MeasuredState:
    return MeasuredState(0.0, np.array([1.0, 2.0, 3.0]), np.zeros(3), np.array([0.1, -0.2, 0.3]), np.zeros(3))


def test_publisher_sends_each_new_sample_once_with_its_stamp_and_age():
    link = _Link()
    pub = TelemetryPublisher(link, {"ATTITUDE": 200.0, "LOCAL_POSITION_NED": 200.0}, SamplePattern("px4-sih", 1))
    ages: list[float] = []

    def measure(age: float) -> MeasuredState:
        ages.append(age)
        return _state()

    sent = [pub.publish(0.005 * k, measure) for k in range(400)]
    stamps = [s for tick in sent for s in tick]
    msgs = [m for batch in link.sent for m in batch]
    assert len(msgs) == 2 * len(stamps)  # both streams, once per new sample
    assert [m.time_boot_ms for m in msgs if m.get_type() == "ATTITUDE"] == stamps
    assert all(0.0 <= a < 0.016 for a in ages)
    pos = next(m for m in msgs if m.get_type() == "LOCAL_POSITION_NED")
    assert (pos.x, pos.y, pos.z) == pytest.approx((2.0, 1.0, -3.0))  # ENU -> NED
    assert not pub.set_interval(0, 5000, 0.0)  # HEARTBEAT is not a stream


def _vehicle(**kw) -> SimVehicle:
    return SimVehicle(VehicleConfig(url=f"udpout:127.0.0.1:{free_port()}", **kw))


def _fly(veh: SimVehicle, ticks: int) -> None:
    for _ in range(ticks):
        veh._tick_start(0.0)
        veh._advance()
        veh.k += 1


def test_vehicle_pushes_reach_the_plant():
    calm, pushed = _vehicle(noise=False), _vehicle(noise=False, pushes=[(0.1, (15.0, 0.0, 0.0), 0.2)])
    _fly(calm, 100)
    _fly(pushed, 100)
    assert pushed.plant.state[0] - calm.plant.state[0] > 0.02  # pushed east, HOLD pulls it back later


def test_vehicle_survives_a_stuck_hybrid_integration(monkeypatch):
    veh = _vehicle(noise=False)

    def stuck(*_a, **_k):
        raise plant_mod.HybridEventError("too many hybrid events (test)")

    monkeypatch.setattr(veh.plant, "step", stuck)
    _fly(veh, 3)  # no exception: the physics freezes, the autopilot goes on
    assert veh.stepper.stuck and any("physics stopped" in e for _, e in veh.events)
    assert veh.summary()["ticks"] == 3


def test_contact_flag_goes_with_each_sample_and_is_read_back():
    from firmware_bridge.telemetry import TelemetryState

    link = _Link()
    pub = TelemetryPublisher(link, {"ATTITUDE": 200.0, "LOCAL_POSITION_NED": 200.0}, SamplePattern("regular"), "CONTACT")
    tel = TelemetryState("ATTITUDE", "LOCAL_POSITION_NED", contact_name="CONTACT")
    flags = [k % 3 == 0 for k in range(12)]
    for k, f in enumerate(flags):
        st = MeasuredState(0.0, np.array([0.0, 0.0, 0.5]), np.zeros(3), np.zeros(3), np.zeros(3), contact=f)
        pub.publish(0.005 * k, lambda age, st=st: st)
        batch = link.sent[-1]
        assert batch[0].get_type() == "NAMED_VALUE_INT" and batch[0].time_boot_ms == 5 * k  # ahead of the state
        assert [tel.update(m, 0.0) for m in batch] == [False, True, True]  # the flag is no state stream
        assert tel.contact is f and tel.contact_stamp == pytest.approx(0.005 * k)
    other = link.mav.named_value_int_encode(0, b"OTHER", 1)
    tel.update(other, 0.0)
    assert tel.contact is flags[-1]  # another name is ignored


def test_hopping_vehicle_logs_true_contact_events_in_vehicle_time(tmp_path):
    from ddpc_codegen.testbed.vehicle import MODE_LAND

    veh = _vehicle(noise=False, scenario="hopping", truth_log=str(tmp_path / "truth.npz"))
    assert veh.plant.state[2] == pytest.approx(0.7)  # the release height
    _fly(veh, 20)
    veh.autopilot.set_mode(MODE_LAND)
    _fly(veh, 300)  # 0.3 m of leg clearance at 0.5 m/s
    td = veh.contact_events["touchdown"]
    assert len(td) >= 1 and td == pytest.approx(veh.stepper.touchdowns)  # armed from the start: plant = vehicle time
    veh._write_truth()
    with np.load(tmp_path / "truth.npz") as z:
        assert z["touchdowns"].tolist() == td and z["liftoffs"].tolist() == veh.contact_events["liftoff"]
    with pytest.raises(ValueError, match="scenario must be"):
        VehicleConfig(scenario="swimming")
