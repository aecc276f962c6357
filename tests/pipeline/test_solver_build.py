"""build_solver: `ddpc-codegen codegen` and `ddpc-codegen fit` refuse the same bad data with the same
one-line message (exit 2, no traceback), and a failed rebuild keeps the working solver."""

import zipfile

import numpy as np
import pytest

from support.lti import random_lti
from ddpc_codegen import IODataset
from ddpc_codegen.cli.main import main
from ddpc_codegen.pipeline.solver_build import build_solver

CONFIG = """name = "sbtest"
[horizon]
t_ini = 4
t_f = 3
dt = 0.005
[signals]
inputs = ["z_ref"]
outputs = ["z"]
[cost]
Q = [1.0]
R = [0.1]
[bounds]
u_min = [-2.0]
u_max = [2.0]
[predictor]
method = "lsq"
"""


def _dataset(dt=0.005, names=("z_ref", "z")) -> IODataset:
    sys_ = random_lti(3, 1, 1, 8)
    rng = np.random.default_rng(8)
    u = rng.standard_normal((300, 1))
    y, _ = sys_.simulate(u, np.zeros(3))
    return IODataset(u, y, dt, input_names=[names[0]], output_names=[names[1]])


@pytest.fixture()
def cfg(tmp_path):
    path = tmp_path / "sb.toml"
    path.write_text(CONFIG)
    return path


def _both(cfg, data, tmp_path, capsys) -> list[str]:
    """stderr of `codegen` and of `fit --no-codegen` on the same file (each must exit 2)."""
    errs = []
    for argv in (["codegen", str(cfg), "--dataset", str(data), "--out", str(tmp_path / "gen"), "--quiet"],
                 ["fit", str(cfg), str(data), "--no-codegen", "--quiet"]):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err.strip()
        assert "\n" not in err and "Traceback" not in err
        errs.append(err.split(": error: ", 1)[1])
    assert errs[0] == errs[1]
    return errs


def test_swapped_channel_names(cfg, tmp_path, capsys):
    data = _dataset(names=("z", "z_ref")).save(tmp_path / "swapped.npz")
    msg = _both(cfg, data, tmp_path, capsys)[0]
    assert msg.startswith(f"{cfg} with dataset {data}: ")


def test_other_rate(cfg, tmp_path, capsys):
    data = _dataset(dt=0.01).save(tmp_path / "100hz.npz")
    assert _both(cfg, data, tmp_path, capsys)[0] == (
        f"{cfg} with dataset {data}: the dataset is sampled every 0.01 s but [horizon] dt = 0.005 s; resample the "
        "data (e.g. ddpc-codegen import-ulog --rate) or fix [horizon] dt")


def test_nan_data(cfg, tmp_path, capsys):
    good = _dataset().save(tmp_path / "good.npz")
    with np.load(good, allow_pickle=False) as z:
        entries = {k: z[k] for k in z.files}
    entries["y_0"] = entries["y_0"].copy()
    entries["y_0"][7, 0] = np.nan
    bad = tmp_path / "nan.npz"
    np.savez(bad, **entries)
    assert _both(cfg, bad, tmp_path, capsys)[0] == (
        f"dataset {bad}: y of trajectory 0 has 1 non-finite value(s) (first at sample 7, channel 0: nan); clean or "
        "drop them before building a dataset")


def test_bad_crc(cfg, tmp_path, capsys):
    good = _dataset().save(tmp_path / "good.npz")
    with zipfile.ZipFile(good) as z:
        info = z.getinfo("u_0.npy")
    raw = bytearray(good.read_bytes())
    start = info.header_offset + 30 + len(info.filename) + len(info.extra) + info.compress_size // 2
    raw[start] ^= 0xFF
    bad = tmp_path / "crc.npz"
    bad.write_bytes(bytes(raw))
    msg = _both(cfg, bad, tmp_path, capsys)[0]
    assert msg.startswith(f"dataset {bad} is damaged or not an IODataset file (")


def test_missing_dataset(cfg, tmp_path, capsys):
    assert _both(cfg, tmp_path / "absent.npz", tmp_path, capsys)[0] == f"dataset file {tmp_path / 'absent.npz'} does not exist"


@pytest.mark.compiler
def test_failed_rebuild_keeps_the_solver(cfg, tmp_path, capsys, monkeypatch):
    data = _dataset().save(tmp_path / "good.npz")
    argv = ["codegen", str(cfg), "--dataset", str(data), "--out", str(tmp_path / "gen"), "--quiet"]
    assert main(argv) == 0
    folder = tmp_path / "gen" / "sbtest"
    before = {p.name: p.read_bytes() for p in folder.iterdir() if p.is_file()}
    capsys.readouterr()
    monkeypatch.setenv("CC", "/bin/false")
    assert main(argv + ["--backend", "osqp"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"ddpc-codegen codegen: error: {folder} not replaced (the previous solver there is kept): "
                          "compiling solver 'sbtest' failed")
    assert {p.name: p.read_bytes() for p in folder.iterdir() if p.is_file()} == before


def test_build_solver_in_memory_and_fit_only(cfg):
    built = build_solver(cfg, _dataset(), None)
    assert built.path is None and built.problem.config.name == "sbtest" and built.provenance["path"] == "<in memory>"
    assert built.dataset.input_names == ("z_ref",)


def test_holdout_figures_reach_the_log_the_report_and_the_provenance(cfg):
    logged: list[str] = []
    built = build_solver(cfg, _dataset(), None, holdout=0.4, log=logged.append)
    h = built.report["holdout"]
    assert built.provenance["holdout"] is h and h["share"] == 0.4 and h["outputs"] == ["z"]
    assert h["rmse"][0] < 1e-8 < h["persistence_rmse"][0]  # an exact LTI system: predicted exactly
    assert any("held-out prediction" in m for m in logged) and any(m.strip().startswith("z:") for m in logged)
    assert "holdout" not in build_solver(cfg, _dataset(), None).report  # off unless asked


@pytest.mark.parametrize("share, message", [("1.5", "a share in [0, 1)"), ("-0.1", "a share in [0, 1)"),
                                            ("nan", "a share in [0, 1)"), ("a fifth", "a share in [0, 1), got 'a fifth'")])
def test_codegen_refuses_a_holdout_share_outside_zero_one(cfg, capsys, share, message):
    with pytest.raises(SystemExit) as e:
        main(["codegen", str(cfg), "--holdout", share])
    assert e.value.code == 2 and message in capsys.readouterr().err
