"""Deterministic process parallelism for per-segment work."""

from __future__ import annotations

import os
import signal
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from typing import TypeVar

T = TypeVar("T")
R = TypeVar("R")


def ignore_interrupts() -> None:
    """In a worker process: Ctrl-C is the parent's to handle (it stops the workers at once)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def resolve_workers(workers: int) -> int:
    """``0`` means every core this process may use."""
    if workers > 0:
        return workers
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not on Linux
        return max(1, os.cpu_count() or 1)


def map_chunks(func: Callable[[T], R], tasks: Sequence[T], *, workers: int = 1,
               weights: Sequence[int] | None = None,
               progress: Callable[[int, int], None] | None = None) -> list[R]:
    """``[func(t) for t in tasks]``, in order, over ``workers`` processes.

    The results are those of the serial loop whatever the number of workers: each task is
    computed alone and the list keeps the tasks' order. ``progress(done, total)`` is called with
    the summed ``weights`` of the finished tasks.
    """
    weights = list(weights) if weights is not None else [1] * len(tasks)
    total = sum(weights)
    done = 0
    if progress:
        progress(0, total)
    n_workers = min(resolve_workers(workers), len(tasks))
    if n_workers <= 1:
        out: list[R] = []
        for task, w in zip(tasks, weights, strict=True):
            out.append(func(task))
            done += w
            if progress:
                progress(done, total)
        return out
    pool = ProcessPoolExecutor(max_workers=n_workers, initializer=ignore_interrupts)
    try:
        futures = [pool.submit(func, task) for task in tasks]
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
