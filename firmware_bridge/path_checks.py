"""Every input that defines the flown path, checked *as a path* against the robot's envelope
(:class:`~ddpc_codegen.robot.profile.Envelope`) before anything connects or arms: inputs that pass each
key's own range check can still fly the vehicle into the ground (a prefilter gain of 0.001, a
feed-forward table of 20 m, a 63 km/s ellipse, a 1000 m step in a trajectory file, a PRBS of 1e308).

* the trajectory (profile ellipse, random, file): its largest speed and acceleration sampled at the
  control rate over its time span (an endless one: its first :data:`SPAN_CAP` s), its extent (every
  height it takes, the horizontal distance from its start);
* a hopper's apex height and target speed, and the distance it hops at that speed over ``--duration``;
* a prefilter: the references it would produce on that path (its gain, offset and lead applied) inside
  the envelope and its rate limits;
* a feed-forward table: the nominal path plus each row inside the envelope;
* collect's excitation: the nominal path plus or minus the amplitude inside the envelope, and a PRBS step
  (twice the amplitude in one tick) within the references' rate limits;
* ``--thrust-min`` / ``--thrust-max`` around the hover thrust (:func:`check_thrust_limits`, run again once the
  vehicle's own hover thrust is read), and the controller model's hover thrust against the vehicle's
  (:func:`check_model_hover`, once it is read).

A refusal is a :class:`PathRefused` (a ConfigError: exit 2) whose one line names the file or flag, the
limit and the value.
"""

from __future__ import annotations

import math

import numpy as np

from ddpc_codegen.errors import ConfigError
from ddpc_codegen.robot.controller_config import ControllerConfig
from ddpc_codegen.robot.profile import Envelope
from ddpc_codegen.robot.signals import REFERENCES
from ddpc_codegen.robot.trajectory import RandomSmoothTrajectory

from firmware_bridge.baseline_modes import load_feedforward, load_prefilter

__all__ = ["PathRefused", "SPAN_CAP", "path_times", "path_limits", "check_trajectory_path", "nominal_path",
           "check_references", "check_prefilter_path", "check_feedforward_path", "check_excitation", "check_hopping_path",
           "check_thrust_limits", "check_model_hover", "MAX_HOVER_OFFSET_M", "check_flight_paths"]

SPAN_CAP = 600.0  # s of an endless path that are sampled
_MAX_SAMPLES = 2_000_000  # a finite path longer than this many ticks is sampled this often (evenly)
_CHUNK = 100_000
_TOL = 1e-9
# A model-based height loop settling further than this from its references is a model of another vehicle (the
# shipped profiles' models settle within about a quarter of it on their vehicles); make fuzz flew a model 4x off
# into the ground with every reference inside the envelope.
MAX_HOVER_OFFSET_M = 0.25


class PathRefused(ConfigError):
    """An input that would fly outside the envelope (one line: the file or flag, the limit, the value)."""


def path_times(trajectory, rate_hz: float) -> np.ndarray:
    """Sample times [s] of a trajectory: from 0 (the start held) to the end of its time span (an endless
    one: :data:`SPAN_CAP` s after it starts moving), every control tick (at most 2e6 samples)."""
    t0, t1 = trajectory.time_span()
    end = t1 if math.isfinite(t1) else t0 + SPAN_CAP
    end = max(float(end), 0.0)
    n = int(end * rate_hz) + 2
    if n > _MAX_SAMPLES:
        return np.linspace(0.0, end, _MAX_SAMPLES)
    return np.arange(n) / rate_hz


