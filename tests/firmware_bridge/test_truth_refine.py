"""A SITL's truth made finer than its messages carry it: below the grid (the Dequantizer's cells) and on the
sender's clock through the link's bursts (LinkClock). SimTruth's use of both: ``test_bridge_truth.py``."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from firmware_bridge.truth_refine import Dequantizer, LinkClock


def test_dequantizer_restarts_when_the_cells_contradict_the_integral():
    d = Dequantizer(0.01, (0.0, 1.0))
    assert d.update(1.00, 0.0, 0.0) == pytest.approx(1.005)
    assert d.update(1.50, 0.0, 0.1) == pytest.approx(1.505)  # a jump no rate explains: this cell again


@pytest.mark.parametrize("truth_first", [True, False])
def test_link_clock_puts_bursty_truth_on_the_senders_clock(truth_first):
    """ArduCopter's loop sends the truth and a stamped message together every 5 ms; TCP delivers several loops at
    once, 0-20 ms late. Matched first come first matched (in either order), each truth sample takes its loop's time
    on the receiver's clock (the quickest transit's offset), not its arrival."""
    rng = np.random.default_rng(0)
    clock, placed, sent = LinkClock(), [], []
    boot0, transit = 100.0, 0.0001  # the sender's clock is 100 s ahead of the receiver's
    delay = 0.0
    for k in range(400):
        boot = boot0 + 0.005 * k
        if k % 4 == 0:
            delay = rng.uniform(0.0, 0.02)  # a new burst: four loops arrive together
        rx = boot - boot0 + transit + delay
        first, second = ("truth", "stamp") if truth_first else ("stamp", "truth")
        for i, what in enumerate((first, second)):
            if what == "truth":
                placed += clock.truth(k, rx + 1e-5 * i)
            else:
                placed += clock.stamped(boot, rx + 1e-5 * i)
        sent.append(boot - boot0 + transit)
    got = dict(placed)
    assert clock.paired == len(placed) == 400 and clock.unpaired == 0
    err = np.array([got[k] - sent[k] for k in range(400)])
    assert err.min() > -1e-6 and err.max() < 0.02  # never before it was sent, never later than it arrived
    assert np.abs(err[100:]).max() < 5e-4  # once a quick burst set the offset: its send time, whatever its delay


def test_link_clock_keeps_the_arrival_of_a_truth_sample_without_partner():
    clock = LinkClock(pair_s=0.002)
    assert clock.stamped(10.0, 1.0) == []
    assert clock.truth("a", 1.0005) == [("a", pytest.approx(1.0))]  # its loop's stamp
    assert clock.truth("b", 1.010) == []  # none yet: held
    assert clock.truth("c", 1.020) == [("b", 1.010)]  # none came within 2 ms: its arrival
    assert clock.at(10.5) == pytest.approx(1.5) and clock.unpaired == 1


def test_link_clock_places_a_mavlink_message_by_its_type():
    clock = LinkClock()
    stamp = SimpleNamespace(get_type=lambda: "ATTITUDE", time_boot_ms=10_000)
    truth = SimpleNamespace(get_type=lambda: "SIM_STATE")
    assert clock.place(truth, 1.0, "ATTITUDE") == []  # held for its partner
    assert clock.place(stamp, 1.0005, "ATTITUDE") == [(truth, pytest.approx(1.0005))]
