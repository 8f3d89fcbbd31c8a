"""Stopping a run that the user asked to stop (Ctrl-C), at the next safe point.

Python turns SIGINT into a KeyboardInterrupt wherever the main thread happens to be, and some
library code drops it (a bare ``except:`` around an import, pyarrow asking whether pandas
imports, an at-fork handler): the run then goes on as if nothing was pressed. The ``odocal``
program's handler (:mod:`odocal.cli.interrupt`) therefore also *remembers* the request here,
and the library looks at it as it goes: every stage and step a calibration reports
(:class:`odocal.pipeline.calibrate.Stopwatch`), every task of a worker pool, every generation of
the minimum's search, every update of a replay, every fleet result; and, above all, right
before a finished output replaces an earlier one (:mod:`odocal.io.atomic`): a run asked to stop
never publishes its results, whenever the request came.

Nothing sets the request but a signal handler that chose to (a caller of the library who
installs none gets Python's own behaviour); :func:`check` raises KeyboardInterrupt, so a stop
unwinds through the same ``finally`` blocks (temporary folders removed, worker pools stopped)
as an interrupt that was not swallowed.

A leaf module: nothing of odocal imported.
"""

from __future__ import annotations

_requested = [False]


def request() -> None:
    """Remember that the user asked the run to stop (called from a signal handler)."""
    _requested[0] = True


def requested() -> bool:
    """Whether a stop was asked for (and not cleared)."""
    return _requested[0]


def clear() -> None:
    """Forget a request (a program that starts a new run in the same process)."""
    _requested[0] = False


def check() -> None:
    """Raise KeyboardInterrupt if a stop was asked for: the caller is at a safe point."""
    if _requested[0]:
        raise KeyboardInterrupt
