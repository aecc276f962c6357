"""Hopping phase detection on the companion computer: descent / ground / ascent from what the
robot actually sends.

Two sources, configured in the robot profile (``[contact]``):

* ``signal``: the robot has a leg sensor and publishes contact (e.g. a MAVLink NAMED_VALUE_INT
  named ``CONTACT``, 1 = foot on the ground); the estimator only debounces it.
* ``estimate``: from telemetry alone. The leg points along body -z, so the foot height above the
  contact plane is h = z - L0 cos(roll) cos(pitch) (L0: leg rest length, body COM to foot). A
  touchdown is h below ``-touchdown_margin`` while vz < -``vz_band``; a liftoff is h above
  ``+liftoff_margin`` while vz > ``vz_band``. The velocity conditions and the minimum dwell times
  make the estimate hysteretic: noise near h = 0 at rest never switches it. ``liftoff_margin`` may be
  negative: a springy leg still extending when the foot leaves the ground lifts off before it
  reaches its rest length (PogoX's profile sets its thresholds where they detect liftoff and touchdown
  on the sample a contact sensor would).

In the air, ascent vs descent is the sign of vz with a dead band (``vz_band``), switching to
descent once per arc (at the apex), never back.

Labels of past samples. The margins make a touchdown from telemetry 0-1 samples later than the
sample on which the foot first went below the plane; a sample of the stance labelled aerial would
put spring dynamics into the aerial data (the artificial-IO Hankel, the online windows). So once a
touchdown is confirmed, :attr:`PhaseEstimator.backdate` says how many of the samples just before
were already below the plane (at most ``backdate_ticks``): the loop relabels them ground. An
aerial sample labelled ground is harmless (it is completed like the stance), so liftoffs are not
back-dated. The contact signal belongs to its own sample: never back-dated.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from ddpc_codegen.values.phases import ASCENT, DESCENT, GROUND

__all__ = ["ContactConfig", "PhaseEstimator"]

_SOURCES = ("estimate", "signal")


@dataclass(frozen=True)
class ContactConfig:
    """How the companion computer knows the foot is on the ground (SI units).

    Attributes:
        source: "estimate" (from telemetry) or "signal" (a contact message from the robot).
        signal_name: name of the NAMED_VALUE_INT / NAMED_VALUE_FLOAT carrying contact (signal).
        leg_length: leg rest length L0, body COM to foot [m].
        ground_z: height of the contact plane in the trajectory frame [m] (0: take-off plane).
        touchdown_margin, liftoff_margin: foot-height thresholds below / above the plane [m]
            (liftoff_margin < 0: the foot leaves the ground below the leg's rest length).
        vz_band: dead band of the vertical velocity for touchdown / liftoff / apex [m/s].
        min_ground_ticks, min_air_ticks: shortest ground / aerial phase accepted [ticks].
        backdate_ticks: most samples before a confirmed touchdown relabelled ground (estimate).
    """

    source: str = "estimate"
    signal_name: str = "CONTACT"
    leg_length: float = 0.40
    ground_z: float = 0.0
    touchdown_margin: float = 0.004
    liftoff_margin: float = 0.004
    vz_band: float = 0.05
    min_ground_ticks: int = 3
    min_air_ticks: int = 10
    backdate_ticks: int = 2

    def __post_init__(self) -> None:
        if self.source not in _SOURCES:
            raise ValueError(f"source must be one of {list(_SOURCES)}; got {self.source!r}")
        for key in ("leg_length", "touchdown_margin", "liftoff_margin", "vz_band"):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"{key} must be a number; got {v!r}")
            if v < 0 and key != "liftoff_margin":
                raise ValueError(f"{key} must be a number >= 0; got {v!r}")
        if self.leg_length <= 0:
            raise ValueError(f"leg_length must be > 0; got {self.leg_length!r}")
        if not -self.leg_length < self.liftoff_margin:
            raise ValueError(f"liftoff_margin must be > -leg_length ({-self.leg_length!r}); got {self.liftoff_margin!r}")
        for key in ("min_ground_ticks", "min_air_ticks"):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ValueError(f"{key} must be an integer >= 1; got {v!r}")
        v = self.backdate_ticks
        if isinstance(v, bool) or not isinstance(v, int) or v < 0:
            raise ValueError(f"backdate_ticks must be an integer >= 0; got {v!r}")


@dataclass
class PhaseEstimator:
    """Per-tick phase of a hopping robot (GROUND, ASCENT or DESCENT from values.phases).

    Call :meth:`update` once per control tick. ``events`` collects (tick, "touchdown" | "liftoff");
    ``backdate`` is, on the tick a touchdown is confirmed, the number of samples just before it
    that were already below the plane (0 otherwise; see the module docstring).
    """

    config: ContactConfig
    phase: int = DESCENT
    events: list = field(default_factory=list)

    def __post_init__(self) -> None:
        self._k = -1
        self._since = 10**9  # ticks in the current phase (contact or air); large: free to switch
        self._below = 0  # consecutive samples with the foot below the plane (estimate)
        self.backdate = 0

    @property
    def contact(self) -> bool:
        return self.phase == GROUND

    def reset(self, phase: int = DESCENT) -> None:
        """Start over (e.g. released in the air: DESCENT)."""
        self.phase = phase
        self._since = 10**9
        self._below = 0
        self.backdate = 0
        self.events.clear()

    def foot_height(self, z: float, roll: float, pitch: float) -> float:
        """Foot height above the contact plane [m] with the leg at rest length."""
        c = self.config
        return z - c.ground_z - c.leg_length * math.cos(roll) * math.cos(pitch)

    def update(self, z: float, vz: float, roll: float, pitch: float, signal: bool | None = None) -> int:
        """Phase at this tick from the measured height z [m], vertical velocity vz [m/s] and leg
        angles [rad]; ``signal`` is the robot's contact flag when ``source == "signal"``."""
        c = self.config
        self._k += 1
        self._since += 1
        self.backdate = 0
        if c.source == "signal":
            if signal is None:
                raise ValueError("contact source 'signal' needs the robot's contact flag every tick")
            touch, lift = bool(signal), not bool(signal)
        else:
            h = self.foot_height(z, roll, pitch)
            self._below = self._below + 1 if h < 0.0 else 0
            # both conditions, each a few noise sigmas from 0: a foot resting near the plane
            # (noisy h and vz around 0) never switches
            touch = h < -c.touchdown_margin and vz < -c.vz_band
            lift = h > c.liftoff_margin and vz > c.vz_band
        if self.phase == GROUND:
            if lift and self._since >= c.min_ground_ticks:
                self._switch(ASCENT, "liftoff")
        elif touch and self._since >= c.min_air_ticks:
            self._switch(GROUND, "touchdown")
            if c.source == "estimate":
                self.backdate = min(max(self._below - 1, 0), c.backdate_ticks)
        elif self.phase == ASCENT and vz < -c.vz_band:
            self.phase = DESCENT  # past the apex; the air-time counter keeps running
        return self.phase

    def _switch(self, phase: int, event: str) -> None:
        self.phase = phase
        self._since = 0
        self.events.append((self._k, event))
