"""tlog import from the MAVLink definitions (issue 12): units from the XML that pymavlink ships,
ArduPilot modes decoded per vehicle type, a memory bound on --rate, CRC drops named by message."""

from __future__ import annotations

import time

import numpy as np
import pytest
from tlog_writer import UNIX_T0_US, TlogWriter

from ddpc_codegen.cli.main import main
from ddpc_codegen.errors import DataError
from ddpc_codegen.logs import LogImportWarning, import_tlog
from ddpc_codegen.logs.resample import MAX_GRID_SAMPLES

pytestmark = pytest.mark.filterwarnings("ignore::ddpc_codegen.logs.LogImportWarning")

ARDUPILOT, PX4 = 3, 12
QUAD, SUB = 2, 12


def _flight(path, modes, *, autopilot=ARDUPILOT, vehicle=QUAD, seconds=10):
    """1 Hz heartbeats with custom_mode ``modes[s]``, ATTITUDE / VFR_HUD / GLOBAL_POSITION_INT /
    MANUAL_CONTROL at 50 Hz from the vehicle, SET_ATTITUDE_TARGET at 50 Hz from a companion."""
    w = TlogWriter()
    veh, comp = w.encoder(1, 1), w.encoder(1, 191)
    for s in range(seconds + 1):
        w.add(UNIX_T0_US + s * 1_000_000, veh.heartbeat_encode(vehicle, autopilot, 1 | 128, modes(s), 4), 1, 1)
    for t in range(0, seconds * 1_000_000 + 1, 20_000):
        x = np.sin(t / 7e5)
        w.add(UNIX_T0_US + t, veh.attitude_encode(t // 1000, 0.0, 0.1 * x, 0.2, 0, 0, 0), 1, 1)
        w.add(UNIX_T0_US + t, veh.vfr_hud_encode(3.0, 2.0, int(90 + 10 * x), 50, 12.0, 0.5 * x), 1, 1)
        w.add(UNIX_T0_US + t, veh.global_position_int_encode(t // 1000, 0, 0, 12000, 2000, 0, 0, int(30 * x), 9000), 1, 1)
        w.add(UNIX_T0_US + t, veh.manual_control_encode(1, int(500 * x), 0, 500, 0, 0), 1, 1)
        q = [1.0, 0.0, 0.05 * x, 0.0]
        w.add(UNIX_T0_US + t, comp.set_attitude_target_encode(t // 1000, 1, 1, 0b111, q, 0, 0, 0, 0.5), 1, 191)
    return w.write(path)


@pytest.fixture(scope="module")
def guided(tmp_path_factory):
    # ArduCopter: LOITER 0..3 s, GUIDED 4..6 s, GUIDED_NOGPS 7..10 s
    return _flight(tmp_path_factory.mktemp("ap") / "copter.tlog", lambda s: 5 if s < 4 else 4 if s < 7 else 20)


def test_units_come_from_the_mavlink_definitions(guided):
    ds = import_tlog(guided, ["SET_ATTITUDE_TARGET.pitch", "MANUAL_CONTROL.x"],
                     ["VFR_HUD.heading", "GLOBAL_POSITION_INT.vz", "ATTITUDE.pitch", "VFR_HUD.climb"])
    assert ds.input_units == ("rad", "")  # Euler pitch derived from q is rad; MANUAL_CONTROL.x has no unit
    assert ds.output_units == ("deg", "cm/s", "rad", "m/s")
    assert ds.metadata["outputs"][0]["unit"] == "deg"


def test_a_stated_unit_that_contradicts_the_definition_is_refused(guided):
    with pytest.raises(DataError) as e:
        import_tlog(guided, ["SET_ATTITUDE_TARGET.pitch"], ["VFR_HUD.heading:rad"])
    assert ("channel 'VFR_HUD.heading:rad': VFR_HUD.heading is in 'deg' by the MAVLink definition, not 'rad'; "
            "the importer does not convert units") in str(e.value)
    # agreeing or unit-less fields accept a stated unit
    ds = import_tlog(guided, ["SET_ATTITUDE_TARGET.thrust:1"], ["h=VFR_HUD.heading:deg"])
    assert ds.input_units == ("1",) and ds.output_units == ("deg",)


def test_ardupilot_modes_offboard_only_and_split(guided):
    spec = (["SET_ATTITUDE_TARGET.pitch"], ["ATTITUDE.pitch"])
    ds = import_tlog(guided, *spec, offboard_only=True, min_duration=0.5)
    assert [(s["t_start_s"], s["t_end_s"], s["mode"]) for s in ds.metadata["segments"]] == [
        (4.0, 6.0, "GUIDED"), (7.0, 10.0, "GUIDED_NOGPS")]
    ds = import_tlog(guided, *spec, split_on_mode=True, min_duration=0.5)
    assert [s["mode"] for s in ds.metadata["segments"]] == ["LOITER", "GUIDED", "GUIDED_NOGPS"]


def test_ardusub_modes_are_decoded_with_the_sub_map(tmp_path):
    p = _flight(tmp_path / "sub.tlog", lambda s: 19 if s < 5 else 0, vehicle=SUB, seconds=8)
    spec = (["SET_ATTITUDE_TARGET.pitch"], ["ATTITUDE.pitch"])
    ds = import_tlog(p, *spec, split_on_mode=True, min_duration=0.5)
    assert [s["mode"] for s in ds.metadata["segments"]] == ["MANUAL", "STABILIZE"]
    with pytest.raises(DataError, match=r"--offboard-only: .*sub.tlog never reports ArduPilot GUIDED / GUIDED_NOGPS "
                                        r"mode \(0.000 s..8.000 s; modes seen: MANUAL, STABILIZE\)"):
        import_tlog(p, *spec, offboard_only=True)


def test_px4_heartbeats_still_decode_as_px4(tmp_path):
    p = _flight(tmp_path / "px4.tlog", lambda s: (6 if s < 5 else 3) << 16, autopilot=PX4, seconds=8)
    ds = import_tlog(p, ["SET_ATTITUDE_TARGET.pitch"], ["ATTITUDE.pitch"], split_on_mode=True, min_duration=0.5)
    assert [s["mode"] for s in ds.metadata["segments"]] == ["offboard", "posctl"]


def test_rate_memory_bound(guided, tmp_path, capsys):
    t0 = time.perf_counter()
    with pytest.raises(DataError) as e:
        import_tlog(guided, ["SET_ATTITUDE_TARGET.pitch"], ["ATTITUDE.pitch"], rate_hz=1e7)
    assert "--rate 1e+07 Hz is above 1e+06 Hz: log time stamps are whole microseconds" in str(e.value)
    assert time.perf_counter() - t0 < 30  # refused before anything is allocated
    # the CLI reports it as an error, not a MemoryError traceback
    rc = main(["import-tlog", str(guided), "--input", "SET_ATTITUDE_TARGET.pitch", "--output", "ATTITUDE.pitch",
               "--rate", "1e9", "-o", str(tmp_path / "x.npz")])
    assert rc == 2 and "--rate 1e+09 Hz is above 1e+06 Hz" in capsys.readouterr().err


def test_grid_size_limit(monkeypatch, guided):
    import ddpc_codegen.logs.resample as rs

    monkeypatch.setattr(rs, "MAX_GRID_SAMPLES", 100_000)
    with pytest.raises(DataError) as e:
        import_tlog(guided, ["SET_ATTITUDE_TARGET.pitch"], ["ATTITUDE.pitch"], rate_hz=20_000)
    assert ("--rate 20000 Hz over 10.0 s of copter.tlog would make 2e+05 grid samples (~0.00447 GiB for 2 channels), "
            "above the limit of 1e+05; use the controller rate") in str(e.value)
    assert MAX_GRID_SAMPLES == 50_000_000


def test_crc_drop_names_the_message(guided, tmp_path):
    data = bytearray(guided.read_bytes())
    # the first VFR_HUD packet (msgid 74): flip a payload byte, the CRC no longer matches
    pos = 0
    while True:
        if data[pos + 8] == 0xFD and data[pos + 15] == 74:
            break
        pos += 8 + 12 + data[pos + 9]
    data[pos + 8 + 10 + 1] ^= 0xFF
    p = tmp_path / "crc.tlog"
    p.write_bytes(bytes(data))
    with pytest.warns(LogImportWarning, match=r"crc.tlog: dropped 1 packet\(s\) failing the MAVLink CRC/decode "
                                              r"\(VFR_HUD x1\): VFR_HUD at offset \d+, 0.000 s"):
        import_tlog(p, ["SET_ATTITUDE_TARGET.pitch"], ["VFR_HUD.heading"])
