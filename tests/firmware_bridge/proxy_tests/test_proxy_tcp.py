"""A byte-stream vehicle (TCP, as ArduPilot's SITL serves it): the stream is split into frames, each
sent to the clients as its own datagram; the clients' frames are written into the stream whole; the
proxy reconnects when the vehicle drops the connection."""

from __future__ import annotations

import random
import socket
import time

import pytest

from firmware_bridge.proxy.rewrite import decode_frame

from firmware_bridge.proxy import SetpointEncoder
from proxy_support import POS_ONLY, Peer, RunningProxy, frames, free_port, mav, setpoint


def _accept(srv: socket.socket) -> socket.socket:
    srv.settimeout(5)
    conn, _ = srv.accept()
    conn.settimeout(0.05)
    return conn


def _read_stream(conn: socket.socket, n: int, timeout: float = 5.0) -> bytes:
    buf = b""
    end = time.monotonic() + timeout
    while len(buf) < n and time.monotonic() < end:
        try:
            buf += conn.recv(65536)
        except (TimeoutError, socket.timeout):
            pass
    return buf


def _vehicle_server() -> socket.socket:
    """A TCP server on a free loopback port where the proxy connects as to ArduPilot SITL's 5760."""
    srv = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    srv.bind(("127.0.0.1", 0))
    srv.listen(1)
    return srv


def test_tcp_vehicle_stream_split_into_frames_both_ways_and_reconnected():
    srv = _vehicle_server()
    ap = free_port()
    rp = RunningProxy(f"udpin:127.0.0.1:{ap}", f"tcp:127.0.0.1:{srv.getsockname()[1]}", reconnect_interval=0.2)
    app = Peer()
    conn = _accept(srv)
    try:
        app.send(frames(mav(2, 245, 190), 1, 99)[0], ap)     # register the client
        _read_stream(conn, 1)
        # vehicle -> app: frames of both versions with garbage, cut at random places
        m1, m2 = mav(1, 1, 1), mav(2, 1, 1)
        fs = [f for k in range(300) for f in (frames(m1, 1, k)[0], frames(m2, 1, k)[0])]
        stream = b"".join(b"\x00\xfe\x03zz" + f if k % 9 == 0 else f for k, f in enumerate(fs))
        rng = random.Random(3)
        pos = 0
        while pos < len(stream):
            step = rng.randint(1, 200)
            conn.sendall(stream[pos:pos + step])
            pos += step
            time.sleep(0.0005)
        assert app.wait_for(len(fs)) == fs
        # app -> vehicle: the same bytes into the stream
        out = frames(mav(2, 245, 190), 200)
        for f in out:
            app.send(f, ap)
        assert _read_stream(conn, sum(map(len, out))) == b"".join(out)
        # the vehicle drops the link: the proxy connects again and forwarding resumes
        conn.close()
        conn = _accept(srv)
        again = frames(m2, 3, 1000)
        conn.sendall(b"".join(again))
        assert app.wait_for(len(fs) + 3)[len(fs):] == again
    finally:
        s = rp.stop()
        conn.close()
        srv.close()
        app.close()
    d = s["vehicle_to_app"]
    assert d["received"] == d["forwarded"] == len(fs) + 3 and d["garbage_bytes"] == 5 * len(range(0, len(fs), 9))
    assert s["events"]["vehicle_reconnects"] >= 1 and s["events"]["vehicle_link_errors"] >= 1
    assert s["app_to_vehicle"]["forwarded"] == 201


def test_into_a_stream_go_whole_frames_with_the_hooks_replacement():
    srv = _vehicle_server()
    enc = SetpointEncoder()
    ap = free_port()
    rp = RunningProxy(f"udpin:127.0.0.1:{ap}", f"tcp:127.0.0.1:{srv.getsockname()[1]}",
                      rewrite=lambda msg, frame, t: enc.encode(msg, (msg.x, msg.y, msg.z - 1.0)))
    app = Peer()
    conn = _accept(srv)
    try:
        a = mav(2, 245, 190)
        hb, sp = frames(a, 1)[0], setpoint(a, 1, POS_ONLY)
        app.send(b"junk" + hb + sp + b"\xfd\x01", ap)          # one datagram: garbage, two frames, a stub
        want = hb + enc.encode(decode_frame(sp), (0.1, 0.2, -1.01 - 1.0))
        got = _read_stream(conn, len(want))
    finally:
        s = rp.stop()
        conn.close()
        srv.close()
        app.close()
    assert len(got) == len(want) and got[:len(hb)] == hb
    assert decode_frame(got[len(hb):]).z == pytest.approx(-2.01, abs=1e-6)
    assert s["app_to_vehicle"]["rewritten"] == 1 and s["app_to_vehicle"]["garbage_bytes"] == 6


def test_tcp_clients_get_whole_frames_and_their_frames_reach_the_vehicle():
    ap, vp = free_port(), free_port()
    rp = RunningProxy([f"tcpin:127.0.0.1:{ap}", f"udpin:127.0.0.1:{free_port()}"], f"udpin:127.0.0.1:{vp}")
    veh = Peer()
    veh.send(frames(mav(2, 1, 9), 1)[0], vp)
    end = time.monotonic() + 5
    while rp.proxy.vehicle.peer is None and time.monotonic() < end:
        time.sleep(0.01)
    a, b = (socket.create_connection(("127.0.0.1", ap), timeout=5) for _ in range(2))
    try:
        end = time.monotonic() + 5
        while (rp.proxy.events["clients_joined"] < 2 or rp.proxy.vehicle.peer is None) and time.monotonic() < end:
            time.sleep(0.01)
        fs = frames(mav(2, 1, 1), 300)
        for k, f in enumerate(fs):                                  # garbage around some datagrams
            veh.send(b"\x00zz" + f if k % 10 == 0 else f, vp)
            if k % 40 == 39:
                time.sleep(0.003)
        want = b"".join(fs)
        for c in (a, b):
            c.settimeout(0.05)
            assert _read_stream(c, len(want)) == want                 # whole frames, no garbage, in order
        out = frames(mav(2, 255, 190), 100)
        stream = b"".join(b"\xfe\x07noise" + f if k % 7 == 0 else f for k, f in enumerate(out))
        for k in range(0, len(stream), 37):                           # cut anywhere
            a.sendall(stream[k:k + 37])
        got = b""
        end = time.monotonic() + 5
        while len(got) < len(b"".join(out)) and time.monotonic() < end:
            got = b"".join(veh.got)
            time.sleep(0.01)
        assert got == b"".join(out)
        b.close()
        end = time.monotonic() + 5
        while rp.proxy.events["clients_left"] < 1 and time.monotonic() < end:
            veh.send(frames(mav(2, 1, 1), 1, 500)[0], vp)              # the proxy notices on its next read / write
            time.sleep(0.02)
    finally:
        s = rp.stop()
        for c in (a, b):
            c.close()
        veh.close()
    assert s["events"]["clients_left"] == 1 and s["app_to_vehicle"]["received"] == 100
    assert s["app_to_vehicle"]["garbage_bytes"] == 7 * len(range(0, 100, 7))
    assert s["vehicle_to_app"]["garbage_bytes"] == 3 * 30
