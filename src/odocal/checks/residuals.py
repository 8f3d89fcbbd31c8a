"""The fit's residuals against the model: what only shows after fitting (codes and numbers).

The default method fits every window of the drives with one theta; two departures then show in
its residuals, whatever the noise:

* **a change inside the log** (a tyre's pressure, a tyre change): the windows' relative residual
  in the distance channel (``c_e``: revolutions measured less predicted, over those predicted)
  or in the yaw channel per revolution (one wheel's circumference: ``c_d``) steps at one time.
  The clusters' means (independent pieces of evidence, in time order) are tested with the
  CUSUM statistic, ``max_k |S_k| / (s sqrt(n))``, whose null distribution is that of a Brownian
  bridge's largest excursion (Kolmogorov's): beyond ``change_statistic`` (1.95: a 0.1% false
  alarm rate) *and* by at least ``change_min`` of the level, the log holds a change; the
  spread ``s`` is taken from neighbouring clusters' differences, which a step does not inflate.
* **front wheels**: a front wheel runs on a wider circle than the rear axle beside it, by the
  wheelbase times the curvature across the direction of travel: its revolutions exceed a rear
  wheel's by about ``(L kappa)^2 / 2`` of them. Regressed on the windows' curvature squared, the
  distance channel's relative residual gives ``L^2 / 2``; a rear axle's wheels give about none.
* **a wheel-rate offset while moving** (a speed signal that reads a constant rate too much or
  too little, on a drive that never stands still long enough to measure it at rest): every
  window's distance residual (revolutions) holds the same number of revolutions whatever its
  speed, where a scale error grows with the revolutions. Regressed on the window's
  revolutions and a constant, with the spread taken cluster by cluster (sandwich: the windows
  of a cluster overlap), a constant beyond ``moving_offset_sigmas`` standard errors is an
  offset, where the windows' speeds spread enough to tell it from ``c_e``
  (``moving_offset_min_spread``): the default method then fits it beside ``c_e``, and keeps
  that fit where it determines the offset (:func:`offset_determined`).

The thresholds, with their reasons, are settings (``[checks]``:
:class:`~odocal.settings.ChecksSettings`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from odocal.checks.findings import Check, Finding, Severity
from odocal.settings import ChecksSettings, Settings

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

@dataclass(frozen=True)
class Change:
    """A change inside the log.

    channel : "c_e" (the distance channel) or "c_d" (the yaw channel)
    index : the first window after the change (in the order of the windows)
    size : the change of the relative residual's level (after less before): for c_e, minus the
        relative change of the circumference; for c_d, minus its change over c_e
    statistic : the CUSUM statistic
    """

    channel: str
    index: int
    size: float
    statistic: float


def _cluster_means(values: FloatArray, weights: FloatArray, cluster: IntArray
                   ) -> tuple[FloatArray, FloatArray, IntArray]:
    """Per cluster in the order they first appear: the weighted mean, the weight, and the index
    of its first window."""
    _, first, inverse = np.unique(cluster, return_index=True, return_inverse=True)
    order = np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    group = rank[inverse]
    total = np.bincount(group, weights=weights)
    sums = np.bincount(group, weights=weights * values)
    with np.errstate(divide="ignore", invalid="ignore"):
        means = np.where(total > 0, sums / total, 0.0)
    return (np.asarray(means, dtype=np.float64), np.asarray(total, dtype=np.float64),
            np.asarray(first[order], dtype=np.int64))


def _long_run_std(values: FloatArray) -> float:
    """The long-run standard deviation of a series (Bartlett weights, Newey and West's
    bandwidth): neighbouring clusters that share slow errors (a reference's drift, a slip that
    lasts) spread a mean wider than independent ones would."""
    n = values.size
    centred = values - values.mean()
    variance = float(centred @ centred) / n
    lags = int(4.0 * (n / 100.0) ** (2.0 / 9.0))
    for k in range(1, min(lags, n - 1) + 1):
        variance += 2.0 * (1.0 - k / (lags + 1.0)) * float(centred[k:] @ centred[:-k]) / n
    return math.sqrt(max(variance, 0.0))


def cusum(means: FloatArray,
          min_side: int = ChecksSettings.change_min_side_clusters) -> tuple[int, float]:
    """The split (first index after it) with the largest CUSUM excursion of ``means``, at least
    ``min_side`` values from either end, and the statistic ``max |S_k| / (s sqrt(n))`` there (0
    for fewer than ``2 min_side + 2`` values or no spread). s is the larger of the spread
    neighbours' differences give (which a step does not inflate) and the long-run spread about
    the two levels on either side of the split."""
    n = means.size
    if n < 2 * min_side + 2:
        return 0, 0.0
    diffs = np.diff(means)
    # a normal's sigma from the MAD; a difference of two values spreads sqrt(2) times wider
    spread = 1.4826 * float(np.median(np.abs(diffs - np.median(diffs)))) / math.sqrt(2.0)
    s = np.cumsum(means - means.mean())[:-1]
    ks = np.arange(1, n)
    allowed = (ks >= min_side) & (ks <= n - min_side)
    excursion = np.where(allowed, np.abs(s), 0.0)
    k = int(np.argmax(excursion))
    levels = np.where(np.arange(n) <= k, means[:k + 1].mean(), means[k + 1:].mean())
    spread = max(spread, _long_run_std(means - levels))
    if spread <= 0:
        return 0, 0.0
    return k + 1, float(excursion[k] / (spread * math.sqrt(n)))


def find_change(measured: FloatArray, residual: FloatArray, cluster: IntArray,
                settings: Settings) -> Change | None:
    """The strongest change inside the windows' residuals, where it is one (see the module
    docstring). ``measured``, ``residual`` (W, 2) are per channel (distance, yaw), in
    revolutions; windows in time order."""
    lim = settings.checks
    revs = np.abs(measured[:, 0])
    moving = revs > lim.window_min_revs
    if moving.sum() < lim.change_min_windows:
        return None
    best: Change | None = None
    for channel, column in (("c_e", 0), ("c_d", 1)):
        ratio = np.where(moving, residual[:, column] / np.maximum(revs, 1e-9), 0.0)
        means, weight, first = _cluster_means(ratio, np.where(moving, revs, 0.0), cluster)
        # clusters that turn the wheels little (a stop, a crawl) say little of a level
        keep = weight > lim.change_min_cluster_share * float(np.median(weight[weight > 0]))
        means, first = means[keep], first[keep]
        split, statistic = cusum(means, lim.change_min_side_clusters)
        if statistic < lim.change_statistic:
            continue
        size = float(means[split:].mean() - means[:split].mean())
        if abs(size) < lim.change_min:
            continue
        if best is None or statistic > best.statistic:
            best = Change(channel=channel, index=int(first[split]), size=size,
                          statistic=statistic)
    return best


def change_finding(change: Change, when_s: float, where: str) -> Finding:
    """A change as a finding: the calibration stands on the part after it (it does less than
    asked). value: the parameter's relative change (c_e), or its change over c_e (c_d)."""
    return Finding(Check.CHANGE_IN_LOG, Severity.FALLBACK, -change.size, when_s,
                   f"{change.channel}|{where}")


