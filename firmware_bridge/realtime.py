"""Real-time setup of a tick loop on Linux, and a wake-up latency probe (``ddpc-rtcheck``).

A 200 Hz loop on a companion computer misses ticks when its process wakes up late. Three
causes are common, and each has a standard remedy that :func:`setup_realtime` applies (each
step opt-in, each refusal reported, never raised):

* the scheduler lets best-effort work finish its time slice first -> ``SCHED_FIFO`` priority;
* page faults on the tick path (first touch, swap-out) -> ``mlockall(MCL_CURRENT | MCL_FUTURE)``;
* a CPU in a deep idle state -- or, in a virtual machine, a halted vCPU whose host thread must
  be scheduled again -- wakes up milliseconds late -> a PM QoS request of 0 us on
  ``/dev/cpu_dma_latency`` (held while the loop runs; what ``cyclictest`` does). The CPUs then
  poll when idle instead of halting: more power drawn, far less wake-up jitter.

None of this removes latency the kernel itself adds: with preemption model "none" or
"voluntary" (:func:`kernel_preemption`), kernel code runs on until it yields, whatever the task's
priority. On a non-preemptible guest kernel the PM QoS request cuts the bridge demo's missed
ticks, not to zero (README, "Real time").
``ddpc-rtcheck`` measures the machine at hand.
"""

from __future__ import annotations

import argparse
import ctypes
import ctypes.util
import json
import os
import struct
import sys
import time
from dataclasses import dataclass, field

import numpy as np

__all__ = ["RealtimeSetup", "setup_realtime", "measure_wakeup_latency", "probe_cpus", "kernel_preemption",
           "PM_QOS_PATH"]

PM_QOS_PATH = "/dev/cpu_dma_latency"
_MCL_CURRENT, _MCL_FUTURE = 1, 2


@dataclass
class RealtimeSetup:
    """What :func:`setup_realtime` achieved. Keep it alive while the loop runs: the PM QoS
    request lasts as long as its file descriptor is open (:meth:`release` closes it)."""

    priority: int = 0
    notes: list[str] = field(default_factory=list)
    fifo: bool = False
    memory_locked: bool = False
    cpu_latency_us: int | None = None
    cpus: tuple[int, ...] | None = None
    _qos_fd: int | None = None

    def describe(self) -> str:
        """One line for logs and summaries, e.g. ``SCHED_FIFO 30, mlockall, cpu_dma_latency 0 us``."""
        return ", ".join(self.notes) if self.notes else "best effort"

    def release(self) -> None:
        """Drop the PM QoS request (the CPUs may sleep deeply again)."""
        if self._qos_fd is not None:
            try:
                os.close(self._qos_fd)
            except OSError:
                pass
            self._qos_fd = None

    def __enter__(self) -> "RealtimeSetup":
        return self

    def __exit__(self, *exc) -> None:
        self.release()


def _can_lock_unlimited(status: str = "/proc/self/status") -> bool:
    """CAP_IPC_LOCK (bit 14 of CapEff): locked memory is then not bounded by RLIMIT_MEMLOCK."""
    try:
        with open(status) as f:
            for line in f:
                if line.startswith("CapEff:"):
                    return bool(int(line.split()[1], 16) >> 14 & 1)
    except (OSError, ValueError, IndexError):
        pass
    return False


def _lock_memory() -> str | None:
    """mlockall; None on success, else why not. Without CAP_IPC_LOCK only when RLIMIT_MEMLOCK
    is unlimited: with MCL_FUTURE, a finite limit would turn later allocations into MemoryError
    (root in a container usually lacks CAP_IPC_LOCK)."""
    import resource

    soft, _ = resource.getrlimit(resource.RLIMIT_MEMLOCK)
    if not _can_lock_unlimited() and soft != resource.RLIM_INFINITY:
        return f"memory not locked (RLIMIT_MEMLOCK {soft} B; raise it with ulimit -l or run with CAP_IPC_LOCK)"
    libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
    if libc.mlockall(_MCL_CURRENT | _MCL_FUTURE) != 0:
        return f"memory not locked (mlockall: {os.strerror(ctypes.get_errno())})"
    return None


