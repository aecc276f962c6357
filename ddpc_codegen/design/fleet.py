"""Predictor fit from many data files (a fleet's logs) as map/reduce on the task engine.

The fit is a TSQR over Hankel columns (:mod:`ddpc_codegen.design.predictor`): R factors of
disjoint sets of columns combine by stacking and one more QR. Here:

* **statistics** (a cheap first map): per piece the count, mean, squared deviations and squares of
  every channel, combined in piece order (Chan et al.) into the global RMS and std, hence the
  same per-channel scales as the serial fit's (the fit is unit-free: channels divided by their std).
* **map** (one task per *piece*: one file, or a slice of a long trajectory, or several short
  trajectories of one file packed together): read only the piece's samples from the ``.npz``
  (:class:`~ddpc_codegen.design.data.IODataset` files) and return the R factor of its scaled
  Hankel rows, :func:`~ddpc_codegen.design.predictor.hankel_r_factor`, the serial fit's own primitive.
  A slice of a trajectory carries Tini+Tf-1 samples of overlap, so the slices' columns are exactly
  the trajectory's columns, each once. Trajectories are never joined, within or across files.
* **reduce**: a binary tree of QRs of stacked factors, in piece order (the result does not depend
  on which task finishes first). The factors are small ((r+q) x (r+q), r+q ~ 10^2), so the tree runs
  in the driver as they arrive: at most log2(pieces) + in-flight factors are held.
* **finish**: :func:`~ddpc_codegen.design.predictor.predictor_from_r`, the serial fit's last step.

Memory per task: the piece's samples (<= ``chunk_columns + Tini+Tf-1`` rows x (m+p) x 8 bytes,
8 MiB at the default 2^18 columns and m+p = 4) plus one Hankel block (``block_columns`` x width x 8
bytes times ~4 for copies and the QR's workspace: ~35 MiB at 8192 x 140) plus the worker's Python,
numpy and Ray; the measured peak per worker is in the returned report.

Files whose trajectories are all shorter than Tini+Tf hold no Hankel column: they are skipped and
named in ``FleetFit.skipped`` (never merged with another file).
"""

from __future__ import annotations

import resource
import time
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ddpc_codegen.cluster import engine
from ddpc_codegen.design.data import checked_json_entry
from ddpc_codegen.design.predictor import (FitLayout, Predictor, channel_scale, hankel_r_factor, predictor_from_r,
                                           stack_r_factors)
from ddpc_codegen.errors import ConfigError, DataError
from ddpc_codegen.values.files import checked_input_path

__all__ = ["FileInfo", "Piece", "FleetFit", "scan_files", "plan_pieces", "plan_stat_pieces", "combine_stats",
           "fit_files"]


@dataclass(frozen=True)
class FileInfo:
    """An IODataset file's header: channels, dt and trajectory lengths (no sample is read)."""

    path: str
    lengths: tuple[int, ...]
    m: int
    p: int
    dt: float
    input_names: tuple[str, ...]
    output_names: tuple[str, ...]


@dataclass(frozen=True)
class Piece:
    """One map task: sample ranges ``(trajectory, start, stop)`` of one file."""

    index: int
    path: str
    ranges: tuple[tuple[int, int, int], ...]


@dataclass
class FleetFit:
    """Result of :func:`fit_files`: the predictor and what went into it (seconds, MiB)."""

    predictor: Predictor
    files: int
    used: int
    skipped: list[tuple[str, str]]
    pieces: int
    samples: int
    columns: int
    workers: int
    seconds: float
    peak_mib_per_worker: float
    timings: dict = field(default_factory=dict)

    def summary(self) -> str:
        return (f"{self.used}/{self.files} files ({len(self.skipped)} skipped), {self.samples} samples, "
                f"{self.columns} Hankel columns in {self.pieces} pieces on {self.workers} worker(s): "
                f"{self.seconds:.2f} s, peak {self.peak_mib_per_worker:.0f} MiB per worker")


