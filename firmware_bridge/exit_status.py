"""How a bridge run ended, as ``ddpc-bridge``'s exit code and one line saying why (:func:`run_outcome`), and
the table of every code (:data:`EXIT_CODES`: the CLI's help epilog and the bridge guide list the same).

Exit 0 means something was flown and the run ended as asked: the ``--duration`` flown, or stopped by a
signal or ``--timeout`` while the bridge steered. A run that never engaged, that ended with the vehicle in a
mode of its own (its failsafe or the pilot took it out of off-board and did not give it back), or that timed
out before the ``--duration`` was flown is not a flight that happened, and says so."""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["EXIT_CODES", "RunEnd", "run_outcome", "exit_codes_epilog"]

EXIT_CODES = {
    0: "flown: the --duration flown, or stopped (signal, --timeout) while engaged",
    2: "configuration error (a flag, a file, an output path), before anything connects",
    3: "no vehicle answered within --wait-heartbeat",
    4: "the vehicle is not what the bridge was told (preflight: autopilot, GUID_OPTIONS)",
    5: "a flight phase failed (arming refused until --arm-timeout)",
    6: "interrupted (SIGINT / SIGTERM) before the first tick",
    7: "vehicle lost: nothing heard for --vehicle-lost-timeout",
    8: "never engaged: the vehicle was never armed + off-board while the bridge ran (nothing flown)",
    9: "the vehicle's own failsafe: it left off-board by itself and the run ended so",
    10: "--timeout before the --duration was flown",
}


@dataclass(frozen=True)
class RunEnd:
    """What the outcome depends on.

    Attributes:
        stop_reason: the bridge's stop reason ("signal", "timeout 30 s", "duration 20 s flown", "vehicle lost", ...).
        ticks: ticks run; activations: engagements (armed + off-board) seen.
        engaged: engaged at the last tick; left_mode: the vehicle's mode when it last left off-board ("": never).
        flown_s: trajectory time flown [s]; duration: --duration [s] (None: none).
        lost_after: --vehicle-lost-timeout [s].
    """

    stop_reason: str
    ticks: int
    activations: int
    engaged: bool
    left_mode: str = ""
    flown_s: float = 0.0
    duration: float | None = None
    lost_after: float = 10.0


def run_outcome(end: RunEnd) -> tuple[int, str]:
    """(exit code, one line saying why; "" for 0) of a run that got past its preflight (see :data:`EXIT_CODES`)."""
    why = end.stop_reason or "stopped"
    if why == "vehicle lost":
        return 7, f"vehicle lost: nothing heard for {end.lost_after:g} s"
    if end.ticks == 0 and why == "signal":
        return 6, "interrupted before the first tick (nothing flown)"
    if end.activations == 0:
        seen = "no telemetry arrived (0 ticks)" if end.ticks == 0 else "the vehicle was never armed + off-board"
        return 8, f"never engaged ({why}): {seen}; nothing flown"
    if not end.engaged and end.left_mode and not why.startswith("duration"):
        return 9, (f"ended in the vehicle's own mode {end.left_mode} ({why}): it left off-board by itself "
                   f"(failsafe or pilot) after {end.flown_s:.1f} s of the trajectory")
    if why.startswith("timeout") and end.duration is not None:
        return 10, f"{why} before the --duration was flown ({end.flown_s:.1f} of {end.duration:g} s)"
    return 0, ""


def exit_codes_epilog() -> str:
    """The exit codes, one per line, for a help text."""
    return "Exit codes:\n" + "\n".join(f"  {code:>2}  {text}" for code, text in EXIT_CODES.items())
