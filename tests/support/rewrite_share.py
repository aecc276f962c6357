"""Share pytest's assertion rewriting between the xdist workers of one run.

Why: every worker imports every test module to collect it, and pytest rewrites a test module's asserts (and
caches the result as a ``__pycache__/*-pytest-*.pyc``) on first import. On a fresh clone no cached file
exists yet and the workers start together, so each of them rewrote every module (~4 s of CPU per worker,
all at once). Here each worker first rewrites the modules of its own share (a rotation of the sorted list
starting at its index), then walks on through the others' shares, which by then are mostly cached: each
module is rewritten about once per run. What a test module runs is pytest's own rewrite either way; this
only chooses which process writes the cached file first.

It reaches into ``_pytest.assertion.rewrite`` (no public API does this); on any error it gives up quietly
and collection rewrites as before.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest


def test_modules(config: pytest.Config) -> list[Path] | None:
    """The test modules and conftest files under the run's arguments, sorted; None when an argument is not a
    directory (a narrowed run: not worth it)."""
    dirs = [Path(a) for a in config.args]
    if not dirs or not all(d.is_dir() for d in dirs):
        return None
    files = {p.resolve() for d in dirs for pat in ("test_*.py", "conftest.py") for p in d.rglob(pat)}
    return sorted(p for p in files if "__pycache__" not in p.parts)


def rotation(files: list[Path], worker: str, count: int) -> list[Path]:
    """``files`` starting at worker ``gw<i>``'s share (i / count of the way in)."""
    i = int(worker[2:]) if worker[:2] == "gw" and worker[2:].isdigit() else 0
    start = (i * len(files)) // max(1, count)
    return files[start:] + files[:start]


def share_rewrites(config: pytest.Config) -> int:
    """In an xdist worker: write the rewritten-module caches missing for this run's test modules, this worker's
    share first. The number this worker rewrote (0 outside a worker or when bytecode is not written)."""
    worker = os.environ.get("PYTEST_XDIST_WORKER")
    if not worker or sys.dont_write_bytecode or config.getoption("assertmode") != "rewrite":
        return 0
    try:
        from _pytest.assertion.rewrite import (
            PYC_TAIL,
            _read_pyc,
            _rewrite_test,
            _write_pyc,
            assertstate_key,
            get_cache_dir,
            try_makedirs,
        )

        files = test_modules(config)
        if files is None:
            return 0
        state = config.stash[assertstate_key]
        done = 0
        for fn in rotation(files, worker, int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))):
            cache_dir = get_cache_dir(fn)
            pyc = cache_dir / (fn.name[:-3] + PYC_TAIL)
            if _read_pyc(fn, pyc) is not None or not try_makedirs(cache_dir):
                continue
            source_stat, co = _rewrite_test(fn, config)
            _write_pyc(state, co, source_stat, pyc)
            done += 1
        return done
    except Exception:  # an optimisation only: pytest's own import path still rewrites what is missing
        return 0
