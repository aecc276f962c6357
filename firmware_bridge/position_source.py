"""Which position the bridge's loop measures (``ddpc-bridge --position-source``): the autopilot's estimate
(its LOCAL_POSITION_NED / ODOMETRY, the default) or a lab's motion capture (:mod:`.mocap_input`), so that the
steering's measured outputs are the lab's measurement, not the estimator's smoothed copy of it.

Frames. The loop flies in its trajectory frame (:class:`.telemetry.TrajectoryFrame`): x along the vehicle's
heading, from where it stood, heights from where it stood disarmed. The autopilot's estimate is captured into
that frame from the EKF's local frame; the mocap pose has its own frame (the lab's), so it gets a trajectory
frame of its own, captured at the same ticks from the mocap's position and yaw. Both then describe the same
trajectory frame, each from its own measurement: with source ``mocap`` the measured position is the mocap's,
the attitude, velocity and body rates stay the autopilot's (the EKF's attitude is the IMU's; a
VISION_POSITION_ESTIMATE has no velocity), and the setpoints go out in the autopilot's frame as before.

A pose older than ``max_age`` (or none yet) is never used as the measurement. With source ``mocap`` that
makes the tick stale, as stale telemetry does (:mod:`.engagement`: the fallback action, no steering, no
data, and no first engagement before the mocap frame is captured), with an event at each change; the state
the unsteered fallback flies on is then the autopilot's estimate, shifted by the offset between the two
measurements at the last fresh tick (no jump where the stream stops), and the tick log's ``mocap_*``
columns stay nan. With source ``autopilot`` and ``--mocap`` given, the poses are only logged beside.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from ddpc_codegen.stats import percentiles
from firmware_bridge.events import EventLog
from firmware_bridge.link import LinkError, MavLink
from firmware_bridge.mocap_input import MocapInput
from firmware_bridge.plausibility import TelemetryLimits
from firmware_bridge.telemetry import TrajectoryFrame
from firmware_bridge.ticklog import TickLog

__all__ = ["PositionSource", "POSITION_SOURCES"]

POSITION_SOURCES = ("autopilot", "mocap")


class PositionSource:
    """The measured position of each tick (see the module docstring).

    Args:
        kind: "autopilot" or "mocap".
        frame: the bridge's trajectory frame (its mode and anchor are the mocap frame's).
        events: where the mocap's changes are said.
        max_age: a pose older than this [s] is stale.
        mocap: the mocap stream (None: none; ``kind`` "mocap" needs one).
    """

    def __init__(self, kind: str, frame: TrajectoryFrame, events: EventLog, max_age: float,
                 mocap: MocapInput | None = None) -> None:
        if kind not in POSITION_SOURCES:
            raise ValueError(f"position source must be one of {POSITION_SOURCES}; got {kind!r}")
        if kind == "mocap" and mocap is None:
            raise ValueError("position source 'mocap' needs the mocap stream (--mocap udpin:HOST:PORT)")
        self.kind, self.events, self.max_age, self.mocap = kind, events, max_age, mocap
        self.frame = TrajectoryFrame(frame.mode, anchor=tuple(frame.anchor))  # the mocap's trajectory frame
        self.estimate = np.full(3, np.nan)  # the autopilot's estimate this tick, trajectory frame [m]
        self.measured = np.full(3, np.nan)  # the mocap's this tick, trajectory frame [m] (nan: not used)
        self.offset = np.zeros(3)           # mocap - estimate at the last fresh tick [m]
        self.fresh = False                  # the newest pose is fresh
        self.stale_ticks = 0
        self.stale_events = 0
        self._stale_since: float | None = None
        self._first_said = False
        self._waiting_said = False

    @classmethod
    def for_bridge(cls, c: Any, frame: TrajectoryFrame, events: EventLog, limits: TelemetryLimits) -> PositionSource:
        """From the bridge's config ``c`` (``position_source``, ``mocap``, ``max_age``): the mocap link opened
        (a listening UDP link takes every sender: the poses carry no vehicle ids)."""
        try:
            mocap = MocapInput(MavLink(c.mocap, target_system=None), limits) if c.mocap else None
        except (OSError, LinkError) as e:
            raise LinkError(f"--mocap {c.mocap}: {e}") from None
        return cls(c.position_source, frame, events, c.max_age, mocap)

    @property
    def uses_mocap(self) -> bool:
        return self.kind == "mocap"

    @property
    def captured(self) -> bool:
        """The source's frame is known (the loop may engage)."""
        return not self.uses_mocap or self.frame.captured

    def pump(self) -> None:
        """Fold the pending poses in."""
        if self.mocap is not None:
            self.mocap.pump()

    def age(self, now: float, telemetry_age: float) -> float:
        """The tick's age [s]: the telemetry's, and with source mocap the older of it and the pose's (each
        change of the pose's freshness is an event)."""
        if self.mocap is None:
            return telemetry_age
        if self.uses_mocap and not self.mocap.present and not self._waiting_said:
            self._waiting_said = True
            self.events(f"position source mocap: no pose yet on {getattr(self.mocap.link, 'url', '?')}: stale ticks, "
                        "no engagement until the first pose")
        age = self.mocap.age(now)
        fresh = age <= self.max_age
        if fresh != self.fresh:
            self._said(now, fresh, age)
        self.fresh = fresh
        if not self.uses_mocap:
            return telemetry_age
        if not fresh:
            self.stale_ticks += 1
        return max(telemetry_age, age)

    def _said(self, now: float, fresh: bool, age: float) -> None:
        role = "" if self.uses_mocap else " (logged only: the position source is the autopilot)"
        if fresh:
            since = "first pose" if not self._first_said else f"fresh again after {now - self._stale_since:.3f} s"
            self.events(f"mocap {since}: {self.mocap.seq} poses, latency "
                        + ("unknown (stamps not on this clock)" if math.isnan(self.mocap.latency)
                           else f"{self.mocap.latency * 1e3:.1f} ms") + role)
            self._first_said, self._stale_since = True, None
            return
        self._stale_since = now
        if self._first_said:
            self.stale_events += 1
            why = f"no pose for {age * 1e3:.1f} ms (> {self.max_age * 1e3:.0f} ms)"
            fallback = ": stale ticks, the autopilot's estimate shifted to where the mocap last was" \
                if self.uses_mocap else ""
            self.events(f"mocap stale: {why}, dropped {dict(self.mocap.rejected)}{fallback}{role}")

    def capture(self, armed: bool) -> None:
        """Follow the vehicle with the mocap's frame (call while the bridge's frame follows it); heights from
        where it stands while disarmed."""
        m = self.mocap
        if m is None or not self.fresh:
            return
        self.frame.capture(m.position, m.yaw)
        if not armed:
            self.frame.z0 = float(m.position[2])

    def measure(self, state: Any) -> Any:
        """The tick's measured state (its position replaced in place with source mocap; returns it):
        ``state`` is the autopilot's, already in the trajectory frame."""
        self.estimate[:] = state.position
        self.measured[:] = np.nan
        if self.mocap is not None and self.fresh and self.frame.captured:
            self.measured[:] = self.frame.point(self.mocap.position.copy())
        if not self.uses_mocap:
            return state
        if np.isfinite(self.measured[0]):
            self.offset[:] = self.measured - self.estimate
            state.position[:] = self.measured
        else:
            state.position[:] = self.estimate + self.offset
        return state

    def columns(self, now: float) -> dict[str, Any]:
        """The tick log's columns of this tick (:func:`.ticklog.tick_fields`)."""
        out: dict[str, Any] = {"estimate_position": self.estimate}
        m = self.mocap
        if m is not None and self.fresh:
            out.update(mocap_position=m.position - np.array([0.0, 0.0, self.frame.z0]),
                       mocap_age_ms=m.age(now) * 1e3, mocap_latency_ms=m.latency * 1e3)
        return out

    def annotate(self, log: TickLog, t0: float) -> TickLog:
        """``log`` with the source in its metadata and every accepted pose's (stamp, rx - ``t0``) [s] in its samples
        (``sample_mocap``); returns it."""
        log.metadata["position_source"] = self.summary()
        if self.mocap is not None:
            log.samples["mocap"] = np.array(self.mocap.history, dtype=float).reshape(-1, 2) - np.array([0.0, t0])
        return log

    def summary(self) -> dict:
        """For the summary and the tick log's metadata."""
        out: dict[str, Any] = {"kind": self.kind, "frame": self.frame.as_dict() if self.mocap is not None else None}
        m = self.mocap
        if m is not None:
            lat = m.latencies()
            out.update(url=getattr(m.link, "url", None), poses=m.seq, dropped=m.dropped, rejected=dict(m.rejected),
                       foreign_stamps=m.foreign_stamps, stale_events=self.stale_events, stale_ticks=self.stale_ticks,
                       latency_ms=percentiles(lat * 1e3))
        return out

    def close(self) -> None:
        """Close the mocap link."""
        if self.mocap is not None:
            self.mocap.close()
