"""The proxy soak (:mod:`ddpc_codegen.testbed.proxy_soak`): ``ddpc-vehicle --setpoint-log`` keeps every setpoint it
receives and answers a full parameter list; a short session through ``ddpc-proxy`` with a ground station, without
and with a 2 kHz foreign flood, loses, duplicates, reorders and changes none of the app's setpoints, and the vehicle
gets the same setpoints from the app in both."""

from __future__ import annotations

import time

import numpy as np
import pytest

from ddpc_codegen.testbed.proxy_soak import run_session, same_setpoints
from ddpc_codegen.testbed.sitl import run_isolated
from ddpc_codegen.testbed.vehicle_autopilot import SETPOINT_LOG_FIELDS
from firmware_bridge.link import MavLink

from support.bridge_helpers import free_port, procs  # noqa: F401 (fixture)

pytestmark = [pytest.mark.e2e]


def test_the_vehicle_logs_every_setpoint_and_lists_its_parameters(procs, tmp_path):  # noqa: F811
    port = free_port()
    link = MavLink(f"udpin:127.0.0.1:{port}", source_system=245, source_component=191, target_system=None)
    veh = procs.spawn("vehicle", f"udpout:127.0.0.1:{port}", "--setpoint-log", str(tmp_path / "sp.npz"), name="vehicle")
    try:
        end, heard = time.monotonic() + 20, False
        while not heard and time.monotonic() < end:  # the vehicle is up (its heartbeat pins our reply address)
            heard = any(m.get_type() == "HEARTBEAT" for m, _ in link.drain())
            time.sleep(0.05)
        assert heard, procs.log(veh)
        mav = link.mav
        for k in range(20):  # the vehicle's own (a foreign target is logged too: before any check)
            link.send(mav.set_position_target_local_ned_encode(20 * k, 1 if k % 5 else 99, 1, 1, 0b0000_1111_1111_1000,
                                                               0.1 * k, 0.2, -1.0, 0, 0, 0, 0, 0, 0, 0, 0))
        link.send(mav.param_request_list_encode(1, 1))
        params, end = {}, time.monotonic() + 5
        while len(params) < 2 and time.monotonic() < end:
            for m, _ in link.drain():
                if m.get_type() == "PARAM_VALUE":
                    params[m.param_index] = (m.param_id, m.param_count)
            time.sleep(0.02)
    finally:
        procs.terminate(veh)
        link.close()
    assert sorted(params) == [0, 1] and {c for _, c in params.values()} == {2}
    log = np.load(tmp_path / "sp.npz")
    assert set(log.files) == set(SETPOINT_LOG_FIELDS)
    assert list(log["time_boot_ms"]) == [20 * k for k in range(20)]
    assert list(log["target_system"]) == [1 if k % 5 else 99 for k in range(20)]
    assert np.allclose(log["x"], np.float32(0.1 * np.arange(20))) and set(log["sysid"]) == {245}
    assert list(log["seq"]) == list(range(20)) and np.all(np.diff(log["rx"]) >= 0)


@pytest.mark.slow  # two 18 s sessions (not yet in tests/durations.json)
@pytest.mark.realtime  # wall-clock sessions; the figures are this machine's
def test_a_short_soak_loses_nothing_with_and_without_a_flood(tmp_path):
    runs = {}
    for name, hz in (("baseline", 0.0), ("flood", 2000.0)):
        kw = {"out_dir": str(tmp_path), "name": name, "minutes": 0.3, "flood_hz": hz, "param_period": 5.0}
        runs[name] = run_isolated(f"{run_session.__module__}:run_session", kw, timeout=60)
    for name, s in runs.items():
        sp, up, g = s["setpoints"], s["proxy"]["app_to_vehicle"], s["gcs"]
        assert sp["sent"] == sp["received"] == 900, (name, sp)
        assert sp["lost"] == sp["duplicated"] == sp["reordered"] == sp["fields_changed"] == sp["seq_changed"] == 0
        # every frame the proxy forwarded reached the vehicle's parser (those before the vehicle was heard: dropped)
        assert up["forwarded"] == s["vehicle"]["rx"] and up["dropped"] <= 4 and up["send_errors"] == 0, (name, up)
        assert up["seq_gaps"] == 0 and s["proxy"]["vehicle_to_app"]["seq_gaps"] == 0
        assert s["app"]["lost_by_seq"] == 0 and g["lost_by_seq"] == 0, (name, s["app"], g)
        assert g["param_lists"] >= 3 and g["param_lists_complete"] == g["param_lists"], g
        assert g["interval_acks"] == g["interval_requests"] and g["mode_acks"] == g["mode_requests"], g
        assert sp["send_to_vehicle_ms"]["p50"] < 5.0
    fl = runs["flood"]
    assert fl["flood"]["datagrams"] > 2000 * 10 and fl["proxy"]["foreign_setpoints"] > 0
    assert fl["proxy"]["app_to_vehicle"]["garbage_bytes"] == fl["flood"]["garbage_bytes"]
    assert fl["setpoints"]["foreign_setpoints_at_vehicle"] == fl["proxy"]["foreign_setpoints"]  # forwarded, ignored
    cmp_ = same_setpoints(runs["baseline"]["setpoint_log"], fl["setpoint_log"])
    assert cmp_ == {"compared": 900, "counts": [900, 900], "differing": 0}
