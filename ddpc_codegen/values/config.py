"""Steering configuration: horizons, weights, bounds, predictor and codegen options.

Loaded from TOML and validated on load; every message names the offending key and value.
See ``configs/flying.toml`` for an annotated example.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ddpc_codegen.values.adapt import AdaptSettings, adapt_settings
from ddpc_codegen.values.config_values import (channel_bounds, incremental_problem, is_number, knot_positions,
                                               weight_matrix)
from ddpc_codegen.values.files import load_toml_bounded
from ddpc_codegen.values.tomlconfig import config_error as _err

__all__ = ["SteeringConfig", "R_MODES", "BACKENDS"]

R_MODES = ("absolute", "offset", "increment")
BACKENDS = ("daqp", "osqp")
_PREDICTOR_METHODS = ("pem", "lsq")
_PREDICTOR_FORMS = ("absolute", "incremental")

# section -> allowed keys (unknown keys are errors: a typo must not silently fall back to a default)
_SCHEMA: dict[str, tuple[str, ...]] = {
    "": ("name", "horizon", "signals", "cost", "bounds", "predictor", "codegen", "artificial_io", "data", "adapt"),
    "horizon": ("t_ini", "t_f", "dt", "knots"),
    "signals": ("inputs", "outputs", "input_units", "output_units"),
    "cost": ("Q", "R", "R_mode", "R_du", "R_doffset", "R_ddu", "R_de", "lambda_sigma"),
    "bounds": ("u_min", "u_max", "y_min", "y_max", "du_max"),
    "predictor": ("method", "form", "slack_weight", "ridge", "rcond"),
    "codegen": ("backend", "max_iter", "eps", "rho", "march_native"),
    "artificial_io": ("t_d", "t_a", "t_d_online", "min_ascent", "ground_margin", "noise_level", "noise_level_online",
                      "denoise_online", "refit_residual"),
    "data": ("dataset", "max_output_noise"),
    "adapt": ("enabled", "forgetting", "period_ticks", "dither", "max_change", "window", "min_excitation",
              "min_improvement", "max_gain_change", "offset", "max_offset"),
}
# Sizes a steering problem can have (a 10 s preview at 200 Hz; a Gram matrix of 8000^2 doubles = 512 MB).
MAX_HORIZON = 2000
MAX_CHANNELS = 32
MAX_HANKEL_ROWS = 8000
# [artificial_io] (hopping): integer keys and their smallest allowed value; the rest are sigmas >= 0.
_ART_INT_MIN = {"t_d": 1, "t_a": 1, "t_d_online": 0, "min_ascent": 1, "ground_margin": 0}


@dataclass(frozen=True, eq=False)
class SteeringConfig:
    """Validated steering configuration.

    Shapes: Q (p, p), R (m, m) per time step (expanded block-diagonally over Tf);
    u_min/u_max/du_max (m,), y_min/y_max (p,) in the signals' units (±inf = unbounded).
    ``R_mode``: ``absolute`` penalises ||u||_R (the paper), ``offset`` ||u - u_nom||_R,
    ``increment`` ||Δu||_R with Δu_0 = u_0 - u_ini[-1]. ``R_du`` (m, m; default 0) adds a rate
    penalty ||Δu||_R_du on top of any mode, e.g. a smooth *and* small steering offset. ``R_doffset`` (m, m;
    default 0; R_mode ``offset`` only) penalizes the changes of the steering offset ||Δ(u - u_nom)||_R_doffset
    instead: the references follow the nominal ones' own ramps for free (the first change against the last
    applied input and the nominal's first increment extrapolated one step back). ``R_ddu`` (m, m;
    default 0) penalizes the second differences ||Δ²u||_R_ddu (Δ²u_0 = u_0 - 2 u_ini[-1] + u_ini[-2]): ramps
    without kinks, which a cascaded position loop turns into thrust steps; needs t_ini >= 2. ``R_de`` (m, m; default
    0) penalizes the changes of the tracking error e = u_i - y_i (input i against output i; needs m <= p; the first
    change against u_ini[-1] - y_ini[-1]): what a PD tracking loop turns into command steps.
    ``knots`` (None: every sample is free) parameterizes the references over the horizon by their
    values at these sample indices, linear in between (``design.blocking``); a count is resolved to
    indices on load.
    """

    t_ini: int
    t_f: int
    m: int
    p: int
    Q: np.ndarray
    R: np.ndarray
    lambda_sigma: float = 1e3
    R_mode: str = "offset"
    R_du: np.ndarray | None = None
    R_doffset: np.ndarray | None = None
    R_ddu: np.ndarray | None = None
    R_de: np.ndarray | None = None
    u_min: np.ndarray | None = None
    u_max: np.ndarray | None = None
    y_min: np.ndarray | None = None
    y_max: np.ndarray | None = None
    du_max: np.ndarray | None = None
    dt: float = 0.005
    knots: tuple[int, ...] | None = None
    name: str = "steering"
    input_names: tuple[str, ...] = ()
    output_names: tuple[str, ...] = ()
    input_units: tuple[str, ...] = ()
    output_units: tuple[str, ...] = ()
    predictor: dict = field(default_factory=dict)
    codegen: dict = field(default_factory=dict)
    artificial_io: dict = field(default_factory=dict)
    dataset: str | None = None
    max_output_noise: np.ndarray | None = None
    adapt: AdaptSettings | dict | None = None  # [adapt] table -> AdaptSettings (online predictor updates; disabled by default)
    source: str = "<config>"

    def _set(self, key: str, value) -> None:
        object.__setattr__(self, key, value)  # a frozen dataclass normalises its fields once, on validation

    def __post_init__(self) -> None:
        src = self.source
        set_ = self._set
        for key in ("t_ini", "t_f", "m", "p"):
            v = getattr(self, key)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise _err(src, key, f"must be a positive integer; got {v!r}")
            set_(key, int(v))
        self._check_sizes()
        self._validate_cost()
        self._validate_bounds()
        self._validate_horizon()
        self._check_signals()
        self._validate_predictor()
        self._validate_codegen()
        self._validate_extras()

    def _validate_cost(self) -> None:
        """[cost]: the weights as matrices of the right size, the penalties their options need."""
        src = self.source
        set_ = self._set
        m, p = self.m, self.p
        set_("Q", weight_matrix(self.Q, p, "[cost] Q", src))
        set_("R", weight_matrix(self.R, m, "[cost] R", src))
        set_("R_du", np.zeros((m, m)) if self.R_du is None else weight_matrix(self.R_du, m, "[cost] R_du", src))
        set_("R_doffset", np.zeros((m, m)) if self.R_doffset is None
             else weight_matrix(self.R_doffset, m, "[cost] R_doffset", src))
        set_("R_ddu", np.zeros((m, m)) if self.R_ddu is None else weight_matrix(self.R_ddu, m, "[cost] R_ddu", src))
        set_("R_de", np.zeros((m, m)) if self.R_de is None else weight_matrix(self.R_de, m, "[cost] R_de", src))
        if np.any(self.R_de) and m > p:
            raise _err(src, "[cost] R_de", f"pairs input i with output i and needs m <= p; m is {m}, p is {p}")
        if np.any(self.R_ddu) and self.t_ini < 2:
            raise _err(src, "[cost] R_ddu", f"needs t_ini >= 2 (the first second difference reads the last two "
                       f"applied inputs); t_ini is {self.t_ini}")
        if self.R_mode not in R_MODES:
            raise _err(src, "[cost] R_mode", f"must be one of {list(R_MODES)}; got {self.R_mode!r}")
        if np.any(self.R_doffset) and self.R_mode != "offset":
            raise _err(src, "[cost] R_doffset", f"penalizes the changes of u - u_nom and needs R_mode = \"offset\" "
                       f"(u_nom is a parameter only there); R_mode is {self.R_mode!r}")
        ls = self.lambda_sigma
        if not is_number(ls) or not np.isfinite(ls) or ls < 0:
            raise _err(src, "[cost] lambda_sigma", f"must be a number >= 0; got {ls!r}")
        set_("lambda_sigma", float(ls))

    def _validate_bounds(self) -> None:
        """[bounds] and [data] max_output_noise: per-channel arrays, lower strictly below upper."""
        src = self.source
        set_ = self._set
        m, p = self.m, self.p
        set_("u_min", channel_bounds(self.u_min, m, "[bounds] u_min", src, -np.inf))
        set_("u_max", channel_bounds(self.u_max, m, "[bounds] u_max", src, np.inf))
        set_("y_min", channel_bounds(self.y_min, p, "[bounds] y_min", src, -np.inf))
        set_("y_max", channel_bounds(self.y_max, p, "[bounds] y_max", src, np.inf))
        set_("du_max", channel_bounds(self.du_max, m, "[bounds] du_max", src, np.inf))
        if self.max_output_noise is not None:
            a = channel_bounds(self.max_output_noise, p, "[data] max_output_noise", src, np.inf)
            if np.any(a < 0):
                raise _err(src, "[data] max_output_noise", f"must be >= 0 per output; got {a.tolist()}")
            set_("max_output_noise", a)
        for lo, hi in (("u_min", "u_max"), ("y_min", "y_max")):
            # Equal bounds are refused too: a box without interior is an equality the QP cannot meet soundly.
            bad = np.nonzero(getattr(self, lo) >= getattr(self, hi))[0]
            if bad.size:
                i = int(bad[0])
                raise _err(src, f"[bounds] {lo}/{hi}", f"channel {i}: lower {getattr(self, lo)[i]} >= upper "
                           f"{getattr(self, hi)[i]}; the lower bound must be strictly below the upper")
        if np.any(self.du_max <= 0):
            raise _err(src, "[bounds] du_max", f"must be > 0 (per step); got {self.du_max.tolist()}")

    def _validate_horizon(self) -> None:
        """[horizon] dt and knots."""
        src = self.source
        set_ = self._set
        if not (is_number(self.dt) and np.isfinite(self.dt) and self.dt > 0):
            raise _err(src, "[horizon] dt", f"must be a positive number of seconds; got {self.dt!r}")
        set_("dt", float(self.dt))
        if self.knots is not None:
            try:
                set_("knots", knot_positions(self.knots, self.t_f))
            except ValueError as e:
                raise _err(src, "[horizon] knots", str(e)) from None

    def _validate_predictor(self) -> None:
        """[predictor]: method, form and the fit options, with their defaults."""
        src = self.source
        set_ = self._set
        pred = dict(self.predictor)
        pred.setdefault("method", "pem")
        if pred["method"] not in _PREDICTOR_METHODS:
            raise _err(src, "[predictor] method", f"must be one of {list(_PREDICTOR_METHODS)}; got {pred['method']!r}")
        pred.setdefault("form", "absolute")
        if pred["form"] not in _PREDICTOR_FORMS:
            raise _err(src, "[predictor] form", f"must be one of {list(_PREDICTOR_FORMS)}; got {pred['form']!r}")
        if pred["form"] == "incremental":
            why = incremental_problem(pred["method"], self.t_ini)
            if why:
                raise _err(src, "[predictor] form", f"\"incremental\" {why}")
        for k, lo in (("slack_weight", 0.0), ("ridge", -1e-300), ("rcond", 0.0)):
            if k in pred and not (is_number(pred[k]) and np.isfinite(pred[k]) and pred[k] > lo):
                what = "a number >= 0" if k == "ridge" else "a positive number"
                raise _err(src, f"[predictor] {k}", f"must be {what}; got {pred[k]!r}")
        set_("predictor", pred)

    def _validate_codegen(self) -> None:
        """[codegen]: the backend and its solver options, with the default backend."""
        src = self.source
        set_ = self._set
        cg = dict(self.codegen)
        cg.setdefault("backend", "daqp")
        if cg["backend"] not in BACKENDS:
            raise _err(src, "[codegen] backend", f"must be one of {list(BACKENDS)}; got {cg['backend']!r}")
        if "max_iter" in cg and not (is_number(cg["max_iter"]) and isinstance(cg["max_iter"], int) and cg["max_iter"] > 0):
            raise _err(src, "[codegen] max_iter", f"must be a positive integer; got {cg['max_iter']!r}")
        if "eps" in cg and not (is_number(cg["eps"]) and 0 < cg["eps"] < 1):
            raise _err(src, "[codegen] eps", f"must be a number in (0, 1); got {cg['eps']!r}")
        if "rho" in cg and not (is_number(cg["rho"]) and np.isfinite(cg["rho"]) and cg["rho"] > 0):
            raise _err(src, "[codegen] rho", f"must be a positive number; got {cg['rho']!r}")
        if "march_native" in cg and not isinstance(cg["march_native"], bool):
            raise _err(src, "[codegen] march_native", f"must be true or false; got {cg['march_native']!r}")
        set_("codegen", cg)

    def _validate_extras(self) -> None:
        """[artificial_io] and [adapt]."""
        src = self.source
        set_ = self._set
        art = dict(self.artificial_io)
        for k, v in art.items():
            if k == "denoise_online":
                if not isinstance(v, bool):
                    raise _err(src, f"[artificial_io] {k}", f"must be true or false; got {v!r}")
            elif k in _ART_INT_MIN:
                if isinstance(v, bool) or not isinstance(v, int) or v < _ART_INT_MIN[k]:
                    raise _err(src, f"[artificial_io] {k}", f"must be an integer >= {_ART_INT_MIN[k]}; got {v!r}")
            elif k in _SCHEMA["artificial_io"]:
                if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v) or v < 0:
                    raise _err(src, f"[artificial_io] {k}", f"must be a number >= 0; got {v!r}")
            else:
                raise _err(src, f"[artificial_io] {k}", f"is not a known key; allowed: {list(_SCHEMA['artificial_io'])}")
        set_("artificial_io", art)
        if not isinstance(self.adapt, (dict, AdaptSettings, type(None))):
            raise _err(src, "[adapt]", f"must be a table; got {self.adapt!r}")
        set_("adapt", self.adapt if isinstance(self.adapt, AdaptSettings) else adapt_settings(self.adapt, src, self.p))

    def _check_sizes(self) -> None:
        """Upper limits, checked before any matrix is formed: the Hankel has (m+p)(Tini+Tf) rows and its
        Gram matrix that many squared (a 5000-step horizon would ask for gigabytes before any other check)."""
        src = self.source
        for key in ("t_ini", "t_f"):
            if getattr(self, key) > MAX_HORIZON:
                raise _err(src, f"[horizon] {key}", f"must be at most {MAX_HORIZON} steps; got {getattr(self, key)}")
        for key, what in (("m", "inputs"), ("p", "outputs")):
            if getattr(self, key) > MAX_CHANNELS:
                raise _err(src, f"[signals] {what}", f"must have at most {MAX_CHANNELS} channels; got {getattr(self, key)}")
        rows = (self.m + self.p) * (self.t_ini + self.t_f)
        if rows > MAX_HANKEL_ROWS:
            raise _err(src, "[horizon] t_ini/t_f", f"give a Hankel of (m+p)*(t_ini+t_f) = {rows} rows, more than "
                       f"{MAX_HANKEL_ROWS}; shorten the horizons (move blocking keeps long previews cheap)")

    def _check_signals(self) -> None:
        """Names and units: lists of strings of the right length, channel names unique; name and dataset strings."""
        src, set_ = self.source, self._set
        m, p = self.m, self.p
        for key, n in (("input_names", m), ("output_names", p), ("input_units", m), ("output_units", p)):
            raw = getattr(self, key)
            raw = () if raw is None else raw
            if not isinstance(raw, (list, tuple)) or not all(isinstance(x, str) for x in raw):
                raise _err(src, f"[signals] {key}", f"must be a list of {n} strings; got {raw!r}")
            v = tuple(raw)
            if v and len(v) != n:
                raise _err(src, f"[signals] {key}", f"must have {n} entries; got {len(v)}: {list(v)}")
            set_(key, v)
        names = self.input_names + self.output_names
        dup = sorted({x for x in names if names.count(x) > 1})
        if dup:
            raise _err(src, "[signals] inputs/outputs", f"channel names must be unique; {dup} appear more than once "
                       f"in inputs {list(self.input_names)} / outputs {list(self.output_names)}")
        if not isinstance(self.name, str) or not self.name:
            raise _err(src, "name", f"must be a non-empty string; got {self.name!r}")
        if self.dataset is not None and not isinstance(self.dataset, str):
            raise _err(src, "[data] dataset", f"must be a path string; got {self.dataset!r}")


    # ------------------------------------------------------------------ loading
    @classmethod
    def from_toml(cls, path: str | Path) -> "SteeringConfig":
        """Load and validate a TOML config; a relative [data] dataset is resolved against its folder."""
        path = Path(path)
        raw = load_toml_bounded(path, "steering config")
        cfg = cls.from_dict(raw, source=str(path))
        if cfg.dataset and not Path(cfg.dataset).is_absolute():
            object.__setattr__(cfg, "dataset", str((path.parent / cfg.dataset).resolve()))
        return cfg

    @classmethod
    def from_dict(cls, raw: dict, source: str = "<config>") -> "SteeringConfig":
        """Validate a nested dict with the TOML layout (sections horizon, signals, cost, ...)."""
        for key in raw:
            if key not in _SCHEMA[""]:
                raise _err(source, repr(key), f"is not a known top-level key; allowed: {list(_SCHEMA[''])}")
        for sec, keys in _SCHEMA.items():
            if not sec or sec == "name":
                continue
            body = raw.get(sec, {})
            if not isinstance(body, dict):
                raise _err(source, f"[{sec}]", f"must be a table; got {body!r}")
            for key in body:
                if key not in keys:
                    raise _err(source, f"[{sec}] {key}", f"is not a known key; allowed: {list(keys)}")
        hz, sg, co, bd = (raw.get(k, {}) for k in ("horizon", "signals", "cost", "bounds"))
        for sec, body, key in (("horizon", hz, "t_ini"), ("horizon", hz, "t_f"), ("signals", sg, "inputs"),
                               ("signals", sg, "outputs"), ("cost", co, "Q"), ("cost", co, "R")):
            if key not in body:
                raise _err(source, f"[{sec}] {key}", "is required but missing")
        for key in ("inputs", "outputs"):
            if not isinstance(sg[key], list) or not sg[key] or not all(isinstance(s, str) for s in sg[key]):
                raise _err(source, f"[signals] {key}", f"must be a non-empty list of channel names; got {sg[key]!r}")
        return cls(
            t_ini=hz["t_ini"],
            t_f=hz["t_f"],
            dt=hz.get("dt", 0.005),
            knots=hz.get("knots"),
            m=len(sg["inputs"]),
            p=len(sg["outputs"]),
            input_names=tuple(sg["inputs"]),
            output_names=tuple(sg["outputs"]),
            input_units=sg.get("input_units", ()),
            output_units=sg.get("output_units", ()),
            Q=co["Q"],
            R=co["R"],
            R_mode=co.get("R_mode", "offset"),
            R_du=co.get("R_du"),
            R_doffset=co.get("R_doffset"),
            R_ddu=co.get("R_ddu"),
            R_de=co.get("R_de"),
            lambda_sigma=co.get("lambda_sigma", 1e3),
            u_min=bd.get("u_min"),
            u_max=bd.get("u_max"),
            y_min=bd.get("y_min"),
            y_max=bd.get("y_max"),
            du_max=bd.get("du_max"),
            name=raw.get("name", Path(source).stem if source != "<config>" else "steering"),
            predictor=raw.get("predictor", {}),
            codegen=raw.get("codegen", {}),
            artificial_io=raw.get("artificial_io", {}),
            dataset=raw.get("data", {}).get("dataset"),
            max_output_noise=raw.get("data", {}).get("max_output_noise"),
            adapt=raw.get("adapt"),
            source=source,
        )

    # ------------------------------------------------------------------ identity
    def to_dict(self) -> dict:
        """JSON-friendly dict of the validated values (infinite bounds as null)."""
        f = lambda a: [None if not np.isfinite(x) else float(x) for x in np.ravel(a)]  # noqa: E731
        return {
            "name": self.name, "t_ini": self.t_ini, "t_f": self.t_f, "m": self.m, "p": self.p,
            "dt": self.dt, "Q": self.Q.tolist(), "R": self.R.tolist(), "R_mode": self.R_mode,
            "lambda_sigma": self.lambda_sigma, "u_min": f(self.u_min), "u_max": f(self.u_max),
            "y_min": f(self.y_min), "y_max": f(self.y_max), "du_max": f(self.du_max),
            "input_names": list(self.input_names), "output_names": list(self.output_names),
            "predictor": {k: v for k, v in self.predictor.items()},
            "codegen": {k: v for k, v in self.codegen.items()},
            # only when used: configs without a rate penalty keep their digest (and their solvers)
            **({"R_du": self.R_du.tolist()} if np.any(self.R_du) else {}),
            **({"R_doffset": self.R_doffset.tolist()} if np.any(self.R_doffset) else {}),
            **({"R_ddu": self.R_ddu.tolist()} if np.any(self.R_ddu) else {}),
            **({"R_de": self.R_de.tolist()} if np.any(self.R_de) else {}),
            **({"knots": list(self.knots)} if self.knots is not None else {}),
            **({"artificial_io": dict(self.artificial_io)} if self.artificial_io else {}),
            **({"adapt": dataclasses.asdict(self.adapt)} if self.adapt.enabled else {}),
        }

    @property
    def digest(self) -> str:
        """SHA-256 of the validated problem-defining values (not of file formatting)."""
        d = self.to_dict()
        d.pop("codegen", None)  # how it is compiled does not change what it solves
        d.pop("adapt", None)  # nor does what may update it in flight (the solver's build identity records it)
        return hashlib.sha256(json.dumps(d, sort_keys=True).encode()).hexdigest()

    def replace(self, **changes: Any) -> "SteeringConfig":
        """A copy with some fields changed (validated again)."""
        d = {k: getattr(self, k) for k in self.__dataclass_fields__}
        d.update(changes)
        return SteeringConfig(**d)
