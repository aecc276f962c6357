"""The logs of one closed-loop run (:class:`SimResult`) and their IO dataset.

Per tick k (time-major arrays): y[k] is the measurement the tick-k decision was based on and
u[k] the reference applied from t_k to t_k + dt, so u[k] influences y[k+1], y[k+2], ... (a
strictly proper closed loop).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ddpc_codegen.design.data import IODataset
from ddpc_codegen.values.phases import ASCENT, DESCENT, GROUND, PHASE_NAMES
from ddpc_codegen.errors import DataError
from ddpc_codegen.robot.controller import ControllerConfig
from ddpc_codegen.robot.frames import euler_from_quat_array
from ddpc_codegen.sim.metrics import compute_metrics
from ddpc_codegen.sim.params import PogoXParams

__all__ = ["SimResult"]


@dataclass
class SimResult:
    """Time-major logs of one closed-loop run (N control ticks).

    Attributes:
        scenario: "flying" / "hopping"; dt: control period [s].
        t: (N,) tick times [s].
        state: (N, 19) true plant state at the tick (see :mod:`ddpc_codegen.sim.plant`).
        u: (N, m) references actually applied (after hook and excitation).
        r_nom: (N, m) nominal references (stage a).
        excitation: (N, m) the PRBS part of u (zeros if none).
        y: (N, p) measured outputs (delayed, noisy); y_true: (N, p) true outputs at t.
        y_des: (N, p) desired outputs.
        phase: (N,) int8 phase labels (controller's estimate); contact: (N,) true contact.
        setpoint_q: (N, 4) attitude setpoints (w, x, y, z) ENU/FLU; setpoint_thrust: (N,) normalized;
        setpoint_euler: (N, 3) commanded roll, pitch, yaw.
        touchdowns, liftoffs: event times [s] located by the plant.
        extras: scenario-specific logs (flying: "x_des", "z_des" of the ellipse).
        crashed: True if the robot was lost (tilt > 70 deg, body near the ground, NaN state, or the
            hybrid integration stuck in foot chattering); crash_reason says which, and when.
    """

    scenario: str
    dt: float
    t: np.ndarray
    state: np.ndarray
    u: np.ndarray
    r_nom: np.ndarray
    excitation: np.ndarray
    y: np.ndarray
    y_true: np.ndarray
    y_des: np.ndarray
    phase: np.ndarray
    contact: np.ndarray
    setpoint_q: np.ndarray
    setpoint_thrust: np.ndarray
    setpoint_euler: np.ndarray
    touchdowns: np.ndarray
    liftoffs: np.ndarray
    input_names: tuple[str, ...]
    output_names: tuple[str, ...]
    input_units: tuple[str, ...]
    output_units: tuple[str, ...]
    params: PogoXParams
    config: ControllerConfig
    scenario_obj: Any
    seed: int
    crashed: bool = False
    crash_reason: str = ""
    n_bottom_outs: int = 0
    wall_time: float = 0.0
    extras: dict[str, np.ndarray] = field(default_factory=dict)

    @property
    def n(self) -> int:
        return int(self.t.shape[0])

    @property
    def position(self) -> np.ndarray:
        """(N, 3) true position [m]."""
        return self.state[:, 0:3]

    @property
    def velocity(self) -> np.ndarray:
        """(N, 3) true velocity [m/s]."""
        return self.state[:, 3:6]

    @property
    def euler(self) -> np.ndarray:
        """(N, 3) true roll, pitch, yaw [rad] (the vectorised frames path)."""
        return euler_from_quat_array(self.state[:, 6:10]).reshape(-1, 3)

    def metrics(self) -> dict[str, Any]:
        """Tracking metrics (see :mod:`ddpc_codegen.sim.metrics`)."""
        return compute_metrics(self)

    def to_dataset(self, split: str = "auto", *, t_min: float | None = None, metadata: dict | None = None) -> IODataset:
        """The IO data (u applied, y measured) as an :class:`IODataset` with phase labels.

        Args:
            split: "none" (one trajectory), "hops" (hopping: apex-to-apex segments, each with
                descent / ground / ascent -- what artificial-IO generation needs), "aerial"
                (hopping: liftoff-to-touchdown segments only), "auto" (flying: none, hopping: hops).
            t_min: drop samples (flying) / segments (hopping) starting before this time [s]
                (default: the scenario's settle time / settle hops).
        """
        if split == "auto":
            split = "none" if self.scenario == "flying" else "hops"
        n = self.n
        if t_min is None:
            if self.scenario == "flying":
                t_min = getattr(self.scenario_obj, "settle_time", 0.0)
            else:
                t_min = 0.0
        segments: list[tuple[int, int]] = []
        if split == "none":
            k0 = int(np.searchsorted(self.t, t_min - 1e-12))
            segments = [(k0, n)]
        elif split == "hops":
            ph = self.phase
            # Apexes: ascent -> descent transitions (and the release at rest at k = 0).
            apex = [0] + [k for k in range(1, n) if ph[k - 1] == ASCENT and ph[k] == DESCENT]
            for a, b in zip(apex[:-1], apex[1:]):
                if self.t[a] >= t_min - 1e-12 and np.any(ph[a:b] == GROUND):
                    segments.append((a, b))
        elif split == "aerial":
            ground = self.phase == GROUND
            k = 0
            while k < n:
                if ground[k]:
                    k += 1
                    continue
                j = k
                while j < n and not ground[j]:
                    j += 1
                # Only complete aerial phases (ending in a touchdown) unless it is the last one.
                if self.t[k] >= t_min - 1e-12 and j - k >= 2:
                    segments.append((k, j))
                k = j
        else:
            raise ValueError(f"split must be 'auto', 'none', 'hops' or 'aerial'; got {split!r}")
        if not segments:
            raise DataError(
                f"no {split!r} segments in this {self.scenario} run of {self.t[-1] if n else 0:.2f} s "
                f"(t_min={t_min}); simulate longer"
            )
        meta = {
            "source": "ddpc_codegen.sim",
            "scenario": self.scenario,
            "split": split,
            "seed": self.seed,
            "segments_ticks": [[int(a), int(b)] for a, b in segments],
            "controller_model_mass": self.config.model_mass,
            "true_mass": self.params.mass,
            "phase_labels": {str(k): v for k, v in PHASE_NAMES.items()},
        }
        meta.update(metadata or {})
        return IODataset(
            [self.u[a:b] for a, b in segments],
            [self.y[a:b] for a, b in segments],
            self.dt,
            input_names=self.input_names,
            output_names=self.output_names,
            input_units=self.input_units,
            output_units=self.output_units,
            phases=[self.phase[a:b] for a, b in segments],
            metadata=meta,
        )
