"""The online predictor update timed by a C program (issue 30's target: "in C, also under qemu aarch64"): the
emitted folder's library built by its own Makefile, natively and with the aarch64 cross compiler, linked with
``<name>_adapt_bench`` (``templates/adapt_bench.c.in``: init, one push per window, each period's fold into R and
snapshot, a few re-solves, each call timed
with ``clock_gettime(CLOCK_MONOTONIC)``); the aarch64 build runs under qemu-user, the native build of the same
program in the same run is the reference (qemu's slowdown is the ratio). Both runs must agree on what they computed
(the re-solve's verdict, the updated R and the candidate G) before a time is reported.
"""

from __future__ import annotations

import json
import os
import shlex
import subprocess
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ddpc_codegen.codegen import standalone
from ddpc_codegen.codegen.build import include_dirs_of
from ddpc_codegen.codegen.render import render
from ddpc_codegen.errors import CodegenError

RUN_TIMEOUT_S = 300.0  # qemu runs the flying size's 2000 pushes and 9 re-solves in ~1 s; a hang must not stall make bench
AGREE_RTOL = 1e-9  # native vs aarch64 checksums (ISO C: no FMA contraction, the same operations in the same order)


def build_timer(folder: Path, cc: str | None = None, build: str = "build-adapt-bench") -> Path:
    """``lib<name>.a`` by the folder's Makefile (``CC=cc``; None: the host compiler, ``$CC`` or ``cc``) and the timing
    program linked with it; returns the executable."""
    folder = Path(folder)
    name = standalone.solver_name(folder)
    # the Makefile's default CFLAGS (-O3) and the phase clock the timing program provides
    args = ["make", "-s", f"BUILD={build}", f"{build}/lib{name}.a",
            f"CFLAGS=-O3 -D{name.upper()}_ADAPT_CLOCK={name}_bench_clock_ns"] + ([f"CC={cc}"] if cc else [])
    res = subprocess.run(args, cwd=folder, capture_output=True, text=True, timeout=900)
    if res.returncode != 0:
        raise CodegenError(f"`{' '.join(args)}` failed in {folder}:\n{(res.stdout + res.stderr)[-3000:]}")
    src = folder / f"{name}_adapt_bench.c"
    src.write_text(render("adapt_bench.c.in", name=name, NAME=name.upper()))
    exe = folder / build / f"{name}_adapt_bench"
    compiler = [cc] if cc else shlex.split(os.environ.get("CC") or "cc")
    incs = [f"-I{folder}"] + [f"-I{folder / i}" for i in include_dirs_of("daqp")]
    # the Makefile's flags (ALL_CFLAGS with its default CFLAGS): the program times the library as a C user builds it
    cmd = compiler + ["-O3", "-std=c99", "-fno-strict-aliasing", *incs, "-o", str(exe), str(src),
                      str(folder / build / f"lib{name}.a"), "-lm"]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    if res.returncode != 0 or not exe.is_file():
        raise CodegenError(f"linking {exe.name} failed:\n{(res.stdout + res.stderr)[-3000:]}")
    return exe


def run_timer(exe: Path, windows: Path, n_resolves: int, qemu: str | None = None,
              timeout: float = RUN_TIMEOUT_S) -> dict:
    """Run the timing program (under qemu when given); its JSON line (times in ns). A non-zero exit -- a result
    check failed in the program -- is a CodegenError, never a time."""
    cmd = ([qemu, "-L", standalone.AARCH64_SYSROOT] if qemu else []) + [str(exe), str(windows), str(n_resolves)]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    if res.returncode != 0:
        raise CodegenError(f"{exe.name}{' under qemu' if qemu else ''} exited {res.returncode}: "
                           f"{(res.stdout + res.stderr)[-2000:]}")
    out = json.loads(res.stdout.strip().splitlines()[-1])
    times = [out[k] for k in ("push_ns_median", "push_ns_max", "resolve_ns_median", "resolve_ns_max",
                              "fold_ns_median", "snapshot_ns_median")]
    if not all(np.isfinite(t) and t > 0 for t in times):
        raise CodegenError(f"{exe.name} reported a non-positive time: {out}")
    return out


def _agree(a: dict, b: dict) -> bool:
    """The two runs computed the same thing (verdict and counts exactly, checksums to AGREE_RTOL)."""
    same = all(a[k] == b[k] for k in ("pushes", "resolves", "verdict", "updates"))
    return same and all(abs(a[k] - b[k]) <= AGREE_RTOL * max(1.0, abs(a[k]))
                        for k in ("sum_abs_g", "sum_abs_r", "error_candidate"))


PHASES = ("fold", "g_solve", "qp_rebuild", "excitation", "prediction", "offset")  # the timing program's order


