"""Drawing the report's figures from plain data, in this process or in forked helpers.

A figure is described by a :class:`FigureSpec`: its size, its grid of axes and a list of calls
of the plot functions in :mod:`odocal.report.figures` with their (numpy) arguments. Specs are
built without matplotlib and are small, so they travel to helper processes cheaply; the helpers
draw them and send back PNG bytes.

A :class:`Renderer` started before the calibration forks its helper while the process is still
light, and it imports matplotlib at once, on the otherwise idle core, while the calibration
computes: by the time the figures are wanted, the plotting library is loaded, and the helper
forks the processes that draw beside it from itself.
"""

from __future__ import annotations

import gc
import io
import multiprocessing
import os
import pickle
import signal
import sys
import weakref
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

DPI = 110


@dataclass(frozen=True)
class Call:
    """One call ``figures.<function>(axes[row][col], *args, **kwargs)``; ``row`` None: all axes
    of the first row are passed as a list (for functions that draw on several axes)."""

    function: str
    args: tuple[Any, ...] = ()
    kwargs: dict[str, Any] = field(default_factory=dict)
    row: int | None = 0
    col: int = 0


@dataclass(frozen=True)
class FigureSpec:
    """What to draw for one figure of the page."""

    name: str
    caption: str
    width: float
    height: float
    calls: tuple[Call, ...]
    rows: int = 1
    cols: int = 1
    #: Relative heights of the rows (None: equal).
    height_ratios: tuple[float, ...] | None = None


def figure(spec: FigureSpec) -> Any:
    """The matplotlib figure of one spec, drawn (not yet saved)."""
    from matplotlib.figure import Figure

    from odocal.report import figures

    fig = Figure(figsize=(spec.width, spec.height), dpi=DPI, layout="constrained")
    axes = fig.subplots(spec.rows, spec.cols, squeeze=False,
                        height_ratios=list(spec.height_ratios) if spec.height_ratios else None)
    for call in spec.calls:
        target: Any = list(axes[0]) if call.row is None else axes[call.row][call.col]
        getattr(figures, call.function)(target, *call.args, **call.kwargs)
    return fig


def draw(spec: FigureSpec) -> bytes:
    """The PNG of one figure."""
    buffer = io.BytesIO()
    figure(spec).savefig(buffer, format="png", dpi=DPI, pil_kwargs={"compress_level": 3})
    return buffer.getvalue()


def _warm_up() -> None:
    """Draw a small figure: the first figure a process draws pays for loading fonts and
    building caches (0.3 s of the map's 0.55 s on a one-hour drive)."""
    import numpy as np

    line = np.array([[0.0, 0.0], [1.0, 1.0]])
    draw(FigureSpec("warm-up", "", 2.0, 1.5, (
        Call("plot_map", (line, line, line), {"title": "warm-up"}),
        Call("legend", kwargs={"fontsize": 8}))))


def _host(connection: Any, callers: Any, workers: int, caller_pid: int | None = None) -> None:
    """The helper process: loads matplotlib once, then draws each list of specs it receives,
    with ``workers - 1`` processes forked from itself for the time (they start with the library
    loaded and warm), and sends back the PNGs, or the exception. ``None`` or the caller's end
    ends it; SIGTERM ends it at once, and so does the end of the caller (``caller_pid``), however
    it ends (Ctrl-C leaves at once: no helper is left drawing)."""
    from odocal.estimators.parallel import die_with_parent, ignore_interrupts

    callers.close()        # our copy of the caller's end: its EOF must reach us when it goes
    ignore_interrupts()
    if caller_pid is not None:
        die_with_parent(caller_pid)
    # the caller's computation goes first while we prepare (its stages took 0.1 s longer)
    os.nice(5)
    import matplotlib.backends.backend_agg
    import matplotlib.figure  # noqa: F401

    import odocal.report.figures  # noqa: F401

    _warm_up()
    # what is loaded now is never collected: the drawing processes' collections then do not
    # touch (and so copy) the pages they share with this one
    gc.freeze()
    while (specs := _receive(connection)) is not None:
        try:
            pngs = _draw_forked(specs, workers)
        except Exception as exc:  # sent to the caller, raised there
            connection.send(exc)
        else:
            connection.send(pngs)


