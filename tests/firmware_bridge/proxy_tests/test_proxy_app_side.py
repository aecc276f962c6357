"""The proxy's UDP server side keeps its clients as an autopilot's port does: a sender is a client from its
first datagram on, however long it is quiet (a ground station that only listens keeps the vehicle's stream);
beyond the bound the sender heard least recently is replaced; the app's setpoint role still passes on after
its silence (a restarted app on a new port)."""

from __future__ import annotations

import socket
import time

from firmware_bridge.proxy.app_side import UdpApps

from proxy_support import POS_ONLY, Peer, RunningProxy, frames, free_port, mav, setpoint, until



def _read_all(ep: UdpApps, n: int) -> list:
    """Everything ``n`` datagrams sent to ``ep`` (bounded wait), in one list."""
    got: list = []
    end = time.monotonic() + 5.0
    while len(got) < n and time.monotonic() < end:
        got += ep.read(ep.fds()[0])
        time.sleep(0.01)
    assert len(got) == n
    return got


def test_a_udp_server_keeps_its_senders_and_replaces_the_least_recently_heard_beyond_its_bound():
    ep = UdpApps("127.0.0.1", 0, listen=True, max_clients=2)
    port = ep.local_address[1]
    socks = {k: socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for k in "abcd"}
    try:
        for s in socks.values():
            s.bind(("127.0.0.1", 0))
        addr = {k: s.getsockname() for k, s in socks.items()}

        def send(*keys: str) -> list:
            for k in keys:
                socks[k].sendto(b"x", ("127.0.0.1", port))
            got = _read_all(ep, len(keys))
            joined, gone = list(ep.joined), list(ep.gone)
            ep.joined.clear()
            ep.gone.clear()
            assert [g[0] for g in got] == [addr[k] for k in keys]
            return [joined, gone]

        assert send("a", "b") == [[addr["a"], addr["b"]], []]
        assert send("a") == [[], []]                         # heard again (b is now the least recent)
        assert send("c") == [[addr["c"]], [addr["b"]]]       # past the bound: b, not the quiet-but-newer a
        # within one read: d replaces a, a comes back and replaces c; a never left as far as the proxy knows
        assert send("d", "a") == [[addr["d"]], [addr["c"]]]
        assert list(ep._heard) == [addr["d"], addr["a"]]
    finally:
        ep.close()
        for s in socks.values():
            s.close()


def test_a_quiet_ground_station_keeps_receiving_past_the_client_timeout():
    ap, vp = free_port(), free_port()
    rp = RunningProxy(f"udpin:127.0.0.1:{ap}", f"udpin:127.0.0.1:{vp}", client_timeout=0.2)
    veh, gcs = Peer(), Peer()
    try:
        veh.send(frames(mav(2, 1, 9), 1)[0], vp)
        until(lambda: rp.proxy.vehicle.peer is not None)
        gcs.send(frames(mav(2, 255, 190), 1)[0], ap)       # one heartbeat, then it only listens
        until(lambda: len(veh.got) == 1)
        m, sent = mav(2, 1, 1), []
        for burst in range(6):                             # 0.6 s: three times the client timeout
            sent += frames(m, 5, len(sent))
            for f in sent[-5:]:
                veh.send(f, vp)
            time.sleep(0.1)
        assert gcs.wait_for(len(sent)) == sent
        s = rp.stop()
    finally:
        rp.stop()
        veh.close()
        gcs.close()
    assert len(s["clients"]) == 1 and s["clients"][0]["silent_s"] > 0.5
    assert s["clients"][0]["datagrams_out"] == len(sent) and s["events"]["clients_left"] == 0


def test_beyond_the_bound_the_longest_silent_sender_stops_receiving():
    ap, vp = free_port(), free_port()
    rp = RunningProxy(f"udpin:127.0.0.1:{ap}", f"udpin:127.0.0.1:{vp}")
    rp.proxy.apps[0].max_clients = 2
    veh, old, app, new = Peer(), Peer(), Peer(), Peer()
    try:
        veh.send(frames(mav(2, 1, 9), 1)[0], vp)
        until(lambda: rp.proxy.vehicle.peer is not None)
        for k, p in enumerate((old, app, new)):
            p.send(frames(mav(2, 200 + k, 190), 1)[0], ap)
            until(lambda: len(veh.got) == k + 1)
        fs = frames(mav(2, 1, 1), 10)
        for f in fs:
            veh.send(f, vp)
        assert app.wait_for(10) == fs and new.wait_for(10) == fs
        time.sleep(0.1)
        assert old.got == []
        s = rp.stop()
    finally:
        rp.stop()
        for p in (veh, old, app, new):
            p.close()
    assert s["events"]["clients_joined"] == 3 and s["events"]["clients_left"] == 1 and len(s["clients"]) == 2
    assert s["vehicle_to_app"]["forwarded"] == 20 and s["vehicle_to_app"]["send_errors"] == 0


