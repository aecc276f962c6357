"""The one bounded reader of the files the tools are given (robot profiles, steering configs, sweep specs,
trajectories, manifests, prefilter models, dataset headers): only regular files, never more than a cap,
nesting bounded, numbers within float range -- every refusal one line, ``<file>: <key>: <message>``
(``<key>`` names the file's kind when no key is at fault).

A FIFO, a device or a folder is refused from its ``stat`` before anything opens it, and the open itself is
non-blocking, so a FIFO swapped in after the check cannot hang the reader; ``/dev/zero`` behind a symlink
is a device too. numpy-free and project-free: the bridge, the runtime and the design side all import it.
"""

from __future__ import annotations

import json
import math
import os
import stat
import tomllib
from pathlib import Path
from typing import Any

from ddpc_codegen.errors import ConfigError

__all__ = ["checked_input_path", "checked_output_folder", "checked_output_file", "read_bytes_bounded", "read_text_bounded", "parse_toml", "parse_json",
           "load_toml_bounded", "load_json_bounded", "check_nesting", "nesting_depth", "text_nesting_depth",
           "MiB", "MAX_TEXT_BYTES", "MAX_LOG_BYTES", "MAX_DEPTH"]

MiB = 2**20
# A steering config, sweep spec, manifest or trajectory file is kilobytes; 16 MiB is a thousand times that and
# still parses in about a second, while /dev/zero or a runaway file behind the path is refused before reading.
MAX_TEXT_BYTES = 16 * MiB
# A flight log (ULog, tlog): a day of full-rate logging is about 1 GiB; the parsers hold the file and its decoded
# messages in memory, so a larger file is refused before it is read.
MAX_LOG_BYTES = 4096 * MiB
# Our files nest at most four levels (a table, a sub-table, a list of lists); every parser recurses per level.
MAX_DEPTH = 32

_KINDS = ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISCHR, "a character device"),
          (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))


def _kind(mode: int) -> str:
    return next((name for test, name in _KINDS if test(mode)), "not a regular file")


def checked_input_path(path: str | Path, what: str = "input file", max_bytes: int | None = None,
                       error: type[Exception] = ConfigError) -> Path:
    """``path`` (symlinks followed) must be an existing regular file, of at most ``max_bytes`` if given: a
    directory, FIFO, device or socket is refused from its ``stat``, without opening it (a FIFO's open would
    wait for a writer). For readers that open the file themselves (``np.load``).

    Raises:
        error: ``<path>: <what>: does not exist`` / ``is a FIFO (named pipe), not a regular file`` / ...
    """
    p = Path(path)
    try:
        st = p.stat()
    except FileNotFoundError:
        raise error(f"{p}: {what}: does not exist") from None
    except OSError as e:
        raise error(f"{p}: {what}: cannot be read ({e.strerror or type(e).__name__})") from None
    if not stat.S_ISREG(st.st_mode):
        raise error(f"{p}: {what}: is {_kind(st.st_mode)}, not a regular file")
    if max_bytes is not None and st.st_size > max_bytes:
        raise error(_too_big(p, what, st.st_size, max_bytes))
    return p


def checked_output_folder(path: str | Path, what: str, error: type[Exception] = ConfigError) -> Path:
    """``path`` is a folder to write into, or can be made one: it, or its nearest existing ancestor, must be a
    directory (a file, FIFO or device there would fail the write after all the work)."""
    p = Path(path)
    for at in (p, *p.parents):
        try:
            mode = at.stat().st_mode
        except (FileNotFoundError, NotADirectoryError):  # made by the writer, or an ancestor is no folder
            continue
        except OSError as e:
            raise error(f"{p}: {what}: cannot be used ({e.strerror or type(e).__name__})") from None
        if not stat.S_ISDIR(mode):
            kind = "a regular file" if stat.S_ISREG(mode) else _kind(mode)
            raise error(f"{p}: {what}: {'' if at == p else f'{at} '}is {kind}, not a folder")
        break
    return p


