"""Piecewise-linear knots over the horizon: the steered references u (m*Tf) = B v with v (m*K) the
references at K knot samples, so a long horizon keeps a small QP.

Knots are sample indices 0 = k_0 < k_1 < ... < k_{K-1} = Tf-1; between two knots each reference is the
straight line through its knot values, so u at a knot *is* the knot value (B has an identity row there)
and every u_k is a convex combination of two knot values. Hence a box on u holds on the whole horizon
exactly when it holds at the knots, and a rate bound holds on the whole horizon exactly when it holds
on the first increment and on each segment's slope (the increments inside a segment are all equal).
"""

from __future__ import annotations

import numpy as np

__all__ = ["knot_positions", "knot_basis", "distinct_rows"]


def knot_positions(knots: int | list[int] | tuple[int, ...], t_f: int) -> tuple[int, ...]:
    """Knot sample indices for ``knots`` (a count, or the indices themselves) over a horizon of ``t_f``.

    A count K spaces the knots quadratically, (Tf-1) (i/(K-1))^2 rounded and made strictly increasing:
    short segments where the next moves are decided, long ones where the plan is only a preview.
    Raises ValueError with the reason for a count outside 2..Tf or indices that are not
    0 = k_0 < ... < k_{K-1} = Tf-1.
    """
    if isinstance(knots, (int, np.integer)) and not isinstance(knots, bool):
        k = int(knots)
        if not 2 <= k <= t_f:
            raise ValueError(f"must be between 2 and t_f = {t_f} knots; got {k}")
        raw = np.rint((t_f - 1) * (np.arange(k) / (k - 1)) ** 2).astype(int)
        pos = [0]
        for i in range(1, k):
            # strictly increasing, and leave room for the knots still to come
            pos.append(min(max(pos[-1] + 1, int(raw[i])), t_f - 1 - (k - 1 - i)))
        return tuple(pos)
    if not isinstance(knots, (list, tuple)) or not all(
            isinstance(x, (int, np.integer)) and not isinstance(x, bool) for x in knots):
        raise ValueError(f"must be a number of knots or a list of sample indices; got {knots!r}")
    pos = tuple(int(x) for x in knots)
    if len(pos) < 2 or pos[0] != 0 or pos[-1] != t_f - 1 or any(b <= a for a, b in zip(pos, pos[1:])):
        raise ValueError(f"sample indices must increase strictly from 0 to t_f - 1 = {t_f - 1}; got {list(pos)}")
    return pos


def knot_basis(positions: tuple[int, ...], t_f: int, m: int) -> np.ndarray:
    """B (m*Tf, m*K): time-major u = B v, v the time-major knot values (linear interpolation per channel)."""
    b = np.zeros((t_f, len(positions)))
    for j, (k0, k1) in enumerate(zip(positions, positions[1:])):
        a = (np.arange(k0, k1 + 1) - k0) / (k1 - k0)
        b[k0 : k1 + 1, j] = 1.0 - a
        b[k0 : k1 + 1, j + 1] = a
    return np.kron(b, np.eye(m))


def distinct_rows(A: np.ndarray, rhs: np.ndarray, rtol: float = 1e-12) -> np.ndarray:
    """Indices of the rows of [A | rhs] to keep: the first of each group of rows equal to within
    ``rtol`` x the row's largest entry, and no row that is all zero (such a row bounds nothing as long as
    its bounds contain 0, which the caller guarantees).

    Blocked increments repeat one row per tick of a segment; a QP handed copies of a row is degenerate
    for an active-set method, and the copies add nothing once one of them holds.
    """
    M = np.hstack([A, rhs.reshape(len(A), -1)])
    scale = np.max(np.abs(M), axis=1)
    keep: list[int] = []
    for i in np.nonzero(scale > 0)[0]:
        if not any(np.max(np.abs(M[i] - M[j])) <= rtol * max(scale[i], scale[j]) for j in keep):
            keep.append(int(i))
    return np.array(keep, dtype=int)