# ----------------------------------------------------------------------------- reading
def _npy_header(f: Any) -> tuple[tuple[int, ...], bool, np.dtype]:
    major, _ = np.lib.format.read_magic(f)
    read = np.lib.format.read_array_header_1_0 if major == 1 else np.lib.format.read_array_header_2_0
    return read(f)


def _file_info(path: str) -> FileInfo:
    checked_input_path(path, "dataset", error=DataError)  # a FIFO or a device is never opened
    try:
        with np.load(path, allow_pickle=False) as npz:
            header = checked_json_entry(npz, "header", path, "dataset header")  # IODataset.save: JSON as uint8
        with zipfile.ZipFile(path) as z:
            n = int(header["n_trajectories"])
            lengths, dims = [], set()
            for i in range(n):
                for name in (f"u_{i}", f"y_{i}"):
                    with z.open(f"{name}.npy") as f:
                        shape, _, _ = _npy_header(f)
                    dims.add((name[0], shape[1] if len(shape) > 1 else 1))
                    if name[0] == "u":
                        lengths.append(int(shape[0]))
    except DataError:
        raise  # the header refused by name
    except (OSError, KeyError, ValueError, zipfile.BadZipFile) as e:
        raise DataError(f"{path} is not a readable IODataset .npz file: {e}") from None
    m = {d for k, d in dims if k == "u"}
    p = {d for k, d in dims if k == "y"}
    if len(m) != 1 or len(p) != 1:
        raise DataError(f"{path}: trajectories with different channel counts (u {sorted(m)}, y {sorted(p)})")
    return FileInfo(path, tuple(lengths), m.pop(), p.pop(), float(header["dt"]), tuple(header["input_names"]),
                    tuple(header["output_names"]))


def _read_rows(z: zipfile.ZipFile, member: str, start: int, stop: int) -> np.ndarray:
    """Rows [start, stop) of a (T, d) array in an npz without decompressing the rest into memory."""
    with z.open(member) as f:
        shape, fortran, dtype = _npy_header(f)
        if fortran or dtype != np.float64 or len(shape) != 2:  # unusual layout: read it whole
            f.seek(0)
            return np.lib.format.read_array(f)[start:stop].astype(float)
        row = shape[1] * 8
        f.seek(f.tell() + start * row)  # a forward seek decompresses and discards, in bounded memory
        return np.frombuffer(f.read((stop - start) * row), dtype=np.float64).reshape(stop - start, shape[1])


def scan_files(paths: Sequence[str | Path], depth: int) -> tuple[list[FileInfo], list[tuple[str, str]]]:
    """Headers of every file (checked for equal channels and dt); files without a trajectory of
    ``depth`` samples are returned as skipped with the reason."""
    infos, skipped = [], []
    for path in map(str, paths):
        info = _file_info(path)
        if infos:
            ref = infos[0]
            if (info.m, info.p, info.input_names, info.output_names) != (ref.m, ref.p, ref.input_names, ref.output_names):
                raise DataError(f"{path} has inputs {list(info.input_names)}, outputs {list(info.output_names)}; "
                                f"{ref.path} has {list(ref.input_names)}, {list(ref.output_names)}")
            if not np.isclose(info.dt, ref.dt, rtol=1e-9, atol=0.0):
                raise DataError(f"{path} has dt = {info.dt} s, {ref.path} has {ref.dt} s; resample to one rate")
        if max(info.lengths, default=0) < depth:
            skipped.append((path, f"longest trajectory has {max(info.lengths, default=0)} samples, fewer than "
                                  f"Tini+Tf = {depth}: no Hankel column (files are never joined)"))
            continue
        infos.append(info)
    return infos, skipped


