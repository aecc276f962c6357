"""A C compiler wrapper for the test run: a compile step whose preprocessed source, flags and compiler
were seen before reuses that object file instead of compiling again.

Why: every generated solver folder carries the DAQP (and OSQP) library sources and compiles them with
the same flags; in a test run that builds dozens of solvers, recompiling identical library code is most
of the compile time (e.g. ~4.5 s of a flying DAQP solver's ~6 s; ~400 s of a ``make test``). The wrapper
is ``CC`` for the test session (:func:`install`; the cffi builds, ``make`` and CMake read it), so the code
under test runs unchanged: only *how* an identical object file is obtained changes.

What makes two compile steps identical (the key): the real compiler (path, size, mtime), every argument
except the output path, the source path, ``-I`` directories (generated folders live in fresh temporary
directories) and ``-D``/``-U`` macros, and the source as preprocessed with all of them (``-E -P``: headers and macros
included, so an edited header or ``-D`` is a different key). A hit copies the object file and replays
the compiler's messages; anything other than a plain ``-c one.c -o one.o`` step (linking, dependency
files without a named ``-MF``, ``-E``, response files ...) runs the real compiler untouched; a step that also
writes a make dependency file (CMake's ``-MD -MT t -MF f``) reuses the object and writes the file with the
preprocessor alone (``-M``). Failed compiles are never stored.

Per-solver symbol names: each library source of a generated folder first includes
``<name>_<lib>_names.h`` (``#define daqp_solve <name>_daqp_solve`` ..., see ``codegen/libs.py``), so the
same library differs between solvers in its global names only. Such a step is keyed on the source
preprocessed *without* the renaming (the header's include guard predefined) plus the list of renamed
names; a hit from another solver is the stored object with its symbols renamed to this solver's by
``objcopy --redefine-syms`` (the machine code is the compiler's either way: names are not code).
Debug information in a reused object still names the first solver and folder (harmless in tests).

Run as a script (``python -S cc_cache.py <compiler args>``): the real compiler is ``$DDPC_CC_REAL``,
the object store ``$DDPC_CC_CACHE``. The script starts once per compile step (thousands in a test run), so it
imports only what starts fast: ``os.posix_spawnp`` instead of ``subprocess``, string methods instead of ``re``,
``os.path`` instead of ``pathlib`` (each of those costs more to import than a cached compile step's own work).
"""

from __future__ import annotations

import fcntl
import hashlib
import os
import sys

SOURCE_SUFFIXES = (".c",)
_NAMES_PREFIX = '#include "'
_NAMES_SUFFIX = '" /* ddpc-codegen: per-solver symbol names */'
# a step with any of these is not a plain "compile one source to one object" step: run it as asked
_PASS_PREFIXES = ("-M", "@", "-E", "-S", "-x", "-save-temps", "-fdump", "-###", "-v", "--version")


def spawn(argv: list[str], stdout: int | None = None, stderr: int | None = None) -> int:
    """Run ``argv`` (the program looked up on PATH) to its end; its exit code. ``stdout``/``stderr``: a file
    descriptor the child writes that stream to, None: this process's own."""
    actions = [(os.POSIX_SPAWN_DUP2, fd, std) for fd, std in ((stdout, 1), (stderr, 2)) if fd is not None]
    pid = os.posix_spawnp(argv[0], argv, os.environ, file_actions=actions)
    return os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1])


def captured(argv: list[str], stream: int) -> tuple[int, bytes]:
    """(exit code, what it wrote to ``stream``) of ``argv``; ``stream`` 1: its stderr is dropped, 2: its stdout
    is this process's."""
    r, w = os.pipe()
    null = os.open(os.devnull, os.O_WRONLY)
    actions = [(os.POSIX_SPAWN_DUP2, w, stream)] + ([(os.POSIX_SPAWN_DUP2, null, 2)] if stream == 1 else [])
    try:
        pid = os.posix_spawnp(argv[0], argv, os.environ, file_actions=actions)
    finally:
        os.close(w)
        os.close(null)
    with os.fdopen(r, "rb") as f:
        data = f.read()
    return os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1]), data


