"""Ctrl-C at a chosen moment of a command, and what it left: for the interrupt tests and for
``benchmarks/bench_interrupts.py``.

A moment is a line the command writes to stderr (its progress in line mode: ``ODOCAL_PROGRESS=
lines``, one line as each stage starts) and a delay after it, never a fixed time since the
start: the same moment on a fast or a busy machine. The command runs in a session of its own, so
that every process it starts (pool workers, the report's helper, a Dask cluster) can be found
afterwards by its session id.
"""

from __future__ import annotations

import hashlib
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO

BIN = Path(sys.executable).parent


def tree_hashes(folder: Path) -> dict[str, str] | None:
    """Every file under ``folder`` (and ``folder`` itself if a file) by SHA-256; None if absent."""
    if not folder.exists():
        return None
    if folder.is_file():
        return {"": hashlib.sha256(folder.read_bytes()).hexdigest()}
    return {p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def session_processes(sid: int) -> list[int]:
    """The processes alive in session ``sid`` (zombies not counted)."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        fields = stat.rsplit(")", 1)[1].split()
        state, session = fields[0], int(fields[3])
        if session == sid and state != "Z":
            found.append(int(entry.name))
    return found


@dataclass(frozen=True)
class Outcome:
    """What Ctrl-C did: the exit code, seconds from the signal to the exit, stderr, whether the
    command had already ended before the signal (``finished``), the earlier outputs unchanged
    (``intact``), the processes still alive a moment after the exit (``left``, after up to
    ``linger_s`` of waiting for them to go) and temporary files left beside the output."""

    code: int | None
    stop_s: float
    stderr: str
    finished: bool
    intact: bool
    left: tuple[int, ...]
    leftovers: tuple[str, ...]
    reached: bool

    @property
    def clean(self) -> bool:
        """Stopped as promised: exit 130, one line, no traceback, outputs and processes as
        before (or finished before the signal came: exit 0 or 3)."""
        if not self.reached:
            return False
        if self.finished:
            return self.code in (0, 3) and not self.left
        return (self.code == 130 and self.intact and not self.left and not self.leftovers
                and "Traceback" not in self.stderr and "leaked" not in self.stderr
                and self.stderr.rstrip().endswith("interrupted"))


def interrupt_at(argv: Sequence[str], *, outputs: Sequence[Path], line: str | None = None,
                 delay_s: float = 0.0, timeout_s: float = 60.0, cwd: Path | None = None,
                 env: dict[str, str] | None = None, linger_s: float = 2.0,
                 program: Sequence[str] | None = None, signal_sent: bool = True) -> Outcome:
    """Run ``odocal argv`` (or ``program argv``); Ctrl-C ``delay_s`` after the first line (of
    stdout or stderr) holding ``line`` (None: after ``delay_s`` from the start). Without
    ``signal_sent`` nothing is sent (the program interrupts itself: tests/cli/swallowing.py)."""
    before = {str(p): tree_hashes(p) for p in outputs}
    environment = {**os.environ, "ODOCAL_PROGRESS": "lines", **(env or {})}
    command = list(program) if program is not None else [str(BIN / "odocal")]
    proc = subprocess.Popen([*command, *argv], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True,
                            cwd=cwd, env=environment)
    lines: list[str] = []
    seen = threading.Event()

    def read(stream: IO[str], kept: list[str] | None) -> None:
        for text in stream:
            if kept is not None:
                kept.append(text)
            if line is not None and line in text:
                seen.set()

    assert proc.stdout is not None and proc.stderr is not None
    reader = threading.Thread(target=read, args=(proc.stderr, lines), daemon=True)
    reader.start()
    threading.Thread(target=read, args=(proc.stdout, None), daemon=True).start()
    reached = True
    if line is not None:
        while not seen.wait(0.01):
            if proc.poll() is not None:
                reader.join(5)
                reached = seen.is_set()
                break
    time.sleep(delay_s)
    finished = proc.poll() is not None
    sent = time.monotonic()
    if not finished and signal_sent:
        os.killpg(proc.pid, signal.SIGINT)
    finished = finished and signal_sent
    try:
        proc.wait(timeout_s)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    stop_s = time.monotonic() - sent
    reader.join(5)
    left = session_processes(proc.pid)
    waited = 0.0
    while left and waited < linger_s:
        time.sleep(0.1)
        waited += 0.1
        left = session_processes(proc.pid)
    for pid in left:                          # never leave them to the next test
        try:
            os.kill(pid, signal.SIGKILL)
        except OSError:
            pass
    intact = all(tree_hashes(p) == before[str(p)] for p in outputs)
    leftovers = tuple(sorted(q.name for p in outputs for q in p.parent.glob(f".{p.name}.*")))
    return Outcome(code=proc.returncode, stop_s=stop_s, stderr="".join(lines),
                   finished=finished, intact=intact, left=tuple(left), leftovers=leftovers,
                   reached=reached)
