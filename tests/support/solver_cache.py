"""Build an expensive test artifact (a generated, compiled solver) once per test run, shared by every
pytest-xdist worker and by both phases of ``make test``.

The artifact lives in ``<root>/<key>/`` where ``key`` hashes what the artifact is made of: the caller's
recipe (config text, data digest, seeds ...), the source of ``ddpc_codegen`` and ``firmware_bridge``
(so any code change rebuilds), the Python version and the C compiler named by ``CC`` (the real one behind
the test session's compile cache, :mod:`cc_cache`). A file lock
serialises builders of one key; a ``.complete`` marker, written last, says the folder is whole (a
builder that died half way leaves none, and the next one starts the folder afresh).

``root`` is ``$DDPC_TEST_CACHE`` when set (``make test`` points both of its phases at one fresh
directory), else the run's shared base temp directory (the parent of each xdist worker's own).
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import sys
from collections.abc import Callable
from pathlib import Path

from filelock import FileLock

ROOT = Path(__file__).resolve().parents[2]
CODE_DIRS = (ROOT / "ddpc_codegen", ROOT / "firmware_bridge")
_CODE_DIGEST: str | None = None


def code_digest() -> str:
    """sha256 of every source file (``.py``, templates, profiles) of the two packages, by relative path."""
    global _CODE_DIGEST
    if _CODE_DIGEST is None:
        h = hashlib.sha256()
        for top in CODE_DIRS:
            for p in sorted(top.rglob("*")):
                if p.is_file() and "__pycache__" not in p.parts and p.suffix not in (".pyc", ".so", ".o"):
                    h.update(str(p.relative_to(ROOT)).encode() + b"\0" + p.read_bytes() + b"\0")
        _CODE_DIGEST = h.hexdigest()
    return _CODE_DIGEST


def cache_key(recipe: dict) -> str:
    """24 hex digits naming the artifact made by ``recipe`` (JSON-serialisable) with this code and toolchain."""
    blob = json.dumps({"recipe": recipe, "code": code_digest(), "python": sys.version,
                       "cc": os.environ.get("DDPC_CC_REAL") or os.environ.get("CC", "")}, sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:24]


def cache_root(basetemp: Path) -> Path:
    """Where artifacts are shared: ``$DDPC_TEST_CACHE``, else the run's base temp (one level up in an xdist worker)."""
    env = os.environ.get("DDPC_TEST_CACHE")
    if env:
        return Path(env)
    return basetemp.parent if os.environ.get("PYTEST_XDIST_WORKER") else basetemp


def shared_build(root: Path, recipe: dict, build: Callable[[Path], object]) -> Path:
    """The folder ``<root>/<key>`` holding what ``build(folder)`` made from ``recipe``; built at most once.

    ``build`` writes into the (empty) folder it is given; its return value is ignored. An exception
    from it propagates and leaves no ``.complete`` marker, so the next caller builds again.
    """
    root.mkdir(parents=True, exist_ok=True)
    folder = root / cache_key(recipe)
    done = folder / ".complete"
    with FileLock(str(folder) + ".lock"):
        if not done.exists():
            shutil.rmtree(folder, ignore_errors=True)
            folder.mkdir()
            build(folder)
            done.write_text(json.dumps(recipe, sort_keys=True, default=str))
    return folder
