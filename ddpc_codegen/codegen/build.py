"""Compile emitted sources into a Python-loadable extension (cffi, API mode) — offline, local compiler only."""

from __future__ import annotations

import os
import shutil
import sys
import sysconfig
import tempfile
from contextlib import contextmanager
from pathlib import Path

import cffi

from ddpc_codegen.codegen.render import render
from ddpc_codegen.errors import CodegenError

PORTABLE_FLAGS = ["-O3", "-std=c99", "-fno-strict-aliasing", "-Wno-unused-function", "-Wno-unused-variable"]


@contextmanager
def _captured_fds():
    """Capture what the compiler (a child process) writes to fds 1 and 2; yields a reader."""
    sys.stdout.flush()
    sys.stderr.flush()
    with tempfile.TemporaryFile(mode="w+b") as tmp:
        saved = os.dup(1), os.dup(2)
        os.dup2(tmp.fileno(), 1)
        os.dup2(tmp.fileno(), 2)
        text: list[str] = []
        try:
            yield text
        finally:
            sys.stdout.flush()
            sys.stderr.flush()
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            os.close(saved[0])
            os.close(saved[1])
            tmp.seek(0)
            text.append(tmp.read().decode(errors="replace"))


def cdef_text(name: str, artio: bool = False, adapt: bool = False) -> str:
    """The C API of a generated solver (with its artificial-IO completion, its online update) as cffi declares
    it (the workspace's layout is the compiler's)."""
    return render("cdef.in", name=name, artio=artio, adapt=adapt)


def include_dirs_of(backend: str, artio: bool = False) -> list[str]:
    """Private include directories of a backend's library (and of DAQP for a hopping solver's
    artificial-IO completion), relative to the solver folder."""
    # OSQP's first: both libraries have a types.h; DAQP's sources never include theirs by -I (their
    # headers find it next to themselves), OSQP's sources do.
    osqp = ["osqp", "osqp/inc/public", "osqp/inc/private"] if backend == "osqp" else []
    return osqp + (["daqp/include"] if backend == "daqp" or artio else [])


def compile_extension(out_dir: Path, name: str, module: str, units: list[Path], backend: str,
                      march_native: bool = False, verbose: bool = False, artio: bool = False,
                      adapt: bool = False) -> tuple[Path, list[str]]:
    """Build ``module`` from ``units`` -- the very sources CMake and the Makefile compile, with the same
    portable flags; returns (extension path, compiler flags used). ``adapt``: also declare the online
    predictor update (``<name>_adapt.h``, emitted only when adaptation is enabled)."""
    flags = list(PORTABLE_FLAGS) + (["-march=native"] if march_native else [])
    include_dirs = [str(out_dir)] + [str(out_dir / i) for i in include_dirs_of(backend, artio)]
    glue = render("cffi_glue.c.in", name=name, adapt=adapt)  # <name>_solver.h includes <name>_artio.h
    ffi = cffi.FFI()
    ffi.cdef(cdef_text(name, artio, adapt))
    ffi.set_source(module, glue, sources=[str(u) for u in units], include_dirs=include_dirs,
                   libraries=["m"], extra_compile_args=flags)
    # A fresh directory per build: distutils caches the directories it created per process, so
    # reusing a deleted one makes the second build in a process fail.
    build_dir = Path(tempfile.mkdtemp(prefix="build-", dir=out_dir))
    error = None
    with _captured_fds() as log:
        try:
            built = Path(ffi.compile(tmpdir=str(build_dir), verbose=verbose))
        except Exception as e:  # cffi raises VerificationError/CompileError/DistutilsError variants
            error = e
    if error is not None:
        raise CodegenError(
            f"compiling solver '{name}' failed ({type(error).__name__}: {error}). Is a C compiler (cc/gcc) "
            f"installed? Build log (tail):\n{log[0][-4000:]}"
        ) from error
    if verbose:
        print(log[0], file=sys.stderr)
    suffix = sysconfig.get_config_var("EXT_SUFFIX") or ".so"
    target = out_dir / f"{module}{suffix}"
    shutil.copy2(built, target)
    if not os.environ.get("DDPC_KEEP_BUILD"):
        shutil.rmtree(build_dir, ignore_errors=True)
    return target, flags
