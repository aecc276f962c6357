"""Exception hierarchy. Every message says what was wrong and what to do about it."""

from __future__ import annotations


class DDPCError(Exception):
    """Base class of every error raised by ddpc_codegen."""


class DataError(DDPCError, ValueError):
    """Input/output data is malformed: wrong shape, NaN/inf, mismatched trajectories, too short."""


class ExcitationError(DataError):
    """The input is not persistently exciting enough for the requested horizons."""


class ConfigError(DDPCError, ValueError):
    """A configuration (TOML or keyword) value is missing, of the wrong type or out of range."""


class SolverError(DDPCError, RuntimeError):
    """A QP solver failed in a way the caller asked to be raised (not a status to fall back on)."""


class CodegenError(DDPCError, RuntimeError):
    """Emitting or compiling generated C code failed."""


class ManifestError(DDPCError, ValueError):
    """A generated artifact's manifest.json is missing, corrupt or does not match what is asked."""