def setup_realtime(priority: int = 0, *, cpus: tuple[int, ...] | None = None, lock_memory: bool = True,
                   cpu_latency_us: int | None = 0, pm_qos_path: str = PM_QOS_PATH) -> RealtimeSetup:
    """Make this process a real-time loop, as far as permitted; never raises.

    Args:
        priority: SCHED_FIFO priority (1-99); <= 0 leaves the process best effort and skips the
            memory lock and the PM QoS request (``cpus`` still applies).
        cpus: pin the process to these CPUs (None: leave the affinity alone).
        lock_memory: mlockall current and future pages (with ``priority`` > 0).
        cpu_latency_us: PM QoS CPU wake-up latency bound [us] held while the returned object
            lives (with ``priority`` > 0; None: no request). 0 keeps the CPUs out of idle states.
        pm_qos_path: the PM QoS device (tests pass a plain file).

    Returns:
        RealtimeSetup; ``describe()`` lists what was applied and what was refused and why.
    """
    rt = RealtimeSetup(priority=max(0, int(priority)))
    if cpus is not None:
        try:
            os.sched_setaffinity(0, set(int(c) for c in cpus))
            rt.cpus = tuple(sorted(os.sched_getaffinity(0)))
            rt.notes.append(f"CPUs {','.join(map(str, rt.cpus))}")
        except (AttributeError, OSError, ValueError) as e:
            rt.notes.append(f"affinity {tuple(cpus)} refused: {e}")
    if rt.priority <= 0:
        return rt
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(rt.priority))
        rt.fifo = True
        rt.notes.append(f"SCHED_FIFO {rt.priority}")
    except (AttributeError, PermissionError, OSError) as e:
        rt.notes.append(f"best effort (SCHED_FIFO {rt.priority} refused: {e})")
    if lock_memory:
        why = _lock_memory()
        rt.memory_locked = why is None
        rt.notes.append("mlockall" if why is None else why)
    if cpu_latency_us is not None:
        try:
            fd = os.open(pm_qos_path, os.O_WRONLY)
            try:
                os.write(fd, struct.pack("i", int(cpu_latency_us)))
            except OSError:
                os.close(fd)
                raise
            rt._qos_fd = fd
            rt.cpu_latency_us = int(cpu_latency_us)
            rt.notes.append(f"cpu_dma_latency {int(cpu_latency_us)} us")
        except OSError as e:
            rt.notes.append(f"no PM QoS request ({pm_qos_path}: {e.strerror or e})")
    return rt


def _boot_log_preempt(kmsg: str) -> str | None:
    """The mode from the boot log line "Dynamic Preempt: <mode>" (if the log is readable and still has it)."""
    try:
        fd = os.open(kmsg, os.O_RDONLY | os.O_NONBLOCK)
    except OSError:
        return None
    try:
        for _ in range(100_000):  # one record per read; EAGAIN at the end of the buffer
            try:
                rec = os.read(fd, 8192)
            except BlockingIOError:
                return None
            except OSError:  # EPIPE: a record was overwritten while reading; go on
                continue
            if not rec:
                return None
            text = rec.decode(errors="replace")
            if "Dynamic Preempt:" in text:
                return text.split("Dynamic Preempt:", 1)[1].split()[0]
        return None
    finally:
        os.close(fd)


def kernel_preemption(version: str | None = None, debugfs: str = "/sys/kernel/debug/sched/preempt",
                      cmdline: str = "/proc/cmdline", kmsg: str = "/dev/kmsg") -> str:
    """The kernel's preemption model, as far as it can be read: "PREEMPT_RT", "full",
    "voluntary", "none", "lazy", or "dynamic (mode not readable)" / "unknown".

    With "none" or "voluntary", kernel code runs to its next scheduling point before a waking
    SCHED_FIFO task gets the CPU: milliseconds of latency that no user-space setting removes
    (boot with ``preempt=full`` or a PREEMPT_RT kernel on the robot)."""
    v = os.uname().version if version is None else version
    if "PREEMPT_RT" in v:
        return "PREEMPT_RT"
    try:
        with open(debugfs) as f:  # e.g. "none voluntary (full) lazy"
            for word in f.read().split():
                if word.startswith("(") and word.endswith(")"):
                    return word[1:-1]
    except OSError:
        pass
    if "PREEMPT_DYNAMIC" in v:
        try:
            with open(cmdline) as f:
                for arg in f.read().split():
                    if arg.startswith("preempt="):
                        return arg.split("=", 1)[1]
        except OSError:
            pass
        mode = _boot_log_preempt(kmsg)
        return mode or "dynamic (mode not readable)"
    if "PREEMPT" in v.split():
        return "full"
    return "none or voluntary" if v else "unknown"


