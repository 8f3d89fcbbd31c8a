"""The node's calibrator, in a process of its own beside the node's (or in its thread).

The node puts the messages onto the drive's grid and sends the rows here in replay's blocks;
here they are pushed into an :class:`~odocal.OnlineCalibrator` and the estimate is taken every
``[online] update_s`` of data, as ``odocal replay`` takes it. What comes back are events, in the
order they happened: samples left out, alarms raised, estimates taken, the request's blocks
pushed, each with a :class:`View` of the calibrator as it was then.

In its own process (:class:`Beside`, the node's default) the estimates (tens to a hundred
milliseconds each) never hold up the node's thread, which takes the messages and publishes the
odometry; the requests are answered in order, each answer once, and the node reads them as they
come (:meth:`Beside.answers`) or waits for them all (:meth:`Beside.settle`, at the drive's end).
In the node's thread (:class:`InThread`) each request is answered at once. Both run the same
:class:`Schedule`, so the estimates are the same, only when the node publishes them differs.
The process is started with Ctrl-C and SIGTERM blocked and ignores them: the node ends it by
closing its pipe after the final estimate (it also ends when the node's process dies).
"""

from __future__ import annotations

import multiprocessing
import queue
import signal
import threading
import time
from collections import deque
from dataclasses import dataclass
from multiprocessing import resource_tracker
from typing import Any

import numpy as np

from odocal.checks.findings import Finding
from odocal.errors import DataError, OdocalError
from odocal.estimators.estimate import Estimate
from odocal.online.calibrator import OnlineCalibrator, Updates
from odocal.online.changes import Alarm
from odocal.settings import Settings

Block = dict[str, np.ndarray]


@dataclass(frozen=True)
class View:
    """What the node reads of its calibrator, as of an event."""

    halted: bool = False
    distance_km: float = 0.0
    samples: int = 0
    span_s: tuple[float, float] | None = None
    findings: tuple[Finding, ...] = ()
    alarms: tuple[Alarm, ...] = ()


@dataclass(frozen=True)
class LeftOut:
    """A block the calibrator could not use (from ``t0``, s), with why."""

    t0: float
    message: str
    view: View


@dataclass(frozen=True)
class Raised:
    """A change alarm (or several) raised by a push."""

    view: View


@dataclass(frozen=True)
class Updated:
    """An estimate taken (every ``update_s`` of data, where the calibrator halted, or asked)."""

    estimate: Estimate
    view: View


@dataclass(frozen=True)
class Pushed:
    """The blocks of a request pushed (the last event of each push request)."""

    view: View


Event = LeftOut | Raised | Updated | Pushed


class Schedule:
    """An :class:`OnlineCalibrator` fed as replay feeds it: blocks pushed until it halts, the
    estimate every ``[online] update_s`` of data and at once where it halts."""

    def __init__(self, settings: Settings) -> None:
        self.calibrator = OnlineCalibrator(settings)
        self._updates = Updates(settings.online.update_s)
        self._alarms = 0

    def view(self) -> View:
        c = self.calibrator
        return View(halted=c.halted, distance_km=c.distance_km, samples=c.details_samples(),
                    span_s=c.span_s, findings=tuple(c.diagnosis.findings),
                    alarms=tuple(c.alarms))

    def push(self, blocks: list[Block]) -> list[Event]:
        events: list[Event] = []
        c = self.calibrator
        for block in blocks:
            if c.halted:
                break
            try:
                c.push(block)
            except DataError as exc:            # a block it cannot use: said, and left out
                events.append(LeftOut(float(block["t"][0]), str(exc), self.view()))
                continue
            if c.halted:
                events.append(self.estimate())
                break
            if len(c.alarms) > self._alarms:
                self._alarms = len(c.alarms)
                events.append(Raised(self.view()))
            if self._updates.due(c.span_s):
                events.append(self.estimate(running=True))
        events.append(Pushed(self.view()))
        return events

    def estimate(self, *, running: bool = False) -> Updated:
        """The estimate now (``running``: a periodic update, as replay's are:
        :meth:`~odocal.online.calibrator.OnlineCalibrator.estimate`)."""
        est = self.calibrator.estimate(running=running)
        self._alarms = len(self.calibrator.alarms)
        return Updated(est, self.view())


class InThread:
    """The schedule in the node's own thread: each request answered at once."""

    def __init__(self, settings: Settings) -> None:
        self._schedule = Schedule(settings)
        self._events: deque[Event] = deque()

    def push(self, blocks: list[Block]) -> None:
        self._events.extend(self._schedule.push(blocks))

    def estimate(self) -> None:
        self._events.append(self._schedule.estimate())

    def answers(self) -> list[Event]:
        out = list(self._events)
        self._events.clear()
        return out

    def settle(self, timeout_s: float = 0.0) -> list[Event]:
        return self.answers()

    @property
    def idle(self) -> bool:
        return not self._events

    @property
    def backlog(self) -> int:
        return 0

    def close(self, *, wait: bool = True) -> None:
        self._events.clear()


