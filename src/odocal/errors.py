"""The exceptions odocal raises.

Every error odocal raises on purpose derives from :class:`OdocalError` and from the builtin
that matches its kind, so ``except ValueError`` keeps working for callers who do not know odocal.
Messages name the input, the bad value and what would be right; the CLI prints them as one line.
"""

from __future__ import annotations


class OdocalError(Exception):
    """Base class of every error odocal raises on purpose."""


class DataError(OdocalError, ValueError):
    """An input log or drive is malformed: missing columns, NaNs, gaps, bad time, wrong units."""


class ConfigError(OdocalError, ValueError):
    """A settings file or option is invalid: unknown key, wrong type, value out of range."""


class InputFileError(OdocalError, FileNotFoundError):
    """An input path does not exist or cannot be read."""


class OutputError(OdocalError, OSError):
    """An output cannot be written, or writing it would overwrite one of the inputs."""


class SolverError(OdocalError, RuntimeError):
    """A numerical solver could not produce any usable answer."""


class MissingDependencyError(OdocalError, ImportError):
    """An optional dependency needed for the requested feature is not installed."""