def path_limits(trajectory, times: np.ndarray) -> dict[str, float]:
    """Largest speed [m/s], acceleration [m/s^2] and horizontal distance from the start [m] of a path on
    ``times``, and its height range (``z_lo``, ``z_hi`` [m]: the sampled range widened by its ``extent()``,
    which covers a file's spline between samples). NaN anywhere makes every figure NaN."""
    x0, y0, _ = trajectory.start_position()
    speed = accel = dist = 0.0
    z_lo, z_hi = math.inf, -math.inf
    for i in range(0, times.size, _CHUNK):
        d = trajectory.sample(times[i:i + _CHUNK])
        speed = max(speed, float(np.max(np.sqrt(d["vx"] ** 2 + d["vy"] ** 2 + d["vz"] ** 2))))
        accel = max(accel, float(np.max(np.sqrt(d["ax"] ** 2 + d["ay"] ** 2 + d["az"] ** 2))))
        dist = max(dist, float(np.max(np.hypot(d["x"] - x0, d["y"] - y0))))
        z_lo, z_hi = min(z_lo, float(np.min(d["z"]))), max(z_hi, float(np.max(d["z"])))
    ext = trajectory.extent()
    z_lo, z_hi = min(z_lo, ext["z"][0]), max(z_hi, ext["z"][1])
    far = math.hypot(max(abs(ext["x"][0] - x0), abs(ext["x"][1] - x0)),
                     max(abs(ext["y"][0] - y0), abs(ext["y"][1] - y0)))
    out = {"speed": speed, "accel": accel, "radius": max(dist, far), "z_lo": z_lo, "z_hi": z_hi}
    if not all(math.isfinite(v) for v in out.values()):
        return dict.fromkeys(out, math.nan)
    return out


def _refuse(what: str, quantity: str, value: float, limit: str, unit: str = "") -> None:
    raise PathRefused(f"{what}: {quantity} {value:.6g}{unit}, outside the envelope's {limit}")


def check_trajectory_path(trajectory, env: Envelope, rate_hz: float, what: str = "trajectory") -> dict[str, float]:
    """Refuse a path faster, more accelerated or wider than ``env``; its :func:`path_limits` otherwise.

    Raises:
        PathRefused: naming ``what`` (the trajectory's file, if it has one), the limit and the value.
    """
    source = getattr(trajectory, "source", None)
    what = f"{what} {source}" if source else what
    lim = path_limits(trajectory, path_times(trajectory, rate_hz))
    if not math.isfinite(lim["speed"]):
        raise PathRefused(f"{what}: the path is not finite everywhere")
    if lim["speed"] > env.max_speed * (1 + _TOL):
        _refuse(what, "speed", lim["speed"], f"max_speed {env.max_speed:g} m/s", " m/s")
    if lim["accel"] > env.max_accel * (1 + _TOL):
        _refuse(what, "acceleration", lim["accel"], f"max_accel {env.max_accel:g} m/s^2", " m/s^2")
    if lim["z_lo"] < env.z_min - _TOL:
        _refuse(what, "lowest height", lim["z_lo"], f"z_min {env.z_min:g} m (heights from the take-off point)", " m")
    if lim["z_hi"] > env.z_max + _TOL:
        _refuse(what, "highest height", lim["z_hi"], f"z_max {env.z_max:g} m", " m")
    if lim["radius"] > env.radius * (1 + _TOL):
        _refuse(what, "horizontal distance from the start", lim["radius"], f"radius {env.radius:g} m", " m")
    return lim


def nominal_path(trajectory, ctrl: ControllerConfig, times: np.ndarray) -> np.ndarray:
    """(N, 2) nominal flying references [z_ref m, pitch_ref rad] of a vehicle on the path at ``times``
    (on the path the horizontal PD is zero: the pitch is the path's own acceleration's)."""
    d = trajectory.sample(times)
    yaw = d["yaw"]
    ax = np.cos(yaw) * d["ax"] + np.sin(yaw) * d["ay"]
    pitch = np.clip(np.arctan2(ax, ctrl.g), -ctrl.max_tilt, ctrl.max_tilt)
    return np.column_stack([d["z"], pitch])


def check_references(u: np.ndarray, env: Envelope, mode: str, max_tilt: float, rate_hz: float | None,
                     what: str) -> None:
    """Refuse references ``u`` (N, m), one row per tick, outside the envelope's box or (``rate_hz`` given)
    moving faster than its ``ref_rate`` from one row to the next.

    Raises:
        PathRefused: naming ``what``, the reference, the limit and the value.
    """
    refs = REFERENCES[mode]
    lo, hi = env.reference_bounds(mode, max_tilt)
    u = np.asarray(u, dtype=float)
    for i, name in enumerate(refs):
        col = u[:, i]
        unit = " m" if name == "z_ref" else " rad"
        if not np.all(np.isfinite(col)):
            raise PathRefused(f"{what}: {name} is not finite on the path")
        if col.min() < lo[i] - _TOL:
            _refuse(what, f"{name} on the path reaches", float(col.min()), f"lower bound {lo[i]:g}{unit}", unit)
        if col.max() > hi[i] + _TOL:
            _refuse(what, f"{name} on the path reaches", float(col.max()), f"upper bound {hi[i]:g}{unit}", unit)
        if rate_hz is not None and col.size > 1:
            rate = float(np.max(np.abs(np.diff(col)))) * rate_hz
            limit = float(env.ref_rates(mode)[i])
            if rate > limit * (1 + 1e-6):
                _refuse(what, f"{name} on the path moves at", rate, f"ref_rate {limit:g}{unit}/s", f"{unit}/s")


