"""The JSON reports under ``reports/`` that several make targets share: each target replaces only its own
top-level sections (``make demo`` the simulator's, ``make adapt-eval`` ``adaptation`` in summary.json;
``make sitl-demo`` the autopilots, ``make sitl-adapt`` ``adaptation`` in sitl.json)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Callable

__all__ = ["update_report", "nan_as_null"]


def nan_as_null(o: Any) -> Any:
    """``json.dumps`` default for the SITL reports: NaN -> null, anything else unknown -> its str."""
    if isinstance(o, float) and math.isnan(o):
        return None
    return str(o)


def update_report(path: Path, updates: dict, default: Callable[[Any], Any] | None = None) -> dict:
    """Replace the top-level keys ``updates`` names in the JSON object at ``path`` (created if absent) and keep
    the others, which other targets measured; the result. ``default``: as ``json.dumps``'s.

    Raises:
        ValueError: the file there is not a JSON object (it is left as it is).
    """
    path = Path(path)
    try:
        report = json.loads(path.read_text()) if path.is_file() else {}
    except json.JSONDecodeError as e:
        raise ValueError(f"{path}: not valid JSON ({e}); move it away to start a new report") from None
    if not isinstance(report, dict):
        raise ValueError(f"{path}: expected a JSON object, got {type(report).__name__}")
    report.update(updates)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(report, indent=2, default=default) + "\n")
    return report
