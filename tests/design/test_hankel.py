import numpy as np
import pytest

from ddpc_codegen import DataError, block_hankel, mosaic_hankel, persistency_of_excitation, prbs


def test_block_hankel_hand_checked():
    w = np.array([[1.0, 10.0], [2.0, 20.0], [3.0, 30.0], [4.0, 40.0]])
    H = block_hankel(w, 2)
    expected = np.array([[1, 2, 3], [10, 20, 30], [2, 3, 4], [20, 30, 40]], dtype=float)
    np.testing.assert_array_equal(H, expected)


def test_block_hankel_entry_rule():
    rng = np.random.default_rng(0)
    w = rng.standard_normal((30, 3))
    L = 7
    H = block_hankel(w, L)
    assert H.shape == (L * 3, 30 - L + 1)
    for i in range(L):
        for j in range(H.shape[1]):
            np.testing.assert_array_equal(H[3 * i : 3 * i + 3, j], w[i + j])


def test_mosaic_never_mixes_trajectories():
    a = np.arange(5.0)[:, None]
    b = 100 + np.arange(4.0)[:, None]
    H = mosaic_hankel([a, b], 3)
    assert H.shape == (3, 3 + 2)
    np.testing.assert_array_equal(H[:, :3], block_hankel(a, 3))
    np.testing.assert_array_equal(H[:, 3:], block_hankel(b, 3))
    # no column holds samples of both trajectories
    assert all(np.all(col < 100) or np.all(col >= 100) for col in H.T)


def test_mosaic_skips_short_and_rejects_all_short():
    a, short = np.ones((6, 1)), np.ones((2, 1))
    assert mosaic_hankel([a, short], 3).shape == (3, 4)
    with pytest.raises(DataError, match="no trajectory is long enough for depth 3"):
        mosaic_hankel([short], 3)
    with pytest.raises(DataError, match="trajectory 1 has 2 channels"):
        mosaic_hankel([a, np.ones((6, 2))], 3)


def test_hankel_errors():
    with pytest.raises(DataError, match="needs at least 5 samples; got 3"):
        block_hankel(np.ones((3, 1)), 5)
    with pytest.raises(DataError, match="NaN"):
        block_hankel(np.array([1.0, np.nan, 2.0]), 2)


def test_pe_prbs_passes_with_report():
    u = prbs(600, 2, seed=3)
    rep = persistency_of_excitation(u, 30)
    assert rep.ok and rep.rank == rep.required_rank == 60
    assert rep.singular_values.shape == (60,) and rep.singular_values[-1] > rep.tol
    assert np.isfinite(rep.condition_number)
    assert "persistently exciting of order 30: rank 60/60" in rep.summary()


def test_pe_constant_and_short_fail_with_report():
    const = persistency_of_excitation(np.ones((600, 2)), 30)
    assert not const.ok and const.rank == 1 and const.singular_values.shape == (60,)
    assert "NOT persistently exciting" in const.summary()
    short = persistency_of_excitation(prbs(80, 2, seed=1), 30)  # 51 columns < 60 rows
    assert not short.ok and short.rank <= 51
    tiny = persistency_of_excitation(prbs(20, 2, seed=1), 30)
    assert not tiny.ok and tiny.columns == 0


def test_pe_mosaic_of_trajectories():
    parts = [prbs(200, 1, seed=s) for s in range(3)]
    assert persistency_of_excitation(parts, 20).ok
