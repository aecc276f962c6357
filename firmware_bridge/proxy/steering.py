"""The steering proxy's tick: the app's position setpoint in, the steered one out (the proxy's rewrite hook).

Each position setpoint the app sends in a steered frame (:mod:`.setpoint_frames`: ``SET_POSITION_TARGET_LOCAL_NED``
in the local frame, ``SET_POSITION_TARGET_GLOBAL_INT`` above home or sea level) is one tick (the app's own period
is the steering's tick, and must match the solver's ``dt``). A tick composes the companion loop's own parts, as the
bridge does: :class:`~firmware_bridge.engagement.Engagement` (edges: armed + off-board / guided, the vehicle heard,
fresh position), :class:`~firmware_bridge.reference_stage.ReferenceStage` (steer: the generated solver through the
steering policy and its fallbacks; passthrough; collect: the app's setpoint plus the PRBS dither) and
:class:`~firmware_bridge.tick_gate.TickGate` (finite, rate bound, the solver's bounds, the step guard). The
nominal reference is the app's height in the local frame (``-z``; a global setpoint's ``alt`` minus its frame's
offset, measured by :class:`.vehicle_view.VehicleView`); the preview comes from :mod:`.preview`; the measured output
is the vehicle's ``LOCAL_POSITION_NED`` height (or the motion capture's, put into the local frame).

Two coordinate systems, named by the solver's signals (the generated solver is the authority on what it steers):

* absolute (inputs ``z_ref``, outputs ``z``): the loop from the height sent to the height flown; the app's height
  is the nominal reference and the preview its future. Right for an app without its own feed-forward.
* deviation (inputs ``z_offset``, outputs ``z_error``): the loop from the offset added to the app's height to the
  tracking error (measured height - the app's height); the nominal offset and the desired error are 0. Right for
  an app that sends its own velocity / acceleration: the autopilot's feed-forward carries the path, and what is
  left to steer is the error around it, which an absolute model cannot separate from the path.

What goes out: only the height of the app's setpoint is replaced (``z``, or ``alt`` = the steered local height plus
the frame's offset; x, y, lat, lon, velocity and acceleration fields, yaw, ``type_mask`` and the frame are the
app's). A tick that is not steered (not engaged, stale, a solver failure, the guard, a global frame's offset not
known) sends the app's own setpoint unchanged (with ``--preview-delay``: its delayed one), and the rate bound
counts from there. A setpoint in another frame, or whose height ``type_mask`` ignores, is never steered. When the
app changes frames, a delayed preview is not steered until it holds only the new frame's setpoints.
"""

from __future__ import annotations

import math
import time

import numpy as np

from ddpc_codegen.runtime.baselines import PassthroughPolicy
from ddpc_codegen.runtime.policy import SteeringPolicy
from ddpc_codegen.runtime.prediction_watch import PredictionWatch
from ddpc_codegen.runtime.steerer import ReferenceSteerer, solver_input_bounds

from firmware_bridge.engagement import Engagement
from firmware_bridge.events import EventLog
from firmware_bridge.excitation import Excitation
from firmware_bridge.gate import SetpointGate
from firmware_bridge.proxy.file_preview import FilePreview
from firmware_bridge.proxy.jerk_bound import JerkBound
from firmware_bridge.proxy.preview import DelayedPreview, LocalPreview
from firmware_bridge.proxy.record import ProxyRecord
from firmware_bridge.proxy.rewrite import SetpointEncoder
from firmware_bridge.proxy.setpoint_frames import AMSL, LOCAL, RELATIVE_ALT, app_height, height_fields, steered_frame
from firmware_bridge.proxy.stats import SetpointPeriod
from firmware_bridge.proxy.vehicle_view import VehicleView
from firmware_bridge.reference_stage import ReferenceStage
from firmware_bridge.tick_gate import TickGate

__all__ = ["ProxySteering", "check_proxy_solver"]

_WIDE = 1e4  # m: the gate's height range when no solver bounds it (passthrough, collect)


COORDINATES = {"absolute": (("z_ref",), ("z",)), "deviation": (("z_offset",), ("z_error",))}


