"""The test run's compile cache (tests/support/cc_cache.py): an identical compile step reuses its object,
any change the compiler would see (header, macro, flag, compiler) compiles again, failures are not stored."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from support.cc_cache import compile_step, cross_wrapper, dependency_flags, install

CC = shutil.which("cc") or shutil.which("gcc")
needs_cc = pytest.mark.skipif(CC is None, reason="no C compiler")


@pytest.mark.parametrize("args, want", [
    (["-O3", "-Ia/b", "-c", "x.c", "-o", "x.o"], ("x.c", "x.o", ["-O3", "-Ia/b", "-c"])),
    (["-c", "-o", "o/x.o", "-I", "inc.c", "s/x.c"], ("s/x.c", "o/x.o", ["-c", "-I", "inc.c"])),
    (["x.o", "y.o", "-shared", "-o", "m.so"], None),                   # a link step
    (["-c", "x.c", "y.c"], None),                                      # two sources, no -o
    (["-MD", "-MF", "x.d", "-c", "x.c", "-o", "x.o"], None),           # dependency flags: see below
    (["-E", "-c", "x.c", "-o", "x.i"], None),
    (["@args.rsp", "-c", "x.c", "-o", "x.o"], None),
])
def test_only_plain_compile_steps_are_cacheable(args, want):
    assert compile_step(args) == want


@pytest.mark.parametrize("args, want", [
    (["-O3", "-c", "x.c", "-o", "x.o"], (["-O3", "-c", "x.c", "-o", "x.o"], [])),
    (["-MD", "-MT", "x.o", "-MF", "x.o.d", "-o", "x.o", "-c", "x.c"],  # CMake's
     (["-o", "x.o", "-c", "x.c"], ["-MD", "-MT", "x.o", "-MF", "x.o.d"])),
    (["-MMD", "-MP", "-MF", "x.d", "-c", "x.c", "-o", "x.o"], (["-c", "x.c", "-o", "x.o"], ["-MMD", "-MP", "-MF", "x.d"])),
    (["-MD", "-c", "x.c", "-o", "x.o"], None),                          # depfile named after -o: run as asked
    (["-M", "x.c"], None), (["-MG", "-MD", "-MF", "x.d", "-c", "x.c", "-o", "x.o"], None),
])
def test_dependency_flags_are_split_off_only_with_a_named_depfile(args, want):
    assert dependency_flags(args) == want


def _fake_compiler(tmp: Path) -> tuple[Path, Path]:
    """A compiler that logs each real compile (not the preprocessing) to a file, then runs cc."""
    log = tmp / "compiles.log"
    exe = tmp / "logcc"
    exe.write_text(f'#!/bin/sh\ncase " $* " in *" -E "*|*" -M "*) ;; *) echo "$*" >> "{log}";; esac\n'
                   f'exec "{CC}" "$@"\n')
    exe.chmod(0o755)
    return exe, log


def _program(folder: Path, value: str, extra: str = "") -> Path:
    """A folder with main.c printing VALUE from a header in its own include directory."""
    (folder / "inc").mkdir(parents=True)
    (folder / "inc" / "v.h").write_text(f"#define VALUE {value}\n")
    (folder / "main.c").write_text('#include <stdio.h>\n#include "v.h"\n'
                                   f'int main(void) {{ {extra} printf("%d\\n", VALUE); return 0; }}\n')
    return folder


def _build_and_run(env: dict, folder: Path, *flags: str) -> tuple[subprocess.CompletedProcess, str | None]:
    """Compile main.c through the wrapper, link it with the real compiler, run it: (compile, output)."""
    comp = subprocess.run([env["CC"], *flags, "-I", str(folder / "inc"), "-c", str(folder / "main.c"),
                           "-o", str(folder / "main.o")], env=env, capture_output=True, text=True)
    if comp.returncode != 0:
        return comp, None
    subprocess.run([CC, str(folder / "main.o"), "-o", str(folder / "main")], check=True)
    return comp, subprocess.run([str(folder / "main")], capture_output=True, text=True, check=True).stdout.strip()


def _counting_cache(tmp_path):
    """(the environment of a session cache in front of a fake compiler that logs its calls, the calls so far)."""
    real, log = _fake_compiler(tmp_path)
    env = dict(os.environ, **install(tmp_path / "cache", {"CC": str(real)}))
    return env, lambda: len(log.read_text().splitlines()) if log.exists() else 0


@needs_cc
@pytest.mark.compiler
def test_identical_steps_reuse_the_object_and_changes_compile_again(tmp_path):
    env, n_compiles = _counting_cache(tmp_path)

    assert _build_and_run(env, _program(tmp_path / "a", "41"))[1] == "41" and n_compiles() == 1
    # another folder (other -I path, other object path), the same content: reused, and it runs
    assert _build_and_run(env, _program(tmp_path / "b", "41"))[1] == "41" and n_compiles() == 1
    # what the compiler sees changed: a header, a macro, a flag
    assert _build_and_run(env, _program(tmp_path / "c", "42"))[1] == "42" and n_compiles() == 2
    assert _build_and_run(env, _program(tmp_path / "d", "VALUE2"), "-DVALUE2=7")[1] == "7" and n_compiles() == 3
    assert _build_and_run(env, _program(tmp_path / "e", "41"), "-O1")[1] == "41" and n_compiles() == 4


@needs_cc
@pytest.mark.compiler
def test_a_macro_the_source_never_reads_reuses_the_object(tmp_path):
    """-D/-U are not in the key as arguments: what they change is in the preprocessed source, which is."""
    env, n_compiles = _counting_cache(tmp_path)

    assert _build_and_run(env, _program(tmp_path / "a", "41"))[1] == "41" and n_compiles() == 1
    assert _build_and_run(env, _program(tmp_path / "b", "41"), "-DUNREAD=3", "-U", "OTHER")[1] == "41"
    assert n_compiles() == 1
    assert _build_and_run(env, _program(tmp_path / "c", "READ"), "-D", "READ=5")[1] == "5" and n_compiles() == 2


@needs_cc
@pytest.mark.compiler
def test_a_cross_wrapper_stores_under_its_own_compiler(tmp_path, monkeypatch):
    """cross_wrapper(real): real's objects are its own (not the host compiler's for the same step), reused
    like CC's; without a session store it is real itself."""
    real, log = _fake_compiler(tmp_path)
    env = dict(os.environ, **install(tmp_path / "cache", {"CC": CC}))
    monkeypatch.setenv("DDPC_CC_CACHE", env["DDPC_CC_CACHE"])
    cross = cross_wrapper(str(real))
    assert cross != str(real) and Path(cross).parent == Path(env["DDPC_CC_CACHE"]).parent
    assert _build_and_run(env, _program(tmp_path / "host", "41"))[1] == "41" and not log.exists()
    cross_env = dict(env, CC=cross)
    assert _build_and_run(cross_env, _program(tmp_path / "a", "41"))[1] == "41"
    assert _build_and_run(cross_env, _program(tmp_path / "b", "41"))[1] == "41"
    assert len(log.read_text().splitlines()) == 1
    monkeypatch.delenv("DDPC_CC_CACHE")
    assert cross_wrapper(str(real)) == str(real)


