"""``--preview-file``: the app's path given ahead as a trajectory file, matched to its stream
(:class:`firmware_bridge.proxy.file_preview.FilePreview`). Whatever the moment and height the app starts the path
at, its rate, its clock's jitter and drift, the match locks and then previews the file's future; holds keep the
lock; an app that leaves the path, or a file that is not the app's path, falls back to the local preview and says
so; the command line refuses the option with a delay or a bad file."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ddpc_codegen.robot.trajectory import SampledTrajectory
from ddpc_codegen.robot.trajectory_files import save_trajectory_csv
from ddpc_codegen.testbed import proxy_app
from ddpc_codegen.testbed.proxy_app import PATHS
from firmware_bridge.proxy.cli import main
from firmware_bridge.proxy.file_preview import FilePreview
from firmware_bridge.proxy.record import ProxyRecord
from firmware_bridge.proxy.steering import ProxySteering
from firmware_bridge.proxy.vehicle_view import VehicleView
from ddpc_codegen.runtime.loader import load_solver
from firmware_bridge.proxy.preview import DelayedPreview
from lti_loop import DT, fly
from test_proxy_steering import _hook, _rmse, solver  # noqa: F401 (solver: the fixture of the known loop's solver)
from test_proxy_steering import _path as _steering_path

AHEAD = np.arange(0.0, 2.0, 0.02)  # the steering's horizon (100 ticks of 20 ms)
DURATION = 30.0  # s: the file's path


class _Setpoint:
    """What a preview reads of a LOCAL_NED setpoint: the height (z down) and no feed-forward fields."""

    type_mask, vz, afz = 0xFFFF, 0.0, 0.0

    def __init__(self, height: float) -> None:
        self.z = -height


def _wander(t: np.ndarray) -> np.ndarray:
    """The demo's non-repeating path's height (z up) [m], held before 0 and after :data:`DURATION`."""
    return PATHS["wander"](np.clip(t, 0.0, DURATION))[2]


def _trajectory(z_of, duration: float = DURATION, step: float = 0.05) -> SampledTrajectory:
    t = np.arange(0.0, duration + 0.5 * step, step)
    return SampledTrajectory(t=tuple(t), x=tuple(0.0 * t), z=tuple(z_of(t)), source="test")


def _stream(preview, z_of, *, t0: float = 1000.0, c: float = 2.5, rate: float = 50.0, jitter: float = 0.0,
            drift: float = 0.0, lead: float = 2.0, end: float = 25.0, seed: int = 0, check=None) -> None:
    """Stream the app's heights ``z_of(s) + c`` at ``rate`` [Hz] from file time ``-lead`` to ``end`` [s] into
    ``preview``, each arriving at ``t0 + s (1 + drift) + U(-jitter, jitter)``; ``check(s, h)`` after each push, the match's
    work after it (as the proxy's tick: push, steer, send, catch up)."""
    rng = np.random.default_rng(seed)
    for s in np.arange(-lead, end, 1.0 / rate):
        h = float(z_of(np.array([s]))[0]) + c
        preview.push(t0 + s * (1.0 + drift) + rng.uniform(-jitter, jitter), _Setpoint(h))
        if check is not None:
            check(s, h)
        preview.catch_up()  # after the tick's send, as the proxy does


def _future_error(preview: FilePreview, z_of, s: float, c: float) -> float:
    """The largest miss of the preview's desired heights against the file's future from ``s`` (+ ``c``) [m]."""
    return float(np.max(np.abs(preview.desired(AHEAD)[:, 0] - z_of(s + AHEAD) - c)))


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(t0=st.floats(0.0, 2e9), c=st.floats(-20.0, 20.0), rate=st.sampled_from([20.0, 25.0, 50.0, 100.0]),
       jitter=st.floats(0.0, 0.003), drift=st.floats(-0.002, 0.002), lead=st.floats(0.5, 8.0))
def test_the_match_locks_and_then_previews_the_files_future(t0, c, rate, jitter, drift, lead):
    pv, events = FilePreview(_trajectory(_wander)), []
    pv.bind(events.append)
    errors = []

    def check(s, h):
        if s >= 4.0:  # (a window of the path is in: locked from here on)
            assert pv.locked, (s, pv.summary())
            errors.append(_future_error(pv, _wander, s, c))

    _stream(pv, _wander, t0=t0, c=c, rate=rate, jitter=jitter, drift=drift, lead=lead, check=check)
    # a miss of the clock by the jitter and drift moves the height by the path's speed (up to ~1.3 m/s) times it
    assert max(errors) < 0.008, max(errors)
    out = pv.summary()
    assert out["locks"] == 1 and out["losses"] == 0 and out["offset_m"] == pytest.approx(c, abs=0.003)
    assert out["matched"] + out["fallback"] == len(np.arange(-lead, 25.0, 1.0 / rate))
    assert len(events) == 1 and "matches the trajectory file" in events[0]


@pytest.mark.parametrize("name", sorted(PATHS))
def test_each_demo_path_locks_and_holds_keep_the_lock(name):
    """The demo's paths, steps with 2.5 s holds between its ramps among them: once locked, the clock carries the
    file time through each hold and the preview sees the next ramp coming at its time."""
    z_of = lambda t: PATHS[name](np.clip(t, 0.0, DURATION))[2]  # noqa: E731
    pv = FilePreview(_trajectory(z_of))
    errors = []

    def check(s, h):
        if pv.locked:
            errors.append(_future_error(pv, z_of, s, 1.7))

    _stream(pv, z_of, c=1.7, jitter=0.002, drift=0.001, lead=6.0, end=DURATION + 1.0, check=check)
    out = pv.summary()
    assert out["locks"] == 1 and out["losses"] == 0, out
    assert max(errors) < 0.008 and len(errors) > 0.8 * DURATION / DT


def test_an_app_that_leaves_the_files_path_falls_back_and_says_so():
    """12 s on the file's path, then the app holds its height for 6 s: the lock is lost at once, every tick from
    there previews the local guess (counted as fallback), an event says why; back on the path, it locks again."""
    def z_app(t):
        return np.where((t > 12.0) & (t < 18.0), _wander(np.array([12.0]))[0], _wander(t))

    pv, events = FilePreview(_trajectory(_wander)), []
    pv.bind(events.append)
    off, on_file = [], []

    def check(s, h):
        if 12.15 < s < 18.0:
            off.append(pv.locked)
            assert np.array_equal(pv.desired(AHEAD), pv.local.desired(AHEAD))
        if s > 23.6:  # (the lock's window of 5 s back on the path, and its scan)
            on_file.append(pv.locked)

    _stream(pv, z_app, c=0.0, end=DURATION, check=check)
    out = pv.summary()
    assert not any(off) and all(on_file)
    assert out["losses"] == 1 and out["locks"] == 2 and out["fallback"] > 5.8 / DT
    assert "left the trajectory file" in events[1] and "mm off" in events[1]


def _never_matched(z_app) -> None:
    """Stream ``z_app`` against the wander file: no tick matched, the local preview's guess on every one."""
    pv = FilePreview(_trajectory(_wander))

    def check(s, h):
        assert np.array_equal(pv.desired(AHEAD), pv.local.desired(AHEAD))

    _stream(pv, z_app, c=1.0, jitter=0.002, rate=25.0, end=40.0, check=check)
    assert pv.summary()["matched"] == 0 and pv.summary()["locks"] == 0


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(per=st.lists(st.floats(2.0, 9.0), min_size=3, max_size=3), amp=st.lists(st.floats(0.0, 0.6), min_size=3,
       max_size=3), phase=st.lists(st.floats(0.0, 2 * np.pi), min_size=3, max_size=3))
def test_a_file_that_is_not_the_apps_path_never_steers(per, amp, phase):
    """The app flies another smooth path (three sines, any size down to a ripple): never matched."""
    _never_matched(lambda t: sum(a * np.sin(2 * np.pi * t / p + f) for a, p, f in zip(amp, per, phase)))


@pytest.mark.parametrize("name", ["helix", "steps"])
def test_another_demo_paths_file_never_steers(name):
    _never_matched(lambda t: PATHS[name](np.clip(t, 0.0, DURATION))[2])


def test_a_frame_change_drops_the_lock():
    pv, events = FilePreview(_trajectory(_wander)), []
    pv.bind(events.append)
    _stream(pv, _wander, end=8.0)
    assert pv.locked
    pv.reset()
    assert not pv.locked and "changed frame" in events[-1]


def test_the_steering_reports_the_match_and_previews_from_the_csv_file(tmp_path):
    """Through :class:`ProxySteering` (pass-through) with a CSV written as the demo's app writes its path: the
    summary's ``preview`` counts the ticks matched and fallen back, the steering's events hold the lock, and the
    desired heights ahead are the file's."""
    path = save_trajectory_csv(tmp_path / "wander.csv", proxy_app.PathTrajectory("wander"), DURATION, dt=0.02,
                               columns=("t", "x", "y", "z"))
    hook = ProxySteering(VehicleView(), record=ProxyRecord(), preview=FilePreview.from_file(path))
    n = int(20.0 / DT)
    fly(hook, 2.0 + _wander(np.arange(n) * DT - 3.0))
    out = hook.summary()["preview"]
    assert out["kind"] == "file" and out["file"] == str(path) and out["matched"] + out["fallback"] == n
    assert out["matched"] > 0.75 * n and out["offset_m"] == pytest.approx(2.0, abs=1e-3)
    assert any("matches the trajectory file" in e[1] for e in hook.events.events)
    s = (n - 1) * DT - 3.0
    assert np.allclose(hook._desired(AHEAD)[:, 0], 2.0 + _wander(s + AHEAD), atol=3e-3)


def test_the_demo_apps_written_path_previews_its_flight(tmp_path, capsys):
    """``proxy_app --write-path`` (what ``make proxy-demo`` hands ``--preview-file``): the app's steps flight, its
    lead-in from another height included, locks on the file once a ramp is in and previews the next ramps."""
    f = tmp_path / "steps.path.csv"
    assert proxy_app.main(["--write-path", str(f), "--path", "steps", "--duration", "30"]) == 0
    pv = FilePreview.from_file(f)

    def z_app(s):  # the app's lead-in: 6 s from 2.2 m to its start at 2.5 m (in 3.6 s), then the path
        u = np.clip((s + 6.0) / 3.6, 0.0, 1.0)
        return np.where(s < 0, 2.2 + 0.3 * (0.5 - 0.5 * np.cos(np.pi * u)), 2.5 + PATHS["steps"](s)[2])

    errors = []
    _stream(pv, lambda s: z_app(np.clip(s, None, 30.0)), c=0.0, lead=6.0, end=31.0, jitter=0.002,
            check=lambda s, h: errors.append(_future_error(pv, lambda t: PATHS["steps"](np.clip(t, 0, 30))[2], s, 2.5))
            if pv.locked else None)
    assert pv.summary()["locks"] == 1 and pv.summary()["losses"] == 0 and max(errors) < 0.008
    assert len(errors) * DT > 24.0  # (the path's first 4 s hold and its first ramp before the lock)


def _refused(capsys, *argv: str) -> str:
    assert main(["--app", "udpin:127.0.0.1:0", "--vehicle", "udpout:127.0.0.1:9", *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("ddpc-proxy: "), err
    return err


def test_the_command_line_refuses_a_file_with_a_delay_or_a_bad_file(capsys, tmp_path):
    good = save_trajectory_csv(tmp_path / "p.csv", proxy_app.PathTrajectory("helix"), 5.0)
    assert "--preview-file and --preview-delay 0.5 are two previews: give one" in _refused(
        capsys, "--preview-file", str(good), "--preview-delay", "0.5")
    assert str(tmp_path / "none.csv") in _refused(capsys, "--preview-file", str(tmp_path / "none.csv"))
    bad = tmp_path / "bad.csv"
    bad.write_text("t,x,z\n0,0,0\n0,1,1\n")
    assert "not after" in _refused(capsys, "--preview-file", str(bad))


@pytest.mark.compiler
def test_the_file_previews_an_absolute_steering_as_well_as_a_delay_without_it(solver):  # noqa: F811 (the fixture)
    """The known loop steered in absolute coordinates on a fast path, where the local guess of the future is wrong:
    with the path given as a file (its heights 2 m below the app's, its start 3 s after the stream's) the steering
    follows it closer than with the local preview, and about as close as with a 1.5 s delay, without the delay."""
    n, start = 1500, 3.0
    fast = _steering_path(n, seed=2)
    t = np.arange(n) * DT
    shifted = lambda s: np.interp(s + start, t, fast) - 2.0  # noqa: E731 (the file: file time 0 = stream time 3 s)
    local, filed = (_hook(solver=load_solver(solver), preview=p) for p in (None, FilePreview(_trajectory(
        shifted, duration=(n - 1) * DT - start, step=DT))))
    e = {k: _rmse(fly(h, fast)["h"], fast, skip=400) for k, h in (("local", local), ("file", filed))}
    delay = 1.5
    late, lag = _hook(solver=load_solver(solver), preview=DelayedPreview(delay)), int(round(delay / DT))
    e["delay"] = _rmse(fly(late, fast)["h"], np.concatenate((np.full(lag, fast[0]), fast[:-lag])), skip=400 + lag)
    out = filed.summary()["preview"]
    print(json.dumps({**{k: v * 1e3 for k, v in e.items()}, "matched": out["matched"]}))
    assert out["locks"] == 1 and out["losses"] == 0 and out["matched"] > n - 450
    assert e["file"] < 0.7 * e["local"] and e["file"] < 1.3 * e["delay"]
