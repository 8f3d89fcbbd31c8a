"""Ctrl-C for the ``odocal`` program: exit 130 with one line, at any moment.

Python turns SIGINT into a KeyboardInterrupt wherever the main thread happens to be, and some
compiled library code drops it: pyarrow, asked for a column as numpy, checks whether pandas can
be imported; an interrupt that lands during that import is swallowed with it, the run goes on
(for 22 s, then exit 0), and pandas is left half-imported (the next use of it fails, exit 4).

So the program's handler also remembers the interrupt: the commands call :func:`checkpoint` as
they go (replay at every update), which raises it again, and ``main`` reports any failure after
an interrupt, and any run that ends after one, as the interrupt it is (exit 130; not for a
command whose normal end is Ctrl-C, ``odocal ros2``, which catches it itself). The handler is
installed only by the program itself (:func:`install` from :func:`odocal.cli.run` and
``main()`` without arguments), never by a caller of ``main([...])``.
"""

from __future__ import annotations

import os
import signal
import sys
from types import FrameType

_seen = False


def _on_interrupt(signum: int, frame: FrameType | None) -> None:
    global _seen
    _seen = True
    raise KeyboardInterrupt


def install() -> None:
    """SIGINT raises KeyboardInterrupt, as Python's own handler does, and is remembered."""
    signal.signal(signal.SIGINT, _on_interrupt)


def interrupted() -> bool:
    """Whether Ctrl-C was pressed (since :func:`install`)."""
    return _seen


def checkpoint() -> None:
    """Raise KeyboardInterrupt if Ctrl-C was pressed and the interrupt was swallowed."""
    if _seen:
        raise KeyboardInterrupt


def leave(command: str) -> None:
    """One line on stderr, and exit 130 at once (nothing is waited for on the way out)."""
    try:
        sys.stderr.write(f"{command}: interrupted\n")
        sys.stderr.flush()
        sys.stdout.flush()
    except (OSError, ValueError):               # the terminal went away too
        pass
    os._exit(130)
