"""Fleet fit: map (per file / slice) + reduction tree == the serial fit; short files skipped by name."""

from __future__ import annotations

import zipfile

import numpy as np
import pytest

from ddpc_codegen.cli.main import build_parser
from ddpc_codegen.design.data import IODataset, prbs
from ddpc_codegen.design.fleet import (_read_rows, _TreeReducer, combine_stats, fit_files, piece_stats, plan_pieces,
                                       plan_stat_pieces, scan_files)
from ddpc_codegen.design.hankel import channel_stats
from ddpc_codegen.design.predictor import FitLayout, fit_predictor, hankel_r_factor, stack_r_factors
from ddpc_codegen.errors import ConfigError, DataError

T_INI, T_F = 4, 6
NAMES = dict(input_names=["z_ref", "pitch_ref"], output_names=["z", "pitch"])


def _trajectory(lti, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """PRBS through a random stable LTI (m = p = 2) with a little output noise."""
    u = prbs(n, 2, amplitude=[0.05, 2.0], min_hold=2, seed=seed)  # channels in very different units
    y, _ = lti.simulate(u, np.zeros(lti.n))
    return u, y * [1.0, 300.0] + [1.5, 0.0] + 1e-3 * np.random.default_rng(seed).standard_normal(y.shape)


@pytest.fixture(scope="module")
def fleet(tmp_path_factory):
    """14 files: 1-3 trajectories each, lengths 4 to 700 samples; 3 files hold no Hankel column."""
    from support.lti import random_lti

    lti = random_lti(4, 2, 2, seed=3)
    tmp = tmp_path_factory.mktemp("fleet")
    paths, used = [], []
    lengths = [[300], [7], [120, 9, 450], [700], [4, 5], [60, 61], [9], [250, 250, 11], [33], [400], [15, 8],
               [500], [90, 200], [10]]
    for i, ls in enumerate(lengths):
        trajs = [_trajectory(lti, n, 100 * i + j) for j, n in enumerate(ls)]
        ds = IODataset([u for u, _ in trajs], [y for _, y in trajs], 0.005, **NAMES)
        paths.append(ds.save(tmp / f"flight_{i:02d}.npz"))
        if max(ls) >= T_INI + T_F:
            used += trajs
    ref = IODataset([u for u, _ in used], [y for _, y in used], 0.005, **NAMES)
    return paths, ref


def _rel(a, b) -> float:
    """Largest relative difference of the predictors' matrices (G = [Gy; Gs], each block by its own size)."""
    pairs = [(getattr(a, k), getattr(b, k)) for k in ("Gy_w", "Gy_u", "Gs_w", "Gs_u")]
    return max(float(np.abs(x - y).max() / max(np.abs(x).max(), 1e-300)) for x, y in pairs)


@pytest.mark.parametrize("method, ridge", [("pem", 0.0), ("lsq", 1e-3)])
def test_fleet_fit_equals_the_serial_fit(fleet, method, ridge):
    paths, ref = fleet
    serial = fit_predictor(ref, T_INI, T_F, method, ridge=ridge)
    msgs: list[str] = []
    fit = fit_files(paths, T_INI, T_F, method, ridge=ridge, chunk_columns=97, block_columns=64, log=msgs.append)
    assert _rel(serial, fit.predictor) <= 1e-10
    assert fit.columns == serial.n_columns and fit.predictor.rank == serial.rank
    np.testing.assert_allclose(fit.predictor.options["channel_scale"], serial.options["channel_scale"], rtol=1e-13)
    assert fit.pieces > len(paths) - 3  # long trajectories were sliced
    skipped = {p for p, _ in fit.skipped}
    assert skipped == {str(paths[i]) for i in (1, 4, 6)}
    assert sum("skipped" in m and "no Hankel column" in m for m in msgs) == 3
    assert 0 < fit.peak_mib_per_worker < 1024


def test_pieces_cover_every_hankel_column_once(fleet):
    paths, _ = fleet
    depth = T_INI + T_F
    infos, _ = scan_files(paths, depth)
    for chunk in (1, 7, 97, 10**6):
        seen: dict[tuple[str, int], list[int]] = {}
        for piece in plan_pieces(infos, depth, chunk):
            assert sum(b - a - depth + 1 for _, a, b in piece.ranges) <= chunk
            for k, a, b in piece.ranges:
                seen.setdefault((piece.path, k), []).extend(range(a, b - depth + 1))
        for info in infos:
            for k, T in enumerate(info.lengths):
                assert sorted(seen.get((info.path, k), [])) == list(range(max(0, T - depth + 1)))


def test_partial_reads_and_tree_order(fleet, tmp_path):
    paths, ref = fleet
    ds = IODataset.load(paths[3])
    with zipfile.ZipFile(paths[3]) as z:
        np.testing.assert_array_equal(_read_rows(z, "y_0.npy", 123, 456), ds.y[0][123:456])
    layout = FitLayout(2, 2, T_INI, T_F, "pem")
    factors = [hankel_r_factor([t], layout, np.ones(4)) for t in ref.trajectories() if t[0].shape[0] >= layout.depth]
    results = []
    for order in (range(len(factors)), reversed(range(len(factors))), np.random.default_rng(0).permutation(len(factors))):
        red = _TreeReducer()
        for i in order:
            red.add(int(i), factors[int(i)])
        results.append(red.result())
    assert all(np.array_equal(results[0], r) for r in results[1:])  # the same tree for any arrival order
    seq = factors[0]
    for f in factors[1:]:
        seq = stack_r_factors(seq, f)
    np.testing.assert_allclose(np.abs(np.diag(results[0])), np.abs(np.diag(seq)), rtol=1e-10)


def test_statistics_pass_equals_the_serial_statistics(fleet):
    paths, ref = fleet
    infos, _ = scan_files(paths, T_INI + T_F)
    for chunk in (3, 50, 10**6):
        parts = [piece_stats(None, piece) for piece in plan_stat_pieces(infos, chunk)]
        rms, std = combine_stats(parts)
        rms0, std0 = channel_stats([np.hstack(t) for t in ref.trajectories()])
        np.testing.assert_allclose(rms, rms0, rtol=1e-13)
        np.testing.assert_allclose(std, std0, rtol=1e-12)


def test_mismatched_files_are_refused_by_name(fleet, tmp_path):
    paths, _ = fleet
    u, y = prbs(50, 2, seed=1), prbs(50, 2, seed=2)
    other_dt = IODataset(u, y, 0.01, **NAMES).save(tmp_path / "slow.npz")
    with pytest.raises(DataError, match="slow.npz has dt = 0.01"):
        fit_files([paths[0], other_dt], T_INI, T_F)
    renamed = IODataset(u, y, 0.005, input_names=["a", "b"], output_names=["z", "pitch"]).save(tmp_path / "renamed.npz")
    with pytest.raises(DataError, match="renamed.npz has inputs"):
        fit_files([paths[0], renamed], T_INI, T_F)
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip")
    with pytest.raises(DataError, match="bad.npz is not a readable"):
        fit_files([bad], T_INI, T_F)
    with pytest.raises(DataError, match="none of the 1 files"):
        fit_files([paths[1]], T_INI, T_F)
    with pytest.raises(ConfigError, match="chunk_columns"):
        fit_files([paths[0]], T_INI, T_F, chunk_columns=0)


def test_cli_registers_fit():
    a = build_parser().parse_args(["fit", "c.toml", "a.npz", "logs/", "--workers", "2", "--no-codegen"])
    assert a.func.__name__ == "_cmd_fit" and a.data == ["a.npz", "logs/"] and a.workers == 2 and a.no_codegen


@pytest.mark.slow
def test_fleet_fit_on_local_ray_equals_serial(fleet):
    pytest.importorskip("ray")
    paths, ref = fleet
    serial = fit_files(paths, T_INI, T_F, "lsq", ridge=1e-3, chunk_columns=97)
    par = fit_files(paths, T_INI, T_F, "lsq", ridge=1e-3, chunk_columns=97, workers=2)
    assert par.workers == 2 and _rel(serial.predictor, par.predictor) <= 1e-12
    assert _rel(fit_predictor(ref, T_INI, T_F, "lsq", ridge=1e-3), par.predictor) <= 1e-10
    assert 0 < par.peak_mib_per_worker < 1024


def test_cli_fit_over_a_folder(fleet, tmp_path, capsys):
    import json

    from ddpc_codegen.cli.main import main

    paths, ref = fleet
    cfg = tmp_path / "fleet.toml"
    cfg.write_text(f'name = "fleet"\n[horizon]\nt_ini = {T_INI}\nt_f = {T_F}\n[signals]\ninputs = ["z_ref", "pitch_ref"]\n'
                   'outputs = ["z", "pitch"]\n[cost]\nQ = [1.0, 1.0]\nR = [1.0, 1.0]\n[predictor]\nmethod = "lsq"\n'
                   'ridge = 1e-3\n')
    assert main(["fit", str(cfg), str(paths[0].parent), "--no-codegen", "--json", "--quiet"]) == 0
    rep = json.loads(capsys.readouterr().out)
    assert rep["used"] == len(paths) - 3 and len(rep["skipped"]) == 3 and rep["workers"] == 1
    assert rep["columns"] == ref.columns(T_INI + T_F) and rep["rank"] == fit_predictor(ref, T_INI, T_F, "lsq", ridge=1e-3).rank
    assert main(["fit", str(cfg), str(tmp_path / "nowhere")]) == 2  # a ConfigError, named
    assert "nowhere does not exist" in capsys.readouterr().err
    inc = tmp_path / "inc.toml"
    inc.write_text(cfg.read_text().replace('method = "lsq"\n', 'method = "lsq"\nform = "incremental"\n'))
    assert main(["fit", str(inc), str(paths[0].parent), "--no-codegen", "--quiet"]) == 2  # refused, not fitted wrong
    assert "streams samples, not increments" in capsys.readouterr().err
