"""firmware_bridge.realtime: the real-time setup never raises, reports what it did, holds and
releases the PM QoS request; the wake-up probe measures; ddpc-rtcheck and the --cpus flag."""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys

import pytest

from ddpc_codegen.testbed.vehicle_cli import build_vehicle_parser
from firmware_bridge.cli import build_bridge_parser
from firmware_bridge.realtime import main as rtcheck_main
from firmware_bridge.realtime import kernel_preemption, measure_wakeup_latency, setup_realtime

pytestmark = pytest.mark.realtime


def test_best_effort_does_nothing(tmp_path):
    qos = tmp_path / "qos"
    qos.write_bytes(b"")
    rt = setup_realtime(0, pm_qos_path=str(qos))
    assert rt.describe() == "best effort"
    assert not rt.fifo and not rt.memory_locked and rt.cpu_latency_us is None
    assert qos.read_bytes() == b""  # no request without a real-time priority
    rt.release()


def _run_setup(code: str) -> dict:
    """Real-time setup changes the whole process (FIFO, mlockall): do it in a child, not in pytest."""
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout)


def test_pm_qos_request_is_written_held_and_released(tmp_path):
    qos = tmp_path / "qos"
    qos.write_bytes(b"")
    out = _run_setup(f"""
import json, os
from firmware_bridge.realtime import setup_realtime
rt = setup_realtime(10, cpu_latency_us=7, lock_memory=False, pm_qos_path={str(qos)!r})
fd = rt._qos_fd
held = fd is not None and os.fstat(fd).st_size == 4
rt.release()
try:
    os.fstat(fd); closed = False
except OSError:
    closed = True
print(json.dumps({{"desc": rt.describe(), "held": held, "closed": closed, "lat": rt.cpu_latency_us}}))
""")
    assert qos.read_bytes() == struct.pack("i", 7)
    assert out["held"] and out["closed"] and out["lat"] == 7
    assert "cpu_dma_latency 7 us" in out["desc"]
    # SCHED_FIFO granted or refused, either way said so.
    assert "SCHED_FIFO 10" in out["desc"]


def test_refusals_are_reported_not_raised(tmp_path):
    out = _run_setup(f"""
import json
from firmware_bridge.realtime import setup_realtime
rt = setup_realtime(10, cpus=(10_000,), pm_qos_path={str(tmp_path / 'missing' / 'qos')!r})
print(json.dumps({{"desc": rt.describe(), "lat": rt.cpu_latency_us, "fd": rt._qos_fd}}))
""")
    assert out["lat"] is None and out["fd"] is None
    assert "no PM QoS request" in out["desc"]
    assert "affinity (10000,) refused" in out["desc"]


def test_affinity_alone_applies_without_priority():
    cpu = min(os.sched_getaffinity(0))
    out = _run_setup(f"""
import json, os
from firmware_bridge.realtime import setup_realtime
rt = setup_realtime(0, cpus=({cpu},))
print(json.dumps({{"desc": rt.describe(), "aff": sorted(os.sched_getaffinity(0))}}))
""")
    assert out["aff"] == [cpu] and out["desc"] == f"CPUs {cpu}"


def test_wakeup_probe_measures_and_restores_the_process():
    aff, pol = os.sched_getaffinity(0), os.sched_getscheduler(0)
    cpu = min(aff)
    r = measure_wakeup_latency(0.2, period=0.002, cpu=cpu)
    assert r["n"] == 100
    # Every sleep ends at or after its deadline (the kernel never wakes a sleeper early).
    assert 0.0 <= r["p50_us"] <= r["p99_us"] <= r["p9999_us"] <= r["max_us"]
    assert r["over_2500us"] <= r["over_1ms"] <= r["n"]
    assert r["setup"] == f"CPUs {cpu}"
    assert os.sched_getaffinity(0) == aff and os.sched_getscheduler(0) == pol