def which(program: str) -> str | None:
    """``program``'s path as the shell would run it (PATH searched when it has no slash), or None."""
    paths = [program] if os.sep in program else [os.path.join(d, program) for d in
                                                 os.environ.get("PATH", os.defpath).split(os.pathsep) if d]
    return next((q for q in paths if os.path.isfile(q) and os.access(q, os.X_OK)), None)


def _read(path: str, mode: str = "r"):
    with open(path, mode) as f:
        return f.read()


def _write(path: str, data, mode: str = "w") -> None:
    with open(path, mode) as f:
        f.write(data)


def dependency_flags(args: list[str]) -> tuple[list[str], list[str]] | None:
    """(the arguments without them, the make-dependency flags) of a compile step that writes its dependency
    file as a side effect with a named ``-MF`` (CMake's ``-MD -MT t -MF f``); ([], ...) untouched when it has
    none; None when it has other ``-M`` flags (not cacheable)."""
    rest, dep, i = [], [], 0
    while i < len(args):
        a = args[i]
        if a in ("-MD", "-MMD", "-MP"):
            dep.append(a)
        elif a in ("-MT", "-MF", "-MQ") and i + 1 < len(args):
            dep += [a, args[i + 1]]
            i += 1
        elif a.startswith("-M"):
            return None
        else:
            rest.append(a)
        i += 1
    if dep and ("-MF" not in dep or not {"-MD", "-MMD"} & set(dep)):
        return None
    return rest, dep


def write_dependencies(real: list[str], src: str, rest: list[str], dep: list[str]) -> bool:
    """The dependency file a ``-MD``/``-MMD`` compile would have written, from the preprocessor alone
    (``-M``/``-MM``: no code generated) -- what a reused object's build still needs."""
    only = ["-M" if a == "-MD" else "-MM" if a == "-MMD" else a for a in dep]
    return spawn([*real, *[a for a in rest if a != "-c"], *only, src]) == 0


def compile_step(args: list[str]) -> tuple[str, str, list[str]] | None:
    """(source, object, the other arguments) of a plain ``-c`` step, else None (not cacheable)."""
    if "-c" not in args or any(a == "-" or a.startswith(_PASS_PREFIXES) for a in args):
        return None
    srcs = [i for i, a in enumerate(args) if a.endswith(SOURCE_SUFFIXES) and not a.startswith("-")
            and not (i > 0 and args[i - 1] in ("-o", "-I", "-include", "-isystem", "-iquote"))]
    outs = [i for i, a in enumerate(args) if a == "-o"]
    if len(srcs) != 1 or len(outs) != 1 or outs[0] + 1 >= len(args):
        return None
    src, obj = args[srcs[0]], args[outs[0] + 1]
    rest = [a for i, a in enumerate(args) if i not in (srcs[0], outs[0], outs[0] + 1)]
    return src, obj, rest


def _key_arguments(args: list[str]) -> list[str]:
    """``args`` less the ``-I`` directories (temporary folders) and the ``-D``/``-U`` macros (what they change is
    in the preprocessed source the key holds: ``make``'s ``CFLAGS=-O3 -DX`` and ``-O3`` then share objects of a
    source that never reads ``X``)."""
    out, skip = [], False
    for a in args:
        if skip:
            skip = False
        elif a in ("-I", "-D", "-U"):
            skip = True
        elif not a.startswith(("-I", "-D", "-U")):
            out.append(a)
    return out


def _word(s: str) -> bool:
    """``s`` is one word of letters, digits and underscores (a C identifier or number)."""
    return bool(s) and all(c.isalnum() or c == "_" for c in s)


def names_header(first_line: str) -> str | None:
    """The header a renamed library source includes on its first line (``#include "<x>_names.h" /* ...
    per-solver symbol names */``), or None."""
    if not first_line.startswith(_NAMES_PREFIX):
        return None
    end = first_line.find(_NAMES_SUFFIX, len(_NAMES_PREFIX))
    header = first_line[len(_NAMES_PREFIX):end] if end >= 0 else ""
    return header if header.endswith("_names.h") and len(header) > 8 and '"' not in header else None


