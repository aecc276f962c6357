"""PX4 ULog -> IODataset: round trip on logs written by tests/logs/ulog_writer.py, bad logs."""

from __future__ import annotations

import json

import numpy as np
import pytest
from pyulog import ULog
from ulog_writer import SyntheticFlight, ULogWriter, write_ulog

from ddpc_codegen import IODataset
from ddpc_codegen.errors import DataError
from ddpc_codegen.logs import LogImportWarning, import_ulog

pytestmark = pytest.mark.filterwarnings("ignore::ddpc_codegen.logs.LogImportWarning")

F32 = 2e-6  # values pass through float32 in the log (and a quaternion for angles)


@pytest.fixture(scope="module")
def flight():
    return SyntheticFlight(seed=0)


@pytest.fixture(scope="module")
def ulg(flight, tmp_path_factory):
    return write_ulog(tmp_path_factory.mktemp("ulog") / "flight.ulg", flight.topics())


def _grid(ds, i=0):
    """Grid times (µs since boot) of trajectory i, from the recorded provenance."""
    seg = ds.metadata["segments"][i]
    t0 = SyntheticFlight.start_us + round(seg["t_start_s"] * 1e6)
    return t0 + np.arange(ds.lengths[i]) * round(ds.dt * 1e6)


def test_writer_follows_the_format_pyulog_reads_it(ulg):
    log = ULog(str(ulg))
    assert not log.file_corruption
    assert log.start_timestamp == SyntheticFlight.start_us
    assert log.msg_info_dict["sys_name"] == "PX4"
    assert log.initial_parameters == {"MPC_THR_HOVER": 0.5, "SDLOG_PROFILE": 1}
    assert [m.message for m in log.logged_messages] == ["[commander] Armed by external command"]
    att = log.get_dataset("vehicle_attitude")
    assert att.data["timestamp"][0] == SyntheticFlight.t0 and len(att.data["timestamp"]) == 2501
    assert "_padding0" not in att.data  # trailing padding dropped, as in PX4 logs


def test_known_signals_come_back_exactly(flight, ulg):
    ds = import_ulog(ulg, preset="pogox-flying", rate_hz=200)
    assert ds.input_names == ("z_ref", "pitch_ref") and ds.output_names == ("z", "pitch")
    assert ds.input_units == ("m", "rad") and ds.output_units == ("m", "rad")
    assert ds.dt == 0.005 and ds.n_trajectories == 1 and ds.lengths == (2001,)  # 2 s .. 12 s inclusive
    g = _grid(ds)
    u, y = ds.u[0], ds.y[0]
    # setpoints: zero-order hold of what was logged -- exact (position is float32 in the log)
    np.testing.assert_array_equal(u[:, 0], flight.z_ref(g).astype(np.float32))
    np.testing.assert_allclose(u[:, 1], flight.pitch_ref(g), atol=F32)
    # states: linear interpolation of piecewise-linear signals -- exact up to float32
    np.testing.assert_allclose(y[:, 0], flight.z(g), atol=F32)
    np.testing.assert_allclose(y[:, 1], flight.pitch(g), atol=F32)
    md = ds.metadata
    assert md["source_format"] == "ulog" and md["files"][0]["name"] == "flight.ulg"
    assert md["files"][0]["topics"] == ["trajectory_setpoint", "vehicle_attitude", "vehicle_attitude_setpoint",
                                        "vehicle_local_position"]
    assert md["segments"] == [{"file": 0, "file_name": "flight.ulg", "t_start_s": 1.0, "t_end_s": 11.0,
                               "samples": 2001, "mode": ""}]
    assert [c["rule"] for c in md["inputs"]] == ["hold", "hold"]
    assert md["outputs"][1]["derivation"] == "pitch of Euler ZYX(q[0..3])"
    assert "zero-order hold" in md["resampling"]


def test_dataset_save_load_keeps_provenance(ulg, tmp_path):
    ds = import_ulog(ulg, preset="pogox-flying")
    back = IODataset.load(ds.save(tmp_path / "data.npz"))
    np.testing.assert_array_equal(back.u[0], ds.u[0])
    assert back.metadata == json.loads(json.dumps(ds.metadata))
    assert back.metadata["files"][0]["sha256"] == ds.metadata["files"][0]["sha256"]


