"""The windows as the builder hands them to the online calibrator: split at their clusters, the
cluster under way's kept aside until it completes, and counted."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from odocal.estimators.windows import WindowSet


class Arrivals:
    """The cluster under way (``cluster``: its label, None before the first window) and its
    windows kept aside (the window set is put together once per cluster, not once per push:
    with a lag range of a second a window holds 85 shifts of its moments); ``total`` counts
    every window made."""

    def __init__(self) -> None:
        self.cluster: int | None = None
        self.total = 0
        self._aside: list[WindowSet] = []
        self._aside_size = 0

    def groups(self, new: WindowSet) -> Iterator[tuple[int | None, WindowSet]]:
        """``new`` cluster by cluster, each group with the cluster it completes (the one under
        way before it, where it starts another; None where it continues it). The group's
        cluster is under way from then on; the caller keeps its windows."""
        if not new.size:
            return
        labels = new.cluster
        for group in np.split(np.arange(new.size), np.flatnonzero(np.diff(labels)) + 1):
            cluster = int(labels[group[0]])
            done = self.cluster if self.cluster is not None and cluster != self.cluster \
                else None
            self.cluster = cluster
            yield done, new.take(group)

    def set_aside(self, windows: WindowSet) -> None:
        """Windows of the cluster under way, kept aside."""
        self._aside.append(windows)
        self._aside_size += windows.size
        self.total += windows.size

    def counted(self, windows: WindowSet) -> None:
        """Windows that went straight into the window set."""
        self.total += windows.size

    @property
    def aside(self) -> int:
        """Windows kept aside."""
        return self._aside_size

    def take_aside(self) -> list[WindowSet]:
        """The windows kept aside, handed over (none are kept)."""
        out, self._aside, self._aside_size = self._aside, [], 0
        return out

    def restart(self, windows: WindowSet) -> None:
        """The windows made again from the start (``windows``): nothing aside, and the cluster
        under way their last."""
        self._aside, self._aside_size = [], 0
        self.total = windows.size
        self.cluster = int(windows.cluster[-1]) if windows.size else None
