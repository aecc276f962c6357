"""The bridge's command-line values, checked before anything connects (:func:`check_bridge_values`): types,
finiteness and ranges, with a message naming the flag -- ``--sysid 300`` is refused here, not as a
``struct.error`` when the first message is packed; ``--max-tilt-deg 400`` and ``--duration -1`` likewise.
The files the bridge flies on are checked by their loaders (:mod:`ddpc_codegen.robot.validate`): robot
profiles, prefilter models, feed-forward tables. What each value *does* to the flown path (a prefilter gain
of 0.001, an excitation of 1e308, a thrust floor above the hover thrust) is checked against the robot's
envelope by :mod:`firmware_bridge.path_checks`.
"""

from __future__ import annotations

import math

from ddpc_codegen.errors import ConfigError
from ddpc_codegen.robot.validate import Range, check_number

__all__ = ["check_bridge_values", "BRIDGE_RANGES"]

_ID = Range(lo=0, hi=255, integer=True)
_SECONDS = Range(lo=0.0, lo_open=True, hi=86_400.0)
# field -> (flag, scale from the field's unit to the flag's, what the flag may hold)
BRIDGE_RANGES: dict[str, tuple[str, float, Range]] = {
    "sysid": ("--sysid", 1.0, Range(lo=1, hi=255, integer=True)),
    "compid": ("--compid", 1.0, _ID),
    "target_system": ("--target-system", 1.0, _ID),
    "target_component": ("--target-component", 1.0, _ID),
    "baud": ("--baud", 1.0, Range(lo=1, hi=100_000_000, integer=True, optional=True)),
    "guid_options": ("--guid-options", 1.0, Range(lo=0, hi=2**24, integer=True, optional=True)),
    "rate_hz": ("--rate", 1.0, Range(lo=0.0, lo_open=True, hi=1000.0)),
    "max_age": ("--max-age-ms", 1e3, Range(lo=0.0, lo_open=True, hi=10_000.0)),
    "stale_stream_limit": ("--stale-stream-limit", 1.0, Range(lo=0.0, hi=3600.0)),
    "link_timeout": ("--link-timeout", 1.0, Range(lo=0.0, lo_open=True, hi=3600.0)),
    "vehicle_lost_timeout": ("--vehicle-lost-timeout", 1.0, Range(lo=0.0, lo_open=True, hi=86_400.0)),
    "max_tilt_deg": ("--max-tilt-deg", 1.0, Range(lo=0.0, lo_open=True, hi=90.0, hi_open=True)),
    "thrust_min": ("--thrust-min", 1.0, Range(lo=0.0, hi=1.0)),
    "thrust_max": ("--thrust-max", 1.0, Range(lo=0.0, hi=1.0)),
    "max_gap_fill": ("--max-gap-fill", 1.0, Range(lo=0, hi=1000, integer=True)),
    "guard_hold": ("--guard-hold", 1.0, Range(lo=0.0, hi=3600.0)),
    "arm_timeout": ("--arm-timeout", 1.0, Range(lo=0.0, lo_open=True, hi=3600.0)),
    "prestream": ("--prestream", 1.0, Range(lo=0.0, hi=60.0)),
    "climb_rate": ("--climb-rate", 1.0, Range(lo=0.0, lo_open=True, hi=10.0)),
    "approach_timeout": ("--approach-timeout", 1.0, Range(lo=0.0, lo_open=True, hi=3600.0)),
    "approach_tolerance": ("--approach-tolerance", 1.0, Range(lo=0.0, lo_open=True, hi=10.0)),
    "duration": ("--duration", 1.0, Range(lo=0.0, lo_open=True, hi=86_400.0, optional=True)),
    "timeout": ("--timeout", 1.0, Range(lo=0.0, lo_open=True, hi=30 * 86_400.0, optional=True)),
    "wait_heartbeat": ("--wait-heartbeat", 1.0, _SECONDS),
    "dataset_skip": ("--dataset-skip", 1.0, Range(lo=0.0, hi=86_400.0)),
    "settle": ("--settle", 1.0, Range(lo=0.0, hi=86_400.0)),
    "excitation_hold": ("--excitation-hold", 1.0, Range(lo=1, hi=100_000, integer=True)),
    "seed": ("--seed", 1.0, Range(lo=0, hi=2**32 - 1, integer=True)),
    "rt_priority": ("--rt-priority", 1.0, Range(lo=0, hi=99, integer=True)),
    "cpu_latency_us": ("--cpu-latency-us", 1.0, Range(lo=0, hi=1_000_000, integer=True, optional=True)),
}


def check_bridge_values(cfg) -> None:
    """Every numeric option of a :class:`~firmware_bridge.bridge_config.BridgeConfig` against
    :data:`BRIDGE_RANGES`, the fault-injection spec and the contact flag's name.

    Raises:
        ValueError: ``"<flag> must be ...; got <value>"`` (a ConfigError, also a ValueError).
    """
    for key, (flag, scale, r) in BRIDGE_RANGES.items():
        v = getattr(cfg, key)
        if v is None and r.optional:
            continue
        shown = v * scale if scale != 1.0 and isinstance(v, (int, float)) and not isinstance(v, bool) else v
        check_number(shown, flag, r)
    if cfg.inject_solver_failure is not None:
        start, count, *_ = cfg.inject_solver_failure
        for v in (start, count):
            check_number(v, "--inject-solver-failure", Range(lo=0, hi=10**9, integer=True))
    name = getattr(cfg.contact, "signal_name", None) if cfg.contact is not None else None
    if name is not None and (not 0 < len(name) <= 10 or not name.isprintable()):
        raise ConfigError(f"--contact-name must be 1 to 10 printable characters (a NAMED_VALUE_INT name); got {name!r}")
    if cfg.cpus is not None and any(not (isinstance(c, int) and 0 <= c < 4096) for c in cfg.cpus):
        raise ConfigError(f"--cpus must be CPU numbers in [0, 4096); got {cfg.cpus!r}")
    if not math.isfinite(cfg.thrust_min) or not cfg.thrust_min < cfg.thrust_max:
        raise ConfigError(f"--thrust-min must be below --thrust-max; got {cfg.thrust_min!r}, {cfg.thrust_max!r}")
