"""The checks of parsed TOML tables: unknown keys and bad values become
:class:`~ddpc_codegen.errors.ConfigError` messages that name the file, the key and the value (the files
themselves are read by :func:`ddpc_codegen.values.files.load_toml_bounded`)."""

from __future__ import annotations

import dataclasses
from typing import Any, TypeVar

from ddpc_codegen.errors import ConfigError

__all__ = ["check_keys", "dataclass_from_table", "config_error"]

T = TypeVar("T")


def check_keys(table: Any, allowed: tuple[str, ...] | list[str], where: str, src: str) -> dict:
    """``table`` must be a TOML table whose keys are all in ``allowed`` (a typo is an error, not a default)."""
    if not isinstance(table, dict):
        raise ConfigError(f"{src}: {where} must be a table; got {table!r}")
    for key in table:
        if key not in allowed:
            raise ConfigError(f"{src}: {where} {key} is not a known key; allowed: {sorted(allowed)}")
    return table


def dataclass_from_table(cls: type[T], table: Any, where: str, src: str, base: T | None = None) -> T:
    """Build dataclass ``cls`` from a TOML table (lists become tuples), on top of ``base`` if given.

    The dataclass's own validation (ValueError / TypeError in ``__post_init__``) is reported as a
    ConfigError naming the file and table.
    """
    names = [f.name for f in dataclasses.fields(cls)]
    check_keys(table, names, where, src)
    values = {k: tuple(v) if isinstance(v, list) else v for k, v in table.items()}
    try:
        return dataclasses.replace(base, **values) if base is not None else cls(**values)
    except (TypeError, ValueError) as e:
        raise ConfigError(f"{src}: {where} {e}") from None


def config_error(src: str, key: str, msg: str) -> ConfigError:
    """The error of one bad value: ``<file>: <key> <what is wrong>``."""
    return ConfigError(f"{src}: {key} {msg}")
