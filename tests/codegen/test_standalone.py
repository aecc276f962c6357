"""The generated folder outside Python: self-contained C99, per-name symbols, caller-owned workspaces,
CMake (add_subdirectory) and Makefile builds, the example replaying the vectors, and the very same
answers as the Python extension."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from conftest import BACKENDS, SIZES
from ddpc_codegen import load_solver
from ddpc_codegen.codegen import vectors as test_vectors
from ddpc_codegen.codegen.standalone import relocated_copy, tool

pytestmark = pytest.mark.compiler

LIBC_LIBM = {"calloc", "malloc", "free", "memcpy", "memmove", "memset", "sqrt", "fmax", "fabs", "clock_gettime",
             "printf", "__stack_chk_fail", "__memcpy_chk", "__memset_chk", "_GLOBAL_OFFSET_TABLE_",
             # libgcc's CPU detection behind the AVX-512 / AVX2 clones (x86-64 Linux, GCC): linked by every gcc/g++
             # driver
             "__cpu_indicator_init", "__cpu_model", "__cpu_features2"}


def _make(folder: Path, *args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(["make", "-s", *args], cwd=folder, capture_output=True, text=True, env=env, timeout=600)


def _result(text: str) -> dict:
    line = next(ln for ln in text.splitlines() if ln.startswith("RESULT "))
    return dict(kv.split("=", 1) for kv in line.split()[1:])


@pytest.fixture(scope="module")
def made(generated, tmp_path_factory) -> dict:
    """Each solver built with its own Makefile (library + example) in a relocated copy."""
    if tool("make") is None:
        pytest.skip("make not found")
    root = tmp_path_factory.mktemp("make")
    out = {}
    for key, folder in generated.items():
        copy = relocated_copy(folder, root)
        res = _make(copy)
        assert res.returncode == 0, res.stderr[-3000:]
        out[key] = copy
    return out


def test_folder_holds_every_source_and_no_python_or_network(generated):
    for (size, backend), folder in generated.items():
        name = f"{size}_{backend}"
        for f in ("CMakeLists.txt", "Makefile", "example_main.c", f"{name}_solver.h", f"{name}_vectors.txt"):
            assert (folder / f).is_file(), f
        assert (folder / backend / "LICENSE").is_file() or backend == "osqp"
        vec = json.loads((folder / "manifest.json").read_text())["vectors"]  # both regimes are recorded
        assert vec["file"] == f"{name}_vectors.txt" and vec["fast_path"] >= 10 and vec["active_bound"] >= 10
        code = "\n".join(p.read_text() for p in folder.rglob("*") if p.is_file() and p.suffix in (".c", ".h"))
        build = (folder / "CMakeLists.txt").read_text() + (folder / "Makefile").read_text()
        for banned in ("Python.h", "casadi/", "pybind11"):
            assert banned not in code + build, (name, banned)
        for banned in ("rpath", "FetchContent", "ExternalProject", "http", "git ", "pip "):
            assert banned not in build, (name, banned)


def test_every_exported_symbol_carries_the_solver_name(made):
    for (size, backend), folder in made.items():
        name = f"{size}_{backend}"
        nm = subprocess.run(["nm", "-g", "--defined-only", str(folder / "build-make" / f"lib{name}.a")],
                            capture_output=True, text=True, check=True).stdout
        defined = {ln.split()[-1] for ln in nm.splitlines() if re.match(r"^[0-9a-f]+ [A-Z] ", ln)}
        assert defined and all(s.startswith(f"{name}_") for s in defined), sorted(
            s for s in defined if not s.startswith(f"{name}_"))
        und = subprocess.run(["nm", "-u", str(folder / "build-make" / f"lib{name}.a")], capture_output=True,
                             text=True, check=True).stdout
        undefined = {ln.split()[-1] for ln in und.splitlines() if ln.strip() and ":" not in ln}
        assert undefined - {s for s in undefined if s.startswith(f"{name}_")} <= LIBC_LIBM


def test_structs_are_named_and_the_tables_are_one_const_struct(made):
    """Every struct of the templates' C is named (``typedef struct <name>_workspace {...} <name>_workspace;``) and the
    constant tables are members of one const struct, ``<name>_data``: the only data symbol they export."""
    for (size, backend), folder in made.items():
        name = f"{size}_{backend}"
        for f in sorted(folder.glob(f"{name}_*.[ch]")):
            if not f.name.startswith(f"{name}_param_map"):  # CasADi's
                assert "typedef struct {" not in f.read_text(), f.name
        nm = subprocess.run(["nm", "-g", "--defined-only", str(folder / "build-make" / f"lib{name}.a")],
                            capture_output=True, text=True, check=True).stdout
        data = {ln.split()[-1] for ln in nm.splitlines() if re.match(r"^[0-9a-f]+ [DR] ", ln)}
        assert f"{name}_data" in data and not any(s.startswith(f"{name}_K") for s in data), sorted(data)


def test_public_header_is_cxx_safe_and_includes_no_library_header(generated):
    for (size, backend), folder in generated.items():
        h = (folder / f"{size}_{backend}_solver.h").read_text()
        assert 'extern "C"' in h and "#include" not in h
        assert re.search(rf"int {size}_{backend}_solve\({size}_{backend}_workspace \*ws", h)
        assert f"#define {size.upper()}_{backend.upper()}_NU " in h


def test_makefile_example_replays_the_vectors(made):
    for (size, backend), folder in made.items():
        name = f"{size}_{backend}"
        res = _make(folder, "check")
        assert res.returncode == 0, res.stdout + res.stderr
        r = _result(res.stdout)
        tol = 1e-9 if backend == "daqp" else json.loads((folder / "manifest.json").read_text())["vector_tol"]
        assert r["name"] == name and r["mismatches"] == "0" and float(r["max_err"]) <= tol


def test_python_extension_and_c_example_agree_bit_for_bit(made, generated, tmp_path):
    for key, folder in made.items():
        dump = tmp_path / f"{key[0]}_{key[1]}.txt"
        exe = folder / "build-make" / f"{key[0]}_{key[1]}_example"
        res = subprocess.run([str(exe), str(folder / f"{key[0]}_{key[1]}_vectors.txt"), "--dump", str(dump),
                              "--ticks", "1"], capture_output=True, text=True, timeout=300)
        assert res.returncode == 0, res.stderr
        c_rows = [ln.split() for ln in dump.read_text().splitlines()]
        s = load_solver(generated[key])  # a fresh instance replays the same sequence
        vec = test_vectors.read(generated[key] / f"{key[0]}_{key[1]}_vectors.txt")
        for row, th in zip(c_rows, vec.theta, strict=True):
            r = s.solve_theta(th)
            c_u = np.array([float(x) for x in row[1:]])
            assert int(row[0]) == test_vectors.STATUS_CODES[r.status]
            assert np.array_equal(c_u.view(np.int64), r.u.ravel().view(np.int64)) or (
                not r.ok and np.isnan(c_u).all() and np.isnan(r.u).all())


def test_several_solvers_in_one_c_and_one_cxx_program_via_add_subdirectory(generated, tmp_path):
    """All four solvers (two sizes x two backends) linked into one C and one C++ program with CMake
    add_subdirectory; each replays its vectors on two workspaces (forwards and backwards) in turn."""
    cmake, cxx = tool("cmake"), tool("c++") or tool("g++")
    if cmake is None or cxx is None:
        pytest.skip(f"needs cmake and a C++ compiler (cmake={cmake}, c++={cxx}); .ci/run installs both")
    src = Path(__file__).parent / "c"
    proj = tmp_path / "proj"
    shutil.copytree(src, proj)
    shutil.copy(proj / "multi_main.c", proj / "multi_main.cpp")
    names = [f"{s}_{b}" for s in SIZES for b in BACKENDS]
    dirs = [relocated_copy(generated[(s, b)], tmp_path) for s in SIZES for b in BACKENDS]
    (proj / "solvers.h").write_text("".join(f'#include "{n}_solver.h"\n' for n in names) + "#define FOR_EACH_SOLVER(X) "
                                    + " ".join(f"X({n}, {n.upper()})" for n in names) + "\n")
    build = tmp_path / "build"
    cfg = subprocess.run([cmake, "-S", str(proj), "-B", str(build), "-DCMAKE_BUILD_TYPE=Release",
                          f"-DSOLVER_DIRS={';'.join(map(str, dirs))}", f"-DSOLVER_TARGETS={';'.join('ddpc::' + n for n in names)}"],
                         capture_output=True, text=True, timeout=300)
    assert cfg.returncode == 0, cfg.stdout + cfg.stderr
    bld = subprocess.run([cmake, "--build", str(build), "-j", "2"], capture_output=True, text=True, timeout=900)
    assert bld.returncode == 0, bld.stdout[-3000:] + bld.stderr[-3000:]
    for exe in ("multi_c", "multi_cpp"):
        run = subprocess.run([str(build / exe)] + [str(d / f"{d.name}_vectors.txt") for d in dirs],
                             capture_output=True, text=True, timeout=300)
        assert run.returncode == 0, run.stdout + run.stderr
        rows = {ln.split()[1]: dict(kv.split("=") for kv in ln.split()[2:]) for ln in run.stdout.splitlines()
                if ln.startswith("SOLVER ")}
        assert set(rows) == set(names)
        for n, r in rows.items():
            assert r["mismatches"] == "0"
            assert float(r["max_err"]) <= (1e-9 if n.endswith("daqp") else 1e-6), (exe, n, r)


def test_standalone_cmake_build_and_ctest(generated, tmp_path):
    cmake, ctest = tool("cmake"), tool("ctest")
    if cmake is None or ctest is None:
        pytest.skip("cmake/ctest not found (.ci/run installs cmake)")
    folder = relocated_copy(generated[("flying", "daqp")], tmp_path)
    build = tmp_path / "b"
    for cmd in ([cmake, "-S", str(folder), "-B", str(build)], [cmake, "--build", str(build), "-j", "2"],
                [ctest, "--test-dir", str(build), "--output-on-failure"]):
        res = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
        assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    assert "100% tests passed" in res.stdout
