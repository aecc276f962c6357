"""What the identified loop allows on one path: tracking error against the reference's own activity.

Leading a height step takes reference motion, and every method's thrust change per tick follows its
reference's change per tick through the controller, so the two figures trade. The **front** is that
trade for the loop the data describe, with nothing else in the way: one reference channel chosen with
the whole desired path known in advance (no horizon, no bounds, no noise), for each weight w on its
tick-to-tick change

    u_w = argmin ||T u - e||^2 + w ||D u||^2,

T the lower-triangular Toeplitz matrix of the impulse response of the predictor as the plant (its first
prediction, chained sample by sample: :func:`impulse_response`), e the desired output's deviation,
D the first difference. Convex in u, so the weighted sums trace every Pareto point of the two squared
figures: no reference, causal or not, does better on both. :func:`fly_on_model` flies a steering problem
on the same predictor (the predictor as its own plant), so its point against the front says what the
horizon and the penalties cost, and what only another loop could give.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sl

from ddpc_codegen.design.predictor import Predictor
from ddpc_codegen.design.step_response import step_response
from ddpc_codegen.errors import ConfigError

__all__ = ["FrontPoint", "impulse_response", "reference_front", "front_error_at", "fly_on_model", "follow_on_model",
           "front_report", "operating_point", "point_of", "desired_from_trajectory"]

# weights on the rate term relative to trace(T'T) / trace(D'D) (the two terms' scales): the front's span
RELATIVE_WEIGHTS = tuple(float(w) for w in np.logspace(-2, 8, 31))


@dataclass(frozen=True)
class FrontPoint:
    """One reference for one path: output error RMS (output units), the reference's tick-to-tick change
    RMS over that of the desired path itself (what passthrough sends: 1.0), and the weight w that made it
    (None: a flown point)."""

    error_rms: float
    rate_ratio: float
    weight: float | None = None


def impulse_response(pred: Predictor, input_index: int, output_index: int, n: int) -> np.ndarray:
    """Output ``output_index``'s answer (n,) to a unit pulse on input ``input_index`` at k = 0, from rest, of
    the predictor as the plant (:func:`follow_on_model`: each sample its first prediction, chained sample by
    sample; a multi-step predictor fitted on noisy data is not exactly its own one-step chain, and this is
    the plant the flown points use)."""
    u = np.zeros((n, pred.m))
    u[0, input_index] = 1.0
    return _chain(pred, np.zeros((pred.t_ini, pred.m)), np.zeros((pred.t_ini, pred.p)),
                  lambda k, uh, yh: u[k], n)[1][:, output_index]


def operating_point(pred: Predictor, u0: np.ndarray, y_start: np.ndarray | None = None, span: int = 4000) -> np.ndarray:
    """Outputs (p,) at rest under the constant inputs u0 (m,): ``y_start`` when the predictor holds it there
    (an offset-free, incremental predictor rests at any output), else what the predictor as the plant settles to
    from zero after ``span`` samples of u0."""
    u0 = np.asarray(u0, dtype=float)
    if y_start is not None:
        y_start = np.asarray(y_start, dtype=float)
        held = pred.predict(np.tile(u0, (pred.t_ini, 1)), np.tile(y_start, (pred.t_ini, 1)),
                            np.tile(u0, (pred.t_f, 1)))[0]
        if np.allclose(held, y_start, rtol=0.0, atol=1e-9 * max(1.0, float(np.abs(y_start).max()))):
            return y_start
    return _chain(pred, np.zeros((pred.t_ini, pred.m)), np.zeros((pred.t_ini, pred.p)), lambda k, uh, yh: u0, span)[1][-1]


def point_of(error: np.ndarray, u: np.ndarray, desired_ref: np.ndarray, weight: float | None = None) -> FrontPoint:
    """The figures of a reference u (n,) that left the output ``error`` (n,), against the desired path's
    own reference desired_ref (n,) (passthrough)."""
    base = np.sqrt(np.mean(np.diff(desired_ref) ** 2))
    if not base > 0.0:
        raise ValueError("the desired path does not move: no reference activity to compare against")
    return FrontPoint(float(np.sqrt(np.mean(error ** 2))), float(np.sqrt(np.mean(np.diff(u) ** 2)) / base), weight)


def reference_front(pred: Predictor, desired: np.ndarray, *, input_index: int = 0, output_index: int = 0,
                    relative_weights: tuple[float, ...] = RELATIVE_WEIGHTS,
                    impulse: np.ndarray | None = None) -> list[FrontPoint]:
    """The front on desired outputs ``desired`` (n, p) (the references' nominal values: the first m
    outputs' channels), scored on output ``output_index``, steering input ``input_index``, the other inputs
    held at the path's start. The loop starts at rest at the path's first sample (:func:`operating_point`).
    One point per weight, by rising weight (the rate falls, the error rises). Dense: n up to a few
    thousand samples (n x n matrices). ``impulse``: :func:`impulse_response` (n,) if the caller has it."""
    desired = np.asarray(desired, dtype=float)
    if desired.ndim != 2 or desired.shape[1] != pred.p or desired.shape[0] < 2:
        raise ValueError(f"desired must be (n >= 2, p = {pred.p}); got {desired.shape}")
    n = desired.shape[0]
    u0 = desired[0, : pred.m]
    e = desired[:, output_index] - operating_point(pred, u0, desired[0])[output_index]
    h = impulse_response(pred, input_index, output_index, n) if impulse is None else np.asarray(impulse, dtype=float)
    if h.shape != (n,):
        raise ValueError(f"impulse must be ({n},); got {h.shape}")
    T = sl.toeplitz(h, np.zeros(n))
    # the reference's deviation du from u0, and its n - 1 changes: the two figures of point_of, squared
    D = (np.eye(n, k=1) - np.eye(n))[:-1]
    TT, DD, Te = T.T @ T, D.T @ D, T.T @ e
    scale = np.trace(TT) / np.trace(DD)
    out = []
    for rw in sorted(relative_weights):
        du = sl.solve(TT + rw * scale * DD, Te, assume_a="pos")
        out.append(point_of(T @ du - e, u0[input_index] + du, desired[:, output_index], rw * scale))
    return out


def fly_on_model(problem, desired: np.ndarray, *, solver: str = "fast") -> tuple[np.ndarray, np.ndarray]:
    """Steer ``problem`` (a :class:`~ddpc_codegen.design.problem.SteeringProblem`) on its own predictor as
    the plant along desired outputs (n, p) (the references' nominal values: the same channels), from rest at
    the path's first sample (:func:`operating_point`). Returns the applied references u (n, m) and outputs
    y (n, p); the horizon past the path's end sees its last sample. A tick the solver does not solve is an
    error (no fallback here: this measures the steering)."""
    tf = problem.predictor.t_f
    desired = np.asarray(desired, dtype=float)
    ahead = np.vstack([desired, np.repeat(desired[-1:], tf, axis=0)])

    def steer(k: int, u_hist: np.ndarray, y_hist: np.ndarray) -> np.ndarray:
        r = problem.solve(u_hist, y_hist, ahead[k:k + tf], ahead[k:k + tf, : u_hist.shape[1]], solver=solver)
        if r.status != "solved":
            raise RuntimeError(f"the steering QP was not solved at sample {k}: {r.status}")
        return r.u[0]

    return _chain(problem.predictor, *_at_rest(problem.predictor, desired), steer, desired.shape[0])


def follow_on_model(pred: Predictor, u: np.ndarray, desired: np.ndarray) -> np.ndarray:
    """The predictor's outputs (n, p) (as its own plant, from rest at the path's first sample) for the given
    references u (n, m), e.g. the path itself (passthrough)."""
    u = np.asarray(u, dtype=float)
    desired = np.asarray(desired, dtype=float)
    return _chain(pred, *_at_rest(pred, desired), lambda k, uh, yh: u[k], desired.shape[0])[1]


def _chain(pred: Predictor, u_hist: np.ndarray, y_hist: np.ndarray, reference_at, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(u, y) over n samples of the predictor as the plant from the histories (Tini, m), (Tini, p): each sample's
    reference from reference_at(k, u_hist, y_hist), its output the predictor's first predicted sample with that
    reference held."""
    tf = pred.t_f
    u, y = np.zeros((n, pred.m)), np.zeros((n, pred.p))
    for k in range(n):
        u[k] = reference_at(k, u_hist, y_hist)
        y[k] = pred.predict(u_hist, y_hist, np.repeat(u[k:k + 1], tf, axis=0))[0][0]
        u_hist = np.vstack([u_hist[1:], u[k:k + 1]])
        y_hist = np.vstack([y_hist[1:], y[k:k + 1]])
    return u, y


def _at_rest(pred: Predictor, desired: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The histories at rest at the path's first sample (:func:`operating_point`)."""
    u0 = desired[0, : pred.m]
    return (np.repeat(u0[None, :], pred.t_ini, axis=0),
            np.repeat(operating_point(pred, u0, desired[0])[None, :], pred.t_ini, axis=0))


def front_error_at(front: list[FrontPoint], rate_ratio: float) -> float:
    """The front's error at a reference activity (log error linear in log activity between its points, where
    the front is nearly straight); nan outside it."""
    pts = sorted(front, key=lambda p: p.rate_ratio)
    r = np.log([p.rate_ratio for p in pts])
    if not (pts and r[0] <= np.log(rate_ratio) <= r[-1]):
        return float("nan")
    return float(np.exp(np.interp(np.log(rate_ratio), r, np.log([p.error_rms for p in pts]))))


def front_report(problem, desired: np.ndarray, input_index: int, output_index: int, log=lambda msg: None) -> dict:
    """The front, passthrough's point and the steering's (``problem`` flown on its predictor) on desired
    outputs (n, p), as JSON-ready floats; each point with the front's error at its activity; ``step_gain``: the
    steady-state gain of the predictor as the plant (``chained``) and of its own multi-step prediction
    (``predicted``: what the steering plans with), which agree for a predictor consistent with itself."""
    pred = problem.predictor
    t0 = time.perf_counter()
    h = impulse_response(pred, input_index, output_index, desired.shape[0])
    front = reference_front(pred, desired, input_index=input_index, output_index=output_index, impulse=h)
    log(f"  front: {len(front)} points in {time.perf_counter() - t0:.1f} s; flying the steering on the predictor ...")
    u_pt = np.repeat(desired[:1, : pred.m], desired.shape[0], axis=0)
    u_pt[:, input_index] = desired[:, output_index]
    y_pt = follow_on_model(pred, u_pt, desired)
    u, y = fly_on_model(problem, desired)
    path = desired[:, output_index]
    pts = {"passthrough": point_of(y_pt[:, output_index] - path, u_pt[:, input_index], path),
           "steered": point_of(y[:, output_index] - path, u[:, input_index], path)}
    # the predictor's own consistency: the step gain of its one-step chain (the plant here) and of its
    # multi-step prediction (what the steering plans with); far apart, the model flight is not the steering's loop
    gains = {"chained": float(np.sum(h)),
             "predicted": float(step_response(pred, input_index, desired.shape[0])[-1, output_index])}
    return {"samples": int(desired.shape[0]), "dt": pred.dt, "step_gain": gains,
            "front": [{"error_rms": p.error_rms, "rate_ratio": p.rate_ratio, "weight": p.weight} for p in front],
            **{k: {"error_rms": p.error_rms, "rate_ratio": p.rate_ratio,
                   "front_error_at_this_rate": front_error_at(front, p.rate_ratio)} for k, p in pts.items()}}


def desired_from_trajectory(cfg, trajectory, output: str, duration: float | None) -> tuple[np.ndarray, int]:
    """Desired outputs (n, p) on the config's tick from the channel ``output`` of ``trajectory`` (anything with
    ``time_span()`` and ``sample(t)``, e.g. a loaded trajectory file; the config's output of that name, every
    other output 0) over ``duration`` s from its start (None: its whole span), and that output's index."""
    names = list(cfg.output_names)
    if output not in names:
        raise ConfigError(f"--output {output!r} is not one of the config's outputs {names}")
    t0, t1 = trajectory.time_span()
    end = t1 if duration is None else t0 + duration
    if not np.isfinite(end) or end <= t0:
        raise ConfigError(f"the trajectory's time span is {t0:g} .. {t1:g} s: give --duration (s, > 0)")
    t = np.arange(t0, end, cfg.dt)
    s = trajectory.sample(t)
    if output not in s:
        raise ConfigError(f"the trajectory has no channel {output!r} (it has {sorted(s)})")
    desired = np.zeros((t.size, cfg.p))
    desired[:, names.index(output)] = s[output]
    return desired, names.index(output)
