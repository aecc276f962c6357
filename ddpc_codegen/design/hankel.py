"""Block and mosaic Hankel matrices, and the persistency-of-excitation check.

Block Hankel of depth L of a time-major signal w (T, d): shape (L*d, T-L+1), block row i,
column j equal to w[i+j]. Several trajectories are joined column-wise (mosaic), never by
concatenating the signals.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from ddpc_codegen.errors import DataError

__all__ = ["block_hankel", "mosaic_hankel", "persistency_of_excitation", "PEReport"]


def _signal(w: np.ndarray, what: str = "signal") -> np.ndarray:
    a = np.asarray(w, dtype=float)
    if a.ndim == 1:
        a = a[:, None]
    if a.ndim != 2:
        raise DataError(f"{what} must be time-major (T, channels); got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise DataError(f"{what} contains NaN or inf; clean the data before building a Hankel matrix")
    return a


def block_hankel(w: np.ndarray, depth: int) -> np.ndarray:
    """Block Hankel matrix of depth ``depth`` of ``w`` (T, d) -> (depth*d, T-depth+1)."""
    a = _signal(w)
    depth = int(depth)
    T, d = a.shape
    if depth < 1:
        raise DataError(f"Hankel depth must be >= 1; got {depth}")
    if T < depth:
        raise DataError(f"a Hankel matrix of depth {depth} needs at least {depth} samples; got {T}")
    # windows[j] = a[j:j+depth] -> (cols, depth, d); column j stacks them time-major.
    windows = sliding_window_view(a, (depth, d))[:, 0]
    return np.ascontiguousarray(windows.reshape(T - depth + 1, depth * d).T)


def mosaic_hankel(trajectories: Sequence[np.ndarray], depth: int) -> np.ndarray:
    """Mosaic Hankel: the column-wise concatenation of each trajectory's block Hankel.

    Trajectories shorter than ``depth`` contribute no column (they cannot hold a window).
    Raises DataError when no trajectory is long enough or channel counts differ.
    """
    sigs = [_signal(w, f"trajectory {i}") for i, w in enumerate(trajectories)]
    if not sigs:
        raise DataError("mosaic_hankel needs at least one trajectory")
    d = sigs[0].shape[1]
    for i, s in enumerate(sigs):
        if s.shape[1] != d:
            raise DataError(f"trajectory {i} has {s.shape[1]} channels, trajectory 0 has {d}")
    blocks = [block_hankel(s, depth) for s in sigs if s.shape[0] >= depth]
    if not blocks:
        longest = max(s.shape[0] for s in sigs)
        raise DataError(
            f"no trajectory is long enough for depth {depth} (longest has {longest} samples)"
        )
    return np.hstack(blocks)


@dataclass(frozen=True)
class PEReport:
    """Result of a persistency-of-excitation check of order ``order``.

    ``ok`` is True when H_order(u) has full row rank ``required_rank = m*order`` numerically,
    i.e. singular values above ``tol``.
    """

    order: int
    rank: int
    required_rank: int
    singular_values: np.ndarray
    tol: float
    condition_number: float
    columns: int

    @property
    def ok(self) -> bool:
        return self.rank >= self.required_rank

    def __bool__(self) -> bool:
        return self.ok

    def summary(self) -> str:
        s = self.singular_values
        smin = s[-1] if s.size else 0.0
        verdict = "persistently exciting" if self.ok else "NOT persistently exciting"
        return (
            f"{verdict} of order {self.order}: rank {self.rank}/{self.required_rank} "
            f"({self.columns} Hankel columns), sigma_max={s[0] if s.size else 0.0:.3g}, "
            f"sigma_min={smin:.3g}, tol={self.tol:.3g}, cond={self.condition_number:.3g}"
        )


def persistency_of_excitation(
    u: np.ndarray | Sequence[np.ndarray], order: int, tol: float | None = None
) -> PEReport:
    """Check that input data is persistently exciting of ``order`` (rank of H_order(u)).

    Args:
        u: input (T, m), or a list of trajectories (mosaic Hankel).
        order: Hankel depth, L + n for the fundamental lemma (L = Tini + Tf, n = state dim).
        tol: singular-value threshold; default ``max(shape) * eps * sigma_max`` (numpy's rank rule).
    """
    trajs = [u] if isinstance(u, np.ndarray) else list(u)
    m = _signal(trajs[0], "u").shape[1]
    required = m * int(order)
    try:
        H = mosaic_hankel(trajs, order)
    except DataError:
        cols = 0
        s = np.zeros(0)
        return PEReport(int(order), 0, required, s, float(tol or 0.0), float("inf"), cols)
    s = np.linalg.svd(H, compute_uv=False)
    if tol is None:
        tol = float(max(H.shape) * np.finfo(float).eps * (s[0] if s.size else 0.0))
    rank = int(np.sum(s > tol))
    cond = float(s[0] / s[-1]) if s.size and s[-1] > 0 else float("inf")
    if H.shape[1] < required:
        cond = float("inf")
    return PEReport(int(order), rank, required, s, float(tol), cond, H.shape[1])
