"""The steering of an app's SET_POSITION_TARGET_GLOBAL_INT (:mod:`firmware_bridge.proxy.setpoint_frames`): its
altitude above home or sea level is steered in the local frame by the offset the vehicle's own reports give, the
same as a local app on the same loop; everything but ``alt`` leaves byte for byte as the app sent it; a frame or a
``type_mask`` the proxy does not steer, or an offset it does not know, sends the app's own setpoint."""

from __future__ import annotations

import json
import math
import time

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink

from ddpc_codegen.runtime.loader import load_solver
from firmware_bridge.mocap_input import MocapInput
from firmware_bridge.proxy import PROXY_COMPONENT, SetpointEncoder
from firmware_bridge.proxy.frames import header
from firmware_bridge.proxy.preview import DelayedPreview
from firmware_bridge.proxy.record import ProxyRecord
from firmware_bridge.proxy.rewrite import decode_frame
from firmware_bridge.proxy.setpoint_frames import FrameOffsets
from firmware_bridge.proxy.steering import ProxySteering
from firmware_bridge.proxy.vehicle_view import VehicleView
from lti_loop import DT, LAT, LON, POS_ONLY, LoopSim, PoseLink, fly
from proxy_support import Peer, RunningProxy, frames, free_port, mav
import test_proxy_steering
from test_proxy_steering import _drift, _hook, _path, _rmse, _slow_path

solver, deviation_solver = test_proxy_steering.solver, test_proxy_steering.deviation_solver  # the same built solvers

_ALT = slice(12, 16)  # SET_POSITION_TARGET_GLOBAL_INT's payload: time, lat, lon, then alt (float)
_FULL = 53  # its payload's length untruncated


def _payload(frame: bytes) -> bytes:
    """The frame's payload (MAVLink 2), its trailing zeros restored."""
    return frame[10:10 + frame[1]].ljust(_FULL, b"\0")


def _global(sim: LoopSim, alt: float, frame: int, mask: int = POS_ONLY):
    m = sim.app.set_position_target_global_int_encode(7, 1, 1, frame, mask, LAT, LON, alt, 0.1, -0.2, 0.0, 0.0, 0.0,
                                                      0.0, 1.25, 0.0)
    f = bytes(m.pack(sim.app))
    return decode_frame(f), f


@pytest.mark.compiler
@pytest.mark.parametrize("frame", ["relative_alt", "amsl"])
def test_a_global_app_is_steered_as_the_same_local_app(solver, frame):
    """The same path, the same loop: the heights the vehicle is sent (in its local frame) and the height flown."""
    path = _slow_path(2000)
    local = _hook(solver=load_solver(solver))
    out_l = fly(local, path)
    glob = _hook(solver=load_solver(solver))
    out_g = fly(glob, path, frame=frame)
    gap = np.abs(out_g["sent"] - out_l["sent"])[100:]
    e_l, e_g = _rmse(out_l["h"], path), _rmse(out_g["h"], path)
    print(json.dumps({"frame": frame, "max_sent_gap_mm": float(gap.max() * 1e3), "rmse_mm": [e_l * 1e3, e_g * 1e3]}))
    # (a steered alt above sea level within float32's resolution of the app's is the app's frame: not rewritten)
    assert glob.frames[frame] == 2000 and glob.counts["steered"] > 1900 and out_g["rewritten"][100:].mean() > 0.99
    assert gap.max() < 1e-3 and e_g == pytest.approx(e_l, rel=0.02)
    assert glob.summary()["frame_offsets"][f"{frame}_m"] == pytest.approx(LoopSim().frame_offset(frame), abs=1e-3)


@pytest.mark.compiler
def test_a_global_app_on_a_motion_capture_takes_out_the_estimators_drift(deviation_solver):
    """The pose's offset is the local frame's (measured disarmed); the global setpoint goes into the local frame by
    the estimator's own offset, which the drift does not touch: as steered as a local app on the same lab."""
    path = _slow_path(3000)
    path[:200] = path[200]
    vz = np.gradient(path, DT)
    errs = {}
    for frame in ("local", "relative_alt"):
        hook = ProxySteering(VehicleView(mocap=MocapInput(PoseLink())), record=ProxyRecord(),
                             solver=load_solver(deviation_solver))
        sim = LoopSim(h0=float(path[0]), drift=_drift, arm_at=200)
        errs[frame] = _rmse(fly(hook, path, sim, vz=vz, frame=frame)["h"], path, skip=600)
    print(json.dumps({k: v * 1e3 for k, v in errs.items()}))
    assert errs["relative_alt"] == pytest.approx(errs["local"], rel=0.05, abs=5e-4)


