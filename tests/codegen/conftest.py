"""Generated solvers shared by the codegen tests: flying (m=p=2, Tini=20, Tf=15) and hopping
(m=p=3, Tini=20, Tf=25) sizes with u, du and y bounds, both backends, generated once per session."""

from __future__ import annotations

from pathlib import Path

import pytest

from ddpc_codegen.design.problem import SteeringProblem
from ddpc_codegen.experiments.bench_problems import build_problem

SIZES = ("flying", "hopping")
BACKENDS = ("daqp", "osqp")


def sized_problem(size: str) -> SteeringProblem:
    """The benchmark problem of ``size`` with output bounds added, so that all three kinds of rows exist."""
    prob, _ = build_problem(size)
    m = prob.config.m
    return SteeringProblem(prob.predictor, prob.config.replace(y_min=[-0.25] * m, y_max=[0.25] * m))


@pytest.fixture(scope="session")
def problems() -> dict[str, SteeringProblem]:
    return {s: sized_problem(s) for s in SIZES}


@pytest.fixture(scope="session")
def generated(request, tmp_path_factory) -> dict[tuple[str, str], Path]:
    """(size, backend) -> generated folder named ``<size>_<backend>`` (the solver name too); built once
    per test run for every xdist worker (:mod:`solver_cache`), the problems formed only when building."""
    from ddpc_codegen.codegen import generate
    from support.solver_cache import cache_root, shared_build

    def build(folder: Path) -> None:
        problems = request.getfixturevalue("problems")
        for s in SIZES:
            for b in BACKENDS:
                generate(problems[s], folder / f"{s}_{b}", backend=b, name=f"{s}_{b}")

    # sized_problem's inputs are code (bench.build_problem, seed 0) and the bounds, so the code digest
    # in the key covers them
    recipe = {"what": "codegen test solvers", "sizes": SIZES, "backends": BACKENDS, "y_bound": 0.25}
    folder = shared_build(cache_root(tmp_path_factory.getbasetemp()), recipe, build)
    return {(s, b): folder / f"{s}_{b}" for s in SIZES for b in BACKENDS}