class CalibratorLost(OdocalError):
    """The calibrator's process ended before it answered."""


#: How long (s) the node waits at most for the calibrator's last answers (the drive's end, an
#: estimate asked for): a process that does not answer by then (frozen, stopped) is ended.
SETTLE_S = 10.0


class Beside:
    """The schedule in a process of its own (spawned, signals blocked: see the module). The
    requests go out through a thread of the node's (its sends wait on a full pipe, never the
    node's thread, whatever the calibrator does)."""

    def __init__(self, settings: Settings) -> None:
        context = multiprocessing.get_context("spawn")
        self._conn, child = context.Pipe()
        self._process = context.Process(target=_serve, args=(child, settings), daemon=True,
                                        name="odocal calibrator")
        # (starting multiprocessing's resource tracker unblocks both signals in the calling
        # thread: it is started first, so that the calibrator is born with them blocked)
        resource_tracker.ensure_running()
        held = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})
        try:
            self._process.start()
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, held)
        child.close()
        self._waiting = 0
        self._broken = False
        self._outbox: queue.SimpleQueue[tuple[str, Any] | None] = queue.SimpleQueue()
        self._sender = threading.Thread(target=self._send_all, name="calibrator requests",
                                        daemon=True)
        self._sender.start()

    def push(self, blocks: list[Block]) -> None:
        self._send(("push", blocks))

    def estimate(self) -> None:
        self._send(("estimate", None))

    def _send(self, request: tuple[str, Any]) -> None:
        if self._broken or not self._process.is_alive():
            raise self._lost()
        self._outbox.put(request)
        self._waiting += 1

    def _send_all(self) -> None:
        while (request := self._outbox.get()) is not None:
            try:
                self._conn.send(request)
            except (OSError, ValueError, TypeError):
                # (TypeError: the pipe closed under this send by the node's release, its
                # handle gone: multiprocessing writes to None)
                self._broken = True
                return

    def answers(self) -> list[Event]:
        """The events of every request answered so far (never waits)."""
        out: list[Event] = []
        try:
            while self._waiting and self._conn.poll():
                out.extend(self._conn.recv())
                self._waiting -= 1
        except (EOFError, OSError) as exc:
            raise self._lost() from exc
        if self._waiting and (self._broken or not self._process.is_alive()):
            raise self._lost()
        return out

    def settle(self, timeout_s: float = SETTLE_S) -> list[Event]:
        """The events of every request sent, waiting for those not answered yet (at most
        ``timeout_s``: then the process is ended and named lost)."""
        out: list[Event] = []
        deadline = time.monotonic() + timeout_s
        try:
            while self._waiting:
                if not self._conn.poll(max(deadline - time.monotonic(), 0.0)):
                    self._process.kill()
                    raise self._lost(f"did not answer within {timeout_s:g} s; it was ended")
                out.extend(self._conn.recv())
                self._waiting -= 1
        except (EOFError, OSError) as exc:
            raise self._lost() from exc
        return out

    @property
    def idle(self) -> bool:
        """Whether every request sent has been answered and read."""
        return self._waiting == 0

    @property
    def backlog(self) -> int:
        """The requests sent and not answered yet."""
        return self._waiting

    def _lost(self, why: str = "") -> CalibratorLost:
        self._process.join(timeout=1.0)
        self._waiting = 0
        return CalibratorLost("the calibrator's process " + (why or f"ended (exit code "
                              f"{self._process.exitcode})") + ": nothing more is calibrated")

    def close(self, *, wait: bool = True) -> None:
        """The process ended: its pipe closed, and (``wait``) it exits as it reads the end (one
        that does not within half a second is killed); without ``wait`` it is killed at once
        (what it was doing is forgotten: a reset)."""
        self._outbox.put(None)
        self._conn.close()              # (a send under way in the sender thread fails: it ends)
        if wait:
            self._process.join(timeout=0.5)
        if self._process.is_alive():
            self._process.kill()
            self._process.join()


def _serve(conn: Any, settings: Settings) -> None:
    """The calibrator's process: one answer (a list of events) per request, until the pipe
    ends. A thread of its own reads the requests as they come, so that the node's sends never
    wait on a full pipe while an estimate is taken."""
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT, signal.SIGTERM})
    requests: queue.SimpleQueue[tuple[str, Any] | None] = queue.SimpleQueue()

    def read() -> None:
        while True:
            try:
                requests.put(conn.recv())
            except (EOFError, OSError):
                requests.put(None)
                return

    threading.Thread(target=read, name="requests", daemon=True).start()
    schedule = Schedule(settings)
    while (request := requests.get()) is not None:
        kind, blocks = request
        events: list[Event] = (schedule.push(blocks) if kind == "push"
                               else [schedule.estimate()])
        try:
            conn.send(events)
        except OSError:
            return
