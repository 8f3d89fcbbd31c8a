"""Changes within a drive: a two-sided CUSUM on each completed cluster's own estimate.

A cluster of windows (one segment length of driving) gives its own one-step estimate of c_e
and c_d from the running estimate, standardised by its information; the CUSUM accumulates these
standardised steps (allowance ``k``, threshold ``h``, ``[online] cusum_k, cusum_h``), scaled by
their own running RMS so that mis-weighted errors do not pass for changes. When it rises, the
step's size and the time and distance it began at become an :class:`Alarm`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from odocal.estimators.error_model import (
    CHANNELS,
    ErrorModel,
    coupling_gain,
    decouple,
    expected_revolutions,
    window_variance,
)
from odocal.estimators.windows import WindowSet
from odocal.model.vehicle import MODEL

FloatArray = NDArray[np.float64]

#: Standardised steps kept for their running RMS.
_SCALE_MEMORY = 200
#: Steps before the RMS is trusted (until then the scale is generous).
_SCALE_WARMUP = 10


@dataclass(frozen=True)
class Alarm:
    """A change within the drive, found by the CUSUM on the clusters' own estimates.

    parameter : ``c_e`` or ``c_d``
    t : time of the first cluster after the change (the CUSUM's last reset), s
    detected_t : when the alarm rose, s
    distance_km, detected_distance_km : the same in driven distance
    relative_change : the step over the estimate before it (c_d: over c_e)
    sigmas : the step in standard deviations of one cluster's estimate
    """

    parameter: str
    t: float
    detected_t: float
    distance_km: float
    detected_distance_km: float
    relative_change: float
    sigmas: float

    def to_dict(self) -> dict[str, Any]:
        return {"parameter": self.parameter, "t": self.t, "detected_t": self.detected_t,
                "distance_km": self.distance_km, "detected_distance_km": self.detected_distance_km,
                "relative_change": self.relative_change, "sigmas": self.sigmas}


@dataclass
class Cusum:
    """Two-sided CUSUM on standardised innovations (k: allowance, h: threshold)."""

    k: float
    h: float
    upper: float = 0.0
    lower: float = 0.0
    count: int = 0
    total: float = 0.0
    start_t: float = 0.0
    start_km: float = 0.0

    def update(self, z: float, t: float, km: float) -> bool:
        if self.upper == 0.0 and self.lower == 0.0:
            self.count, self.total, self.start_t, self.start_km = 0, 0.0, t, km
        self.upper = max(0.0, self.upper + z - self.k)
        self.lower = max(0.0, self.lower - z - self.k)
        self.count += 1
        self.total += z
        return self.upper > self.h or self.lower > self.h

    def reset(self) -> None:
        self.upper = self.lower = 0.0


class ChangeDetector:
    """The CUSUMs of c_e and c_d over completed clusters."""

    def __init__(self, *, k: float, h: float) -> None:
        self.cusum = {"c_e": Cusum(k, h), "c_d": Cusum(k, h)}
        self.seen: dict[str, list[float]] = {"c_e": [], "c_d": []}

    def reset(self) -> None:
        for c in self.cusum.values():
            c.reset()

    def watch(self, cluster: WindowSet, theta: FloatArray, shift: float, heading_offset: float,
              model: ErrorModel) -> tuple[Alarm, int, float] | None:
        """One completed cluster against the running estimate ``theta``: an alarm with the
        parameter's index and the change found, or None."""
        at, _ = cluster.at(shift, heading_offset)
        pred, jac = MODEL.predict(theta, at)
        r = (cluster.measured - pred) @ CHANNELS.T
        j = np.einsum("ci,wip->wcp", CHANNELS, jac)
        w = 1.0 / window_variance(expected_revolutions(cluster.measured, r), model.noise)
        gain = coupling_gain(cluster.measured, r, model.coupling)
        r, j = decouple(r, gain), decouple(j, gain)
        for index, name in ((0, "c_e"), (1, "c_d")):
            info = float(np.sum(w * j[:, :, index] ** 2))
            if info <= 0:
                continue
            step = float(np.sum(w * j[:, :, index] * r)) / info
            z = step * math.sqrt(info)
            seen = self.seen[name]
            seen.append(z)
            if len(seen) > _SCALE_MEMORY:
                seen.pop(0)
            scale = (max(float(np.sqrt(np.mean(np.square(seen)))), 1.0)
                     if len(seen) >= _SCALE_WARMUP else 1.0 + 10.0 / len(seen))
            cusum = self.cusum[name]
            km = float(cluster.distance_m[0]) / 1000.0
            if cusum.update(z / scale, float(cluster.t0[0]), km) and len(seen) >= _SCALE_WARMUP:
                mean_z = cusum.total / max(cusum.count, 1)
                change = mean_z * scale / math.sqrt(info)
                alarm = Alarm(parameter=name, t=cusum.start_t, detected_t=float(cluster.t0[-1]),
                              distance_km=cusum.start_km,
                              detected_distance_km=float(cluster.distance_m[-1]) / 1000.0,
                              relative_change=change / MODEL.layout.value(
                                  theta, MODEL.layout.scale),
                              sigmas=mean_z)
                return alarm, index, change
        return None
