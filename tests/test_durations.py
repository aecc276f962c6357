"""The test loop's labels: measured durations set ``slow``, explicit markers agree with the measurements,
both phases of ``make test`` build their own module fixtures, and the shared solver cache builds once."""

from __future__ import annotations

import json
import os
import threading
from pathlib import Path
from types import SimpleNamespace

import pytest
from threadpoolctl import threadpool_info

from support.durations import (
    DISHONEST,
    FILE,
    SHARED_ACROSS_TIERS,
    THRESHOLD_S,
    Durations,
    dishonest_slow_markers,
    heaviest_files_first,
    is_slow,
    measured_seconds,
)
from support.solver_cache import cache_key, shared_build

ROOT = Path(__file__).resolve().parents[1]


def fake_item(nodeid: str, fixtures: dict[str, tuple[str, str]] = (), markers: tuple[str, ...] = ()):
    """A stand-in with what the helpers read: nodeid, the fixture closure {name: (baseid, scope)}, markers."""
    defs = {name: [SimpleNamespace(baseid=b, scope=s)] for name, (b, s) in dict(fixtures).items()}
    return SimpleNamespace(nodeid=nodeid, _fixtureinfo=SimpleNamespace(name2fixturedefs=defs),
                           iter_markers=lambda: [SimpleNamespace(name=m) for m in markers])


# ------------------------------------------------------------------------------ the committed file
def test_the_committed_file_names_existing_test_files_only():
    d = Durations.load()
    assert d.threshold_s == THRESHOLD_S
    assert d.tests, "tests/durations.json is empty: run make test-durations"
    missing = sorted({k.split("::")[0] for k in d.tests if not (ROOT / k.split("::")[0]).exists()})
    assert missing == [], "stale entries: any make test-durations PYTEST_ARGS=<path> run drops deleted files"
    assert all(v >= 0 for v in list(d.tests.values()) + list(d.fixtures.values()))


def test_no_explicit_slow_marker_contradicts_its_measurement(request):
    assert request.config.stash[DISHONEST] == [], (
        "marked slow in the source but measured far below %.0f s (tests/durations.json)" % THRESHOLD_S)


def test_no_module_fixture_is_built_in_both_phases_of_make_test(request):
    # a module fixture used by a realtime/sitl test and by another test would be built once per phase
    assert request.config.stash[SHARED_ACROSS_TIERS] == []


# ------------------------------------------------------------------------------ the rules
def test_a_test_is_slow_by_its_own_time_or_a_non_session_fixture():
    d = Durations(tests={"a.py::t1": 12.0, "a.py::t2": 0.1, "a.py::t3": 0.1, "a.py::t4": 0.2},
                  fixtures={"a.py::flight": 40.0, "::solver": 30.0, "a.py::cheap": 1.0})
    assert is_slow(fake_item("a.py::t1"), d)
    assert is_slow(fake_item("a.py::t2", {"flight": ("a.py", "module")}), d)
    # a session fixture is paid once per run, whoever comes first: it does not make its users slow
    assert not is_slow(fake_item("a.py::t3", {"solver": ("", "session")}), d)
    assert not is_slow(fake_item("a.py::t4", {"cheap": ("a.py", "module")}), d)
    assert not is_slow(fake_item("a.py::unmeasured"), d)
    assert measured_seconds(fake_item("a.py::unmeasured"), d) is None
    assert measured_seconds(fake_item("a.py::t2", {"flight": ("a.py", "module")}), d) == 40.0
    assert is_slow(fake_item("a.py::edge"), Durations(tests={"a.py::edge": THRESHOLD_S}))


def test_an_explicit_slow_marker_on_a_fast_test_is_named():
    d = Durations(tests={"a.py::fast": 0.3, "a.py::slowish": 6.0, "a.py::long": 30.0})
    items = [fake_item("a.py::fast", markers=("slow",)), fake_item("a.py::slowish", markers=("slow",)),
             fake_item("a.py::long", markers=("slow",)), fake_item("a.py::new", markers=("slow",)),
             fake_item("a.py::fast")]
    assert dishonest_slow_markers(items, d) == ["a.py::fast (0.3 s)"]


def test_files_are_handed_out_longest_first_and_stay_together():
    d = Durations(tests={"a.py::1": 1.0, "a.py::2": 1.0, "b.py::1": 5.0, "c.py::1": 0.5})
    items = [fake_item(n) for n in ("a.py::1", "c.py::1", "a.py::2", "b.py::1", "d.py::1")]
    got = [it.nodeid for it in heaviest_files_first(items, d)]
    assert got == ["b.py::1", "a.py::1", "a.py::2", "c.py::1", "d.py::1"]


def test_merge_replaces_what_ran_and_drops_deleted_files(tmp_path):
    (tmp_path / "kept.py").write_text("")
    d = Durations(tests={"kept.py::a": 1.0, "kept.py::b": 2.0, "gone.py::a": 3.0},
                  fixtures={"gone.py::f": 9.0, "::g": 4.0, "kept.py::h": 20.0})
    d.merge({"kept.py::a": 5.0}, {"kept.py::f": 11.0, "kept.py::h": 0.1}, tmp_path)
    assert d.tests == {"kept.py::a": 5.0, "kept.py::b": 2.0}
    assert d.fixtures == {"::g": 4.0, "kept.py::f": 11.0, "kept.py::h": 0.1}
    d.save(tmp_path / "d.json")
    # a fixture that became cheap is forgotten, not kept at its old figure
    assert Durations.load(tmp_path / "d.json") == Durations(d.tests, {"::g": 4.0, "kept.py::f": 11.0})
    assert json.loads((tmp_path / "d.json").read_text())["threshold_s"] == THRESHOLD_S
    assert Durations.load(tmp_path / "absent.json") == Durations()


def test_the_committed_file_is_the_one_the_hooks_read():
    assert FILE == ROOT / "tests" / "durations.json" and FILE.exists()


# ------------------------------------------------------------------------------ the shared build
def test_shared_build_builds_once_for_concurrent_callers(tmp_path):
    calls = []

    def build(folder: Path) -> None:
        calls.append(folder)
        (folder / "out.txt").write_text("x")

    recipe = {"what": "probe", "n": 1}
    results: list[Path] = []
    threads = [threading.Thread(target=lambda: results.append(shared_build(tmp_path, recipe, build)))
               for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(30)
    assert len(calls) == 1 and len(set(results)) == 1 and (results[0] / "out.txt").read_text() == "x"
    assert results[0].name == cache_key(recipe) and cache_key({"what": "probe", "n": 2}) != cache_key(recipe)


def test_a_failed_build_leaves_nothing_that_counts_as_built(tmp_path):
    def broken(folder: Path) -> None:
        (folder / "half.txt").write_text("half")
        raise RuntimeError("compiler died")

    with pytest.raises(RuntimeError, match="compiler died"):
        shared_build(tmp_path, {"what": "probe"}, broken)
    folder = shared_build(tmp_path, {"what": "probe"}, lambda f: (f / "whole.txt").write_text("whole"))
    assert sorted(p.name for p in folder.iterdir()) == [".complete", "whole.txt"]



# ------------------------------------------------------------------------------ the test processes
def test_blas_runs_one_thread_unless_the_environment_says_otherwise():
    blas = [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]  # numpy is loaded
    assert blas and set(blas) == {int(os.environ.get("OPENBLAS_NUM_THREADS", "0"))}
