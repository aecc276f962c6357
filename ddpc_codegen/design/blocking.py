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

__all__ = ["knot_basis", "distinct_rows"]


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
