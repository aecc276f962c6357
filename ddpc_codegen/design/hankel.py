"""Block and mosaic Hankel matrices, and the persistency-of-excitation check.

Block Hankel of depth L of a time-major signal w (T, d): shape (L*d, T-L+1), block row i,
column j equal to w[i+j]. Several trajectories are joined column-wise (mosaic), never by
concatenating the signals.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from ddpc_codegen.errors import DataError

__all__ = ["block_hankel", "mosaic_hankel", "persistency_of_excitation", "PEReport", "channel_stats",
           "near_constant_channels", "NEAR_CONSTANT_RTOL", "NEAR_CONSTANT_SELF_RTOL"]

# A channel is near-constant when its standard deviation is below NEAR_CONSTANT_RTOL times the
# largest standard deviation of all channels (compared in the data's own units), or below
# NEAR_CONSTANT_SELF_RTOL times its own RMS (a constant at an offset, varying at rounding level).
# Channel scaling would otherwise blow such a channel up to unit size and call it exciting.
NEAR_CONSTANT_RTOL = 1e-6
NEAR_CONSTANT_SELF_RTOL = 1e-9


def _signal(w: np.ndarray, what: str = "signal") -> np.ndarray:
    a = np.asarray(w, dtype=float)
    if a.ndim == 1:
        a = a[:, None]
    if a.ndim != 2:
        raise DataError(f"{what} must be time-major (T, channels); got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise DataError(f"{what} contains NaN or inf; clean the data before building a Hankel matrix")
    return a


def block_hankel(w: np.ndarray, depth: int) -> np.ndarray:
    """Block Hankel matrix of depth ``depth`` of ``w`` (T, d) -> (depth*d, T-depth+1)."""
    a = _signal(w)
    depth = int(depth)
    T, d = a.shape
    if depth < 1:
        raise DataError(f"Hankel depth must be >= 1; got {depth}")
    if T < depth:
        raise DataError(f"a Hankel matrix of depth {depth} needs at least {depth} samples; got {T}")
    # windows[j] = a[j:j+depth] -> (cols, depth, d); column j stacks them time-major.
    windows = sliding_window_view(a, (depth, d))[:, 0]
    return np.ascontiguousarray(windows.reshape(T - depth + 1, depth * d).T)


def mosaic_hankel(trajectories: Sequence[np.ndarray], depth: int) -> np.ndarray:
    """Mosaic Hankel: the column-wise concatenation of each trajectory's block Hankel.

    Trajectories shorter than ``depth`` contribute no column (they cannot hold a window).
    Raises DataError when no trajectory is long enough or channel counts differ.
    """
    sigs = [_signal(w, f"trajectory {i}") for i, w in enumerate(trajectories)]
    if not sigs:
        raise DataError("mosaic_hankel needs at least one trajectory")
    d = sigs[0].shape[1]
    for i, s in enumerate(sigs):
        if s.shape[1] != d:
            raise DataError(f"trajectory {i} has {s.shape[1]} channels, trajectory 0 has {d}")
    blocks = [block_hankel(s, depth) for s in sigs if s.shape[0] >= depth]
    if not blocks:
        longest = max(s.shape[0] for s in sigs)
        raise DataError(
            f"no trajectory is long enough for depth {depth} (longest has {longest} samples)"
        )
    return np.hstack(blocks)


@dataclass(frozen=True)
class PEReport:
    """Result of a persistency-of-excitation check of order ``order``.

    ``ok`` is True when H_order(u) has full row rank ``required_rank = m*order`` numerically,
    i.e. singular values above ``tol``, and no input channel is near-constant. Singular values
    are those of the Hankel of the channels scaled to unit std (so they do not depend on units).
    ``near_constant_inputs`` / ``near_constant_outputs`` name near-constant channels (see
    NEAR_CONSTANT_RTOL); ``channel_std`` maps every channel name to its std in the data's units.
    """

    order: int
    rank: int
    required_rank: int
    singular_values: np.ndarray
    tol: float
    condition_number: float
    columns: int
    near_constant_inputs: tuple[str, ...] = ()
    near_constant_outputs: tuple[str, ...] = ()
    channel_std: dict = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        return self.rank >= self.required_rank and not self.near_constant_inputs

    def __bool__(self) -> bool:
        return self.ok

    def summary(self) -> str:
        s = self.singular_values
        smin = s[-1] if s.size else 0.0
        verdict = "persistently exciting" if self.ok else "NOT persistently exciting"
        text = (
            f"{verdict} of order {self.order}: rank {self.rank}/{self.required_rank} "
            f"({self.columns} Hankel columns, channels scaled to unit std), sigma_max={s[0] if s.size else 0.0:.3g}, "
            f"sigma_min={smin:.3g}, tol={self.tol:.3g}, cond={self.condition_number:.3g}"
        )
        for kind, names in (("input", self.near_constant_inputs), ("output", self.near_constant_outputs)):
            if names:
                std = ", ".join(f"{n} (std {self.channel_std.get(n, float('nan')):.3g})" for n in names)
                text += (f"; near-constant {kind} channel(s): {std} (std below {NEAR_CONSTANT_RTOL:g} x the largest "
                         f"channel std or {NEAR_CONSTANT_SELF_RTOL:g} x its own RMS)")
        return text


def channel_stats(trajectories: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Per-channel (RMS, std) over all samples of all trajectories (each (T_i, d)) -> two (d,) arrays.

    Two passes (mean, then squared deviations) so a small std on a large offset is not lost to cancellation.
    """
    n = sum(w.shape[0] for w in trajectories)
    mean = sum(w.sum(axis=0) for w in trajectories) / n
    var = sum(((w - mean) ** 2).sum(axis=0) for w in trajectories) / n
    ms = sum((w**2).sum(axis=0) for w in trajectories) / n
    return np.sqrt(ms), np.sqrt(var)


