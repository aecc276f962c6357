"""What the steering proxy keeps of a session: one row per tick (the app's height, the height sent, the
measured height, why, the gate's flags, the position's age), saved as a log (``--log``), and the engaged
stretches as a dataset for ``ddpc-codegen`` (``--collect``): the heights sent to the vehicle in, its measured
height out, one trajectory per stretch flown armed in off-board / guided on fresh positions.

Files are never replaced unless asked (``overwrite``), so a session cannot lose a recorded flight.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ddpc_codegen.design.data import IODataset, output_path
from firmware_bridge.ticklog import REASONS

__all__ = ["ProxyRecord", "ROW"]

ROW = np.dtype([("t", "f8"), ("r_nom", "f8"), ("u", "f8"), ("y", "f8"), ("reason", "u1"), ("gate", "u2"),
                ("age", "f4"), ("engaged", "?"), ("solve_us", "f4"), ("pos_seq", "u4")])
_REASON = {r: i for i, r in enumerate(REASONS)}
_MIN_STRETCH_S = 2.0  # shorter engaged stretches hold too few Hankel columns to be worth a trajectory


class ProxyRecord:
    """Rows of one session, in a growing preallocated array (no allocation per tick)."""

    def __init__(self, capacity: int = 1 << 16) -> None:
        self.rows = np.zeros(capacity, dtype=ROW)
        self.n = 0

    def add(self, t: float, r_nom: float, u: float, y: float, reason: str, gate: int, age: float, engaged: bool,
            solve_us: float, pos_seq: int) -> None:
        """One tick: times [s], heights up [m], the tick-log reason, gate flags, the position's age [s]."""
        if self.n == len(self.rows):
            self.rows = np.concatenate((self.rows, np.zeros(len(self.rows), dtype=ROW)))
        self.rows[self.n] = (t, r_nom, u, y, _REASON.get(reason, 0), gate, age, engaged, solve_us, pos_seq)
        self.n += 1

    def view(self) -> np.ndarray:
        return self.rows[:self.n]

    def stretches(self, dt: float) -> list[np.ndarray]:
        """Row indices of each engaged stretch at least :data:`_MIN_STRETCH_S` long whose positions are at most
        three ticks old and whose setpoints came every ``dt`` (within half of it): a longer hole, or an app streaming
        at another rate (PX4's take-off stream), ends the stretch, since its rows would no longer be on the ticks'
        grid."""
        r = self.view()
        ok = r["engaged"] & (r["age"] <= 3.0 * dt)
        ok[1:] &= np.abs(np.diff(r["t"]) - dt) <= 0.5 * dt
        out, start = [], None
        for k, good in enumerate(np.append(ok, False)):
            if good and start is None:
                start = k
            elif not good and start is not None:
                if (k - start) * dt >= _MIN_STRETCH_S:
                    out.append(np.arange(start, k))
                start = None
        return out

    def dataset(self, dt: float, metadata: dict | None = None, coordinates: str = "absolute") -> IODataset:
        """The engaged stretches as an :class:`IODataset` [m]: absolute (u ``z_ref``: the heights sent, y ``z``: the
        measured ones, up), or deviation (u ``z_offset``: sent - the app's, y ``z_error``: measured - the app's).

        Raises:
            ValueError: no stretch long enough was flown.
        """
        idx = self.stretches(dt)
        if not idx:
            raise ValueError(f"no engaged stretch of {_MIN_STRETCH_S:g} s or more with fresh positions was flown: "
                             "nothing to collect (was the vehicle armed in off-board / guided?)")
        r = self.view()
        base = r["r_nom"] if coordinates == "deviation" else np.zeros(len(r))
        names = (["z_offset"], ["z_error"]) if coordinates == "deviation" else (["z_ref"], ["z"])
        return IODataset([(r["u"] - base)[i, None] for i in idx], [(r["y"] - base)[i, None] for i in idx], dt,
                         input_names=names[0], output_names=names[1], input_units=["m"], output_units=["m"],
                         metadata={"source": "ddpc-proxy --collect", "coordinates": coordinates, **(metadata or {})})

    def save_log(self, path: str | Path, summary: dict, overwrite: bool = False) -> Path:
        """Every row and the session's summary as ``.npz`` (``rows``, ``reasons``, ``summary`` JSON)."""
        out = output_path(path, overwrite)
        np.savez_compressed(out, rows=self.view(), reasons=np.array(REASONS),
                            summary=np.frombuffer(json.dumps(summary).encode(), dtype=np.uint8))
        return out