def check_proxy_solver(solver) -> tuple[float, str]:
    """(the solver's tick [s], its coordinates), after checking it steers a height loop (:data:`COORDINATES`)."""
    man = solver.manifest
    d, sig = man["dims"], man.get("signals") or {}
    io = (tuple(sig.get("inputs") or ()), tuple(sig.get("outputs") or ()))
    kind = next((k for k, v in COORDINATES.items() if v == io), None)
    if (d["m"], d["p"]) != (1, 1) or kind is None:
        raise ValueError(f"the proxy steers the height of position setpoints: a solver with inputs ['z_ref'] and "
                         f"outputs ['z'], or ['z_offset'] and ['z_error'] (m = p = 1); this one has inputs "
                         f"{sig.get('inputs')}, outputs {sig.get('outputs')} (configs/proxy_*.toml make one)")
    dt = sig.get("dt")
    if not (isinstance(dt, (int, float)) and dt > 0):
        raise ValueError("the solver's manifest has no signals.dt: regenerate it")
    return float(dt), kind


def _no_error(t: np.ndarray) -> np.ndarray:
    """Deviation coordinates' desired outputs: no tracking error, (len(t), 1)."""
    return np.zeros((len(t), 1))


class ProxySteering:
    """The rewrite hook (see the module docstring); ``proxy = Proxy(..., rewrite=hook)``, ``hook.view`` folded in
    from the vehicle's frames by the proxy.

    Args:
        view: the vehicle as the proxy sees it.
        solver: a loaded generated solver (steer); None: passthrough or (``dither`` > 0) collect.
        preview: :class:`.preview.LocalPreview`, :class:`.preview.DelayedPreview` or
            :class:`.file_preview.FilePreview` (its matched / fallback ticks in :meth:`summary`'s ``preview``).
        dt: the tick without a solver [s] (None: the app's measured period; a solver brings its own).
        max_age: an older position sample is stale [s]; max_step: the steering's step guard [m].
        dither: collect: the PRBS amplitude added to the app's height [m]; dither_hold: its shortest hold [ticks].
        period_tolerance: steer only while the app's median period is within this fraction of ``dt``.
        record: where each tick is recorded (None: not kept).
        coordinates: collect / passthrough: what the record's dataset holds (a solver brings its own).
        z_feedforward: "zero": a rewritten setpoint's z velocity and acceleration are 0 (the steered height carries
            the lead; the loop collected and steered is then the position loop alone); "keep": the app's.
        model_watch: steer: while the predictor's error on the flight exceeds this many times its held-out error,
            the app's own setpoints go out (:class:`~ddpc_codegen.runtime.prediction_watch.PredictionWatch`;
            0: no watch).
        max_jerk: the autopilot's vertical jerk limit [m/s^3] (ArduCopter's ``PSC_JERK_Z``): the steering pauses
            around the app's acceleration jumps it shapes, and a delayed preview spreads them (:mod:`.jerk_bound`);
            0: neither.
    """

    def __init__(self, view: VehicleView, *, solver=None,
                 preview: LocalPreview | DelayedPreview | FilePreview | None = None, dt: float | None = None,
                 max_age: float = 0.2, max_step: float | None = None, dither: float = 0.0,
                 dither_hold: int = 3, seed: int = 0, period_tolerance: float = 0.25, offset_rate: float = 1.0,
                 events: EventLog | None = None, record: ProxyRecord | None = None,
                 z_feedforward: str = "keep", coordinates: str = "absolute", model_watch: float = 8.0,
                 max_jerk: float = 0.0) -> None:
        if z_feedforward not in ("zero", "keep"):
            raise ValueError(f"z_feedforward must be 'zero' or 'keep'; got {z_feedforward!r}")
        self.ff_fields = {"vz": 0.0, "afz": 0.0} if z_feedforward == "zero" else {}
        self.view, self.preview = view, preview or LocalPreview()
        self.jerk = JerkBound(max_jerk, self.preview.delay) if max_jerk else None
        if self.jerk is not None and self.ff_fields:
            raise ValueError("--max-jerk spreads the app's own z feed-forward; --z-feedforward zero sends none")
        self.events = events or EventLog(name="proxy")
        self.preview.bind(self.events)
        self.dt, self.coordinates = check_proxy_solver(solver) if solver is not None else (dt, coordinates)
        if self.coordinates not in COORDINATES:
            raise ValueError(f"coordinates must be one of {sorted(COORDINATES)}; got {coordinates!r}")
        self.period_tolerance = period_tolerance
        self.record = record
        self.period = SetpointPeriod(ring_size=64)
        self.mode = "steer" if solver is not None else "collect" if dither > 0 else "passthrough"
        self.stage, self.steerer, lo, hi, rate = self._stage(solver, max_step, dither, dither_hold, seed, model_watch)
        rate = np.minimum(rate, offset_rate * self.tick)  # the envelope's offset rate, as the bridge's gate
        self.gate = TickGate(SetpointGate(lo, hi, None if self.mode == "collect" else rate), self.events,
                             max_step=None if max_step is None else np.array([max_step]), max_tilt=math.pi,
                             thrust_min=0.0, thrust_max=1.0, hover_thrust=0.5, max_age=None, guard_hold=0.0)
        self.engagement = Engagement(self.events, max_age=max_age)
        self.encoder = SetpointEncoder()
        self.counts = dict.fromkeys(("ticks", "steered", "rewritten", "not_steerable", "period_mismatch",
                                     "no_frame_offset"), 0)
        self.frames = dict.fromkeys((LOCAL, RELATIVE_ALT, AMSL), 0)  # the app's setpoints per steered frame
        self._frame: str | None = None  # the frame of the app's newest setpoint
        self._switched = -math.inf  # when the app changed frames [s]
        self._offset, self._offset_ok = 0.0, True  # this tick's frame offset [m]; whether it was known last tick
        self._period_said = False
        self._period: float | None = None  # the app's median period, refreshed every 16 setpoints [s]
        self._pending: tuple | None = None  # what :meth:`settle` does of the last tick (after the send)

    @property
    def deviation(self) -> bool:
        """Whether the steering is in deviation coordinates (see the module docstring)."""
        return self.coordinates == "deviation"

    @property
    def max_age(self) -> float:
        """An older position sample is stale [s] (the engagement's limit)."""
        return self.engagement.max_age

    def _stage(self, solver, max_step, dither, hold, seed, model_watch):
        """(reference stage, steerer or None, lo (1,), hi (1,), rate per tick (1,)) of the mode."""
        if solver is None:
            lo, hi, rate = np.array([-_WIDE]), np.array([_WIDE]), np.array([np.inf])
            if self.mode == "collect":
                exc = Excitation(1, dither, hold, seed)
                exc.prepare()
                return ReferenceStage("collect", self._desired, self.tick, excitation=exc), None, lo, hi, rate
            return (ReferenceStage("passthrough", self._desired, self.tick, policy=PassthroughPolicy()), None,
                    lo, hi, rate)
        steerer = ReferenceSteerer.for_solver(solver, max_step=None if max_step is None else np.array([max_step]),
                                              watch=self._watch(solver, model_watch))
        policy = SteeringPolicy(steerer, ramp_ticks=max(int(round(0.5 / self.dt)), 1))
        t_f = solver.manifest["dims"]["t_f"]
        desired = _no_error if self.deviation else self._desired
        stage = ReferenceStage("steer", desired, self.dt, policy=policy,
                               ahead=self.dt * np.arange(t_f), steerer=steerer)
        du = (solver.manifest.get("bounds") or {}).get("du_max") or [None]
        rate = np.array([np.inf if du[0] is None else float(du[0])])
        lo, hi = solver_input_bounds(solver)
        return stage, steerer, lo, hi, rate

    def _watch(self, solver, ratio: float) -> PredictionWatch | None:
        """The steering's prediction watch at ``ratio`` (None: 0, switched off, or the solver's manifest has no
        held-out error)."""
        if not ratio:
            return None
        watch = PredictionWatch.for_solver(solver, ratio, on_change=self._watch_changed)
        if watch is None:
            self.events("the solver's manifest has no held-out prediction error: no prediction watch (regenerate it)")
        return watch

    def _watch_changed(self, ok: bool, score: float) -> None:
        self.events(f"the predictor describes the flight again ({score:.1f}x its held-out error): steering" if ok else
                    f"the predictor is {score:.1f}x its held-out error on this flight, over "
                    f"{self.steerer.watch.ratio:g}x: the app's own setpoints go out until it is back under")

    # ------------------------------------------------------------------ the hook
    def __call__(self, msg, frame: bytes, t_rx: float) -> bytes | None:
        """One whole tick on the app's setpoint ``msg`` (received at ``t_rx`` [s, time.time()]): the frame to send
        instead, or None (the app's own frame goes out). The proxy splits it: :meth:`decide`, the send, :meth:`settle`
        (or, :attr:`passive`, the whole call after the send)."""
        try:
            return self.decide(msg, frame, t_rx)
        finally:
            self.settle()

    @property
    def passive(self) -> bool:
        """Whether every tick sends the app's own frame (passthrough without a delay): the proxy then runs the whole
        tick after the send."""
        return self.mode == "passthrough" and self.preview.delay == 0

    def settle(self) -> None:
        """The rest of the tick :meth:`decide` left for after the send: what the steering's next tick starts from
        (the gate's rate bound, the steering history, the engagement's last applied reference) and the record."""
        p, self._pending = self._pending, None
        if p is None:
            return
        self.preview.catch_up()  # (a file's match, off this tick's latency)
        now, ref, u, flags, age, engaged, base, steered = p
        if steered:
            self.stage.applied(ref, u)
            self.engagement.applied(u)
        else:  # the app's own setpoint, from this tick on (the rate bound counts from it)
            self.gate.gate.passed(u)
            self.stage.applied(ref, u)
        self._record(now, ref, u, flags, age, engaged, base)
        watch = None if self.steerer is None else self.steerer.watch
        if watch is not None:  # a due check of the predictor, off the next tick's latency
            watch.poll()

    def decide(self, msg, frame: bytes, t_rx: float) -> bytes | None:
        """What goes out for the app's setpoint ``msg`` (see :meth:`__call__`); :meth:`settle` before the next."""
        self.settle()  # (a previous tick not settled yet)
        kind = steered_frame(msg)
        if kind is None:
            self.counts["not_steerable"] += 1
            return None
        self.counts["ticks"] += 1
        self.frames[kind] += 1
        self.period.add(t_rx)
        if kind != self._frame:
            self._new_frame(kind, t_rx)
        h_app = app_height(msg)
        self.preview.push(t_rx, msg, h_app)
        if self.jerk is not None:
            self.jerk.push(t_rx, msg)
        cur = self.preview.current(t_rx)
        delayed = cur is not msg
        if delayed:
            h_app, kind = app_height(cur), steered_frame(cur)
        if self.jerk is not None and self.steerer is not None:
            t_sent = t_rx - self.preview.delay if delayed else t_rx  # (the held setpoint came about a delay ago)
            self.steerer.pause = "beyond_jerk" if self.jerk.paused(t_sent) else ""
        u, reason = self._tick(h_app, self.view.frame_offset(kind, t_rx), t_rx)
        if reason == "steered" or reason == "collect":
            self.counts["steered"] += 1
        if not delayed and (u is None or np.float32(u) == np.float32(h_app)):  # the same bytes: the app's frame
            return None
        self.counts["rewritten"] += 1
        ff = self.ff_fields if self.jerk is None or not delayed else self.jerk.fields(cur)
        if u is None:
            return self.encoder.encode(cur, **ff)
        return self.encoder.encode(cur, **height_fields(cur, u), **ff)

    def _new_frame(self, kind: str, now: float) -> None:
        """The app's setpoints are in frame ``kind`` from now on: a local preview's slope starts anew; a delayed one
        holds the other frame's heights for its delay (not steered meanwhile: :meth:`_tick`)."""
        if self._frame is not None:
            self.events(f"the app's setpoints changed frame ({self._frame} -> {kind})")
            self.preview.reset()
            self._switched = now
        self._frame = kind

    def _desired(self, ahead: np.ndarray) -> np.ndarray:
        """The preview's heights in the local frame, (len(ahead), 1) [m]."""
        return self.preview.desired(ahead) - self._offset

    def _tick(self, h_app: float, offset: float, now: float) -> tuple[float | None, str]:
        """(the height to send [m, up, the app's frame], None: the app's own; the tick's reason) for the app's height
        ``h_app`` [m, up] in a frame ``offset`` [m] above the local one (nan: unknown, the tick is stale)."""
        view, eng = self.view, self.engagement
        view.pump(now)
        measured = view.height(now)
        known = self._offset_known(offset)
        self._offset = offset if known else 0.0
        app = h_app - offset if known else measured  # (unknown: a stand-in, never sent: the tick is stale)
        base = app if self.deviation else 0.0  # deviation: offsets and errors around the app's height
        r = np.array([app - base])
        y = np.array([measured - base])
        age = view.position_age(now) if known else math.inf
        fresh = age <= self.max_age and now - self._switched >= self.preview.delay
        heard = view.heard(now)
        engaged = view.armed and view.offboard and heard and self._period_ok()
        eng.telemetry(now, age, fresh)
        if eng.update(engaged, now, y, float(y[0]), view.mode_name) in ("first", "again", "resume"):
            self.stage.reset()
        r_nom, hold = eng.reference(r, y, now, self.tick, heard=heard, engaged=engaged, fresh=fresh)
        ref = self.stage.step(r_nom, y, 0.0, hold)
        if ref.reason not in ("steered", "collect") and ref.candidate is None:  # not steered: the app's own
            self._pending = (now, ref, r_nom, 0, age, engaged, base, False)
            return None, ref.reason
        u, flags = self.gate.reference(ref)
        self._pending = (now, ref, u, flags, age, engaged, base, True)  # (:meth:`settle`, after the send)
        return float(u[0]) + base + offset, ref.reason

    def _offset_known(self, offset: float) -> bool:
        """Whether the frame's offset is known (counted and said when that changes)."""
        known = math.isfinite(offset)
        if not known:
            self.counts["no_frame_offset"] += 1
        if known != self._offset_ok:
            self._offset_ok = known
            self.events(f"the app's frame is {offset:+.3f} m above the local one: its setpoints steered" if known else
                        "the offset of the app's frame to the local one is not known (GLOBAL_POSITION_INT with "
                        "LOCAL_POSITION_NED): its setpoints go out unsteered")
        return known

    @property
    def tick(self) -> float:
        """The steering's tick [s]: the solver's, else the app's median period so far as a whole rate in Hz (an app
        streams at a round rate; the jitter of its clock is not the tick): 0.02 before two setpoints."""
        if self.dt is not None:
            return self.dt
        p = self.period.period()
        return 0.02 if p is None else 1.0 / max(round(1.0 / p), 1)

    def _period_ok(self) -> bool:
        """The app streams at the solver's tick (within the tolerance); said once when it does not."""
        if self.dt is None:
            return True
        if self.period.count % 16 == 1 or self._period is None:  # a median per tick would cost more than the tick
            self._period = self.period.period()
        p = self._period
        ok = p is not None and abs(p - self.dt) <= self.period_tolerance * self.dt
        if not ok and p is not None:
            self.counts["period_mismatch"] += 1
            if not self._period_said:
                self._period_said = True
                self.events(f"the app streams setpoints every {p * 1e3:.1f} ms but the steering's tick is "
                            f"{self.dt * 1e3:.1f} ms: not steering (a solver generated at the app's rate steers it)")
        return ok

    def _record(self, now: float, ref, u: np.ndarray, flags: int, age: float, engaged: bool, base: float) -> None:
        """One row, in absolute heights whatever the coordinates."""
        if self.record is not None:
            self.record.add(now, float(ref.r_nom[0]) + base, float(u[0]) + base, float(ref.y[0]) + base, ref.reason,
                            flags, age, engaged, ref.solve_us, self.view.telem.pos.seq)

    def own_messages(self, now: float) -> list[bytes]:
        """What the proxy sends of its own (:meth:`.core.Proxy.run`, between forwarded frames): the position stream
        at twice the steering's rate (every tick then has a fresh sample) when the vehicle sends it slower, and for an
        app in a global frame GLOBAL_POSITION_INT (its frame's offset)."""
        self.view.pump(now)  # the poses' offset is measured before arming, when no setpoint may come
        return self.view.stream_request(now, min(0.5 * self.tick, 0.025),
                                        global_too=self.frames[RELATIVE_ALT] + self.frames[AMSL] > 0)

    def summary(self) -> dict:
        """Counts, the engagement, the gate and the steering's own summary (JSON-ready)."""
        self.settle()
        out = {"mode": self.mode, "coordinates": self.coordinates, "dt": self.tick, "preview_delay_s": self.preview.delay,
               "preview": self.preview.summary(),
               "z_feedforward": "zero" if self.ff_fields else "keep",
               "jerk_bound": None if self.jerk is None else self.jerk.summary(), **self.counts, "frames": dict(self.frames),
               "frame_offsets": self.view.offsets.summary(self.engagement.t_last),
               "app_period": self.period.summary(), "activations": self.engagement.activations,
               "gate": self.gate.gate.summary(), "position_source": self.view.source_summary(), "events": [list(e) for e in self.events.events],
               "t_wall": time.time()}
        out.update(self.stage.summary())
        return out
