"""Input/output datasets of a closed loop, and PRBS excitation signals.

Signals are time-major: ``u.shape == (T, m)``, ``y.shape == (T, p)``. A dataset holds one or
more trajectories (flights, hops); they are never concatenated into one signal, because a
Hankel matrix across the seam would invent a transition that never happened.
"""

from __future__ import annotations

import json
import zipfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ddpc_codegen.errors import DataError
from ddpc_codegen.values.files import checked_input_path, parse_json

__all__ = ["IODataset", "prbs", "output_noise", "output_path", "checked_entry", "checked_json_entry", "MAX_ARRAY_BYTES",
           "MAX_HEADER_BYTES"]


def _as_signal(x: Any, what: str, index: int) -> np.ndarray:
    a = np.asarray(x, dtype=float)
    if a.ndim == 1:
        a = a[:, None]
    if a.ndim != 2:
        raise DataError(
            f"{what} of trajectory {index} must be a 2-D time-major array (T, channels); "
            f"got shape {a.shape}"
        )
    if a.shape[0] == 0:
        raise DataError(f"{what} of trajectory {index} is empty (0 samples)")
    bad = ~np.isfinite(a)
    if bad.any():
        t, c = np.argwhere(bad)[0]
        raise DataError(
            f"{what} of trajectory {index} has {int(bad.sum())} non-finite value(s) "
            f"(first at sample {t}, channel {c}: {a[t, c]}); clean or drop them before building a dataset"
        )
    return a


def _names(names: Sequence[str] | None, n: int, prefix: str, what: str) -> tuple[str, ...]:
    if names is None:
        return tuple(f"{prefix}{i}" for i in range(n))
    names = tuple(str(s) for s in names)
    if len(names) != n:
        raise DataError(f"{what} has {len(names)} entries {list(names)} but the data has {n} channels")
    return names


