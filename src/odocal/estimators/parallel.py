"""Deterministic process parallelism for per-segment work."""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import signal
import sys
import threading
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures import TimeoutError as FuturesTimeout
from typing import TypeVar

from odocal import cancel

T = TypeVar("T")
R = TypeVar("R")


def ignore_interrupts() -> None:
    """In a worker process: Ctrl-C is the parent's to handle (it stops the workers at once)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _worker_start(parent_pid: int) -> None:
    """A pool worker's first act: leave Ctrl-C to the parent, and die with it even when it is
    killed with SIGKILL (else the worker would wait for work that never comes, for ever)."""
    ignore_interrupts()
    die_with_parent(parent_pid)


def die_with_parent(parent_pid: int) -> None:
    """In a worker process: end when the process ``parent_pid`` (its parent) ends, however it
    ends. Linux sends SIGKILL on the parent's death (``prctl(PR_SET_PDEATHSIG)``); elsewhere, or
    if that is refused, a daemon thread polls the parent."""
    armed = False
    if sys.platform.startswith("linux"):
        try:
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            pr_set_pdeathsig = 1
            armed = libc.prctl(pr_set_pdeathsig, int(signal.SIGKILL), 0, 0, 0) == 0
        except (OSError, AttributeError):
            armed = False
    if os.getppid() != parent_pid:               # the parent died before the signal was set
        os._exit(1)
    if armed:
        return

    def watch() -> None:                         # pragma: no cover - not on Linux
        import time

        while os.getppid() == parent_pid:
            time.sleep(0.5)
        os._exit(1)

    threading.Thread(target=watch, name="odocal-parent-watch", daemon=True).start()


@contextlib.contextmanager
def interrupts_held() -> Iterator[None]:
    """Hold Ctrl-C back while processes are forked, and deliver it after.

    A SIGINT that lands during ``fork()`` raises KeyboardInterrupt inside the interpreter's
    at-fork handlers (logging's lock release), where Python prints it as ignored and the run
    goes on as if nothing was pressed. Blocked here, it stays pending and is raised as soon as
    the forks are done.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def _cores() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not on Linux
        return max(1, os.cpu_count() or 1)


def resolve_workers(workers: int) -> int:
    """``0`` means every core this process may use; more than that is cut to it (the results
    are the same for any number of workers, and more processes than cores only cost memory)."""
    if workers > 0:
        return min(workers, _cores())
    return _cores()


def _result(future: Future[R]) -> R:
    """A worker's result, looking every :data:`POLL_S` seconds whether the run was asked to
    stop (:mod:`odocal.cancel`: an interrupt some library swallowed)."""
    while True:
        cancel.check()
        try:
            return future.result(timeout=POLL_S)
        except FuturesTimeout:
            continue


#: Seconds between two looks at a stop request while a worker computes.
POLL_S = 0.2


def map_chunks(func: Callable[[T], R], tasks: Sequence[T], *, workers: int = 1,
               weights: Sequence[int] | None = None,
               progress: Callable[[int, int], None] | None = None) -> list[R]:
    """``[func(t) for t in tasks]``, in order, over ``workers`` processes.

    The results are those of the serial loop whatever the number of workers: each task is
    computed alone and the list keeps the tasks' order. Workers are forked, so a task may read
    large inputs its caller set aside in a module before the call (they are not copied into
    each task); where processes cannot be forked, the tasks run here, one after another.
    ``progress(done, total)`` is called with the summed ``weights`` of the finished tasks.
    """
    weights = list(weights) if weights is not None else [1] * len(tasks)
    total = sum(weights)
    done = 0
    if progress:
        progress(0, total)
    n_workers = min(resolve_workers(workers), len(tasks))
    if "fork" not in multiprocessing.get_all_start_methods():
        n_workers = 1                    # workers read shared inputs through the fork
    if n_workers <= 1:
        out: list[R] = []
        for task, w in zip(tasks, weights, strict=True):
            cancel.check()
            out.append(func(task))
            done += w
            if progress:
                progress(done, total)
        return out
    pool = _start_pool(n_workers)
    try:
        futures = [pool.submit(func, task) for task in tasks]
        results: list[R] = []
        for future, w in zip(futures, weights, strict=True):
            results.append(_result(future))
            done += w
            if progress:
                progress(done, total)
    except BaseException:
        _stop_pool(pool)      # interrupted or failed: the workers stop now, not after the queue
        raise
    pool.shutdown()
    return results


def _start_pool(n_workers: int) -> ProcessPoolExecutor:
    """A pool of ``n_workers`` forked processes that leave Ctrl-C to this one and die with it.

    A fork pool forks all its workers as the first task is submitted: that happens here, with
    nothing to do, while Ctrl-C is held back (:func:`interrupts_held`)."""
    with interrupts_held():
        pool = ProcessPoolExecutor(max_workers=n_workers, initializer=_worker_start,
                                   initargs=(os.getpid(),),
                                   mp_context=multiprocessing.get_context("fork"))
        try:
            pool.submit(_nothing)
        except BaseException:
            _stop_pool(pool)
            raise
    return pool


def _nothing() -> None:
    """A task that makes a pool fork its worker."""


def _stop_pool(pool: ProcessPoolExecutor) -> None:
    """Drop the queued work and end the workers at once (their work is lost anyway)."""
    processes = list(getattr(pool, "_processes", {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        with contextlib.suppress(Exception):
            process.kill()
    for process in processes:
        with contextlib.suppress(Exception):
            process.join(5.0)


def _evaluate(func: Callable[[T], R], chunk: Sequence[T]) -> list[R]:
    return [func(x) for x in chunk]


@contextlib.contextmanager
def process_map(workers: int) -> Iterator[Callable[[Callable[[T], R], Iterable[T]], list[R]]]:
    """A map-like callable, ``map(func, items) -> list``, over ``workers`` processes that live
    for the block: for an optimiser that evaluates a population per iteration (scipy's
    ``differential_evolution(workers=...)``), without the optimiser's own pool, whose workers
    take Ctrl-C themselves (each prints a traceback, semaphores leak, and a worker may be left
    running). These workers leave Ctrl-C to this process, die with it, and are stopped at once
    when the block ends by an exception or an interrupt; the results keep the items' order.
    One worker or no ``fork``: the items are evaluated here.
    """
    n_workers = resolve_workers(workers)
    if n_workers <= 1 or "fork" not in multiprocessing.get_all_start_methods():
        def serial(func: Callable[[T], R], items: Iterable[T]) -> list[R]:
            out = []
            for x in items:
                cancel.check()
                out.append(func(x))
            return out

        yield serial
        return
    pool = _start_pool(n_workers)

    def parallel(func: Callable[[T], R], items: Iterable[T]) -> list[R]:
        listed = list(items)
        size = -(-len(listed) // n_workers) if listed else 1
        futures = [pool.submit(_evaluate, func, listed[i:i + size])
                   for i in range(0, len(listed), size)]
        return [r for future in futures for r in _result(future)]

    try:
        yield parallel
    except BaseException:
        _stop_pool(pool)
        raise
    pool.shutdown()