def measure_wakeup_latency(duration: float = 5.0, *, period: float = 0.001, priority: int = 0,
                           cpu: int | None = None, cpu_latency_us: int | None = None) -> dict:
    """How late this process wakes from a periodic absolute-deadline sleep (a small cyclictest).

    Args:
        duration: seconds to measure. period: sleep period [s].
        priority, cpu, cpu_latency_us: as :func:`setup_realtime` (no memory lock; restored after).

    Returns:
        {"n", "p50_us", "p99_us", "p9999_us", "max_us", "over_1ms", "over_2500us", "setup"}:
        lateness statistics [us] and the count of wake-ups later than 1 ms / half a 200 Hz tick.
    """
    old_aff = os.sched_getaffinity(0)
    old_pol, old_prm = os.sched_getscheduler(0), os.sched_getparam(0)
    rt = setup_realtime(priority, cpus=None if cpu is None else (cpu,), lock_memory=False,
                        cpu_latency_us=cpu_latency_us)
    n = int(round(duration / period))
    late = np.empty(n)
    try:
        t0 = time.monotonic()
        for k in range(n):
            target = t0 + (k + 1) * period
            dt = target - time.monotonic()
            if dt > 0:
                time.sleep(dt)
            late[k] = time.monotonic() - target
            if late[k] > period:  # resynchronise: one stall is one sample, not a burst of catch-ups
                t0 = time.monotonic() - (k + 1) * period
    finally:
        rt.release()
        try:
            os.sched_setscheduler(0, old_pol, old_prm)
        except OSError:
            pass
        os.sched_setaffinity(0, old_aff)
    us = late * 1e6
    return {"n": n, "p50_us": float(np.percentile(us, 50)), "p99_us": float(np.percentile(us, 99)),
            "p9999_us": float(np.percentile(us, 99.99)), "max_us": float(us.max()),
            "over_1ms": int((us > 1000).sum()), "over_2500us": int((us > 2500).sum()), "setup": rt.describe()}


def probe_cpus(duration: float, *, priority: int, cpus: list[int] | None = None, cpu_latency_us: int | None = 0,
               period: float = 0.001, log=None) -> list[dict]:
    """:func:`measure_wakeup_latency` on each CPU, first without a PM QoS request, then (with
    ``priority`` > 0 and ``cpu_latency_us`` not None) with it. ``log`` gets one line per row.

    Returns:
        [{"cpu", "pm_qos_us", **measure_wakeup_latency(...)}, ...]
    """
    cpus = sorted(os.sched_getaffinity(0)) if cpus is None else list(cpus)
    # the PM QoS request comes with real time only (setup_realtime)
    qos_values = [None] + ([int(cpu_latency_us)] if priority > 0 and cpu_latency_us is not None else [])
    rows = []
    for qos in qos_values:
        for c in cpus:
            r = measure_wakeup_latency(duration, period=period, priority=priority, cpu=c, cpu_latency_us=qos)
            rows.append({"cpu": c, "pm_qos_us": qos, **r})
            if log is not None:
                log(f"cpu {c}  PM QoS {'-' if qos is None else f'{qos} us':>5}  p50 {r['p50_us']:7.0f}  "
                    f"p99 {r['p99_us']:7.0f}  p99.99 {r['p9999_us']:7.0f}  max {r['max_us']:7.0f} us  "
                    f">1 ms {r['over_1ms']:4d}  >2.5 ms {r['over_2500us']:4d}   [{r['setup']}]")
    return rows


def main(argv: list[str] | None = None) -> int:
    """``ddpc-rtcheck``: wake-up latency of this machine per CPU, without and with the PM QoS request."""
    p = argparse.ArgumentParser(
        prog="ddpc-rtcheck",
        description="Measure how late a periodic real-time sleeper wakes up on this machine (per CPU), without "
                    "and with a 0 us PM QoS request -- whether a 200 Hz bridge loop can hold its ticks here.")
    p.add_argument("--duration", type=float, default=10.0, help="seconds per measurement")
    p.add_argument("--period-us", type=float, default=1000.0, help="sleep period [us]")
    p.add_argument("--rt-priority", type=int, default=50, help="SCHED_FIFO priority (0: best effort)")
    p.add_argument("--cpus", default=None, help="comma-separated CPUs (default: each CPU this process may use)")
    p.add_argument("--json", action="store_true", help="print the results as JSON")
    a = p.parse_args(argv)
    if a.duration <= 0 or a.period_us <= 0:
        p.error("--duration and --period-us must be positive")
    try:
        cpus = sorted(os.sched_getaffinity(0)) if a.cpus is None else [int(c) for c in a.cpus.split(",")]
    except ValueError:
        p.error(f"--cpus expects comma-separated CPU numbers; got {a.cpus!r}")
    preempt = kernel_preemption()
    if not a.json:
        print(f"kernel {os.uname().release}: preemption {preempt}", flush=True)
    rows = probe_cpus(a.duration, priority=a.rt_priority, cpus=cpus, period=a.period_us * 1e-6,
                      log=None if a.json else (lambda line: print(line, flush=True)))
    if a.json:
        print(json.dumps({"kernel": os.uname().release, "preemption": preempt, "rows": rows}, indent=2))
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
