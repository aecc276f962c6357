"""The rewrite hook: it is asked about exactly the app's position setpoints, replaces exactly those,
everything else (and every fault of the hook) leaves the bytes as they came; the app's setpoint
period is recorded."""

from __future__ import annotations

import time

import pytest

from firmware_bridge.proxy import PROXY_COMPONENT, SetpointEncoder
from firmware_bridge.proxy.frames import header
from firmware_bridge.proxy.rewrite import decode_frame

from proxy_support import POS_ONLY, VEL_ONLY, Peer, RunningProxy, frames, free_port, mav, setpoint

def _fly(hook, n: int = 200):
    """The app streams n setpoints (every 2nd position, every 4th velocity only) among heartbeats at
    ~200 Hz, a ground station sends a position setpoint too; -> (app sent, gcs sent, vehicle got, summary)."""
    ap, vp = free_port(), free_port()
    rp = RunningProxy(f"udpin:127.0.0.1:{ap}", f"udpin:127.0.0.1:{vp}", rewrite=hook)
    veh, app, gcs = Peer(), Peer(), Peer()
    try:
        veh.send(frames(mav(2, 1, 1), 1)[0], vp)
        rp.wait_vehicle()
        a, g = mav(2, 245, 190), mav(2, 255, 190)
        sent = []
        for k in range(n):
            f = setpoint(a, k, POS_ONLY) if k % 2 == 0 else (setpoint(a, k, VEL_ONLY) if k % 4 == 1
                                                               else frames(a, 1, k)[0])
            sent.append(f)
            app.send(f, ap)
            time.sleep(0.005)
        gs = [setpoint(g, 7, POS_ONLY)]
        gcs.send(gs[0], ap)
        got = veh.wait_for(n + 1)
        return sent, gs, got, rp.stop()
    finally:
        rp.stop()
        for p in (veh, app, gcs):
            p.close()


def test_without_a_hook_setpoints_pass_and_their_period_is_recorded():
    sent, gs, got, s = _fly(None)
    assert got == sent + gs
    sp = s["setpoints"]
    assert sp["count"] == 150 and s["events"]["foreign_setpoints"] == 1   # 100 position + 50 velocity; the GCS's
    assert sp["period_s"] == pytest.approx(0.0075, abs=0.004) and sp["client"] is not None


def test_the_hook_replaces_exactly_the_apps_position_setpoints():
    enc = SetpointEncoder()
    asked = []

    def lift(msg, frame, t_rx):
        asked.append(frame)
        return enc.encode(msg, (msg.x, msg.y, msg.z - 1.0))

    sent, gs, got, s = _fly(lift)
    assert len(got) == len(sent) + 1 and got[-1] == gs[0]       # the ground station's setpoint untouched
    expected_asked = [f for k, f in enumerate(sent) if k % 2 == 0]
    assert asked == expected_asked and s["app_to_vehicle"]["rewritten"] == len(expected_asked)
    seqs = []
    for k, (out, orig) in enumerate(zip(got, sent)):
        if k % 2:
            assert out == orig                                  # velocity-only setpoints, heartbeats: same bytes
            continue
        h, m, m0 = header(out), decode_frame(out), decode_frame(orig)
        assert h.compid == PROXY_COMPONENT and h.sysid == 245 and h.msgid == 84
        assert m.z == pytest.approx(m0.z - 1.0) and (m.x, m.y) == pytest.approx((m0.x, m0.y))
        assert (m.vx, m.yaw, m.type_mask, m.coordinate_frame) == pytest.approx((m0.vx, m0.yaw, m0.type_mask,
                                                                                m0.coordinate_frame))
        seqs.append(h.seq)
    assert seqs == [k % 256 for k in range(len(seqs))]          # the proxy's own sequence


@pytest.mark.parametrize("bad", ["raise", "junk", "other_message"])
def test_a_faulty_hook_forwards_the_apps_ownsetpoint(bad):
    def hook(msg, frame, t_rx):
        if bad == "raise":
            raise RuntimeError("solver failed")
        if bad == "junk":
            return b"\xfd\x00junk"
        return frames(mav(2, 245, 192), 1)[0]                   # a valid frame, but not a setpoint

    sent, gs, got, s = _fly(hook, n=40)
    assert got == sent + gs
    assert s["events"]["rewrite_errors"] == 20 and s["app_to_vehicle"]["rewritten"] == 0
