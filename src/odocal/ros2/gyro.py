"""The IMU's yaw-rate offset against the reference heading, as Autoware's deviation_estimator
finds it, and the yaw-rate noise of one IMU message.

The offset ``b`` of a gyro that reads ``omega + b + noise`` is what its reading adds over the
reference heading's change: over the drive's grid samples (the IMU's yaw rate and the
reference's unwrapped heading, both on the grid), ``b = sum(omega dt - dpsi) / sum(dt)`` over
every step within a piece (a constant error of the reference heading cancels). Its standard
deviation is the spread of the same ratio over blocks of :data:`BLOCK_S` of driving, divided by
the root of their number. The noise of one message is measured as the twist's is
(:mod:`odocal.ros2.twist`): a sixth of the mean squared second difference of the readings.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from odocal.arrays import FloatArray

#: Blocks (s of driving) whose offsets give the estimate's spread.
BLOCK_S = 60.0
#: Blocks needed before an offset is stated.
MIN_BLOCKS = 3


@dataclass(frozen=True)
class GyroOffset:
    """The yaw-rate offset (rad/s, what to subtract), its standard deviation, over how much
    driving, and the yaw-rate noise of one message (rad/s; NaN where not measured)."""

    offset_radps: float
    std_radps: float
    seconds: float
    noise_radps: float


class GyroBias:
    """The yaw-rate offset from grid chunks (see the module)."""

    def __init__(self, max_gap_s: float) -> None:
        self.max_gap_s = max_gap_s
        self._last: tuple[float, float, float] | None = None   # t, yaw rate, psi
        self._sum = 0.0
        self._seconds = 0.0
        self._block = [0.0, 0.0]
        self._blocks: list[float] = []
        self._noise = [0.0, 0.0]                 # sum of squared second differences / 6, count
        self._readings: list[float] = []

    def add(self, t: FloatArray, yaw_rate: FloatArray, psi: FloatArray) -> None:
        """A chunk of grid samples (psi unwrapped, continuing the previous chunk)."""
        if t.size == 0:
            return
        if self._last is not None:
            t = np.concatenate([[self._last[0]], t])
            yaw_rate = np.concatenate([[self._last[1]], yaw_rate])
            psi = np.concatenate([[self._last[2]], psi])
        self._last = (float(t[-1]), float(yaw_rate[-1]), float(psi[-1]))
        dt = np.diff(t)
        ok = (dt > 0) & (dt <= self.max_gap_s)
        excess = 0.5 * (yaw_rate[1:] + yaw_rate[:-1]) * dt - np.diff(psi)
        for e, step in zip(excess[ok].tolist(), dt[ok].tolist(), strict=True):
            self._block[0] += e
            self._block[1] += step
            if self._block[1] >= BLOCK_S:
                self._blocks.append(self._block[0] / self._block[1])
                self._block = [0.0, 0.0]
        self._sum += float(excess[ok].sum())
        self._seconds += float(dt[ok].sum())

    def add_reading(self, yaw_rate: float) -> None:
        """One IMU message's yaw rate, as it came (for its noise)."""
        r = self._readings
        r.append(yaw_rate)
        if len(r) == 3:
            self._noise[0] += (r[2] - 2.0 * r[1] + r[0]) ** 2 / 6.0
            self._noise[1] += 1.0
            del r[0]

    def result(self) -> GyroOffset | None:
        """The offset so far (None before :data:`MIN_BLOCKS` blocks of driving)."""
        if len(self._blocks) < MIN_BLOCKS or self._seconds <= 0:
            return None
        blocks = np.asarray(self._blocks)
        noise = (math.sqrt(self._noise[0] / self._noise[1]) if self._noise[1]
                 else float("nan"))
        return GyroOffset(offset_radps=self._sum / self._seconds,
                          std_radps=float(blocks.std(ddof=1) / math.sqrt(blocks.size)),
                          seconds=self._seconds, noise_radps=noise)

    def reading_gap(self) -> None:
        """The IMU's messages stopped or went back: the next one starts a new difference."""
        self._readings.clear()
