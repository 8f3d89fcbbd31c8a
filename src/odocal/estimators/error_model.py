"""The default method's error model: how the windows' residuals are weighted and filtered.

Every part is fitted from the residuals through sums that add up over windows, chunks and
times, so the online calibrator folds them as it folds the normal equations:

* **Weights.** The residuals of the sum channel (distance: c_e) and the difference channel
  (yaw: t_r, c_d, d) get a variance that grows with the revolutions, ``s0^2 + (f rev)^2``
  (white noise; slip and rate-proportional noise), fitted to the squared residuals; spikes
  beyond :data:`HUBER` standard deviations are down-weighted (:func:`noise_sums`,
  :func:`window_weights`).
* **A wheel error common to both wheels.** A slip that scales both wheels' revolutions alike
  shows in the distance channel and, times the window's ratio ``rho`` of the wheels' difference
  to their mean, in the yaw channel. The yaw residuals are regressed on ``rho`` times the
  distance residuals (``beta``: 1 for a common slip); where it stands out and lies in
  :data:`COUPLING_RANGE`, that part is taken out of the yaw channel (:func:`coupling_sums`,
  :func:`decouple`).
* **Telescoping errors.** Errors that are differences of something bounded (rounded tick
  counts, a reference pose's own errors differenced per window) are found from the residuals'
  lag-one and lag-two correlations and prewhitened, ARMA(1, 1) (:func:`arma_from_sums`,
  :func:`prewhiten`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from odocal.arrays import BoolArray, FloatArray
from odocal.model.vehicle import MODEL

#: Residuals beyond this many standard deviations are down-weighted (Huber).
HUBER = 4.0
_MAX_MA = 0.95            # prewhitening stays a stable filter
COUPLING_WALD = 10.83     # the common wheel error's share in the yaw channel: used where its
COUPLING_RANGE = (0.5, 1.5)  # Wald statistic (chi-square, 1 dof, p = 0.001) and value allow
#: The Wald statistic a coupling the live path took keeps it by (p = 0.01): its windows are
#: folded with it, and a statistic that wanders about one threshold would fold some with and
#: some without it.
COUPLING_KEEP_WALD = 6.63
_RHO_MAX = 0.5            # windows with a larger wheel difference over mean (reversing, spikes)


#: The model's channels of its wheels: the sum (distance) and the difference (yaw).
CHANNELS = MODEL.channel_map
_TO_WHEELS = np.linalg.inv(CHANNELS)



@dataclass(frozen=True)
class ErrorModel:
    """The fitted error model.

    noise : (2, 2) per channel (distance, yaw): ``s0`` (revolutions per window) and ``f``
    ma : (2, 2) per channel the prewhitening's ``m, phi`` (0: no filter)
    coupling : ``beta``, the share of the distance channel's errors in the yaw channel (0: none)
    reference : (2,) the spread of the reference channels' residuals: its motion across its
        heading (m per window) and a_y's sum against ``v w`` (m/s per window); infinite where
        not yet fitted
    """

    noise: FloatArray = field(default_factory=lambda: np.full((2, 2), 1e-3))
    ma: FloatArray = field(default_factory=lambda: np.zeros((2, 2)))
    coupling: float = 0.0
    reference: FloatArray = field(default_factory=lambda: np.full(2, np.inf))


def prewhiten(x: FloatArray, follows: BoolArray, ma: FloatArray,
              before: tuple[FloatArray, FloatArray] | None = None) -> FloatArray:
    """Filter rows by ``(1 - phi L) / (1 - m L)`` along runs of windows that follow one another.

    ``x`` (W, C, K): per window and channel a residual and its Jacobian (any K columns);
    ``follows`` (W,): the window starts where the one before it ended; ``ma`` (C, 2): each
    channel's ``m, phi`` (:func:`arma_from_sums`). ``before`` continues a run from an earlier
    call: the last window's row there, unfiltered and filtered (each (C, K)); it is used where
    ``follows[0]`` is set. ``out[w] = x[w] - phi x[w - 1] + m out[w - 1]``.
    """
    x = np.ascontiguousarray(x, dtype=np.float64)
    out = x.copy()
    if x.shape[0] == 0:
        return out
    follows = np.asarray(follows, dtype=bool).copy()
    carry = before is not None and bool(follows[0])
    follows[0] = carry
    for c in range(x.shape[1]):
        m, phi = float(ma[c, 0]), float(ma[c, 1])
        if m == 0.0 and phi == 0.0:
            continue                                       # no filter: the rows as they are
        previous = np.zeros_like(x[:, c])
        previous[1:] = x[:-1, c]
        if carry:
            assert before is not None
            previous[0] = before[0][c]
        u = x[:, c] - phi * np.where(follows[:, None], previous, 0.0)
        out[:, c] = _recursion(u, m, follows, before[1][c] if carry and before else None)
    return out


#: Windows filtered together by one matrix product in :func:`_recursion`.
_BLOCK = 64


def _recursion(u: FloatArray, m: float, follows: BoolArray,
               start: FloatArray | None) -> FloatArray:
    """``y[w] = u[w] + m y[w - 1]`` where window w follows the one before (``y[-1]`` =
    ``start``), else ``y[w] = u[w]``: blocks of windows at once, each a lower-triangular product
    with ``m^(i - j)`` over the windows of one run, the block's last value carried on."""
    n, k = u.shape
    blocks = -(-n // _BLOCK)
    pad = blocks * _BLOCK - n
    u_b = np.concatenate([u, np.zeros((pad, k))]).reshape(blocks, _BLOCK, k)
    f_b = np.concatenate([follows, np.zeros(pad, dtype=bool)]).reshape(blocks, _BLOCK)
    breaks = np.cumsum(~f_b, axis=1)                       # runs begun within the block
    i = np.arange(_BLOCK)
    decay = np.tril(float(m) ** np.maximum(i[:, None] - i[None, :], 0))
    within = decay[None] * (breaks[:, :, None] == breaks[:, None, :])
    local = np.einsum("bij,bjk->bik", within, u_b)
    reach = (breaks == 0) * float(m) ** (i + 1)            # what the block before still adds
    carried = np.zeros(k) if start is None else np.asarray(start, dtype=np.float64)
    for b in range(blocks):
        local[b] += reach[b, :, None] * carried[None, :]
        carried = local[b, -1]
    return np.asarray(local.reshape(blocks * _BLOCK, k)[:n])


def expected_revolutions(measured: FloatArray, residual: FloatArray) -> FloatArray:
    """(W, 2): each window's wheel revolutions as the fit explains them (measured minus the
    channel residuals). The noise model's rate-proportional part is taken at these, not at the
    measured revolutions: weights that fall where a wheel error raises the count weight the
    errors unevenly (a wheel slip of 1% around its mean biased c_e by +0.25 mm, 1e-4 of it)."""
    return measured - residual @ _TO_WHEELS.T


def window_weights(measured: FloatArray, residual: FloatArray, noise: FloatArray,
                   gain: FloatArray | None = None) -> FloatArray:
    """1 / variance per window and channel from the noise model, Huber-limited (on the
    residuals decoupled by ``gain``, :func:`coupling_gain`)."""
    w = 1.0 / window_variance(expected_revolutions(measured, residual), noise)
    z = np.abs(decouple(residual, gain)) * np.sqrt(w)
    return w * np.minimum(1.0, HUBER / np.maximum(z, 1e-300))


def window_variance(measured: FloatArray, noise: FloatArray) -> FloatArray:
    """``s0^2 + (f rev)^2`` per channel; ``noise`` is (2, 2): rows channels, columns s0, f."""
    rev = np.abs(measured.mean(axis=1))[:, None]
    return noise[None, :, 0] ** 2 + (noise[None, :, 1] * rev) ** 2


def _ratio(rev: FloatArray) -> FloatArray:
    """(W,): each window's difference of the wheels' revolutions ``rev`` over their mean."""
    mean = rev.mean(axis=1)
    safe = np.where(np.abs(mean) > 1e-9, mean, np.inf)
    return np.asarray((rev[:, 1] - rev[:, 0]) / safe)


def coupling_gain(measured: FloatArray, residual: FloatArray,
                  beta: float) -> FloatArray | None:
    """(W,): the share ``beta rho`` of each window's distance-channel error that shows in its
    yaw channel (0 where ``|rho|`` is beyond a car's turning; None where ``beta`` is 0)."""
    if beta == 0.0:
        return None
    rho = _ratio(expected_revolutions(measured, residual))
    return np.asarray(np.where(np.abs(rho) <= _RHO_MAX, beta * rho, 0.0))


def decouple(x: FloatArray, gain: FloatArray | None) -> FloatArray:
    """``x`` (W, 2, ...) with ``gain`` times the distance channel taken out of the yaw channel."""
    if gain is None:
        return x
    out = np.array(x, dtype=np.float64, copy=True)
    out[:, 1] -= gain.reshape((-1,) + (1,) * (x.ndim - 2)) * out[:, 0]
    return out


def _regressor(measured: FloatArray, residual: FloatArray,
               weight: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Each window's ``rho`` and its weight in the coupling's regression: the yaw channel's,
    or 0 for a window that reverses, turns tighter than ``|rho| = 0.5`` or is an outlier in the
    distance channel (such windows would carry the regression alone)."""
    rev = expected_revolutions(measured, residual)
    rho = _ratio(rev)
    usable = ((rev[:, 0] * rev[:, 1] > 0) & (np.abs(rho) <= _RHO_MAX)
              & (np.abs(residual[:, 0]) * np.sqrt(weight[:, 0]) <= HUBER))
    return rho, np.where(usable, weight[:, 1], 0.0)


def coupling_sums(measured: FloatArray, residual: FloatArray, weight: FloatArray) -> FloatArray:
    """Sums that regress the yaw channel's residuals on ``rho`` times the distance channel's
    (:func:`coupling_from_sums`); they add up over parts. ``weight`` (W, 2): the windows'
    weights. Returns (2,): ``sum w x^2, sum w x y`` with ``x = rho r_s``, ``y = r_d``."""
    rho, w = _regressor(measured, residual, weight)
    x = rho * residual[:, 0]
    return np.array([float(np.sum(w * x * x)), float(np.sum(w * x * residual[:, 1]))])


def coupling_moments(measured: FloatArray, residual: FloatArray, jac: FloatArray,
                     offset: FloatArray, weight: FloatArray) -> FloatArray:
    """What :func:`coupling_sums` needs, kept so that it can be had at other parameters
    (:func:`coupling_sums_at`): the residuals move with the parameters as ``r - jac (q - p)``.
    ``jac`` (W, 2, P): the channel predictions' Jacobian at ``p``; ``offset``: ``p`` less a
    fixed origin near the answer (the moments are taken about it, so that they do not cancel
    in rounding). Returns (2, 1 + P, 1 + P); moments of different windows and linearisation
    points add up."""
    rho, w = _regressor(measured, residual, weight)
    rows = np.concatenate([(residual + jac @ offset)[..., None], -jac], axis=2)
    s, d = rows[:, 0], rows[:, 1]
    return np.stack([np.einsum("w,wi,wj->ij", w * rho**2, s, s),
                     np.einsum("w,wi,wj->ij", w * rho, s, d)])


def coupling_sums_at(moments: FloatArray, offset: FloatArray) -> FloatArray:
    """:func:`coupling_sums` at the origin plus ``offset`` from :func:`coupling_moments`, shape
    (2,)."""
    v = np.append(1.0, offset)
    return np.asarray(np.einsum("kij,i,j->k", moments, v, v))


def coupling_from_sums(sums: FloatArray, *, kept: bool = False) -> float:
    """``beta``, the common wheel error's share in the yaw channel, or 0 where it does not stand
    out (Wald statistic below :data:`COUPLING_WALD`; the weights standardise the residuals, so
    it is chi-square with one degree of freedom where there is no such error; ``kept``: at
    :data:`COUPLING_KEEP_WALD`, for a coupling taken before) or lies outside
    :data:`COUPLING_RANGE` (a common slip gives 1; what else correlates the channels, e.g.
    rounded tick counts that telescope, can pass the Wald test with a beta of 2 to 12)."""
    sxx, sxy = float(sums[0]), float(sums[1])
    if not (math.isfinite(sxx) and math.isfinite(sxy)) or sxx <= 0.0:
        return 0.0
    beta = sxy / sxx
    wald = COUPLING_KEEP_WALD if kept else COUPLING_WALD
    if beta * beta * sxx < wald or not COUPLING_RANGE[0] <= beta <= COUPLING_RANGE[1]:
        return 0.0
    return beta


def correlation_sums(u: FloatArray, follows: BoolArray) -> FloatArray:
    """Sums that give each channel's lag-one and lag-two correlation (:func:`arma_from_sums`).

    ``u`` (W, C): standardised residuals of consecutive windows. Returns (C, 6): sum u^2, count,
    sum of lag-one products, their count, sum of lag-two products, their count (pairs only
    within runs of windows that follow one another). Sums of parts add up.
    """
    one = follows[1:]
    two = follows[2:] & follows[1:-1]
    out = np.zeros((u.shape[1], 6))
    for c in range(u.shape[1]):
        x = u[:, c]
        out[c] = (float(x @ x), x.size, float(np.sum(x[1:][one] * x[:-1][one])), one.sum(),
                  float(np.sum(x[2:][two] * x[:-2][two])), two.sum())
    return out


def arma_from_sums(sums: FloatArray) -> FloatArray:
    """Each channel's prewhitening ``m, phi``: errors that telescope across windows.

    Errors that are differences of something bounded (the rounding of integer tick counts, a
    reference position or heading error differenced over each window) make consecutive
    windows' residuals negatively correlated: the sum over a run of windows keeps only its ends.
    Weighted least squares then wastes information, and a cluster covariance is a difference of
    large, nearly cancelling terms (it can come out near zero). The standardised residuals are
    modelled as ARMA(1, 1), ``u_w - phi u_(w-1) = e_w - m e_(w-1)`` with white ``e``: ``phi``
    from the ratio of the lag-two and lag-one correlations (the bounded error's own memory:
    0 for rounding, ``exp(-window / correlation time)`` for a smooth reference error), ``m``
    from the lag-one correlation. The residuals and the Jacobian are then filtered by
    ``(1 - phi L) / (1 - m L)`` (:func:`prewhiten`: generalised least squares). A positive
    lag-one correlation (slow errors), or one no larger than white errors would show by
    chance, is left to the cluster covariance: no filter. ``sums`` from
    :func:`correlation_sums`; returns (C, 2).
    """
    out = np.zeros((sums.shape[0], 2))
    for c, (sq, n, lag1, n1, lag2, n2) in enumerate(sums):
        if n1 < 20 or n2 < 20 or sq <= 0:
            continue
        rho1 = (lag1 / n1) / (sq / n)
        rho2 = (lag2 / n2) / (sq / n)
        # white errors give correlations of about 1 / sqrt(pairs): filter only what stands out
        if rho1 >= -3.0 / math.sqrt(n1):
            continue
        phi = 0.0
        if rho2 < -2.0 / math.sqrt(n2):
            phi = min(rho2 / rho1, _MAX_MA - 0.05)
        out[c] = _arma_ma(max(rho1, -0.4999), phi), phi
    return out


def _arma_ma(rho1: float, phi: float) -> float:
    """The ``m`` in (phi, _MAX_MA] whose ARMA(1, 1) has lag-one correlation ``rho1`` (< 0)."""
    def lag_one(m: float) -> float:
        return (1.0 - phi * m) * (phi - m) / (1.0 + m * m - 2.0 * phi * m)
    lo, hi = phi, _MAX_MA              # lag_one falls from phi's 0 as m grows
    if lag_one(hi) >= rho1:
        return hi
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if lag_one(mid) > rho1:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def noise_sums(measured: FloatArray, residual: FloatArray,
               gain: FloatArray | None = None) -> FloatArray:
    """Sums that fit ``r^2 ~ s0^2 + f^2 rev^2`` (:func:`noise_from_sums`); they add up over parts.

    The residuals are decoupled by ``gain`` (:func:`coupling_gain`) first. Returns (2, 5): per
    channel n, sum rev^2, sum rev^4, sum r^2, sum r^2 rev^2.
    """
    rev2 = expected_revolutions(measured, residual).mean(axis=1) ** 2
    decoupled = decouple(residual, gain)
    out = np.empty((2, 5))
    for c in range(2):
        r2 = decoupled[:, c] ** 2
        out[c] = r2.size, rev2.sum(), (rev2**2).sum(), r2.sum(), (r2 * rev2).sum()
    return out


def noise_from_sums(sums: FloatArray) -> FloatArray:
    """Each channel's ``s0, f``: least squares of ``r^2 ~ s0^2 + f^2 rev^2`` with both terms
    kept non-negative (a term that comes out negative is dropped and the other refitted), a
    floor of 1e-3 of the mean square under ``s0^2``."""
    out = np.empty((2, 2))
    for c in range(2):
        n, sx, sxx, sy, sxy = sums[c]
        det = n * sxx - sx * sx
        a, b = sy / max(n, 1.0), 0.0
        if det > 0:
            a2 = (sxx * sy - sx * sxy) / det
            b2 = (n * sxy - sx * sy) / det
            if a2 >= 0 and b2 >= 0:
                a, b = a2, b2
            elif b2 < 0:
                a, b = sy / max(n, 1.0), 0.0
            else:
                a, b = 0.0, max(sxy / max(sxx, 1e-300), 0.0)
        floor = max(sy / max(n, 1.0) * 1e-3, 1e-24)
        out[c] = math.sqrt(max(a, floor)), math.sqrt(max(b, 0.0))
    return out