def native_figures(folder: Path, windows: np.ndarray, n_resolves: int, verdict: int | None = None,
                   runs: int = 5) -> dict:
    """The timing program built natively for the emitted adaptive ``folder`` and run ``runs`` times on ``windows``
    ((N, DEPTH*(M+P)) time-major data-unit windows, written to ``folder/adapt_bench_windows.bin``): the first run's
    JSON figures with each median (ns) the median of the runs' medians and each max their max, and
    ``phase_ns_median`` named by :data:`PHASES`. Several processes, because a machine's speed can drift between
    processes more than within one. ``verdict``: the re-solve's verdict the caller's own build gave, if known
    (a different one, or runs that disagree, is a CodegenError). ValueError: ``runs`` < 1."""
    if isinstance(runs, bool) or not isinstance(runs, int) or runs < 1:
        raise ValueError(f"runs must be an integer >= 1; got {runs!r}")
    folder = Path(folder)
    data = folder / "adapt_bench_windows.bin"
    np.ascontiguousarray(windows, dtype=np.float64).tofile(data)  # host order: x86-64 and aarch64 are little-endian
    exe = build_timer(folder, None, "build-adapt-bench-native")
    outs = [run_timer(exe, data, n_resolves) for _ in range(runs)]
    native = dict(outs[0])
    if not all(_agree(native, o) for o in outs[1:]):
        raise CodegenError(f"runs of the same timing program disagree: {outs}")
    if verdict is not None and native["verdict"] != verdict:
        raise CodegenError(f"the timing program's verdict {native['verdict']} is not the Python build's {verdict}")
    for key in [k for k in native if k.endswith("_ns_median") and k != "phase_ns_median"]:
        native[key] = float(np.median([o[key] for o in outs]))
    for key in [k for k in native if k.endswith("_ns_max")]:
        native[key] = float(np.max([o[key] for o in outs]))
    native["phase_ns_median"] = dict(zip(PHASES, np.median([o["phase_ns_median"] for o in outs], axis=0).tolist()))
    native["runs"] = len(outs)
    return native


def cross_figures(folder: Path, windows: np.ndarray, n_resolves: int, verdict: int | None = None,
                  log: Callable[[str], None] = print, native: dict | None = None) -> dict | None:
    """Push / re-solve times of the emitted adaptive ``folder`` built for aarch64 and run under qemu, and of the
    same program built natively (us / ms); None when the aarch64 tools are missing. ``windows``, ``verdict``: as
    :func:`native_figures`; ``native``: its result when the caller already ran it on the same windows."""
    tools = standalone.aarch64_tools()
    if tools is None:
        log(f"  aarch64 online update: skipped ({standalone.MISSING_AARCH64})")
        return None
    folder = Path(folder)
    native = native or native_figures(folder, windows, n_resolves, verdict)
    data = folder / "adapt_bench_windows.bin"
    arm = run_timer(build_timer(folder, tools[0], "build-adapt-bench-aarch64"), data, n_resolves, qemu=tools[1])
    if not _agree(native, arm):
        raise CodegenError(f"native and aarch64 timing programs disagree:\n native  {native}\n aarch64 {arm}")
    us, ms = 1e-3, 1e-6
    return {"push_us_median": round(arm["push_ns_median"] * us, 2), "push_us_max": round(arm["push_ns_max"] * us, 2),
            "resolve_ms_median": round(arm["resolve_ns_median"] * ms, 3),
            "resolve_ms_max": round(arm["resolve_ns_max"] * ms, 3),
            "fold_us_median": round(arm["fold_ns_median"] * us, 2),
            "native_fold_us_median": round(native["fold_ns_median"] * us, 2),
            "native_push_us_median": round(native["push_ns_median"] * us, 2),
            "native_push_us_max": round(native["push_ns_max"] * us, 2),
            "native_resolve_ms_median": round(native["resolve_ns_median"] * ms, 3),
            "native_resolve_ms_max": round(native["resolve_ns_max"] * ms, 3),
            "qemu_over_native_push": round(arm["push_ns_median"] / native["push_ns_median"], 1),
            "qemu_over_native_resolve": round(arm["resolve_ns_median"] / native["resolve_ns_median"], 1),
            "phase_ms_median": {k: round(v * ms, 3) for k, v in zip(PHASES, arm["phase_ns_median"])},
            "pushes": arm["pushes"], "resolves": arm["resolves"], "verdict": arm["verdict"],
            "compiler": standalone.AARCH64_CC, "runner": standalone.QEMU}


def cross_line(size: str, row: dict) -> str | None:
    """The table line of a :func:`cross_figures` result in an ``adapt_timing`` row (None: an older report)."""
    if "aarch64_qemu" not in row:
        return None
    a = row["aarch64_qemu"]
    if a is None:
        return f"  {size:<8} aarch64 (qemu): {row.get('aarch64_qemu_note', 'not measured')}"
    fold = f"  fold us per column {a['fold_us_median']:.2f}" if "fold_us_median" in a else ""
    return (f"  {size:<8} aarch64 (qemu), median/max: update us {a['push_us_median']:.2f} / {a['push_us_max']:.2f}"
            f"{fold}  re-solve ms {a['resolve_ms_median']:.3f} / {a['resolve_ms_max']:.3f}  (same C program native: "
            f"{a['native_push_us_median']:.2f} us, {a['native_resolve_ms_median']:.3f} ms; qemu / native "
            f"{a['qemu_over_native_push']:.1f}x, {a['qemu_over_native_resolve']:.1f}x)")
