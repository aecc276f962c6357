"""Collect mode's excitation: the seeded PRBS added to the references, made in blocks by the design side's
:func:`~ddpc_codegen.design.data.prbs` (block ``i`` with seed ``seed * 1009 + i``)."""

from __future__ import annotations

import numpy as np

from ddpc_codegen.design.data import prbs

__all__ = ["Excitation"]


class Excitation:
    """The PRBS samples of a collect flight, one per tick.

    Args:
        m: number of references; amplitude: (m,) or scalar [reference units].
        hold: shortest hold of a PRBS level [ticks]; seed: the flight's seed.
    """

    BLOCK = 12000  # samples of PRBS made at once (60 s at 200 Hz)

    def __init__(self, m: int, amplitude, hold: int, seed: int) -> None:
        self.m = m
        self.amplitude = np.broadcast_to(np.asarray(amplitude, dtype=float), (m,)).copy()
        self.hold = hold
        self.seed = seed
        self.k = 0
        self.block: np.ndarray | None = None

    def make_block(self, index: int) -> np.ndarray:
        """Block ``index`` of the PRBS, (BLOCK, m)."""
        return prbs(self.BLOCK, self.m, amplitude=self.amplitude, min_hold=self.hold, seed=self.seed * 1009 + index)

    def prepare(self) -> None:
        """Make the first block now, off the tick path: making one imports scipy.signal, a stall on a tick."""
        self.block = self.make_block(0)

    def next(self) -> np.ndarray:
        """This tick's sample (m,)."""
        j = self.k % self.BLOCK
        if self.block is None or (j == 0 and self.k > 0):
            self.block = self.make_block(self.k // self.BLOCK)
        self.k += 1
        return self.block[j]
