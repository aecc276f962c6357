"""The controller's closed loop as the steering sees it, per mode: the references it takes (the
loop's inputs u) and the outputs it tracks (y), and the check of a setting given per reference
(a step guard, a blend rate, an excitation amplitude) shared by the robot profile and the bridge.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["REFERENCES", "OUTPUTS", "check_per_reference"]

# The references the controller takes (the closed loop's inputs) and the outputs it tracks, per mode.
REFERENCES = {"flying": ("z_ref", "pitch_ref"), "hopping": ("z_ref", "roll_ref", "pitch_ref")}
OUTPUTS = {"flying": ("z", "pitch"), "hopping": ("z", "roll", "pitch")}


def check_per_reference(key: str, values, mode: str, *, zero_ok: bool = False) -> tuple[float, ...] | None:
    """A per-reference setting (a step guard, a blend rate, an excitation amplitude) checked for the
    ``mode`` loop: one finite number per reference, > 0 (>= 0 with ``zero_ok``); None passes.

    Raises:
        ValueError: naming ``key``, the loop's references and the value.
    """
    if values is None:
        return None
    refs = REFERENCES[mode]
    seq = isinstance(values, (list, tuple)) or (isinstance(values, np.ndarray) and values.ndim == 1)
    flat = list(values) if seq else [values]
    if not seq or len(flat) != len(refs):
        raise ValueError(f"{key} needs {len(refs)} values on the {mode} loop ({', '.join(refs)}); got {values!r}")
    ok = all(not isinstance(v, bool) and isinstance(v, (int, float, np.floating, np.integer)) and math.isfinite(v)
             and (v >= 0.0 if zero_ok else v > 0.0) for v in flat)
    if not ok:
        raise ValueError(f"{key} must be finite and {'>= 0' if zero_ok else '> 0'} per reference; got {values!r}")
    return tuple(float(v) for v in flat)
