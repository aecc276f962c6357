"""Know the vehicle before engaging: which autopilot answers, its parameters, its thrust semantics.

Run once, after the first heartbeat and before the tick loop sends any mode command or setpoint:

* the heartbeat's ``autopilot`` field must match ``--autopilot`` -- PX4's OFFBOARD (custom mode 6)
  is RTL on ArduCopter, so a mismatch is refused before anything is sent;
* parameters are read with PARAM_REQUEST_READ (retried): the hover thrust (PX4
  ``MPC_THR_HOVER``, ArduPilot ``MOT_THST_HOVER``), PX4's ``COM_OF_LOSS_T``, ArduPilot's
  ``GUID_OPTIONS`` (bit 3: SET_ATTITUDE_TARGET.thrust is a thrust, else a climb rate). PX4 sends
  integer parameters bytewise (the float's bits are the int32), ArduPilot as float values;
* ``--guid-options`` is accepted only when it agrees with the vehicle, or with ``force``;
* ``--thrust-min`` / ``--thrust-max`` must bracket the hover thrust the vehicle reports
  (:func:`check_vehicle_thrust`; refused with :class:`EnvelopeRefusal`, exit 2, before arming).

Both SITLs answer the parameter reads within a fraction of a second of the first heartbeat.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

import numpy as np

from ddpc_codegen.robot.controller_config import ControllerConfig

from firmware_bridge.path_checks import PathRefused, check_model_hover, check_thrust_limits
from firmware_bridge.profiles import MAV_AUTOPILOT_ARDUPILOTMEGA, MAV_AUTOPILOT_PX4, Profile

__all__ = [
    "AUTOPILOT_NAMES",
    "PreflightError",
    "EnvelopeRefusal",
    "check_vehicle_thrust",
    "VehicleInfo",
    "autopilot_name",
    "check_autopilot",
    "decode_param_value",
    "params_to_read",
    "resolve_guid_options",
    "check_trajectory_bounds",
    "check_trajectory_extent",
    "trajectory_rate_warning",
    "check_solver_loop",
]

AUTOPILOT_NAMES = {0: "generic", 3: "ArduPilot", 8: "none (a GCS or companion)", 12: "PX4"}
_INT_TYPES = {1: "<B", 2: "<b", 3: "<H", 4: "<h", 5: "<I", 6: "<i"}  # MAV_PARAM_TYPE_UINT8 .. INT32


class PreflightError(RuntimeError):
    """The vehicle is not what the bridge was told, or a parameter it needs could not be read."""


class EnvelopeRefusal(PreflightError):
    """A setting that would fly outside the envelope on this vehicle (a configuration error: exit 2)."""


@dataclass
class VehicleInfo:
    """What the bridge knows about the vehicle before its first commanded tick.

    Attributes:
        autopilot: HEARTBEAT.autopilot (3 ArduPilot, 12 PX4); vehicle_type: HEARTBEAT.type.
        params: parameter values read [their own units].
        hover_thrust: the autopilot's hover thrust estimate [0..1] (None if not read).
    """

    autopilot: int
    vehicle_type: int
    params: dict[str, float] = field(default_factory=dict)
    hover_thrust: float | None = None


def autopilot_name(autopilot: int) -> str:
    return AUTOPILOT_NAMES.get(int(autopilot), f"autopilot id {autopilot}")


def check_autopilot(autopilot: int, profile: Profile) -> None:
    """Refuse a vehicle whose heartbeat names another autopilot than the profile (no mode command sent)."""
    if int(autopilot) != profile.autopilot:
        flag = {MAV_AUTOPILOT_PX4: "px4", MAV_AUTOPILOT_ARDUPILOTMEGA: "ardupilot"}.get(int(autopilot))
        hint = f"; use --autopilot {flag}" if flag else ""
        raise PreflightError(f"the vehicle's heartbeat says {autopilot_name(autopilot)} (autopilot {autopilot}) "
                             f"but the bridge is set for {profile.name}: refusing before any mode command{hint}")


def decode_param_value(value: float, param_type: int, autopilot: int) -> float:
    """PARAM_VALUE.param_value as a number: PX4 packs integer types bytewise into the float."""
    fmt = _INT_TYPES.get(int(param_type))
    if fmt is None or int(autopilot) != MAV_AUTOPILOT_PX4:
        return float(value)
    raw = struct.pack("<f", value)
    return float(struct.unpack(fmt, raw[: struct.calcsize(fmt)])[0])


def params_to_read(profile: Profile) -> dict[str, bool]:
    """Parameter name -> required (the bridge cannot fly correctly without it)."""
    if profile.autopilot == MAV_AUTOPILOT_ARDUPILOTMEGA:
        return {"GUID_OPTIONS": True, "MOT_THST_HOVER": False, "GUID_TIMEOUT": False}
    return {"MPC_THR_HOVER": False, "COM_OF_LOSS_T": False}


def hover_param(profile: Profile) -> str:
    """The autopilot's hover-thrust parameter name."""
    return "MOT_THST_HOVER" if profile.autopilot == MAV_AUTOPILOT_ARDUPILOTMEGA else "MPC_THR_HOVER"