def front_wheels(measured: FloatArray, residual: FloatArray, along_m: FloatArray,
                 turn_rad: FloatArray, settings: Settings) -> Finding | None:
    """The wheels as front wheels, where their distance channel grows with the curvature
    squared (see the module docstring): value the distance ahead of the rear axle (m),
    reference its standard error."""
    lim = settings.checks
    revs = np.abs(measured[:, 0])
    with np.errstate(divide="ignore", invalid="ignore"):
        curvature = np.where(np.abs(along_m) > lim.front_min_window_m, turn_rad / along_m, 0.0)
    use = (revs > lim.window_min_revs) & np.isfinite(curvature)
    curved = np.abs(curvature[use]) > lim.front_min_curvature_1pm
    if use.sum() < lim.front_min_windows or curved.sum() < lim.front_min_curved_windows:
        return None
    x = curvature[use] ** 2
    y = residual[use, 0] / revs[use]
    design = np.column_stack([np.ones_like(x), x])
    coef, *_ = np.linalg.lstsq(design, y, rcond=None)
    rest = y - design @ coef
    spread = 1.4826 * float(np.median(np.abs(rest - np.median(rest))))     # a normal's sigma
    cov = np.linalg.pinv(design.T @ design) * spread ** 2
    slope, slope_std = float(coef[1]), float(math.sqrt(max(cov[1, 1], 0.0)))
    if slope <= 0 or slope < lim.front_sigmas * slope_std:
        return None
    distance = math.sqrt(2.0 * slope)
    if distance < lim.front_min_distance_m:
        return None
    return Finding(Check.FRONT_WHEELS, Severity.FATAL, distance,
                   slope_std / max(2.0 * distance, 1e-9))


