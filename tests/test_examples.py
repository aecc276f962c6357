"""Each program in examples/ runs as a user would run it (a fresh process, its own arguments) and says
what it promises: example 1 generates a solver that solves a tick, example 2 steers closer than the
nominal reference, example 3 builds against the folder example 2 generated and steers from C++."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"

# each example compiles a solver (10-20 s): slow until tests/durations.json measures them
pytestmark = [pytest.mark.compiler, pytest.mark.slow]


def run(args: list[str], cwd: Path, timeout: float = 300) -> subprocess.CompletedProcess:
    r = subprocess.run(args, cwd=cwd, capture_output=True, text=True, timeout=timeout,
                       env={**os.environ, "PYTHONDONTWRITEBYTECODE": "1"})
    assert r.returncode == 0, f"{args}:\n{r.stdout[-2000:]}\n{r.stderr[-4000:]}"
    return r


@pytest.fixture(scope="module")
def loop_solver(tmp_path_factory) -> tuple[Path, str]:
    """Example 2 run once: the folder of the solver it generated, and what it printed."""
    out = tmp_path_factory.mktemp("example_loop") / "loop"
    r = run([sys.executable, str(EXAMPLES / "02_steer_your_loop.py"), str(out)], cwd=out.parent)
    return out, r.stdout


def test_example_1_records_fits_generates_and_solves_a_tick(tmp_path):
    out = tmp_path / "flying"
    r = run([sys.executable, str(EXAMPLES / "01_fit_and_generate.py"), str(out)], cwd=tmp_path)
    assert "status solved" in r.stdout
    assert (tmp_path / "flying_collect.npz").is_file() and (out / "flying_solver.h").is_file()
    assert (out / "manifest.json").is_file()


def test_example_2_steers_closer_than_the_nominal_reference(loop_solver):
    out, stdout = loop_solver
    assert "height RMSE: nominal" in stdout and "0 fallbacks" in stdout
    assert (out / "loop_solver.h").is_file() and (out / "CMakeLists.txt").is_file()


def test_example_3_calls_the_generated_c_from_cpp(loop_solver, tmp_path):
    cmake, cxx = shutil.which("cmake"), shutil.which("c++") or shutil.which("g++")
    if not (cmake and cxx):
        pytest.skip(f"needs cmake and a C++ compiler (cmake={cmake}, c++={cxx}); .ci/run installs both")
    folder, _ = loop_solver
    build = tmp_path / "build"
    run([cmake, "-S", str(EXAMPLES / "03_cpp"), "-B", str(build), f"-DDDPC_SOLVER_DIR={folder}",
         "-DCMAKE_BUILD_TYPE=Release"], cwd=tmp_path)
    run([cmake, "--build", str(build)], cwd=tmp_path)
    r = run([str(build / "steer_loop")], cwd=tmp_path, timeout=60)
    assert "height RMSE: nominal" in r.stdout and "0 fallbacks" in r.stdout
