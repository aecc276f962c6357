"""The parameters that make each autopilot fly on the motion-capture stand-in (:mod:`.mocap`) as a lab
would: the external pose as its horizontal position, height and yaw source, GPS off, the barometer kept
on board but not fused (ArduPilot's EKF3 has no switch for it outside its height-source choice).

The harness sets them when it starts the SITL (:meth:`~.sitl.Sitl.ardupilot` / :meth:`~.sitl.Sitl.px4`
``params=``): ArduPilot's ``VISO_TYPE`` and ``GPS1_TYPE`` take effect only at boot, and PX4's EKF2 picks its
aiding sources when it starts. The guide ``docs/guides/lab.md`` lists them for a real vehicle.
"""

from __future__ import annotations

from pathlib import Path

from ddpc_codegen.testbed.mocap import MocapConfig

__all__ = ["lab_params", "ARDUPILOT_LAB", "PX4_LAB", "EV_NOISE_FLOOR_M", "px4_has_external_vision"]

# ArduPilot EKF3: ExternalNav (6) for position, height and yaw; velocity too when ODOMETRY carries it.
ARDUPILOT_LAB: dict[str, float] = {
    "VISO_TYPE": 1,          # visual odometry over MAVLink (VISION_POSITION_ESTIMATE / ODOMETRY)
    "EK3_SRC1_POSXY": 6,     # ExternalNav
    "EK3_SRC1_POSZ": 6,
    "EK3_SRC1_YAW": 6,
    "EK3_SRC1_VELXY": 0,     # none: VISION_POSITION_ESTIMATE has no velocity (6 with ODOMETRY)
    "EK3_SRC1_VELZ": 0,
    "GPS1_TYPE": 0,          # indoors: no GPS
}

# PX4 EKF2: external vision for horizontal position, height (the height reference) and yaw.
PX4_LAB: dict[str, float] = {
    "EKF2_EV_CTRL": 11,      # bits: 1 horizontal position, 2 vertical position, 8 yaw (+4 velocity with ODOMETRY)
    "EKF2_HGT_REF": 3,       # vision
    "EKF2_GPS_CTRL": 0,      # indoors: no GPS
    "EKF2_BARO_CTRL": 0,     # a barometer indoors follows doors and air conditioning, not height
    "EKF2_MAG_TYPE": 5,      # none: the heading comes from the mocap (magnetometers err near steel)
    "EKF2_RNG_CTRL": 0,
    "EKF2_EV_NOISE_MD": 0,   # the noise the message reports, floored by EKF2_EVP_NOISE / EKF2_EVA_NOISE
    "EKF2_EV_QMIN": 0,
}

# The smallest position noise either EKF accepts [m] (PX4 EKF2_EVP_NOISE's minimum; ArduPilot's EKF3
# constrains the reported error to >= 0.01 m).
EV_NOISE_FLOOR_M = 0.01


def lab_params(autopilot: str, config: MocapConfig | None = None) -> dict[str, float]:
    """The lab set of ``autopilot`` ("ardupilot" or "px4") for the stream ``config`` describes: the fixed
    set above plus the delay [ms] (the stream's latency) and the noise floors [m, rad, m/s].

    Raises:
        ValueError: unknown autopilot.
    """
    c = config or MocapConfig()
    delay_ms = float(round(1e3 * c.latency_s))
    pos, att = max(c.pos_noise_m, EV_NOISE_FLOOR_M), max(c.att_noise_rad, EV_NOISE_FLOOR_M)
    vel = max(c.vel_noise_mps, EV_NOISE_FLOOR_M)
    odometry = c.message == "odometry"
    if autopilot == "ardupilot":
        p = dict(ARDUPILOT_LAB)
        p.update({"VISO_DELAY_MS": delay_ms, "VISO_POS_M_NSE": pos, "VISO_YAW_M_NSE": att, "VISO_VEL_M_NSE": vel})
        if odometry:
            p.update({"EK3_SRC1_VELXY": 6, "EK3_SRC1_VELZ": 6})
        return p
    if autopilot == "px4":
        p = dict(PX4_LAB)
        p.update({"EKF2_EV_DELAY": delay_ms, "EKF2_EVP_NOISE": pos, "EKF2_EVA_NOISE": att, "EKF2_EVV_NOISE": vel})
        if odometry:
            p["EKF2_EV_CTRL"] = 15
        return p
    raise ValueError(f"unknown autopilot {autopilot!r}; choose 'ardupilot' or 'px4'")


def px4_has_external_vision(folder: str | Path) -> bool:
    """Whether the PX4 build in ``folder`` (``bin/px4``) has EKF2's external-vision fusion: its parameter
    table then names EKF2_EV_CTRL (a build with ``CONFIG_EKF2_EXTERNAL_VISION=n`` has none of EKF2_EV_*)."""
    return b"EKF2_EV_CTRL\0" in (Path(folder) / "bin" / "px4").read_bytes()
