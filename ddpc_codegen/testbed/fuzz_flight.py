"""One bridge configuration flown against the simulated vehicle for the fuzzer, and what is checked on it.

In-process lock-step: the real :class:`firmware_bridge.bridge.Bridge` (every part of ``ddpc-bridge``: link,
telemetry plausibility, engagement, reference stage, last gate, setpoints) in this thread and the real
:class:`ddpc_codegen.testbed.vehicle.SimVehicle` (``ddpc-vehicle``: the simulator's plant, the PX4-like
autopilot) in a second one, over UDP on 127.0.0.1 in lock-step: the vehicle advances one tick per setpoint, so a
flight runs as fast as the two can compute, on one core. The same pair as two processes:
:func:`fly_processes`. Nothing of either is copied: a flight here is a ``ddpc-bridge`` flight.

What a flight is judged on (:class:`FlightCheck`):

* the vehicle's *true* position (the simulator's state, never the telemetry) inside the envelope's box: height
  within [``z_min``, ``z_max``] from the take-off point (the simulator's ground) and horizontal distance from
  where the path started (the bridge's frame origin) within ``radius``, each widened by :data:`TRACK_MARGIN_M`;
* every applied reference (the tick log's ``u``) within the envelope's rate bound of the one applied on the tick
  before (``ref_rate`` / rate, per reference).
"""

from __future__ import annotations

import json
import math
import subprocess
import threading
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ddpc_codegen.errors import DDPCError
from ddpc_codegen.robot.profile import Envelope
from ddpc_codegen.testbed.bridge_flights import child_env, free_udp_port, python_m, stop_process
from ddpc_codegen.testbed.vehicle import SimVehicle, VehicleConfig

from firmware_bridge.bridge import Bridge, BridgeConfig, FlightError, NoVehicleError
from firmware_bridge.cli import bridge_config_from_args, build_bridge_parser
from firmware_bridge.link import LinkError, MavLink
from firmware_bridge.preflight import PreflightError
from firmware_bridge.ticklog import load_ticklog

__all__ = ["TRACK_MARGIN_M", "RATE_TOL", "REFUSALS", "COUNTED", "LOCKSTEP_ARGS", "FlightCheck", "accept",
           "fly_in_process", "fly_processes", "vehicle_link", "envelope_excess", "rate_ratio"]

# The envelope bounds the references; the vehicle follows them with its own controller's tracking error. A
# reference stopped at the envelope's edge while the path moved at max_speed is overshot by the closed loop
# (the model-based height loop and the attitude loop under it) by less than this: a vehicle further out
# was sent somewhere it should not have been.
TRACK_MARGIN_M = 0.3
RATE_TOL = 1e-6  # relative: float rounding of the gate's clip, never a real step
# Every fuzzed flight: lock-step, the bridge switches to off-board itself after a short pre-stream, and a wall
# clock bound; the mutant's own flags come after these.
LOCKSTEP_ARGS = ("--lockstep", "--offboard", "--prestream", "0.1", "--timeout", "30", "--wait-heartbeat", "5",
                 "--vehicle-lost-timeout", "3")
REFUSALS = (ValueError, DDPCError, OSError, LinkError)
# The summary's counters a fuzzed flight keeps: the link's (``summary["link"]``) and the vehicle link's own.
COUNTED = (("link", "peer_changes"), ("link", "foreign_packets"), ("link", "foreign_heartbeats"), ("link", "unpinned"),
           ("link", "bad_data"), ("link", "parse_errors"), ("link", "unsigned"), ("link", "bad_signature"), (None, "reboots"), (None, "stream_requests"),
           (None, "link_losses"), (None, "telemetry_dropped"))


@dataclass
class FlightCheck:
    """One flight's verdict.

    Attributes:
        outcome: "flown", "refused" (when set up or before arming: the steering solver, the vehicle's hover
            thrust), or "error: ..." (an exception that is not a refusal: a defect of its own).
        ticks: bridge ticks; engaged_ticks: ticks steered / flown engaged.
        excess_m: how far the true position got outside the envelope's box (negative: the closest it came to
            an edge, inside) [m]; margin [m] allowed beyond it.
        rate_ratio: largest one-tick change of an applied reference over its rate bound (<= 1: within).
        stop_reason, exit_code: the bridge's; z_range [m], radius_m: the truth's extent.
        counts: the bridge's link and telemetry counters (:data:`COUNTED`).
    """

    outcome: str
    ticks: int = 0
    engaged_ticks: int = 0
    excess_m: float = -math.inf
    margin: float = TRACK_MARGIN_M
    rate_ratio: float = 0.0
    stop_reason: str = ""
    exit_code: int | None = None
    z_range: tuple[float, float] = (math.nan, math.nan)
    radius_m: float = math.nan
    notes: list[str] = field(default_factory=list)
    counts: dict = field(default_factory=dict)

    @property
    def violation(self) -> bool:
        """The vehicle left its envelope (beyond the margin) or a reference stepped beyond the rate bound."""
        return self.outcome == "flown" and (self.excess_m > self.margin or self.rate_ratio > 1.0 + RATE_TOL)

    def as_dict(self) -> dict:
        return {"outcome": self.outcome, "ticks": self.ticks, "engaged_ticks": self.engaged_ticks,
                "excess_m": _r(self.excess_m), "rate_ratio": _r(self.rate_ratio), "stop_reason": self.stop_reason,
                "exit_code": self.exit_code, "z_range": [_r(v) for v in self.z_range], "radius_m": _r(self.radius_m),
                "violation": self.violation, "notes": self.notes, "counts": self.counts}


