"""Mutants of the inputs ``ddpc-bridge`` flies on, for the fuzzer: their *dynamics* (speeds, steps, gains, scales,
amplitudes, limits) and their raw bytes, not only their types.

A mutant is a list of ``ddpc-bridge`` flags and the files they name (written into a folder), drawn from one
seed (:func:`make_mutant`: the same seed gives the same mutant, so a failure replays from its seed alone). Its
kind is one of :data:`KINDS`:

* ``profile``: the shipped ``pogox`` profile with numbers of its ``[trajectory]`` (centre, radii, period, spin-up,
  start), ``[envelope]`` (box, speed and acceleration, rate limits) and ``[controller]`` (gains, model, tilt)
  scaled, shifted, negated or set to an edge value;
* ``trajectory``: a path file (CSV) of smooth samples, then time-compressed, scaled, offset, given a step, a
  velocity column or fewer rows;
* ``prefilter``: a prefilter JSON whose gains, offsets and leads are mutated;
* ``feedforward``: a feed-forward table (npz) of sines, steps and noise of mutated amplitude and tick;
* ``excitation``: collect mode's PRBS amplitude and hold;
* ``flags``: thrust limits, blend rates, tilt, take-off ramp, frame, a random path;
* ``hopping``: the ``pogox_hopping`` profile's hop (apex, target velocity, thrust share, stance boost, Raibert and
  velocity gains) and envelope mutated, hopped or collected;
* ``steer`` (given a generated solver): steered flights with the step guard, its hold and injected solver
  failures (failed or NaN solutions) mutated, on a mutated profile or path file now and then.

Any kind may carry a mutated profile as well (a tight envelope is what makes a short flight reach its edges),
and any file may have its bytes flipped, inserted, deleted, duplicated or truncated.
"""

from __future__ import annotations

import copy
import json
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ddpc_codegen.robot.profile import PROFILE_DIR
from ddpc_codegen.testbed.bridge_flights import write_toml

__all__ = ["KINDS", "Mutant", "make_mutant", "mutate_number", "mutate_bytes", "VEHICLE_START_Z"]

KINDS = ("profile", "trajectory", "prefilter", "feedforward", "excitation", "flags", "hopping", "steer")
_KIND_WEIGHTS = (0.3, 0.2, 0.14, 0.14, 0.1, 0.12, 0.08, 0.15)  # steer: only with a solver (the others renormalised)
VEHICLE_START_Z = 0.9  # m: where ddpc-vehicle hovers (the default ellipse's start), heights from the ground
_RATE = 200.0

# [table] keys whose numbers define the flown dynamics (a list: index into it); controller keys less often
_PROFILE_KEYS = [("trajectory", "center", 0), ("trajectory", "center", 1), ("trajectory", "radii", 0),
                 ("trajectory", "radii", 1), ("trajectory", "period", None), ("trajectory", "spin_up", None),
                 ("trajectory", "t_start", None), ("envelope", "z_min", None), ("envelope", "z_max", None),
                 ("envelope", "radius", None), ("envelope", "max_speed", None), ("envelope", "max_accel", None),
                 ("envelope", "ref_rate", 0), ("envelope", "ref_rate", 1), ("envelope", "offset_rate", 0),
                 ("envelope", "offset_rate", 1)]
_CONTROLLER_KEYS = [("controller", k, None) for k in ("kp_z", "kd_z", "kp_xy", "kd_xy", "max_tilt", "model_mass",
                                                      "max_thrust", "ref_velocity_tau")]
_HOP_KEYS = [("controller", "apex_height", None), ("controller", "target_velocity", 0),
             ("controller", "target_velocity", 1), ("controller", "thrust_fraction", None),
             ("controller", "stance_boost", None), ("controller", "raibert_gain", None),
             ("controller", "velocity_integral_gain", None), ("envelope", "z_max", None), ("envelope", "radius", None),
             ("envelope", "max_speed", None), ("envelope", "ref_rate", 0), ("envelope", "ref_rate", 2)]
