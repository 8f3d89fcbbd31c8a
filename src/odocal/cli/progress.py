"""Progress on the terminal: a bar per stage, or a line per stage where stderr is not a terminal."""

from __future__ import annotations

import sys
import time
from typing import Any


class Progress:
    """tqdm bars per stage on a terminal; otherwise one line on stderr as each stage starts."""

    def __init__(self, enabled: bool) -> None:
        self.enabled = enabled and sys.stderr.isatty()
        self.lines = enabled and not self.enabled
        self.bars: dict[str, Any] = {}
        self.started = time.perf_counter()

    def __call__(self, stage: str, done: int, total: int) -> None:
        if self.lines and stage not in self.bars:
            # not a terminal (a log file, CI): one line as each stage starts
            self.bars[stage] = None
            sys.stderr.write(f"[{time.perf_counter() - self.started:6.1f} s] {stage} ...\n")
            sys.stderr.flush()
        if not self.enabled:
            return
        from tqdm import tqdm

        bar = self.bars.get(stage)
        if bar is None:
            bar = tqdm(total=total, desc=stage, unit="", leave=True, file=sys.stderr,
                       dynamic_ncols=True)
            self.bars[stage] = bar
        bar.total = total
        bar.n = done
        bar.refresh()
        if done >= total:
            bar.close()

    def close(self) -> None:
        for bar in self.bars.values():
            if bar is not None:
                bar.close()
