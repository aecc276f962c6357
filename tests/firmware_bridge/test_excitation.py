"""The collect flight's excitation (firmware_bridge/excitation.py): the PRBS blocks the design side makes, the
first one made before the tick loop (its scipy import would otherwise stall the first excitation tick)."""

from __future__ import annotations

import numpy as np
import pytest

from ddpc_codegen.design import data
from firmware_bridge import excitation
from firmware_bridge.excitation import Excitation


def _exc(seed: int = 3) -> Excitation:
    return Excitation(2, [0.05, 0.1], hold=4, seed=seed)


def test_excitation_is_the_seeded_prbs_blocks_one_after_another():
    s = _exc()
    s.prepare()
    got = np.array([s.next() for _ in range(2 * s.BLOCK + 5)])
    want = np.vstack([data.prbs(s.BLOCK, 2, amplitude=[0.05, 0.1], min_hold=4, seed=3 * 1009 + i)
                      for i in range(3)])[: len(got)]
    np.testing.assert_array_equal(got, want)


def test_a_prepared_excitation_makes_nothing_on_the_first_ticks(monkeypatch):
    s = _exc()
    s.prepare()

    def refuse(*a, **k):
        raise AssertionError("a PRBS block made on a tick")

    monkeypatch.setattr(excitation, "prbs", refuse)
    assert np.abs([s.next() for _ in range(100)]).max() > 0
    with pytest.raises(AssertionError, match="on a tick"):  # an unprepared one would make it on its first tick
        _exc().next()
