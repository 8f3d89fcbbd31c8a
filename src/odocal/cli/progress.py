"""Progress on the terminal: what is being done, how far it is and how long is left.

A stage that counts sub-steps (batches, segments, generations, drives) gets a tqdm bar with its
count, the time spent and tqdm's estimate of the time left. A stage of one step (reading the
logs, the checks, writing the report) gets a line that shows its elapsed time as it runs and
"done" when it ends, never a bar that jumps from 0/1 to 1/1. An open bar or line is redrawn every
half second, so the clock moves even while one long step (a first compilation, a slow
generation) reports nothing. A stage that ends within :data:`SLOW_S` seconds is wiped; a slower
one stays on the screen with its time.

Where stderr is not a terminal (a log file, CI) no bars are drawn: one line as each stage starts,
a line with the count and the time left at most every :data:`LINE_EVERY_S` seconds, and one
when a stage that took :data:`SLOW_S` seconds or more ends. ``-q`` shows nothing.

``ODOCAL_PROGRESS`` overrides the choice: ``bars`` (draw bars even into a pipe), ``lines`` or
``off``.
"""

from __future__ import annotations

import os
import sys
import threading
import time
from typing import Any, TextIO

#: The environment variable that forces a mode: bars, lines or off.
ENV = "ODOCAL_PROGRESS"
MODES = ("bars", "lines", "off")
#: Seconds between two lines of one stage in line mode.
LINE_EVERY_S = 10.0
#: A stage that took this long gets a closing line in line mode.
SLOW_S = 2.0
#: Seconds between redraws of the open bars.
TICK_S = 0.5

#: Held while a bar is drawn (by a callback or the redrawing thread), and across a fork: a worker
#: forked while the redrawing thread wrote to stderr would inherit stderr's lock held for good.
_DRAWING = threading.RLock()
if hasattr(os, "register_at_fork"):
    os.register_at_fork(before=_DRAWING.acquire, after_in_parent=_DRAWING.release,
                        after_in_child=_DRAWING.release)

_COUNTED = "{desc}: {percentage:3.0f}%|{bar}| {n_fmt}/{total_fmt} [{elapsed}<{remaining}]"
_RUNNING = "{desc} ... {elapsed_s:.0f} s"
_DONE = "{desc}: done in {elapsed_s:.1f} s"


def _mode(enabled: bool, stream: TextIO) -> str:
    if not enabled:
        return "off"
    forced = os.environ.get(ENV, "").strip().lower()
    if forced in MODES:
        return forced
    try:
        return "bars" if stream.isatty() else "lines"
    except (AttributeError, ValueError):           # a closed or odd stream
        return "lines"


def _clock(seconds: float) -> str:
    seconds = max(0, round(seconds))
    return f"{seconds // 60}:{seconds % 60:02d}" if seconds >= 60 else f"{seconds} s"


class _Stage:
    def __init__(self, total: int) -> None:
        self.started = time.perf_counter()
        self.total = total
        self.done = 0
        self.said = self.started                   # line mode: when the last line was written
        self.bar: Any = None
        self.open = True


class Progress:
    """A ``progress(stage, done, total)`` callback that draws on stderr (see the module text).

    ``enabled`` False (``-q``) shows nothing. ``mode`` (bars, lines, off) overrides both the
    terminal test and ``ODOCAL_PROGRESS``; ``stream`` defaults to stderr.
    """

    def __init__(self, enabled: bool, *, mode: str | None = None,
                 stream: TextIO | None = None) -> None:
        self.stream = stream if stream is not None else sys.stderr
        self.mode = mode if mode in MODES else _mode(enabled, self.stream)
        if not enabled:
            self.mode = "off"
        self.enabled = self.mode == "bars"
        self.lines = self.mode == "lines"
        self.started = time.perf_counter()
        self.stages: dict[str, _Stage] = {}
        self._lock = _DRAWING
        self._ticker: threading.Thread | None = None
        self._stop = threading.Event()

    # -- the callback ------------------------------------------------------------------------

    def __call__(self, stage: str, done: int, total: int) -> None:
        if self.mode == "off":
            return
        with self._lock:
            state = self.stages.get(stage)
            if state is None or not state.open:
                if state is not None and done >= total:
                    return                          # a late 'done' of a finished stage
                state = self.stages[stage] = _Stage(total)
                self._begin(stage, state)
            state.total, state.done = total, done
            if self.enabled:
                self._draw(state)
            elif done < total:
                self._line_progress(stage, state)
            if done >= total:
                self._end(stage, state)

    def close(self) -> None:
        """Close every open bar (a stage left unfinished by an error) and stop redrawing."""
        with self._lock:
            for state in self.stages.values():
                if state.bar is not None and state.open:
                    state.bar.close()
                state.open = False
            self.stages.clear()
        self._stop.set()
        if self._ticker is not None and self._ticker is not threading.current_thread():
            self._ticker.join(timeout=1.0)
        self._ticker = None

    # -- bars --------------------------------------------------------------------------------

    def _begin(self, stage: str, state: _Stage) -> None:
        if self.lines:
            self._write(f"{stage} ...")
            return
        from tqdm import tqdm

        counted = state.total > 1
        state.bar = tqdm(total=state.total if counted else None, desc=stage, leave=True,
                         file=self.stream, dynamic_ncols=True, mininterval=0.0,
                         bar_format=_COUNTED if counted else _RUNNING)
        self._tick()

    def _draw(self, state: _Stage) -> None:
        bar = state.bar
        if bar is None:
            return
        if state.total > 1:
            if bar.total != state.total:
                bar.total = state.total
                bar.bar_format = _COUNTED
            bar.n = min(state.done, state.total)
        bar.refresh()

    def _end(self, stage: str, state: _Stage) -> None:
        state.open = False
        if state.bar is not None:
            # a quick stage is wiped when it ends; one that took a while stays, with its time
            state.bar.leave = time.perf_counter() - state.started >= SLOW_S
            if state.total <= 1 and state.bar.leave:
                state.bar.bar_format = _DONE
                state.bar.refresh()
            state.bar.close()
        elif self.lines:
            took = time.perf_counter() - state.started
            if took >= SLOW_S:
                self._write(f"{stage}: done in {_clock(took)}")

    def _tick(self) -> None:
        """Start the thread that redraws the open bars, so their clocks move."""
        if self._ticker is not None:
            return
        self._stop.clear()

        def redraw() -> None:
            while not self._stop.wait(TICK_S):
                with self._lock:
                    for state in self.stages.values():
                        if state.open and state.bar is not None:
                            state.bar.refresh()

        self._ticker = threading.Thread(target=redraw, name="odocal-progress", daemon=True)
        self._ticker.start()

    # -- lines -------------------------------------------------------------------------------

    def _line_progress(self, stage: str, state: _Stage) -> None:
        now = time.perf_counter()
        if not self.lines or state.total <= 1 or state.done <= 0 \
                or now - state.said < LINE_EVERY_S:
            return
        state.said = now
        spent = now - state.started
        left = spent / state.done * (state.total - state.done)
        self._write(f"{stage}: {state.done}/{state.total}, {_clock(spent)} so far, "
                    f"about {_clock(left)} left")

    def _write(self, text: str) -> None:
        self.stream.write(f"[{time.perf_counter() - self.started:6.1f} s] {text}\n")
        self.stream.flush()
