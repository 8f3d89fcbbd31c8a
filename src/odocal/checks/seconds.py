"""One-second windows of every piece of the drives: what the checks before a fit compare
(:mod:`odocal.checks.diagnosis`, :mod:`odocal.checks.departures`)."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np

from odocal.arrays import FloatArray, IntArray
from odocal.data.drive import Drive
from odocal.model.kinematics import midpoint_heading


@dataclass(frozen=True)
class Piece:
    """One piece of a drive (samples ``a`` to ``b``) cut into ``count`` whole seconds of
    ``size`` samples; ``index`` is the drive's among the drives."""

    index: int
    drive: Drive
    a: int
    b: int
    size: int
    count: int

    @property
    def starts(self) -> IntArray:
        """(count,): each second's first sample."""
        return np.asarray(self.a + self.size * np.arange(self.count), dtype=np.int64)

    def sums(self, steps: FloatArray) -> FloatArray:
        """(count,): ``steps`` (one value per step of the piece, ``b - a - 1``) summed over each
        second."""
        return np.asarray(steps[:self.count * self.size].reshape(-1, self.size).sum(axis=1))

    def course(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Per second: the reference's turn (rad), its heading at the middle of the second (the
        second's mean sideslip in it) and the gap of its course to that heading (rad, wrapped
        to +-pi)."""
        d, s, n = self.drive, self.starts, self.size
        dx = d.x[s + n] - d.x[s]
        dy = d.y[s + n] - d.y[s]
        turn = d.psi[s + n] - d.psi[s]
        heading = midpoint_heading(d.psi[s], turn, self.sums(d.beta[self.a:self.b - 1]) / n)
        gap = np.remainder(np.arctan2(dy, dx) - heading + np.pi, 2 * np.pi) - np.pi
        return turn, heading, gap


def pieces(drives: Sequence[Drive]) -> Iterator[Piece]:
    """Every piece of the drives that holds one whole second or more, in order."""
    for index, d in enumerate(drives):
        size = max(round(1.0 / d.t_s), 1)
        for a, b in d.pieces:
            count = (b - a - 1) // size
            if count >= 1:
                yield Piece(index, d, a, b, size, count)
