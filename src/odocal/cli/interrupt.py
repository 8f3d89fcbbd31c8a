"""Ctrl-C for the ``odocal`` program: exit 130 with one line, at any moment.

Python turns SIGINT into a KeyboardInterrupt wherever the main thread happens to be, and some
compiled library code drops it: pyarrow, asked for a column as numpy, checks whether pandas can
be imported; an interrupt that lands during that import is swallowed with it, the run goes on
(for 22 s, then exit 0), and pandas is left half-imported (the next use of it fails, exit 4).

So the program's handler also remembers the interrupt (in :mod:`odocal.cancel`, where the
library looks as it goes, and before any result replaces an earlier one): the commands call
:func:`checkpoint` as they go (replay at every update), which raises it again, and ``main``
reports any failure after an interrupt, and any run that ends after one, as the interrupt it
is (exit 130; not for a command whose normal end is Ctrl-C, ``odocal ros2``, which catches it
itself). The handler is installed only by the program itself (:func:`install` from
:func:`odocal.cli.run` and ``main()`` without arguments), never by a caller of
``main([...])``.

A clean-up that never comes back (a library waiting on a closing connection: Dask's client
waits up to a minute for a scheduler that is going away) must not keep the program: once a
command is :func:`watch`-ed, Ctrl-C also starts a timer that leaves (:func:`leave`: its one
line, exit 130) :data:`LEAVE_WITHIN_S` seconds later if the program is still there.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
from types import FrameType

from odocal import cancel

#: Seconds from Ctrl-C to the program leaving whatever its clean-up is waiting for.
LEAVE_WITHIN_S = 5.0

_watched: list[str | None] = [None]      # the command whose Ctrl-C starts the timer
_leaving = threading.Lock()              # one leave: the timer's or the program's


def _on_interrupt(signum: int, frame: FrameType | None) -> None:
    first = not cancel.requested()
    cancel.request()
    command = _watched[0]
    if first and command is not None:
        timer = threading.Timer(LEAVE_WITHIN_S, leave, args=(command,))
        timer.daemon = True
        timer.start()
    raise KeyboardInterrupt


def watch(command: str) -> None:
    """From now on Ctrl-C leaves within :data:`LEAVE_WITHIN_S` seconds as ``command``, whatever
    the program's clean-up waits for (not for a command that handles Ctrl-C as its normal end)."""
    _watched[0] = command


def install() -> None:
    """SIGINT raises KeyboardInterrupt, as Python's own handler does, and is remembered."""
    signal.signal(signal.SIGINT, _on_interrupt)


def interrupted() -> bool:
    """Whether Ctrl-C was pressed (since :func:`install`)."""
    return cancel.requested()


def checkpoint() -> None:
    """Raise KeyboardInterrupt if Ctrl-C was pressed and the interrupt was swallowed."""
    cancel.check()


def _release_semaphores() -> None:
    """Unlink the named semaphores this process made for processes it spawned (a Dask
    cluster's queues), as a normal exit's finalizers do: leaving with ``os._exit`` skips those,
    and multiprocessing's resource tracker then prints "leaked semaphore objects" after the
    program ended. Only those finalizers run here (each an unlink and a note to the tracker);
    nothing that waits."""
    util = sys.modules.get("multiprocessing.util")
    synchronize = sys.modules.get("multiprocessing.synchronize")
    if util is None or synchronize is None:
        return
    cleanup = getattr(getattr(synchronize, "SemLock", None), "_cleanup", None)
    try:
        finalizers = list(getattr(util, "_finalizer_registry", {}).values())
    except RuntimeError:                        # changed by another thread meanwhile
        return
    for finalizer in finalizers:
        if cleanup is not None and getattr(finalizer, "_callback", None) is cleanup:
            try:
                finalizer()
            except Exception:                   # already gone: nothing to release
                pass


def _kill_children() -> None:
    """Kill the processes this one started through multiprocessing (pool workers, the report's
    helper, a Dask cluster's workers, some still starting): they leave Ctrl-C to this process,
    and their work is lost anyway. Killed before their semaphores are released, which a worker
    still starting would otherwise look for (and fail on, with a traceback)."""
    mp = sys.modules.get("multiprocessing")
    if mp is None:
        return
    try:
        children = mp.active_children()
    except Exception:                           # (a child's state unreadable: leave them)
        return
    for child in children:
        try:
            child.kill()
        except Exception:
            pass


def leave(command: str) -> None:
    """One line on stderr, and exit 130 at once (nothing is waited for on the way out). Called
    twice (the program and its timer), the second call waits for the first one's exit."""
    _leaving.acquire()
    _kill_children()
    _release_semaphores()
    try:
        sys.stderr.write(f"{command}: interrupted\n")
        sys.stderr.flush()
        sys.stdout.flush()
    except (OSError, ValueError):               # the terminal went away too
        pass
    os._exit(130)
