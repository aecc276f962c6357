"""What the identified closed loop says about the horizon it needs: the predictor's step response, its
dead time, how much of it the horizon sees, and its 90 % settling time.

A reference steering acts on an output only through the part of the loop's response that appears within
its horizon Tf * dt. A loop whose response to a reference step has not begun when the horizon ends (a dead
time of Tf or more) cannot be steered: no reference inside the horizon moves the predicted output. A loop
that starts answering within the horizon can be steered even when it settles much later (the steering
then works through that first part of its response); what a horizon shorter than the settling time costs
is preview: a change of the desired path is seen, and led, at most Tf * dt ahead. The response is
computed from the predictor alone (from rest, a unit step on one input, the predictor chained over its own
predictions), so it is the loop the data describe, beyond Tf if need be.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ddpc_codegen.design.predictor import Predictor

__all__ = ["step_response", "settling_index", "dead_index", "OutputSettling", "settling_summary", "settling_report"]

SETTLED = 0.1  # "settled": within 10 % of the final change for good (the 90 % settling time)
# "answering": beyond 1 % of the response's largest change, above what a fit on noisy data leaves on a
# step response before the loop answers
ANSWERED = 0.01


def step_response(pred: Predictor, input_index: int, n: int) -> np.ndarray:
    """Outputs (n, p) after a unit step on input ``input_index`` at k = 0, from rest (zero history).

    The predictor is chained: each Tf-sample prediction becomes history for the next, so n may exceed Tf.
    """
    if not 0 <= input_index < pred.m:
        raise ValueError(f"input_index must be in 0..{pred.m - 1}; got {input_index}")
    m, p, ti, tf = pred.m, pred.p, pred.t_ini, pred.t_f
    step = np.zeros(m)
    step[input_index] = 1.0
    u_hist, y_hist = np.zeros((ti, m)), np.zeros((ti, p))
    out = []
    while sum(len(o) for o in out) < n:
        y, _ = pred.predict(u_hist, y_hist, np.tile(step, (tf, 1)))
        out.append(y)
        u_hist = np.vstack([u_hist, np.tile(step, (tf, 1))])[-ti:]
        y_hist = np.vstack([y_hist, y])[-ti:]
    return np.vstack(out)[:n]


def settling_index(y: np.ndarray, band: float = SETTLED) -> int | None:
    """First sample index after which a response y (n,) stays within ``band`` x its final change of the
    final value (the last sample), i.e. the samples to settle; None if it has not settled (the last
    10 % of the samples are not inside the band, or there is no change)."""
    y = np.asarray(y, dtype=float)
    final = y[-1]
    tol = band * abs(final)
    if tol == 0.0 or not np.all(np.isfinite(y)):
        return None
    outside = np.nonzero(np.abs(y - final) > tol)[0]
    k = 0 if outside.size == 0 else int(outside[-1]) + 1
    return k if k <= 0.9 * len(y) else None


def dead_index(y: np.ndarray, band: float = ANSWERED) -> int | None:
    """First sample index at which a response y (n,) reaches ``band`` x its largest change max |y|, i.e.
    its dead time in samples; None if it never changes (or is not finite)."""
    a = np.abs(np.asarray(y, dtype=float))
    if a.size == 0 or not np.all(np.isfinite(a)) or a.max() == 0.0:
        return None
    return int(np.argmax(a >= band * a.max()))


@dataclass(frozen=True)
class OutputSettling:
    """One output's answer to its strongest input: steady-state gain; the 90 % settling time in samples
    and seconds (None: not settled within the simulated span ``span_s``); the dead time in samples (None:
    no answer); and ``seen``, the largest |response| within the horizon Tf over the largest within the span."""

    output: str
    input: str
    gain: float
    ticks: int | None
    seconds: float | None
    span_s: float
    dead_ticks: int | None
    seen: float


def settling_summary(pred: Predictor, span_s: float = 5.0) -> list[OutputSettling]:
    """Per output, the step response from the input with the largest final effect on it, over ``span_s``."""
    n = max(pred.t_f, int(round(span_s / pred.dt)))
    names_u = pred.input_names or tuple(f"u{j}" for j in range(pred.m))
    names_y = pred.output_names or tuple(f"y{i}" for i in range(pred.p))
    resp = [step_response(pred, j, n) for j in range(pred.m)]
    out = []
    for i in range(pred.p):
        j = int(np.argmax([abs(r[-1, i]) for r in resp]))
        y = resp[j][:, i]
        k, peak = settling_index(y), float(np.max(np.abs(y)))
        seen = float(np.max(np.abs(y[: pred.t_f]))) / peak if peak > 0.0 and np.isfinite(peak) else 0.0
        out.append(OutputSettling(names_y[i], names_u[j], float(y[-1]), k, None if k is None else k * pred.dt,
                                  n * pred.dt, dead_index(y), seen))
    return out


def settling_report(pred: Predictor, span_s: float = 5.0) -> tuple[list[str], list[str]]:
    """(summary lines, warnings): each output's step response summary (gain, dead time, settling time, the
    share of the response the horizon Tf * dt sees), and a warning per output that has not begun to
    answer its strongest input within the horizon (dead time >= Tf): the steering cannot act on it."""
    lines, warnings = [], []
    t_f, dt = pred.t_f, pred.dt
    horizon = f"{t_f} x {dt:g} s = {t_f * dt:.3g} s"
    for s in settling_summary(pred, span_s):
        head = f"step response {s.input} -> {s.output}: gain {s.gain:.3g}, "
        if not np.isfinite(s.gain):
            lines.append(f"step response {s.input} -> {s.output}: not finite within {s.span_s:g} s")
            warnings.append(f"warning: the predicted response of {s.output} to a {s.input} step diverges within "
                            f"{s.span_s:g} s: the horizon cannot be checked against it")
            continue
        if s.dead_ticks is None:
            lines.append(head + "no answer")
            warnings.append(f"warning: {s.output} does not answer a {s.input} step within {s.span_s:g} s: the "
                            f"steering cannot act on it")
            continue
        settled = (f"90 % settling time {s.seconds:.3g} s ({s.ticks} ticks)" if s.ticks is not None
                   else f"not settled within {s.span_s:g} s")
        lines.append(head + f"dead time {s.dead_ticks * dt:.3g} s ({s.dead_ticks} ticks), {settled}; the horizon "
                     f"({t_f * dt:.3g} s) sees {100 * s.seen:.3g} % of the response")
        if s.dead_ticks >= t_f:
            warnings.append(f"warning: {s.output} has not begun to answer a {s.input} step when the horizon ({horizon}) "
                            f"ends (dead time {s.dead_ticks * dt:.3g} s: below {100 * ANSWERED:g} % of its largest "
                            f"change for {s.dead_ticks} ticks): the steering cannot act on that loop; raise [horizon] "
                            f"t_f above {s.dead_ticks} (with [horizon] knots to keep the QP small)")
    return lines, warnings
