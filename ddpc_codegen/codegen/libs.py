"""Solver library sources copied into a generated folder, with every global symbol renamed per solver.

DAQP's C sources come from its PyPI source distribution, fetched once into a local cache by
``make install`` (``python -m ddpc_codegen.codegen.libs fetch``); generation then only copies from
the cache, so it works offline. OSQP's embedded sources come from the osqp wheel's own code generator.
Both libraries use global names (``daqp_solve``, ``osqp_solve`` ...); a generated
``<name>_<lib>_names.h`` maps each of them to ``<name>_<symbol>`` and is included first by every
library source, so several solvers link into one program.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

from ddpc_codegen.errors import CodegenError
from ddpc_codegen.codegen.render import render

DAQP_VERSION = "0.11.0"  # pinned: the backend template uses this version's workspace layout

_COMMENTS = re.compile(r"/\*.*?\*/|//[^\n]*", re.S)
# File-scope, non-static definitions: functions `type name(args) {` and data `type name[..] = `.
_FUNC_DEF = re.compile(r"^(?!static\b|typedef\b|return\b)(?:[A-Za-z_]\w*[\s\*]+)+\**([A-Za-z_]\w*)\s*\([^;{}]*\)\s*\{",
                       re.M)
_DATA_DEF = re.compile(r"^(?!static\b|typedef\b|extern\b|#)(?:const\s+)?[A-Za-z_]\w*[\s\*]+(?:const\s+)?"
                       r"\**([A-Za-z_]\w*)\s*(?:\[[^\]]*\])*\s*=", re.M)


def cache_dir() -> Path:
    """Where fetched library sources live: ``$DDPC_CODEGEN_CACHE`` or ``<venv>/share/ddpc-codegen``."""
    env = os.environ.get("DDPC_CODEGEN_CACHE")
    return Path(env) if env else Path(sys.prefix) / "share" / "ddpc-codegen"


def daqp_source() -> Path:
    """The cached DAQP source tree (``csrc/src``, ``csrc/include``, ``LICENSE``); CodegenError if absent."""
    root = cache_dir() / f"daqp-{DAQP_VERSION}"
    if not (root / "csrc" / "src" / "api.c").exists() or not (root / "LICENSE").exists():
        raise CodegenError(
            f"the DAQP {DAQP_VERSION} C sources are not in the cache {root}: run `make install` once (it fetches "
            f"the daqp source distribution from PyPI), or `python -m ddpc_codegen.codegen.libs fetch`, or point "
            f"DDPC_CODEGEN_CACHE at a cache that has them"
        )
    return root


def fetch_daqp(log=print) -> Path:
    """Download the daqp sdist with pip and keep its C sources and licence in the cache (idempotent)."""
    dest = cache_dir() / f"daqp-{DAQP_VERSION}"
    if (dest / "csrc" / "src" / "api.c").exists():
        return dest
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-m", "pip", "download", "-q", "--disable-pip-version-check", "--no-deps",
               "--no-binary", "daqp", f"daqp=={DAQP_VERSION}", "-d", tmp]
        res = subprocess.run(cmd, capture_output=True, text=True)
        archives = list(Path(tmp).glob("daqp-*.tar.gz"))
        if res.returncode != 0 or not archives:
            raise CodegenError(f"fetching the daqp {DAQP_VERSION} sdist failed: {res.stderr.strip()[-800:]}")
        with tarfile.open(archives[0]) as tar:
            tar.extractall(tmp, filter="data")
        src = Path(tmp) / f"daqp-{DAQP_VERSION}"
        staging = dest.with_name(dest.name + ".partial")
        shutil.rmtree(staging, ignore_errors=True)
        (staging / "csrc").mkdir(parents=True)
        for part in ("src", "include"):
            shutil.copytree(src / "csrc" / part, staging / "csrc" / part)
        shutil.copy2(src / "LICENSE", staging / "LICENSE")
        shutil.rmtree(dest, ignore_errors=True)
        staging.rename(dest)
    log(f"cached the DAQP {DAQP_VERSION} C sources in {dest}")
    return dest


def global_names(sources: list[Path], keep_prefix: str) -> list[str]:
    """Non-static functions and data defined at file scope in ``sources`` (names already starting
    with ``keep_prefix`` excluded). Checked against ``nm -g`` by the tests (two solvers link)."""
    names: set[str] = set()
    for f in sources:
        text = _COMMENTS.sub("", f.read_text())
        names.update(_FUNC_DEF.findall(text))
        names.update(_DATA_DEF.findall(text))
    return sorted(n for n in names if not n.startswith(keep_prefix) and n != "main")


def _names_header(path: Path, name: str, lib: str, names: list[str]) -> None:
    path.write_text(render("names.h.in", guard=f"{name.upper()}_{lib.upper()}_NAMES_H", lib=lib, name=name,
                           symbols=names))


def _prepend_include(files: list[Path], include: str) -> None:
    for f in files:
        f.write_text(render("names_include.in", header=include) + f.read_text())


def emit_daqp(out_dir: Path, name: str) -> list[Path]:
    """Copy DAQP into ``out_dir/daqp`` (sources renamed per solver); returns its compilation units."""
    src = daqp_source()
    dst = out_dir / "daqp"
    shutil.rmtree(dst, ignore_errors=True)
    (dst / "src").mkdir(parents=True)
    shutil.copytree(src / "csrc" / "include", dst / "include")
    units = []
    for c in sorted((src / "csrc" / "src").glob("*.c")):
        shutil.copy2(c, dst / "src" / c.name)
        units.append(dst / "src" / c.name)
    shutil.copy2(src / "LICENSE", dst / "LICENSE")
    _names_header(dst / f"{name}_daqp_names.h", name, "daqp", global_names(units, f"{name}_"))
    _prepend_include(units, f"../{name}_daqp_names.h")
    return units


def emit_osqp_library(solver, out_dir: Path, name: str) -> list[Path]:
    """OSQP's embedded code generator (parameters='vectors') into ``out_dir/osqp``, renamed per solver."""
    dst = out_dir / "osqp"
    shutil.rmtree(dst, ignore_errors=True)
    solver.codegen(str(dst), prefix=f"{name}_osqp_", parameters="vectors", force_rewrite=True,
                   compile=False, printing_enable=False)
    # Only the C library and the workspace are ours to build; the folder's own CMakeLists/Makefile
    # replace OSQP's example and Python bindings (which fetch pybind11 at build time).
    for junk in ("emosqp.c", "bindings.cpp", "setup.py", "CMakeLists.txt", "Makefile"):
        (dst / junk).unlink(missing_ok=True)
    stamp = re.compile(r"(autogenerated by OSQP) on [^\n]*")  # a timestamp would break reproducible output
    for f in sorted(dst.rglob("*")):
        if f.is_file() and f.suffix in (".c", ".h"):
            text = f.read_text()
            if stamp.search(text):
                f.write_text(stamp.sub(r"\1", text))
    lib_units = sorted((dst / "src").glob("*.c"))
    ws = dst / f"{name}_osqp_workspace.c"
    _names_header(dst / f"{name}_osqp_names.h", name, "osqp", global_names(lib_units + [ws], f"{name}_"))
    _prepend_include(lib_units, f"../{name}_osqp_names.h")
    _prepend_include([ws], f"{name}_osqp_names.h")
    return lib_units + [ws]


def main(argv: list[str] | None = None) -> int:
    """``python -m ddpc_codegen.codegen.libs fetch``: fill the source cache (needs the network once)."""
    args = sys.argv[1:] if argv is None else argv
    if args != ["fetch"]:
        print("usage: python -m ddpc_codegen.codegen.libs fetch", file=sys.stderr)
        return 2
    try:
        fetch_daqp()
    except CodegenError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
