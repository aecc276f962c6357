"""The bridge's udpin link pins its peer and, with a key, takes only signed packets (firmware_bridge/link.py,
signing.py): a second process on the network with the vehicle's ids steers nothing and learns nothing."""

from __future__ import annotations

import os
import socket
import time

import pytest

from firmware_bridge.link import MavLink, mavlink
from firmware_bridge.signing import SigningError, load_signing_key
from firmware_bridge.transports import parse_address

KEY = bytes(range(32))


def _port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _vehicle(port: int, key: bytes | None = None) -> MavLink:
    """A vehicle (system 1, component 1) talking to the bridge's udpin port from its own socket."""
    link = MavLink(f"udpout:127.0.0.1:{port}", source_system=1, source_component=1, target_system=None,
                   signing_key=key)
    return link


def _drain(link: MavLink, seconds: float = 0.3) -> list:
    got, t_end = [], time.monotonic() + seconds
    while time.monotonic() < t_end:
        link.wait(0.02)
        got += [m for m, _ in link.drain()]
    return got


def _hb(link: MavLink) -> None:
    link.send_heartbeat(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, 129, 6 << 16, 4)


@pytest.fixture
def links():
    made: list[MavLink] = []

    def make(link: MavLink) -> MavLink:
        made.append(link)
        return link

    yield make
    for link in made:
        link.close()


def test_a_spoofer_with_the_vehicles_ids_on_another_port_is_counted_and_never_answered(links):
    port = _port()
    bridge = links(MavLink(f"udpin:127.0.0.1:{port}", target_system=1, target_component=1))
    veh, spoof = links(_vehicle(port)), links(_vehicle(port))
    _hb(veh)
    assert [m.get_type() for m in _drain(bridge)] == ["HEARTBEAT"] and bridge.peer == veh.local_address()
    for k in range(20):  # the spoofer: heartbeats, telemetry, acks, all with system 1 / component 1
        _hb(spoof)
        spoof.send(spoof.mav.local_position_ned_encode(k, 0.0, 0.0, -100.0, 0.0, 0.0, 0.0))
        spoof.send(spoof.mav.command_ack_encode(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0))
    veh.send(veh.mav.local_position_ned_encode(7, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0))
    got = _drain(bridge)
    assert [(m.get_type(), m.z) for m in got] == [("LOCAL_POSITION_NED", -1.0)]
    assert bridge.stats["foreign_packets"] == 60 and bridge.stats["peer_changes"] == 1
    assert bridge.stats["foreign_heartbeats"] == 20 and bridge.pin.foreign_address == spoof.local_address()
    bridge.command_long(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, (32.0, 5000.0))
    assert [m.get_type() for m in _drain(veh)] == ["COMMAND_LONG"]
    assert _drain(spoof, 0.1) == []


def test_a_spoof_at_start_up_does_not_take_the_stream_request(links):
    port = _port()
    bridge = links(MavLink(f"udpin:127.0.0.1:{port}", target_system=1, target_component=1))
    veh, spoof = links(_vehicle(port)), links(_vehicle(port))
    for k in range(10):  # before the vehicle speaks: everything but a heartbeat, with the vehicle's ids
        spoof.send(spoof.mav.local_position_ned_encode(k, 0.0, 0.0, -100.0, 0.0, 0.0, 0.0))
        spoof.send(spoof.mav.command_ack_encode(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0))
    assert _drain(bridge) == [] and bridge.peer is None and bridge.stats["unpinned"] == 20
    assert not bridge.command_long(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, (32.0, 5000.0))  # no one to send to
    _hb(veh)
    _drain(bridge)
    assert bridge.command_long(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, (32.0, 5000.0))
    assert [m.get_type() for m in _drain(veh)] == ["COMMAND_LONG"] and _drain(spoof, 0.1) == []


def test_a_given_vehicle_address_is_pinned_before_any_heartbeat(links):
    port = _port()
    veh_port = _port()
    bridge = links(MavLink(f"udpin:127.0.0.1:{port}", target_system=1, target_component=1,
                           vehicle_address=("127.0.0.1", veh_port)))
    spoof = links(_vehicle(port))
    _hb(spoof)                                          # first heartbeat with the ids: not the given address
    assert _drain(bridge) == [] and bridge.peer == ("127.0.0.1", veh_port)
    veh = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        veh.bind(("127.0.0.1", veh_port))
        mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        veh.sendto(mav.heartbeat_encode(2, 12, 129, 0, 4).pack(mav), ("127.0.0.1", port))
        assert [m.get_type() for m in _drain(bridge)] == ["HEARTBEAT"]
        assert bridge.stats["foreign_packets"] == 1 and bridge.stats["peer_changes"] == 0
    finally:
        veh.close()
    assert parse_address("localhost:14550") == ("127.0.0.1", 14550)
    for bad in ("14550", "host:0", ":14550", "no.such.host.invalid:1"):
        with pytest.raises(ValueError):
            parse_address(bad)


