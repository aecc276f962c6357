"""The two estimation setups ``make sitl-demo`` flies each autopilot in (:data:`SETUPS`).

* ``outdoor``: the autopilot's EKF on its own simulated sensors (GPS, barometer, magnetometer), as a vehicle
  flies outdoors; the bridge steers on that estimate. Its height is tens to hundreds of mm off the truth on
  PX4 SIH, so the true-height figures there say what the estimator allows, not what the steering does.
* ``lab``: a motion capture (:class:`~ddpc_codegen.testbed.mocap.MocapStandIn`, from the SITL's truth) as a
  lab flies. ArduCopter's EKF3 fuses it as its position, height and yaw source (the lab parameters of
  :func:`~ddpc_codegen.testbed.mocap_params.lab_params`, GPS off; the stand-in's link, SERIAL1 (:func:`second_link`),
  declared fast enough that EKF3 dates its poses right) and the bridge steers on that estimate;
  the shared PX4 build has no EKF2 external vision, so PX4's EKF keeps its own sensors and the bridge steers
  on the poses the stand-in forwards to it (``--position-source mocap``), as a lab's companion would. Either
  way the height the loop measures is within a few mm of the truth: the true-height figures judge the steering.

:func:`flown_setup` starts the stream around a running SITL and yields the SITL as the flights see it (its
``bridge_args`` go on every ``ddpc-bridge`` command line, :func:`~ddpc_codegen.testbed.sitl_flight.bridge_command`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict
from typing import Any

from ddpc_codegen.testbed.mocap import MocapConfig, MocapStandIn
from ddpc_codegen.testbed.mocap_params import lab_params
from ddpc_codegen.testbed.sitl import Sitl

__all__ = ["SETUPS", "LAB_SOURCE", "MOCAP_PORT", "SetupSitl", "setup_params", "flown_setup", "describe_setup",
           "setup_folder", "second_link"]

SETUPS = ("outdoor", "lab")
# The lab's position source per autopilot: its EKF fused on the mocap ("autopilot"), or the mocap itself where the
# SITL build cannot fuse it (PX4 here: CONFIG_EKF2_EXTERNAL_VISION=n).
LAB_SOURCE = {"ardupilot": "autopilot", "px4": "mocap"}
MOCAP_PORT = 14600  # the bridge's mocap link inside the run's private network namespace
_ESTIMATOR = {
    ("ardupilot", "outdoor"): "ArduCopter EKF3 on its GPS, barometer and compass",
    ("px4", "outdoor"): "PX4 EKF2 on its GPS, barometer and magnetometer",
    ("ardupilot", "lab"): "ArduCopter EKF3 on the motion capture (ExternalNav position, height and yaw; no GPS)",
    ("px4", "lab"): "the motion capture itself (--position-source mocap: this PX4 build's EKF2 fuses no external "
                    "vision, its EKF flies on its own sensors beside)",
}


def second_link(sitl: Sitl) -> Sitl:
    """A view of the running ``sitl`` whose ``url`` is its second MAVLink link (the bridge holds the
    first): ArduCopter's SERIAL1 TCP server (first port + 2), PX4's GCS link (it sends to UDP 14550).
    Same process: :meth:`Sitl.connect` on it checks the same SITL is alive; never stop the view."""
    if sitl.autopilot == "ardupilot":
        host, _, port = sitl.url[len("tcp:"):].rpartition(":")
        return dataclasses.replace(sitl, url=f"tcp:{host}:{int(port) + 2}")
    return dataclasses.replace(sitl, url="udpin:127.0.0.1:14550")


class SetupSitl:
    """A running SITL as one setup's flights see it: every attribute is the SITL's, plus ``bridge_args`` (the
    setup's ``ddpc-bridge`` arguments) and ``mocap`` (its stream, None without). Never stops the SITL."""

    def __init__(self, sitl: Any, bridge_args: tuple[str, ...] = (), mocap: MocapStandIn | None = None) -> None:
        self._sitl = sitl
        self.bridge_args = tuple(bridge_args)
        self.mocap = mocap

    def __getattr__(self, name: str) -> Any:
        return getattr(self._sitl, name)


def setup_params(autopilot: str, setup: str, base: dict[str, float], config: MocapConfig | None = None) -> dict:
    """The SITL's start parameters of ``setup``: ``base`` (the demo's own), plus the lab set where the autopilot
    fuses the mocap (ArduCopter; they take effect only at boot).

    Raises:
        ValueError: unknown setup.
    """
    if setup not in SETUPS:
        raise ValueError(f"unknown setup {setup!r}; choose from {SETUPS}")
    if setup == "lab" and LAB_SOURCE[autopilot] == "autopilot":
        return {**base, **lab_params(autopilot, config)}
    return dict(base)


@contextmanager
def flown_setup(sitl: Any, autopilot: str, setup: str, config: MocapConfig | None = None,
                measure_on_mocap: bool = False) -> Iterator[SetupSitl]:
    """Around a running ``sitl`` started with :func:`setup_params`: outdoor as it is; lab with the mocap stand-in
    on its second link (sent to the autopilot, and forwarded to the bridge's ``--mocap`` where the bridge steers
    on it: PX4, or ``measure_on_mocap``), stopped at the end. Yields the SITL as the flights see it; ``.mocap`` is
    the stand-in (None outdoors)."""
    if setup == "outdoor":
        yield SetupSitl(sitl)
        return
    from pymavlink import mavutil  # optional: the SITL harness only

    fused = LAB_SOURCE[autopilot] == "autopilot"  # the autopilot's EKF fuses the poses
    on_mocap = measure_on_mocap or not fused
    sitl.connect(timeout=90).close()  # booted: ArduCopter waits for a client on its first link before the second opens
    link = second_link(sitl).connect(timeout=30)
    fwd = (mavutil.mavlink_connection(f"udpout:127.0.0.1:{MOCAP_PORT}", source_system=1, source_component=197)
           if on_mocap else None)
    # ArduCopter fuses it: its origin set from the stream (no GPS); PX4 only forwards it (its EKF keeps its own)
    mocap = MocapStandIn(link, autopilot, config or MocapConfig(seed=1), set_origin=fused, forward=fwd)
    mocap.start()
    try:
        yield SetupSitl(sitl, ("--mocap", f"udpin:127.0.0.1:{MOCAP_PORT}", "--position-source", "mocap")
                        if on_mocap else (), mocap)
    finally:
        mocap.stop()
        for c in (link, fwd):
            if c is not None:
                c.close()


def describe_setup(autopilot: str, setup: str, mocap: MocapStandIn | None = None) -> dict:
    """The report's ``setup``: its name, what the loop measures the height with (``position_source``, the
    ``estimator`` in words) and, in the lab, the stream's settings and counts."""
    out: dict = {"name": setup, "position_source": LAB_SOURCE[autopilot] if setup == "lab" else "autopilot",
                 "estimator": _ESTIMATOR[(autopilot, setup)]}
    if mocap is not None:
        out["mocap"] = {**asdict(mocap.config), "sent": mocap.stats.sent, "skipped": mocap.stats.skipped,
                        "errors": list(mocap.stats.errors)}
    return out


def setup_folder(autopilot: str, setup: str) -> str:
    """The folder (under the report's) of one autopilot's flights in ``setup``: ``sitl_<autopilot>`` outdoors (as
    before the lab existed), ``sitl_<autopilot>_lab`` in the lab."""
    return f"sitl_{autopilot}" + ("" if setup == "outdoor" else f"_{setup}")
