import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from ddpc_codegen import DataError, IODataset, prbs


def test_single_and_multi_trajectory_shapes():
    ds = IODataset(np.zeros((10, 2)), np.ones((10, 1)), 0.005, input_names=["a", "b"], output_names=["c"])
    assert (ds.m, ds.p, ds.n_trajectories, ds.n_samples) == (2, 1, 1, 10)
    ds2 = IODataset([np.zeros((10, 2)), np.zeros((7, 2))], [np.zeros((10, 1)), np.zeros((7, 1))], 0.01)
    assert ds2.lengths == (10, 7) and ds2.columns(5) == 6 + 3
    assert ds2.input_names == ("u0", "u1")


def test_one_dimensional_signals_become_single_channel():
    ds = IODataset(np.arange(5.0), np.arange(5.0), 1.0)
    assert ds.u[0].shape == (5, 1)


@pytest.mark.parametrize(
    "u, y, dt, msg",
    [
        (np.zeros((10, 2)), np.zeros((9, 1)), 0.1, "trajectory 0: u has 10 samples but y has 9"),
        (np.zeros((10, 2, 1)), np.zeros((10, 1)), 0.1, "u of trajectory 0 must be a 2-D time-major array"),
        (np.array([[0.0, np.nan]] * 4), np.zeros((4, 1)), 0.1, "u of trajectory 0 has 4 non-finite value(s) (first at sample 0, channel 1"),
        (np.zeros((4, 1)), np.array([[np.inf]] * 4), 0.1, "y of trajectory 0 has 4 non-finite"),
        (np.zeros((4, 1)), np.zeros((4, 1)), 0.0, "dt must be a positive number of seconds; got 0.0"),
        (np.zeros((4, 1)), np.zeros((4, 1)), "x", "dt must be a positive number of seconds; got 'x'"),
        ([np.zeros((4, 1)), np.zeros((4, 2))], [np.zeros((4, 1))] * 2, 0.1, "trajectory 1 has m=2, p=1 but trajectory 0 has m=1, p=1"),
        ([np.zeros((4, 1))], [np.zeros((4, 1))] * 2, 0.1, "got 1 input trajectories but 2 output trajectories"),
        ([], [], 0.1, "at least one trajectory"),
        (np.zeros((0, 1)), np.zeros((0, 1)), 0.1, "is empty"),
    ],
)
def test_validation_errors(u, y, dt, msg):
    with pytest.raises(DataError) as e:
        IODataset(u, y, dt)
    assert msg in str(e.value)


def test_names_must_match_channels():
    with pytest.raises(DataError, match=r"input_names has 1 entries \['a'\] but the data has 2 channels"):
        IODataset(np.zeros((4, 2)), np.zeros((4, 1)), 0.1, input_names=["a"])


def test_save_load_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    u = [rng.standard_normal((20, 2)), rng.standard_normal((15, 2))]
    y = [rng.standard_normal((20, 3)), rng.standard_normal((15, 3))]
    ph = [np.arange(20) % 3, np.zeros(15, int)]
    ds = IODataset(u, y, 0.005, input_names=["z_ref", "pitch_ref"], output_names=["z", "roll", "pitch"],
                   input_units=["m", "rad"], output_units=["m", "rad", "rad"], phases=ph,
                   metadata={"source": "test", "seed": 3})
    path = ds.save(tmp_path / "d")
    assert path.suffix == ".npz"
    back = IODataset.load(path)
    assert back.dt == 0.005 and back.input_names == ds.input_names and back.output_units == ds.output_units
    assert back.metadata == {"source": "test", "seed": 3}
    for a, b in zip(ds.u + ds.y + ds.phases, back.u + back.y + back.phases):
        np.testing.assert_array_equal(a, b)


def test_load_errors(tmp_path):
    with pytest.raises(DataError, match="does not exist"):
        IODataset.load(tmp_path / "none.npz")
    np.savez(tmp_path / "x.npz", a=np.zeros(3))
    with pytest.raises(DataError, match="not an IODataset file"):
        IODataset.load(tmp_path / "x.npz")


def test_prbs_values_hold_and_determinism():
    x = prbs(1000, 3, amplitude=[1.0, 0.5, 2.0], min_hold=4, seed=7)
    assert x.shape == (1000, 3)
    for c, a in enumerate([1.0, 0.5, 2.0]):
        assert set(np.unique(x[:, c])) == {-a, a}
    # every run of equal values is a multiple of the hold (except the truncated tail)
    change = np.nonzero(np.diff(x[:, 0]))[0] + 1
    assert np.all(change % 4 == 0)
    np.testing.assert_array_equal(x, prbs(1000, 3, amplitude=[1.0, 0.5, 2.0], min_hold=4, seed=7))
    assert not np.array_equal(x, prbs(1000, 3, amplitude=[1.0, 0.5, 2.0], min_hold=4, seed=8))


def test_prbs_is_maximal_length():
    order = 7
    x = prbs(2 * 127, 1, order=order, seed=1)[:, 0]
    assert np.array_equal(x[:127], x[127:])  # period 2^7 - 1
    assert not any(np.array_equal(x[: 254 - k], x[k:]) for k in range(1, 127))  # no shorter period
    assert np.sum(x[:127] > 0) == 64  # an m-sequence has 2^(n-1) ones per period


@pytest.mark.parametrize("kw, msg", [({"n_samples": 0}, "n_samples > 0"), ({"min_hold": 0}, "min_hold must be >= 1"),
                                     ({"order": 40}, "order must be in 3..24"), ({"channels": 0}, "channels >= 1")])
def test_prbs_errors(kw, msg):
    args = {"n_samples": 10, "channels": 1} | kw
    with pytest.raises(DataError, match=msg):
        prbs(**args)


@settings(max_examples=25, deadline=None)
@given(sigma=st.floats(1e-4, 1e-2), freq=st.floats(0.1, 3.0), amp=st.floats(0.01, 0.5), seed=st.integers(0, 2**31))
def test_output_noise_recovers_white_noise_on_smooth_motion(sigma, freq, amp, seed):
    """sigma of white noise on a smooth motion sampled at 200 Hz, from the third differences (within 15 %),
    whenever the motion's own third difference (jerk dt^3) is small against the noise; on the clean
    channel the estimate stays below that bound."""
    from ddpc_codegen.design.data import output_noise

    jerk_d3 = amp * (2 * np.pi * freq) ** 3 * 0.005 ** 3  # largest third difference of the sine
    assume(jerk_d3 < 0.2 * sigma)
    t = np.arange(3000) * 0.005
    smooth = amp * np.sin(2 * np.pi * freq * t) + 0.3 * t - 0.5 * 4.9 * (t % 0.6) ** 2  # arcs, kinks at hops
    y = smooth + np.random.default_rng(seed).normal(0.0, sigma, t.size)
    ds = IODataset(np.zeros((t.size, 1)), np.column_stack([y, smooth]), 0.005)
    est = output_noise(ds)
    assert est[0] == pytest.approx(sigma, rel=0.15)
    assert est[1] <= 1.4826 * jerk_d3 / np.sqrt(20.0) + 1e-12  # clean channel: the MAD scale of the motion's own jerk


def test_output_noise_of_short_trajectories_is_nan():
    from ddpc_codegen.design.data import output_noise

    assert np.isnan(output_noise(IODataset(np.zeros((3, 1)), np.zeros((3, 2)), 0.005))).all()
