"""The robot-side hopping policy (runtime/hopping.py): its own history equals the simulator's logs,
ground ticks pass the controller's reference, a hole in the samples resets the history."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from ddpc_codegen.values.phases import GROUND
from ddpc_codegen.experiments.policy_hook import PolicyHook
from ddpc_codegen.runtime.hopping import HoppingSteering, HoppingWindow, _History
from ddpc_codegen.runtime.policy import SteeringPolicy
from ddpc_codegen.runtime.steerer import SteerOutcome
from ddpc_codegen.sim import simulate


class _Steerer:
    """A stand-in steerer that never steers (warm-up) and records the windows it is given."""

    t_ini, t_f, m, p = 4, 6, 3, 3

    def __init__(self) -> None:
        self.windows: list[tuple[np.ndarray, np.ndarray]] = []

    def observe(self, u, y) -> None:
        pass

    def reset(self) -> None:
        pass

    def set_window(self, u, y) -> None:
        self.windows.append((np.array(u), np.array(y)))

    def step(self, y_des, u_nom):
        return SteerOutcome(np.asarray(u_nom[0]), False, "warmup")


class _Spy:
    """A completion operator that records the histories the window hands it."""

    depth, noise_level, m, p = 40, 0.0, 3, 3

    def __init__(self) -> None:
        self.calls = 0

    def complete(self, u, y, missing, *, replace_known=False, noise_level=None):
        raise AssertionError("not reached: the spy window below never completes")


class _CheckingWindow(HoppingWindow):
    """Compares the policy's history with the simulator's logs of the same tick."""

    ctx = None
    checked = 0

    def window(self, u_log, y_log, phase_log):
        c = self.ctx
        n = u_log.shape[0]
        np.testing.assert_array_equal(u_log, c.u_log[-n:] if n else c.u_log[:0])
        np.testing.assert_array_equal(y_log, c.y_log[:-1][-n:] if n else c.y_log[:0])
        np.testing.assert_array_equal(phase_log, c.phase_log[:-1][-n:] if n else c.phase_log[:0])
        assert n == min(c.u_log.shape[0], n)  # never more than the simulator has
        _CheckingWindow.checked += 1
        return "history"


def test_history_is_the_simulators_log_and_ground_ticks_pass_r_nom():
    win = _CheckingWindow(_Spy(), t_ini=4)
    hook = PolicyHook(SteeringPolicy(_Steerer(), max_gap_fill=0), "hopping", window=win, g_eff=9.0, dt=0.005)

    def tick(ctx):
        win.ctx = ctx
        return hook(ctx)

    res = simulate("hopping", 2.5, reference_hook=tick, seed=0, noise=True)
    assert _CheckingWindow.checked == res.n - hook.counts["ground"]
    assert hook.counts["ground"] > 50 and np.any(res.phase == GROUND)
    # The capacity (t_ini + depth + 2) wrapped several times: the views stay the newest samples.
    assert hook.hopping.history.capacity == 4 + 40 + 2 < res.n
    np.testing.assert_array_equal(res.u, res.r_nom)


def test_history_buffer_wraps_and_clears():
    h = _History(5, 1, 2)
    for k in range(23):
        h.append(np.array([k]), np.array([k, -k]), k % 4)
        u, y, ph = h.views()
        assert min(k + 1, 5) <= u.shape[0] <= 10 and u[-1, 0] == k and y[-1, 1] == -k and ph[-1] == k % 4
        assert np.array_equal(u[:, 0], np.arange(k + 1 - u.shape[0], k + 1))
    h.clear()
    assert h.views()[0].shape == (0, 1)


def test_a_lost_sample_resets_the_hopping_history():
    from ddpc_codegen.runtime.policy import SteeringPolicy

    st = _Steerer()
    hop = HoppingSteering(SteeringPolicy(st), None, None, 0.005)
    for _ in range(7):
        hop.decide(0, np.zeros(3), np.ones(3), np.zeros((6, 3)), np.zeros(6))
    assert hop.history.views()[0].shape[0] == 7
    hop.lost(0)
    assert hop.history.views()[0].shape[0] == 7
    hop.lost(2)
    assert hop.history.views()[0].shape[0] == 0


def test_relabel_changes_only_the_last_samples_phase():
    from ddpc_codegen.values.phases import DESCENT
    from ddpc_codegen.runtime.policy import SteeringPolicy

    hop = HoppingSteering(SteeringPolicy(_Steerer()), None, None, 0.005)
    for k in range(6):
        hop.decide(DESCENT, np.full(3, k), np.ones(3), np.zeros((6, 3)), np.zeros(6))
    hop.relabel(2, GROUND)
    u, y, ph = hop.history.views()
    assert ph.tolist() == [DESCENT] * 4 + [GROUND] * 2
    assert y[:, 0].tolist() == list(range(6))  # the samples themselves stay
    hop.relabel(50, GROUND)  # more than held: all of them, nothing else
    assert hop.history.views()[2].tolist() == [GROUND] * 6
def test_denoised_clean_window_is_closer_to_the_truth(lti_factory):
    """A clean aerial window projected onto the data's dynamics (denoise=True): measurement noise
    on y shrinks, exact data stay exact."""
    from ddpc_codegen.design.artificial_io import ArtificialIO
    from ddpc_codegen.design.data import IODataset

    n, m, p, L = 4, 1, 2, 20
    sys_ = lti_factory(n, m, p, seed=3)
    rng = np.random.default_rng(0)
    us, ys = [], []
    for _ in range(5):
        u = rng.standard_normal((300, m))
        y, _ = sys_.simulate(u, rng.standard_normal(n))
        us.append(u)
        ys.append(y)
    art = ArtificialIO(IODataset(us, ys, 0.005), L, noise_level=0.02)
    u = rng.standard_normal((L, m))
    y, _ = sys_.simulate(u, rng.standard_normal(n))
    ph = np.zeros(L, dtype=np.int8)
    win = HoppingWindow(art, L, t_d=0, denoise=True)
    ui, yi = win.window(u, y, ph)
    assert np.abs(yi - y).max() < 0.02 * np.abs(y).max()  # exact data: nearly unchanged
    errs = []
    for seed in range(20):
        noisy = y + np.random.default_rng(seed).normal(0, 0.02, y.shape)
        _, yd = win.window(u, noisy, ph)
        errs.append((np.sqrt(np.mean((yd - y) ** 2)), np.sqrt(np.mean((noisy - y) ** 2))))
    e = np.mean(errs, axis=0)
    # u and y are both refit, so the noise keeps its share in the behaviour's m L + n of (m + p) L
    # directions: rms x sqrt(24 / 60) = 0.63 expected.
    assert e[0] < 0.75 * e[1], e
    assert HoppingWindow(art, L, t_d=0).window(u, y, ph) is None  # without denoise: the real window


class _Identity:
    """A completion operator that returns the window it is given (and records its length)."""

    depth, noise_level = 200, 0.0

    def __init__(self) -> None:
        self.lengths: list[int] = []

    def complete(self, u, y, missing, *, replace_known=False, noise_level=None):
        self.lengths.append(u.shape[0])
        return SimpleNamespace(u=u.copy(), y=y.copy(), status="solved")


def test_window_keeps_t_ini_rows_when_ground_and_ascent_are_short():
    """Tini longer than descent context + ground + ascent (t_ini 40 crashed the hopping loop with
    a 36-row window): the fill then starts Tini samples back and the window has Tini rows."""
    from ddpc_codegen.values.phases import ASCENT, DESCENT

    ti, t_d = 40, 10
    ph = np.array([DESCENT] * 60 + [GROUND] * 12 + [ASCENT] * 14, dtype=np.int8)
    k = ph.size
    u = np.arange(k, dtype=float)[:, None] * np.ones((1, 3))
    y = -u
    art = _Identity()
    ui, yi = HoppingWindow(art, ti, t_d=t_d, min_ascent=10).window(u, y, ph)
    assert ui.shape == (ti, 3) and yi.shape == (ti, 3)
    np.testing.assert_array_equal(ui, u[-ti:])  # the identity fill: exactly the last Tini samples
    assert art.lengths == [ti]  # conditioned on 40 - 12 - 14 = 14 >= t_d descent samples
    # A short Tini keeps its t_d descent samples of context: 10 + 12 + 14 = 36 > Tini.
    ui, _ = HoppingWindow(art, 20, t_d=t_d, min_ascent=10).window(u, y, ph)
    assert ui.shape == (20, 3) and art.lengths[-1] == t_d + 12 + 14


class _Residual(_Identity):
    """The identity fill, reporting a chosen residual."""

    def __init__(self, residual: float, depth: int = 200) -> None:
        super().__init__()
        self.residual, self.depth = residual, depth

    def complete(self, u, y, missing, *, replace_known=False, noise_level=None):
        c = super().complete(u, y, missing, replace_known=replace_known, noise_level=noise_level)
        c.residual = self.residual
        return c


def test_refit_spans_the_samples_since_the_liftoff_only_when_the_short_fit_is_poor():
    """refit_residual: a clean window whose fit leaves more than the threshold is fitted again over
    every sample since the last ground one (at most the depth), and the last Tini rows are kept."""
    from ddpc_codegen.values.phases import ASCENT, DESCENT

    ti = 20
    ph = np.array([DESCENT] * 30 + [GROUND] * 10 + [ASCENT] * 50, dtype=np.int8)
    u = np.arange(ph.size, dtype=float)[:, None] * np.ones((1, 3))
    y = -u
    kw = dict(t_d=0, min_ascent=10, noise_level=2e-3, denoise=True)
    for residual, threshold, lengths in ((1.0, 0.5, [ti, 50]), (0.4, 0.5, [ti]), (1.0, 0.0, [ti])):
        art = _Residual(residual)
        win = HoppingWindow(art, ti, refit_residual=threshold, **kw)
        ui, yi = win.window(u, y, ph)
        assert art.lengths == lengths, (residual, threshold)
        np.testing.assert_array_equal(ui, u[-ti:])
        assert win.counts.get("refit", 0) == (len(lengths) == 2)
    art = _Residual(1.0, depth=30)  # the depth bounds the refit
    HoppingWindow(art, ti, refit_residual=0.5, **kw).window(u, y, ph)
    assert art.lengths == [ti, 30]
    art = _Residual(1.0)  # no more aerial samples than Tini: nothing to refit over
    HoppingWindow(art, ti, refit_residual=0.5, **kw).window(u[:60], y[:60], ph[:60])
    assert art.lengths == [ti]

