"""A user's own pymavlink app (:mod:`ddpc_codegen.testbed.proxy_app`) steered through ``ddpc-proxy`` on the real
PX4 SIH SITL in the lab setup, as ``make proxy-demo`` flies it, shorter: one collect flight through the proxy
(``--collect --dither``), ``ddpc-codegen codegen`` on it, then the helix flown directly (the app's own velocity and
acceleration feed-forward, on PX4's own estimate) and steered with the local preview, the proxy measuring on the
motion-capture stand-in (``--position-source mocap``), both judged on the simulator's true height. The app flies the
path as SET_POSITION_TARGET_GLOBAL_INT above sea level (``proxy_app --frame amsl``; ``make proxy-demo`` flies
LOCAL_NED): the proxy steers it in the local frame through the offset the vehicle's own reports give. Not above home:
this PX4 build flies MAV_FRAME_GLOBAL_RELATIVE_ALT_INT setpoints off by twice home's height above its origin (a
direct flight of the app tried so: 2.4 m RMS). Skipped without the SITL.

What it holds: the whole chain runs on a real autopilot (collect, fit, generate, steer), the steering engages once
and steers nearly every tick, nothing is dropped or reordered, and the steered flight's true height is at least
twice closer to the app's path than the app's own flight: this PX4 build's EKF (GPS and barometer) drifts off the
truth by more than the app's tracking error, and the proxy closes its loop on the lab's measurement. When the app
stops at the end of each flight, the proxy's last setpoint to the vehicle follows the app's last by less than one
app period plus one tick, and PX4's offboard-loss failsafe (timed by its CURRENT_MODE, sent on each change) fires
about 1 s after it with and without the proxy. The two flights' times are compared within 150 ms, not the issue's
30 ms: PX4's own time varies more than that from one flight to the next; the 30 ms are resolved by ``make
proxy-demo``'s repeated, interleaved trials (:mod:`ddpc_codegen.testbed.proxy_failsafe`, the proxy results page)."""

from __future__ import annotations

import numpy as np
import pytest

from ddpc_codegen.testbed.sitl import missing_reason, run_isolated

pytestmark = [pytest.mark.sitl, pytest.mark.slow, pytest.mark.realtime]


def test_an_app_is_collected_fitted_and_steered_on_the_motion_capture(tmp_path):
    why = missing_reason("px4")
    if why:
        pytest.skip(why)
    res = run_isolated("ddpc_codegen.testbed.proxy_demo:run",
                       {"autopilot": "px4", "out_dir": str(tmp_path), "paths": ["helix"], "duration": 15.0,
                        "collect_s": 40.0, "kinds": ["direct", "steer_local"], "proxy_death": False, "frame": "amsl"},
                       timeout=480)
    runs = res["paths"]["helix"]
    direct, steered = runs["direct"], runs["steer_local"]
    print(f"[proxy-steer] PX4 helix true height: direct {direct['rmse_z_truth_mm']:.1f} mm, steered (local preview, "
          f"on the mocap) {steered['rmse_z_truth_mm']:.1f} mm; the EKF's own error {direct['estimator_rms_mm']:.1f} "
          f"/ {steered['estimator_rms_mm']:.1f} mm")
    assert res["setup_detail"]["position_source"] == "mocap" and res["collect"]["mocap_offset_m"] is not None
    p = steered["proxy"]
    assert p["app_to_vehicle"]["dropped"] == 0 and p["app_to_vehicle"]["seq_gaps"] == 0
    st = p["steering"]
    # every tick from the engagement on (before it the app re-enters OFFBOARD after the last flight's failsafe)
    log = np.load(tmp_path / "helix_steer_local.ticks.npz")
    rows, steered_code = log["rows"], list(log["reasons"]).index("steered")
    since = rows[int(np.argmax(rows["engaged"])):]
    assert st["activations"] == 1 and st["steered"] == int(np.sum(since["reason"] == steered_code))
    assert st["frames"]["amsl"] > 0.9 * len(since) and res["app_frame"] == "amsl"
    assert st["steered"] > 0.95 * len(since), (st, len(since))
    assert steered["rmse_z_truth_mm"] < 0.5 * direct["rmse_z_truth_mm"]
    gone, alone = steered["app_stops"], direct["app_stops"]
    print(f"[proxy-steer] the app's end: the proxy's last setpoint {gone['proxy_last_out_s'] * 1e3:.1f} ms after the "
          f"app's; failsafe {alone['failsafe_s']} s direct, {gone['failsafe_s']} s steered "
          f"({gone['mode_before']} -> {gone['mode_after']}, timed by {gone['timed_by']})")
    assert gone["proxy_last_out_s"] < 0.02 + 0.02  # one app period + one tick (both 50 Hz)
    assert alone["failsafe_s"] is not None and gone["failsafe_s"] is not None and "CURRENT_MODE" in gone["timed_by"]
    assert 0.8 < alone["failsafe_s"] < 1.5 and 0.8 < gone["failsafe_s"] < 1.5  # COM_OF_LOSS_T: 1 s
    assert abs(gone["failsafe_s"] - alone["failsafe_s"]) < 0.15

