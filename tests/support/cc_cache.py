"""A C compiler wrapper for the test run: a compile step whose preprocessed source, flags and compiler
were seen before reuses that object file instead of compiling again.

Why: every generated solver folder carries the DAQP (and OSQP) library sources and compiles them with
the same flags; in a test run that builds dozens of solvers, recompiling identical library code is most
of the compile time (e.g. ~4.5 s of a flying DAQP solver's ~6 s). The wrapper is ``CC`` for the test
session (:func:`install`; the cffi builds, ``make`` and CMake read it), so the code under test runs
unchanged: only *how* an identical object file is obtained changes.

What makes two compile steps identical (the key): the real compiler (path, size, mtime), every argument
except the output path, the source path and ``-I`` directories (generated folders live in fresh temporary
directories), and the source as preprocessed with those arguments (``-E -P``: headers and macros
included, so an edited header or ``-D`` is a different key). A hit copies the object file and replays
the compiler's messages; anything other than a plain ``-c one.c -o one.o`` step (linking, dependency
files, ``-E``, response files ...) runs the real compiler untouched. Failed compiles are never stored.
Debug information in a reused object names the first folder it was compiled in (harmless in tests).

Run as a script (``python -S cc_cache.py <compiler args>``): the real compiler is ``$DDPC_CC_REAL``,
the object store ``$DDPC_CC_CACHE``.
"""

from __future__ import annotations

import hashlib
import os
import shlex
import shutil
import subprocess
import sys
import sysconfig
import tempfile
from pathlib import Path

SOURCE_SUFFIXES = (".c",)
# a step with any of these is not a plain "compile one source to one object" step: run it as asked
_PASS_PREFIXES = ("-M", "@", "-E", "-S", "-x", "-save-temps", "-fdump", "-###", "-v", "--version")


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


def step_key(real: list[str], src: str, rest: list[str]) -> str | None:
    """The content key of compiling ``src`` with ``rest`` (see the module docstring); None if the
    source does not preprocess (the real compile then reports why)."""
    pre = subprocess.run([*real, *[a for a in rest if a != "-c"], "-E", "-P", src], capture_output=True)
    if pre.returncode != 0:
        return None
    exe = shutil.which(real[0]) or real[0]
    st = os.stat(exe)
    h = hashlib.sha256()
    for part in (os.path.realpath(exe), str(st.st_size), str(st.st_mtime_ns), *real[1:], *_without_include_dirs(rest)):
        h.update(part.encode() + b"\0")
    h.update(pre.stdout)
    return h.hexdigest()


def _store(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (concurrent workers may store the same key)."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".tmp-")
    with os.fdopen(fd, "wb") as f:
        f.write(data)
    os.replace(tmp, path)


def run(args: list[str], real: list[str], cache: Path | None) -> int:
    """Compile as ``real args`` would, through the object store ``cache`` when the step is cacheable."""
    step = compile_step(args) if cache is not None else None
    key = step_key(real, step[0], step[2]) if step else None
    if key is None:
        return subprocess.run([*real, *args]).returncode
    obj, msgs = cache / f"{key}.o", cache / f"{key}.err"
    if obj.exists() and msgs.exists():
        shutil.copyfile(obj, step[1])
        sys.stderr.buffer.write(msgs.read_bytes())
        return 0
    res = subprocess.run([*real, *args], stderr=subprocess.PIPE)
    sys.stderr.buffer.write(res.stderr)
    if res.returncode == 0 and os.path.exists(step[1]):
        cache.mkdir(parents=True, exist_ok=True)
        _store(obj, Path(step[1]).read_bytes())
        _store(msgs, res.stderr)  # written last: its presence says the object is whole
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
