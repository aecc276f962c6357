"""ILC between flights: a tick log -> its error on the trajectory tick grid -> the next table,
against known answers on a synthetic tick log (no flight)."""

from __future__ import annotations

import numpy as np
import pytest

from ddpc_codegen.design.baselines import error_on_grid
from ddpc_codegen.values.prefilter import PrefilterModel
from ddpc_codegen.runtime.baselines import FeedforwardPolicy
from ddpc_codegen.testbed.ilc import next_table, table_rows, ticklog_error
from firmware_bridge.ticklog import TickRecorder

DT = 0.005
F = 0.2  # Hz: the ellipse's frequency, far below the 1 Hz Q-filter


def _log(tmp_path, err, *, flown: float = 10.0, takeoff: int = 300, missed=(1234, 1235), stale=(1000, 1010),
         name: str = "flight"):
    """A tick log as the bridge writes one: ``takeoff`` ticks of the take-off ramp (active False,
    t_traj 0, a large error that must not be learned), then the trajectory for ``flown`` s with
    y - y_des = err(t_traj) (z) and err / 10 (pitch), two missed grid ticks, and a stale stretch
    (fresh False, a wrong error)."""
    rec = TickRecorder(2, 2)
    n = int(round(flown / DT)) + 1
    rows = [(0.0, False, True, 5.0)] * takeoff
    for j in range(n):
        if j in missed:
            continue
        t = j * DT
        st = stale[0] <= j < stale[1]
        rows.append((t, not st, not st, -7.0 if st else float(err(t))))
    for t, active, fresh, e in rows:
        i = rec.new_row()
        a = rec.arrays
        a["t_wall"][i] = a["t_vehicle"][i] = t
        a["t_traj"][i] = t
        a["y_des"][i] = (1.0 + 0.1 * np.sin(2 * np.pi * F * t), 0.0)
        a["y"][i] = a["y_des"][i] + (e, e / 10)
        a["u"][i] = a["r_nom"][i] = a["y_des"][i]
        a["active"][i] = a["valid"][i] = a["event"][i] = active
        a["fresh"][i] = fresh
        a["armed"][i] = a["offboard"][i] = True
    log = rec.to_log(dt=DT, input_names=("z_ref", "pitch_ref"), output_names=("z", "pitch"))
    return log, log.save(tmp_path / f"{name}.npz")


def test_error_on_grid_averages_interpolates_and_ignores_off_grid_samples():
    t = np.array([0.0, 0.005, 0.005, 0.02, np.nan, 0.5, -0.005])
    e = np.array([[1.0], [2.0], [4.0], [9.0], [100.0], [100.0], [100.0]])
    err, seen = error_on_grid(t, e, 6, 0.005)
    # row 1: mean of 2 and 4; rows 2, 3 between 3 (row 1) and 9 (row 4); row 5 never reached (held)
    np.testing.assert_allclose(err[:, 0], [1.0, 3.0, 5.0, 7.0, 9.0, 9.0])
    assert seen.tolist() == [True, True, True, True, True, False]


def test_ticklog_error_is_the_flight_error_on_the_trajectory_grid(tmp_path):
    log, _ = _log(tmp_path, lambda t: 0.05 + 0.02 * np.sin(2 * np.pi * F * t), flown=8.0)
    n = table_rows(10.0, DT)
    err, seen = ticklog_error(log, n)
    j = np.arange(n)
    want = 0.05 + 0.02 * np.sin(2 * np.pi * F * j * DT)
    flown = j <= round(8.0 / DT)
    assert seen.tolist() == flown.tolist()  # the take-off ticks (t_traj 0, not active) add nothing to row 0
    # exact on the grid; the stale stretch (10 ticks) is interpolated linearly across 11 ticks: error
    # at most (11 DT)^2 / 8 max|e''| = 1.2e-5 m with e'' = 0.02 (2 pi F)^2 (the missed ticks: less)
    bound = (11 * DT) ** 2 / 8 * 0.02 * (2 * np.pi * F) ** 2
    np.testing.assert_allclose(err[flown, 0], want[flown], atol=bound)
    np.testing.assert_allclose(err[flown, 1], want[flown] / 10, atol=bound / 10)
    filled = np.zeros(n, bool)
    filled[[*range(1000, 1010), 1234, 1235]] = True
    assert np.abs(err[filled, 0] - want[filled]).max() > 1e-8  # (the interpolated ticks are not the truth)
    np.testing.assert_allclose(err[flown & ~filled, 0], want[flown & ~filled], rtol=0, atol=1e-12)
    np.testing.assert_allclose(err[~flown, 0], err[flown][-1, 0])  # after the flight: its last error held


