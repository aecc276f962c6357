"""The collect flight's excitation (firmware_bridge/setpoints.py): the PRBS blocks the design side makes, the
first one made before the tick loop (its scipy import would otherwise stall the first excitation tick)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from ddpc_codegen.design import data
from firmware_bridge.setpoints import SetpointShaping


def _shaping(seed: int = 3) -> SetpointShaping:
    s = SetpointShaping()
    s.cfg, s.m = SimpleNamespace(seed=seed, excitation_hold=4), 2
    s._exc_amp, s._exc, s._k_exc = np.array([0.05, 0.1]), None, 0
    return s


def test_excitation_is_the_seeded_prbs_blocks_one_after_another():
    s = _shaping()
    s.prepare_excitation()
    got = np.array([s._excitation() for _ in range(2 * s._EXC_BLOCK + 5)])
    want = np.vstack([data.prbs(s._EXC_BLOCK, 2, amplitude=[0.05, 0.1], min_hold=4, seed=3 * 1009 + i)
                      for i in range(3)])[: len(got)]
    np.testing.assert_array_equal(got, want)


def test_a_prepared_excitation_makes_nothing_on_the_first_ticks(monkeypatch):
    s = _shaping()
    s.prepare_excitation()

    def refuse(*a, **k):
        raise AssertionError("a PRBS block made on a tick")

    monkeypatch.setattr(data, "prbs", refuse)
    assert np.abs([s._excitation() for _ in range(100)]).max() > 0
    with pytest.raises(AssertionError, match="on a tick"):  # an unprepared one would make it on its first tick
        _shaping()._excitation()
