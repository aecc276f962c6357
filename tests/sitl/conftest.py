"""The SITL tier runs on two pytest-xdist workers (``make test``: ``--dist loadgroup``): each test waits on a
real-time autopilot most of its wall time, so two at once halve the tier's wall time while the CPU stays
free enough for the bridge's 200 Hz loop (three at once made the climb-rate flight fall back under load).
The groups balance the measured durations (tests/durations.json): the two longest tests apart."""

from __future__ import annotations

import pytest

# ~550 s each on this 2-core machine (CI of 2026-12-05: group B alone was 685 s before this split):
# the PX4 flight, ArduCopter's climb-rate mode, the steering proxy's chain and the 4 s bridge stall | the rest
# (among them the proxy's real clients, ~61 s, which took the place of the 58 s pymavlink-only proxy flight)
_GROUP_A = ("test_sitl_from_the_ground.py::test_from_the_ground_to_steered_flight[px4]",
            "test_sitl_climb_rate.py::test_ardupilot_climb_rate_mode_collect_and_steer",
            "test_sitl_proxy_steer.py::test_an_app_is_collected_fitted_and_steered_on_the_motion_capture",
            "test_sitl_bridge_stall.py::test_a_4s_bridge_stall_mid_steer_resumes_within_the_rate_bound")


@pytest.hookimpl(tryfirst=True)  # before xdist's loadgroup reads the markers
def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        if "tests/sitl/" in item.nodeid:
            group = "sitl-a" if item.nodeid.endswith(_GROUP_A) else "sitl-b"
            item.add_marker(pytest.mark.xdist_group(group))
