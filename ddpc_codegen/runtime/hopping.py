"""Hopping steering on the robot side: the ground-phase window and the per-tick hopping policy.

One implementation for every loop (the simulator's reference hook, the MAVLink bridge):

* :class:`HoppingWindow` -- the Tini window of u_ini / y_ini whose ground samples are replaced by
  artificial IO (the completion operator is the interpreted
  :class:`~ddpc_codegen.design.artificial_io.ArtificialIO` or the one compiled into a generated
  hopping artifact: anything with ``depth``, ``noise_level`` and ``complete``).
* :class:`HoppingSteering` -- one tick of hopping: no steering on the ground (the reference the
  controller sends is applied and recorded, so the spring keeps its natural dynamics); in the air a
  window with its ground part filled, and the desired arc continued ballistically past the
  predicted touchdown (the aerial predictor knows nothing of the ground, so the horizon is scored
  against the arc the aerial dynamics should fly; the leg angles are held as the controller does).
  It keeps its own history of (applied u, measured y, phase), so a loop only hands it this tick.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from ddpc_codegen.values.phases import GROUND, ground_runs
from ddpc_codegen.runtime.policy import SteeringPolicy
from ddpc_codegen.runtime.steerer import SteerOutcome

__all__ = ["Completer", "HoppingWindow", "HoppingSteering"]


class Completer(Protocol):
    """What the online window needs of an artificial-IO operator."""

    depth: int
    noise_level: float

    def complete(self, u: np.ndarray, y: np.ndarray, missing: np.ndarray, *, replace_known: bool = False,
                 noise_level: float | None = None): ...


@dataclass
class HoppingWindow:
    """Online artificial IO: the Tini window of u_ini / y_ini with its ground part filled.

    Args:
        art: completion operator (aerial dynamics).
        t_ini: window length.
        t_d: real descent samples before the touchdown that the fill is conditioned on.
        min_ascent: fewest ascent samples after the liftoff before a window is produced
            (right after the liftoff nothing is known yet about the aerial state).
        noise_level: sigma of the online completion [m / rad] (None: the operator's); online
            windows are noisy measurements, so a sigma near the sensor noise keeps the fill from
            amplifying it.
        smooth: return the fitted window (known samples too) when sigma > 0 (see
            :meth:`ArtificialIO.complete`, ``replace_known``).
        denoise: also replace a window without ground samples by its fit (sigma > 0): the nearest
            trajectory of the data's dynamics. With sensor noise the steering's gain on the noisy
            window otherwise jitters z_ref from tick to tick, which through the tilted thrust moves
            the hop's horizontal velocity.
        refit_residual: when a denoised window's fit leaves a residual above this [m / rad], fit
            again over every aerial sample since the last ground phase (up to the operator's depth)
            and keep the last ``t_ini`` samples (0: never). Why: a 20-sample fit of a noisy window
            still passes much of the noise on; a longer fit averages it, but on noise-free windows it
            also fits the aerial loop's nonlinearity (a larger nominal apex error), so it is used
            only when the short fit says the window is noisy (the steering config's
            ``refit_residual`` lies between the residuals of noise-free and noisy windows).
    """

    art: Completer
    t_ini: int
    t_d: int = 10
    min_ascent: int = 1
    noise_level: float | None = None
    smooth: bool = True
    denoise: bool = False
    refit_residual: float = 0.0
    counts: dict = field(default_factory=lambda: {"filled": 0, "clean": 0, "unavailable": 0})

    def window(self, u_log: np.ndarray, y_log: np.ndarray, phase_log: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray] | None | str:
        """The window over the last ``t_ini`` samples of the logs.

        Args:
            u_log (k, m), y_log (k, p), phase_log (k,): history up to (not including) this tick.
        Returns:
            (u_ini (Tini, m), y_ini (Tini, p)) with ground samples replaced; ``None`` when the window
            has no ground sample (use the real one); a reason string when no window can be formed
            ("history": fewer than Tini samples, "early_ascent": fewer than ``min_ascent`` ascent
            samples, "no_context": the descent context or the depth is missing, "fill_<status>": the
            completion did not verify its bounds).
        """
        k = u_log.shape[0]
        Ti = self.t_ini
        if k < Ti:
            return "history"
        ph = phase_log[:k]
        sig = self.art.noise_level if self.noise_level is None else self.noise_level
        if not np.any(ph[k - Ti :] == GROUND):
            self.counts["clean"] += 1
            if self.denoise and sig > 0:
                return self._denoised(u_log, y_log, ph, sig)
            return None
        runs = [r for r in ground_runs(ph[max(0, k - Ti - self.art.depth) :])]
        off = max(0, k - Ti - self.art.depth)
        g0, g1 = runs[-1][0] + off, runs[-1][1] + off
        if g1 >= k or k - g1 < self.min_ascent:
            self.counts["unavailable"] += 1
            return "early_ascent"
        # The fill is conditioned on t_d descent samples, and the window it returns must still hold
        # Tini samples when the ground phase and the ascent are short against Tini.
        a = min(g0 - self.t_d, k - Ti)
        if a < 0 or np.any(ph[a:g0] == GROUND) or k - a > self.art.depth:
            self.counts["unavailable"] += 1
            return "no_context"
        missing = np.zeros(k - a, dtype=bool)
        missing[g0 - a : g1 - a] = True
        c = self.art.complete(u_log[a:k], y_log[a:k], missing, replace_known=self.smooth and sig > 0,
                              noise_level=sig)
        self.counts["filled"] += 1
        return self._checked(c)

    def _denoised(self, u_log: np.ndarray, y_log: np.ndarray, ph: np.ndarray, sig: float
                  ) -> tuple[np.ndarray, np.ndarray] | str:
        """A window without ground samples replaced by its fit (refitted longer when noisy)."""
        k, Ti = u_log.shape[0], self.t_ini
        c = self.art.complete(u_log[k - Ti :], y_log[k - Ti :], np.zeros(Ti, dtype=bool), replace_known=True,
                              noise_level=sig)
        if self.refit_residual > 0 and c.status == "solved" and c.residual > self.refit_residual:
            lo = max(0, k - self.art.depth)
            ground = np.flatnonzero(ph[lo:k] == GROUND)
            a = lo + int(ground[-1]) + 1 if ground.size else lo
            if k - a > Ti:
                self.counts["refit"] = self.counts.get("refit", 0) + 1
                c = self.art.complete(u_log[a:k], y_log[a:k], np.zeros(k - a, dtype=bool), replace_known=True,
                                      noise_level=sig)
        return self._checked(c)

    def _checked(self, c) -> tuple[np.ndarray, np.ndarray] | str:
        """The last ``t_ini`` samples of the completed window, or "fill_<status>" when the fill is not a
        verified solution (a clipped fill violates the data's dynamics: the predictor must not see it)."""
        if c.status != "solved":
            self.counts["unverified"] = self.counts.get("unverified", 0) + 1
            return f"fill_{c.status}"
        return c.u[-self.t_ini :], c.y[-self.t_ini :]


class _History:
    """The last ``capacity`` (u, y, phase) samples as contiguous arrays (a sliding buffer: amortised
    O(1) per tick, views without copies)."""

    def __init__(self, capacity: int, m: int, p: int) -> None:
        self.capacity = int(capacity)
        self._u = np.zeros((2 * self.capacity, m))
        self._y = np.zeros((2 * self.capacity, p))
        self._ph = np.zeros(2 * self.capacity, dtype=np.int8)
        self._n = 0

    def clear(self) -> None:
        self._n = 0

    def append(self, u: np.ndarray, y: np.ndarray, phase: int) -> None:
        if self._n == self._u.shape[0]:
            keep = self.capacity
            for a in (self._u, self._y, self._ph):
                a[:keep] = a[self._n - keep : self._n]
            self._n = keep
        self._u[self._n], self._y[self._n], self._ph[self._n] = u, y, phase
        self._n += 1

    def relabel(self, n: int, phase: int) -> None:
        """The phase of the last ``n`` samples (at most those held)."""
        n = min(int(n), self._n)
        if n > 0:
            self._ph[self._n - n : self._n] = phase

    def views(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        n = self._n
        return self._u[:n], self._y[:n], self._ph[:n]


class HoppingSteering:
    """One tick of hopping reference steering (see the module docstring).

    Args:
        policy: the shared flying/hopping policy (steerer, fade-in, fallbacks).
        window: ground-phase completion of the past window (None: the real window is used).
        g_eff: effective gravity of the ballistic arc [m/s^2] (None: y_des is used as given).
        dt: tick period [s].

    Per tick call :meth:`decide`; it returns the reference to apply (m,) and the steerer's outcome
    (None on ground ticks and ticks without a window). Counts (``counts``): ticks, ground,
    no_window:<reason>, filled.
    """

    def __init__(self, policy: SteeringPolicy, window: HoppingWindow | None, g_eff: float | None,
                 dt: float) -> None:
        self.policy = policy
        self.window = window
        self.g_eff = g_eff
        self.dt = float(dt)
        st = policy.steerer
        depth = window.art.depth if window is not None else 0
        self.history = _History(st.t_ini + depth + 2, st.m, st.p)
        self.counts: dict[str, int] = {}
        self._v_arc: float | None = None

    def _count(self, key: str) -> None:
        self.counts[key] = self.counts.get(key, 0) + 1

    def reset(self) -> None:
        """Forget every past sample (re-engagement, a telemetry hole): windows need new history."""
        self.policy.reset()
        self.history.clear()
        self._v_arc = None

    def lost(self, n_missing: int) -> None:
        """``n_missing`` ticks had no sample. A hopping window cannot be bridged across a hole (the
        ground phase may sit in it), so any loss resets the history."""
        if n_missing > 0:
            self.reset()

    def relabel(self, n: int, phase: int) -> None:
        """The last ``n`` recorded ticks were in fact in ``phase`` (a touchdown estimated from
        telemetry is confirmed a sample or two after the foot went down; see
        :attr:`ddpc_codegen.robot.phases.PhaseEstimator.backdate`): later windows complete them."""
        self.history.relabel(n, phase)

    def decide(self, phase: int, y: np.ndarray, r_nom: np.ndarray, y_des: np.ndarray,
               phases_ahead: np.ndarray) -> tuple[np.ndarray, SteerOutcome | None]:
        """This tick's reference.

        Args:
            phase: this tick's phase label (values.phases). y (p,): measured outputs. r_nom (m,):
            the controller's reference. y_des (Tf, p): desired outputs ahead. phases_ahead (Tf,):
            the predicted phase labels over the horizon (the nominal hop cycle).
        Returns:
            (u (m,), outcome or None); (u, y, phase) is recorded for the next windows.
        """
        u, out = self._decide(int(phase), np.asarray(y, float), np.asarray(r_nom, float), y_des, phases_ahead)
        self.history.append(u, y, phase)
        return u, out

    def _decide(self, phase, y, r_nom, y_des, phases_ahead):
        pol = self.policy
        self._count("ticks")
        if phase == GROUND:
            self._count("ground")
            pol.observe(r_nom, y)
            return r_nom, None
        if self.window is not None:
            u_log, y_log, ph_log = self.history.views()
            w = self.window.window(u_log, y_log, ph_log)
            if isinstance(w, str):
                self._count(f"no_window:{w}")
                pol.observe(r_nom, y)
                return r_nom, None
            if w is not None:
                pol.steerer.set_window(*w)
                self._count("filled")
            else:
                # A clean aerial window: the real samples (a fitted window of an earlier tick may
                # still sit in the steerer's ring buffer otherwise).
                Ti = pol.steerer.t_ini
                pol.steerer.set_window(u_log[-Ti:], y_log[-Ti:])
        out = pol.decide(y, r_nom, self.arc_horizon(y_des, phases_ahead))
        return out.u, out

    def arc_horizon(self, y_des: np.ndarray, phases_ahead: np.ndarray) -> np.ndarray:
        """(Tf, p) desired outputs with z continued on the current ballistic arc after touchdown."""
        yd = np.array(y_des, dtype=float)
        n = yd.shape[0]
        ph = np.asarray(phases_ahead)
        g = self.g_eff
        air = np.flatnonzero(ph != GROUND)
        # The aerial samples before the first predicted ground sample define the arc.
        first_ground = int(np.argmax(ph == GROUND)) if np.any(ph == GROUND) else n
        if g is None or first_ground >= n:
            if first_ground >= n and len(air) >= 2:
                self._v_arc = (yd[1, 0] - yd[0, 0]) / self.dt + 0.5 * (g or 0.0) * self.dt
            return yd
        tau = self.dt * np.arange(n)
        z0 = yd[0, 0]
        if first_ground >= 2:
            v = float(np.mean((yd[1:first_ground, 0] - z0 + 0.5 * g * tau[1:first_ground] ** 2) / tau[1:first_ground]))
        elif self._v_arc is not None:
            v = self._v_arc - g * self.dt
        else:
            v = 0.0
        self._v_arc = v
        yd[first_ground:, 0] = z0 + v * tau[first_ground:] - 0.5 * g * tau[first_ground:] ** 2
        # Leg angles: held at the current aerial command (what the controller does in the air).
        yd[first_ground:, 1:] = yd[0, 1:]
        return yd