def test_custom_channels_raw_fields_units_and_unwrapped_yaw(flight, ulg):
    ds = import_ulog(
        ulg,
        inputs=["vehicle_attitude_setpoint.thrust_body[2]_up", "trajectory_setpoint.position[2]"],
        outputs=["yaw=vehicle_attitude.yaw", "vehicle_attitude.q[0]", "h=vehicle_local_position.z_up:cm"],
        output_rule="linear",
    )
    assert ds.input_names == ("thrust_body2_ref", "position2_ref")
    assert ds.output_names == ("yaw", "q0", "h") and ds.output_units == ("rad", "", "cm")
    g = _grid(ds)
    np.testing.assert_allclose(ds.u[0][:, 0], 0.55, atol=1e-7)
    np.testing.assert_array_equal(ds.u[0][:, 1], -flight.z_ref(g).astype(np.float32))
    # yaw ramps through +π: unwrapped, it stays one straight line (no invented spin)
    assert ds.y[0][:, 0].max() > np.pi
    np.testing.assert_allclose(ds.y[0][:, 0], flight.yaw(g), atol=F32)


def test_offboard_only_and_split_on_mode(ulg):
    ds = import_ulog(ulg, preset="pogox-flying", offboard_only=True)
    segs = [(s["t_start_s"], s["t_end_s"], s["samples"], s["mode"]) for s in ds.metadata["segments"]]
    # offboard 2..7 s and 9..12 s since boot (log start at 1 s)
    assert segs == [(1.0, 5.995, 1000, "offboard"), (8.0, 11.0, 601, "offboard")]
    ds = import_ulog(ulg, preset="pogox-flying", split_on_mode=True)
    assert [s["mode"] for s in ds.metadata["segments"]] == ["offboard", "posctl", "offboard"]
    # the three pieces tile 2..12 s (2001 grid points); the grid restarts at each switch
    assert ds.lengths == (1000, 400, 601)
    ds = import_ulog(ulg, preset="pogox-flying", armed_only=True, time_range=(3.0, 6.0))
    assert ds.metadata["segments"][0]["t_start_s"] == 3.0 and ds.metadata["segments"][0]["t_end_s"] == 6.0


def test_several_files_and_instances(flight, tmp_path):
    topics = flight.topics()
    lp = topics["vehicle_local_position"]
    topics["vehicle_local_position@1"] = dict(lp, z=lp["z"] - 1.0)  # a second estimator, 1 m higher
    a = write_ulog(tmp_path / "a.ulg", topics)
    b = write_ulog(tmp_path / "b.ulg", flight.topics())
    ds = import_ulog(a, ["trajectory_setpoint.z_up"], ["vehicle_local_position@1.z_up"])
    np.testing.assert_allclose(ds.y[0][:, 0], flight.z(_grid(ds)) + 1.0, atol=F32)
    with pytest.raises(DataError, match=r"has no instance 1 in .*b.ulg; instances: \[0\]"):
        import_ulog([a, b], ["trajectory_setpoint.z_up"], ["vehicle_local_position@1.z_up"])
    ds = import_ulog([a, b], preset="pogox-flying", offboard_only=True)
    assert ds.n_trajectories == 4
    assert [s["file_name"] for s in ds.metadata["segments"]] == ["a.ulg", "a.ulg", "b.ulg", "b.ulg"]
    assert [f["name"] for f in ds.metadata["files"]] == ["a.ulg", "b.ulg"]


def test_gap_splits_with_warning(flight, tmp_path):
    topics = flight.topics()
    att = topics["vehicle_attitude"]
    keep = (att["timestamp"] < 5_000_000) | (att["timestamp"] > 5_500_000)
    topics["vehicle_attitude"] = {k: v[keep] for k, v in att.items()}
    p = write_ulog(tmp_path / "gap.ulg", topics)
    with pytest.warns(LogImportWarning, match=r"vehicle_attitude.pitch: 1 gap\(s\) without samples, split there: 3.996 s..4.504 s"):
        ds = import_ulog(p, preset="pogox-flying")
    # last sample before the gap at 3.996 s, first after at 4.504 s (since log start)
    assert [(s["t_start_s"], s["t_end_s"]) for s in ds.metadata["segments"]] == [(1.0, 3.995), (4.504, 10.999)]
    np.testing.assert_allclose(ds.y[1][:, 1], flight.pitch(_grid(ds, 1)), atol=F32)  # nothing bridged
    assert any("gap" in w for w in ds.metadata["warnings"])