def test_next_table_learns_the_inverse_of_a_constant_and_a_slow_periodic_error(tmp_path):
    """Known answers of the law delta_next = Q(delta - e[k + d] / g): a constant error c gives
    delta = -c / g exactly (the Q-filter passes DC); a 0.2 Hz error, d ticks ahead and / g, to
    within the Q-filter's attenuation there (|H|^2 = 1 / (1 + (0.2 / 1)^4) ~ 0.998)."""
    g, d = (0.8, 1.0), (40, 10)
    pf = PrefilterModel(g, (0.0, 0.0), d, DT, ("z_ref", "pitch_ref"))
    _, path = _log(tmp_path, lambda t: 0.06 + 0.0 * t)
    first = next_table(path, None, pf, 10.0)
    assert first.clock == "trajectory" and first.dt == DT and first.delta.shape == (table_rows(10.0, DT), 2)
    np.testing.assert_allclose(first.delta, np.tile([-0.06 / 0.8, -0.006 / 1.0], (first.delta.shape[0], 1)),
                               atol=1e-9)
    # A flight shorter than the table: the rows it did not reach keep the previous table (here 0).
    _, short = _log(tmp_path, lambda t: 0.06 + 0.0 * t, flown=8.0, name="short")
    part = next_table(short, None, pf, 10.0).delta
    np.testing.assert_allclose(part[:1601, 0], -0.075, atol=1e-9)
    assert np.all(part[1601:] == 0.0)
    # The second iteration starts from the first table: the corrections add up.
    second = next_table(path, first, pf, 10.0)
    np.testing.assert_allclose(second.delta[:, 0], -2 * 0.06 / 0.8, atol=1e-9)

    _, path = _log(tmp_path, lambda t: 0.03 * np.sin(2 * np.pi * F * t))
    tab = next_table(path, FeedforwardPolicy(np.zeros((2001, 2)), DT), pf, 10.0).delta
    k = np.arange(200, 2001 - 200)  # away from the filter's edges
    want = -0.03 * np.sin(2 * np.pi * F * (k + d[0]) * DT) / g[0]
    np.testing.assert_allclose(tab[k, 0], want, atol=0.003 * 0.03 / g[0] + 1e-5)
    np.testing.assert_allclose(tab[k, 1], -0.003 * np.sin(2 * np.pi * F * (k + d[1]) * DT), atol=2e-5)


def test_next_table_refuses_a_table_of_another_flight_and_a_log_without_trajectory(tmp_path):
    pf = PrefilterModel((1.0, 1.0), (0.0, 0.0), (0, 0), DT)
    _, path = _log(tmp_path, lambda t: 0.0 * t)
    with pytest.raises(ValueError, match=r"the table has shape \(10, 2\), the flight of 10 s at dt 0.005 s needs "
                                         r"\(2001, 2\)"):
        next_table(path, FeedforwardPolicy(np.zeros((10, 2)), DT), pf, 10.0)
    _, path = _log(tmp_path, lambda t: 0.0 * t, flown=0.0, takeoff=50, missed=(), stale=(0, 1))
    with pytest.raises(ValueError, match="no engaged tick on the trajectory to learn from"):
        next_table(path, None, pf, 10.0)
