"""GeneratedSolver refuses wrong shapes before C reads a buffer; load_solver checks the manifest's
weights, sources and test vectors against the folder."""

import json
import shutil

import numpy as np
import pytest

from support.lti import random_lti
from ddpc_codegen import DataError, IODataset, ManifestError, SteeringConfig, SteeringProblem, fit_predictor, load_solver
from ddpc_codegen.codegen import generate

pytestmark = pytest.mark.compiler


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    sys_ = random_lti(3, 1, 1, 2)
    rng = np.random.default_rng(2)
    u = rng.standard_normal((200, 1))
    y, _ = sys_.simulate(u, np.zeros(3))
    cfg = SteeringConfig(t_ini=4, t_f=3, m=1, p=1, Q=[1.0], R=[0.1], u_min=[-2.0], u_max=[2.0], name="ldtest")
    return generate(SteeringProblem(fit_predictor(IODataset(u, y, 0.005), 4, 3, "lsq"), cfg),
                    tmp_path_factory.mktemp("ld") / "ldtest")


@pytest.fixture(scope="module")
def solver(folder):
    return load_solver(folder)


def _msg(call) -> str:
    with pytest.raises(DataError) as e:
        call()
    return str(e.value)


def test_bench_wrong_row_width(solver):
    n = solver.n_theta
    assert _msg(lambda: solver.bench(np.zeros((1000, 5)))) == f"thetas must have shape (n, {n}); got (1000, 5)"
    assert _msg(lambda: solver.bench(np.zeros(n))) == f"thetas must have shape (n, {n}); got ({n},)"
    times, sts, us = solver.bench(np.zeros((3, n)))
    assert times.shape == (3,) and us.shape == (3, solver.n_u) and (sts == 0).all()


def test_step_u_no_broadcasting(solver):
    n = solver.n_theta
    assert _msg(lambda: solver.step_u(0.0)) == f"theta must have shape ({n},); got ()"
    assert _msg(lambda: solver.step_u(np.zeros((1, n)))) == f"theta must have shape ({n},); got (1, {n})"
    assert solver.step_u(np.zeros(n))[0] == 0


def test_solve_theta_and_predict_shapes(solver):
    n = solver.n_theta
    assert _msg(lambda: solver.solve_theta(np.zeros(n + 1))) == f"theta must have shape ({n},); got ({n + 1},)"
    assert _msg(lambda: solver._predict(np.zeros(n), np.zeros(1))) == (
        f"predict needs theta ({n},) and u of {solver.n_u} entries; got ({n},), (1,)")


def _edited(folder, tmp_path, edit) -> str:
    copy = tmp_path / "copy"
    shutil.copytree(folder, copy)
    man = json.loads((copy / "manifest.json").read_text())
    edit(copy, man)
    (copy / "manifest.json").write_text(json.dumps(man))
    with pytest.raises(ManifestError) as e:
        load_solver(copy)
    return str(e.value).replace(str(copy), "<f>")


def test_weights_checked_against_dims(folder, tmp_path):
    def q_wrong(f, m):
        m["weights"]["Q"] = [[1.0, 0.0], [0.0, 1.0]]
    assert _edited(folder, tmp_path, q_wrong) == ("<f>: manifest.json weights.Q must be a finite 1x1 matrix (dims); "
                                                  "got [[1.0, 0.0], [0.0, 1.0]]")


@pytest.mark.parametrize("key", ["R_ddu", "R_de", "R_doffset"])
def test_later_weights_checked_when_present_and_optional_in_older_manifests(folder, tmp_path, key):
    def wrong(f, m):
        m["weights"][key] = [[float("nan")]]
    assert _edited(folder, tmp_path, wrong) == (f"<f>: manifest.json weights.{key} must be a finite 1x1 matrix "
                                                "(dims); got [[nan]]")
    older = tmp_path / "older"
    shutil.copytree(folder, older)
    man = json.loads((older / "manifest.json").read_text())
    del man["weights"][key]  # an artifact generated before the key existed
    (older / "manifest.json").write_text(json.dumps(man))
    assert load_solver(older).manifest["weights"].get(key) is None


def test_negative_lambda_sigma(folder, tmp_path):
    def neg(f, m):
        m["weights"]["lambda_sigma"] = -1
    assert _edited(folder, tmp_path, neg) == "<f>: manifest.json weights.lambda_sigma must be a number >= 0; got -1"


def test_source_outside_the_folder(folder, tmp_path):
    def outside(f, m):
        m["sources"]["../evil.c"] = "0" * 64
    assert _edited(folder, tmp_path, outside) == "<f>: manifest.json source '../evil.c' is outside the solver folder"


def test_unlisted_source(folder, tmp_path):
    def extra(f, m):
        (f / "extra.c").write_text("int x;\n")
    assert _edited(folder, tmp_path, extra) == ("<f>: ['extra.c'] are in the folder but not in manifest.json "
                                                "'sources' (added after generation?); regenerate")


def test_vectors_file_checked(folder, tmp_path):
    def path_name(f, m):
        m["vectors"]["file"] = "../ldtest_vectors.txt"
    assert _edited(folder, tmp_path, path_name) == ("<f>: manifest.json vectors.file must be a file name in the "
                                                    "folder; got '../ldtest_vectors.txt'")


def test_vectors_file_edited(folder, tmp_path):
    def edit(f, m):
        p = f / m["vectors"]["file"]
        p.write_text(p.read_text() + "\n")
    assert _edited(folder, tmp_path, edit) == ("<f>: test vectors ldtest_vectors.txt differ from the ones recorded "
                                               "at generation (edited?); regenerate")


def test_extra_manifest_keys_are_tolerated(folder, tmp_path):
    copy = tmp_path / "copy"
    shutil.copytree(folder, copy)
    man = json.loads((copy / "manifest.json").read_text())
    man["a_future_field"] = {"knots": [0, 2]}
    (copy / "manifest.json").write_text(json.dumps(man))
    assert load_solver(copy).n_theta > 0
