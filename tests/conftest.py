"""Shared fixtures and the hooks that keep the test loop honest and fast (helpers live in ``tests/support``;
nothing is imported from here).

- ``slow`` is set from ``tests/durations.json`` (:mod:`support.durations`): a test is slow when it, or a
  non-session fixture it uses, was measured at >= 10 s. ``--record-durations`` re-measures what runs.
- Under pytest-xdist the test files are handed out longest first (recorded totals).
- One BLAS thread per test process and its children (unless the environment sets one): the tests'
  matrices are small, and OpenBLAS's spinning threads cost several times the CPU when xdist workers or
  other processes share the cores.
- The xdist workers share the rewriting of the test modules' asserts (:mod:`support.rewrite_share`): on a
  fresh clone each module is rewritten about once per run instead of once per worker.
- C compiles go through :mod:`support.cc_cache` (``CC`` for the session, its subprocesses included): the
  library sources every generated folder carries are compiled once per run, not once per solver.
  ``DDPC_TEST_CC_CACHE=0`` compiles everything afresh.
"""

from __future__ import annotations

import os
import time
from collections import defaultdict

import pytest
from threadpoolctl import threadpool_limits

from support.durations import (
    DISHONEST,
    DURATIONS,
    SHARED_ACROSS_TIERS,
    Durations,
    dishonest_slow_markers,
    fixture_keys,
    heaviest_files_first,
    is_slow,
)
from support.cc_cache import install as install_cc_cache
from support.lti import random_lti
from support.rewrite_share import share_rewrites
from support.solver_cache import cache_root

_FIXTURE_PROP = "ddpc_fixture_setup"


@pytest.fixture
def lti_factory():
    """``random_lti(n, m, p, seed, radius=0.9, feedthrough=False)``."""
    return random_lti


@pytest.fixture(scope="session", autouse=True)
def _compile_cache(tmp_path_factory):
    """``CC`` = the object-reusing wrapper for the whole session (objects shared like the solver cache)."""
    if os.environ.get("DDPC_TEST_CC_CACHE", "1") == "0":
        yield
        return
    settings = install_cc_cache(cache_root(tmp_path_factory.getbasetemp()) / "cc", dict(os.environ))
    with pytest.MonkeyPatch.context() as mp:
        for k, v in settings.items():
            mp.setenv(k, v)
        yield


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--record-durations", action="store_true",
                     help="measure every test and non-session fixture that runs into tests/durations.json "
                          "(run serially: a second worker inflates the figures)")


BLAS_THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def one_blas_thread() -> None:
    """BLAS threads for this process (now, numpy being loaded) and its subprocesses: 1 unless set."""
    for var in BLAS_THREAD_VARS:
        os.environ.setdefault(var, "1")
    threadpool_limits(int(os.environ["OPENBLAS_NUM_THREADS"]), user_api="blas")


def pytest_configure(config: pytest.Config) -> None:
    one_blas_thread()
    config.stash[DURATIONS] = Durations.load()
    if config.getoption("record_durations"):
        config.pluginmanager.register(FixtureTimer(), "ddpc-fixture-timer")
        if not os.environ.get("PYTEST_XDIST_WORKER"):
            config.pluginmanager.register(DurationRecorder(config), "ddpc-duration-recorder")


def pytest_sessionstart(session: pytest.Session) -> None:
    share_rewrites(session.config)


@pytest.hookimpl(tryfirst=True)  # before -m deselects, so that `-m "not slow"` sees the measured markers
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    d = config.stash[DURATIONS]
    config.stash[DISHONEST] = dishonest_slow_markers(items, d)
    config.stash[SHARED_ACROSS_TIERS] = fixtures_shared_across_tiers(items)
    for it in items:
        if is_slow(it, d):
            it.add_marker(pytest.mark.slow)
            it._slow_from_durations = True  # type: ignore[attr-defined]
    group_module_fixture_users(items)
    if os.environ.get("PYTEST_XDIST_WORKER"):
        items[:] = heaviest_files_first(items, d)