def renaming(src: str) -> tuple[str, dict[str, str]] | None:
    """(include guard, {library name: this solver's name}) of the per-solver names header that ``src``
    includes on its first line, or None (not a renamed library source)."""
    with open(src, errors="replace") as f:
        header = names_header(f.readline())
    if header is None:
        return None
    try:
        lines = _read(os.path.join(os.path.dirname(src), header)).splitlines()
    except OSError:
        return None
    guard = next((ln[8:] for ln in lines if ln.startswith("#ifndef ") and _word(ln[8:])), None)
    names = dict(parts[1:] for parts in (ln.split(" ") for ln in lines)
                 if len(parts) == 3 and parts[0] == "#define" and _word(parts[1]) and _word(parts[2]))
    return (guard, names) if guard else None


def step_key(real: list[str], src: str, rest: list[str], names: tuple[str, dict[str, str]] | None = None,
             ) -> str | None:
    """The content key of compiling ``src`` with ``rest`` (see the module docstring); ``names``: the
    source's renaming (keyed on the source without it). None if the source does not preprocess (the
    real compile then reports why)."""
    unrenamed = [f"-D{names[0]}"] if names else []
    rc, pre = captured([*real, *[a for a in rest if a != "-c"], *unrenamed, "-E", "-P", src], 1)
    if rc != 0:
        return None
    exe = which(real[0]) or real[0]
    st = os.stat(exe)
    h = hashlib.sha256()
    for part in (os.path.realpath(exe), str(st.st_size), str(st.st_mtime_ns), *real[1:], *_key_arguments(rest),
                 " ".join(sorted(names[1])) if names else "-"):
        h.update(part.encode() + b"\0")
    h.update(pre)
    return h.hexdigest()


def _read_names(path: str) -> dict[str, str]:
    return dict(ln.split(" ") for ln in _read(path).splitlines())


def _renamed_copy(cached: str, was: dict[str, str], now: dict[str, str], obj: str) -> bool:
    """``cached`` (compiled with the names ``was``) written to ``obj`` with the names ``now``."""
    if was == now:
        _write(obj, _read(cached, "rb"), "wb")
        return True
    objcopy = which(os.environ.get("OBJCOPY", "objcopy"))
    if objcopy is None or set(was) != set(now):
        return False
    syms = f"{obj}.{os.getpid()}.syms"
    try:
        _write(syms, "".join(f"{was[k]} {now[k]}\n" for k in sorted(now)))
        return spawn([objcopy, f"--redefine-syms={syms}", cached, obj]) == 0
    finally:
        os.unlink(syms)


def _store(entry: str, obj: bytes, names: dict[str, str], messages: bytes) -> None:
    """Write a cache entry (a folder) atomically, first writer wins (xdist workers may race on a key)."""
    tmp = os.path.join(os.path.dirname(entry), f".tmp-{os.getpid()}-{os.path.basename(entry)}")
    os.makedirs(tmp, exist_ok=True)
    _write(os.path.join(tmp, "obj.o"), obj, "wb")
    _write(os.path.join(tmp, "names"), "".join(f"{k} {v}\n" for k, v in sorted(names.items())))
    _write(os.path.join(tmp, "messages"), messages, "wb")
    try:
        os.rename(tmp, entry)
    except OSError:  # another process stored this key meanwhile: same content but for the names
        for f in ("obj.o", "names", "messages"):
            os.unlink(os.path.join(tmp, f))
        os.rmdir(tmp)


