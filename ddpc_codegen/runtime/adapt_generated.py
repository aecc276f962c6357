"""The online update of a generated solver built with ``[adapt] enabled`` (``<name>_adapt_*`` in its
extension), behind the adaptation API the interpreted twin has too (issue 30).

Threads (the contract in ``<name>_adapt.h``): a re-solve may run in another thread while the tick pushes and
solves; everything else is the tick's. Two guards, both non-blocking (a call that would share a workspace with
another thread raises :class:`~ddpc_codegen.runtime.guard.SolverBusyError`): the solver's (push, clear,
snapshot, swap, and the solver's own calls) and the re-solve's (resolve, snapshot, swap)."""

from __future__ import annotations

import numpy as np

from ddpc_codegen.errors import ManifestError
from ddpc_codegen.runtime.guard import Guard
from ddpc_codegen.values.adapt import OFFSET_COUNTS, REJECTIONS, AdaptSettings, SampleWindow, Swapped

__all__ = ["GeneratedAdaptation"]

_COUNTS = ("updates", "skipped", "dropped", "folded", "resolves", "accepted", "swaps", "clipped")


class GeneratedAdaptation:
    """The C update of one :class:`~ddpc_codegen.runtime.loader.GeneratedSolver` instance: its own
    ``<name>_adapt_workspace``; a swap installs the rebuilt QP data into the solver's workspace."""

    def __init__(self, solver) -> None:
        man = solver.manifest
        fs, st = man.get("fit_statistic"), man.get("adapt")
        if not isinstance(fs, dict) or not isinstance(st, dict):
            raise ManifestError(f"{solver.folder}: the binary has an online update but manifest.json records no "
                                "fit_statistic / adapt entry (edited?); regenerate the solver")
        self._solver, self._ffi, self._lib, name = solver, solver._ffi, solver._lib, solver.name
        self._tick, self._resolving = solver._guard, Guard(name)
        self._fn = {f: getattr(self._lib, f"{name}_adapt_{f}") for f in ("init", "push", "snapshot", "resolve", "swap")}
        self.settings = AdaptSettings(**st)
        self._ws = self._ffi.new(f"{name}_adapt_workspace *")
        if self._fn["init"](self._ws) != 0:
            raise ManifestError(f"{solver.folder}: the shipped R factor cannot be re-solved (adapt_init failed)")
        lay = fs["layout"]
        self.depth = int(lay["t_ini"]) + int(lay["t_f"])
        self._window = SampleWindow(self.depth, solver.m, solver.p, fs["signal"] == "increments")
        self._buf = np.empty(self.depth * (solver.m + solver.p))
        self._pbuf = self._ffi.from_buffer("double[]", self._buf)

    def push(self, u: np.ndarray, y: np.ndarray) -> bool:
        """One (u (m,), y (p,)) sample; True when a column was taken (queued for R: the next re-solve folds it
        in, off the tick path)."""
        with self._tick.held("adapt_push"):
            w = self._window.push(np.asarray(u, float), np.asarray(y, float))
            if w is None:
                return False
            self._buf[:] = w.reshape(-1)
            return bool(self._fn["push"](self._ws, self._pbuf))

    def clear(self) -> None:
        with self._tick.held("adapt_clear"):
            self._window.clear()

    def snapshot(self) -> None:
        """Copy the recent columns and hand the queued ones to the next re-solve (in the tick)."""
        with self._tick.held("adapt_snapshot"), \
                self._resolving.held("adapt_snapshot (a re-solve runs)"):
            self._fn["snapshot"](self._ws)

    def resolve(self, snapshot: bool = True) -> str:
        """Re-solve, rebuild and verify: "accepted" or the rejection reason. ``snapshot=False``: from the last
        :meth:`snapshot`, safe in another thread while :meth:`push` and the solver run (cffi releases the GIL
        for the C call; see the contract in ``<name>_adapt.h``)."""
        if snapshot:
            self.snapshot()
        with self._resolving.held("adapt_resolve (another re-solve runs)"):
            code = self._fn["resolve"](self._ws)
        return "accepted" if code == 0 else REJECTIONS[code - 1]

    def swap(self) -> Swapped:
        """Install a verified candidate G into the solver's workspace (its warm start is dropped) and a verified
        output offset; what was installed."""
        with self._tick.held("adapt_swap"), \
                self._resolving.held("adapt_swap (a re-solve runs)"):
            return Swapped.of_code(self._fn["swap"](self._ws, self._solver._ws))

    def refused(self) -> int:
        """Columns not taken (skipped NaN/inf + dropped on a full queue): counters only push() writes, so safe to
        read in the tick while a re-solve runs."""
        c = self._ws.counts
        return int(c.skipped) + int(c.dropped)

    def counts(self) -> dict:
        c = self._ws.counts
        out = {k: int(getattr(c, k)) for k in _COUNTS}
        out.update({f"rejected_{r}": int(c.rejected[i + 1]) for i, r in enumerate(REJECTIONS)})
        out.update({k: int(getattr(c, k)) for k in OFFSET_COUNTS}, offset_norm=float(c.offset_norm))
        out.update({k: float(getattr(c, k)) for k in ("error_current", "error_candidate",  # the last error checks
                                                      "offset_error_current", "offset_error_candidate")})
        return out

    def offset(self) -> np.ndarray:
        """The output offset in use (p Tf,), data units, time-major (zeros before the first offset swap)."""
        n = self._solver.p * self._solver.t_f
        if self._ws.counts.offset_swaps == 0:
            return np.zeros(n)
        half = 1 - self._ws.off_spare  # the swap flipped off_spare away from the half in use
        return np.array([self._ws.yoff[half * n + i] for i in range(n)])