@pytest.mark.parametrize("prio, qos", [(0, [None]), (5, [None, 0])])
def test_rtcheck_cli_json(prio, qos, capsys):
    cpu = min(os.sched_getaffinity(0))
    pol = os.sched_getscheduler(0)
    assert rtcheck_main(["--duration", "0.05", "--rt-priority", str(prio), "--json", "--cpus", str(cpu)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["preemption"] and out["kernel"] == os.uname().release
    rows = out["rows"]
    assert [(r["cpu"], r["pm_qos_us"]) for r in rows] == [(cpu, q) for q in qos]
    assert all(r["n"] == 50 for r in rows)
    assert os.sched_getscheduler(0) == pol  # the probe's real-time setup is undone


def test_rtcheck_cli_rejects_nonpositive_duration(capsys):
    with pytest.raises(SystemExit) as e:
        rtcheck_main(["--duration", "0"])
    assert e.value.code == 2
    assert "--duration and --period-us must be positive" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        rtcheck_main(["--cpus", "0,x"])
    assert "--cpus expects comma-separated CPU numbers; got '0,x'" in capsys.readouterr().err


@pytest.mark.parametrize("build", [build_bridge_parser, build_vehicle_parser])
def test_realtime_flags(build, capsys):
    a = build().parse_args(["udpin:127.0.0.1:14540", "--rt-priority", "30", "--cpus", "1,2", "--cpu-latency-us", "-1"])
    assert (a.rt_priority, a.cpus, a.cpu_latency_us) == (30, (1, 2), -1)
    with pytest.raises(SystemExit):
        build().parse_args(["udpin:127.0.0.1:14540", "--cpus", "one"])
    assert "expected comma-separated CPU numbers, got 'one'" in capsys.readouterr().err


def test_kernel_preemption_model(tmp_path):
    none = tmp_path / "none"
    assert kernel_preemption("#1 SMP PREEMPT_RT Mon", debugfs=str(none)) == "PREEMPT_RT"
    dbg = tmp_path / "preempt"
    dbg.write_text("none voluntary (full) lazy\n")
    assert kernel_preemption("#1 SMP PREEMPT_DYNAMIC", debugfs=str(dbg)) == "full"
    cmd = tmp_path / "cmdline"
    cmd.write_text("quiet preempt=voluntary ro\n")
    assert kernel_preemption("#1 SMP PREEMPT_DYNAMIC", debugfs=str(none), cmdline=str(cmd)) == "voluntary"
    assert kernel_preemption("#1 SMP PREEMPT_DYNAMIC", debugfs=str(none), cmdline=str(none),
                             kmsg=str(none)) == "dynamic (mode not readable)"
    log = tmp_path / "kmsg"
    log.write_text("6,120,219334,-;Dynamic Preempt: none\n")
    assert kernel_preemption("#1 SMP PREEMPT_DYNAMIC", debugfs=str(none), cmdline=str(none), kmsg=str(log)) == "none"
    assert kernel_preemption("#1 SMP PREEMPT Mon", debugfs=str(none)) == "full"
    assert kernel_preemption("#1 SMP Mon", debugfs=str(none)) == "none or voluntary"


def test_memory_is_locked_only_when_it_cannot_run_out(tmp_path):
    # With MCL_FUTURE and a finite RLIMIT_MEMLOCK (no CAP_IPC_LOCK), later allocations would fail
    # mid-flight: the lock must be skipped then, and said why.
    from firmware_bridge.realtime import _can_lock_unlimited

    st = tmp_path / "status"
    st.write_text("Name:\tpython\nCapEff:\t00000000a80425fb\n")  # docker's default set: no IPC_LOCK
    assert not _can_lock_unlimited(str(st))
    st.write_text("Name:\tpython\nCapEff:\t000001ffffffffff\n")
    assert _can_lock_unlimited(str(st))
    out = _run_setup("""
import json, resource
from firmware_bridge import realtime
realtime._can_lock_unlimited = lambda: False
hard = resource.getrlimit(resource.RLIMIT_MEMLOCK)[1]
resource.setrlimit(resource.RLIMIT_MEMLOCK, (1 << 30 if hard == resource.RLIM_INFINITY else hard, hard))
rt = realtime.setup_realtime(5, cpu_latency_us=None)
print(json.dumps({"desc": rt.describe(), "locked": rt.memory_locked}))
""")
    assert not out["locked"] and "memory not locked (RLIMIT_MEMLOCK " in out["desc"]