def _r(v: float) -> float | None:
    return round(float(v), 5) if math.isfinite(v) else None


def accept(args: list[str], port: int, duration: float, lockstep: bool = True) -> BridgeConfig:
    """The bridge config ``ddpc-bridge udpin:127.0.0.1:PORT`` + :data:`LOCKSTEP_ARGS` (without ``--lockstep``: a
    real-time flight) + ``--duration`` + ``args`` makes: every loader and every before-arming path check of the
    command line runs.

    Raises:
        ValueError, DDPCError, OSError, LinkError: the refusal ``ddpc-bridge`` exits 2 with; SystemExit: argparse's.
    """
    fixed = [x for x in LOCKSTEP_ARGS if lockstep or x != "--lockstep"]
    a = build_bridge_parser().parse_args([f"udpin:127.0.0.1:{port}", *fixed, "--duration", f"{duration:g}", *args])
    return bridge_config_from_args(a)


def envelope_excess(pos: np.ndarray, origin_xy, env: Envelope) -> tuple[float, tuple[float, float], float]:
    """(largest distance outside the box [m] (negative: inside by that much), (lowest, highest height) [m],
    largest horizontal distance from ``origin_xy`` [m]) of true positions ``pos`` (N, 3) [m, ENU, z from the
    take-off point]."""
    if pos.size == 0:
        return -math.inf, (math.nan, math.nan), math.nan
    z = pos[:, 2]
    rad = np.hypot(pos[:, 0] - origin_xy[0], pos[:, 1] - origin_xy[1])
    out = np.maximum.reduce([env.z_min - z, z - env.z_max, rad - env.radius])
    return float(np.max(out)), (float(z.min()), float(z.max())), float(rad.max())


def rate_ratio(u: np.ndarray, step: np.ndarray, flown: np.ndarray | None = None) -> float:
    """Largest one-tick change of the references ``u`` (N, m) over their bound per tick ``step`` (m,), between
    ticks whose references the vehicle flew (``flown`` (N,): armed in off-board as the bridge knew it; None:
    all). A reference computed while the vehicle was disarmed or in its own mode was never flown: the first
    engaged tick starts at the nominal reference, not from it."""
    if u.shape[0] < 2:
        return 0.0
    du = np.abs(np.diff(u, axis=0)) / np.asarray(step, dtype=float)
    if flown is not None:
        f = np.asarray(flown, dtype=bool)
        du = du[f[:-1] & f[1:]]
    return float(np.max(du)) if du.size else 0.0


def _rate_step(cfg: BridgeConfig) -> np.ndarray:
    return (cfg.envelope or Envelope()).ref_rates(cfg.scenario) / cfg.rate_hz


def vehicle_link(url: str, signing_key: bytes | None = None) -> MavLink:
    """The link :class:`SimVehicle` would open on ``url`` (system 1, component 1), signing with ``signing_key``."""
    return MavLink(url, source_system=1, source_component=1, target_system=None, signing_key=signing_key)


def _vehicle_thread(v: SimVehicle, bridge: Bridge, done: threading.Event) -> threading.Thread:
    """The vehicle's loop; when its simulated time is up, the bridge is stopped (the flight's end)."""
    def run() -> None:
        try:
            v.run(install_signals=False)
        finally:
            done.set()
            bridge.stop()

    return threading.Thread(target=run, name="fuzz-vehicle", daemon=True)