_HOP_RELEASE_Z = 0.7  # m: where ddpc-vehicle --scenario hopping releases the hopper (the shipped apex)


@dataclass
class Mutant:
    """One mutant: ``args`` (``ddpc-bridge`` flags naming ``files``), its ``kind``, ``seed`` and what was changed."""

    kind: str
    seed: int
    args: list[str]
    changes: list[str] = field(default_factory=list)
    files: list[Path] = field(default_factory=list)

    def as_dict(self) -> dict:
        return {"kind": self.kind, "seed": self.seed, "args": self.args, "changes": self.changes}


def mutate_number(rng: np.random.Generator, v: float) -> float:
    """``v`` scaled (by 1e-3 .. 1e3, or by 0.5 .. 2), shifted, negated, or replaced by an edge value."""
    op = rng.integers(0, 6)
    if op == 0:
        return float(v * 10.0 ** rng.uniform(-3, 3))
    if op == 1:
        return float(v * rng.uniform(0.5, 2.0))
    if op == 2:
        return float(v + rng.normal() * max(abs(v), 0.1) * 10.0 ** rng.uniform(-2, 1))
    if op == 3:
        return float(-v)
    if op == 4:
        return float(rng.choice([0.0, 1e-9, 1e-3, 1.0, 1e3, 1e9, 1e300, -1e-3, -1.0]))
    return float(v * rng.uniform(0.9, 1.1))  # near the original: most of these are accepted


def mutate_bytes(rng: np.random.Generator, data: bytes) -> tuple[bytes, str]:
    """One raw-byte mutation of ``data``: (the bytes, what was done)."""
    b = bytearray(data)
    n = len(b)
    op = int(rng.integers(0, 6))
    i = int(rng.integers(0, max(n, 1)))
    if op == 0 and n:
        b[i] ^= 1 << int(rng.integers(0, 8))
        return bytes(b), f"bit flip at byte {i}"
    if op == 1:
        ins = bytes(rng.choice(list(b"0123456789.-+eE,\n\"[]{}= nanif\x00\xff"), int(rng.integers(1, 6))))
        return bytes(b[:i] + ins + b[i:]), f"{ins!r} inserted at byte {i}"
    if op == 2 and n:
        j = min(n, i + int(rng.integers(1, 16)))
        return bytes(b[:i] + b[j:]), f"bytes {i}..{j} deleted"
    if op == 3 and n:
        j = min(n, i + int(rng.integers(1, 64)))
        return bytes(b[:j] + b[i:j] + b[j:]), f"bytes {i}..{j} duplicated"
    if op == 4 and n:
        return bytes(b[:i]), f"truncated at byte {i}"
    if n:
        digits = [k for k, c in enumerate(b) if chr(c).isdigit()]
        if digits:
            k = int(rng.choice(digits))
            b[k] = ord(str(int(rng.integers(0, 10))))
            return bytes(b), f"digit at byte {k} changed"
    return bytes(b), "unchanged"


def _maybe_bytes(rng: np.random.Generator, path: Path, changes: list[str], p: float = 0.2) -> None:
    if rng.random() < p:
        data, what = mutate_bytes(rng, path.read_bytes())
        path.write_bytes(data)
        changes.append(f"{path.name}: {what}")


def _mutate_keys(rng: np.random.Generator, raw: dict, keys: list, n: int, changes: list[str],
                 base: dict | None = None) -> None:
    """``n`` numbers of ``raw`` (a profile's tables) at ``keys`` ((table, key, index or None)) mutated in place; a
    key ``raw`` does not set starts from ``base`` (the profile it extends)."""
    defaults = {"ref_rate": [30.0, 100.0, 100.0], "offset_rate": [5.0, 5.0, 5.0]}
    for _ in range(n):
        table, key, idx = keys[int(rng.integers(0, len(keys)))]
        t = raw.setdefault(table, {})
        old = t.get(key, (base or {}).get(table, {}).get(key, defaults.get(key)))
        if old is None:
            continue
        if idx is None:
            t[key] = mutate_number(rng, float(old))
        else:
            old = [float(x) for x in old]
            old[idx] = mutate_number(rng, old[idx])
            t[key] = old
        changes.append(f"[{table}] {key} = {t[key]}")


