"""MAVLink tlog -> IODataset: round trip on tlogs encoded with pymavlink, bad logs, npz pass-through."""

from __future__ import annotations

import struct

import numpy as np
import pytest
from pymavlink import mavutil
from tlog_writer import UNIX_T0_US, SyntheticMavlinkFlight

from ddpc_codegen import IODataset
from ddpc_codegen.errors import DataError
from ddpc_codegen.logs import LogImportWarning, import_tlog, read_tlog

pytestmark = pytest.mark.filterwarnings("ignore::ddpc_codegen.logs.LogImportWarning")

F32 = 2e-6


@pytest.fixture(scope="module")
def flight():
    return SyntheticMavlinkFlight(seed=1)


@pytest.fixture(scope="module")
def tlog(flight, tmp_path_factory):
    return flight.writer().write(tmp_path_factory.mktemp("tlog") / "flight.tlog")


def _grid(ds, i=0):
    seg = ds.metadata["segments"][i]
    return round(seg["t_start_s"] * 1e6) + np.arange(ds.lengths[i]) * round(ds.dt * 1e6)


def test_writer_output_is_a_tlog_mavutil_reads(tlog):
    conn = mavutil.mavlink_connection(str(tlog))
    n, first = 0, None
    while (m := conn.recv_match()) is not None:
        first = first or m
        n += 1
    conn.close()
    assert n == 11 * 2 + 1001 + 3 * 501
    assert first.get_type() == "HEARTBEAT" and first._timestamp == pytest.approx(UNIX_T0_US / 1e6)
    msgs, t0 = read_tlog(tlog, None)
    assert t0 == UNIX_T0_US and sum(len(v) for v in msgs.values()) == n


def test_known_signals_come_back_exactly(flight, tlog):
    ds = import_tlog(tlog, preset="pogox-flying", rate_hz=200)
    assert ds.input_names == ("z_ref", "pitch_ref") and ds.output_names == ("z", "pitch")
    assert ds.input_units == ("m", "rad") and ds.output_units == ("m", "rad")
    assert ds.lengths == (2001,) and ds.dt == 0.005
    g = _grid(ds)
    assert g[0] == 0
    np.testing.assert_array_equal(ds.u[0][:, 0], flight.z_ref(g).astype(np.float32))
    np.testing.assert_allclose(ds.u[0][:, 1], flight.pitch_ref(g), atol=F32)
    np.testing.assert_allclose(ds.y[0][:, 0], flight.z(g), atol=F32)
    np.testing.assert_allclose(ds.y[0][:, 1], flight.pitch(g), atol=F32)
    md = ds.metadata
    assert md["source_format"] == "tlog" and md["time_source"] == "log"
    assert [(c["message"], c["sysid"], c["compid"]) for c in md["inputs"]] == [
        ("SET_POSITION_TARGET_LOCAL_NED", 1, 191), ("SET_ATTITUDE_TARGET", 1, 191)]
    assert md["files"][0]["log_start_us"] == UNIX_T0_US


def test_mavlink1_packets_and_type_mask(flight, tmp_path):
    p = flight.writer(mavlink1_attitude=True, ignore_position_at={2_000_000, 2_020_000}).write(tmp_path / "m.tlog")
    with pytest.warns(LogImportWarning, match=r"SET_POSITION_TARGET_LOCAL_NED.z_up: dropped 2 sample\(s\) whose "
                                              r"type_mask marks z as ignored \(2.000 s..2.020 s\)"):
        ds = import_tlog(p, preset="pogox-flying")
    g = _grid(ds)
    np.testing.assert_allclose(ds.y[0][:, 1], flight.pitch(g), atol=F32)  # v1 ATTITUDE decoded
    # the ignored samples are not used: the hold carries the value from before them
    k = np.flatnonzero((g >= 2_000_000) & (g < 2_040_000))
    np.testing.assert_array_equal(ds.u[0][k, 0], np.float32(flight.z_ref(1_980_000)))


def test_offboard_only_from_heartbeats(tlog):
    ds = import_tlog(tlog, preset="pogox-flying", offboard_only=True)
    # heartbeats report offboard at 0..5 s and 8..10 s: a mode counts from first to last report
    assert [(s["t_start_s"], s["t_end_s"], s["mode"]) for s in ds.metadata["segments"]] == [
        (0.0, 5.0, "offboard"), (8.0, 10.0, "offboard")]
    ds = import_tlog(tlog, preset="pogox-flying", split_on_mode=True, min_duration=0.5)
    assert [s["mode"] for s in ds.metadata["segments"]] == ["offboard", "posctl", "offboard"]


