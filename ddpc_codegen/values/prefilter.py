"""The prefilter model: per-channel static gain, offset and dead time of the closed loop, its inverse and
its JSON file (fitted by :func:`ddpc_codegen.design.baselines.fit_prefilter`, run by
:mod:`ddpc_codegen.runtime.baselines`)."""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from ddpc_codegen.errors import ConfigError
from ddpc_codegen.values.files import load_json_bounded

__all__ = ["PrefilterModel", "load_prefilter_table", "PREFILTER_MAX_BYTES"]

PREFILTER_MAX_BYTES = 1_000_000  # a model is a few hundred bytes (16 channels with names: about 2 kB)


@dataclass(frozen=True)
class PrefilterModel:
    """Per-channel static gain, offset and dead time of the closed loop: y_i[k] = g_i u_i[k - d_i] + c_i.

    Attributes:
        gain: (m,) g [output unit / input unit]; offset: (m,) c [output unit]; lead: (m,) d [ticks].
        dt: tick [s]. names: channel names (inputs). residual_rms: (m,) fit residual [output unit].
        r2: (m,) share of the output variance the fit explains.
    """

    gain: tuple[float, ...]
    offset: tuple[float, ...]
    lead: tuple[int, ...]
    dt: float
    names: tuple[str, ...] = ()
    residual_rms: tuple[float, ...] = ()
    r2: tuple[float, ...] = ()

    @property
    def m(self) -> int:
        return len(self.gain)

    def inverse(self, y_des_ahead: np.ndarray, r_nom: np.ndarray) -> np.ndarray:
        """u (m,) for desired outputs ``y_des_ahead`` (H, p) at ticks k..k+H-1 and the nominal
        reference r_nom (m,): u_i = r_nom_i + (y_des[d_i, i] - c_i) / g_i - y_des[0, i].

        Written as a correction of r_nom so that whatever the controller adds to its reference
        (e.g. the horizontal PD in the pitch reference) is kept; leads beyond the horizon are
        clipped to H - 1."""
        yd = np.atleast_2d(np.asarray(y_des_ahead, dtype=float))
        u = np.array(r_nom, dtype=float, copy=True)
        for i in range(self.m):
            d = min(int(self.lead[i]), yd.shape[0] - 1)
            u[i] += (yd[d, i] - self.offset[i]) / self.gain[i] - yd[0, i]
        return u

    def to_dict(self) -> dict:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, d: dict, src: str = "<dict>") -> "PrefilterModel":
        try:
            m = cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()})
        except TypeError as e:
            raise ConfigError(f"{src}: not a prefilter model ({e})") from None
        if not (len(m.gain) == len(m.offset) == len(m.lead) > 0) or any(g == 0 for g in m.gain):
            raise ConfigError(f"{src}: gain, offset and lead need one nonzero gain per channel; got {d!r}")
        return m

    def save(self, path: str | Path) -> Path:
        """JSON (what the bridge loads with :meth:`load`)."""
        path = Path(path)
        path.write_text(json.dumps({"prefilter": self.to_dict()}, indent=2) + "\n")
        return path

    @classmethod
    def load(cls, path: str | Path) -> "PrefilterModel":
        return cls.from_dict(load_prefilter_table(path), str(path))


def load_prefilter_table(path: str | Path) -> dict:
    """The ``prefilter`` table of a prefilter JSON file (read bounded), its values not yet checked."""
    raw = load_json_bounded(path, "prefilter", PREFILTER_MAX_BYTES)
    if not isinstance(raw, dict) or not isinstance(raw.get("prefilter"), dict):
        raise ConfigError(f"{path}: not a prefilter JSON file (no 'prefilter' table)")
    return raw["prefilter"]
