"""Sizes checked before reading (a huge declared shape never reaches an allocation), and output files:
a folder is refused, an existing file is replaced only when asked."""

import io
import json
import zipfile

import numpy as np
import pytest

from ddpc_codegen import DataError, IODataset
from ddpc_codegen.design.data import MAX_ARRAY_BYTES, output_path
from ddpc_codegen.design.fleet import _file_info
from support.bounded import bounded_refusal, make_fifo, needs_dev_zero, needs_fifo

HEADER = {"format": "ddpc-iodataset", "version": 1, "n_trajectories": 1, "dt": 0.005, "input_names": ["a"],
          "output_names": ["b"], "input_units": [""], "output_units": [""], "has_phases": False, "metadata": {}}


def _npy(shape, descr="<f8", payload=b"") -> bytes:
    f = io.BytesIO()
    np.lib.format.write_array_header_1_0(f, {"descr": descr, "fortran_order": False, "shape": shape})
    return f.getvalue() + payload


def _npz(path, members: dict[str, bytes], header=None):
    head = np.frombuffer(json.dumps(header or HEADER).encode(), dtype=np.uint8)
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("header.npy", _npy(head.shape, "|u1", head.tobytes()))
        for name, data in members.items():
            z.writestr(f"{name}.npy", data)
    return path


def _message(path) -> str:
    with pytest.raises(DataError) as e:
        IODataset.load(path)
    return str(e.value)


def test_huge_declared_shape_refused_before_reading(tmp_path):
    path = _npz(tmp_path / "huge.npz", {"u_0": _npy((10**12, 1), payload=b"\0" * 8), "y_0": _npy((1, 1), payload=b"\0" * 8)})
    assert _message(path) == (f"dataset {path}: entry 'u_0' declares shape (1000000000000, 1) (7629395 MiB), more "
                              f"than the {MAX_ARRAY_BYTES / 2**20:.0f} MiB allowed")


def test_declared_shape_must_match_the_stored_bytes(tmp_path):
    path = _npz(tmp_path / "short.npz", {"u_0": _npy((100, 1), payload=b"\0" * 16), "y_0": _npy((1, 1), payload=b"\0" * 8)})
    assert _message(path) == (f"dataset {path}: entry 'u_0' declares shape (100, 1) of float64 (800 bytes) but "
                              "stores 16 bytes")


def test_object_arrays_refused(tmp_path):
    path = _npz(tmp_path / "obj.npz", {"u_0": _npy((1,), "|O", b"\0" * 8), "y_0": _npy((1, 1), payload=b"\0" * 8)})
    assert _message(path) == f"dataset {path}: entry 'u_0' has dtype object; only numbers are read"


def test_trajectory_count_beyond_the_entries(tmp_path):
    path = _npz(tmp_path / "many.npz", {}, {**HEADER, "n_trajectories": 10**9})
    assert _message(path) == f"dataset {path}: header n_trajectories = 1000000000 but the file holds 1 entries"


def test_deeply_nested_header_is_a_data_error(tmp_path):
    deep = "[" * 100_000 + "]" * 100_000
    head = np.frombuffer(deep.encode(), dtype=np.uint8)
    path = tmp_path / "deep.npz"
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("header.npy", _npy(head.shape, "|u1", head.tobytes()))
    assert _message(path) == f"{path}: dataset header: nested 100000 levels deep, more than a dataset header may be (32)"


def test_header_integer_beyond_float_range_is_named(tmp_path):
    path = _npz(tmp_path / "big.npz", {}, {**HEADER, "dt": 10**400})
    assert _message(path) == (f"{path}: dt: an integer of 401 digits, beyond the range of any number a dataset header "
                               "holds (±1.8e308)")


@needs_fifo
@needs_dev_zero
def test_a_fifo_or_device_is_never_opened(tmp_path):
    fifo, unblock = make_fifo(tmp_path / "fifo.npz")
    link = tmp_path / "zero.npz"
    link.symlink_to("/dev/zero")
    for p, kind in ((fifo, "a FIFO (named pipe)"), (link, "a character device")):
        for read in (IODataset.load, _file_info):
            assert bounded_refusal(read, p, error=DataError, unblock=unblock) == \
                f"{p}: dataset: is {kind}, not a regular file"


def test_nan_data_file_is_a_data_error(tmp_path):
    u = np.zeros((5, 1))
    u[3, 0] = np.nan
    path = _npz(tmp_path / "nan.npz", {"u_0": _npy((5, 1), payload=u.tobytes()), "y_0": _npy((5, 1), payload=b"\0" * 40)})
    assert _message(path) == (f"dataset {path}: u of trajectory 0 has 1 non-finite value(s) (first at sample 3, "
                              "channel 0: nan); clean or drop them before building a dataset")


def test_output_path_rules(tmp_path):
    with pytest.raises(DataError) as e:
        output_path(tmp_path)
    assert str(e.value) == f"{tmp_path} is a folder; give the dataset file to write, e.g. {tmp_path / 'data.npz'}"
    ds = IODataset(np.zeros((3, 1)), np.ones((3, 1)), 0.01)
    with pytest.raises(DataError):
        ds.save(tmp_path)
    assert not tmp_path.with_name(tmp_path.name + ".npz").exists()
    first = ds.save(tmp_path / "rec", overwrite=False)
    assert first == tmp_path / "rec.npz"
    with pytest.raises(DataError) as e:
        ds.save(tmp_path / "rec", overwrite=False)
    assert str(e.value) == f"{first} exists; pass --overwrite to replace it, or choose another file"
    assert ds.save(first, overwrite=True) == first


def test_collect_refuses_a_folder_and_an_existing_file(tmp_path, capsys):
    from ddpc_codegen.cli.main import main

    assert main(["collect", "--scenario", "flying", "--duration", "1", "-o", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (f"ddpc-codegen collect: error: {tmp_path} is a folder; give the dataset file to write, e.g. "
                   f"{tmp_path / 'data.npz'}")
    mine = tmp_path / "mine.npz"
    mine.write_bytes(b"recorded")
    assert main(["collect", "--scenario", "flying", "--duration", "1", "-o", str(mine)]) == 2
    assert "exists; pass --overwrite" in capsys.readouterr().err
    assert mine.read_bytes() == b"recorded"


def test_import_refuses_an_existing_file_before_reading_the_log(tmp_path, capsys):
    from ddpc_codegen.cli.main import main

    mine = tmp_path / "mine.npz"
    mine.write_bytes(b"recorded")
    assert main(["import-tlog", str(tmp_path / "absent.tlog"), "--preset", "pogox-flying", "-o", str(mine)]) == 2
    assert capsys.readouterr().err.strip() == (f"ddpc-codegen import-tlog: error: {mine} exists; pass --overwrite "
                                               "to replace it, or choose another file")
    assert mine.read_bytes() == b"recorded"