def moving_offset(measured: FloatArray, residual: FloatArray, cluster: IntArray,
                  window_s: float, settings: Settings) -> Finding | None:
    """The wheels' rate offset while moving, where the distance residuals show one (see the
    module docstring): value the offset (rev/s, both wheels), reference its standard error."""
    lim = settings.checks
    revs = measured[:, 0]
    use = np.abs(revs) > lim.window_min_revs
    groups = np.unique(cluster[use])
    if groups.size < lim.moving_offset_min_clusters:
        return None
    moving = np.abs(revs[use])
    if float(moving.std()) < lim.moving_offset_min_spread * float(moving.mean()):
        return None                        # about one speed: an offset is a scale error there
    design = np.column_stack([revs[use], np.ones(int(use.sum()))])
    y = residual[use, 0]
    bread = np.linalg.pinv(design.T @ design)
    coef = bread @ design.T @ y
    rest = y - design @ coef
    _, where = np.unique(cluster[use], return_inverse=True)
    scores = np.zeros((groups.size, 2))
    np.add.at(scores, where, design * rest[:, None])
    cov = bread @ (scores.T @ scores) @ bread * groups.size / (groups.size - 1)
    std = float(math.sqrt(max(cov[1, 1], 0.0)))
    if not std > 0 or abs(coef[1]) <= lim.moving_offset_sigmas * std:
        return None
    return Finding(Check.MOVING_OFFSET, Severity.NOTE, float(coef[1]) / window_s,
                   std / window_s)


def moving_offset_prior_std(moving: Finding, settings: Settings) -> float:
    """The prior standard deviation (rev/s) of the offset a fit takes on where
    :func:`moving_offset` found one: the settings' own, or twice the offset found where that is
    larger (the prior must not pull the offset in)."""
    return max(settings.inverse.wheel_offset_prior_revps, 2.0 * abs(moving.value))


def offset_determined(value: float, value_std: float, prior_std: float, theta: FloatArray,
                      settings: Settings) -> bool:
    """Whether a fit with the wheel-rate offset free (its prior ``prior_std``) determines it:
    by the data rather than the prior (a standard deviation below half the prior's), beyond
    ``moving_offset_sigmas`` of it, with the parameters beside it finite and in their
    plausible ranges (a fit that could not tell the offset from c_e runs away)."""
    from odocal.checks.gate import gate

    if not (np.isfinite(value) and np.isfinite(value_std) and np.all(np.isfinite(theta))):
        return False
    if not value_std < 0.5 * prior_std or not abs(value) > settings.checks.moving_offset_sigmas \
            * value_std:
        return False
    return not gate(theta, settings, error_m=None, datasheet_error_m=None, segment_m=None)