def test_a_restarted_vehicle_takes_the_peer_only_after_the_old_one_fell_silent(links):
    port = _port()
    bridge = links(MavLink(f"udpin:127.0.0.1:{port}", target_system=1, target_component=1, repin_after=0.3))
    old, new = links(_vehicle(port)), links(_vehicle(port))
    _hb(old)
    _drain(bridge, 0.1)
    _hb(new)                                            # the old peer was heard just now: ignored
    assert _drain(bridge, 0.1) == [] and bridge.peer == old.local_address()
    time.sleep(0.35)
    _hb(new)                                            # the old peer silent past repin_after: moves
    assert [m.get_type() for m in _drain(bridge, 0.1)] == ["HEARTBEAT"] and bridge.peer == new.local_address()
    _hb(old)
    assert _drain(bridge, 0.1) == [] and bridge.stats["peer_changes"] == 2


def test_with_a_key_unsigned_and_wrongly_signed_packets_are_dropped_and_counted(links):
    port = _port()
    bridge = links(MavLink(f"udpin:127.0.0.1:{port}", target_system=1, target_component=1, signing_key=KEY))
    unsigned, wrong = links(_vehicle(port)), links(_vehicle(port, key=bytes(32)))
    _hb(unsigned)
    _hb(wrong)
    mav1 = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    mav1.WIRE_PROTOCOL_VERSION = "1.0"
    raw = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    raw.sendto(mav1.heartbeat_encode(2, 12, 129, 0, 4).pack(mav1, force_mavlink1=True), ("127.0.0.1", port))
    raw.close()
    assert _drain(bridge) == [] and bridge.peer is None
    assert bridge.stats["unsigned"] == 2 and bridge.stats["bad_signature"] == 1 and bridge.stats["bad_data"] == 0
    veh = links(_vehicle(port, key=KEY))
    _hb(veh)
    veh.send(veh.mav.local_position_ned_encode(7, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0))
    assert [m.get_type() for m in _drain(bridge)] == ["HEARTBEAT", "LOCAL_POSITION_NED"]
    assert bridge.peer == veh.local_address()
    bridge.send_heartbeat()                            # ours are signed: the vehicle with the key takes them
    got = _drain(veh)
    assert [m.get_type() for m in got] == ["HEARTBEAT"] and got[0]._signed


def test_a_replayed_signed_packet_is_dropped(links):
    port = _port()
    bridge = links(MavLink(f"udpin:127.0.0.1:{port}", target_system=1, target_component=1, signing_key=KEY))
    veh = links(_vehicle(port, key=KEY))
    mav = veh.mav
    packet = mav.heartbeat_encode(2, 12, 129, 0, 4).pack(mav)
    veh.transport.write(packet)
    assert [m.get_type() for m in _drain(bridge)] == ["HEARTBEAT"]
    veh.transport.write(packet)                        # the same bytes again: its time stamp is not newer
    assert _drain(bridge) == [] and bridge.stats["bad_signature"] == 1


def test_signing_key_files(tmp_path):
    (tmp_path / "hex").write_text(KEY.hex() + "\n")
    (tmp_path / "raw").write_bytes(KEY)
    assert load_signing_key(tmp_path / "hex") == KEY and load_signing_key(tmp_path / "raw") == KEY
    (tmp_path / "short").write_bytes(KEY[:16])
    (tmp_path / "big").write_bytes(os.urandom(5000))
    for name, why in (("short", "32 raw bytes or 64 hex digits; got 16"), ("big", "over 4096 bytes"),
                      ("missing", "not a regular file")):
        with pytest.raises(SigningError, match=why):
            load_signing_key(tmp_path / name)


def test_the_bridge_flags_reach_the_config_and_a_bad_key_is_one_line_exit_2(tmp_path, capsys):
    from firmware_bridge.cli import bridge_config_from_args, build_bridge_parser

    (tmp_path / "key").write_text(KEY.hex())
    a = build_bridge_parser().parse_args(["udpin:127.0.0.1:14540", "--mode", "passthrough", "--vehicle-address",
                                          "127.0.0.1:14580", "--signing-key", str(tmp_path / "key")])
    c = bridge_config_from_args(a)
    assert c.vehicle_address == ("127.0.0.1", 14580) and c.signing_key == KEY and "signing_key" not in repr(c)
    (tmp_path / "bad").write_text("not a key")
    with pytest.raises(SystemExit) as e:
        build_bridge_parser().parse_args(["udpin:127.0.0.1:14540", "--signing-key", str(tmp_path / "bad")])
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert e.value.code == 2 and "--signing-key" in err and "bad: signing key must be 32 raw bytes" in err


@pytest.mark.parametrize("value", ["127.0.0.1", "127.0.0.1:0", "127.0.0.1:70000", "127.0.0.1:port", ":14540"])
def test_a_bad_vehicle_address_is_one_line_exit_2(value, capsys):
    from firmware_bridge.cli import build_bridge_parser

    with pytest.raises(SystemExit) as e:
        build_bridge_parser().parse_args(["udpin:127.0.0.1:14540", "--vehicle-address", value])
    err = capsys.readouterr().err.strip().splitlines()
    assert e.value.code == 2 and "--vehicle-address" in err[-1] and "expected HOST:PORT" in err[-1], err[-1]
