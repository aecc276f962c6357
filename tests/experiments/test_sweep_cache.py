"""The sweep's fit cache: numbers + JSON with a content hash; edited, foreign or pickled files are refused
and never executed."""

import json
import pickle

import numpy as np
import pytest

from support.lti import random_lti
from ddpc_codegen import DataError, IODataset, fit_predictor
from ddpc_codegen.experiments.sweep_cache import load_predictor, save_predictor


@pytest.fixture(scope="module")
def pred():
    sys_ = random_lti(3, 2, 1, 4)
    rng = np.random.default_rng(4)
    u = rng.standard_normal((300, 2))
    y, _ = sys_.simulate(u, np.zeros(3))
    return fit_predictor(IODataset(u, y, 0.01, input_names=["a", "b"], output_names=["c"]), 5, 4, "pem")


def test_round_trip_is_exact(pred, tmp_path):
    back = load_predictor(save_predictor(tmp_path / "k.npz", pred, "k"), "k")
    assert back.digest == pred.digest and back.input_names == ("a", "b") and back.options["ridge"] == pred.options["ridge"]
    assert back.excitation().summary() == pred.excitation().summary()
    assert np.array_equal(back.options["_r_factor"], pred.options["_r_factor"])
    rng = np.random.default_rng(0)
    args = rng.standard_normal(10), rng.standard_normal(5), rng.standard_normal(8)
    assert all(np.array_equal(a, b) for a, b in zip(back.predict(*args), pred.predict(*args)))


def _rewrite(path, **changes):
    with np.load(path, allow_pickle=False) as z:
        entries = {k: z[k] for k in z.files}
    entries.update(changes)
    np.savez(path, **entries)


def test_edited_matrix_refused(pred, tmp_path):
    path = save_predictor(tmp_path / "k.npz", pred, "k")
    _rewrite(path, Gy_u=pred.Gy_u + 1e-9)
    with pytest.raises(DataError) as e:
        load_predictor(path, "k")
    assert str(e.value) == (f"sweep fit cache {path}: its content hash or key does not match (edited, damaged or "
                            "another fit's file); delete it to fit again")


def test_edited_meta_and_rehashed_refused_by_the_digest(pred, tmp_path):
    from ddpc_codegen.experiments import sweep_cache

    path = save_predictor(tmp_path / "k.npz", pred, "k")
    with np.load(path, allow_pickle=False) as z:
        meta = json.loads(bytes(z["meta"]).decode())
        arrays = {k: z[k] for k in z.files if k != "meta"}
    arrays["Gy_w"] = arrays["Gy_w"] * 2
    meta.pop("sha256")
    meta["sha256"] = sweep_cache._content_hash(meta, arrays)
    np.savez(path, meta=np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8), **arrays)
    with pytest.raises(DataError) as e:
        load_predictor(path, "k")
    assert str(e.value) == (f"sweep fit cache {path}: the predictor's matrices do not match its digest; delete it "
                            "to fit again")


def test_another_keys_file_refused(pred, tmp_path):
    path = save_predictor(tmp_path / "k.npz", pred, "k")
    with pytest.raises(DataError, match="content hash or key does not match"):
        load_predictor(path, "other")


MARKER = "/tmp/ddpc_test_planted_pickle_ran"


class _Planted:
    def __reduce__(self):
        return (open, (MARKER, "w"))


def test_planted_pickle_is_not_run(tmp_path):
    from pathlib import Path

    marker = Path(MARKER)
    marker.unlink(missing_ok=True)
    path = tmp_path / "k.npz"
    path.write_bytes(pickle.dumps(_Planted()))
    with pytest.raises(DataError) as e:
        load_predictor(path, "k")
    assert str(e.value).startswith(f"sweep fit cache {path} is damaged (")
    np.savez(path, meta=np.array([_Planted()], dtype=object))
    with pytest.raises(DataError) as e:
        load_predictor(path, "k")
    assert str(e.value) == (f"sweep fit cache {path}: entry 'meta' has dtype object; only numbers are read; delete it "
                            "to fit again")
    assert not marker.exists()
