"""Phase labels of a hybrid robot's samples (int8 in datasets); flying is one continuous phase."""

__all__ = ["FLYING", "DESCENT", "GROUND", "ASCENT", "PHASE_NAMES"]

FLYING, DESCENT, GROUND, ASCENT = 0, 1, 2, 3
PHASE_NAMES = {FLYING: "flying", DESCENT: "descent", GROUND: "ground", ASCENT: "ascent"}
