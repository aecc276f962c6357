"""The bridge's baseline modes behind the steering's per-tick interface, loaded and checked against
the loop before anything flies:

* ``prefilter``: :class:`~ddpc_codegen.runtime.baselines.PrefilterPolicy` (gain + offset + lead,
  a :meth:`~ddpc_codegen.design.baselines.PrefilterModel.save` JSON file); needs y_des up to its
  longest lead ahead.
* ``feedforward``: :class:`~ddpc_codegen.runtime.baselines.FeedforwardPolicy` (an ILC table, a
  :meth:`~ddpc_codegen.runtime.baselines.FeedforwardPolicy.save` npz): u = r_nom + delta[j] with
  j the *trajectory* tick, round(t_traj / dt) -- the grid of the tick log's ``t_traj`` -- derived
  from the trajectory clock at every tick, so a re-engagement or a stall mid-flight continues the
  table where the trajectory is (the clock is never restarted).

Every file is checked before anything connects (its own fields by the loaders, exit 2 with the file and
the key): the channels against the loop, the tick against the rate, and the size of the correction each
can add against the robot's envelope (``span``: the range of each reference, :class:`Envelope`) -- a
table of 1e6 or a prefilter whose offset / gain leaves the envelope never flies.

Both fly the flying scenario only (the hopping baselines run in-process: their clock is the
liftoff, which a hopping bridge would have to reset per hop). ``passthrough`` is
:class:`~ddpc_codegen.runtime.baselines.PassthroughPolicy` (u = r_nom, no file), flying or hopping, so
every mode but collect reaches the loop through the same :class:`~ddpc_codegen.runtime.policy.Policy`
methods (steer: :mod:`firmware_bridge.steering_setup`, hopping steer: :mod:`firmware_bridge.hopping_loop`).
"""

from __future__ import annotations

import numpy as np

from ddpc_codegen.errors import ConfigError
from ddpc_codegen.runtime.baselines import FeedforwardPolicy, PassthroughPolicy, PrefilterPolicy
from ddpc_codegen.runtime.policy import Policy

__all__ = ["BASELINE_MODES", "load_feedforward", "load_prefilter", "baseline_policy", "feedforward_row"]

BASELINE_MODES = ("passthrough", "prefilter", "feedforward")


def load_feedforward(path: str, rate_hz: float, m: int, span: np.ndarray | None = None) -> FeedforwardPolicy:
    """The table of ``--feedforward path``, or ValueError saying what does not fit the loop.

    Args:
        path: npz written by :meth:`FeedforwardPolicy.save`.
        rate_hz: the bridge's control rate: the table's dt must be its period.
        m: the loop's number of references (the table's columns).
        span: (m,) the envelope's range of each reference [m, rad]: |delta| must stay within it.
    """
    try:
        pol = FeedforwardPolicy.load(path)
    except ConfigError as e:
        raise ValueError(f"--feedforward {e}") from None
    if pol.clock != "trajectory":
        raise ValueError(f"--feedforward {path}: table clock {pol.clock!r}; the bridge indexes the table by "
                         "trajectory tick and needs clock 'trajectory'")
    if abs(pol.dt - 1.0 / rate_hz) > 1e-9:
        raise ValueError(f"--feedforward {path}: table tick {pol.dt:g} s does not match the bridge rate "
                         f"{rate_hz:g} Hz ({1.0 / rate_hz:g} s); learn the table at the rate it is flown at")
    if pol.delta.shape[1] != m:
        raise ValueError(f"--feedforward {path}: table has {pol.delta.shape[1]} columns (shape "
                         f"{pol.delta.shape}); the loop has m={m} references")
    if span is not None:
        big = np.abs(pol.delta).max(axis=0)
        for i in np.nonzero(big > span)[0]:
            raise ValueError(f"--feedforward {path}: delta column {i} reaches {big[i]:g}, more than the envelope's "
                             f"range of that reference ({span[i]:g}, the profile's [envelope] / max_tilt)")
    return pol


def load_prefilter(path: str, rate_hz: float, m: int, span: np.ndarray | None = None) -> PrefilterPolicy:
    """The model of ``--prefilter path``, or ValueError saying what does not fit the loop: one channel per
    reference, its tick the bridge's, and each channel's offset / gain within the envelope's range."""
    try:
        pol = PrefilterPolicy.load(path)
    except ConfigError as e:
        raise ValueError(f"--prefilter {e}") from None
    mod = pol.model
    if mod.m != m:
        raise ValueError(f"--prefilter {path}: the model has {mod.m} channels; the loop has m={m} references")
    if abs(mod.dt - 1.0 / rate_hz) > 1e-9:
        raise ValueError(f"--prefilter {path}: model tick {mod.dt:g} s does not match the bridge rate {rate_hz:g} Hz "
                         f"({1.0 / rate_hz:g} s); fit the prefilter at the rate it is flown at")
    if span is not None:
        shift = np.abs(np.asarray(mod.offset) / np.asarray(mod.gain))
        for i in np.nonzero(shift > span)[0]:
            raise ValueError(f"--prefilter {path}: channel {i} shifts the reference by offset / gain = {shift[i]:g}, "
                             f"more than the envelope's range of that reference ({span[i]:g})")
    return pol


def baseline_policy(mode: str, path: str | None, rate_hz: float, m: int, hopping: bool,
                    span: np.ndarray | None = None) -> tuple[Policy, np.ndarray]:
    """(policy, ahead): the baseline of ``mode`` and the trajectory-time offsets [s] of the desired
    outputs its ``decide`` needs (0 .. horizon - 1 ticks ahead). ``path``: the file of a prefilter or
    feed-forward mode (passthrough: none). ``span``: as :func:`load_feedforward`."""
    if mode == "passthrough":  # the controller alone, flying or hopping
        pol: Policy = PassthroughPolicy()
        return pol, np.arange(pol.horizon) / rate_hz
    if hopping:
        raise ValueError(f"{mode} mode flies the flying scenario (the hopping baselines run in-process)")
    if mode == "prefilter":
        pol = load_prefilter(path, rate_hz, m, span)
    elif mode == "feedforward":
        pol = load_feedforward(path, rate_hz, m, span)
    else:
        raise ValueError(f"not a baseline mode: {mode!r} (one of {BASELINE_MODES})")
    return pol, np.arange(pol.horizon) / rate_hz


def feedforward_row(t_traj: float, period: float) -> int:
    """The table row of trajectory time ``t_traj`` [s]: round(t_traj / period), >= 0 (the tick log's
    ``t_traj`` grid, which :func:`ddpc_codegen.design.baselines.error_on_grid` learns on)."""
    return max(int(round(t_traj / period)), 0)