@dataclass(frozen=True, eq=False)
class IODataset:
    """One or more input/output trajectories of a closed loop, sampled every ``dt`` seconds.

    Args:
        u: input array (T, m) or a list of them, one per trajectory (the references sent).
        y: output array (T, p) or a list of them (what the robot really did).
        dt: sample time in seconds.
        input_names / output_names: channel names (default u0.., y0..).
        input_units / output_units: unit strings per channel (default "").
        phases: optional integer label array (T,) per trajectory (e.g. hopping phases).
        metadata: free JSON-serialisable provenance (source file, topics, time ranges...).
    """

    u: tuple[np.ndarray, ...]
    y: tuple[np.ndarray, ...]
    dt: float
    input_names: tuple[str, ...] = ()
    output_names: tuple[str, ...] = ()
    input_units: tuple[str, ...] = ()
    output_units: tuple[str, ...] = ()
    phases: tuple[np.ndarray, ...] | None = None
    metadata: dict = field(default_factory=dict)

    def __init__(
        self,
        u: np.ndarray | Sequence[np.ndarray],
        y: np.ndarray | Sequence[np.ndarray],
        dt: float,
        *,
        input_names: Sequence[str] | None = None,
        output_names: Sequence[str] | None = None,
        input_units: Sequence[str] | None = None,
        output_units: Sequence[str] | None = None,
        phases: np.ndarray | Sequence[np.ndarray] | None = None,
        metadata: dict | None = None,
    ) -> None:
        us = [u] if isinstance(u, np.ndarray) else list(u)
        ys = [y] if isinstance(y, np.ndarray) else list(y)
        if len(us) == 0:
            raise DataError("a dataset needs at least one trajectory; got none")
        if len(us) != len(ys):
            raise DataError(f"got {len(us)} input trajectories but {len(ys)} output trajectories")
        us = [_as_signal(a, "u", i) for i, a in enumerate(us)]
        ys = [_as_signal(a, "y", i) for i, a in enumerate(ys)]
        m, p = us[0].shape[1], ys[0].shape[1]
        for i, (a, b) in enumerate(zip(us, ys)):
            if a.shape[0] != b.shape[0]:
                raise DataError(
                    f"trajectory {i}: u has {a.shape[0]} samples but y has {b.shape[0]}; "
                    "inputs and outputs must be sampled on the same grid"
                )
            if a.shape[1] != m or b.shape[1] != p:
                raise DataError(
                    f"trajectory {i} has m={a.shape[1]}, p={b.shape[1]} but trajectory 0 has m={m}, p={p}"
                )
        try:
            dt = float(dt)
        except (TypeError, ValueError):
            raise DataError(f"dt must be a positive number of seconds; got {dt!r}") from None
        if not np.isfinite(dt) or dt <= 0:
            raise DataError(f"dt must be a positive number of seconds; got {dt}")
        ph = None
        if phases is not None:
            phl = [phases] if isinstance(phases, np.ndarray) else list(phases)
            if len(phl) != len(us):
                raise DataError(f"got {len(phl)} phase arrays for {len(us)} trajectories")
            ph = []
            for i, (lab, a) in enumerate(zip(phl, us)):
                lab = np.asarray(lab).astype(np.int8).reshape(-1)
                if lab.shape[0] != a.shape[0]:
                    raise DataError(f"trajectory {i}: {lab.shape[0]} phase labels for {a.shape[0]} samples")
                ph.append(lab)
            ph = tuple(ph)
        for a in us + ys:
            a.setflags(write=False)
        object.__setattr__(self, "u", tuple(us))
        object.__setattr__(self, "y", tuple(ys))
        object.__setattr__(self, "dt", dt)
        object.__setattr__(self, "input_names", _names(input_names, m, "u", "input_names"))
        object.__setattr__(self, "output_names", _names(output_names, p, "y", "output_names"))
        object.__setattr__(
            self, "input_units", _names(input_units, m, "", "input_units") if input_units else ("",) * m
        )
        object.__setattr__(
            self, "output_units", _names(output_units, p, "", "output_units") if output_units else ("",) * p
        )
        object.__setattr__(self, "phases", ph)
        object.__setattr__(self, "metadata", dict(metadata or {}))

    # ------------------------------------------------------------------ shape facts
    @property
    def m(self) -> int:
        """Number of input channels."""
        return self.u[0].shape[1]

    @property
    def p(self) -> int:
        """Number of output channels."""
        return self.y[0].shape[1]

    @property
    def n_trajectories(self) -> int:
        return len(self.u)

    @property
    def lengths(self) -> tuple[int, ...]:
        """Samples per trajectory."""
        return tuple(a.shape[0] for a in self.u)

    @property
    def n_samples(self) -> int:
        """Total samples over all trajectories."""
        return int(sum(self.lengths))

    def __repr__(self) -> str:
        return (
            f"IODataset(m={self.m} {list(self.input_names)}, p={self.p} {list(self.output_names)}, "
            f"trajectories={self.n_trajectories}, samples={self.n_samples}, dt={self.dt})"
        )

    def trajectories(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """List of (u (T_i, m), y (T_i, p)) pairs."""
        return list(zip(self.u, self.y))

    def columns(self, depth: int) -> int:
        """Number of Hankel columns of the given depth over all trajectories (mosaic)."""
        return int(sum(max(0, T - depth + 1) for T in self.lengths))

    def select(self, indices: Sequence[int]) -> "IODataset":
        """A dataset with only the given trajectories."""
        idx = list(indices)
        return IODataset(
            [self.u[i] for i in idx],
            [self.y[i] for i in idx],
            self.dt,
            input_names=self.input_names,
            output_names=self.output_names,
            input_units=self.input_units,
            output_units=self.output_units,
            phases=None if self.phases is None else [self.phases[i] for i in idx],
            metadata=self.metadata,
        )

    # ------------------------------------------------------------------ persistence
    def save(self, path: str | Path, *, overwrite: bool = True) -> Path:
        """Write the dataset as a compressed ``.npz`` (arrays + JSON metadata); returns the path written
        (``.npz`` appended when missing).

        Raises:
            DataError: ``path`` is a folder, or the file exists and ``overwrite`` is False (what a user
                recorded is never replaced unasked).
        """
        path = output_path(path, overwrite)
        path.parent.mkdir(parents=True, exist_ok=True)
        arrays: dict[str, np.ndarray] = {}
        for i, (a, b) in enumerate(zip(self.u, self.y)):
            arrays[f"u_{i}"] = a
            arrays[f"y_{i}"] = b
            if self.phases is not None:
                arrays[f"phase_{i}"] = self.phases[i]
        header = {
            "format": "ddpc-iodataset",
            "version": 1,
            "n_trajectories": self.n_trajectories,
            "dt": self.dt,
            "input_names": list(self.input_names),
            "output_names": list(self.output_names),
            "input_units": list(self.input_units),
            "output_units": list(self.output_units),
            "has_phases": self.phases is not None,
            "metadata": self.metadata,
        }
        arrays["header"] = np.frombuffer(json.dumps(header, sort_keys=True).encode(), dtype=np.uint8)
        np.savez_compressed(path, **arrays)
        return path

    @classmethod
    def load(cls, path: str | Path) -> "IODataset":
        """Read a dataset written by :meth:`save` (or by the MAVLink bridge's tick log).

        Any damaged or foreign file (truncated, bit-flipped, empty, not an IODataset, missing or
        malformed entries) is a DataError naming the file, never a traceback from zipfile or zlib.
        """
        path = Path(path)
        if not path.exists():
            raise DataError(f"dataset file {path} does not exist")
        checked_input_path(path, "dataset", error=DataError)  # a FIFO or a device is never opened
        try:
            header, u, y, ph = _read_npz(path)
            return cls(u, y, header["dt"], input_names=header["input_names"], output_names=header["output_names"],
                       input_units=header["input_units"], output_units=header["output_units"], phases=ph,
                       metadata=header.get("metadata", {}))
        except DataError as e:
            msg = str(e)  # a header refused by parse_json names the file already
            raise DataError(msg if msg.startswith(f"{path}: ") else f"dataset {path}: {msg}") from e
        except (OSError, EOFError, ValueError, KeyError, TypeError, AttributeError, RecursionError,
                zipfile.BadZipFile, zlib.error) as e:
            # damaged: BadZipFile / zlib.error / EOFError; foreign: KeyError / TypeError / AttributeError
            raise DataError(f"dataset {path} is damaged or not an IODataset file ({type(e).__name__}: {e}); "
                            "record or export it again") from e


_HEADER_KEYS = ("n_trajectories", "dt", "input_names", "output_names", "input_units", "output_units")
# Per stored array, checked on its declared shape before a byte is decompressed: 2 GiB is ~10^8 samples
# of a 2-channel signal (a week at 200 Hz); a larger declaration is a damaged or hostile file.
MAX_ARRAY_BYTES = 2**31
MAX_HEADER_BYTES = 2**24  # the JSON header (names, units, metadata)


def output_path(path: str | Path, overwrite: bool = False) -> Path:
    """The ``.npz`` file a dataset is written to, refused when it is a folder or (unless ``overwrite``)
    an existing file."""
    given = Path(path)
    if given.is_dir():
        raise DataError(f"{given} is a folder; give the dataset file to write, e.g. {given / 'data.npz'}")
    out = given if given.suffix == ".npz" else given.with_name(given.name + ".npz")
    if out.is_dir():
        raise DataError(f"{out} is a folder; give the dataset file to write, e.g. {out / 'data.npz'}")
    if out.exists() and not overwrite:
        raise DataError(f"{out} exists; pass --overwrite to replace it, or choose another file")
    return out


def checked_entry(z: Any, key: str, limit: int = MAX_ARRAY_BYTES) -> np.ndarray:
    """Entry ``key`` of an open npz, read only after its declared shape and dtype were checked against
    the bytes it stores and ``limit`` (a huge declared shape would exhaust memory before any other check)."""
    info = z.zip.getinfo(f"{key}.npy")
    with z.zip.open(info) as f:
        major, _ = np.lib.format.read_magic(f)
        read = np.lib.format.read_array_header_1_0 if major == 1 else np.lib.format.read_array_header_2_0
        shape, _, dtype = read(f, max_header_size=10000)
        stored = info.file_size - f.tell()
    if dtype.hasobject or dtype.kind not in "biuf":
        raise DataError(f"entry {key!r} has dtype {dtype}; only numbers are read")
    declared = int(np.prod(shape, dtype=object)) * dtype.itemsize
    if declared > limit:
        raise DataError(f"entry {key!r} declares shape {tuple(shape)} ({declared / 2**20:.0f} MiB), more than the "
                        f"{limit / 2**20:.0f} MiB allowed")
    if declared != stored:
        raise DataError(f"entry {key!r} declares shape {tuple(shape)} of {dtype} ({declared} bytes) but stores "
                        f"{stored} bytes")
    return z[key]


def checked_json_entry(z: Any, key: str, src: str | Path, what: str, limit: int = MAX_HEADER_BYTES) -> Any:
    """The JSON text stored as uint8 entry ``key`` of an open npz (a header), read after its declared size was
    checked against ``limit`` and parsed with its nesting and integers bounded (DataError naming ``src``)."""
    return parse_json(bytes(checked_entry(z, key, limit)), str(src), what, error=DataError)


def _read_npz(path: Path) -> tuple[dict, list[np.ndarray], list[np.ndarray], list[np.ndarray] | None]:
    """(header, u trajectories, y trajectories, phases or None) of an IODataset .npz; raises on anything else."""
    with np.load(path, allow_pickle=False) as z:
        if "header" not in z.files:
            raise DataError(f"not an IODataset file (no 'header' entry; entries: {sorted(z.files)[:8]})")
        header = checked_json_entry(z, "header", path, "dataset header")
        if not isinstance(header, dict) or header.get("format") != "ddpc-iodataset":
            raise DataError("not an IODataset file (its header is not a ddpc-iodataset header)")
        missing = [k for k in _HEADER_KEYS if k not in header]
        if missing:
            raise DataError(f"header lacks {missing}")
        n = header["n_trajectories"]
        if isinstance(n, bool) or not isinstance(n, int) or n < 1:
            raise DataError(f"header n_trajectories must be a positive integer; got {n!r}")
        if n > len(z.files):
            raise DataError(f"header n_trajectories = {n} but the file holds {len(z.files)} entries")
        absent = [k for i in range(n) for k in (f"u_{i}", f"y_{i}") if k not in z.files]
        if absent:
            raise DataError(f"entries {absent[:6]} are missing")
        u = [checked_entry(z, f"u_{i}") for i in range(n)]
        y = [checked_entry(z, f"y_{i}") for i in range(n)]
        ph = [checked_entry(z, f"phase_{i}") for i in range(n)] if header.get("has_phases") else None
    return header, u, y, ph


def prbs(
    n_samples: int,
    channels: int = 1,
    *,
    amplitude: float | Sequence[float] = 1.0,
    min_hold: int = 1,
    order: int | None = None,
    seed: int = 0,
) -> np.ndarray:
    """Maximal-length pseudo-random binary sequence(s), values ``±amplitude``.

    Each channel is a maximal-length LFSR sequence (``scipy.signal.max_len_seq``) of the given
    ``order`` (period 2**order - 1 bits)
    started from its own seeded nonzero state, each bit held for ``min_hold`` samples.

    Returns:
        array (n_samples, channels).
    """
    if int(n_samples) <= 0:
        raise DataError(f"prbs needs n_samples > 0; got {n_samples}")
    if int(channels) <= 0:
        raise DataError(f"prbs needs channels >= 1; got {channels}")
    if int(min_hold) < 1:
        raise DataError(f"prbs min_hold must be >= 1 sample; got {min_hold}")
    n_samples, channels, min_hold = int(n_samples), int(channels), int(min_hold)
    n_bits = -(-n_samples // min_hold)
    if order is None:
        order = max(7, min(24, int(np.ceil(np.log2(n_bits + 1)))))
    if not 3 <= int(order) <= 24:
        raise DataError(f"prbs order must be in 3..24; got {order}")
    # Imported here: scipy.signal costs ~0.6 s at start-up, and the bridge reads and writes datasets
    # through this module without ever making a PRBS.
    from scipy.signal import max_len_seq

    amp = np.broadcast_to(np.asarray(amplitude, dtype=float), (channels,))
    rng = np.random.default_rng(seed)
    out = np.empty((n_samples, channels))
    for c in range(channels):
        # Different nonzero start states give shifted copies of the m-sequence; a random
        # shift per channel keeps channels nearly uncorrelated.
        state = rng.integers(0, 2, int(order))
        if not state.any():
            state[0] = 1
        bits, _ = max_len_seq(int(order), state=state, length=n_bits)
        out[:, c] = np.repeat(2.0 * bits - 1.0, min_hold)[:n_samples] * amp[c]
    return out


def output_noise(dataset: IODataset) -> np.ndarray:
    """White measurement noise on each output, estimated from the recording: sigma (p,), output units.

    The third difference of a smooth motion sampled at 200 Hz is jerk * dt^3 (micrometres); that of
    white noise of standard deviation sigma has variance 20 sigma^2. A robust scale (1.4826 x median
    absolute deviation) of the third differences over every trajectory, divided by sqrt(20), so the
    few samples around a foot impact or an input step do not count. NaN when no trajectory has 4 samples.
    """
    d = [np.diff(y, n=3, axis=0) for _, y in dataset.trajectories() if y.shape[0] >= 4]
    if not d:
        return np.full(dataset.p, np.nan)
    a = np.vstack(d)
    mad = np.median(np.abs(a - np.median(a, axis=0)), axis=0)
    return 1.4826 * mad / np.sqrt(20.0)
