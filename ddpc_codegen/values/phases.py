"""Phase labels of a hybrid robot's samples (int8 in datasets); flying is one continuous phase."""

import numpy as np

__all__ = ["FLYING", "DESCENT", "GROUND", "ASCENT", "PHASE_NAMES", "ground_runs"]

FLYING, DESCENT, GROUND, ASCENT = 0, 1, 2, 3
PHASE_NAMES = {FLYING: "flying", DESCENT: "descent", GROUND: "ground", ASCENT: "ascent"}


def ground_runs(phase: np.ndarray) -> list[tuple[int, int]]:
    """[start, end) index pairs of every run of GROUND labels in a phase array."""
    g = np.asarray(phase) == GROUND
    edges = np.flatnonzero(np.diff(np.r_[0, g.astype(np.int8), 0]))
    return [(int(a), int(b)) for a, b in zip(edges[0::2], edges[1::2])]
