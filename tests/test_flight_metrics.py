"""The one scoring path of a flight (ddpc_codegen.flight_metrics) against a per-tick loop of its definitions."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from ddpc_codegen.flight_metrics import flight_metrics, near_changes, rms, scored_ticks


def _reference(t, y, y_des, settle, active, u, r_nom, thrust, z_truth, steered):
    """The figures tick by tick, written from the docstring's definitions (plain Python, no masks)."""
    idx = [k for k in range(len(t)) if active[k] and not math.isnan(t[k]) and t[k] >= settle]
    r = lambda v: math.sqrt(sum(x * x for x in v) / len(v)) if v else None  # noqa: E731
    p = y.shape[1]
    out = {"rmse": [r([y[k, i] - y_des[k, i] for k in idx]) for i in range(p)], "ticks": len(idx)}
    tr = [k for k in idx if math.isfinite(z_truth[k])]
    out["rmse_z_truth"] = r([z_truth[k] - y_des[k, 0] for k in tr])
    out["estimator_rms"] = r([y[k, 0] - z_truth[k] for k in tr])
    out["estimator_bias"] = sum(y[k, 0] - z_truth[k] for k in tr) / len(tr) if tr else None
    flown = [k for k in range(len(t)) if not math.isnan(t[k]) and t[k] >= settle]  # engaged or not
    adj = [k for k in flown if k + 1 in flown]  # adjacent ticks k, k+1 of the flight: never across a gap
    off = u[:, 0] - r_nom[:, 0]
    out["max_offset_step"] = max((abs(off[k + 1] - off[k]) for k in adj), default=None)
    out["max_ref_step"] = max((abs(u[k + 1, 0] - u[k, 0]) for k in adj), default=None)
    out["thrust_step_rms"] = r([thrust[k + 1] - thrust[k] for k in adj])
    pairs = [k for k in idx if k + 1 in idx]  # adjacent ticks, both scored
    out["offset_step_rms"] = [r([(u[k + 1, j] - r_nom[k + 1, j]) - (u[k, j] - r_nom[k, j]) for k in pairs])
                              for j in range(u.shape[1])]
    out["engaged_fraction"] = sum(bool(steered[k]) for k in idx) / len(idx) if idx else None
    return out


@settings(max_examples=80, deadline=None)
@given(st.integers(1, 25), st.integers(1, 3), st.floats(-1.0, 3.0), st.data())
def test_flight_metrics_equal_the_per_tick_definitions(n, p, settle, data):
    f = st.floats(-10, 10)
    t = data.draw(arrays(np.float64, n, elements=st.one_of(st.floats(-1.0, 5.0), st.just(np.nan))))
    y, y_des = (data.draw(arrays(np.float64, (n, p), elements=f)) for _ in range(2))
    u, r_nom = (data.draw(arrays(np.float64, (n, 2), elements=f)) for _ in range(2))
    thrust = data.draw(arrays(np.float64, n, elements=st.floats(0, 1)))
    z_truth = data.draw(arrays(np.float64, n, elements=st.one_of(f, st.just(np.nan))))
    active, steered = (data.draw(arrays(np.bool_, n)) for _ in range(2))
    got = flight_metrics(t, y, y_des, settle=settle, active=active, u=u, r_nom=r_nom, thrust=thrust,
                         z_truth=z_truth, steered=steered)
    want = _reference(t, y, y_des, settle, active, u, r_nom, thrust, z_truth, steered)
    for key, w in want.items():
        g = got[key]
        if isinstance(w, list):
            assert [v is None for v in g] == [v is None for v in w], key
            assert [v for v in g if v is not None] == pytest.approx([v for v in w if v is not None], rel=1e-9,
                                                                     abs=1e-12), key
        else:
            assert (g is None) == (w is None) and (w is None or g == pytest.approx(w, rel=1e-9, abs=1e-12)), key


def test_no_scored_tick_gives_the_empty_value_and_bad_shapes_are_refused():
    t = np.array([np.nan, 0.5, 1.0])
    y = np.ones((3, 2))
    f = flight_metrics(t, y, y, settle=2.0, u=np.ones((3, 1)), r_nom=np.ones((3, 1)), thrust=np.ones(3),
                       z_truth=np.ones(3), steered=np.ones(3, bool))
    assert f["rmse"] == [None, None] and f["ticks"] == 0 and f["rmse_z_truth"] is None and f["estimator_bias"] is None
    assert f["max_offset_step"] is None and f["thrust_step_rms"] is None and f["engaged_fraction"] is None
    assert f["thrust_limit_share"] is None and f["offset_step_rms"] == [None]
    # Steps are between adjacent ticks: an inactive tick (a fallback, a stall) counts; the step over an
    # inactive run is not taken as one tick's step (before: 0.5 from tick 1 to tick 4).
    t2, u2 = np.array([0.0, 0.005, 0.01, 0.015, 0.02]), np.array([[0.0], [0.005], [0.2], [0.4], [0.505]])
    g = flight_metrics(t2, np.zeros((5, 1)), np.zeros((5, 1)), active=np.array([True, True, False, False, True]),
                       u=u2, r_nom=np.zeros((5, 1)))
    assert g["max_ref_step"] == pytest.approx(0.2) and g["ticks"] == 3
    nan = flight_metrics(t, y, y, settle=2.0, empty=math.nan)
    assert all(math.isnan(v) for v in nan["rmse"] + nan["mean_error"] + nan["max_abs_error"])
    assert rms([]) is None and math.isnan(rms(np.zeros((0, 2)), math.nan)) and rms([3.0, -3.0]) == 3.0
    with pytest.raises(ValueError, match=r"^y \(3, 2\) and y_des \(3, 1\) must both be \(N, p\) with N = 3 ticks$"):
        flight_metrics(t, y, y[:, :1])
    with pytest.raises(ValueError, match=r"^active has 2 ticks, t has 3$"):
        scored_ticks(t, 0.0, np.ones(2, bool))
    # A NaN trajectory time (before the trajectory started) never counts, whatever the settle time.
    assert scored_ticks(t, -5.0).tolist() == [False, True, True]


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.integers(1, 60), st.floats(-0.3, 0.3), st.integers(0, 40)), min_size=1, max_size=6),
       st.integers(0, 5), st.floats(0.0, 0.6), st.floats(0.0, 2.0))
def test_near_changes_is_the_tick_by_tick_definition(segments, lead, before, after):
    """Holds then ramps of the desired height (hold ticks, ramp height, ramp ticks), NaN before the start: a tick is
    near a change when a tick at most `before` s later or `after` s earlier moved by more than eps from the one
    before it."""
    z, dt = [np.nan] * lead, 0.05
    level = 1.0
    for hold, dz, ramp in segments:
        z += [level] * hold
        z += [level + dz * (k + 1) / ramp for k in range(ramp)]
        level += dz if ramp else 0.0
    z = np.array(z)
    t = np.where(np.isnan(z), np.nan, dt * (np.arange(z.size) - lead))
    got = near_changes(t, z, before, after, eps=5e-4)
    moved = [k for k in range(1, z.size) if abs(z[k] - z[k - 1]) > 5e-4]  # NaN compares False: never moved
    want = [math.isfinite(t[k]) and any(0 <= t[m] - t[k] <= before or 0 <= t[k] - t[m] <= after for m in moved)
            for k in range(z.size)]
    assert got.tolist() == want