def near_constant_channels(std: np.ndarray, rms: np.ndarray, names: Sequence[str]) -> tuple[str, ...]:
    """Names of the near-constant channels (see NEAR_CONSTANT_RTOL), in the order given."""
    ref = float(np.max(std)) if std.size else 0.0
    bad = (std <= NEAR_CONSTANT_RTOL * ref) | (std <= NEAR_CONSTANT_SELF_RTOL * rms)
    return tuple(str(n) for n, b in zip(names, bad) if b)


def persistency_of_excitation(
    u: np.ndarray | Sequence[np.ndarray], order: int, tol: float | None = None,
    names: Sequence[str] | None = None,
) -> PEReport:
    """Check that input data is persistently exciting of ``order`` (rank of H_order(u)).

    Channels are scaled to unit std first (the verdict does not depend on units); near-constant
    channels are named and make the report not ok.

    Args:
        u: input (T, m), or a list of trajectories (mosaic Hankel).
        order: Hankel depth, L + n for the fundamental lemma (L = Tini + Tf, n = state dim).
        tol: singular-value threshold; default ``max(shape) * eps * sigma_max`` (numpy's rank rule).
        names: channel names for the report (default u0, u1, ...).
    """
    trajs = [_signal(w, f"trajectory {i}") for i, w in enumerate([u] if isinstance(u, np.ndarray) else list(u))]
    m = trajs[0].shape[1]
    names = tuple(names) if names is not None else tuple(f"u{i}" for i in range(m))
    required = m * int(order)
    rms, std = channel_stats(trajs) if all(w.shape[1] == m for w in trajs) else (np.ones(m), np.ones(m))
    near_names = near_constant_channels(std, rms, names)
    # unit std per channel (as in fit_predictor); a near-constant one by its RMS (1 if all zero)
    scale = np.where([n in near_names for n in names], np.where(rms > 0, rms, 1.0), std)
    near = dict(near_constant_inputs=near_names, channel_std={n: float(v) for n, v in zip(names, std)})
    try:
        H = mosaic_hankel([w / scale for w in trajs], order)
    except DataError:
        cols = 0
        s = np.zeros(0)
        return PEReport(int(order), 0, required, s, float(tol or 0.0), float("inf"), cols, **near)
    s = np.linalg.svd(H, compute_uv=False)
    if tol is None:
        tol = float(max(H.shape) * np.finfo(float).eps * (s[0] if s.size else 0.0))
    rank = int(np.sum(s > tol))
    cond = float(s[0] / s[-1]) if s.size and s[-1] > 0 else float("inf")
    if H.shape[1] < required:
        cond = float("inf")
    return PEReport(int(order), rank, required, s, float(tol), cond, H.shape[1], **near)
