"""A user's own pymavlink app (:mod:`ddpc_codegen.testbed.proxy_app`) steered through ``ddpc-proxy`` on the real
PX4 SIH SITL in the lab setup, as ``make proxy-demo`` flies it, shorter: one collect flight through the proxy
(``--collect --dither``), ``ddpc-codegen codegen`` on it, then the helix flown directly (the app's own velocity and
acceleration feed-forward, on PX4's own estimate) and steered with the local preview, the proxy measuring on the
motion-capture stand-in (``--position-source mocap``), both judged on the simulator's true height. Skipped without
the SITL.

What it holds: the whole chain runs on a real autopilot (collect, fit, generate, steer), the steering engages once
and steers nearly every tick, nothing is dropped or reordered, and the steered flight's true height is at least
twice closer to the app's path than the app's own flight: this PX4 build's EKF (GPS and barometer) drifts off the
truth by more than the app's tracking error, and the proxy closes its loop on the lab's measurement."""

from __future__ import annotations

import pytest

from ddpc_codegen.testbed.sitl import missing_reason, run_isolated

pytestmark = [pytest.mark.sitl, pytest.mark.slow, pytest.mark.realtime]


def test_an_app_is_collected_fitted_and_steered_on_the_motion_capture(tmp_path):
    why = missing_reason("px4")
    if why:
        pytest.skip(why)
    res = run_isolated("ddpc_codegen.testbed.proxy_demo:run",
                       {"autopilot": "px4", "out_dir": str(tmp_path), "paths": ["helix"], "duration": 15.0,
                        "collect_s": 40.0, "kinds": ["direct", "steer_local"]}, timeout=480)
    runs = res["paths"]["helix"]
    direct, steered = runs["direct"], runs["steer_local"]
    print(f"[proxy-steer] PX4 helix true height: direct {direct['rmse_z_truth_mm']:.1f} mm, steered (local preview, "
          f"on the mocap) {steered['rmse_z_truth_mm']:.1f} mm; the EKF's own error {direct['estimator_rms_mm']:.1f} "
          f"/ {steered['estimator_rms_mm']:.1f} mm")
    assert res["setup_detail"]["position_source"] == "mocap" and res["collect"]["mocap_offset_m"] is not None
    p = steered["proxy"]
    assert p["app_to_vehicle"]["dropped"] == 0 and p["app_to_vehicle"]["seq_gaps"] == 0
    st = p["steering"]
    assert st["activations"] == 1 and st["steered"] > 0.9 * st["ticks"]
    assert steered["rmse_z_truth_mm"] < 0.5 * direct["rmse_z_truth_mm"]
