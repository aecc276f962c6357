"""firmware_bridge.gc_pacer.GcPacer: the collector off during the loop, its passes only when the loop is idle and
due, the middle generation's every N passes, and the collector as it was afterwards."""

import gc

import pytest

from firmware_bridge.gc_pacer import GcPacer


def test_passes_come_only_when_idle_and_due_and_the_collector_is_restored(monkeypatch):
    calls = []
    real = gc.collect
    monkeypatch.setattr(gc, "collect", lambda *a: calls.append(a) or real(*a))
    was = gc.isenabled()
    p = GcPacer(every=1.0, middle_every=3)
    p.idle(100.0)  # not started: nothing
    assert calls == []
    p.start()
    try:
        assert not gc.isenabled() and gc.get_freeze_count() > 0 and calls == [()]
        t0 = p._last
        for k in range(1, 80):  # 0.1 s apart: a pass each second, the third a middle-generation one
            p.idle(t0 + 0.1 * k)
        assert calls[1:] == [(0,), (0,), (1,), (0,), (0,), (1,), (0,)]
    finally:
        p.stop()
    assert gc.isenabled() == was and gc.get_freeze_count() == 0
    p.stop()  # twice: nothing more
    assert gc.isenabled() == was


@pytest.mark.skipif(not gc.isenabled(), reason="the collector is off in this process")
def test_a_collector_that_was_off_stays_off():
    gc.disable()
    try:
        p = GcPacer()
        p.start()
        p.stop()
        assert not gc.isenabled()
    finally:
        gc.enable()