def check_vehicle_thrust(info: VehicleInfo, model_hover: float, thrust_min: float, thrust_max: float,
                         profile: Profile, ctrl: ControllerConfig | None = None) -> None:
    """``--thrust-min`` / ``--thrust-max`` around the vehicle's hover thrust (the controller model's when
    the vehicle did not say), and (``ctrl``: a flying controller's config) the model's hover thrust against the
    vehicle's (:func:`.path_checks.check_model_hover`), before anything arms.

    Raises:
        EnvelopeRefusal: one line naming the flag, the hover thrust (whose) and the value.
    """
    read = info.hover_thrust is not None and np.isfinite(info.hover_thrust)
    hover = float(info.hover_thrust) if read else model_hover
    source = f"the vehicle's {hover_param(profile)}" if read else "the controller model's; the vehicle did not say"
    try:
        check_thrust_limits(hover, thrust_min, thrust_max, source)
        if read and ctrl is not None and ctrl.mode == "flying":
            check_model_hover(model_hover, hover, ctrl.kp_z, ctrl.g, source)
    except PathRefused as e:
        raise EnvelopeRefusal(str(e)) from None


def resolve_guid_options(read: float | None, cli: int | None, force: bool) -> int:
    """The GUID_OPTIONS the bridge encodes thrust for.

    Args:
        read: the vehicle's value (None: not read). cli: ``--guid-options`` (None: not given).
        force: use ``cli`` even when it disagrees with the vehicle or the vehicle did not answer.

    Raises:
        PreflightError: not readable and not forced, or the CLI value disagrees without ``force``.
    """
    if cli is not None and (force or (read is not None and int(read) == int(cli))):
        return int(cli)
    if read is None:
        raise PreflightError("could not read GUID_OPTIONS from the vehicle (it decides whether "
                             "SET_ATTITUDE_TARGET.thrust is a thrust or a climb rate); give --guid-options N "
                             "with --force-guid-options to fly anyway")
    if cli is not None:
        raise PreflightError(f"--guid-options {cli} disagrees with the vehicle's GUID_OPTIONS {int(read)}; set the "
                             "parameter on the vehicle, or add --force-guid-options to encode for {cli} anyway"
                             .replace("{cli}", str(cli)))
    return int(read)


def check_trajectory_bounds(z: np.ndarray, z_min: float, z_max: float, what: str = "trajectory") -> None:
    """Refuse a trajectory whose heights z [m] leave the solver's z_ref bounds: every tick there
    would be a fallback (the solver fails on every tick the path spends outside them).

    Raises:
        ValueError: naming the trajectory's range and the bounds.
    """
    lo, hi = float(np.min(z)), float(np.max(z))
    if lo < z_min or hi > z_max:
        raise ValueError(f"the {what} spans z = {lo:.3f} .. {hi:.3f} m but the solver's z_ref bounds are "
                         f"[{z_min:g}, {z_max:g}] m: steering could never engage; regenerate the solver with "
                         "wider [bounds] or fly a trajectory inside them")


def check_trajectory_extent(trajectory, z_min: float, z_max: float) -> None:
    """:func:`check_trajectory_bounds` on a trajectory's own height range (its ``extent()``: every
    height it takes at any time, the spline's overshoot between a file's samples included).

    Raises:
        ValueError: naming the trajectory (its source, for a file), its range and the bounds.
    """
    lo, hi = trajectory.extent()["z"]
    source = getattr(trajectory, "source", None)
    check_trajectory_bounds(np.array([lo, hi]), z_min, z_max, f"trajectory {source}" if source else "trajectory")


# Seconds of a never-ending trajectory (time span to inf) that the rate check samples.
RATE_CHECK_SPAN = 600.0


def trajectory_rate_warning(trajectory, dz_max: float, rate_hz: float) -> str | None:
    """A warning when the trajectory's height moves faster than the solver may move z_ref
    (``dz_max`` [m per tick] at ``rate_hz``): the steered reference then lags the path by
    construction. Sampled at the tick rate over the trajectory's ``time_span()`` (the first
    :data:`RATE_CHECK_SPAN` s of an endless one). None when it fits or ``dz_max`` is unbounded.
    """
    if not np.isfinite(dz_max):
        return None
    t0, t1 = trajectory.time_span()
    t1 = min(t1, t0 + RATE_CHECK_SPAN)
    t = np.arange(t0, t1 + 0.5 / rate_hz, 1.0 / rate_hz)
    vz = float(np.max(np.abs(trajectory.sample(t)["vz"]))) if t.size else 0.0
    if vz <= dz_max * rate_hz * (1.0 + 1e-9):
        return None
    return (f"the trajectory climbs or sinks at up to {vz:.3f} m/s but the solver moves z_ref by at most "
            f"{dz_max:g} m per tick ({dz_max * rate_hz:.3f} m/s at {rate_hz:g} Hz): the steered reference "
            "lags the path there")


def check_solver_loop(manifest: dict, autopilot: str, thrust_field: str) -> str | None:
    """Refuse a solver fitted on another loop: its manifest's ``dataset`` records what the thrust
    field meant when the data were collected (a climb-rate loop and a thrust loop are different
    dynamics: the predictor would be wrong on every tick).

    Returns:
        a warning when the data came from another autopilot (allowed: e.g. simulator data) or were
        noisier than the solver's config was tuned for (``noise_warning``, written by codegen), else None.
    Raises:
        PreflightError: the thrust semantics differ.
    """
    ds = manifest.get("dataset") or {}
    had = ds.get("thrust_field")
    if had and had != thrust_field:
        raise PreflightError(
            f"the solver was fitted on data where SET_ATTITUDE_TARGET.thrust was a {had.replace('_', ' ')} "
            f"({ds.get('path', 'its dataset')}), but this vehicle reads it as a {thrust_field.replace('_', ' ')}; "
            "collect and generate again in this mode, or set GUID_OPTIONS as it was (bit 3 = thrust)")
    warnings = []
    src = ds.get("autopilot")
    if src and src != autopilot:
        warnings.append(f"the solver's data came from {src}, this vehicle is {autopilot}")
    if ds.get("noise_warning"):
        warnings.append(f"codegen said: {ds['noise_warning']}")
    return "; ".join(warnings) or None