def group_module_fixture_users(items: list[pytest.Item]) -> None:
    """The realtime tier runs on several workers (``--dist loadgroup``): the tests of one module fixture (one
    set of flights) share an ``xdist_group`` so the flights are flown once; every other realtime test goes to
    whichever worker is free."""
    for it in items:
        if it.get_closest_marker("realtime") is None or it.get_closest_marker("sitl") is not None:
            continue
        keys = sorted(k for k, scope in fixture_keys(it) if scope in ("module", "class", "package"))
        if keys and it.get_closest_marker("xdist_group") is None:
            it.add_marker(pytest.mark.xdist_group(keys[0]))


def serial_tier(item: pytest.Item) -> bool:
    """The tiers that measure wall-clock time and so run alone (``make test``'s second phase)."""
    return item.get_closest_marker("realtime") is not None or item.get_closest_marker("sitl") is not None


def fixtures_shared_across_tiers(items: list[pytest.Item]) -> list[str]:
    """Module/class fixtures used by tests of both phases of ``make test`` (each phase would build them)."""
    tiers: dict[str, set[bool]] = defaultdict(set)
    for it in items:
        for key, scope in fixture_keys(it):
            if scope in ("module", "class", "package"):
                tiers[key].add(serial_tier(it))
    return sorted(k for k, t in tiers.items() if len(t) == 2)


class FixtureTimer:
    """Times each fixture's setup and notes it on the test being set up (reports carry it to xdist's controller)."""

    @pytest.hookimpl(hookwrapper=True)
    def pytest_fixture_setup(self, fixturedef, request):
        t0 = time.perf_counter()
        yield
        item = getattr(request, "_pyfuncitem", None)
        if item is not None:
            item.user_properties.append((_FIXTURE_PROP, f"{fixturedef.baseid}::{fixturedef.argname}",
                                         fixturedef.scope, time.perf_counter() - t0))


class DurationRecorder:
    """Sums each test's phases (less session fixtures) and keeps each fixture's setup; merged into the file at the end."""

    def __init__(self, config: pytest.Config) -> None:
        self.config = config
        self.total: dict[str, float] = defaultdict(float)
        self.session_cost: dict[str, float] = defaultdict(float)
        self.fixtures: dict[str, float] = {}
        self.unmeasured: set[str] = set()

    def pytest_runtest_logreport(self, report: pytest.TestReport) -> None:
        self.total[report.nodeid] += report.duration
        if not report.passed:
            # a skipped SITL test or one that errored early must not overwrite its real figure
            self.unmeasured.add(report.nodeid)
        if report.when != "teardown":
            return
        for prop in report.user_properties:
            if isinstance(prop, (tuple, list)) and len(prop) == 4 and prop[0] == _FIXTURE_PROP:
                _, key, scope, secs = prop
                if scope == "session":
                    self.session_cost[report.nodeid] += secs
                else:
                    self.fixtures[key] = max(self.fixtures.get(key, 0.0), secs)

    def pytest_sessionfinish(self, session: pytest.Session, exitstatus: int) -> None:
        if exitstatus == pytest.ExitCode.INTERRUPTED:
            return  # a cut-short run measured a part of what it started
        tests = {k: max(0.0, v - self.session_cost[k]) for k, v in self.total.items() if k not in self.unmeasured}
        d = Durations.load()
        d.merge(tests, self.fixtures, self.config.rootpath)
        d.save()


def pytest_terminal_summary(terminalreporter, config: pytest.Config) -> None:
    """Name the tests that took >= 1.5x the threshold here without being marked slow (durations.json is stale)."""
    d = config.stash[DURATIONS]
    stale = []
    for rep in terminalreporter.stats.get("passed", []) + terminalreporter.stats.get("failed", []):
        if rep.when == "call" and rep.duration >= 1.5 * d.threshold_s and "slow" not in rep.keywords:
            stale.append(f"{rep.nodeid} ({rep.duration:.0f} s)")
    if stale:
        terminalreporter.write_line("not marked slow but took >= %.0f s here (re-record: make test-durations): %s"
                                    % (1.5 * d.threshold_s, ", ".join(stale)), yellow=True)
