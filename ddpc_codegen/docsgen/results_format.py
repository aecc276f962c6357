"""Cell formatting and Markdown tables shared by the results pages (``docsgen.results_*``).

Every figure on a results page goes through these helpers, so a unit and its digits read the same on every
page: lengths in mm, ratios as ``1.23``, a missing figure as ``--``.
"""

from __future__ import annotations

import math
from typing import Any

__all__ = ["NA", "SIMPLE_FIXES", "LABELS", "num", "mm", "ratio", "table", "best_simple_fix", "missing",
           "page_head", "label", "tally"]

NA = "--"
# what an engineer tries before steering: the controller's own feed-forward, a prefilter fitted on the same
# data, iterative learning control; passthrough (the path as it is) is shown beside them, not counted as a fix
SIMPLE_FIXES = ("ctrl_ff", "prefilter", "ilc")
LABELS = {"passthrough": "passthrough", "ctrl_ff": "ctrl ff", "prefilter": "prefilter", "ilc": "ILC",
          "steered": "steered", "ddpc": "steered", "px4": "PX4", "ardupilot": "ArduPilot"}


def label(key: str) -> str:
    """The name a page shows for a report key (method or autopilot)."""
    return LABELS.get(key, key.replace("_", " "))


def num(v: Any, scale: float = 1.0, digits: int = 1) -> str:
    """``v * scale`` with ``digits`` decimals; ``--`` for None, NaN or inf."""
    if v is None or not isinstance(v, (int, float)) or not math.isfinite(v):
        return NA
    return f"{v * scale:.{digits}f}"


def mm(v: Any, digits: int = 1) -> str:
    """A length in m as mm."""
    return num(v, 1e3, digits)


def ratio(a: Any, b: Any, digits: int = 2) -> str:
    """``a / b`` (``--`` when either is missing or b is 0)."""
    if a is None or b is None or not isinstance(a, (int, float)) or not isinstance(b, (int, float)) or b == 0:
        return NA
    return num(a / b, 1.0, digits)


def table(head: list[str] | tuple[str, ...], rows: list[list[str]] | list[tuple[str, ...]]) -> str:
    """A Markdown table; a pipe inside a cell (``mean |apex err|``) is escaped."""
    esc = lambda c: str(c).replace("|", "\\|")  # noqa: E731
    lines = ["| " + " | ".join(esc(h) for h in head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(esc(c) for c in r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def best_simple_fix(values: dict[str, Any], methods: tuple[str, ...] = SIMPLE_FIXES) -> tuple[str, float] | None:
    """The simple fix with the lowest error among ``values`` (method -> error; None or non-finite: not flown)."""
    flown = [(values[m], m) for m in methods
             if isinstance(values.get(m), (int, float)) and math.isfinite(values[m])]
    if not flown:
        return None
    v, m = min(flown)
    return m, v


def tally(pairs: list[tuple[Any, Any]]) -> str:
    """The sentence that counts the conditions where the steering beat every simple fix (``pairs``: the steered
    error and the best simple fix's; a pair with a missing value is not counted)."""
    flown = [(s, b) for s, b in pairs if isinstance(s, (int, float)) and isinstance(b, (int, float)) and b > 0]
    better = sum(s < b for s, b in flown)
    return (f"Steered / best simple fix below 1 (the steering better than every simple fix) in {better} of "
            f"{len(flown)} conditions.\n")


def missing(target: str, report: str) -> str:
    """The paragraph that stands for a campaign not measured yet."""
    return f"Not measured yet -- run `{target}` (it writes `reports/{report}` and rewrites this page).\n"


def page_head(title: str, intro: str) -> str:
    """A results page's title, its do-not-edit marker and its first paragraph."""
    return (f"# {title}\n\n<!-- written by python -m ddpc_codegen.docsgen.results from reports/*.json: "
            f"edit the code, not this page -->\n\n{intro}\n")