def check_prefilter_path(path: str, trajectory, ctrl: ControllerConfig, env: Envelope, rate_hz: float) -> None:
    """The references ``--prefilter path`` would produce on the path: inside the envelope, within its rates."""
    model = load_prefilter(path, rate_hz, len(REFERENCES["flying"])).model
    t = path_times(trajectory, rate_hz)
    r = nominal_path(trajectory, ctrl, t)  # on the path: y_des = r_nom
    u = np.empty_like(r)
    for i in range(r.shape[1]):
        lead = np.minimum(np.arange(r.shape[0]) + int(model.lead[i]), r.shape[0] - 1)
        u[:, i] = (r[lead, i] - model.offset[i]) / model.gain[i]
    check_references(u, env, "flying", ctrl.max_tilt, rate_hz, f"--prefilter {path}")


def check_feedforward_path(path: str, trajectory, ctrl: ControllerConfig, env: Envelope, rate_hz: float) -> None:
    """``--feedforward path``: the table's clock, tick and columns (its loader) and every row added to the
    nominal path inside the envelope (row j at trajectory time j / rate)."""
    delta = load_feedforward(path, rate_hz, len(REFERENCES["flying"])).delta
    t = np.arange(delta.shape[0]) / rate_hz
    check_references(nominal_path(trajectory, ctrl, t) + delta, env, "flying", ctrl.max_tilt, None,
                     f"--feedforward {path}")


def check_excitation(amplitude, nominal: np.ndarray | None, env: Envelope, mode: str, max_tilt: float,
                     rate_hz: float) -> None:
    """``--excitation``: a PRBS step (twice the amplitude in one tick) within the references' rate limits,
    and the nominal references (N, m) plus or minus the amplitude inside the envelope (``nominal`` None:
    the amplitude within half the envelope's range).

    Raises:
        PathRefused: naming ``--excitation``, the reference, the limit and the value.
    """
    amp = np.abs(np.asarray(amplitude, dtype=float))
    refs = REFERENCES[mode]
    step = env.ref_rates(mode) / rate_hz
    lo, hi = env.reference_bounds(mode, max_tilt)
    for i, name in enumerate(refs):
        unit = " m" if name == "z_ref" else " rad"
        if not amp[i] <= step[i] / 2 * (1 + 1e-6):
            _refuse("--excitation", f"{name} amplitude", float(amp[i]),
                    f"ref_rate {env.ref_rates(mode)[i]:g}{unit}/s (a PRBS step is twice the amplitude in one tick: "
                    f"at most {step[i] / 2:.6g}{unit} at {rate_hz:g} Hz)", unit)
        if nominal is None and not amp[i] <= (hi[i] - lo[i]) / 2:
            _refuse("--excitation", f"{name} amplitude", float(amp[i]), f"range [{lo[i]:g}, {hi[i]:g}]{unit}", unit)
    if nominal is not None:
        for sign in (1.0, -1.0):
            check_references(nominal + sign * amp, env, mode, max_tilt, None, "--excitation")


def check_hopping_path(ctrl: ControllerConfig, env: Envelope, what: str = "the profile's [controller]",
                       duration: float | None = None) -> None:
    """A hopper's path: its apex height inside the envelope's heights, its target speed within ``max_speed``, and
    (``duration`` [s] given, the ``--duration``) the distance it travels at that speed within the ``radius``.

    Raises:
        PathRefused: naming the key, the limit and the value.
    """
    if ctrl.apex_height > env.z_max:
        _refuse(what, "apex_height", ctrl.apex_height, f"z_max {env.z_max:g} m", " m")
    speed = math.hypot(*ctrl.target_velocity)
    if speed > env.max_speed:
        _refuse(what, "target_velocity speed", speed, f"max_speed {env.max_speed:g} m/s", " m/s")
    if duration is not None and speed * duration > env.radius * (1 + _TOL):
        _refuse(f"{what} target_velocity over --duration {duration:g} s", "distance from the start",
                speed * duration, f"radius {env.radius:g} m", " m")


