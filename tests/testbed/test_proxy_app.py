"""The demo app's paths (:mod:`ddpc_codegen.testbed.proxy_app`) and the demo's scoring (:mod:`.proxy_demo`) against
closed forms: velocity and acceleration by finite differences agree with each path's analytic derivatives, and a
flight that follows the declared heights exactly scores zero (played late by the delay where there is one)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from ddpc_codegen.testbed.proxy_app import PATHS, path_point
from ddpc_codegen.testbed.proxy_demo import _last_line, failsafe, score


def test_the_helix_derivatives_match_its_closed_form():
    t = 3.7
    p, v, a = path_point("helix", t)
    w, c = 0.5, 2 * np.pi / 12.0
    assert np.allclose(p, [2 * np.cos(w * t) - 2, 2 * np.sin(w * t), 0.6 - 0.6 * np.cos(c * t)])
    assert np.allclose(v, [-2 * w * np.sin(w * t), 2 * w * np.cos(w * t), 0.6 * c * np.sin(c * t)], atol=1e-6)
    assert np.allclose(a, [-2 * w * w * np.cos(w * t), -2 * w * w * np.sin(w * t), 0.6 * c * c * np.cos(c * t)],
                       atol=1e-4)


@pytest.mark.parametrize("name", sorted(PATHS))
def test_every_path_starts_near_its_origin_and_stays_flyable(name):
    t = np.arange(0.0, 60.0, 0.02)
    pts = np.array([path_point(name, s)[0] for s in t[::10]])
    vel = np.array([path_point(name, s)[1] for s in t[::10]])
    assert np.all(pts[:, 2] < 1.7) and np.all(pts[:, 2] > -0.5)  # heights: from 2 m above the ground at the 2.5 m base
    assert np.max(np.linalg.norm(vel, axis=1)) < 2.0  # m/s: within a copter's guided limits


class _Obs:
    """An observer whose truth and estimate are given functions of time."""

    def __init__(self, truth, est, hb=()):
        self.truth, self.est, self.hb, self.modes = truth, est, list(hb), []

    def mode_name(self, custom_mode):
        return {6 << 16: "OFFBOARD", (4 << 16) | (3 << 24): "LOITER"}[custom_mode]

    def heights(self, t):
        return self.truth(t), self.est(t)


def test_a_flight_on_the_declared_heights_scores_zero_and_a_bias_scores_itself(tmp_path):
    log = tmp_path / "app.jsonl"
    t0 = 1000.0
    rows = [{"t": t0 + k * 0.02, "tp": k * 0.02, "x": 0, "y": 0, "z": -(2 + np.sin(0.5 * k * 0.02))} for k in range(500)]
    log.write_text("".join(json.dumps(r) + "\n" for r in rows))
    want = lambda t: 2 + np.sin(0.5 * (t - t0))  # noqa: E731
    s = score(log, _Obs(want, lambda t: want(t) + 0.01))
    assert s["rmse_z_truth_mm"] == pytest.approx(0.0, abs=1e-9) and s["rmse_z_mm"] == pytest.approx(10.0)
    assert s["estimator_rms_mm"] == pytest.approx(10.0)
    late = score(log, _Obs(lambda t: want(t - 0.5), lambda t: want(t - 0.5)), delay=0.5)
    assert late["rmse_z_truth_mm"] == pytest.approx(0.0, abs=1e-9) and late["delay_s"] == 0.5
    shifted = score(log, _Obs(lambda t: want(t) + 0.3, want), ground=0.3)  # the truth's origin 0.3 m lower
    assert shifted["rmse_z_truth_mm"] == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize("argv", [["--kinds", "direct,bogus"], ["--autopilots", "ardupilot,betaflight"]])
def test_the_demo_refuses_unknown_kinds_and_autopilots_before_flying(capsys, argv):
    from ddpc_codegen.testbed.proxy_demo import main

    with pytest.raises(SystemExit) as e:
        main(argv)
    assert e.value.code == 2 and "--kinds from" in capsys.readouterr().err


def test_the_vehicles_reaction_to_the_apps_end_is_timed_from_its_last_setpoint(tmp_path):
    log, ticks = tmp_path / "app.jsonl", tmp_path / "ticks.npz"
    log.write_text("".join(json.dumps({"t": 100.0 + k * 0.02, "tp": k * 0.02, "x": 0, "y": 0, "z": -2}) + "\n"
                           for k in range(51)) + '{"t": 101.0')  # a line cut by the app's kill is not a setpoint
    np.savez(ticks, rows=np.array([(100.0 + k * 0.02 + 4e-4,) for k in range(51)], dtype=[("t", "<f8")]))
    off, loiter = 6 << 16, (4 << 16) | (3 << 24)
    hb = [(99.5, off, True), (100.5, off, True), (101.5, off, True), (102.5, loiter, True), (103.5, loiter, True)]
    f = failsafe(log, _Obs(None, None, hb), ticks)  # heartbeats only (1 Hz): timed to them
    assert f["failsafe_s"] == pytest.approx(1.5) and f["mode_before"] == "OFFBOARD" and f["mode_after"] == "LOITER"
    assert f["proxy_last_out_s"] == pytest.approx(4e-4) and f["timed_by"] == "heartbeats every 1000 ms"
    obs = _Obs(None, None, hb)  # PX4's CURRENT_MODE: every 0.5 s and on the change at 102.04 s
    obs.modes = [(99.6 + 0.5 * k, off) for k in range(5)] + [(102.04, loiter), (102.1, loiter)]
    f = failsafe(log, obs, ticks)
    assert f["failsafe_s"] == pytest.approx(1.04) and f["mode_after"] == "LOITER" and "CURRENT_MODE" in f["timed_by"]
    held = failsafe(log, _Obs(None, None, [h for h in hb if h[1] == off]))  # e.g. ArduCopter holding in GUIDED
    assert held["failsafe_s"] is None and held["mode_after"] is None and "proxy_last_out_s" not in held
    late = failsafe(log, _Obs(None, None, hb), since=101.7)
    assert late["failsafe_s"] == pytest.approx(0.8) and late["from"] == "proxy death"


def test_the_kill_watch_reads_only_the_growing_logs_last_line(tmp_path):
    log = tmp_path / "app.jsonl"
    assert _last_line(log) == ""  # not written yet
    log.write_text("".join(json.dumps({"t": k, "tp": k * 0.02, "pad": "x" * 80}) + "\n" for k in range(400)))
    assert json.loads(_last_line(log))["t"] == 399
    with log.open("a") as f:
        f.write('{"t": 400, "tp"')  # a line being written: not whole yet
    assert not _last_line(log).endswith("}")



def test_a_global_app_sends_its_local_point_as_latitude_longitude_and_height_above_home():
    """``--frame relative_alt``: the setpoint's great-circle distance and bearing from the anchored origin (haversine on
    the same sphere) are the local point's, within the degE7 integers' 1.1 cm; its alt is the height above home."""
    import socket

    from pymavlink.dialects.v20 import common

    from ddpc_codegen.testbed.proxy_app import MASKS, App

    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(5.0)
    try:
        app = App(f"udpout:127.0.0.1:{sock.getsockname()[1]}", None)
        lat0, lon0 = 47.3977418, 8.5455939
        app.anchor = (common.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, lat0, lon0, -0.7)  # home 0.7 m above the origin
        app.setpoint(np.array([3.0, -2.0, 2.5]), np.zeros(3), np.zeros(3), MASKS["vel"], 0.0)
        msg = common.MAVLink(None).parse_char(sock.recv(512))
    finally:
        sock.close()
    assert msg.get_type() == "SET_POSITION_TARGET_GLOBAL_INT"
    assert msg.coordinate_frame == common.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT and msg.type_mask == MASKS["vel"]
    p1, p2, dl = np.radians(lat0), np.radians(msg.lat_int * 1e-7), np.radians(msg.lon_int * 1e-7 - lon0)
    a = np.sin((p2 - p1) / 2) ** 2 + np.cos(p1) * np.cos(p2) * np.sin(dl / 2) ** 2
    dist = 2 * 6378137.0 * np.arcsin(np.sqrt(a))
    bearing = np.arctan2(np.sin(dl) * np.cos(p2), np.cos(p1) * np.sin(p2) - np.sin(p1) * np.cos(p2) * np.cos(dl))
    assert dist == pytest.approx(np.hypot(3.0, -2.0), abs=0.015)
    assert bearing == pytest.approx(np.arctan2(-2.0, 3.0), abs=0.01)
    assert msg.alt == pytest.approx(2.5 - 0.7, abs=1e-6)
