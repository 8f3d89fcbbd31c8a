"""Deterministic process parallelism for per-segment work."""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import signal
import sys
import threading
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from typing import TypeVar

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
            out.append(func(task))
            done += w
            if progress:
                progress(done, total)
        return out
    with interrupts_held():             # the workers are forked while submitting
        pool = ProcessPoolExecutor(max_workers=n_workers, initializer=_worker_start,
                                   initargs=(os.getpid(),),
                                   mp_context=multiprocessing.get_context("fork"))
        try:
            futures = [pool.submit(func, task) for task in tasks]
        except BaseException:
            pool.shutdown(wait=False, cancel_futures=True)
            raise
    try:
        results: list[R] = []
        for future, w in zip(futures, weights, strict=True):
            results.append(future.result())
            done += w
            if progress:
                progress(done, total)
    except BaseException:
        # interrupted or failed: drop the queued work and stop the workers now, not after it
        processes = list(getattr(pool, "_processes", {}).values())
        pool.shutdown(wait=False, cancel_futures=True)
        for process in processes:
            process.terminate()
        raise
    pool.shutdown()
    return results