def check_thrust_limits(hover: float, thrust_min: float, thrust_max: float, source: str) -> None:
    """``--thrust-min`` below and ``--thrust-max`` above the hover thrust (``source`` says whose, e.g. the
    vehicle's MPC_THR_HOVER): otherwise the clamp alone climbs or sinks the vehicle whatever it is sent.

    Raises:
        PathRefused: naming the flag, the hover thrust and the value.
    """
    if not math.isfinite(hover):
        return
    if not thrust_min < hover:
        raise PathRefused(f"--thrust-min {thrust_min:g} is not below the hover thrust {hover:.3f} ({source}): "
                          "the vehicle could only climb")
    if not thrust_max > hover:
        raise PathRefused(f"--thrust-max {thrust_max:g} is not above the hover thrust {hover:.3f} ({source}): "
                          "the vehicle could only sink")


def check_model_hover(model_hover: float, hover: float, kp_z: float, g: float, source: str) -> None:
    """The controller model's hover thrust (its ``model_mass`` g / ``max_thrust``) against the vehicle's ``hover``
    (``source`` says whose): the model's height loop settles ``g / kp_z * (hover / model_hover - 1)`` m below its
    reference (above when negative), whatever the reference, so a model too far off flies the vehicle out of its
    envelope with every reference inside it. Refused beyond :data:`MAX_HOVER_OFFSET_M`.

    Raises:
        PathRefused: naming both hover thrusts and the offset.
    """
    if not (math.isfinite(hover) and hover > 0 and model_hover > 0 and kp_z > 0):
        return
    offset = g / kp_z * (hover / model_hover - 1.0)
    if abs(offset) > MAX_HOVER_OFFSET_M:
        raise PathRefused(f"the controller model's hover thrust {model_hover:.3f} (model_mass g / max_thrust) is far "
                          f"from {source} {hover:.3f}: its height loop would settle {abs(offset):.2f} m "
                          f"{'below' if offset > 0 else 'above'} every reference (at most {MAX_HOVER_OFFSET_M:g} m; "
                          "fix the profile's [controller] model_mass / max_thrust)")


def _trajectory_name(trajectory) -> str:
    """How the user named the path: ``--trajectory`` (a file: its path follows), ``--trajectory random:SEED``,
    or the profile's ``[trajectory]``."""
    if getattr(trajectory, "source", None):
        return "--trajectory"
    if isinstance(trajectory, RandomSmoothTrajectory):
        return f"--trajectory random:{trajectory.seed}"
    return "the profile's [trajectory]"


def check_flight_paths(cfg, ctrl: ControllerConfig, trajectory) -> None:
    """Every path-defining input of a bridge config (:class:`~firmware_bridge.bridge_config.BridgeConfig`)
    against its envelope (``cfg.envelope``, else the defaults); ``ctrl`` and ``trajectory``: the controller's
    config and the path it flies (None when hopping). See the module docstring."""
    env = cfg.envelope or Envelope()
    rate = cfg.rate_hz
    check_thrust_limits(ctrl.model_mass * ctrl.g / ctrl.max_thrust, cfg.thrust_min, cfg.thrust_max,
                        "the controller model's")
    if cfg.takeoff and cfg.climb_rate > env.max_speed:
        _refuse("--climb-rate", "take-off speed", cfg.climb_rate, f"max_speed {env.max_speed:g} m/s", " m/s")
    nominal = None
    if trajectory is not None:
        name = _trajectory_name(trajectory)
        check_trajectory_path(trajectory, env, rate, name)
        nominal = nominal_path(trajectory, ctrl, path_times(trajectory, rate))
        check_references(nominal, env, "flying", ctrl.max_tilt, rate, name)  # the nominal path within ref_rate
        if cfg.mode == "prefilter" and cfg.prefilter:
            check_prefilter_path(cfg.prefilter, trajectory, ctrl, env, rate)
        if cfg.mode == "feedforward" and cfg.feedforward:
            check_feedforward_path(cfg.feedforward, trajectory, ctrl, env, rate)
    else:
        check_hopping_path(ctrl, env, duration=cfg.duration)
    if cfg.mode == "collect" and cfg.excitation is not None:
        check_excitation(cfg.excitation, nominal, env, cfg.scenario, ctrl.max_tilt, rate)