def checked_output_file(path: str | Path, what: str, overwrite: bool = False,
                        error: type[Exception] = ConfigError) -> Path:
    """``path`` (symlinks followed) is a file to write: absent, or an existing regular file and ``overwrite``
    (a result is never replaced silently), in an existing folder that takes new files (probed with a real
    create). A directory, FIFO, device or socket is refused from its ``stat`` (a FIFO's open would wait for a
    reader). Returns the resolved path (two outputs naming one file compare equal)."""
    p = Path(path)
    try:
        mode = p.stat().st_mode
    except (FileNotFoundError, NotADirectoryError):
        mode = None
    except OSError as e:
        raise error(f"{p}: {what}: cannot be used ({e.strerror or type(e).__name__})") from None
    if mode is not None and not stat.S_ISREG(mode):
        raise error(f"{p}: {what}: is {_kind(mode)}, not a regular file")
    if mode is not None and not overwrite:
        raise error(f"{p}: {what}: exists; pass --overwrite to replace it")
    folder = p.parent
    if not folder.is_dir():
        raise error(f"{p}: {what}: folder {folder} does not exist")
    if mode is None:
        try:  # a real create: permission bits say nothing for root or for special filesystems
            with open(p, "xb"):
                pass
            p.unlink()
        except OSError as e:
            raise error(f"{p}: {what}: not writable ({e.strerror or type(e).__name__})") from None
    elif not os.access(p, os.W_OK):
        raise error(f"{p}: {what}: not writable")
    return p.resolve()


def _too_big(p: Path, what: str, size: int | str, max_bytes: int) -> str:
    return f"{p}: {what}: {size} bytes, more than a {what} may have ({max_bytes} bytes)"


def read_bytes_bounded(path: str | Path, what: str, max_bytes: int, error: type[Exception] = ConfigError) -> bytes:
    """The bytes of a regular file of at most ``max_bytes`` (its size checked before reading, and never
    more than ``max_bytes + 1`` bytes read should it grow meanwhile)."""
    p = checked_input_path(path, what, max_bytes, error)
    try:
        fd = os.open(p, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOCTTY", 0))
    except OSError as e:
        raise error(f"{p}: {what}: cannot be read ({e.strerror or type(e).__name__})") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):  # replaced between the check and the open
            raise error(f"{p}: {what}: is {_kind(st.st_mode)}, not a regular file")
        if st.st_size > max_bytes:
            raise error(_too_big(p, what, st.st_size, max_bytes))
        chunks, got = [], 0
        while got <= max_bytes:
            chunk = os.read(fd, min(MiB, max_bytes + 1 - got))
            if not chunk:
                break
            chunks.append(chunk)
            got += len(chunk)
    except OSError as e:
        raise error(f"{p}: {what}: cannot be read ({e.strerror or type(e).__name__})") from None
    finally:
        os.close(fd)
    if got > max_bytes:
        raise error(_too_big(p, what, f"more than {max_bytes}", max_bytes))
    return b"".join(chunks)


def read_text_bounded(path: str | Path, what: str, max_bytes: int = MAX_TEXT_BYTES,
                      error: type[Exception] = ConfigError) -> str:
    """The UTF-8 text of a regular file of at most ``max_bytes`` (see :func:`read_bytes_bounded`)."""
    data = read_bytes_bounded(path, what, max_bytes, error)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise error(f"{path}: {what}: is not UTF-8 text ({_utf8_fault(data, e)})") from None


def _utf8_fault(data: bytes, e: UnicodeDecodeError) -> str:
    return f"byte {e.start} is {data[e.start]:#04x}"


def text_nesting_depth(text: str) -> int:
    """Deepest nesting of [ ] / { } brackets outside quoted strings and # comments (JSON and TOML alike; what
    a parser that gave up would have had to recurse: only for its message)."""
    depth = best = 0
    quote = ""
    escaped = comment = False
    for ch in text:
        if comment:
            comment = ch != "\n"
        elif quote:
            if escaped:
                escaped = False
            elif ch == "\\" and quote == '"':  # TOML's 'literal strings' have no escapes
                escaped = True
            elif ch == quote:
                quote = ""
        elif ch in "\"'":
            quote = ch
        elif ch == "#":
            comment = True
        elif ch in "[{":
            depth += 1
            best = max(best, depth)
        elif ch in "]}":
            depth -= 1
    return best


def nesting_depth(obj: Any) -> int:
    """Levels of dicts / lists / tuples in a parsed value (a scalar: 0, ``{}``: 1), without recursing."""
    if not isinstance(obj, (dict, list, tuple)):
        return 0
    return _walk(obj, math.inf, "")[0]


def _key(path: tuple) -> str:
    """'a.b[3].c' of a linked key path (parent, key); long ones shortened to stay on one line."""
    parts: list[str] = []
    while path:
        path, k = path
        parts.append(f"[{k}]" if isinstance(k, int) else f".{k}")
    text = "".join(reversed(parts)).lstrip(".")
    return text if len(text) <= 80 else text[:77] + "..."


