"""Measured test durations (``tests/durations.json``) and what follows from them: the ``slow`` marker,
the order in which xdist hands out test files, and the check that explicit ``slow`` markers are honest.

The file holds, per test node id, the seconds its setup + call + teardown took less any session-scoped
fixture built during it (paid once per run, whichever test comes first), and, per non-session fixture
(``<baseid>::<name>``), the seconds its setup took. A test is slow when its own time or the setup of a
module/class/function fixture it uses reaches ``threshold_s``: running it alone costs that much.
Re-record with ``make test-durations`` (a serial run, so the figures are not inflated by a second worker).
"""

from __future__ import annotations

import json
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

import pytest

FILE = Path(__file__).resolve().parents[1] / "durations.json"
THRESHOLD_S = 10.0
# an explicit ``slow`` marker is called dishonest below this fraction of the threshold (the figures
# move with the machine's load: 2.5 s is four times faster than slow)
HONEST_FRACTION = 0.25
FIXTURE_FLOOR_S = 0.5


@dataclass
class Durations:
    """Recorded seconds per test node id and per non-session fixture key (``<baseid>::<name>``)."""

    tests: dict[str, float] = field(default_factory=dict)
    fixtures: dict[str, float] = field(default_factory=dict)
    threshold_s: float = THRESHOLD_S

    @classmethod
    def load(cls, path: Path = FILE) -> Durations:
        """The file's figures; an absent file is empty (nothing is then marked from measurements)."""
        if not path.exists():
            return cls()
        d = json.loads(path.read_text())
        return cls(dict(d["tests"]), dict(d["fixtures"]), float(d["threshold_s"]))

    def save(self, path: Path = FILE) -> None:
        """Write sorted, rounded to 10 ms (figures move more than that between runs); fixtures under
        ``FIXTURE_FLOOR_S`` are left out (they cannot make a test slow, and there are hundreds)."""
        d = {"threshold_s": self.threshold_s,
             "tests": {k: round(v, 2) for k, v in sorted(self.tests.items())},
             "fixtures": {k: round(v, 2) for k, v in sorted(self.fixtures.items()) if v >= FIXTURE_FLOOR_S}}
        path.write_text(json.dumps(d, indent=1) + "\n")

    def merge(self, tests: dict[str, float], fixtures: dict[str, float], root: Path) -> None:
        """Replace the figures of what ran; drop the entries of test files that no longer exist."""
        self.tests.update(tests)
        self.fixtures.update(fixtures)
        self.tests = {k: v for k, v in self.tests.items() if (root / k.split("::")[0]).exists()}
        self.fixtures = {k: v for k, v in self.fixtures.items()
                         if not k.split("::")[0] or (root / k.split("::")[0]).exists()}


# what tests/conftest.py computes at collection, for tests/test_durations.py to check
DURATIONS = pytest.StashKey[Durations]()
DISHONEST = pytest.StashKey[list]()  # node ids whose own slow marker contradicts the file
SHARED_ACROSS_TIERS = pytest.StashKey[list]()  # module fixtures used by both phases of make test


def fixture_keys(item: pytest.Item) -> Iterable[tuple[str, str]]:
    """(key, scope) of every fixture that ``item`` uses, directly or through other fixtures."""
    info = getattr(item, "_fixtureinfo", None)
    if info is None:
        return []
    return [(f"{defs[-1].baseid}::{name}", defs[-1].scope) for name, defs in info.name2fixturedefs.items()]


def measured_seconds(item: pytest.Item, d: Durations) -> float | None:
    """What running ``item`` alone costs by the file: its own time or its costliest non-session fixture."""
    own = d.tests.get(item.nodeid)
    fix = [d.fixtures[k] for k, scope in fixture_keys(item) if scope != "session" and k in d.fixtures]
    vals = ([own] if own is not None else []) + fix
    return max(vals) if vals else None


def is_slow(item: pytest.Item, d: Durations) -> bool:
    """Measured at or above the threshold (unmeasured tests are not called slow)."""
    s = measured_seconds(item, d)
    return s is not None and s >= d.threshold_s


def dishonest_slow_markers(items: Iterable[pytest.Item], d: Durations) -> list[str]:
    """Node ids whose own ``slow`` marker (in the source) contradicts a measurement far below the threshold."""
    out = []
    for it in items:
        if any(m.name == "slow" for m in it.iter_markers()) and not getattr(it, "_slow_from_durations", False):
            s = measured_seconds(it, d)
            if s is not None and s < HONEST_FRACTION * d.threshold_s:
                out.append(f"{it.nodeid} ({s:.1f} s)")
    return out


def heaviest_files_first(items: list[pytest.Item], d: Durations) -> list[pytest.Item]:
    """Items regrouped by file, the files in decreasing recorded total (stable otherwise), so that
    xdist's per-file scheduling starts the long files first and the run does not end on one of them."""
    by_file: dict[str, list[pytest.Item]] = {}
    for it in items:
        by_file.setdefault(it.nodeid.split("::")[0], []).append(it)

    def total(f: str) -> float:
        return sum(d.tests.get(it.nodeid, 0.0) for it in by_file[f])

    order = sorted(by_file, key=lambda f: -total(f))  # sorted() is stable: unmeasured files keep their order
    return [it for f in order for it in by_file[f]]