def _profile(rng: np.random.Generator, folder: Path, changes: list[str], n_keys: int | None = None) -> Path:
    """The pogox profile with a few dynamics numbers mutated (the envelope often tightened around the vehicle)."""
    raw = copy.deepcopy(tomllib.loads((PROFILE_DIR / "pogox.toml").read_text()))
    keys = _PROFILE_KEYS + (_CONTROLLER_KEYS if rng.random() < 0.3 else [])
    if rng.random() < 0.5:  # a tight envelope: the short flight reaches its edges
        env = raw["envelope"]
        env["z_min"] = float(max(0.0, VEHICLE_START_Z - rng.uniform(0.2, 0.9)))
        env["z_max"] = float(VEHICLE_START_Z + rng.uniform(0.2, 1.5))
        env["radius"] = float(rng.uniform(0.2, 2.0))
        changes.append(f"envelope z [{env['z_min']:.3g}, {env['z_max']:.3g}] radius {env['radius']:.3g}")
    if rng.random() < 0.6:  # the path starts moving at once
        raw["trajectory"]["t_start"] = float(rng.uniform(0.0, 0.3))
        raw["trajectory"]["spin_up"] = float(rng.uniform(0.01, 0.5))
    _mutate_keys(rng, raw, keys, n_keys if n_keys is not None else int(rng.integers(1, 4)), changes)
    raw["name"] = "fuzzed"
    path = write_toml(raw, folder / "profile.toml")
    _maybe_bytes(rng, path, changes, 0.1)
    return path


def _hopping(rng: np.random.Generator, folder: Path, changes: list[str]) -> list[str]:
    """A ``pogox_hopping`` profile with its hop and envelope mutated (``extends`` the shipped one)."""
    raw: dict = {"extends": "pogox_hopping", "name": "fuzzed_hop"}
    if rng.random() < 0.5:
        raw["envelope"] = {"z_max": float(_HOP_RELEASE_Z + rng.uniform(0.2, 1.0)), "radius": float(rng.uniform(0.3, 2.0))}
        changes.append(f"envelope z_max {raw['envelope']['z_max']:.3g} radius {raw['envelope']['radius']:.3g}")
    base = tomllib.loads((PROFILE_DIR / "pogox_hopping.toml").read_text())
    _mutate_keys(rng, raw, _HOP_KEYS, int(rng.integers(1, 4)), changes, base)
    path = write_toml(raw, folder / "hop.toml")
    _maybe_bytes(rng, path, changes, 0.1)
    return ["--scenario", "hopping", "--controller", str(path), "--mode", str(rng.choice(["passthrough", "collect"]))]