def _draw_forked(specs: Sequence[FigureSpec], workers: int) -> list[bytes]:
    """Every spec drawn by this process and ``workers - 1`` forked ones, which take the next
    undrawn figure from a pipe of indices (a one-byte read is atomic: no locks to be left held
    by a process that stops), and send back what they drew."""
    helpers = min(workers, len(specs)) - 1
    if helpers < 1 or len(specs) > 256:                 # (indices are single bytes)
        return [draw(s) for s in specs]
    tasks_in, tasks_out = os.pipe()
    os.write(tasks_out, bytes(range(len(specs))))
    os.close(tasks_out)
    children = []
    host = os.getpid()
    for _ in range(helpers):
        results_in, results_out = os.pipe()
        pid = os.fork()
        if pid == 0:                                       # a drawing process
            from odocal.estimators.parallel import die_with_parent

            die_with_parent(host)
            os.close(results_in)
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
            code = 0
            try:
                drawn = _take_and_draw(tasks_in, specs)
                with os.fdopen(results_out, "wb") as out:
                    pickle.dump(drawn, out)
            except BaseException:                          # the parent draws them again
                code = 1
            finally:
                os._exit(code)
        os.close(results_out)
        children.append((pid, results_in))
    pngs = _take_and_draw(tasks_in, specs)
    os.close(tasks_in)
    for pid, results_in in children:
        with os.fdopen(results_in, "rb") as answer:
            data = answer.read()
        os.waitpid(pid, 0)
        if data:
            pngs.update(pickle.loads(data))
    # a figure a drawing process failed on is drawn here (and raises here if it fails again)
    return [pngs[i] if i in pngs else draw(s) for i, s in enumerate(specs)]


def _take_and_draw(tasks: int, specs: Sequence[FigureSpec]) -> dict[int, bytes]:
    drawn: dict[int, bytes] = {}
    while index := os.read(tasks, 1):
        drawn[index[0]] = draw(specs[index[0]])
    return drawn


def _receive(connection: Any) -> Any:
    """The next message, or None when the caller has gone (it ended without closing us)."""
    try:
        return connection.recv()
    except (EOFError, OSError):
        return None


def _shut(process: Any, connection: Any) -> None:
    process.terminate()
    process.join(_STOP_WAIT_S)
    if process.is_alive():                        # never let a figure helper hold up the exit
        process.kill()
        process.join()
    connection.close()


#: Seconds a helper gets to stop its drawing processes before it is killed.
_STOP_WAIT_S = 10.0


class Renderer:
    """Draws figure specs, in helper processes (started now) or in this process
    (``workers = 0``).

    One helper is forked at once; it loads matplotlib while the caller works, and when figures
    are wanted it draws them with ``workers - 1`` processes forked from itself, so the library
    is imported once (importing it in two helpers at once slowed a one-hour calibration by
    0.8 s on two cores).

    Use as a context manager; start it early (before heavy imports and computation) so that the
    helper forks from a light process and is ready when the figures are wanted.
    """

    def __init__(self, workers: int = 0) -> None:
        self._process: Any = None
        self._connection: Any = None
        # the helper is forked; from a process that runs ROS 2 it is spawned instead (the
        # middleware's threads do not survive a fork: a forked helper crashed collecting
        # garbage), and forks its drawing processes from itself as ever
        method = "spawn" if "rclpy" in sys.modules else "fork"
        if workers > 0 and method in multiprocessing.get_all_start_methods():
            context: Any = multiprocessing.get_context(method)
            self._connection, theirs = context.Pipe()
            self._process = context.Process(target=_host, daemon=True,
                                            args=(theirs, self._connection, workers,
                                                  os.getpid()))
            self._process.start()
            theirs.close()
            # stopped with this object, or at exit if nobody closed it
            self._finalizer = weakref.finalize(self, _shut, self._process, self._connection)

    def draw(self, specs: Sequence[FigureSpec]) -> list[bytes]:
        if self._process is None:
            return [draw(s) for s in specs]
        self._connection.send(list(specs))
        answer = self._connection.recv()
        if isinstance(answer, BaseException):
            raise answer
        return list(answer)

    def close(self) -> None:
        if self._process is not None:
            self._finalizer()
            self._process = None

    def __enter__(self) -> Renderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
