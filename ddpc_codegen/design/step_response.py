"""What the identified closed loop says about the horizon it needs: the predictor's step response and
the 90 % settling time of each output.

The steering can only correct what its horizon sees: a horizon Tf * dt shorter than the time a loop
needs to answer a reference step cannot lead that loop. The response is computed from the predictor
alone (from rest, a unit step on one input, the predictor chained over its own predictions), so it is
the loop the data describe, beyond Tf if need be.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ddpc_codegen.design.predictor import Predictor

__all__ = ["step_response", "settling_index", "OutputSettling", "settling_summary", "settling_report"]

SETTLED = 0.1  # "settled": within 10 % of the final change for good (the 90 % settling time)


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


@dataclass(frozen=True)
class OutputSettling:
    """One output's answer to its strongest input: steady-state gain, and the 90 % settling time in
    samples and seconds (None: not settled within the simulated span ``span_s``)."""

    output: str
    input: str
    gain: float
    ticks: int | None
    seconds: float | None
    span_s: float


def settling_summary(pred: Predictor, span_s: float = 5.0) -> list[OutputSettling]:
    """Per output, the step response from the input with the largest final effect on it, over ``span_s``."""
    n = max(pred.t_f, int(round(span_s / pred.dt)))
    names_u = pred.input_names or tuple(f"u{j}" for j in range(pred.m))
    names_y = pred.output_names or tuple(f"y{i}" for i in range(pred.p))
    resp = [step_response(pred, j, n) for j in range(pred.m)]
    out = []
    for i in range(pred.p):
        j = int(np.argmax([abs(r[-1, i]) for r in resp]))
        k = settling_index(resp[j][:, i])
        out.append(OutputSettling(names_y[i], names_u[j], float(resp[j][-1, i]), k,
                                  None if k is None else k * pred.dt, n * pred.dt))
    return out


def settling_report(pred: Predictor, span_s: float = 5.0) -> tuple[list[str], list[str]]:
    """(summary lines, warnings): each output's step response summary, and a warning per output whose 90 %
    settling time is longer than the predictor's horizon Tf * dt."""
    lines, warnings = [], []
    t_f, dt = pred.t_f, pred.dt
    horizon = t_f * dt
    for s in settling_summary(pred, span_s):
        if s.ticks is None:
            lines.append(f"step response {s.input} -> {s.output}: gain {s.gain:.3g}, not settled within {s.span_s:g} s")
            warnings.append(f"warning: {s.output} does not settle to 90 % within {s.span_s:g} s of a {s.input} step; "
                            f"the horizon ({t_f} x {dt:g} s = {horizon:.3g} s) cannot be checked against it")
            continue
        lines.append(f"step response {s.input} -> {s.output}: gain {s.gain:.3g}, 90 % settling time "
                     f"{s.seconds:.3g} s ({s.ticks} ticks)")
        if s.ticks > t_f:
            warnings.append(f"warning: the horizon ({t_f} x {dt:g} s = {horizon:.3g} s) covers less than the 90 % "
                            f"settling time of {s.output} ({s.seconds:.3g} s): the steering cannot lead that loop; raise "
                            f"[horizon] t_f to at least {s.ticks} (with [horizon] knots to keep the QP small)")
    return lines, warnings