# ------------------------------------------------------------------ bad logs
def test_missing_topic(flight, tmp_path):
    topics = flight.topics()
    del topics["vehicle_attitude"]
    p = write_ulog(tmp_path / "no_att.ulg", topics)
    with pytest.raises(DataError, match=r"topic 'vehicle_attitude' is not in the log \(.*no_att.ulg\); logged topics: "
                                        r"trajectory_setpoint, vehicle_attitude_setpoint"):
        import_ulog(p, preset="pogox-flying")


def test_topic_defined_but_never_logged(flight, tmp_path):
    w = ULogWriter(SyntheticFlight.start_us)
    w.add_px4_format("vehicle_attitude")
    mid = w.add_subscription("trajectory_setpoint")
    w.add_series(mid, [2_000_000, 2_020_000], position=np.zeros((2, 3)))
    p = w.write(tmp_path / "empty.ulg")
    with pytest.raises(DataError, match="topic 'vehicle_attitude' is defined but has no logged samples"):
        import_ulog(p, ["trajectory_setpoint.z_up"], ["vehicle_attitude.pitch"])


def test_missing_field(ulg):
    with pytest.raises(DataError, match=r"field 'height' not found in topic 'vehicle_local_position' of .*flight.ulg; "
                                        r"fields: .*\bz\b.*; derived: <field>_up"):
        import_ulog(ulg, ["trajectory_setpoint.z_up"], ["vehicle_local_position.height"])


def test_too_short_segments(ulg):
    with pytest.raises(DataError, match=r"no usable segment in .*flight.ulg: dropped 2 segment\(s\) shorter than "
                                        r"min_duration=10 s .*: 1.000 s..5.995 s \(1000 samples\), 8.000 s..11.000 s \(601 samples\)"):
        import_ulog(ulg, preset="pogox-flying", offboard_only=True, min_duration=10)
    with pytest.warns(LogImportWarning, match=r"dropped 1 segment\(s\) shorter than min_duration=4 s"):
        ds = import_ulog(ulg, preset="pogox-flying", offboard_only=True, min_duration=4)
    assert ds.n_trajectories == 1


def test_non_monotonic_timestamps(flight, tmp_path):
    topics = flight.topics()
    t = topics["vehicle_attitude"]["timestamp"].copy()
    t[1000] = t[1000] - 10_000  # a sample stamped 10 ms in the past at 6.0 s since boot
    topics["vehicle_attitude"]["timestamp"] = t
    p = write_ulog(tmp_path / "backwards.ulg", topics)
    with pytest.raises(DataError, match=r"backwards.ulg:vehicle_attitude.pitch: timestamps go backwards: "
                                        r"4.996 s -> 4.990 s \(samples 999 -> 1000\)"):
        import_ulog(p, preset="pogox-flying")
    # cropping to a clean part is the documented way out
    ds = import_ulog(p, preset="pogox-flying", time_range=(1.0, 4.9))
    assert ds.n_samples > 0


def test_nan_samples_dropped_with_warning_or_error(flight, tmp_path):
    topics = flight.topics()
    ts = topics["trajectory_setpoint"]
    bad = (ts["timestamp"] >= 4_000_000) & (ts["timestamp"] < 4_100_000)
    ts["position"][bad, 2] = np.nan
    p = write_ulog(tmp_path / "nan.ulg", topics)
    with pytest.warns(LogImportWarning, match=r"nan.ulg:trajectory_setpoint.z_up: dropped 5 NaN/inf sample\(s\) at "
                                              r"3.000 s..3.080 s \(5 samples\)"):
        ds = import_ulog(p, preset="pogox-flying")
    assert np.isfinite(ds.u[0]).all()
    with pytest.raises(DataError, match=r"trajectory_setpoint.z_up: 5 NaN/inf value\(s\) at 3.000 s..3.080 s"):
        import_ulog(p, preset="pogox-flying", on_nan="error")
    # a field PX4 leaves NaN all flight (velocity not commanded) is not silently filled
    with pytest.raises(DataError, match=r"trajectory_setpoint.vz: every sample is NaN/inf"):
        import_ulog(p, ["trajectory_setpoint.vz"], ["vehicle_local_position.z_up"])


def test_mode_filter_errors(flight, tmp_path):
    topics = flight.topics()
    status = topics.pop("vehicle_status")
    p = write_ulog(tmp_path / "nostatus.ulg", topics)
    with pytest.raises(DataError, match="--offboard-only needs topic vehicle_status .*: topic 'vehicle_status' is not in the log"):
        import_ulog(p, preset="pogox-flying", offboard_only=True)
    topics["vehicle_status"] = dict(status, nav_state=np.full(status["nav_state"].size, 2))
    p = write_ulog(tmp_path / "posctl.ulg", topics)
    with pytest.raises(DataError, match=r"never is in offboard mode \(1.000 s..11.000 s; modes seen: posctl\)"):
        import_ulog(p, preset="pogox-flying", offboard_only=True)


