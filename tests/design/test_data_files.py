"""Damaged or foreign .npz files are a DataError naming the file, never a zipfile / zlib traceback."""

import json

import numpy as np
import pytest

from ddpc_codegen import DataError, IODataset


@pytest.fixture()
def saved(tmp_path):
    rng = np.random.default_rng(0)
    ds = IODataset([rng.standard_normal((300, 2)), rng.standard_normal((200, 2))],
                   [rng.standard_normal((300, 1)), rng.standard_normal((200, 1))], 0.01,
                   input_names=["a", "b"], output_names=["c"], input_units=["m", "rad"], output_units=["m"])
    return ds, ds.save(tmp_path / "good.npz")


def _header_npz(path, header, **arrays):
    np.savez(path, header=np.frombuffer(json.dumps(header).encode(), dtype=np.uint8), **arrays)
    return path


def _raises_naming(path, *fragments):
    with pytest.raises(DataError) as e:
        IODataset.load(path)
    msg = str(e.value)
    assert str(path) in msg
    for f in fragments:
        assert f in msg, msg
    return msg


@pytest.mark.parametrize("keep", [0.0, 0.1, 0.5, 0.9, 0.999])
def test_truncated_file(saved, tmp_path, keep):
    _, good = saved
    data = good.read_bytes()
    bad = tmp_path / "cut.npz"
    bad.write_bytes(data[: int(keep * len(data))])
    _raises_naming(bad, "damaged or not an IODataset file")


def test_empty_file(tmp_path):
    bad = tmp_path / "empty.npz"
    bad.write_bytes(b"")
    _raises_naming(bad, "damaged or not an IODataset file")


def test_bit_flips_are_an_error_or_harmless(saved, tmp_path):
    # The zip CRC protects the arrays: a flipped bit is either refused or (in a field nobody reads) harmless.
    ds, good = saved
    data = bytearray(good.read_bytes())
    refused = 0
    for pos in np.linspace(0, len(data) - 1, 60).astype(int):
        flipped = bytearray(data)
        flipped[pos] ^= 0x10
        bad = tmp_path / f"flip{pos}.npz"
        bad.write_bytes(bytes(flipped))
        try:
            back = IODataset.load(bad)
        except DataError as e:
            assert str(bad) in str(e)
            refused += 1
            continue
        for a, b in zip(back.u + back.y, ds.u + ds.y):
            np.testing.assert_array_equal(a, b)
    assert refused >= 40


def test_not_a_zip_and_pickled(tmp_path):
    txt = tmp_path / "notes.npz"
    txt.write_text("flight notes, not data\n")
    _raises_naming(txt, "damaged or not an IODataset file")


@pytest.mark.parametrize("header, arrays, fragment", [
    (None, {"x": np.zeros(3)}, "no 'header' entry; entries: ['x']"),
    ([1, 2, 3], {}, "its header is not a ddpc-iodataset header"),
    ({"format": "other"}, {}, "its header is not a ddpc-iodataset header"),
    ({"format": "ddpc-iodataset", "n_trajectories": 1}, {}, "header lacks ['dt', 'input_names'"),
    ({"format": "ddpc-iodataset", "n_trajectories": 2, "dt": 0.01, "input_names": ["a"], "output_names": ["c"],
      "input_units": [""], "output_units": [""]}, {"u_0": np.zeros((5, 1)), "y_0": np.zeros((5, 1))},
     "entries ['u_1', 'y_1'] are missing"),
    ({"format": "ddpc-iodataset", "n_trajectories": "1", "dt": 0.01, "input_names": ["a"], "output_names": ["c"],
      "input_units": [""], "output_units": [""]}, {}, "n_trajectories must be a positive integer; got '1'"),
    ({"format": "ddpc-iodataset", "n_trajectories": 1, "dt": "fast", "input_names": ["a"], "output_names": ["c"],
      "input_units": [""], "output_units": [""]}, {"u_0": np.zeros((5, 1)), "y_0": np.zeros((5, 1))},
     "dt must be a positive number of seconds; got 'fast'"),
    ({"format": "ddpc-iodataset", "n_trajectories": 1, "dt": 0.01, "input_names": ["a", "b"], "output_names": ["c"],
      "input_units": [""], "output_units": [""]}, {"u_0": np.zeros((5, 1)), "y_0": np.zeros((5, 1))},
     "input_names has 2 entries"),
])
def test_foreign_or_incomplete_files(tmp_path, header, arrays, fragment):
    path = tmp_path / "foreign.npz"
    if header is None:
        np.savez(path, **arrays)
    else:
        _header_npz(path, header, **arrays)
    _raises_naming(path, fragment)