def plan_pieces(infos: Sequence[FileInfo], depth: int, chunk_columns: int) -> list[Piece]:
    """Pieces of at most ``chunk_columns`` Hankel columns: long trajectories sliced (with depth-1
    samples of overlap), short ones of the same file packed together, in file order."""
    pieces: list[Piece] = []
    for info in infos:
        ranges: list[tuple[int, int, int]] = []
        cols = 0
        for k, T in enumerate(info.lengths):
            for c0 in range(0, max(0, T - depth + 1), chunk_columns):
                c1 = min(c0 + chunk_columns, T - depth + 1)
                if cols and cols + (c1 - c0) > chunk_columns:
                    pieces.append(Piece(len(pieces), info.path, tuple(ranges)))
                    ranges, cols = [], 0
                ranges.append((k, c0, c1 + depth - 1))
                cols += c1 - c0
        if ranges:
            pieces.append(Piece(len(pieces), info.path, tuple(ranges)))
    return pieces


def plan_stat_pieces(infos: Sequence[FileInfo], chunk_samples: int) -> list[Piece]:
    """Pieces of the statistics pass: every sample of every trajectory of the used files once
    (short trajectories included, as in the serial fit's statistics), no overlap."""
    pieces: list[Piece] = []
    for info in infos:
        for k, T in enumerate(info.lengths):
            for a in range(0, T, chunk_samples):
                pieces.append(Piece(len(pieces), info.path, ((k, a, min(a + chunk_samples, T)),)))
    return pieces


# ----------------------------------------------------------------------------- map and reduce
def piece_stats(shared: Any, piece: Piece) -> np.ndarray:
    """Statistics task: (4, m+p) rows count, mean, sum of squared deviations from the mean, sum of squares."""
    with zipfile.ZipFile(piece.path) as z:
        k, a, b = piece.ranges[0]
        w = np.hstack([_read_rows(z, f"u_{k}.npy", a, b), _read_rows(z, f"y_{k}.npy", a, b)])
    mean = w.sum(axis=0) / w.shape[0]
    return np.vstack([np.full(w.shape[1], float(w.shape[0])), mean, ((w - mean) ** 2).sum(axis=0), (w**2).sum(axis=0)])