def fly_in_process(cfg: BridgeConfig, work: Path, *, sim_time: float, seed: int,
                   vehicle_url: str | None = None, vehicle_link: MavLink | None = None) -> FlightCheck:
    """Fly ``cfg`` (from :func:`accept`, listening on its port) against a :class:`SimVehicle` in a thread for
    ``sim_time`` s of vehicle time, and judge it (see the module docstring). Lock-step or real time as ``cfg``.

    Args:
        work: a folder for the vehicle's truth log. seed: the vehicle's sensor-noise seed.
        vehicle_url: where the vehicle sends (default: the bridge's port; a relay's, to fuzz the link).
        vehicle_link: the vehicle's link, made by the caller (signing, a known local address; see :func:`vehicle_link`).
    """
    port = int(cfg.url.rsplit(":", 1)[1])
    truth_path = Path(work) / "truth.npz"
    truth_path.unlink(missing_ok=True)
    vc = VehicleConfig(url=vehicle_url or f"udpout:127.0.0.1:{port}", lockstep=cfg.lockstep, lockstep_timeout=0.05,
                       peer_timeout=2.0, seed=seed, duration=sim_time, truth_log=str(truth_path), scenario=cfg.scenario)
    try:
        bridge = Bridge(cfg)  # ddpc-bridge's last refusals: the steering solver against the path and the loop
    except REFUSALS as e:
        if vehicle_link is not None:
            vehicle_link.close()
        return FlightCheck("refused", notes=[f"refused: {e}"])
    v = SimVehicle(vc, vehicle_link)
    done = threading.Event()
    th = _vehicle_thread(v, bridge, done)
    th.start()
    outcome, summary = "flown", None
    try:
        summary = bridge.run(install_signals=False)
    except PreflightError as e:
        outcome = f"refused: {e}"
    except (NoVehicleError, FlightError) as e:
        outcome = f"error: {type(e).__name__}: {e}"
    except Exception as e:  # noqa: BLE001 -- the fuzzer reports whatever escapes, it never stops on it
        outcome = f"error: {type(e).__name__}: {e}"
    finally:
        v.stop()
        th.join(10)
    if outcome != "flown":
        return FlightCheck("refused" if outcome.startswith("refused") else outcome, notes=[outcome])
    rows = bridge.recorder.rows.view()
    return _judge(cfg, summary, rows["u"], rows["active"], truth_path, bridge.frame.origin if bridge.engagement.flown
                  else None, rows["armed"] & rows["offboard"])


def _judge(cfg: BridgeConfig, summary: dict, u: np.ndarray, engaged: np.ndarray, truth_path: Path,
           origin_xy, flown: np.ndarray) -> FlightCheck:
    """The verdict of a flight from its applied references, the truth log and the bridge's frame origin (None: the
    bridge never flew, the vehicle's true start: a frame captured from forged telemetry is not where it is)."""
    env = cfg.envelope or Envelope()
    check = FlightCheck("flown", ticks=int(summary["ticks"]), engaged_ticks=int(np.sum(engaged)),
                        stop_reason=str(summary["stop_reason"]), exit_code=int(summary["exit"]["code"]))
    check.counts = {key: int((summary.get(table) or {}).get(key, 0) if table else summary.get(key, 0))
                    for table, key in COUNTED}
    check.rate_ratio = rate_ratio(np.asarray(u, dtype=float), _rate_step(cfg), flown)
    if not truth_path.exists():
        check.notes.append("no truth log")
        return check
    with np.load(truth_path) as t:
        pos = np.asarray(t["state"])[:, 0:3]
    if origin_xy is None:
        origin_xy = pos[0, :2]
    check.excess_m, check.z_range, check.radius_m = envelope_excess(pos, origin_xy, env)
    return check


def fly_processes(args: list[str], cfg: BridgeConfig, work: Path, *, sim_time: float, seed: int,
                  timeout: float = 60.0) -> FlightCheck:
    """The same flight as :func:`fly_in_process` with ``ddpc-vehicle`` and ``ddpc-bridge`` as processes over UDP
    loopback (``args``: the mutant's flags, ``cfg`` what :func:`accept` made of them), bounded by ``timeout`` s of
    wall time; both processes are stopped by their pid whatever happens."""
    work = Path(work)
    port = free_udp_port()
    truth, log = work / "proc_truth.npz", work / "proc_flight.npz"
    for p in (truth, log):
        p.unlink(missing_ok=True)
    veh = br = None
    try:
        veh = subprocess.Popen(python_m() + ["ddpc_codegen.testbed.vehicle_cli", f"udpout:127.0.0.1:{port}",
                                             "--lockstep", "--lockstep-timeout", "0.05", "--seed", str(seed),
                                             "--scenario", cfg.scenario,
                                             "--duration", str(sim_time), "--truth-log", str(truth)],
                               env=child_env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, cwd=work)
        br = subprocess.Popen(python_m() + ["firmware_bridge.cli", f"udpin:127.0.0.1:{port}", *LOCKSTEP_ARGS,
                                            "--duration", f"{cfg.duration:g}", *args, "--log", str(log),
                                            "--overwrite", "--json"],
                              env=child_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, cwd=work, text=True)
        # the bridge ends on its --duration (or, never engaged, on the vehicle's end: vehicle lost)
        out, err = br.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        return FlightCheck(f"error: the process flight did not end in {timeout:g} s")
    finally:
        stop_process(br)
        stop_process(veh)
    if br.returncode == 2 and not log.exists():  # refused when the bridge was set up (its solver): one line
        return FlightCheck("refused", notes=[f"refused: {err.strip().splitlines()[-1] if err.strip() else ''}"])
    if not log.exists() or not out.strip().startswith("{"):
        return FlightCheck(f"error: ddpc-bridge exited {br.returncode} without a log: {err.strip()[-300:]}")
    tl = load_ticklog(log)
    summary = json.loads(out)
    origin = summary["frame"]["origin"] if summary.get("activations") else None
    return _judge(cfg, summary, tl.ticks["u"], tl.ticks["active"], truth, origin,
                  tl.ticks["armed"].astype(bool) & tl.ticks["offboard"].astype(bool))