def test_only_alt_changes_and_lat_lon_and_the_rest_stay_byte_identical():
    hook = _hook(dither=0.2, seed=4)
    out = fly(hook, _path(600), frame="relative_alt")
    rows = hook.record.view()
    n = 0
    for (app, sent), rewritten, eng in zip(out["frames"], out["rewritten"], rows["engaged"]):
        if not rewritten:
            assert sent == app
            continue
        n += 1
        a, s = _payload(app), _payload(sent)
        assert a[:_ALT.start] == s[:_ALT.start] and a[_ALT.stop:] == s[_ALT.stop:]
        assert abs(decode_frame(sent).alt - decode_frame(app).alt) == pytest.approx(0.2, abs=1e-4) and eng
        h = header(sent)
        assert h.compid == PROXY_COMPONENT and h.sysid == header(app).sysid and h.msgid == header(app).msgid
    assert n > 500 and hook.counts["rewritten"] == n


@pytest.mark.parametrize("frame, mask", [(mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                                          POS_ONLY | mavlink.POSITION_TARGET_TYPEMASK_Z_IGNORE),
                                         (mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT, POS_ONLY),
                                         (mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT, POS_ONLY),
                                         (mavlink.MAV_FRAME_BODY_NED, POS_ONLY)])
def test_alt_ignored_or_a_frame_not_steered_is_never_touched(frame, mask):
    hook = _hook(dither=0.2)
    sim = LoopSim()
    fly(hook, _path(100), sim, frame="relative_alt")
    before = dict(hook.counts)
    msg, f = _global(sim, 2.0, frame, mask)
    assert hook(msg, f, 1000.0 + 100 * DT) is None
    assert hook.counts["not_steerable"] == before["not_steerable"] + 1 and hook.counts["ticks"] == before["ticks"]


def test_without_the_frames_offset_a_global_app_is_not_steered_until_it_is_known():
    """No GLOBAL_POSITION_INT: the app's own setpoints; once three reports agree, steered (collect: its dither)."""
    hook = _hook(dither=0.2)
    out = fly(hook, _path(200), frame="amsl", global_every=10 ** 9)  # one report only, at the first tick
    assert not out["rewritten"].any() and hook.counts["no_frame_offset"] == 200
    assert any("not known" in e for _, e in hook.events.events)
    hook = _hook(dither=0.2)
    out = fly(hook, _path(200), frame="amsl", global_every=5)
    assert not out["rewritten"][:10].any() and out["rewritten"][10:].all()
    assert any("above the local one" in e for _, e in hook.events.events)


def test_a_reset_home_is_followed_after_three_agreeing_reports():
    """PX4 and ArduPilot reset home at arming: the offset above home jumps; the old one is never used after it."""
    hook = _hook(dither=0.2, seed=1)
    sim, path = LoopSim(), _path(400)
    first = fly(hook, path[:200], sim, frame="relative_alt")
    sim.home = 0.8  # home now 0.5 m higher: the app's alt above it means 0.5 m higher in the local frame
    out = fly(hook, path[200:], sim, frame="relative_alt", t0=1000.0 + 200 * DT)
    assert first["rewritten"][20:].all()
    assert not out["rewritten"][:2].any() and out["rewritten"][10:].all()
    sent = out["sent"][out["rewritten"]]
    assert np.allclose(np.abs(sent - path[200:][out["rewritten"]]), 0.2, atol=1e-3)
    assert hook.view.offsets.restarts >= 1