def test_a_restarted_app_on_a_new_port_becomes_the_app_once_the_old_one_fell_silent():
    ap, vp = free_port(), free_port()
    rp = RunningProxy(f"udpin:127.0.0.1:{ap}", f"udpin:127.0.0.1:{vp}", client_timeout=0.3)
    veh, first, second = Peer(), Peer(), Peer()
    try:
        veh.send(frames(mav(2, 1, 9), 1)[0], vp)
        until(lambda: rp.proxy.vehicle.peer is not None)
        m1, m2 = mav(2, 245, 190), mav(2, 245, 190)
        first.send(setpoint(m1, 0, POS_ONLY), ap)
        until(lambda: rp.proxy.setpoint_client is not None)
        second.send(setpoint(m2, 0, POS_ONLY), ap)        # while the first streams: not the app's
        until(lambda: rp.proxy.events["foreign_setpoints"] == 1)
        until(lambda: rp.proxy.setpoint_client is None, 2.0)  # the first fell silent: the role is free
        second.send(setpoint(m2, 1, POS_ONLY), ap)
        until(lambda: rp.proxy.setpoint_client is not None)
        assert rp.proxy.setpoint_client[1] == ("127.0.0.1", second.port)
        s = rp.stop()
    finally:
        rp.stop()
        for p in (veh, first, second):
            p.close()
    assert s["events"]["foreign_setpoints"] == 1 and s["setpoints"]["count"] == 2
    assert len(s["clients"]) == 2  # the old app's address still hears the vehicle


def test_a_flood_from_many_ports_neither_evicts_the_app_nor_takes_its_setpoints():
    """Beyond the bound, new senders replace each other, never the app; setpoints addressed to another system are
    never the app's, even while the role is free."""
    from firmware_bridge.proxy.vehicle_view import VehicleView

    ap, vp = free_port(), free_port()
    rp = RunningProxy(f"udpin:127.0.0.1:{ap}", f"udpin:127.0.0.1:{vp}", client_timeout=0.3, view=VehicleView())
    veh, app = Peer(), Peer()
    flood = [Peer() for _ in range(24)]
    try:
        vm = mav(2, 1, 1)
        hb = bytes(vm.heartbeat_encode(2, 12, 0, 0, 0).pack(vm))  # a PX4 vehicle, system 1
        veh.send(hb, vp)
        until(lambda: rp.proxy.vehicle.peer is not None and rp.proxy.view.sysid == 1)
        app.send(setpoint(mav(2, 245, 190), 0, POS_ONLY), ap)
        until(lambda: rp.proxy.setpoint_client is not None)
        me = rp.proxy.setpoint_client
        for p in flood:
            p.send(frames(mav(2, 77, 1), 1)[0], ap)
        until(lambda: rp.proxy.events["clients_left"] >= len(flood) - 15)
        assert me in rp.proxy.clients and rp.proxy.setpoint_client == me
        veh.send(hb, vp)
        assert app.wait_for(1) == [hb]                       # still hears the vehicle
        until(lambda: rp.proxy.setpoint_client is None, 2.0)  # the app fell silent: the role is free
        fm = mav(2, 77, 1)
        sp = fm.set_position_target_local_ned_encode(0, 99, 1, 1, POS_ONLY, 0, 0, -1, 0, 0, 0, 0, 0, 0, 0, 0)
        flood[0].send(bytes(sp.pack(fm)), ap)                # a setpoint for system 99: foreign
        until(lambda: rp.proxy.events["foreign_setpoints"] == 1)
        assert rp.proxy.setpoint_client is None
        s = rp.stop()
    finally:
        rp.stop()
        for p in (veh, app, *flood):
            p.close()
    assert s["setpoints"]["count"] == 1
