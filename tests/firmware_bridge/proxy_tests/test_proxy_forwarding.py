"""The transparent proxy in-process over loopback UDP: byte-exact, in-order forwarding both ways with
two clients (an app and a ground station), MAVLink 1 and 2, garbage, a client that goes away, the
optional client-to-client forwarding, and the latency / counter statistics."""

from __future__ import annotations

import time

import pytest

from proxy_support import Peer, RunningProxy, frames, free_port, mav, until


@pytest.fixture
def rig():
    """(proxy, vehicle, app, gcs, app port, vehicle port): both clients registered, the vehicle heard."""
    ap, vp = free_port(), free_port()
    rp = RunningProxy(f"udpin:127.0.0.1:{ap}", f"udpin:127.0.0.1:{vp}", client_timeout=5.0)
    veh, app, gcs = Peer(), Peer(), Peer()
    hello = frames(mav(2, 1, 9), 1)[0]  # (the tests' own senders each start at sequence 0)
    veh.send(hello, vp)
    until(lambda: rp.proxy.vehicle.peer is not None)
    app.send(frames(mav(2, 245, 9), 1)[0], ap)
    gcs.send(frames(mav(1, 255, 9), 1)[0], ap)
    assert len(veh.wait_for(2, 5)) == 2
    for p in (app, gcs):
        p.got.clear()
    veh.got.clear()
    yield rp, veh, app, gcs, ap, vp
    rp.stop()
    for p in (veh, app, gcs):
        p.close()



def _paced(send, items, every: int = 40) -> None:
    for k, f in enumerate(items):
        send(f)
        if k % every == every - 1:
            time.sleep(0.003)  # loopback UDP drops nothing unless a receive buffer overflows


def test_vehicle_to_every_client_byte_exact_and_in_order(rig):
    rp, veh, app, gcs, ap, vp = rig
    m1, m2 = mav(1, 1, 2), mav(2, 1, 1)
    sent = [f for k in range(1500) for f in (frames(m2, 1, k)[0], frames(m1, 1, k)[0])]  # seq wraps 5 times
    _paced(lambda f: veh.send(f, vp), sent)
    for p in (app, gcs):
        assert p.wait_for(len(sent)) == sent, rp.proxy.summary()["vehicle_to_app"]
    s = rp.stop()
    d = s["vehicle_to_app"]
    assert d["received"] == len(sent) + 1 and d["forwarded"] == 2 * len(sent)
    assert d["dropped"] == 1 and d["send_errors"] == 0 and d["garbage_bytes"] == 0 and d["seq_gaps"] == 0
    lat = d["latency_us"]
    assert lat["count"] == d["forwarded"] and 0 < lat["p50"] <= lat["p99"] <= lat["max"]


def test_clients_to_vehicle_byte_exact_each_in_order(rig):
    rp, veh, app, gcs, ap, vp = rig
    a, g = frames(mav(2, 245, 190), 2000), frames(mav(1, 255, 190), 2000)
    _paced(lambda f: (app.send(f[0], ap), gcs.send(f[1], ap)), list(zip(a, g)), every=20)
    got = veh.wait_for(4000)
    assert len(got) == 4000
    assert [f for f in got if f in set(a)] == a and [f for f in got if f in set(g)] == g
    time.sleep(0.1)
    assert app.got == [] and gcs.got == []  # clients do not hear each other unless asked
    s = rp.stop()
    u = s["app_to_vehicle"]
    assert u["received"] == u["forwarded"] == 4002 and u["dropped"] == u["seq_gaps"] == 0
    assert u["latency_us"]["count"] == 4002
    assert s["app_to_vehicle"]["datagrams"] == 4002 and s["events"]["clients_joined"] == 2


def test_garbage_is_forwarded_whole_and_counted(rig):
    rp, veh, app, gcs, ap, vp = rig
    f = frames(mav(2, 1, 1), 3)
    junk = [b"\x00\x01\x02", b"\xfd\x05" + f[0][2:], f[1][:-3], b"noise" + f[2]]
    for d in junk:
        veh.send(d, vp)
    assert app.wait_for(4) == junk and gcs.wait_for(4) == junk
    app.send(b"\xfe\xff garbage", ap)
    assert veh.wait_for(1) == [b"\xfe\xff garbage"]
    s = rp.stop()
    assert s["vehicle_to_app"]["received"] == 1 + 1 and s["vehicle_to_app"]["garbage_bytes"] > 0
    assert s["app_to_vehicle"]["garbage_bytes"] == len(b"\xfe\xff garbage")


def test_frames_lost_before_the_proxy_show_as_sequence_gaps(rig):
    rp, veh, app, gcs, ap, vp = rig
    fs = frames(mav(2, 1, 1), 10)
    for f in fs[:4] + fs[5:]:                               # one lost on the way in
        veh.send(f, vp)
    assert app.wait_for(9) == fs[:4] + fs[5:]
    assert rp.stop()["vehicle_to_app"]["seq_gaps"] == 1


