"""The generated online update (``<name>_adapt.c``) equals the numpy reference (runtime/adaptation.py)."""

from __future__ import annotations

import numpy as np
import pytest

from ddpc_codegen.codegen.adapt import compile_alone
from ddpc_codegen.design.adaptation import adapter
from ddpc_codegen.design.config import SteeringConfig
from ddpc_codegen.design.data import IODataset
from ddpc_codegen.design.fit import fit_incremental
from ddpc_codegen.design.predictor import fit_predictor
from ddpc_codegen.design.problem import SteeringProblem
from ddpc_codegen.runtime.adaptation import REJECTIONS, AdaptSettings
from support.lti import random_lti


def _dataset(seed: int, T: int = 400) -> IODataset:
    sys_ = random_lti(4, 2, 2, seed)
    rng = np.random.default_rng(seed)
    u = rng.standard_normal((T, 2)) * [0.3, 2.0]
    y, _ = sys_.simulate(u, np.zeros(4))
    return IODataset(u, y + 1e-3 * rng.standard_normal(y.shape), 0.01)


def _problem(form: str) -> SteeringProblem:
    ds = _dataset(0)
    pred = fit_incremental(ds, 5, 3, "lsq", ridge=1e-5) if form == "incremental" else \
        fit_predictor(ds, 4, 3, "pem", ridge=1e-5)
    cfg = SteeringConfig(t_ini=pred.t_ini, t_f=3, m=2, p=2, Q=[10.0, 3.0], R=[1.0, 0.5], R_mode="offset",
                         lambda_sigma=50.0, predictor={"method": pred.method})
    return SteeringProblem(pred, cfg)


def _arr(ffi, ptr, n):
    return np.frombuffer(ffi.buffer(ptr, 8 * n), dtype=np.float64).copy()


@pytest.mark.parametrize("form", ["absolute", "incremental"])
def test_generated_update_equals_the_numpy_reference(form, tmp_path):
    """A few hundred random windows from a changed system, a re-solve every 40: R, G, the verdicts and
    the counters of C and numpy agree (R and G to 1e-9 relative)."""
    prob = _problem(form)
    st = AdaptSettings(enabled=True, forgetting=0.99, window=40, max_change=0.3, min_excitation=1e-4)
    name = f"ad_{form}"
    ffi, lib = compile_alone(prob, st, tmp_path, name)
    ref = adapter(prob, st)
    ws = ffi.new(f"{name}_adapt_workspace *")
    assert getattr(lib, f"{name}_adapt_init")(ws) == 0
    lay = ref.layout
    w, q = lay.width, lay.q_y + lay.q_s
    np.testing.assert_allclose(_arr(ffi, ws.G, q * lay.r).reshape(q, lay.r), ref.G, rtol=0, atol=1e-12)
    other = random_lti(4, 2, 2, 7)
    rng = np.random.default_rng(1)
    u = rng.standard_normal((400, 2)) * [0.3, 2.0]
    y, _ = other.simulate(u, np.zeros(4))
    sig = np.hstack([np.diff(u, axis=0), np.diff(y, axis=0)]) if form == "incremental" else np.hstack([u, y])
    verdicts = []
    for k in range(300):
        win = np.ascontiguousarray(sig[k : k + lay.depth])
        if k == 50:
            win = win.copy()
            win[3, 1] = np.nan  # skipped by both
        c_ok = getattr(lib, f"{name}_adapt_push")(ws, ffi.from_buffer("double[]", win))
        assert c_ok == int(ref.push(win))
        if k % 40 == 39:
            res = getattr(lib, f"{name}_adapt_resolve")(ws)
            verdict = ref.resolve()
            verdicts.append(verdict)
            assert res == (0 if verdict == "accepted" else 1 + REJECTIONS.index(verdict))
            if verdict == "accepted":
                np.testing.assert_allclose(_arr(ffi, ws.Gc, q * lay.r).reshape(q, lay.r), ref.pending,
                                           rtol=0, atol=1e-9 * np.abs(ref.pending).max())
            assert getattr(lib, f"{name}_adapt_swap")(ws) == int(ref.swap())
            np.testing.assert_allclose(_arr(ffi, ws.G, q * lay.r).reshape(q, lay.r), ref.G, rtol=0,
                                       atol=1e-9 * np.abs(ref.G).max())
    R_c = _arr(ffi, ws.R, w * w).reshape(w, w)
    np.testing.assert_allclose(R_c, ref.R, rtol=0, atol=1e-9 * np.abs(ref.R).max())
    c = ws.counts
    assert (c.updates, c.skipped, c.resolves, c.accepted, c.swaps, c.clipped) == tuple(
        ref.counts[k] for k in ("updates", "skipped", "resolves", "accepted", "swaps", "clipped"))
    assert [c.rejected[i + 1] for i in range(len(REJECTIONS))] == [ref.counts[f"rejected_{r}"] for r in REJECTIONS]
    assert "accepted" in verdicts  # the changed system is learnt: at least one verified swap


