"""The wheel stream's lag behind the reference, for the default method: the yaw channel's cost
on a half-step grid of shifts (a lag beyond the linear range is not found by a gradient), its
minimum, and the held-out test of whether a lag is there at all."""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from odocal.arrays import FloatArray
from odocal.estimators import departures as dep
from odocal.estimators.error_model import (
    CHANNELS,
    ErrorModel,
    coupling_gain,
    decouple,
    window_weights,
)
from odocal.estimators.fitting import KAPPA, Folded, View, wheels
from odocal.estimators.windows import WindowSet

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class LagScan:
    """The yaw channel's cost on the lag grid (steps), per half of the clusters (2, G)."""

    grid: FloatArray
    costs: FloatArray


def scan_lag(windows: WindowSet, p: FloatArray, heading_offset: float, model: ErrorModel,
             folded: Folded) -> LagScan:
    """The yaw channel's weighted cost at every half step of shift of the reference side, with
    ``p`` (theta and the departures) fixed (the distance channel is left out: a slip that
    grows with acceleration is common to both wheels and would pass for a lag there).

    The prediction is linear in the moments, so it is made once at every whole-step shift and
    interpolated between them, as the moments are.
    """
    p = np.asarray(p, dtype=np.float64)
    limit = windows.shifts
    grid = np.arange(-limit, limit + 0.25, 0.5)
    half = (windows.cluster % 2).astype(np.int64)
    costs = np.zeros((2, grid.size))
    w_count, shifts = windows.size, windows.moments.shape[1]
    if w_count and limit > 0:
        rotated = windows.rotated(heading_offset)                    # (W, S, AT_WIDTH)
        second = np.zeros_like(rotated)
        second[:, 1:-1] = rotated[:, 2:] + rotated[:, :-2] - 2.0 * rotated[:, 1:-1]
        flat = rotated.reshape(w_count * shifts, -1)
        view = View(windows, 0.0, flat, flat, second.reshape(w_count * shifts, -1))
        whole, _ = wheels(p, view, smooth=bool(p[KAPPA]), jacobian=False)
        whole = whole.reshape(w_count, shifts, 2)
        x = grid + windows.margin
        lo = np.floor(x).astype(np.int64)
        frac = (x - lo)[None, :, None]
        pred = whole[:, lo] * (1.0 - frac) + whole[:, np.minimum(lo + 1, shifts - 1)] * frac
        measured = np.repeat(windows.measured, grid.size, axis=0)
        r = (measured - pred.reshape(-1, 2)) @ CHANNELS.T
        gain = coupling_gain(measured, r, model.coupling)
        w = window_weights(measured, r, model.noise, gain) \
            * np.repeat(windows.weight, grid.size)[:, None]
        cost = (w[:, 1] * decouple(r, gain)[:, 1] ** 2).reshape(w_count, grid.size)
        for k in (0, 1):
            costs[k] = cost[half == k].sum(axis=0)
    if folded.scan is not None and folded.scan.shape == costs.shape:
        costs = costs + folded.scan
    return LagScan(grid=grid, costs=costs)


@dataclass(frozen=True)
class Lag:
    """The lag applied: ``shift`` steps (0: none), its standard deviation (nan: not fitted),
    the minimum of the scan (``found``), and why it was not fitted where it was not."""

    shift: float = 0.0
    std: float = float("nan")
    found: float = 0.0
    note: str = ""


def _minimum(grid: FloatArray, costs: FloatArray) -> tuple[float, float] | None:
    """The parabola's minimum through the lowest grid point and its neighbours, and its std
    (the cost is a weighted sum of squares with unit-variance residuals near the minimum);
    None at the edge of the grid or where the cost is flat."""
    i = int(np.argmin(costs))
    if i == 0 or i == grid.size - 1:
        return None
    c0, c1, c2 = costs[i - 1:i + 2]
    curvature = (c0 - 2.0 * c1 + c2) / 0.25            # d^2 cost / d shift^2 (half steps)
    if curvature <= 0:
        return None
    return (float(grid[i] + 0.25 * (c0 - c2) / (c0 - 2.0 * c1 + c2)),
            float(math.sqrt(2.0 / curvature)))


def choose_lag(scan: LagScan) -> Lag:
    """The lag at the scan's minimum (refined by a parabola); none at the grid's edge or where
    the cost is flat (with the reason). Whether a lag is fitted at all is the departures'
    rule (:mod:`.departures`); this finds where."""
    total = scan.costs.sum(axis=0)
    found = _minimum(scan.grid, total)
    if found is None:
        i = int(np.argmin(total))
        if 0 < i < total.size - 1:
            return Lag(note="flat")                    # no turning to time the wheels by
        log.warning("the wheel clock offset lies at the edge of the search range; none applied "
                    "(widen [inverse] max_delay_s)")
        return Lag(note="edge")
    best, std = found
    return Lag(shift=best, std=std, found=best)


def lag_test(scan: LagScan) -> dep.Statistic:
    """The held-out test of a lag: on each half of the clusters, the lag is where that half's
    yaw cost is least (:func:`scan_lag`: the lag is nonlinear, found on a grid), and it must
    lower the other half's cost against none."""
    gains = []
    for k in (0, 1):
        found = _minimum(scan.grid, scan.costs[k])
        other = scan.costs[1 - k]
        if found is None or not other.any():
            gains.append(-math.inf)
            continue
        gains.append(float(np.interp(0.0, scan.grid, other)
                           - np.interp(found[0], scan.grid, other)))
    return dep.Statistic(("lag",), (gains[0], gains[1]))