def test_the_offset_pairs_reports_on_the_vehicles_time_line():
    """A global report 30 ms after the local one, climbing at 1 m/s: the local height advanced to its stamp."""
    off, veh = FrameOffsets(), mavlink.MAVLink(None, srcSystem=1)
    for k in range(3):
        t_ms = 1000 + 100 * k
        off.local(veh.local_position_ned_encode(t_ms, 0, 0, -(2.0 + 0.1 * k), 0, 0, -1.0))
        h = 2.0 + 0.1 * k + 0.03
        off.global_position(veh.global_position_int_encode(t_ms + 30, LAT, LON, round((h + 488.0) * 1e3),
                                                           round((h - 0.3) * 1e3), 0, 0, -100, 0), 10.0 + 0.1 * k)
    assert off.offset("relative_alt", 10.3) == pytest.approx(-0.3, abs=1e-6)
    assert off.offset("amsl", 10.3) == pytest.approx(488.0, abs=1e-6)
    assert math.isnan(off.offset("amsl", 13.0))  # no report for max_age: unknown


def test_a_global_app_asks_the_vehicle_for_its_global_position():
    def requested(frame: str) -> set[int]:
        hook = _hook()
        fly(hook, _path(100), frame=frame, global_every=25)  # GLOBAL_POSITION_INT at 2 Hz
        msgs = [decode_frame(f) for f in hook.own_messages(1000.0 + 100 * DT)]
        assert all(m.command == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL for m in msgs)
        return {int(m.param1): m.param2 for m in msgs}

    assert mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT not in requested("local")
    assert requested("relative_alt")[mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT] == pytest.approx(1e5)


def test_the_proxy_hands_a_global_setpoint_to_the_hook_and_sends_its_replacement():
    enc = SetpointEncoder()
    asked = []

    def hook(msg, frame, t_rx):
        asked.append(msg.get_type())
        if msg.coordinate_frame == mavlink.MAV_FRAME_GLOBAL_INT:  # the wrong message back: ignored, counted
            return enc.encode(LoopSim().setpoint(2.0)[0])
        return enc.encode(msg, alt=msg.alt + 1.0)

    ap, vp = free_port(), free_port()
    rp = RunningProxy(f"udpin:127.0.0.1:{ap}", f"udpin:127.0.0.1:{vp}", rewrite=hook)
    veh, app = Peer(), Peer()
    try:
        veh.send(frames(mav(2, 1, 1), 1)[0], vp)
        rp.wait_vehicle()
        sim = LoopSim()
        sent = [_global(sim, 2.5, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT)[1],
                _global(sim, 490.0, mavlink.MAV_FRAME_GLOBAL_INT)[1]]
        for f in sent:
            app.send(f, ap)
            time.sleep(0.01)
        got = veh.wait_for(2)
        s = rp.stop()
    finally:
        rp.stop()
        veh.close()
        app.close()
    assert asked == ["SET_POSITION_TARGET_GLOBAL_INT"] * 2 and got[1] == sent[1]
    assert decode_frame(got[0]).alt == pytest.approx(3.5) and _payload(got[0])[:12] == _payload(sent[0])[:12]
    assert s["app_to_vehicle"]["rewritten"] == 1 and s["events"]["rewrite_errors"] == 1


def test_an_app_that_changes_frames_is_not_steered_while_the_delay_holds_the_old_frame():
    """--preview-delay 0.1 s: after the switch the held preview mixes the two frames' heights for 0.1 s; meanwhile
    the app's own (delayed) setpoints go out, each converted with its own frame's offset."""
    hook = ProxySteering(VehicleView(), record=ProxyRecord(), dither=0.2, preview=DelayedPreview(0.1))
    sim, path, lag = LoopSim(), _path(400), 5
    first = fly(hook, path[:200], sim)
    out = fly(hook, path[200:], sim, frame="relative_alt", t0=1000.0 + 200 * DT)
    played = path[200 - lag:400 - lag]  # what the app sent 0.1 s before
    assert np.allclose(np.abs(first["sent"][20:] - path[20 - lag:200 - lag]), 0.2, atol=1e-5)
    assert np.allclose(out["sent"][:lag], played[:lag], atol=1e-5)  # the app's own, delayed
    assert np.allclose(np.abs(out["sent"][lag + 2:] - played[lag + 2:]), 0.2, atol=1e-3)
    assert hook.frames == {"local": 200, "relative_alt": 200, "amsl": 0}
    assert any("changed frame (local -> relative_alt)" in e for _, e in hook.events.events)
