"""Measuring a command: wall time and the peak total memory of its whole process tree."""

from __future__ import annotations

import subprocess
import threading
import time
from collections.abc import Sequence
from pathlib import Path


def _tree(pid: int) -> list[int]:
    pids = [pid]
    i = 0
    while i < len(pids):
        try:
            tasks = list(Path(f"/proc/{pids[i]}/task").glob("*"))
        except OSError:                      # the process has just ended
            tasks = []
        for task in tasks:
            try:
                pids.extend(int(c) for c in (task / "children").read_text().split())
            except OSError:
                pass
        i += 1
    return pids


def _pss_kb(pid: int) -> int:
    """Proportional set size: shared pages (forked workers share the parent's) counted once."""
    try:
        for line in Path(f"/proc/{pid}/smaps_rollup").read_text().splitlines():
            if line.startswith("Pss:"):
                return int(line.split()[1])
    except OSError:
        pass
    return 0


def run_measured(argv: Sequence[str], *, env: dict[str, str] | None = None
                 ) -> tuple[float, float]:
    """Run ``argv``; return (wall seconds, peak summed PSS of the process tree in MB).

    The tree is sampled every 200 ms (reading PSS costs the measured process time, so more often
    would slow it down), so short spikes between samples can be missed.
    """
    start = time.perf_counter()
    proc = subprocess.Popen(list(argv), env=env)
    peak = 0
    done = threading.Event()

    def poll() -> None:
        nonlocal peak
        while not done.is_set():
            peak = max(peak, sum(_pss_kb(p) for p in _tree(proc.pid)))
            time.sleep(0.2)

    thread = threading.Thread(target=poll, daemon=True)
    thread.start()
    code = proc.wait()
    wall = time.perf_counter() - start
    done.set()
    thread.join()
    if code != 0:
        raise subprocess.CalledProcessError(code, list(argv))
    return wall, peak / 1024