@needs_cc
@pytest.mark.compiler
def test_the_same_step_started_twice_at_once_compiles_once(tmp_path):
    """Two processes (xdist workers) reach one step together: the second waits for the first's object."""
    real, log = _fake_compiler(tmp_path)
    slow = tmp_path / "slowcc"  # a compile that takes long enough for the second step to start meanwhile
    slow.write_text(f'#!/bin/sh\ncase " $* " in *" -E "*|*" -M "*) ;; *) sleep 1;; esac\nexec "{real}" "$@"\n')
    slow.chmod(0o755)
    env = dict(os.environ, **install(tmp_path / "cache", {"CC": str(slow)}))
    folders = [_program(tmp_path / k, "41") for k in ("a", "b")]
    steps = [subprocess.Popen([env["CC"], "-I", str(f / "inc"), "-c", str(f / "main.c"), "-o", str(f / "main.o")],
                              env=env) for f in folders]
    assert [p.wait(timeout=60) for p in steps] == [0, 0]
    assert len(log.read_text().splitlines()) == 1
    assert all((f / "main.o").read_bytes() == (folders[0] / "main.o").read_bytes() for f in folders)


@needs_cc
@pytest.mark.compiler
def test_a_step_writing_a_dependency_file_reuses_the_object_and_still_writes_the_file(tmp_path):
    real, log = _fake_compiler(tmp_path)
    env = dict(os.environ, **install(tmp_path / "cache", {"CC": str(real)}))
    deps = []
    for name in ("a", "b"):
        folder = _program(tmp_path / name, "41")
        dep = folder / "main.o.d"
        comp, out = _build_and_run(env, folder, "-MD", "-MT", "main.o", "-MF", str(dep))
        assert comp.returncode == 0 and out == "41", comp.stderr
        deps.append(dep.read_text())
    assert len(log.read_text().splitlines()) == 1  # the second object is the first one's
    # each file names its own folder's sources, as the compiler itself writes it
    for name, text in zip("ab", deps):
        assert text.startswith("main.o:") and str(tmp_path / name / "main.c") in text
        assert str(tmp_path / name / "inc" / "v.h") in text


