"""A C compiler wrapper for the test run: a compile step whose preprocessed source, flags and compiler
were seen before reuses that object file instead of compiling again.

Why: every generated solver folder carries the DAQP (and OSQP) library sources and compiles them with
the same flags; in a test run that builds dozens of solvers, recompiling identical library code is most
of the compile time (e.g. ~4.5 s of a flying DAQP solver's ~6 s; ~400 s of a ``make test``). The wrapper
is ``CC`` for the test session (:func:`install`; the cffi builds, ``make`` and CMake read it), so the code
under test runs unchanged: only *how* an identical object file is obtained changes.

What makes two compile steps identical (the key): the real compiler (path, size, mtime), every argument
except the output path, the source path and ``-I`` directories (generated folders live in fresh temporary
directories), and the source as preprocessed with those arguments (``-E -P``: headers and macros
included, so an edited header or ``-D`` is a different key). A hit copies the object file and replays
the compiler's messages; anything other than a plain ``-c one.c -o one.o`` step (linking, dependency
files without a named ``-MF``, ``-E``, response files ...) runs the real compiler untouched; a step that also
writes a make dependency file (CMake's ``-MD -MT t -MF f``) reuses the object and writes the file with the
preprocessor alone (``-M``). Failed compiles are never stored.

Per-solver symbol names: each library source of a generated folder first includes
``<name>_<lib>_names.h`` (``#define daqp_solve <name>_daqp_solve`` ..., see ``codegen/libs.py``), so the
same library differs between solvers in its global names only. Such a step is keyed on the source
preprocessed *without* the renaming (the header's include guard predefined) plus the list of renamed
names; a hit from another solver is the stored object with its symbols renamed to this solver's by
``objcopy --redefine-syms`` (the machine code is the compiler's either way: names are not code).
Debug information in a reused object still names the first solver and folder (harmless in tests).

Run as a script (``python -S cc_cache.py <compiler args>``): the real compiler is ``$DDPC_CC_REAL``,
the object store ``$DDPC_CC_CACHE``.
"""

from __future__ import annotations

import fcntl
import hashlib
import json
import os
import re
import shlex
import shutil
import subprocess
import sys
import sysconfig
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

SOURCE_SUFFIXES = (".c",)
_NAMES_INCLUDE = re.compile(r'#include "([^"]+_names\.h)" /\* ddpc-codegen: per-solver symbol names \*/')
_GUARD = re.compile(r"^#ifndef (\w+)$", re.M)
_RENAME = re.compile(r"^#define (\w+) (\w+)$", re.M)
# a step with any of these is not a plain "compile one source to one object" step: run it as asked
_PASS_PREFIXES = ("-M", "@", "-E", "-S", "-x", "-save-temps", "-fdump", "-###", "-v", "--version")


def dependency_flags(args: list[str]) -> tuple[list[str], list[str]] | None:
    """(the arguments without them, the make-dependency flags) of a compile step that writes its dependency
    file as a side effect with a named ``-MF`` (CMake's ``-MD -MT t -MF f``); ([], ...) untouched when it has
    none; None when it has other ``-M`` flags (not cacheable)."""
    rest, dep, i = [], [], 0
    while i < len(args):
        a = args[i]
        if a in ("-MD", "-MMD", "-MP"):
            dep.append(a)
        elif a in ("-MT", "-MF", "-MQ") and i + 1 < len(args):
            dep += [a, args[i + 1]]
            i += 1
        elif a.startswith("-M"):
            return None
        else:
            rest.append(a)
        i += 1
    if dep and ("-MF" not in dep or not {"-MD", "-MMD"} & set(dep)):
        return None
    return rest, dep


def write_dependencies(real: list[str], src: str, rest: list[str], dep: list[str]) -> bool:
    """The dependency file a ``-MD``/``-MMD`` compile would have written, from the preprocessor alone
    (``-M``/``-MM``: no code generated) -- what a reused object's build still needs."""
    only = ["-M" if a == "-MD" else "-MM" if a == "-MMD" else a for a in dep]
    return subprocess.run([*real, *[a for a in rest if a != "-c"], *only, src]).returncode == 0


def compile_step(args: list[str]) -> tuple[str, str, list[str]] | None:
    """(source, object, the other arguments) of a plain ``-c`` step, else None (not cacheable)."""
    if "-c" not in args or any(a == "-" or a.startswith(_PASS_PREFIXES) for a in args):
        return None
    srcs = [i for i, a in enumerate(args) if a.endswith(SOURCE_SUFFIXES) and not a.startswith("-")
            and not (i > 0 and args[i - 1] in ("-o", "-I", "-include", "-isystem", "-iquote"))]
    outs = [i for i, a in enumerate(args) if a == "-o"]
    if len(srcs) != 1 or len(outs) != 1 or outs[0] + 1 >= len(args):
        return None
    src, obj = args[srcs[0]], args[outs[0] + 1]
    rest = [a for i, a in enumerate(args) if i not in (srcs[0], outs[0], outs[0] + 1)]
    return src, obj, rest


def _without_include_dirs(args: list[str]) -> list[str]:
    out, skip = [], False
    for a in args:
        if skip:
            skip = False
        elif a == "-I":
            skip = True
        elif not a.startswith("-I"):
            out.append(a)
    return out


def renaming(src: str) -> tuple[str, dict[str, str]] | None:
    """(include guard, {library name: this solver's name}) of the per-solver names header that ``src``
    includes on its first line, or None (not a renamed library source)."""
    with open(src, errors="replace") as f:
        m = _NAMES_INCLUDE.match(f.readline())
    if m is None:
        return None
    header = Path(src).parent / m.group(1)
    try:
        text = header.read_text()
    except OSError:
        return None
    guard = _GUARD.search(text)
    return (guard.group(1), dict(_RENAME.findall(text))) if guard else None


