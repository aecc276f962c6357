"""The bridge's per-tick log, stored as an IODataset ``.npz`` with extra ``tick_*`` arrays.

The file is what :meth:`ddpc_codegen.IODataset.save` writes (``header`` + ``u_i`` / ``y_i`` /
``phase_i``), so ``IODataset.load(path)`` and ``ddpc-codegen codegen --dataset path`` read it
directly: collect -> dataset -> codegen -> steer with no glue. The dataset part holds only the
ticks that are valid closed-loop IO data of the loop being modelled:

* the vehicle was armed and in the off-board / guided mode and telemetry was fresh;
* real time: every tick of the bridge's uniform grid (:mod:`.clock`), with the newest telemetry
  held (its age logged) -- the loop the predictor learns includes the telemetry delay it will
  see; lock-step: the tick was triggered by telemetry whose stamp is one period after the
  previous one (a lost or merged sample is a ``gap`` and splits the run);
* u is the reference applied at that tick (nominal + steering or PRBS), y the measured outputs
  the tick decided on (the convention of :mod:`ddpc_codegen.sim.loop`: u[k] acts on y[k+1]...);
  each sample's phase label (hopping: descent / ground / ascent, the controller's) goes with it,
  so a hopping log splits into aerial phases and hops like a simulated run.

Each maximal run of such ticks becomes one trajectory; datasets are never spliced across a gap,
a stale stretch or a mode change. "hold" ticks (older logs) are skipped over; any other tick
(stale, inactive, a fallback outside off-board) or a gap ends the run. Runs shorter than
``min_segment`` ticks, and the first ``skip`` seconds after each activation, are dropped. A log
without any such run is saved marked ``"fit_ok": false`` with the reason, and ``ddpc-codegen
codegen`` refuses it. Every tick is kept in the ``tick_*`` arrays (times, telemetry in the trajectory frame,
references, steered u, setpoint, solver status and time, latency, flags) and every received
telemetry sample in ``sample_<stream>`` (stamp, receive time): a burst of two is two rows; a SITL's
true state (ArduPilot SIM_STATE) is kept in ``truth_*`` columns (nan without it), a lab's motion-capture poses
(``--mocap``) in ``mocap_*`` columns and ``sample_mocap``, the autopilot's estimate in ``estimate_position``.
Each column with a frame says which in the metadata's ``columns`` (:func:`column_frames`): the measured state is
in the bridge's trajectory frame (its start frame, turned by the start heading), the truth in world ENU.
:func:`load_ticklog` reads them back.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ddpc_codegen.design.data import IODataset, checked_json_entry
from ddpc_codegen.errors import DataError

__all__ = ["TickRecorder", "TickLog", "load_ticklog", "log_file", "REASONS", "reason_code", "TICK_FIELDS",
           "column_frames"]

# Why a tick's reference is what it is (int8 in the log).
REASONS = (
    "steered",        # 0 the DDPC solution
    "passthrough",    # 1 mode passthrough: the model-based controller alone
    "collect",        # 2 mode collect: nominal + PRBS
    "warmup",         # 3 steering history not full yet
    "inactive",       # 4 vehicle not armed / not in off-board
    "stale",          # 5 telemetry older than the limit: fallback action
    "hold",           # 6 timer tick with fresh telemetry: last setpoint repeated
    "solver_failed",  # 7 solver status not ok (incl. injected failures)
    "nonfinite",      # 8 NaN / inf in inputs or solution
    "out_of_bounds",  # 9 solution outside u bounds
    "step_too_large", # 10 |u - u_nom| above the guard
    "exception",      # 11 the solver raised
    "no_heartbeat",   # 12 link lost (no vehicle heartbeat)
    "takeoff",        # 13 take-off / approach to the trajectory start (--takeoff): not steered, not data
    "blend",          # 14 bumpless hand-over after (re-)engagement: reference rate-limited, history filling
    "ground",         # 15 hopping steer mode, ground phase: the controller's reference (never steered)
    "no_window",      # 16 hopping steer mode, in the air without a window yet (history, early ascent)
    "prefilter",      # 17 mode prefilter: the static gain + offset + lead baseline
    "feedforward",    # 18 mode feedforward: r_nom + a learned (ILC) table row of this trajectory tick
    "guard_clamped",  # 19 steered, the correction held at the --max-step guard (the proposal in u_proposed)
)
_CODE = {r: i for i, r in enumerate(REASONS)}
FALLBACK_REASONS = frozenset({"stale", "solver_failed", "nonfinite", "out_of_bounds", "step_too_large",
                              "exception", "no_heartbeat"})


def log_file(path: str | Path) -> Path:
    """The file a tick log given as ``path`` is written to: ``.npz`` appended or put in place of another suffix
    (``X``, ``X.log`` and ``X.NPZ`` all write ``X.npz``)."""
    path = Path(path)
    return path if path.suffix == ".npz" else path.with_suffix(".npz")


def reason_code(reason: str) -> int:
    """Map a :class:`ddpc_codegen.SteerOutcome` reason (or a bridge reason) to its code."""
    if reason in _CODE:
        return _CODE[reason]
    if reason.startswith("solver_"):
        return _CODE["solver_failed"]
    if reason.startswith("nonfinite"):
        return _CODE["nonfinite"]
    if reason.startswith("exception"):
        return _CODE["exception"]
    if reason.startswith("prefilter"):
        return _CODE["prefilter"]
    return _CODE["solver_failed"]


# name -> (columns or 0 for a scalar, dtype)
def tick_fields(m: int, p: int) -> dict[str, tuple[int, Any]]:
    return {
        "t_wall": (0, float),       # bridge clock since start [s]
        "t_vehicle": (0, float),    # vehicle time of the tick [s] (telemetry stamp / estimate)
        "t_traj": (0, float),       # controller trajectory time [s] (nan before activation)
        "age_ms": (0, float),       # telemetry age at the tick [ms]
        # The measured state in the trajectory frame (:func:`column_frames`; --frame start: the bridge's start
        # frame, x along the heading at the start; not world ENU), the position the position source's
        "position": (3, float),     # trajectory frame [m], heights from the take-off point
        "velocity": (3, float),     # trajectory frame [m/s]
        "euler": (3, float),        # roll, pitch (body FLU), yaw from the start heading [rad]
        "rates": (3, float),        # body FLU [rad/s]
        "y": (p, float),            # measured outputs
        "y_des": (p, float),        # desired outputs
        "r_nom": (m, float),        # nominal references (stage a)
        "u": (m, float),            # references applied (sent to stage b)
        "u_steered": (m, float),    # solver's u[0] (nan when not solved)
        "u_proposed": (m, float),   # solver's u[0] the step guard clamped (reason guard_clamped; else nan)
        "excitation": (m, float),   # PRBS part of u
        "sp_q": (4, float),         # SET_ATTITUDE_TARGET quaternion (w, x, y, z), FRD -> NED
        "sp_thrust": (0, float),    # normalized thrust after clamping
        "sp_field": (0, float),     # the thrust field sent (climb-rate semantics on ArduPilot)
        "reason": (0, np.int8),     # REASONS code
        "solve_us": (0, float),     # solver wall time [µs] (nan if not called)
        "latency_us": (0, float),   # telemetry receive -> setpoint sent [µs] (event ticks)
        "compute_us": (0, float),   # tick start -> setpoint sent [µs] (the rest of the latency is waking up)
        "event": (0, bool),         # new telemetry since the previous tick (lock-step: the tick's trigger)
        "new_samples": (0, np.int8),  # telemetry samples (both streams) received since the previous tick
        "armed": (0, bool),
        "offboard": (0, bool),
        "active": (0, bool),        # armed & off-board & heartbeat & fresh telemetry
        "fresh": (0, bool),
        "sent": (0, bool),          # setpoint went out
        "valid": (0, bool),         # closed-loop IO sample (event tick, engaged, fresh)
        "gap": (0, bool),           # event tick whose stamp is not one period after the previous one
        "gate": (0, np.int8),       # the last gate's actions on this tick (gate.GATE_FLAGS bits; 1: a stall)
        "adapt": (0, np.int8),      # online update (--adapt): runtime.adapt_loop.ADAPT_CODES (0: none this tick)
        "adapt_offset": (0, float),  # --adapt: norm of the output offset in use (data units; nan: no adaptation)
        "adapt_snap": (0, np.int8),  # --adapt: 1 a re-solve's snapshot taken (its verdict lands, in ``adapt``, on a
                                     # later tick, with the swap), 2 a re-solve period skipped (one still ran)
        "phase": (0, np.int8),      # phase label (design.phases: 0 flying; hopping 1 descent, 2 ground, 3 ascent)
        "contact": (0, np.int8),    # hopping: the robot's contact flag as received (-1: none yet / not read)
        # The simulator's truth (ArduPilot SITL SIM_STATE, :mod:`.truth`; nan without it): never used for control.
        # World ENU, not the trajectory frame: its axes are east / north (the start frame's are turned by the start
        # heading), its origin the first sample's position
        "truth_position": (3, float),  # world ENU [m]: east / north from the first sample, up from the take-off point
        "truth_velocity": (3, float),  # world ENU [m/s]
        "truth_euler": (3, float),     # roll, pitch (body FLU), yaw from east [rad]
        "truth_age_ms": (0, float),    # since the newest truth sample (ArduCopter: its loop's time; else arrival) [ms]
        # The position sources (:mod:`.position_source`): the autopilot's estimate in the trajectory frame (=
        # ``position`` with --position-source autopilot), the motion capture's pose (--mocap; nan while stale)
        "estimate_position": (3, float),  # trajectory frame [m]
        "mocap_position": (3, float),     # the mocap's own ENU frame [m], up from where the vehicle stood disarmed
        "mocap_age_ms": (0, float),       # since the newest pose arrived [ms]
        "mocap_latency_ms": (0, float),   # its arrival minus its measurement stamp [ms] (nan: another clock)
    }


TICK_FIELDS = tuple(tick_fields(1, 1))


def column_frames(frame_mode: str = "start") -> dict[str, str]:
    """What each tick-log column with a frame is in (the metadata's ``columns``), for the bridge's ``--frame``
    ``frame_mode`` ("start" or "world"). The trajectory frame and world ENU differ by the start heading's turn
    and the start point, so a column is never just "ENU"."""
    if frame_mode == "world":
        traj = "the autopilot's local ENU frame (--frame world: east, north, up from its origin)"
    else:
        traj = ("the bridge's start frame (--frame start: x along the vehicle's heading when the trajectory started, "
                "y to its left, z up; origin the trajectory's start point where the vehicle then stood)")
    heights = "heights from the take-off point (where the vehicle stood disarmed)"
    return {
        "position": f"[m] {traj}, {heights}; the position source's measurement (autopilot estimate or mocap)",
        "velocity": f"[m/s] {traj}; the autopilot's estimate",
        "euler": "[rad] roll, pitch of body FLU; yaw " + ("from east (ENU)" if frame_mode == "world" else
                                                          "from the start heading"),
        "estimate_position": f"[m] {traj}, {heights}; the autopilot's estimate",
        "truth_position": ("[m] world ENU: east / north from the simulator's first sample, up from the take-off "
                           "altitude; not the trajectory frame"),
        "truth_velocity": "[m/s] world ENU (east, north, up)",
        "truth_euler": "[rad] roll, pitch of body FLU; yaw from east (world ENU)",
        "mocap_position": ("[m] the motion capture's own frame (its axes and origin, as the lab's system sends them, "
                           "turned to ENU), up from where the vehicle stood disarmed"),
        "sp_q": "quaternion (w, x, y, z) body FRD -> the autopilot's local NED",
        "rates": "[rad/s] body FLU",
    }


class TickRecorder:
    """Growable per-tick arrays (no allocation per tick except when doubling).

    Args:
        m, p: number of references / outputs.
        capacity: initial number of ticks (doubles when full).
    """

    def __init__(self, m: int, p: int, capacity: int = 4096) -> None:
        self.m, self.p = m, p
        self._spec = tick_fields(m, p)
        self.n = 0
        self._cap = max(16, int(capacity))
        self.arrays: dict[str, np.ndarray] = {}
        for k, (c, dt) in self._spec.items():
            shape = (self._cap, c) if c else (self._cap,)
            fill = np.nan if dt is float else 0
            self.arrays[k] = np.full(shape, fill, dtype=dt)

    def new_row(self) -> int:
        """Index of a fresh row (floats nan, flags False)."""
        if self.n == self._cap:
            self._cap *= 2
            for k, a in self.arrays.items():
                b = np.full((self._cap,) + a.shape[1:], np.nan if a.dtype == float else 0, dtype=a.dtype)
                b[: self.n] = a[: self.n]
                self.arrays[k] = b
        i = self.n
        self.n += 1
        return i

    def set_last(self, values: dict[str, Any]) -> None:
        """Fill columns of the newest row (name -> value)."""
        i = self.n - 1
        for k, v in values.items():
            self.arrays[k][i] = v

    def view(self) -> dict[str, np.ndarray]:
        return {k: a[: self.n] for k, a in self.arrays.items()}

    def to_log(self, *, dt: float, input_names, output_names, input_units=None, output_units=None,
               metadata: dict | None = None, samples: dict | None = None) -> "TickLog":
        return TickLog({k: v.copy() for k, v in self.view().items()}, dt, tuple(input_names), tuple(output_names),
                       tuple(input_units or ("",) * self.m), tuple(output_units or ("",) * self.p),
                       dict(metadata or {}), dict(samples or {}))


@dataclass
class TickLog:
    """All ticks of one bridge run (see the module docstring for the fields)."""

    ticks: dict[str, np.ndarray]
    dt: float
    input_names: tuple[str, ...]
    output_names: tuple[str, ...]
    input_units: tuple[str, ...] = ()
    output_units: tuple[str, ...] = ()
    metadata: dict = field(default_factory=dict)
    samples: dict[str, np.ndarray] = field(default_factory=dict)  # stream -> (n, 2) stamp, rx [s]

    @property
    def n(self) -> int:
        return int(self.ticks["t_wall"].shape[0])

    def segments(self, *, skip: float = 0.0, min_segment: int = 50) -> list[np.ndarray]:
        """Row indices of each dataset trajectory: runs of valid rows; "hold" rows (the last setpoint
        repeated while telemetry was late but fresh) are skipped over, anything else or a time-stamp
        gap ends a run."""
        v = self.ticks["valid"].astype(bool)
        gap = self.ticks["gap"].astype(bool) if "gap" in self.ticks else np.zeros(self.n, bool)
        hold = (self.ticks["reason"] == _CODE["hold"]) & self.ticks["active"].astype(bool)
        tt = self.ticks["t_traj"]
        out: list[np.ndarray] = []
        cur: list[int] = []

        def close() -> None:
            idx = np.array(cur, dtype=int)
            if skip > 0 and idx.size:
                # Drop the start of each activation (the hand-over transient), like the simulator's settle time.
                idx = idx[np.nan_to_num(tt[idx], nan=-1.0) >= skip - 1e-9]
            if idx.size >= min_segment:
                out.append(idx)
            cur.clear()

        for i in range(self.n):
            if v[i]:
                if gap[i]:
                    close()
                cur.append(i)
            elif not hold[i]:
                close()
        close()
        return out

    def to_dataset(self, *, skip: float | None = None, min_segment: int | None = None) -> IODataset:
        """The closed-loop IO data as an :class:`IODataset` (one trajectory per valid run)."""
        skip = float(self.metadata.get("dataset_skip", 0.0) if skip is None else skip)
        min_segment = int(self.metadata.get("min_segment", 50) if min_segment is None else min_segment)
        segs = self.segments(skip=skip, min_segment=min_segment)
        meta = {k: v for k, v in self.metadata.items() if k not in ("summary",)}
        meta.update(source="firmware_bridge.ticklog", segments_ticks=[[int(s[0]), int(s[-1]) + 1] for s in segs],
                    dataset_skip=skip, min_segment=min_segment)
        if not segs:
            raise DataError(
                f"the tick log has no closed-loop segment of >= {min_segment} ticks (armed, off-board, fresh "
                f"telemetry, after {skip} s); fly longer or check that the vehicle entered off-board")
        u, y = self.ticks["u"], self.ticks["y"]
        return IODataset([u[s] for s in segs], [y[s] for s in segs], self.dt,
                         input_names=self.input_names, output_names=self.output_names,
                         input_units=self.input_units or None, output_units=self.output_units or None,
                         phases=[self._phases(s) for s in segs], metadata=meta)

    def _phases(self, rows: np.ndarray) -> np.ndarray:
        """Phase labels of the rows (logs older than the field: flying, 0)."""
        ph = self.ticks.get("phase")
        return np.zeros(rows.size, dtype=np.int8) if ph is None else ph[rows].astype(np.int8)

    def save(self, path: str | Path, *, skip: float | None = None, min_segment: int | None = None) -> Path:
        """Write the IODataset part (via IODataset.save) plus the ``tick_*`` arrays in one .npz.

        If there is no valid segment, every tick with finite telemetry is written as one trajectory
        and the metadata says ``"closed_loop": false, "fit_ok": false`` and why (the file still
        loads for inspection; ``ddpc-codegen codegen`` refuses to fit on it).
        """
        path = log_file(path)
        try:
            ds = self.to_dataset(skip=skip, min_segment=min_segment)
            ds = IODataset(list(ds.u), list(ds.y), ds.dt, input_names=ds.input_names, output_names=ds.output_names,
                           input_units=ds.input_units, output_units=ds.output_units, phases=list(ds.phases),
                           metadata={**ds.metadata, "closed_loop": True, "fit_ok": True})
        except DataError as e:
            ok = np.isfinite(self.ticks["y"]).all(axis=1) & np.isfinite(self.ticks["u"]).all(axis=1)
            if not ok.any():
                ok = np.zeros(self.n, dtype=bool)
            u = self.ticks["u"][ok] if ok.any() else np.zeros((1, len(self.input_names)))
            y = self.ticks["y"][ok] if ok.any() else np.zeros((1, len(self.output_names)))
            ds = IODataset(u, y, self.dt, input_names=self.input_names, output_names=self.output_names,
                           metadata={**self.metadata, "closed_loop": False, "fit_ok": False, "unfit_reason": str(e),
                                     "source": "firmware_bridge.ticklog"})
        ds.save(path)
        # Re-open and add the tick arrays (IODataset.load ignores unknown entries).
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
        for k, a in self.ticks.items():
            arrays[f"tick_{k}"] = a
        for k, a in self.samples.items():
            arrays[f"sample_{k}"] = np.asarray(a, dtype=float).reshape(-1, 2)
        extra = {"dt": self.dt, "input_names": list(self.input_names), "output_names": list(self.output_names),
                 "input_units": list(self.input_units), "output_units": list(self.output_units),
                 "reasons": list(REASONS), "metadata": self.metadata}
        arrays["ticklog_header"] = np.frombuffer(json.dumps(extra, sort_keys=True, default=_json_default).encode(),
                                                 dtype=np.uint8)
        tmp = path.with_name(path.name + ".tmp.npz")
        np.savez_compressed(tmp, **arrays)
        tmp.replace(path)
        return path


def _json_default(o):
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)


def load_ticklog(path: str | Path) -> TickLog:
    """Read the tick arrays of a bridge log written by :meth:`TickLog.save`."""
    with np.load(Path(path), allow_pickle=False) as z:
        if "ticklog_header" not in z.files:
            raise ValueError(f"{path} has no tick arrays (not a bridge tick log)")
        h = checked_json_entry(z, "ticklog_header", path, "tick log header")
        ticks = {k[5:]: z[k] for k in z.files if k.startswith("tick_")}
        samples = {k[7:]: z[k] for k in z.files if k.startswith("sample_")}
    return TickLog(ticks, float(h["dt"]), tuple(h["input_names"]), tuple(h["output_names"]),
                   tuple(h.get("input_units", ())), tuple(h.get("output_units", ())), h.get("metadata", {}), samples)