@needs_cc
@pytest.mark.compiler
def test_warnings_are_replayed_and_failures_are_not_stored(tmp_path):
    real, log = _fake_compiler(tmp_path)
    env = dict(os.environ, **install(tmp_path / "cache", {"CC": str(real)}))
    warn = "int unused_var;"
    first, _ = _build_and_run(env, _program(tmp_path / "a", "1", warn), "-Wall")
    again, out = _build_and_run(env, _program(tmp_path / "b", "1", warn), "-Wall")
    assert "unused_var" in first.stderr and again.stderr == first.stderr and out == "1"
    assert len(log.read_text().splitlines()) == 1
    for name in ("c", "d"):  # a compile error: reported each time, never stored
        bad, out = _build_and_run(env, _program(tmp_path / name, "1", "syntax error here"))
        assert bad.returncode != 0 and "error" in bad.stderr and out is None
    assert len(log.read_text().splitlines()) == 3
    assert len([p for p in (tmp_path / "cache" / "objects").iterdir() if not p.name.startswith(".")]) == 1


_LIB = """#include "../{name}_lib_names.h" /* ddpc-codegen: per-solver symbol names */
static int twice(int x) {{ return 2 * x; }}
int lib_scale = 3;
int lib_apply(int x) {{ return lib_scale * twice(x) + 1; }}
"""


def _renamed_library(folder: Path, name: str) -> Path:
    """A library source renamed per solver as codegen/libs.py does (names header included first)."""
    (folder / "src").mkdir(parents=True)
    (folder / f"{name}_lib_names.h").write_text(
        f"#ifndef {name.upper()}_LIB_NAMES_H\n#define {name.upper()}_LIB_NAMES_H\n"
        f"#define lib_apply {name}_lib_apply\n#define lib_scale {name}_lib_scale\n#endif\n")
    (folder / "src" / "lib.c").write_text(_LIB.format(name=name))
    return folder / "src" / "lib.c"


def _section(obj: Path, section: str, tmp: Path) -> bytes:
    out = tmp / f"{obj.stem}{section}.bin"
    subprocess.run(["objcopy", "-O", "binary", f"--only-section={section}", str(obj), str(out)], check=True)
    return out.read_bytes()


@needs_cc
@pytest.mark.compiler
@pytest.mark.skipif(shutil.which("objcopy") is None or shutil.which("nm") is None, reason="no binutils")
def test_a_library_renamed_for_another_solver_is_the_stored_object_with_its_symbols_renamed(tmp_path):
    real, log = _fake_compiler(tmp_path)
    env = dict(os.environ, **install(tmp_path / "cache", {"CC": str(real)}))
    flags = ["-O2", "-fPIC", "-c"]
    for name in ("alpha", "beta"):
        src = _renamed_library(tmp_path / name, name)
        subprocess.run([env["CC"], *flags, str(src), "-o", str(tmp_path / f"{name}.o")], env=env, check=True)
    assert len(log.read_text().splitlines()) == 1  # beta reused alpha's compile
    # the independent reference: beta compiled directly
    subprocess.run([CC, *flags, str(tmp_path / "beta" / "src" / "lib.c"), "-o", str(tmp_path / "direct.o")], check=True)
    nm = lambda o: subprocess.run(["nm", str(o)], capture_output=True, text=True, check=True).stdout  # noqa: E731
    assert "beta_lib_apply" in nm(tmp_path / "beta.o") and "alpha" not in nm(tmp_path / "beta.o")
    assert nm(tmp_path / "beta.o") == nm(tmp_path / "direct.o")
    for section in (".text", ".data"):
        assert _section(tmp_path / "beta.o", section, tmp_path) == _section(tmp_path / "direct.o", section, tmp_path)
    # and it links and runs under the new names
    (tmp_path / "main.c").write_text('#include <stdio.h>\nint beta_lib_apply(int);\nextern int beta_lib_scale;\n'
                                     'int main(void) { beta_lib_scale = 5; printf("%d\\n", beta_lib_apply(4)); }\n')
    subprocess.run([CC, str(tmp_path / "main.c"), str(tmp_path / "beta.o"), "-o", str(tmp_path / "prog")], check=True)
    assert subprocess.run([str(tmp_path / "prog")], capture_output=True, text=True).stdout.strip() == "41"
    # a renaming with another set of names is another key
    other = _renamed_library(tmp_path / "gamma", "gamma")
    hdr = tmp_path / "gamma" / "gamma_lib_names.h"
    hdr.write_text(hdr.read_text().replace("#define lib_scale gamma_lib_scale\n", ""))
    subprocess.run([env["CC"], *flags, str(other), "-o", str(tmp_path / "gamma.o")], env=env, check=True)
    assert len(log.read_text().splitlines()) == 2 and "gamma_lib_apply" in nm(tmp_path / "gamma.o")


def test_the_wrapper_runs_without_site_packages(tmp_path):
    """The wrapper starts Python with -S (fast): the module must need the standard library only."""
    src = Path(__file__).parent / "support" / "cc_cache.py"
    r = subprocess.run([sys.executable, "-S", "-c", f"import runpy; runpy.run_path({str(src)!r}, run_name='x')"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