def _big_int(v: Any) -> bool:
    if not isinstance(v, int) or isinstance(v, bool) or v.bit_length() <= 1000:
        return False
    try:
        float(v)
    except OverflowError:
        return True
    return False


def _big_int_problem(v: int, what: str) -> str:
    return f"an integer of {len(str(abs(v)))} digits, beyond the range of any number a {what} holds (±1.8e308)"


def _walk(obj: Any, max_depth: float, what: str) -> tuple[int, str, str]:
    """(depth, key at fault, problem) of ``obj``: stops at the first container deeper than ``max_depth`` or
    integer outside float range; ``problem`` is "" when there is none. Key paths are built only on a fault."""
    best = 0
    stack: list[tuple[Any, int, tuple]] = [(obj, 1, ())]
    while stack:
        o, depth, path = stack.pop()
        best = max(best, depth)
        if depth > max_depth:
            return best, _key(path), f"nested more than {max_depth:g} levels deep, more than a {what} may be"
        items = o.items() if isinstance(o, dict) else enumerate(o)  # list indices print as [i]
        for k, v in items:
            if isinstance(v, (dict, list, tuple)):
                stack.append((v, depth + 1, (path, k)))
            elif _big_int(v):
                return best, _key((path, k)), _big_int_problem(v, what)
    return best, "", ""


def check_nesting(obj: Any, src: str, what: str, max_depth: int = MAX_DEPTH,
                  error: type[Exception] = ConfigError) -> Any:
    """``obj`` (a parsed file) nested at most ``max_depth`` levels, every integer within float range (a
    401-digit integer would overflow wherever it is used); returns it."""
    if not isinstance(obj, (dict, list, tuple)):
        key, problem = "", _big_int_problem(obj, what) if _big_int(obj) else ""
    else:
        _, key, problem = _walk(obj, max_depth, what)
    if problem:
        raise error(f"{src}: {key or what}: {problem}")
    return obj


def _recursion(src: str, what: str, text: str, max_depth: int, error: type[Exception]) -> Exception:
    return error(f"{src}: {what}: nested {text_nesting_depth(text)} levels deep, more than a {what} may be "
                 f"({max_depth})")


def _parsed(loads, kind: str, text: str, src: str, what: str, max_depth: int, error: type[Exception]) -> Any:
    """``loads(text)`` with its failures as one line each, then :func:`check_nesting`."""
    try:
        raw = loads(text)
    except RecursionError:
        raise _recursion(src, what, text, max_depth, error) from None
    except ValueError as e:  # the decoder's error, or an integer of more than 4300 digits
        raise error(f"{src}: {what}: is not valid {kind}: {e}") from None
    return check_nesting(raw, src, what, max_depth, error)


def parse_toml(text: str, src: str, what: str, max_depth: int = MAX_DEPTH, error: type[Exception] = ConfigError) -> dict:
    """TOML text -> tables, checked by :func:`check_nesting`; ``src`` names the file in errors."""
    return _parsed(tomllib.loads, "TOML", text, src, what, max_depth, error)


def parse_json(text: str | bytes, src: str, what: str, max_depth: int = MAX_DEPTH,
               error: type[Exception] = ConfigError) -> Any:
    """JSON text (bytes: UTF-8) -> value, checked by :func:`check_nesting`. NaN / Infinity literals parse
    (informational fields may hold them); the caller checks the values it uses."""
    if isinstance(text, (bytes, bytearray)):
        try:
            text = bytes(text).decode("utf-8")
        except UnicodeDecodeError as e:
            raise error(f"{src}: {what}: is not valid JSON (not UTF-8: {_utf8_fault(bytes(text), e)})") from None
    return _parsed(json.loads, "JSON", text, src, what, max_depth, error)


def load_toml_bounded(path: str | Path, what: str, max_bytes: int = MAX_TEXT_BYTES, max_depth: int = MAX_DEPTH,
                      error: type[Exception] = ConfigError) -> dict:
    """A TOML file read by :func:`read_text_bounded` and parsed by :func:`parse_toml`."""
    return parse_toml(read_text_bounded(path, what, max_bytes, error), str(path), what, max_depth, error)


def load_json_bounded(path: str | Path, what: str, max_bytes: int = MAX_TEXT_BYTES, max_depth: int = MAX_DEPTH,
                      error: type[Exception] = ConfigError) -> Any:
    """A JSON file read by :func:`read_bytes_bounded` and parsed by :func:`parse_json`."""
    return parse_json(read_bytes_bounded(path, what, max_bytes, error), str(path), what, max_depth, error)
