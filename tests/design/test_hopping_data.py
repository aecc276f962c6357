"""Hopping data preparation: what a raw hopping log must carry, and what it gives."""

from __future__ import annotations

import numpy as np
import pytest

from ddpc_codegen import DataError, IODataset, SteeringConfig
from ddpc_codegen.design.hopping_data import ArtificialIOSpec, is_hopping_config, prepare_hopping
from ddpc_codegen.values.phases import ASCENT, DESCENT, GROUND
from ddpc_codegen.experiments.pipeline import default_config


def _cfg() -> SteeringConfig:
    return SteeringConfig.from_toml(default_config("hopping"))


def _labelled(n: int = 400, **kw) -> IODataset:
    rng = np.random.default_rng(0)
    ph = np.resize(np.r_[[DESCENT] * 40, [GROUND] * 20, [ASCENT] * 40], n)
    return IODataset(rng.standard_normal((n, 3)), rng.standard_normal((n, 3)), 0.005,
                     input_names=("z_ref", "roll_ref", "pitch_ref"), output_names=("z", "roll", "pitch"),
                     phases=[ph], **kw)


def test_the_shipped_hopping_config_is_a_hopping_config():
    cfg = _cfg()
    assert is_hopping_config(cfg)
    # the defaults, except the window refit (off by default: its threshold is the robot's)
    assert ArtificialIOSpec(**cfg.artificial_io) == ArtificialIOSpec(refit_residual=6.5e-3)
    assert not is_hopping_config(SteeringConfig.from_toml(default_config("flying")))


def test_a_log_without_phase_labels_is_refused_with_the_reason():
    ds = _labelled()
    raw = IODataset(list(ds.u), list(ds.y), ds.dt, input_names=ds.input_names, output_names=ds.output_names)
    with pytest.raises(DataError, match="log.npz has no phase labels.*hopping config"):
        prepare_hopping(raw, _cfg(), where="log.npz")


def test_already_stitched_hops_are_refused():
    with pytest.raises(DataError, match="already stitched"):
        prepare_hopping(_labelled(metadata={"artificial_io": {"t_d": 10}}), _cfg())


def test_a_labelled_log_gives_stitched_hops_and_the_operator():
    # random (not dynamical) data: only the bookkeeping is checked here; the method is tested in
    # test_artificial_io.py and the generated completion in tests/codegen
    hd = prepare_hopping(_labelled(2000), _cfg(), ArtificialIOSpec(t_d=5, t_a=20, ground_margin=2))
    assert hd.report["hops"] == hd.dataset.n_trajectories > 0
    assert hd.art.depth == 5 + 20 + 2 + 20 and hd.dataset.metadata["artificial_io"]["t_d"] == 5
