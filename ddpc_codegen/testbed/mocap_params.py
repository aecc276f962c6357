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

__all__ = ["lab_params", "ARDUPILOT_LAB", "ARDUPILOT_SITL_LINK", "EKF3_HALF_STEP_MS", "PX4_LAB", "EV_NOISE_FLOOR_M",
           "transport_allowance_ms", "px4_has_external_vision"]

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

# The stand-in's link on the ArduCopter SITL: its SERIAL1 TCP server (:func:`.sitl_setups.second_link`), declared
# at 12.5 Mbaud. ArduPilot dates each pose by its jitter correction, from the instant the bytes arrived minus their
# transmit time at the port's declared baud (10 bits a byte: the message and every byte still queued behind it).
# SERIAL1's default 57600 baud makes that 22 ms for one VISION_POSITION_ESTIMATE and up to 65 ms with a queue, on a
# loopback that takes ~0.1 ms: EKF3 took every pose for ~30 ms older than it was and its height ran that far ahead
# of the truth (7-25 mm RMS in moving flights, 1-4 mm after). Above 10 Mbaud the allowance is 0 (whole
# microseconds a byte). A real companion's port declares its real baud: there the transmit time is real.
ARDUPILOT_SITL_LINK: dict[str, float] = {"SERIAL1_BAUD": 12_500_000}
_VISION_POSITION_ESTIMATE_BYTES = 129  # MAVLink 2: 117 bytes of payload (with covariance) + 12 of framing


def transport_allowance_ms(baud: float, queued_bytes: int = 0) -> float:
    """What ArduPilot subtracts from a VISION_POSITION_ESTIMATE's arrival for its transmit time [ms] on a port
    declared at ``baud`` (ArduPilot's ``SERIALn_BAUD`` value: a code such as 57 or 921, or a rate above 2000), with
    ``queued_bytes`` more waiting behind it (its integer arithmetic: whole microseconds a byte)."""
    codes = {57: 57600, 115: 115200, 230: 230400, 460: 460800, 500: 500000, 921: 921600, 1500: 1500000,
             2000: 2000000}
    rate = int(codes.get(int(baud), baud))
    return (10_000_000 // rate) * (_VISION_POSITION_ESTIMATE_BYTES + queued_bytes) * 1e-3


# EKF3 dates every ExternalNav pose half its 10 ms filter step earlier than (arrival - VISO_DELAY_MS)
# (NavEKF3_core::writeExtNavData: "average intersampling delay"), meant for poses stamped on the filter's step. The
# stand-in's are stamped where they were measured: with VISO_DELAY_MS = its 5 ms latency, the estimate ran 6-8 ms
# ahead of the truth in moving flights (dataflash SIM2 vs XKF1 and the observer alike), 0 ms with 5 ms less.
EKF3_HALF_STEP_MS = 5.0


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
    set above plus the delay [ms] (the stream's latency; on ArduPilot less the half filter step EKF3 takes off
    itself, :data:`EKF3_HALF_STEP_MS`) and the noise floors [m, rad, m/s]; on ArduPilot the stand-in's SITL link
    too (:data:`ARDUPILOT_SITL_LINK`).

    Raises:
        ValueError: unknown autopilot.
    """
    c = config or MocapConfig()
    delay_ms = float(round(1e3 * c.latency_s))
    pos, att = max(c.pos_noise_m, EV_NOISE_FLOOR_M), max(c.att_noise_rad, EV_NOISE_FLOOR_M)
    vel = max(c.vel_noise_mps, EV_NOISE_FLOOR_M)
    odometry = c.message == "odometry"
    if autopilot == "ardupilot":
        p = {**ARDUPILOT_LAB, **ARDUPILOT_SITL_LINK}
        p.update({"VISO_DELAY_MS": max(0.0, delay_ms - EKF3_HALF_STEP_MS), "VISO_POS_M_NSE": pos, "VISO_YAW_M_NSE": att, "VISO_VEL_M_NSE": vel})
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