def test_rank_deficient_factor_is_refused_at_init(tmp_path):
    """ridge 0 on noise-free data: R11 is singular, the C init refuses (as the reference does)."""
    sys_ = random_lti(2, 1, 1, 3)
    u = np.random.default_rng(3).standard_normal((300, 1))
    y, _ = sys_.simulate(u, np.zeros(2))
    pred = fit_predictor(IODataset(u, y, 0.01), 4, 3, "lsq")
    prob = SteeringProblem(pred, SteeringConfig(t_ini=4, t_f=3, m=1, p=1, Q=[1.0], R=[1.0], R_mode="offset",
                                                predictor={"method": "lsq"}))
    from ddpc_codegen.errors import DataError

    with pytest.raises(DataError, match=r"^the shipped R factor is rank deficient"):
        compile_alone(prob, AdaptSettings(window=10), tmp_path, "ad_rank")


def test_generate_with_adaptation_adds_the_update_and_leaves_the_rest_as_it_was(tmp_path):
    """generate(adapt=...): the compiled extension carries <name>_adapt_*, the manifest the fit statistic;
    every other source is byte-for-byte the non-adaptive build's, and adapt disabled emits nothing new."""
    import json

    from ddpc_codegen.codegen.generate import generate
    from ddpc_codegen.runtime.loader import load_solver

    prob = _problem("incremental")
    st = AdaptSettings(enabled=True, forgetting=0.995, window=40)
    folders = {k: generate(prob, tmp_path / k, name="adsolver", n_vectors=4, adapt=a)
               for k, a in (("plain", None), ("off", AdaptSettings()), ("on", st))}
    man = {k: json.loads((f / "manifest.json").read_text()) for k, f in folders.items()}
    assert man["plain"]["sources"] == man["off"]["sources"]
    extra = set(man["on"]["sources"]) - set(man["plain"]["sources"])
    assert extra == {"adsolver_adapt.c", "adsolver_adapt.h", "adsolver_adapt_data.c", "adsolver_adapt_data.h"}
    assert all(man["on"]["sources"][f] == h for f, h in man["plain"]["sources"].items())
    fs = man["on"]["fit_statistic"]
    assert fs["adapt"]["forgetting"] == 0.995 and fs["signal"] == "increments"
    R = np.load(folders["on"] / fs["file"])
    np.testing.assert_array_equal(R, adapter(prob, st).R)
    solver = load_solver(folders["on"])
    lib, ffi = solver._lib, solver._ffi
    ws = ffi.new("adsolver_adapt_workspace *")
    assert lib.adsolver_adapt_init(ws) == 0 and lib.adsolver_adapt_swap(ws) == 0
    assert not hasattr(load_solver(folders["plain"])._lib, "adsolver_adapt_init")
