"""Artificial ground-phase IO for hopping (paper, "Reference-Steering for Periodic Hopping").

The Hankel matrix of hopping is built from aerial-phase data only: the ground phase has other
dynamics (contact, spring leg). Each ground phase inside a window is replaced by *artificial IO*:
samples that the aerial dynamics could have produced between the real descent before the
touchdown and the real ascent after the liftoff. Per hop the paper solves

    min_g ||g||^2   s.t.  H g = [u_d; u_g; u_a; y_d; y_g; y_a],   u_g, y_g free,  u, y in bounds,

with H a Hankel matrix of aerial data, and joins the completed hops into a mosaic
H_G = [H_G1 | ... | H_Gn]. Online the same construction fills the ground part of u_ini / y_ini.

How it is solved here (:class:`ArtificialIO`). The window is stacked time-major, each sample as
[u_t (m); y_t (p)] (the predictor's layout), so "H g" is a depth-L block Hankel of [u y] times g.
Its transpose is accumulated block-wise into a QR factor, H^T = Q R, and R^T = V S U^T is reduced
to its numerical rank r: H = B W^T with B = V_r S_r (L(m+p) x r) and W orthonormal. Because the
optimal g lies in range(H^T), ||g|| = ||z|| with g = W z, and the problem becomes

    min_z ||z||^2   s.t.  B_K z = b,   lo <= B_F z <= hi          (K: known rows, F: free rows)

whose solution without active bounds is the closed-form least-norm z = pinv(B_K) b, so the
free samples are B_F pinv(B_K) b: a fixed matrix per mask, cached. On noisy or slightly
nonlinear data the exact equality uses directions of H that are only noise; ``noise_level``
sigma replaces it by min lambda ||z||^2 + ||B_K z - b||^2 with lambda = columns * sigma^2 (SVD
filter factors s / (s^2 + lambda): a direction whose amplitude per sample is below sigma is
damped). When a bound on u or y is violated, the bounded QP above is solved by a dense active-set
method (CasADi's daqp; r variables, identity-plus-low-rank Hessian).

Uniqueness. The real descent fixes the state at touchdown and the real ascent the state at
liftoff (when each part is at least the lag long), but the free inputs that join them are unique
only when m*T_g <= n: in general the least-norm g picks one of many aerial trajectories with the
same end states. The *outputs* of a gap whose inputs are known, and the state at the end of the
window (what the predictor needs), are unique.

Layout of the per-hop data: :func:`stitch_hops` takes apex-to-apex hop segments (e.g.
``SimResult.to_dataset("hops")``) and replaces each ground phase by the artificial IO computed
from ``t_d`` descent and ``t_a`` ascent samples around it; the result is an :class:`IODataset`
whose trajectories are the hops H_G1..H_Gn (a mosaic Hankel never crosses from one hop to the next).

Online (:class:`ddpc_codegen.runtime.hopping.HoppingWindow`) the same completion fills the ground samples of u_ini / y_ini
once ``min_ascent`` ascent samples are in. Two choices differ from the offline stitching:
(1) no descent context (``t_d = 0``): joining the real descent to the real ascent forces the
aerial dynamics to reverse the vertical velocity within the short ground phase, an atypical
trajectory with a large ||g|| and extreme references. That is harmless on clean recorded data but
amplifies measurement noise online, while a fill conditioned on the ascent alone is a plausible pre-history of the measured state. (2) a small
``noise_level`` (1e-3) with the fitted window returned (``replace_known``), so the predictor sees
one data-consistent trajectory without a seam.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from ddpc_codegen.values.phases import ground_runs
from ddpc_codegen.design.data import IODataset
from ddpc_codegen.errors import DataError
from ddpc_codegen.design.hankel import PEReport, persistency_of_excitation
from ddpc_codegen.values.completion import Completion, check_window

__all__ = [
    "ArtificialIO",
    "ground_runs",
    "stitch_hops",
    "hop_excitation",
]


def _row_index(t: np.ndarray, c: np.ndarray, d: int) -> np.ndarray:
    return (np.asarray(t)[:, None] * d + np.asarray(c)[None, :]).reshape(-1)


class ArtificialIO:
    """Fill missing samples of an IO window with a trajectory of the data's (aerial) dynamics.

    Args:
        dataset: aerial-phase trajectories (each one continuous, no ground samples).
        depth: longest window (samples) that can be completed; shorter windows use the first
            block rows (a valid Hankel of fewer columns).
        rcond: relative singular-value cutoff deciding the numerical rank r of the Hankel.
        noise_level: sigma >= 0 [signal units, m / rad]: data directions whose amplitude per
            sample is below sigma are treated as noise (Tikhonov lambda = columns * sigma^2, see the
            module docstring); 0 = exact least-norm (noise-free data).
        u_min, u_max (m,), y_min, y_max (p,): bounds on the artificial samples (±inf = none).
        block_columns: Hankel columns per streamed QR block.
    """

    def __init__(
        self,
        dataset: IODataset,
        depth: int,
        *,
        rcond: float = 1e-10,
        noise_level: float = 0.0,
        u_min: Sequence[float] | None = None,
        u_max: Sequence[float] | None = None,
        y_min: Sequence[float] | None = None,
        y_max: Sequence[float] | None = None,
        block_columns: int = 4096,
    ) -> None:
        depth = int(depth)
        if depth < 2:
            raise DataError(f"artificial-IO depth must be >= 2 samples; got {depth}")
        if not (np.isfinite(noise_level) and noise_level >= 0):
            raise DataError(f"noise_level must be >= 0; got {noise_level}")
        self.m, self.p, self.depth = dataset.m, dataset.p, depth
        self.d = self.m + self.p
        self.noise_level = float(noise_level)
        self.rcond = float(rcond)
        rows = depth * self.d
        R = None
        cols = 0
        for u, y in dataset.trajectories():
            w = np.hstack([u, y])
            T = w.shape[0]
            if T < depth:
                continue
            win = sliding_window_view(w, (depth, self.d))[:, 0].reshape(T - depth + 1, rows)
            cols += win.shape[0]
            for s in range(0, win.shape[0], int(block_columns)):
                X = win[s : s + block_columns] if R is None else np.vstack([R, win[s : s + block_columns]])
                R = np.linalg.qr(X, mode="r")
        if R is None:
            raise DataError(
                f"no trajectory of the dataset is long enough ({max(dataset.lengths)} samples) for an "
                f"artificial-IO window of {depth} samples; record longer aerial phases or shorten t_d/t_a"
            )
        # H = R^T Q^T; R^T = V S U^T -> H = (V S) (Q U)^T, B = V_r S_r.
        V, s, _ = np.linalg.svd(R.T, full_matrices=False)
        keep = s > self.rcond * s[0]
        self.basis = V[:, keep] * s[keep]  # (rows, r)
        self.singular_values = s
        self.rank = int(keep.sum())
        self.n_columns = cols
        lo = np.concatenate([np.full(self.m, -np.inf) if u_min is None else np.broadcast_to(np.asarray(u_min, float), (self.m,)),
                             np.full(self.p, -np.inf) if y_min is None else np.broadcast_to(np.asarray(y_min, float), (self.p,))])
        hi = np.concatenate([np.full(self.m, np.inf) if u_max is None else np.broadcast_to(np.asarray(u_max, float), (self.m,)),
                             np.full(self.p, np.inf) if y_max is None else np.broadcast_to(np.asarray(y_max, float), (self.p,))])
        self.lo, self.hi = lo, hi
        self._cache: dict[bytes, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = {}
        self.counts = {"calls": 0, "bounded": 0, "qp_failed": 0}

    def __repr__(self) -> str:
        return (f"ArtificialIO(m={self.m}, p={self.p}, depth={self.depth}, rank={self.rank}, "
                f"columns={self.n_columns}, noise_level={self.noise_level})")

    # ------------------------------------------------------------------ core
    def _operators(self, mask: np.ndarray, lam: float) -> tuple:
        """For a mask, cached: (known row idx K, free row idx F, pinv_lambda(B_K) (r, |K|),
        B_F pinv_lambda(B_K) (|F|, |K|), null-space basis N of B_K (r, r - rank), exact only)."""
        key = mask.tobytes() + bytes(f"{mask.shape}{lam!r}", "ascii")
        hit = self._cache.get(key)
        if hit is not None:
            return hit
        flat = mask.reshape(-1)
        K = np.flatnonzero(~flat)
        F = np.flatnonzero(flat)
        B = self.basis[: flat.size]
        BK = B[K]
        U, s, Vt = np.linalg.svd(BK, full_matrices=True)
        U = U[:, : s.size]
        if s.size == 0 or s[0] == 0:
            inv = np.zeros_like(s)
            rank = 0
        elif lam > 0:
            inv = s / (s * s + lam)
            rank = s.size
        else:
            keep = s > max(self.rcond, 1e-12) * s[0]
            rank = int(keep.sum())
            inv = np.where(keep, 1.0 / np.where(s > 0, s, 1.0), 0.0)
        pinv = (Vt[: s.size].T * inv) @ U.T  # (r, |K|)
        out = (K, F, pinv, B[F] @ pinv, Vt[rank:].T)
        if len(self._cache) < 512:
            self._cache[key] = out
        return out

    def complete(self, u: np.ndarray, y: np.ndarray, missing: np.ndarray, *,
                 replace_known: bool = False, noise_level: float | None = None) -> Completion:
        """Fill the missing samples of a window.

        Args:
            u (L, m), y (L, p): the window (values at missing samples are ignored; NaN allowed there).
            missing: (L,) bool per sample (all channels) or (L, m+p) bool per channel entry.
            replace_known: also return the fitted values H_K g instead of the known samples. With
                noise_level > 0 the fit does not pass exactly through noisy known samples; the fitted
                window is then one trajectory of the data's dynamics end to end (no seam between
                artificial and measured samples), which is what a predictor should be given.
            noise_level: override of the operator's sigma for this call (e.g. 0 for clean recorded
                hops, > 0 for noisy online windows).
        Returns:
            :class:`Completion` with the filled window.
        """
        u, y, mask = check_window(u, y, missing, self.m, self.p, self.depth)
        L = u.shape[0]
        w = np.hstack([u, y]).reshape(-1)
        sig = self.noise_level if noise_level is None else float(noise_level)
        lam = self.n_columns * sig * sig
        K, F, pinv, fill_op, _ = self._operators(mask, lam)
        b = w[K]
        self.counts["calls"] += 1
        z = pinv @ b
        fill = fill_op @ b
        lo = np.tile(self.lo, L)[F]
        hi = np.tile(self.hi, L)[F]
        bounded, status = False, "solved"
        if np.any(fill < lo - 1e-9) or np.any(fill > hi + 1e-9):
            bounded = True
            self.counts["bounded"] += 1
            z2, status = self._bounded(mask, b, lo, hi, lam)
            if z2 is not None:
                z = z2
                fill = self.basis[: mask.size][F] @ z
            else:
                self.counts["qp_failed"] += 1
                fill = np.clip(fill, lo, hi)
        out = w.copy()
        out[F] = fill
        B = self.basis[: mask.size]
        fitted = B[K] @ z
        residual = float(np.max(np.abs(fitted - b))) if K.size else 0.0
        if replace_known:
            out[K] = fitted
        W = out.reshape(L, self.d)
        return Completion(W[:, : self.m].copy(), W[:, self.m :].copy(), residual, float(np.linalg.norm(z)),
                          bounded, status)

    def _bounded(self, mask: np.ndarray, b: np.ndarray, lo: np.ndarray, hi: np.ndarray, lam: float):
        """The bounded QP in z (r variables), dense active set (CasADi's daqp), with
        lo <= B_F z <= hi on the free samples that have a finite bound and

        * exact (lambda = 0): min ||z||^2 s.t. B_K z = b. B_K is rank deficient on exact LTI data, so
          the equality is eliminated: z = z0 + N w with z0 = pinv(B_K) b (row space) and N a basis of
          the null space; ||z||^2 = ||z0||^2 + ||w||^2, an inequality-only least-distance problem.
        * noise_level > 0: min lambda ||z||^2 + ||B_K z - b||^2.
        """
        import casadi as ca

        flat = mask.reshape(-1)
        B = self.basis[: flat.size]
        BK, BF = B[~flat], B[flat]
        fin = np.isfinite(lo) | np.isfinite(hi)
        BF, lo, hi = BF[fin], lo[fin], hi[fin]
        r = B.shape[1]
        if lam > 0:
            H = 2.0 * (lam * np.eye(r) + BK.T @ BK)
            g = -2.0 * BK.T @ b
            A, lba, uba, z0, N = BF, lo, hi, np.zeros(r), np.eye(r)
        else:
            _, _, pinv, _, N = self._operators(mask, 0.0)
            z0 = pinv @ b
            if N.shape[1] == 0:
                return None, "no_freedom"  # the equality fixes z: bounds cannot be met
            H = 2.0 * np.eye(N.shape[1])
            g = np.zeros(N.shape[1])
            A = BF @ N
            lba, uba = lo - BF @ z0, hi - BF @ z0
        solver = ca.conic("art_io", "daqp", {"h": ca.DM(H).sparsity(), "a": ca.DM(A).sparsity()},
                          {"error_on_fail": False, "print_problem": False})
        res = solver(h=H, g=g, a=A, lba=np.maximum(lba, -1e20), uba=np.minimum(uba, 1e20))
        stats = solver.stats()
        w = np.asarray(res["x"], float).reshape(-1)
        if not stats.get("success", False) or not np.all(np.isfinite(w)):
            return None, f"daqp_{stats.get('return_status', 'failed')}".lower().replace(" ", "_")
        return z0 + N @ w, "solved"


# ---------------------------------------------------------------------------- hops
def stitch_hops(
    hops: IODataset,
    art: ArtificialIO,
    t_d: int,
    t_a: int,
    *,
    noise_level: float | None = None,
    progress: bool = False,
) -> tuple[IODataset, dict]:
    """Replace the ground phase of every hop by artificial IO; the hops become the mosaic H_G.

    Args:
        hops: hop segments with phase labels (e.g. ``SimResult.to_dataset("hops")``, apex to apex).
        art: completion operator built from aerial data (depth >= t_d + ground + t_a).
        t_d, t_a: real descent samples before the touchdown / ascent samples after the liftoff
            that the completion is conditioned on (each >= the lag of the aerial dynamics).
        noise_level: sigma of the completion (None: the operator's).
    Returns:
        (dataset of completed hops, report dict: hops used / skipped, max residual, bounded count).
        Hops without a ground phase, with more than one, or without t_d / t_a aerial samples
        around it are skipped (and counted).
    """
    if hops.phases is None:
        raise DataError("stitch_hops needs phase labels (SimResult.to_dataset('hops') provides them)")
    us, ys, phs = [], [], []
    skipped: dict[str, int] = {}
    resid, bounded = 0.0, 0
    it = range(hops.n_trajectories)
    if progress:
        from tqdm import tqdm
        import sys

        it = tqdm(it, desc="artificial IO", unit="hop", file=sys.stderr, leave=False)
    for i in it:
        u, y, ph = hops.u[i], hops.y[i], hops.phases[i]
        runs = ground_runs(ph)
        if len(runs) != 1:
            skipped["ground_runs"] = skipped.get("ground_runs", 0) + 1
            continue
        g0, g1 = runs[0]
        a, b = g0 - t_d, g1 + t_a
        if a < 0 or b > len(ph):
            skipped["short"] = skipped.get("short", 0) + 1
            continue
        if b - a > art.depth:
            skipped["ground_too_long"] = skipped.get("ground_too_long", 0) + 1
            continue
        missing = np.zeros(b - a, dtype=bool)
        missing[g0 - a : g1 - a] = True
        c = art.complete(u[a:b], y[a:b], missing, noise_level=noise_level)
        resid = max(resid, c.residual)
        bounded += int(c.bounded)
        uu, yy = u.copy(), y.copy()
        uu[g0:g1] = c.u[g0 - a : g1 - a]
        yy[g0:g1] = c.y[g0 - a : g1 - a]
        us.append(uu)
        ys.append(yy)
        phs.append(ph)
    if not us:
        raise DataError(f"no hop could be stitched (skipped: {skipped}); record more hops or shorten t_d / t_a")
    meta = dict(hops.metadata)
    meta.update({"artificial_io": {"t_d": int(t_d), "t_a": int(t_a), "depth": art.depth, "rank": art.rank,
                                   "noise_level": art.noise_level if noise_level is None else noise_level}})
    ds = IODataset(us, ys, hops.dt, input_names=hops.input_names, output_names=hops.output_names,
                   input_units=hops.input_units, output_units=hops.output_units, phases=phs, metadata=meta)
    report = {"hops": len(us), "skipped": skipped, "max_residual": resid, "bounded": bounded}
    return ds, report


def hop_excitation(dataset: IODataset, order: int, tol: float | None = None) -> PEReport:
    """PE check of the mosaic Hankel of a hop dataset's inputs (one Hankel per hop, joined)."""
    return persistency_of_excitation(list(dataset.u), order, tol)
