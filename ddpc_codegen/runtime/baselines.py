"""Baseline reference policies behind the steering policy's per-tick interface.

Each has ``decide(y, r_nom, y_des) -> SteerOutcome`` like :class:`~ddpc_codegen.runtime.policy.SteeringPolicy`
(y (p,) measured outputs, r_nom (m,) the nominal reference of this tick, y_des (H, p) the desired
outputs at ticks k..k+H-1), plus ``reset()``, ``observe()`` and ``horizon`` (the H it needs), so any
loop that runs the steering (the simulator hook, the MAVLink bridge) can run them instead:

* :class:`PassthroughPolicy`: u = r_nom (the model-based controller alone).
* :class:`PrefilterPolicy`: u = r_nom + (y_des[k + d] - c) / g - y_des[k] per channel (a
  :class:`~ddpc_codegen.design.baselines.PrefilterModel` fitted offline); needs H = max lead + 1.
* :class:`FeedforwardPolicy`: u = r_nom + delta[j], a learned table (the ILC's last iteration),
  j = ticks since :meth:`~FeedforwardPolicy.reset` (trajectory time, or time since liftoff when the
  loop resets it at every liftoff), or set by :meth:`~FeedforwardPolicy.seek` from the loop's own
  trajectory clock (the bridge); beyond the table the last row is held.

The loaders (:meth:`PrefilterPolicy.load`, :meth:`FeedforwardPolicy.load`) check what a file can say
about itself -- size before reading, the table's declared shape before loading it, types, finiteness,
ranges -- and raise :class:`~ddpc_codegen.errors.ConfigError` naming the file and the key; what fits
the loop (channels, tick, the robot's envelope) the caller checks (the bridge: :mod:`firmware_bridge.baseline_modes`).

numpy only: no CasADi, no simulator.
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ddpc_codegen.values.prefilter import PrefilterModel, load_prefilter_table
from ddpc_codegen.errors import ConfigError
from ddpc_codegen.robot.validate import Range, check_number, check_numbers
from ddpc_codegen.values.files import checked_input_path
from ddpc_codegen.runtime.steerer import SteerOutcome

__all__ = ["PassthroughPolicy", "PrefilterPolicy", "FeedforwardPolicy", "check_prefilter_dict", "FF_MAX_ROWS",
           "FF_MAX_COLS", "PREFILTER_MAX_LEAD"]


@dataclass
class PassthroughPolicy:
    """u = r_nom: the unsteered controller behind the policy interface."""

    horizon: int = 1
    counts: dict = field(default_factory=dict)

    def reset(self) -> None:
        """Nothing to forget."""

    def observe(self, u_applied: np.ndarray, y: np.ndarray) -> None:
        """A tick the policy did not decide (nothing to record)."""

    def decide(self, y: np.ndarray, r_nom: np.ndarray, y_des: np.ndarray) -> SteerOutcome:
        self.counts["ticks"] = self.counts.get("ticks", 0) + 1
        return SteerOutcome(np.array(r_nom, dtype=float, copy=True), False, "passthrough")

    def summary(self) -> dict:
        return dict(self.counts)


@dataclass
class PrefilterPolicy:
    """Static gain + offset + lead inverse of the closed loop (see :class:`PrefilterModel`).

    Args:
        model: the fitted prefilter.
        u_min, u_max: (m,) limits on the applied reference (clipped; counted in ``counts``).
    """

    model: PrefilterModel
    u_min: np.ndarray | None = None
    u_max: np.ndarray | None = None
    counts: dict = field(default_factory=dict)

    @property
    def horizon(self) -> int:
        """Desired outputs needed ahead: ticks k..k+max(lead)."""
        return int(max(self.model.lead)) + 1

    @classmethod
    def load(cls, path: str | Path, **kw) -> "PrefilterPolicy":
        """From a prefilter JSON file (:meth:`PrefilterModel.save`), every field checked
        (:func:`check_prefilter_dict`)."""
        table = check_prefilter_dict(load_prefilter_table(path), str(path))
        return cls(PrefilterModel.from_dict(table, str(path)), **kw)

    def reset(self) -> None:
        """Memoryless: nothing to forget."""

    def observe(self, u_applied: np.ndarray, y: np.ndarray) -> None:
        """Memoryless: nothing to record."""

    def decide(self, y: np.ndarray, r_nom: np.ndarray, y_des: np.ndarray) -> SteerOutcome:
        u = self.model.inverse(y_des, r_nom)
        reason = "prefilter"
        if self.u_min is not None or self.u_max is not None:
            lo = -np.inf if self.u_min is None else self.u_min
            hi = np.inf if self.u_max is None else self.u_max
            clipped = np.clip(u, lo, hi)
            if np.any(clipped != u):
                reason = "prefilter_clipped"
                u = clipped
        self.counts[reason] = self.counts.get(reason, 0) + 1
        return SteerOutcome(u, True, reason)

    def summary(self) -> dict:
        return dict(self.counts)


@dataclass
class FeedforwardPolicy:
    """A learned feed-forward table on top of the nominal reference (the ILC's output).

    Args:
        delta: (N, m) offsets added to r_nom at ticks 0..N-1 after :meth:`reset` [input units].
        dt: tick [s] (for the record; the table is indexed by ticks).
        clock: "trajectory" (index = ticks since the run started) or "liftoff" (the loop calls
            :meth:`reset` at every liftoff; index = ticks in the air).
    """

    delta: np.ndarray
    dt: float = 0.005
    clock: str = "trajectory"
    counts: dict = field(default_factory=dict)
    horizon: int = 1  # needs only this tick's desired output

    def __post_init__(self) -> None:
        self.delta = np.atleast_2d(np.asarray(self.delta, dtype=float))
        if self.delta.shape[0] == 0 or not np.all(np.isfinite(self.delta)):
            raise ConfigError(f"a feed-forward table needs finite (N >= 1, m) values; got shape {self.delta.shape}")
        if self.clock not in ("trajectory", "liftoff"):
            raise ConfigError(f"clock must be 'trajectory' or 'liftoff'; got {self.clock!r}")
        self._k = 0

    def reset(self) -> None:
        """Restart the table's clock (start of a run, or a liftoff)."""
        self._k = 0

    def observe(self, u_applied: np.ndarray, y: np.ndarray) -> None:
        """A tick the policy did not decide: the clock still advances."""
        self._k += 1

    def seek(self, j: int) -> None:
        """The next :meth:`decide` applies row j (a loop with its own clock: the trajectory tick,
        which a stall or a re-engagement does not restart)."""
        if j < 0:
            raise ValueError(f"a feed-forward table row must be >= 0; got {j}")
        self._k = int(j)

    def decide(self, y: np.ndarray, r_nom: np.ndarray, y_des: np.ndarray) -> SteerOutcome:
        j = min(self._k, self.delta.shape[0] - 1)
        if self._k >= self.delta.shape[0]:
            self.counts["beyond_table"] = self.counts.get("beyond_table", 0) + 1
        self._k += 1
        self.counts["ticks"] = self.counts.get("ticks", 0) + 1
        return SteerOutcome(np.asarray(r_nom, dtype=float) + self.delta[j], True, "feedforward")

    def save(self, path: str | Path) -> Path:
        """npz with delta, dt and clock (what :meth:`load` reads)."""
        path = Path(path)
        np.savez(path, delta=self.delta, dt=self.dt, clock=self.clock)
        return path

    @classmethod
    def load(cls, path: str | Path) -> "FeedforwardPolicy":
        """From a :meth:`save` npz: the arrays' declared shapes are read before any data (a table of
        at most :data:`FF_MAX_ROWS` x :data:`FF_MAX_COLS` numbers, a scalar dt in (0, 1] s, a clock name)."""
        p = checked_input_path(path, "feed-forward table", FF_MAX_BYTES)
        shapes = _npz_shapes(p)
        for key, ok, want in (("delta", lambda s, k: len(s) == 2 and 1 <= s[0] <= FF_MAX_ROWS
                               and 1 <= s[1] <= FF_MAX_COLS and k in "fiu", f"(N, m) numbers with N <= {FF_MAX_ROWS} "
                               f"and m <= {FF_MAX_COLS}"),
                              ("dt", lambda s, k: s == () and k in "fiu", "one number"),
                              ("clock", lambda s, k: s == () and k == "U", "one string")):
            if key not in shapes:
                raise ConfigError(f"{p}: not a feed-forward table (no '{key}' array)")
            if not ok(*shapes[key]):
                raise ConfigError(f"{p}: {key} must be {want}; got shape {shapes[key][0]} of kind {shapes[key][1]!r}")
        try:
            with np.load(p, allow_pickle=False) as z:
                delta, dt, clock = z["delta"].astype(float), z["dt"].item(), str(z["clock"])
        except (OSError, KeyError, ValueError, zipfile.BadZipFile) as e:
            raise ConfigError(f"{p}: not a feed-forward table ({type(e).__name__}: {e})") from None
        dt = check_number(dt, f"{p}: dt", Range(lo=0.0, lo_open=True, hi=1.0))
        if not np.all(np.isfinite(delta)):
            bad = np.argwhere(~np.isfinite(delta))[0]
            raise ConfigError(f"{p}: delta must be finite; row {bad[0]} column {bad[1]} is {float(delta[tuple(bad)])!r}")
        if clock not in ("trajectory", "liftoff"):
            raise ConfigError(f"{p}: clock must be 'trajectory' or 'liftoff'; got {clock!r}")
        return cls(delta, dt, clock)

    def summary(self) -> dict:
        return dict(self.counts)


FF_MAX_BYTES = 64_000_000   # a 10^6-row table of two references is 16 MB
FF_MAX_ROWS = 1_000_000     # 83 min at 200 Hz
FF_MAX_COLS = 16
PREFILTER_MAX_LEAD = 2000   # ticks (10 s at 200 Hz): the desired path is sampled this far ahead every tick
_PREFILTER_KEYS = ("gain", "offset", "lead", "dt", "names", "residual_rms", "r2")


def _npz_shapes(path: Path) -> dict[str, tuple[tuple, str]]:
    """{name: (shape, dtype kind)} of an npz's arrays from their headers alone (no data read)."""
    out = {}
    try:
        with zipfile.ZipFile(path) as zf:
            for info in zf.infolist()[:64]:
                if not info.filename.endswith(".npy"):
                    continue
                with zf.open(info) as f:
                    version = np.lib.format.read_magic(f)
                    read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
                    shape, _, dtype = read(f)
                out[info.filename[:-4]] = (tuple(shape), dtype.kind)
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as e:
        raise ConfigError(f"{path}: not a feed-forward table ({type(e).__name__}: {e})") from None
    return out


def check_prefilter_dict(d: dict, src: str) -> dict:
    """The ``prefilter`` table of a prefilter JSON file: known keys; gain, offset, lead one per channel
    (1..16), gains finite with 1e-3 <= |g| <= 1e3, offsets finite, leads integers in 0..2000 ticks, dt in
    (0, 1] s; names strings; residual_rms / r2 numbers or null (informational). Returns it with tuples.

    Raises:
        ConfigError: naming ``src`` and the key.
    """
    for key in d:
        if key not in _PREFILTER_KEYS:
            raise ConfigError(f"{src}: prefilter {key} is not a known key; allowed: {list(_PREFILTER_KEYS)}")
    for key in ("gain", "offset", "lead", "dt"):
        if key not in d:
            raise ConfigError(f"{src}: prefilter {key} is missing")
    gain = d["gain"]
    if not isinstance(gain, list) or not 1 <= len(gain) <= 16:
        raise ConfigError(f"{src}: prefilter gain must be a list of 1 to 16 numbers; got {gain!r}")
    n = len(gain)
    out = dict(d)
    out["gain"] = check_numbers(gain, f"{src}: prefilter gain", Range(lo=-1e3, hi=1e3, n=n))
    if any(abs(g) < 1e-3 for g in out["gain"]):
        raise ConfigError(f"{src}: prefilter gain must be at least 1e-3 in magnitude per channel; got {gain!r}")
    out["offset"] = check_numbers(d["offset"], f"{src}: prefilter offset", Range(lo=-1e4, hi=1e4, n=n))
    out["lead"] = check_numbers(d["lead"], f"{src}: prefilter lead", Range(lo=0, hi=PREFILTER_MAX_LEAD, integer=True, n=n))
    out["dt"] = check_number(d["dt"], f"{src}: prefilter dt", Range(lo=0.0, lo_open=True, hi=1.0))
    names = d.get("names", [])
    if not isinstance(names, list) or len(names) not in (0, n) or not all(isinstance(v, str) and len(v) <= 64 for v in names):
        raise ConfigError(f"{src}: prefilter names must be {n} strings (or none); got {names!r}")
    out["names"] = tuple(names)
    for key in ("residual_rms", "r2"):
        v = d.get(key, [])
        if not isinstance(v, list) or len(v) not in (0, n) or not all(
                x is None or (isinstance(x, (int, float)) and not isinstance(x, bool)) for x in v):
            raise ConfigError(f"{src}: prefilter {key} must be {n} numbers (or none); got {v!r}")
        out[key] = tuple(v)
    return out