def test_not_a_ulog_and_bad_arguments(ulg, tmp_path):
    junk = tmp_path / "junk.ulg"
    junk.write_bytes(b"this is not a ulog file at all")
    with pytest.raises(DataError, match="junk.ulg: not a readable ULog file"):
        import_ulog(junk, preset="pogox-flying")
    with pytest.raises(DataError, match="does not exist"):
        import_ulog(tmp_path / "nope.ulg", preset="pogox-flying")
    with pytest.raises(DataError, match="unknown ULog preset 'pogo'; presets: attitude, pogox-flying, position"):
        import_ulog(ulg, preset="pogo")
    with pytest.raises(DataError, match="channel name 'pitch' is used twice"):
        import_ulog(ulg, ["vehicle_attitude_setpoint.pitch"], ["vehicle_attitude.pitch", "pitch=vehicle_attitude.roll"])
    with pytest.raises(DataError, match="need at least one input and one output"):
        import_ulog(ulg, ["vehicle_attitude_setpoint.pitch"], [])


# ------------------------------------------------------------------ attitude off-board (what ddpc-bridge flies)
PX4_SIH = __import__("pathlib").Path(__file__).parent / "data" / "px4_sih_offboard_attitude.ulg"  # trim_ulog.py


def test_a_real_px4_attitude_offboard_log_imports_with_its_preset():
    # PX4 SITL (SIH) flown by ddpc-bridge (passthrough, SET_ATTITUDE_TARGET): PX4 logs the attitude
    # and thrust it was given (vehicle_attitude_setpoint, 20 Hz here) and the state it reached.
    ds = import_ulog(PX4_SIH, preset="px4-offboard-attitude", offboard_only=True)
    assert ds.input_names == ("roll_ref", "pitch_ref", "yaw_ref", "thrust_ref")
    assert ds.output_names == ("z", "roll", "pitch", "yaw") and ds.n_trajectories == 1
    log = ULog(str(PX4_SIH))
    st = log.get_dataset("vehicle_status").data
    t_off = int(st["timestamp"][np.argmax(st["nav_state"] == 14)])     # PX4's own switch to offboard
    seg = ds.metadata["segments"][0]
    assert log.start_timestamp + seg["t_start_s"] * 1e6 == pytest.approx(t_off, abs=5000)
    grid = log.start_timestamp + round(seg["t_start_s"] * 1e6) + np.arange(ds.lengths[0]) * 5000
    # Against the raw samples: setpoints held (the newest at or before each grid time), height interpolated.
    sp = log.get_dataset("vehicle_attitude_setpoint").data
    i = np.searchsorted(sp["timestamp"], grid, side="right") - 1
    np.testing.assert_allclose(ds.u[0][:, 3], -sp["thrust_body[2]"][i], atol=F32)
    lp = log.get_dataset("vehicle_local_position").data
    np.testing.assert_allclose(ds.y[0][:, 0], -np.interp(grid, lp["timestamp"], lp["z"]), atol=1e-5)


def test_a_preset_reading_trajectory_setpoint_is_refused_on_attitude_offboard_with_advice(flight, tmp_path):
    with pytest.raises(DataError, match=r"PX4 flew attitude off-board here .* no trajectory_setpoint.*ddpc-bridge "
                                        r"--log flight.npz.*--preset px4-offboard-attitude"):
        import_ulog(PX4_SIH, preset="pogox-flying", offboard_only=True)
    # Position off-board (or no offboard_control_mode logged): trajectory_setpoint is there and is read.
    topics = flight.topics()
    t = topics["vehicle_status"]["timestamp"]
    for mode, refused in (({"position": True}, False), ({"attitude": True}, True)):
        topics["offboard_control_mode"] = {"timestamp": t, **{k: np.full(t.size, v) for k, v in mode.items()}}
        p = write_ulog(tmp_path / f"{'att' if refused else 'pos'}.ulg", topics)
        if refused:
            with pytest.raises(DataError, match="attitude off-board"):
                import_ulog(p, preset="pogox-flying")
        else:
            assert import_ulog(p, preset="pogox-flying").n_trajectories == 1
