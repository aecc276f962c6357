"""generate(): the name check before any folder, atomic rebuilds (a failed build keeps the old solver),
the vector replay gate, and the package's lazy re-export (no import cycle inside codegen/)."""

import importlib
import subprocess
import sys

import numpy as np
import pytest

from support.lti import random_lti
from ddpc_codegen import CodegenError, IODataset, SteeringConfig, SteeringProblem, fit_predictor, load_solver
from ddpc_codegen.codegen import generate
from ddpc_codegen.codegen import generate as generate_fn
from ddpc_codegen.codegen import vectors as test_vectors
gen_module = importlib.import_module("ddpc_codegen.codegen.artifact")

pytestmark = pytest.mark.compiler


@pytest.fixture(scope="module")
def problem():
    sys_ = random_lti(3, 1, 1, 11)
    rng = np.random.default_rng(11)
    u = rng.standard_normal((200, 1))
    y, _ = sys_.simulate(u, np.zeros(3))
    cfg = SteeringConfig(t_ini=4, t_f=3, m=1, p=1, Q=[1.0], R=[0.1], u_min=[-2.0], u_max=[2.0], name="gentest")
    return SteeringProblem(fit_predictor(IODataset(u, y, 0.005), 4, 3, "lsq"), cfg)


@pytest.fixture(scope="module")
def built(problem, tmp_path_factory):
    return generate(problem, tmp_path_factory.mktemp("gen") / "solver")


@pytest.mark.parametrize("name", ["a_", "a__b", "a\n", "_a", "1a", "a" * 42])
def test_bad_names_refused_before_any_folder(problem, tmp_path, name):
    with pytest.raises(CodegenError) as e:
        generate(problem, tmp_path / "out" / "solver", name=name, compile=False)
    assert str(e.value) == (
        f"solver name {name!r} must start with a letter, contain only letters, digits and single '_' between "
        "them, not end in '_', and have at most 41 characters (it becomes a C identifier prefix and a Python "
        "module name)")
    assert list(tmp_path.iterdir()) == []


def test_good_names_accepted(problem, tmp_path):
    for name in ("a", "a_b_c1", "A" * 41):
        assert (generate(problem, tmp_path / name, name=name, compile=False) / f"{name}_solver.c").is_file()


def test_failed_compile_keeps_the_old_solver(problem, built, monkeypatch):
    before = {p.name: p.read_bytes() for p in built.iterdir() if p.is_file()}
    monkeypatch.setenv("CC", "/bin/false")
    with pytest.raises(CodegenError) as e:
        generate(problem, built, max_iter=999)
    assert str(e.value).startswith(f"{built} not replaced (the previous solver there is kept): compiling solver "
                                   "'gentest' failed")
    assert {p.name: p.read_bytes() for p in built.iterdir() if p.is_file()} == before
    assert sorted(p.name for p in built.parent.iterdir()) == ["solver"]  # no build folder left behind
    assert load_solver(built).solve_theta(np.zeros(load_solver(built).n_theta)).ok


def test_failed_first_build_leaves_nothing(problem, tmp_path, monkeypatch):
    monkeypatch.setenv("CC", "/bin/false")
    with pytest.raises(CodegenError, match=r"not replaced \(nothing was written there\): compiling"):
        generate(problem, tmp_path / "solver")
    assert list(tmp_path.iterdir()) == []


def test_vectors_not_reproduced_is_refused(problem, built, monkeypatch, tmp_path):
    record = test_vectors.record

    def tampered(prob, n):
        v = record(prob, n)
        v.u = np.where(v.status[:, None] == 0, v.u + 1e-3, v.u)
        return v

    monkeypatch.setattr(gen_module.test_vectors, "record", tampered)
    out = tmp_path / "s"
    with pytest.raises(CodegenError) as e:
        generate(problem, out)
    assert str(e.value) == (f"{out.resolve()} not replaced (nothing was written there): solver 'gentest' fails its "
                            "test vector 0: max |u - recorded| 0.001 > 1e-09")
    assert not out.exists()


def test_verify_vectors_status_mismatch(built):
    vec = test_vectors.read(built / "gentest_vectors.txt")
    vec.status = vec.status.copy()
    vec.status[2] = -1
    with pytest.raises(CodegenError) as e:
        gen_module.verify_vectors(built, vec, 1e-9)
    assert str(e.value) == "solver 'gentest' fails its test vector 2: status 'solved', recorded -1"


def test_rebuild_replaces_the_folder(problem, built):
    new = generate(problem, built, max_iter=77)
    assert new == built
    assert load_solver(built).manifest["settings"]["max_iter"] == 77
    assert sorted(p.name for p in built.parent.iterdir()) == ["solver"]


def test_output_path_that_is_a_file(problem, tmp_path):
    f = tmp_path / "x"
    f.write_text("mine")
    with pytest.raises(CodegenError) as e:
        generate(problem, f, compile=False)
    assert str(e.value) == f"{f} exists and is not a folder; give a folder for the solver"
    assert f.read_text() == "mine"


def test_lazy_reexport_without_cycle():
    """emit and build load without the artifact module; once it is loaded, ``codegen.generate`` (and the package's
    ``ddpc_codegen.generate``) is still the function: no module of that name shadows it."""
    code = ("import sys, ddpc_codegen.codegen.emit, ddpc_codegen.codegen.build;"
            "print('ddpc_codegen.codegen.artifact' in sys.modules);"
            "import importlib, ddpc_codegen; m = importlib.import_module('ddpc_codegen.codegen.artifact');"
            "from ddpc_codegen.codegen import generate;"
            "print(generate is m.generate, ddpc_codegen.generate is m.generate, callable(ddpc_codegen.codegen.generate))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True)
    assert out.stdout.split() == ["False", "True", "True", "True"]
    assert generate_fn is gen_module.generate