def test_a_quiet_client_keeps_everything_and_one_that_went_away_costs_the_others_nothing(rig):
    rp, veh, app, gcs, ap, vp = rig
    rp.proxy.client_timeout = 0.3
    gone = Peer()
    gone.send(frames(mav(2, 200, 190), 1)[0], ap)
    until(lambda: len(rp.proxy.clients) == 3)
    gone.close()                                            # its port is closed from now on
    m = mav(2, 1, 1)
    sent = []
    t_end = time.monotonic() + 1.0  # the gcs says nothing for over three client timeouts
    while time.monotonic() < t_end:
        sent += frames(m, 5, len(sent))
        for f in sent[-5:]:
            veh.send(f, vp)
        app.send(frames(mav(2, 245, 190), 1)[0], ap)  # the app keeps talking (heartbeats)
        time.sleep(0.01)
    assert app.wait_for(len(sent)) == sent and gcs.wait_for(len(sent)) == sent
    s = rp.stop()
    assert s["events"]["clients_left"] == 0 and len(s["clients"]) == 3
    assert s["vehicle_to_app"]["forwarded"] == 3 * len(sent) and s["vehicle_to_app"]["send_errors"] == 0


def test_between_clients_forwards_each_clients_messages_to_the_others():
    ap, vp = free_port(), free_port()
    rp = RunningProxy(f"udpin:127.0.0.1:{ap}", f"udpin:127.0.0.1:{vp}", between_clients=True)
    veh, app, gcs = Peer(), Peer(), Peer()
    try:
        veh.send(frames(mav(2, 1, 1), 1)[0], vp)
        until(lambda: rp.proxy.vehicle.peer is not None)
        gcs.send(frames(mav(2, 255, 190), 1)[0], ap)
        time.sleep(0.1)
        a = frames(mav(2, 245, 190), 3)
        for f in a:
            app.send(f, ap)
        assert gcs.wait_for(3) == a and veh.wait_for(4)[1:] == a
        assert rp.stop()["events"]["between_clients"] == 3
    finally:
        rp.stop()
        for p in (veh, app, gcs):
            p.close()


def test_nothing_reaches_the_vehicle_before_it_is_heard_and_that_is_not_an_error():
    ap, vp = free_port(), free_port()
    rp = RunningProxy(f"udpin:127.0.0.1:{ap}", f"udpin:127.0.0.1:{vp}")
    app = Peer()
    try:
        app.send(frames(mav(2, 245, 190), 1)[0], ap)
        time.sleep(0.1)
    finally:
        s = rp.stop()
        app.close()
    assert s["app_to_vehicle"]["dropped"] == 1 and s["app_to_vehicle"]["send_errors"] == 0


def test_an_app_side_other_than_udpin_udpout_tcpin_is_refused():
    with pytest.raises(ValueError, match="udpin"):
        RunningProxy("tcp:127.0.0.1:14541", "udpin:127.0.0.1:14540")


def test_an_app_that_listens_is_sent_to_like_px4_does_beside_a_server_for_a_ground_station():
    # An app bound to a port waiting for the autopilot (MAVSDK's udp://:14540) and a ground station
    # connecting to the proxy's server port, at once.
    listening, gcs, veh = Peer(), Peer(), Peer()
    ap, vp = free_port(), free_port()
    rp = RunningProxy([f"udpout:127.0.0.1:{listening.port}", f"udpin:127.0.0.1:{ap}"], f"udpin:127.0.0.1:{vp}")
    try:
        veh.send(frames(mav(2, 1, 9), 1)[0], vp)
        until(lambda: rp.proxy.vehicle.peer is not None)
        gcs.send(frames(mav(2, 255, 9), 1)[0], ap)
        until(lambda: len(veh.got) == 1)
        fs = frames(mav(2, 1, 1), 20)
        for f in fs:
            veh.send(f, vp)
        assert listening.wait_for(21)[1:] == fs and gcs.wait_for(20) == fs  # the listening app heard all
        out = frames(mav(2, 245, 190), 5)
        for f in out:
            listening.sock.sendto(f, ("127.0.0.1", rp.proxy.apps[0].local_address[1]))  # it replies to the sender
        assert veh.wait_for(6)[1:] == out
        s = rp.stop()
    finally:
        rp.stop()
        for p in (listening, gcs, veh):
            p.close()
    assert [c["app"] for c in s["clients"]] == s["apps"] and s["events"]["clients_left"] == 0
    assert s["app_to_vehicle"]["forwarded"] == 6 and s["vehicle_to_app"]["forwarded"] == 1 + 2 * 20


def test_a_restarted_vehicle_on_a_new_port_is_taken_after_the_old_one_fell_silent():
    ap, vp = free_port(), free_port()
    rp = RunningProxy(f"udpin:127.0.0.1:{ap}", f"udpin:127.0.0.1:{vp}", client_timeout=0.3)
    old, new, app = Peer(), Peer(), Peer()
    try:
        old.send(frames(mav(2, 1, 1), 1)[0], vp)
        until(lambda: rp.proxy.vehicle.peer is not None)
        new.send(frames(mav(2, 1, 1), 1)[0], vp)            # a second sender while the first is alive: foreign
        until(lambda: rp.proxy.vehicle.counts["foreign"] == 1)
        time.sleep(0.4)                                     # the first falls silent ...
        new.send(frames(mav(2, 1, 1), 1)[0], vp)            # ... and the new one becomes the vehicle
        until(lambda: rp.proxy.vehicle.counts["peer_changes"] == 1)
        app.send(frames(mav(2, 245, 190), 1)[0], ap)
        assert len(new.wait_for(1)) == 1 and old.got == []
    finally:
        s = rp.stop()
        for p in (old, new, app):
            p.close()
    assert s["vehicle_peer"][1] == new.port and s["events"]["vehicle_peer_changes"] == 1
