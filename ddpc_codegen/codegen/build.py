"""Compile emitted sources into a Python-loadable extension (cffi, API mode) — offline, local compiler only."""

from __future__ import annotations

import os
import shutil
import sys
import sysconfig
import tempfile
from contextlib import contextmanager
from pathlib import Path

import casadi
import cffi

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


def casadi_dir() -> Path:
    return Path(casadi.__file__).resolve().parent


def cdef_text() -> str:
    return """
int ddpc_init(void);
int ddpc_step(const double *theta, double *u_out, double *y_out, double *sigma_out, double *info);
void ddpc_reset(void);
void ddpc_predict(const double *theta, const double *u, double *y_out, double *sigma_out);
int ddpc_bench(const double *thetas, int n, double *times_us, int *statuses);
void ddpc_dims(int *out);
"""


def compile_extension(out_dir: Path, name: str, module: str, units: list[Path], backend: str,
                      march_native: bool = False, verbose: bool = False) -> tuple[Path, list[str]]:
    """Build ``module`` from ``units``; returns (extension path, compiler flags used)."""
    flags = list(PORTABLE_FLAGS) + (["-march=native"] if march_native else [])
    include_dirs = [str(out_dir)]
    libraries, library_dirs, link_args = ["m"], [], []
    if backend == "daqp":
        cd = casadi_dir()
        if not (cd / "include" / "daqp" / "api.h").exists():
            raise CodegenError(f"the DAQP headers are missing from the casadi wheel at {cd}; reinstall casadi>=3.6")
        include_dirs.append(str(cd / "include"))
        library_dirs.append(str(cd))
        libraries.append("daqp")
        link_args.append(f"-Wl,-rpath,{cd}")
    else:
        include_dirs += [str(out_dir / "osqp"), str(out_dir / "osqp" / "inc" / "public"),
                         str(out_dir / "osqp" / "inc" / "private")]
    # The dims helper lives in the cffi glue so the loader can check the binary against the manifest.
    glue = f"""
#include "{name}_solver.h"
void ddpc_dims(int *out) {{ out[0] = ddpc_N_U; out[1] = ddpc_N_THETA; out[2] = ddpc_N_Y; out[3] = ddpc_N_SIGMA; }}
"""
    ffi = cffi.FFI()
    ffi.cdef(cdef_text())
    ffi.set_source(module, glue, sources=[str(u) for u in units], include_dirs=include_dirs,
                   libraries=libraries, library_dirs=library_dirs, extra_compile_args=flags,
                   extra_link_args=link_args)
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