def combine_stats(parts: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Per-channel (RMS, std) over all pieces from their (count, mean, M2, sum of squares), in order
    (pairwise update: no cancellation of a small std on a large offset, as in the two-pass serial)."""
    n, mean, m2, sq = parts[0].copy()
    for nb, mb, m2b, sqb in parts[1:]:
        tot = n + nb
        delta = mb - mean
        mean = mean + delta * (nb / tot)
        m2 = m2 + m2b + delta**2 * (n * nb / tot)
        sq, n = sq + sqb, tot
    return np.sqrt(sq / n), np.sqrt(m2 / n)


def piece_r_factor(shared: tuple[FitLayout, np.ndarray, int], piece: Piece) -> tuple[np.ndarray, int, float]:
    """Map task: (R factor of the piece's scaled Hankel rows, its columns, this process's peak RSS in MiB)."""
    from threadpoolctl import threadpool_limits

    layout, scale, block = shared
    # One BLAS thread, as a Ray task has one CPU: the serial path then measures the same work, and
    # threaded BLAS on (block x ~10^2) QRs only adds contention on a loaded machine.
    with threadpool_limits(1), zipfile.ZipFile(piece.path) as z:
        trajs = ((_read_rows(z, f"u_{k}.npy", a, b), _read_rows(z, f"y_{k}.npy", a, b)) for k, a, b in piece.ranges)
        R = hankel_r_factor(trajs, layout, scale, block)
    cols = sum(b - a - layout.depth + 1 for _, a, b in piece.ranges)
    return R, cols, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # Linux: KiB


class _TreeReducer:
    """Binary-counter reduction in piece order: factors arrive in any order, are combined as soon as
    their prefix is complete, pairwise by level (the same tree for any arrival order)."""

    def __init__(self) -> None:
        self.waiting: dict[int, np.ndarray] = {}
        self.stack: list[tuple[int, np.ndarray]] = []  # (level, R)
        self.next = 0

    def add(self, index: int, R: np.ndarray) -> None:
        self.waiting[index] = R
        while self.next in self.waiting:
            self.stack.append((0, self.waiting.pop(self.next)))
            self.next += 1
            while len(self.stack) > 1 and self.stack[-1][0] == self.stack[-2][0]:
                (lv, b), (_, a) = self.stack.pop(), self.stack.pop()
                self.stack.append((lv + 1, stack_r_factors(a, b)))

    def result(self) -> np.ndarray:
        if self.waiting or not self.stack:
            raise DataError("internal: the reduction is missing pieces")
        R = self.stack[-1][1]
        for _, a in reversed(self.stack[:-1]):
            R = stack_r_factors(a, R)
        return R


def fit_files(paths: Sequence[str | Path], t_ini: int, t_f: int, method: str = "pem", *, slack_weight: float = 1.0,
              ridge: float = 0.0, rcond: float = 1e-10, workers: int = 1, address: str | None = None,
              chunk_columns: int = 2**18, block_columns: int = 8192, check_excitation: bool = True,
              log=lambda msg: None) -> FleetFit:
    """Fit one predictor from the Hankel columns of every trajectory of every file (see the module doc).

    Args:
        paths: IODataset ``.npz`` files (same channels and dt).
        t_ini, t_f, method, slack_weight, ridge, rcond, block_columns, check_excitation: as in
            :func:`~ddpc_codegen.design.predictor.fit_predictor`.
        workers, address: the engine (:func:`ddpc_codegen.cluster.engine`; 1 = serial in this process).
        chunk_columns: Hankel columns per map task at most (bounds a task's memory).
        log: progress messages (skipped files, timings).
    """
    for name, v in (("chunk_columns", chunk_columns), ("block_columns", block_columns)):
        if isinstance(v, bool) or not isinstance(v, int) or v < 1:
            raise ConfigError(f"{name} must be a positive integer; got {v!r}")
    t0 = time.perf_counter()
    layout = FitLayout(0, 0, int(t_ini), int(t_f), method)  # m, p from the files
    infos, skipped = scan_files(paths, layout.depth)
    for path, why in skipped:
        log(f"  skipped {path}: {why}")
    if not infos:
        raise DataError(f"none of the {len(paths)} files has a trajectory of Tini+Tf = {layout.depth} samples")
    ref = infos[0]
    layout = FitLayout(ref.m, ref.p, layout.t_ini, layout.t_f, method)
    pieces = plan_pieces(infos, layout.depth, int(chunk_columns))
    t_plan = time.perf_counter() - t0
    from threadpoolctl import threadpool_limits

    red, cols, peak = _TreeReducer(), 0, 0.0
    names = ref.input_names + ref.output_names
    # The driver's QRs of stacked factors are small too: one BLAS thread (threaded, each took ~0.4 s
    # instead of ~10 ms on this loaded machine).
    with engine(workers, address, quiet=True) as eng, threadpool_limits(1):
        t1 = time.perf_counter()
        stats = dict(eng.imap_unordered(piece_stats, plan_stat_pieces(infos, int(chunk_columns))))
        rms, std = combine_stats([stats[i] for i in range(len(stats))])
        scale, _ = channel_scale(rms, std, names)
        t_stats = time.perf_counter() - t1
        for i, (R, c, mib) in eng.imap_unordered(piece_r_factor, pieces, shared=(layout, scale, int(block_columns))):
            red.add(i, R)
            cols, peak = cols + c, max(peak, mib)
        n_workers = eng.workers
        t_map = time.perf_counter() - t1 - t_stats
        pred = predictor_from_r(red.result(), layout, cols, rms, std, ref.dt, ref.input_names, ref.output_names,
                                slack_weight=slack_weight, ridge=ridge, rcond=rcond,
                                check_excitation=check_excitation)
    if n_workers == 1:  # the map ran in this process: its peak is the driver's
        peak = max(peak, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)
    fit = FleetFit(pred, len(paths), len(infos), skipped, len(pieces), sum(sum(i.lengths) for i in infos), cols,
                   n_workers, time.perf_counter() - t0, peak,
                   {"scan_s": round(t_plan, 3), "stats_s": round(t_stats, 3), "map_reduce_s": round(t_map, 3)})
    log(f"  fit: {fit.summary()}")
    return fit