def _trajectory(rng: np.random.Generator, folder: Path, changes: list[str]) -> Path:
    """A smooth path file starting at the vehicle, then its dynamics mutated."""
    dt = float(rng.choice([0.02, 0.05, 0.1, 0.2, 0.5]))
    t = np.arange(0.0, float(rng.uniform(2.0, 8.0)) + 1e-9, dt)
    cols = {"t": t}
    for name, amp in (("x", 0.5), ("y", 0.3), ("z", 0.2)):
        w = rng.uniform(0.2, 1.5, 2)
        a = rng.uniform(0, amp, 2)
        cols[name] = a[0] * np.sin(w[0] * t) + a[1] * (1 - np.cos(w[1] * t))
    cols["z"] = cols["z"] + VEHICLE_START_Z
    for _ in range(int(rng.integers(1, 4))):
        op = int(rng.integers(0, 6))
        if op == 0:
            k = 10.0 ** rng.uniform(-2, 0.5)
            cols["t"] = cols["t"] * k
            changes.append(f"time scaled by {k:.3g}")
        elif op == 1:
            c = str(rng.choice(["x", "y", "z"]))
            k = mutate_number(rng, 1.0)
            cols[c] = (cols[c] - cols[c][0]) * k + cols[c][0]
            changes.append(f"{c} scaled by {k:.3g}")
        elif op == 2:
            c, j = str(rng.choice(["x", "y", "z"])), int(rng.integers(1, len(t)))
            s = float(rng.choice([-1, 1]) * 10.0 ** rng.uniform(-3, 3))
            cols[c] = cols[c].copy()
            cols[c][j:] += s
            changes.append(f"step of {s:.3g} m in {c} at row {j}")
        elif op == 3:
            s = float(rng.normal() * 10.0 ** rng.uniform(-2, 1))
            cols["z"] = cols["z"] + s
            changes.append(f"z offset {s:.3g} m")
        elif op == 4:
            cols["vz"] = rng.normal(size=len(t)) * 10.0 ** rng.uniform(-2, 2)
            changes.append("a vz column")
        else:
            keep = np.sort(rng.choice(len(t), size=max(2, len(t) // int(rng.integers(2, 6))), replace=False))
            cols = {k: v[keep] for k, v in cols.items()}
            t = cols["t"]
            changes.append(f"{len(keep)} rows kept")
    names = list(cols)
    lines = [",".join(names)] + [",".join(f"{cols[n][i]:.6g}" for n in names) for i in range(len(cols["t"]))]
    path = folder / "path.csv"
    path.write_text("\n".join(lines) + "\n")
    _maybe_bytes(rng, path, changes)
    return path


def _prefilter(rng: np.random.Generator, folder: Path, changes: list[str]) -> Path:
    d = {"gain": [0.98, 1.0], "offset": [0.01, 0.0], "lead": [60, 10], "dt": 0.005, "names": ["z_ref", "pitch_ref"]}
    for _ in range(int(rng.integers(1, 4))):
        key, i = str(rng.choice(["gain", "offset", "lead"])), int(rng.integers(0, 2))
        if key == "lead":
            d["lead"][i] = int(rng.choice([0, 1, 5, 50, 200, 1000, 10**6, -1, int(rng.integers(0, 400))]))
        elif key == "gain":
            d["gain"][i] = float(1.0 + rng.normal() * 10.0 ** rng.uniform(-3, 0.5)) if rng.random() < 0.6 \
                else mutate_number(rng, d["gain"][i])
        else:
            d["offset"][i] = float(rng.normal() * 10.0 ** rng.uniform(-3, 1))
        changes.append(f"prefilter {key}[{i}] = {d[key][i]}")
    path = folder / "prefilter.json"
    path.write_text(json.dumps({"prefilter": d}))
    _maybe_bytes(rng, path, changes)
    return path


def _feedforward(rng: np.random.Generator, folder: Path, changes: list[str]) -> Path:
    n = int(rng.integers(20, 2000))
    k = np.arange(n)[:, None]
    amp = 10.0 ** rng.uniform(-4, 1, 2)
    w = rng.uniform(0.001, 0.2, 2)
    delta = amp * np.sin(w * k) * np.array([1.0, 0.05])
    changes.append(f"table {n} rows, sine amplitudes {np.round(amp, 4).tolist()}")
    if rng.random() < 0.5:
        j, s = int(rng.integers(0, n)), float(rng.normal() * 10.0 ** rng.uniform(-3, 1))
        delta[j:, int(rng.integers(0, 2))] += s
        changes.append(f"step {s:.3g} at row {j}")
    if rng.random() < 0.3:
        delta += rng.normal(size=delta.shape) * 10.0 ** rng.uniform(-4, -1)
        changes.append("noise")
    dt = 0.005 if rng.random() < 0.9 else mutate_number(rng, 0.005)
    path = folder / "table.npz"
    np.savez(path, delta=delta, dt=np.float64(dt), clock=np.str_("trajectory"))
    _maybe_bytes(rng, path, changes, 0.1)
    return path


def _excitation(rng: np.random.Generator, changes: list[str]) -> list[str]:
    a = [float(10.0 ** rng.uniform(-5, 1)) if rng.random() < 0.9 else float(rng.choice([1e308, 0.0, 1e3]))
         for _ in range(2)]
    hold = int(rng.choice([1, 2, 4, 10, 50]))
    changes.append(f"excitation {a}, hold {hold}")
    return ["--mode", "collect", "--excitation", f"{a[0]!r},{a[1]!r}", "--excitation-hold", str(hold)]


def _flags(rng: np.random.Generator, changes: list[str]) -> list[str]:
    args: list[str] = ["--mode", str(rng.choice(["passthrough", "collect"]))]
    op = int(rng.integers(0, 5))
    if op == 0:
        lo, hi = sorted(float(x) for x in rng.uniform(0.0, 1.0, 2))
        args += ["--thrust-min", f"{lo:.4f}", "--thrust-max", f"{hi:.4f}"]
    elif op == 1:
        args += ["--blend-rates", ",".join(f"{10.0 ** rng.uniform(-2, 2):.4g}" for _ in range(2))]
    elif op == 2:
        args += ["--max-tilt-deg", f"{rng.uniform(0.5, 89.0):.3f}"]
    elif op == 3:
        args += ["--takeoff", "--climb-rate", f"{10.0 ** rng.uniform(-1.5, 1.5):.4g}"]
    else:
        args += ["--trajectory", f"random:{int(rng.integers(0, 10**6))}", "--frame", str(rng.choice(["start", "world"]))]
    changes.append(" ".join(args[2:]))
    return args


def _steer(rng: np.random.Generator, solver: str, changes: list[str]) -> list[str]:
    args = ["--mode", "steer", "--solver", solver]
    if rng.random() < 0.5:
        args += ["--max-step", ",".join(f"{10.0 ** rng.uniform(-3, 0.5):.4g}" for _ in range(2))]
    if rng.random() < 0.3:
        args += ["--guard-hold", f"{float(rng.choice([0.0, 0.05, 0.3, 1.0])):g}"]
    if rng.random() < 0.4:
        start, count = int(rng.integers(0, 150)), int(rng.integers(1, 100))
        args += ["--inject-solver-failure", f"{start}:{count}:{rng.choice(['fail', 'nan'])}"]
    changes.append(" ".join(args[4:]) or "steered")
    return args


def make_mutant(seed: int, folder: Path, kind: str | None = None, solver: str | None = None) -> Mutant:
    """The mutant of ``seed`` (its files written into ``folder``, created if needed); ``kind`` None: drawn (``steer``
    only with a ``solver`` folder: the same seed draws another mutant with and without one)."""
    rng = np.random.default_rng(seed)
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    w = np.array(_KIND_WEIGHTS, dtype=float)
    if solver is None:
        w[KINDS.index("steer")] = 0.0
    drawn = str(rng.choice(KINDS, p=w / w.sum()))
    kind = kind or drawn
    changes: list[str] = []
    args: list[str] = []
    if kind == "hopping":
        return Mutant(kind, seed, _hopping(rng, folder, changes), changes, [folder / "hop.toml"])
    if kind == "profile" or rng.random() < 0.4:
        args += ["--controller", str(_profile(rng, folder, changes, None if kind == "profile" else 0))]
    if kind in ("profile", "trajectory"):
        args += ["--mode", str(rng.choice(["passthrough", "collect"]))]
    if kind == "trajectory" or (kind == "steer" and rng.random() < 0.3):
        args += ["--trajectory", str(_trajectory(rng, folder, changes))]
    if kind == "steer":
        if solver is None:
            raise ValueError("a steer mutant needs a generated solver folder")
        args += _steer(rng, solver, changes)
    elif kind == "prefilter":
        args += ["--mode", "prefilter", "--prefilter", str(_prefilter(rng, folder, changes))]
    elif kind == "feedforward":
        args += ["--mode", "feedforward", "--feedforward", str(_feedforward(rng, folder, changes))]
    elif kind == "excitation":
        args += _excitation(rng, changes)
    elif kind == "flags":
        args += _flags(rng, changes)
    return Mutant(kind, seed, args, changes, [Path(a) for a in args if a.startswith(str(folder))])

