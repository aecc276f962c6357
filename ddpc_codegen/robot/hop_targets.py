"""Hopping with a varying apex target: a new target per hop, known at liftoff.

The height and leg angle controller plans each aerial arc at liftoff to reach
``ControllerConfig.apex_height``. :class:`ScheduledHoppingController` swaps that field at every
liftoff for the schedule's next value, so the arc, the nominal stance time (foot placement) and the
look-ahead (:meth:`~HeightLegAngleController.predict`) all use the current hop's target.
The first (release) arc keeps the configured apex.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ddpc_codegen.robot.controller import ControllerConfig, HeightLegAngleController

__all__ = ["ApexSchedule", "ScheduledHoppingController"]


@dataclass(frozen=True)
class ApexSchedule:
    """Seeded random apex targets, one per hop, uniform in [low, high] [m], each held ``hold`` hops.

    ``apex(j)`` is the target of the arc after the j-th liftoff (j >= 1).
    """

    seed: int = 0
    low: float = 0.62
    high: float = 0.78
    hold: int = 1

    def __post_init__(self) -> None:
        if not (0.0 < self.low <= self.high):
            raise ValueError(f"ApexSchedule needs 0 < low <= high [m]; got {self.low!r}, {self.high!r}")
        if not (isinstance(self.hold, int) and self.hold >= 1):
            raise ValueError(f"hold must be an integer >= 1 hops; got {self.hold!r}")

    def apex(self, j: int) -> float:
        """Target apex height of hop j (the arc after the j-th liftoff) [m]."""
        block = max(int(j) - 1, 0) // self.hold
        rng = np.random.default_rng([self.seed, block])
        return float(rng.uniform(self.low, self.high))


class ScheduledHoppingController(HeightLegAngleController):
    """:class:`HeightLegAngleController` (hopping) whose apex target follows an :class:`ApexSchedule`."""

    def __init__(self, config: ControllerConfig, schedule: ApexSchedule) -> None:
        if config.mode != "hopping":
            raise ValueError("a scheduled apex needs a hopping controller")
        self.schedule = schedule
        self._base_config = config
        super().__init__(config)

    def reset(self, t0: float = 0.0, z0: float | None = None) -> None:
        self.config = self._base_config
        super().reset(t0, z0)

    def _start_arc(self, t: float, z: float) -> None:
        # Called at each measured liftoff, after n_liftoffs was incremented.
        self.config = replace(self.config, apex_height=self.schedule.apex(self.n_liftoffs))
        super()._start_arc(t, z)