def run(args: list[str], real: list[str], cache: str | None) -> int:
    """Compile as ``real args`` would, through the object store ``cache`` when the step is cacheable."""
    split = dependency_flags(args) if cache is not None else None
    plain, dep = split if split else (args, [])
    step = compile_step(plain) if split is not None else None
    names = renaming(step[0]) if step else None
    key = step_key(real, step[0], step[2], names) if step else None
    if key is None:
        return spawn([*real, *args])
    entry, now = os.path.join(cache, key), names[1] if names else {}

    def reused() -> bool:
        if not (os.path.isdir(entry) and _renamed_copy(os.path.join(entry, "obj.o"),
                                                      _read_names(os.path.join(entry, "names")), now, step[1])
                and (not dep or write_dependencies(real, step[0], step[2], dep))):
            return False
        sys.stderr.buffer.write(_read(os.path.join(entry, "messages"), "rb"))
        return True

    if reused():
        return 0
    # xdist workers start alike and reach the same library sources together: the first compiles, the others
    # wait for its object instead of compiling the same step again (the kernel drops the lock of a dead holder)
    os.makedirs(cache, exist_ok=True)
    with open(os.path.join(cache, f".{key}.lock"), "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if reused():
            return 0
        rc, messages = captured([*real, *args], 2)
        sys.stderr.buffer.write(messages)
        if rc == 0 and os.path.exists(step[1]):
            _store(entry, _read(step[1], "rb"), now, messages)
    return rc


def install(root: str | os.PathLike, env: dict[str, str]) -> dict[str, str]:
    """Make ``<root>/cc``, a wrapper around the compiler ``env`` names (``CC``, else Python's, which the
    cffi builds would use), storing objects in ``<root>/objects``; returns the variables to set:
    ``CC`` (the wrapper), ``DDPC_CC_REAL`` and ``DDPC_CC_CACHE``."""
    import sysconfig  # here, not at the top: the wrapper (the script) never needs it

    root = os.fspath(root)
    real = env.get("DDPC_CC_REAL") or env.get("CC") or sysconfig.get_config_var("CC") or "cc"
    os.makedirs(root, exist_ok=True)
    script = os.path.join(root, "cc")
    text = f'#!/bin/sh\nexec "{sys.executable}" -S "{os.path.realpath(__file__)}" "$@"\n'
    if not os.path.exists(script) or _read(script) != text:
        tmp = os.path.join(root, f".cc-{os.getpid()}")
        _write(tmp, text)
        os.chmod(tmp, 0o755)
        os.replace(tmp, script)  # atomic: every xdist worker installs the same script
    return {"CC": script, "DDPC_CC_REAL": real, "DDPC_CC_CACHE": os.path.join(root, "objects")}


def cross_wrapper(real: str) -> str:
    """A wrapper like ``CC``'s around another compiler ``real`` (a cross compiler, named in the key; its own
    binutils' ``objcopy`` renames), storing in this session's object store; ``real`` itself when the session
    has none (``DDPC_TEST_CC_CACHE=0``)."""
    import shlex  # here, not at the top: the wrapper (the script) never needs it

    store = os.environ.get("DDPC_CC_CACHE")
    if not store:
        return real
    objcopy = which(real[: -len("gcc")] + "objcopy") if real.endswith("gcc") else None
    env = f"export DDPC_CC_REAL={shlex.quote(real)}\n" + (f"export OBJCOPY={shlex.quote(objcopy)}\n" if objcopy else "")
    text = f'#!/bin/sh\n{env}exec "{sys.executable}" -S "{os.path.realpath(__file__)}" "$@"\n'
    script = os.path.join(os.path.dirname(store), "cc-" + os.path.basename(real))
    if not os.path.exists(script) or _read(script) != text:
        tmp = f"{script}.{os.getpid()}"
        _write(tmp, text)
        os.chmod(tmp, 0o755)
        os.replace(tmp, script)
    return script


def real_compiler(text: str) -> list[str]:
    """``$DDPC_CC_REAL`` as words (shell quoting understood when there is any)."""
    if any(c in text for c in "'\"\\"):
        import shlex  # only for a quoted compiler command: the common one splits on blanks

        return shlex.split(text)
    return text.split()


if __name__ == "__main__":
    cache_dir = os.environ.get("DDPC_CC_CACHE")
    sys.exit(run(sys.argv[1:], real_compiler(os.environ.get("DDPC_CC_REAL", "cc")), cache_dir or None))
