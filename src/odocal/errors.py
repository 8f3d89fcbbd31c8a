"""The exceptions odocal raises.

Every error odocal raises on purpose derives from :class:`OdocalError` and from the builtin
that matches its kind, so ``except ValueError`` keeps working for callers who do not know odocal.
Messages name the input, the bad value and what would be right; the CLI prints them as one line.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from pathlib import Path


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


def shown(path: object, limit: int = 120) -> str:
    """A path, name or message, safe to print on one line: no secret (a URL's credentials and
    query, a path's query-like tail, a credential variable's value: :mod:`odocal.redaction`),
    control characters escaped, and a long one shortened in the middle."""
    from odocal.redaction import redact_text

    text = "".join(c if c.isprintable() else repr(c)[1:-1] for c in redact_text(path))
    if len(text) > limit:
        half = (limit - 3) // 2
        text = f"{text[:half]}...{text[-half:]}"
    return text


def input_file(path: object, kind: str = "input file") -> Path:
    """``path`` as a Path if it names a regular file, else an InputFileError that says what it is
    (missing, a folder, a FIFO, a device, a socket, a name too long): never a read that blocks."""
    import os
    import stat
    from pathlib import Path

    p = Path(str(path))
    try:
        mode = os.stat(p).st_mode
    except FileNotFoundError as err:
        raise InputFileError(f"{kind} '{shown(p)}' does not exist") from err
    except OSError as exc:
        raise InputFileError(f"{kind} '{shown(p)}' cannot be read: "
                             f"{exc.strerror or exc}") from exc
    if stat.S_ISREG(mode):
        return p
    what = ("a folder" if stat.S_ISDIR(mode) else "a FIFO (named pipe)" if stat.S_ISFIFO(mode)
            else "a character device" if stat.S_ISCHR(mode)
            else "a block device" if stat.S_ISBLK(mode)
            else "a socket" if stat.S_ISSOCK(mode) else "not a regular file")
    raise InputFileError(f"{kind} '{shown(p)}' is {what}, not a file")