def test_time_source_boot(flight, tlog):
    ds = import_tlog(tlog, ["ATTITUDE.roll"], ["ATTITUDE.pitch", "z=LOCAL_POSITION_NED.z_up"], time_source="boot")
    assert ds.metadata["segments"][0]["t_start_s"] == 30.0  # seconds since the vehicle booted
    g = _grid(ds) - flight.vehicle_boot_us
    np.testing.assert_allclose(ds.y[0][:, 0], flight.pitch(g), atol=F32)
    with pytest.raises(DataError, match=r"time_source='boot' mixes clocks: .*\(1, 1\), \(1, 191\)"):
        import_tlog(tlog, preset="pogox-flying", time_source="boot")


def test_corrupt_bytes_are_skipped_with_a_warning(flight, tmp_path):
    w = flight.writer()
    w.records.sort(key=lambda r: r[0])
    w.records.insert(500, (-1, b"\x00\x13garbage-bytes\xfd\x01"))
    p = w.write(tmp_path / "corrupt.tlog", sort=False)
    with pytest.warns(LogImportWarning, match=r"corrupt.tlog: skipped 17 corrupt byte\(s\) in 1 place\(s\)"):
        ds = import_tlog(p, preset="pogox-flying")
    np.testing.assert_allclose(ds.y[0][:, 1], flight.pitch(_grid(ds)), atol=F32)
    # a packet whose CRC fails is dropped, not decoded into garbage
    data = bytearray(p.read_bytes())
    i = data.index(b"\x00\x13garbage")
    data[i + 17 + 8 + 12] ^= 0xFF  # a payload byte of the next packet
    p.write_bytes(bytes(data))
    with pytest.warns(LogImportWarning, match=r"dropped 1 packet\(s\) failing the MAVLink CRC"):
        import_tlog(p, preset="pogox-flying")


def test_truncated_file_warns(tlog, tmp_path):
    p = tmp_path / "cut.tlog"
    p.write_bytes(tlog.read_bytes()[:-7])
    with pytest.warns(LogImportWarning, match="the file ends inside a packet"):
        import_tlog(p, preset="pogox-flying")


# ------------------------------------------------------------------ bad logs
def test_missing_message(flight, tmp_path):
    w = flight.writer()
    w.records = [r for r in w.records if b"" != r[1] and r[1][7 if r[1][0] == 0xFD else 5] != 30]  # drop ATTITUDE (id 30)
    p = w.write(tmp_path / "noatt.tlog")
    with pytest.raises(DataError, match=r"message ATTITUDE \(for output 'pitch'\) is not in .*noatt.tlog"):
        import_tlog(p, preset="pogox-flying")
    with pytest.raises(DataError, match="MAVLink message\\(s\\) ATTITUDEX not in dialect 'common'"):
        import_tlog(p, ["ATTITUDE_TARGET.pitch"], ["ATTITUDEX.pitch"])


def test_attitude_offboard_tlog_refuses_a_position_setpoint_preset_with_advice(flight, tmp_path):
    # The companion sent SET_ATTITUDE_TARGET only (like ddpc-bridge): no height reference on the link.
    w = flight.writer()
    w.records = [r for r in w.records if r[1][7 if r[1][0] == 0xFD else 5] != 84]  # drop SET_POSITION_TARGET_LOCAL_NED
    p = w.write(tmp_path / "att_only.tlog")
    with pytest.raises(DataError, match=r"att_only.tlog has attitude setpoints \(SET_ATTITUDE_TARGET\) but no "
                                        r"SET_POSITION_TARGET_LOCAL_NED \(for input 'z_ref'\).*ddpc-bridge --log "
                                        r"flight.npz.*--preset ardupilot-guided-attitude"):
        import_tlog(p, preset="pogox-flying")
    ds = import_tlog(p, ["thrust=SET_ATTITUDE_TARGET.thrust"], ["ATTITUDE.pitch"])  # what is there still imports
    assert np.all(ds.u[0] == np.float32(0.55))


