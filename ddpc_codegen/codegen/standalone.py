"""Build and run a generated folder the way a C user does -- its own Makefile and example, natively or
cross-compiled for aarch64 and run under qemu -- for the tests and ``make bench``."""

from __future__ import annotations

import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

from ddpc_codegen.errors import CodegenError

AARCH64_CC = "aarch64-linux-gnu-gcc"
QEMU = "qemu-aarch64"
AARCH64_SYSROOT = "/usr/aarch64-linux-gnu"
MISSING_AARCH64 = (f"{AARCH64_CC} and {QEMU} are needed (Debian/Ubuntu: apt-get install gcc-aarch64-linux-gnu "
                   "qemu-user; .ci/run installs them when CI=true)")


def tool(name: str) -> str | None:
    """An executable on PATH or in this interpreter's environment (e.g. cmake installed with pip)."""
    return shutil.which(name) or shutil.which(name, path=str(Path(sys.prefix) / "bin"))


def aarch64_tools() -> tuple[str, str] | None:
    """(cross compiler, qemu) or None when either is missing."""
    cc, qemu = tool(AARCH64_CC), tool(QEMU)
    return (cc, qemu) if cc and qemu else None


@dataclass
class ExampleRun:
    """What ``<name>_example`` reported: vectors, status mismatches, max |u - u_ref|, C-only tick times."""

    returncode: int
    vectors: int
    mismatches: int
    max_err: float
    median_us: float
    p99_us: float
    output: str


def relocated_copy(folder: Path, dst: Path) -> Path:
    """A copy of a generated folder without its Python extension or build output (proves it relocates)."""
    out = Path(dst) / Path(folder).name
    shutil.copytree(folder, out, ignore=shutil.ignore_patterns("_ddpc_*", "build*", "__pycache__"))
    return out


def solver_name(folder: Path) -> str:
    """The solver's name (the C prefix), from its public header ``<name>_solver.h``."""
    headers = sorted(Path(folder).glob("*_solver.h"))
    if len(headers) != 1:
        raise CodegenError(f"{folder} is not a generated solver folder (expected one *_solver.h, found {len(headers)})")
    return headers[0].name[: -len("_solver.h")]


def vectors_file(folder: Path) -> Path:
    """The recorded test vectors of a generated folder."""
    return Path(folder) / f"{solver_name(folder)}_vectors.txt"


def make_example(folder: Path, cc: str | None = None, build: str = "build-make", timeout: float = 900) -> Path:
    """``make`` in the folder (optionally ``CC=cc``); returns the example executable."""
    args = ["make", "-s", f"BUILD={build}"] + ([f"CC={cc}"] if cc else [])
    res = subprocess.run(args, cwd=folder, capture_output=True, text=True, timeout=timeout)
    if res.returncode != 0:
        raise CodegenError(f"`{' '.join(args)}` failed in {folder}:\n{(res.stdout + res.stderr)[-3000:]}")
    exe = Path(folder) / build / f"{solver_name(folder)}_example"
    if not exe.is_file():
        raise CodegenError(f"`{' '.join(args)}` in {folder} built no {exe.name}")
    return exe


def run_example(exe: Path, vectors: Path, *, qemu: str | None = None, dump: Path | None = None,
                ticks: int = 200, timeout: float = 900) -> ExampleRun:
    """Run the example on a vectors file (under qemu when given) and parse its RESULT line."""
    cmd = ([qemu, "-L", AARCH64_SYSROOT] if qemu else []) + [str(exe), str(vectors), "--ticks", str(ticks)]
    if dump is not None:
        cmd += ["--dump", str(dump)]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    line = next((ln for ln in res.stdout.splitlines() if ln.startswith("RESULT ")), None)
    if line is None:
        raise CodegenError(f"{exe.name} printed no RESULT line (exit {res.returncode}):\n{res.stdout}{res.stderr}")
    kv = dict(item.split("=", 1) for item in line.split()[1:])
    return ExampleRun(res.returncode, int(kv["vectors"]), int(kv["mismatches"]), float(kv["max_err"]),
                      float(kv["median_us"]), float(kv["p99_us"]), res.stdout + res.stderr)


def read_dump(path: Path) -> tuple[list[int], list[list[float]]]:
    """Statuses and u of an ``--dump`` file (one line per vector)."""
    rows = [ln.split() for ln in Path(path).read_text().splitlines()]
    return [int(r[0]) for r in rows], [[float(x) for x in r[1:]] for r in rows]