def step_key(real: list[str], src: str, rest: list[str], names: tuple[str, dict[str, str]] | None = None,
             ) -> str | None:
    """The content key of compiling ``src`` with ``rest`` (see the module docstring); ``names``: the
    source's renaming (keyed on the source without it). None if the source does not preprocess (the
    real compile then reports why)."""
    unrenamed = [f"-D{names[0]}"] if names else []
    pre = subprocess.run([*real, *[a for a in rest if a != "-c"], *unrenamed, "-E", "-P", src], capture_output=True)
    if pre.returncode != 0:
        return None
    exe = shutil.which(real[0]) or real[0]
    st = os.stat(exe)
    h = hashlib.sha256()
    for part in (os.path.realpath(exe), str(st.st_size), str(st.st_mtime_ns), *real[1:], *_without_include_dirs(rest),
                 json.dumps(sorted(names[1]) if names else None)):
        h.update(part.encode() + b"\0")
    h.update(pre.stdout)
    return h.hexdigest()


def _renamed_copy(cached: Path, was: dict[str, str], now: dict[str, str], obj: str) -> bool:
    """``cached`` (compiled with the names ``was``) written to ``obj`` with the names ``now``."""
    if was == now:
        shutil.copyfile(cached, obj)
        return True
    objcopy = shutil.which(os.environ.get("OBJCOPY", "objcopy"))
    if objcopy is None or set(was) != set(now):
        return False
    with tempfile.NamedTemporaryFile("w", suffix=".syms") as syms:
        syms.write("".join(f"{was[k]} {now[k]}\n" for k in sorted(now)))
        syms.flush()
        return subprocess.run([objcopy, f"--redefine-syms={syms.name}", str(cached), obj]).returncode == 0


@contextmanager
def _key_lock(cache: Path, key: str) -> Iterator[None]:
    """Hold the exclusive lock of ``key`` (``flock``, released by the kernel if the holder dies)."""
    cache.mkdir(parents=True, exist_ok=True)
    with open(cache / f".{key}.lock", "a") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        yield


def _store(entry: Path, obj: bytes, names: dict[str, str], messages: bytes) -> None:
    """Write a cache entry (a folder) atomically, first writer wins (xdist workers may race on a key)."""
    entry.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(dir=entry.parent, prefix=".tmp-"))
    (tmp / "obj.o").write_bytes(obj)
    (tmp / "names.json").write_text(json.dumps(names))
    (tmp / "messages").write_bytes(messages)
    try:
        os.rename(tmp, entry)
    except OSError:  # another process stored this key meanwhile: same content but for the names
        shutil.rmtree(tmp, ignore_errors=True)


def run(args: list[str], real: list[str], cache: Path | None) -> int:
    """Compile as ``real args`` would, through the object store ``cache`` when the step is cacheable."""
    split = dependency_flags(args) if cache is not None else None
    plain, dep = split if split else (args, [])
    step = compile_step(plain) if split is not None else None
    names = renaming(step[0]) if step else None
    key = step_key(real, step[0], step[2], names) if step else None
    if key is None:
        return subprocess.run([*real, *args]).returncode
    entry, now = cache / key, names[1] if names else {}

    def reused() -> bool:
        if not (entry.is_dir() and _renamed_copy(entry / "obj.o", json.loads((entry / "names.json").read_text()), now,
                                                 step[1]) and (not dep or write_dependencies(real, step[0], step[2], dep))):
            return False
        sys.stderr.buffer.write((entry / "messages").read_bytes())
        return True

    if reused():
        return 0
    # xdist workers start alike and reach the same library sources together: the first compiles, the others
    # wait for its object instead of compiling the same step again
    with _key_lock(cache, key):
        if reused():
            return 0
        res = subprocess.run([*real, *args], stderr=subprocess.PIPE)
        sys.stderr.buffer.write(res.stderr)
        if res.returncode == 0 and os.path.exists(step[1]):
            _store(entry, Path(step[1]).read_bytes(), now, res.stderr)
    return res.returncode


def install(root: Path, env: dict[str, str]) -> dict[str, str]:
    """Make ``<root>/cc``, a wrapper around the compiler ``env`` names (``CC``, else Python's, which the
    cffi builds would use), storing objects in ``<root>/objects``; returns the variables to set:
    ``CC`` (the wrapper), ``DDPC_CC_REAL`` and ``DDPC_CC_CACHE``."""
    real = env.get("DDPC_CC_REAL") or env.get("CC") or sysconfig.get_config_var("CC") or "cc"
    root.mkdir(parents=True, exist_ok=True)
    script = root / "cc"
    text = f'#!/bin/sh\nexec "{sys.executable}" -S "{Path(__file__).resolve()}" "$@"\n'
    if not script.exists() or script.read_text() != text:
        fd, tmp = tempfile.mkstemp(dir=root, prefix=".cc-")
        with os.fdopen(fd, "w") as f:
            f.write(text)
        os.chmod(tmp, 0o755)
        os.replace(tmp, script)  # atomic: every xdist worker installs the same script
    return {"CC": str(script), "DDPC_CC_REAL": real, "DDPC_CC_CACHE": str(root / "objects")}


if __name__ == "__main__":
    cache_dir = os.environ.get("DDPC_CC_CACHE")
    sys.exit(run(sys.argv[1:], shlex.split(os.environ.get("DDPC_CC_REAL", "cc")), Path(cache_dir) if cache_dir else None))