def test_missing_field(tlog):
    with pytest.raises(DataError, match=r"field 'height' not found in message LOCAL_POSITION_NED of .*; fields: "
                                        r"time_boot_ms, vx, vy, vz, x, y, z"):
        import_tlog(tlog, ["SET_ATTITUDE_TARGET.pitch"], ["LOCAL_POSITION_NED.height"])


def test_several_sources_need_a_choice(flight, tmp_path):
    w = flight.writer()
    other = w.encoder(2, 1)
    for t in range(0, 10_000_001, 10_000):
        w.add(UNIX_T0_US + t + 3, other.attitude_encode(t // 1000, 0, 0.5, 0, 0, 0, 0), 2, 1)
    p = w.write(tmp_path / "two.tlog")
    with pytest.raises(DataError, match=r"ATTITUDE in .*two.tlog comes from 2 sources \(system 1/component 1: 1001 msgs, "
                                        r"system 2/component 1: 1001 msgs\).*MESSAGE@SYSID.FIELD or --sysid"):
        import_tlog(p, preset="pogox-flying")
    ds = import_tlog(p, preset="pogox-flying", sysid=1)
    np.testing.assert_allclose(ds.y[0][:, 1], flight.pitch(_grid(ds)), atol=F32)
    ds = import_tlog(p, ["SET_ATTITUDE_TARGET.pitch"], ["ATTITUDE@2.pitch"])
    np.testing.assert_allclose(ds.y[0][:, 0], 0.5, atol=F32)


def test_non_monotonic_timestamps(flight, tmp_path):
    w = flight.writer()
    w.records.sort(key=lambda r: r[0])
    # swap the stamps of two ATTITUDE records 1 s apart: the stream jumps back
    att = [i for i, (_, b) in enumerate(w.records) if b[7] == 30]
    i, j = att[300], att[400]
    (ti, bi), (tj, bj) = w.records[i], w.records[j]
    w.records[i], w.records[j] = (tj, bi), (ti, bj)
    p = w.write(tmp_path / "back.tlog", sort=False)
    with pytest.raises(DataError, match=r"back.tlog:ATTITUDE.pitch: timestamps go backwards: 4.000 s -> 3.010 s"):
        import_tlog(p, preset="pogox-flying")


def test_not_a_tlog(tmp_path):
    p = tmp_path / "x.tlog"
    p.write_bytes(struct.pack(">Q", 5) + b"no mavlink here at all")
    with pytest.warns(LogImportWarning, match="corrupt byte"), pytest.raises(DataError, match="no MAVLink record found"):
        import_tlog(p, preset="pogox-flying")
    with pytest.raises(DataError, match="does not exist"):
        import_tlog(tmp_path / "missing.tlog", preset="pogox-flying")


def test_bridge_npz_logs_need_no_conversion(tmp_path):
    rng = np.random.default_rng(0)
    a = IODataset(rng.standard_normal((50, 2)), rng.standard_normal((50, 2)), 0.005,
                  input_names=["z_ref", "pitch_ref"], output_names=["z", "pitch"]).save(tmp_path / "a.npz")
    b = IODataset(rng.standard_normal((40, 2)), rng.standard_normal((40, 2)), 0.005,
                  input_names=["z_ref", "pitch_ref"], output_names=["z", "pitch"]).save(tmp_path / "b.npz")
    ds = import_tlog(a)
    np.testing.assert_array_equal(ds.u[0], IODataset.load(a).u[0])
    ds = import_tlog([a, b])
    assert ds.lengths == (50, 40) and ds.metadata["merged_from"] == [str(a), str(b)]
    c = IODataset(np.zeros((40, 1)), np.zeros((40, 2)), 0.005).save(tmp_path / "c.npz")
    with pytest.raises(DataError, match="cannot merge .*c.npz .* channels/dt differ"):
        import_tlog([a, c])


def test_ground_rover_log_warns(flight, tmp_path):
    p = flight.writer(vehicle_type=10).write(tmp_path / "rover.tlog")
    with pytest.warns(LogImportWarning) as rec:
        import_tlog(p, preset="pogox-flying")
    msgs = [str(w.message) for w in rec]
    assert ("rover.tlog: system 1 reports HEARTBEAT type 10 (MAV_TYPE_GROUND_ROVER): not a flying vehicle; is this "
            "the right log?") in msgs


def test_quadrotor_log_does_not_warn_about_the_vehicle(tlog):
    import warnings

    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        import_tlog(tlog, preset="pogox-flying")
    assert not [w for w in rec if "flying vehicle" in str(w.message)]
