"""The default method (``inverse``): the wheel rates as the measurement, the motion as the model.

The paper's Gauss-Newton rolls the model out *with the measured wheel rates as inputs* and fits
the poses. Wheel-rate noise then sits in the regressors: integrated along a segment it blurs the
heading, which shrinks the rolled-out trajectory (c_e comes out too large) and attenuates the
yaw-rate gain (t_r comes out too large): the errors-in-variables bias, which grows with the
square of the noise. The three-step method inherits it from its step-1 sets; compensation cannot
remove what it does not know.

Here the model runs the other way (:func:`odocal.model.inverse_revolutions`): from the reference
motion of each step (along-track displacement ``ds`` and heading change ``dpsi``, by (1)
inverted), (2)-(3) give the revolutions each rear wheel must have turned::

    n_rl t_s = (ds - t_r dpsi / 2) / c_rl,      n_rr t_s = (ds + t_r dpsi / 2) / c_rr

and theta is fitted to the *measured* revolutions, summed over short windows (``window_s``).
Wheel errors of every kind that is independent of the reference (white, growing with the rate,
coloured, slip, quantisation) are now in the measurement, where least squares is unbiased; only
the reference's own errors sit in the regressors, and over a window of seconds they are tiny
against the motion (a heading error of 0.2 degrees against the turns of a city drive attenuates
t_r by well under a millimetre).

What remains is done from the data:

* **Weights.** The windows' residuals, in a sum channel (distance: c_e) and a difference channel
  (yaw: t_r, c_d, d), get a variance that grows with the revolutions, ``s0^2 + (f rev)^2`` (white
  noise; slip and rate-proportional noise), fitted to the residuals; spikes beyond four standard
  deviations are down-weighted (Huber) and counted.
* **Clock offset.** A wheel stream that lags the reference (a logging delay, or the window an ABS
  unit counts its ticks over) biases the yaw terms in every bend. The lag is found by scanning
  the yaw channel's cost over shifts of the reference side (which carries no wheel noise) and
  refining the minimum by a parabola; theta is refitted at that lag and the scan repeated until
  the lag settles (to 1e-3 steps: c_e is sensitive to it where the wheel errors are small). It
  is reported and applied. (The distance channel is left out: slip that grows with
  acceleration looks like a lag there.) A wheel unit that counts its ticks over a window
  reports a moving average: a lag *and* a smoothing, whose spread is fitted with theta.
* **Heading offset.** A reference heading rotated against the direction of travel (a mounting
  yaw) shortens every projected step by the cosine of the offset; it is measured on the straight
  stretches and applied.
* **A wheel error common to both wheels.** A slip (or any error) that scales both wheels'
  revolutions alike shows in the distance channel and, times the window's ratio ``rho`` of the
  wheels' difference to their mean, in the yaw channel: in bends it is a yaw error. The yaw
  channel's residuals are regressed on ``rho`` times the distance channel's (``beta``: 1 for a
  common slip, a little less with other noise), over windows that move one way, turn no
  tighter than ``|rho| <= 0.5`` and are not outliers; where ``beta`` stands out (Wald statistic
  above 10.83) and lies in [0.5, 1.5], that part is taken out of the yaw channel and its
  Jacobian: generalised least squares with the two channels' covariance. On ``slip-heavy`` it
  took the t_r error from 4.0 to 2.7 mm (20 seeds); where there is no common error it stays off.
* **Telescoping errors.** Errors that are differences of something bounded (rounded tick
  counts, a reference pose's own errors differenced per window) are found from the residuals'
  lag-one and lag-two correlations and prewhitened (ARMA(1,1), generalised least squares).
* **Uncertainty.** The covariance is a sandwich over clusters of windows (cross products of
  clusters up to three apart included, with Newey and West's weights), on the prewhitened
  residuals, so correlated and mis-weighted errors widen it rather than hide.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from odocal.data.drive import Drive
from odocal.data.segments import common_sampling_time
from odocal.estimators.base import NEED_DIFFERENTIAL, MethodOutcome, Prepared, ProgressCallback
from odocal.estimators.covariance import NEWEY_WEST, leverage_adjusted_scores, robust_covariance
from odocal.estimators.estimate import (
    CovarianceKind,
    Estimate,
    NotIdentified,
    Reason,
    Status,
    few_clusters_inflation,
    held_as_weak,
    judge,
    weak,
)
from odocal.estimators.validation import heading_offset as reference_heading_offset
from odocal.model._jit import jit
from odocal.model.kinematics import inverse_revolutions, motion_increments
from odocal.model.parameters import PARAMETER_NAMES, Parameters
from odocal.settings import Settings

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]
log = logging.getLogger(__name__)

_HUBER = 4.0              # residuals beyond this many standard deviations are down-weighted
_MIN_CLUSTERS_FOR_ROBUST = 10
_MAX_MA = 0.95            # prewhitening stays a stable filter
_P = 5                    # theta and the counting window's spread
_SHIFT_ROUNDS = 6         # the lag scanned and theta refitted in turn at most so often
_SHIFT_SETTLED = 1e-3     # steps
COUPLING_WALD = 10.83     # the common wheel error's share in the yaw channel: used where its
COUPLING_RANGE = (0.5, 1.5)  # Wald statistic (chi-square, 1 dof, p = 0.001) and value allow
_RHO_MAX = 0.5            # windows with a larger wheel difference over mean (reversing, spikes)


@dataclass(frozen=True)
class _Steps:
    """Every step of every piece of every drive, one after another.

    ds, dpsi, a_y : per step (see :func:`odocal.model.motion_increments`)
    revs : ndarray, shape (S, 2), measured wheel revolutions of each step (n t_s)
    piece_start, piece_stop : ndarray of int, the step range of each piece
    time_s : ndarray, shape (S,), the time of each step (for clustering)
    drive : ndarray of int, shape (S,), the drive of each step
    """

    ds: FloatArray
    dpsi: FloatArray
    a_y: FloatArray
    revs: FloatArray
    piece_start: IntArray
    piece_stop: IntArray
    time_s: FloatArray
    drive: IntArray
    speed: FloatArray


def _steps(drives: Sequence[Drive], heading_offset: float = 0.0) -> _Steps:
    parts: dict[str, list[FloatArray]] = {k: [] for k in ("ds", "dpsi", "a_y", "revs", "t", "drv",
                                                           "speed")}
    starts, stops = [], []
    count = 0
    for i, d in enumerate(drives):
        for a, b in d.pieces:
            if b - a < 2:
                continue
            ds, dpsi = motion_increments(d.x[a:b], d.y[a:b], d.psi[a:b],
                                         d.beta[a:b] + heading_offset)
            parts["ds"].append(ds)
            parts["dpsi"].append(dpsi)
            parts["a_y"].append(d.a_y[a:b - 1])
            parts["revs"].append(np.column_stack([d.n_rl[a:b - 1], d.n_rr[a:b - 1]]) * d.t_s)
            parts["t"].append(d.t[a:b - 1])
            parts["drv"].append(np.full(b - a - 1, i, dtype=np.float64))
            parts["speed"].append(np.hypot(np.diff(d.x[a:b]), np.diff(d.y[a:b])) / d.t_s)
            starts.append(count)
            count += b - a - 1
            stops.append(count)
    cat = {k: np.concatenate(v) if v else np.zeros(0) for k, v in parts.items()}
    return _Steps(ds=cat["ds"], dpsi=cat["dpsi"], a_y=cat["a_y"],
                  revs=cat["revs"].reshape(-1, 2), piece_start=np.array(starts, dtype=np.int64),
                  piece_stop=np.array(stops, dtype=np.int64), time_s=cat["t"],
                  drive=cat["drv"].astype(np.int64), speed=cat["speed"])


@dataclass(frozen=True)
class _Windows:
    """Windows of ``length`` steps inside the pieces, leaving ``margin`` steps at each end (room
    for the clock-offset shift)."""

    start: IntArray
    length: int
    measured: FloatArray          # (W, 2) measured revolutions
    cluster: IntArray             # (W,) cluster label
    follows: BoolArray            # (W,) the window starts where the one before it ends


def _windows(steps: _Steps, length: int, margin: int, cluster_steps: int) -> _Windows:
    starts, pieces = [], []
    for k, (a, b) in enumerate(zip(steps.piece_start, steps.piece_stop, strict=True)):
        lo, hi = a + margin, b - margin
        n = (hi - lo) // length
        if n > 0:
            starts.append(lo + length * np.arange(n, dtype=np.int64))
            pieces.append(np.full(n, k, dtype=np.int64))
    start = np.concatenate(starts) if starts else np.zeros(0, dtype=np.int64)
    piece = np.concatenate(pieces) if pieces else np.zeros(0, dtype=np.int64)
    cum = np.concatenate([np.zeros((1, 2)), np.cumsum(steps.revs, axis=0)])
    measured = cum[start + length] - cum[start]
    moving = np.abs(measured).sum(axis=1) > 0       # a window at a standstill says nothing
    start, measured, piece = start[moving], measured[moving], piece[moving]
    follows = np.zeros(start.size, dtype=bool)
    follows[1:] = (np.diff(start) == length) & (np.diff(piece) == 0)
    cluster = steps.drive[start] * (10**9) + (start // max(cluster_steps, 1))
    return _Windows(start=start, length=length, measured=measured,
                    cluster=cluster.astype(np.int64), follows=follows)


@jit
def _window_sums(values: FloatArray, start: IntArray, length: int, shift: float,
                 out: FloatArray) -> None:  # pragma: no cover
    """out[w] = sum of values over steps [start[w] - shift, start[w] - shift + length).

    ``values`` (M, P); a fractional shift takes the fraction of the end steps (the cumulative
    sum interpolated linearly).
    """
    p = values.shape[1]
    for w in range(start.shape[0]):
        lo = start[w] - shift
        i0 = int(np.floor(lo))
        f0 = lo - i0
        hi = lo + length
        i1 = int(np.floor(hi))
        f1 = hi - i1
        for c in range(p):
            total = 0.0
            for k in range(i0, i1):
                total += values[k, c]
            if f1 > 0.0:
                total += f1 * values[i1, c]
            if f0 > 0.0:
                total -= f0 * values[i0, c]
            out[w, c] = total


def _sums(values: FloatArray, win: _Windows, shift: float) -> FloatArray:
    """Window sums of per-step ``values`` (M, ...) at ``shift`` steps, shape (W, ...)."""
    flat = np.ascontiguousarray(values.reshape(values.shape[0], -1))
    out = np.empty((win.start.shape[0], flat.shape[1]))
    _window_sums(flat, win.start, win.length, float(shift), out)
    return out.reshape((win.start.shape[0], *values.shape[1:]))


def _predict(p: FloatArray, steps: _Steps, win: _Windows, shift: float,
             smooth: bool) -> tuple[FloatArray, FloatArray]:
    """Predicted revolutions of each window (W, 2) and their Jacobian (W, 2, 5).

    ``p`` is theta and the counting window's spread ``kappa`` (half its variance, steps^2).
    ``shift`` (steps, may be fractional) moves the reference side back in time: the wheel window
    [s, e) is compared with the motion over [s - shift, e - shift). A wheel stream that is a
    moving average of tick counts (as an ABS unit reports it) is the motion seen through a
    kernel: its mean is the lag, and its spread adds ``kappa`` times the second difference of
    the window sums in the shift (``smooth``). Left out, the spread biases c_e by about 1e-6
    (the second difference correlates with the acceleration squared, which never averages out).
    """
    revs, jac = inverse_revolutions(p[:4], steps.ds, steps.dpsi, steps.a_y)
    pred = _sums(revs, win, shift)
    out = np.zeros((pred.shape[0], 2, _P))
    out[..., :4] = _sums(jac, win, shift)
    if smooth:
        second = _sums(revs, win, shift + 1.0) + _sums(revs, win, shift - 1.0) - 2.0 * pred
        pred = pred + p[4] * second
        out[..., 4] = second
    return pred, out


CHANNELS = np.array([[0.5, 0.5], [-1.0, 1.0]])   # sum (distance) and difference (yaw) channels
_TO_WHEELS = np.linalg.inv(CHANNELS)


@dataclass
class _Fit:
    theta: FloatArray             # (5,): theta and the counting window's spread kappa
    residual: FloatArray          # (W, 2) channel residuals (before decoupling)
    weight: FloatArray            # (W, 2)
    white_residual: FloatArray    # (W, 2) standardised and prewhitened residuals
    white_jac: FloatArray         # (W, 2, 5) their Jacobian
    cost: float
    iterations: int
    history: list[float] = field(default_factory=list)
    decoupled: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    """(W, 2): the residuals with the yaw channel's common-wheel part taken out."""


@jit
def _prewhiten_kernel(x: FloatArray, follows: BoolArray, ma: FloatArray, prev_x: FloatArray,
                      prev_out: FloatArray, out: FloatArray) -> None:  # pragma: no cover
    for w in range(x.shape[0]):
        for c in range(x.shape[1]):
            for k in range(x.shape[2]):
                v = x[w, c, k]
                if follows[w]:
                    before_x = x[w - 1, c, k] if w > 0 else prev_x[c, k]
                    before_out = out[w - 1, c, k] if w > 0 else prev_out[c, k]
                    v += ma[c, 0] * before_out - ma[c, 1] * before_x
                out[w, c, k] = v


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
    out = np.empty_like(x)
    if before is None:
        follows = follows.copy()
        if follows.size:
            follows[0] = False
        prev = np.zeros(x.shape[1:])
        _prewhiten_kernel(x, follows, ma, prev, prev, out)
    else:
        _prewhiten_kernel(x, follows, ma, np.ascontiguousarray(before[0]),
                          np.ascontiguousarray(before[1]), out)
    return out


def _evaluate(p: FloatArray, steps: _Steps, win: _Windows, shift: float, smooth: bool,
              noise: FloatArray, ma: FloatArray, coupling: float, channels: FloatArray,
              iterations: int, history: list[float]) -> _Fit:
    pred, jac = _predict(p, steps, win, shift, smooth)
    r = (win.measured - pred) @ CHANNELS.T
    j = np.einsum("ci,wip->wcp", CHANNELS, jac)
    gain = coupling_gain(win.measured, r, coupling)
    w = window_weights(win.measured, r, noise, gain) * channels
    sw = np.sqrt(w)
    stacked = decouple(np.concatenate([r[..., None], j], axis=2), gain) * sw[..., None]
    white = prewhiten(stacked, win.follows, ma)
    cost = float(np.sum(white[..., 0] ** 2))
    history.append(cost)
    return _Fit(p, r, w, white[..., 0], white[..., 1:], cost, iterations, history,
                decoupled=decouple(r, gain))


def _solve(p0: FloatArray, steps: _Steps, win: _Windows, shift: float, free: BoolArray,
           noise: FloatArray, ma: FloatArray, coupling: float, max_iterations: int,
           tolerance: float, channels: FloatArray) -> _Fit:
    """Weighted Gauss-Newton on the prewhitened channel residuals (nearly linear in theta).

    ``free`` (5,) marks the free parameters of ``p`` (theta and kappa); ``ma`` (2, 2) the
    prewhitening of each channel (see :func:`arma_from_sums`); ``coupling`` the common wheel
    error's share in the yaw channel (``beta``, :func:`coupling_from_sums`);
    ``channels`` (2,) scales the weights of the distance and yaw channels (0 leaves one out).
    """
    p = p0.copy()
    history: list[float] = []
    smooth = bool(free[4])
    fit = _evaluate(p, steps, win, shift, smooth, noise, ma, coupling, channels, 0, history)
    for iterations in range(1, max_iterations + 1):
        if not free.any():
            break
        step = np.zeros(_P)
        a = fit.white_jac.reshape(-1, _P)[:, free]
        step[free] = np.linalg.lstsq(a, fit.white_residual.ravel(), rcond=None)[0]
        p = p + step
        fit = _evaluate(p, steps, win, shift, smooth, noise, ma, coupling, channels, iterations,
                        history)
        scale = np.maximum(np.abs(p), 1e-3)
        if np.max(np.abs(step) / scale) < tolerance:
            break
    return fit


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
    return w * np.minimum(1.0, _HUBER / np.maximum(z, 1e-300))


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
              & (np.abs(residual[:, 0]) * np.sqrt(weight[:, 0]) <= _HUBER))
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


def coupling_from_sums(sums: FloatArray) -> float:
    """``beta``, the common wheel error's share in the yaw channel, or 0 where it does not stand
    out (Wald statistic below :data:`COUPLING_WALD`; the weights standardise the residuals, so
    it is chi-square with one degree of freedom where there is no such error) or lies outside
    :data:`COUPLING_RANGE` (a common slip gives 1; what else correlates the channels, e.g.
    rounded tick counts that telescope, can pass the Wald test with a beta of 2 to 12)."""
    sxx, sxy = float(sums[0]), float(sums[1])
    if not (math.isfinite(sxx) and math.isfinite(sxy)) or sxx <= 0.0:
        return 0.0
    beta = sxy / sxx
    if beta * beta * sxx < COUPLING_WALD or not COUPLING_RANGE[0] <= beta <= COUPLING_RANGE[1]:
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


def _fit_noise(measured: FloatArray, residual: FloatArray,
               gain: FloatArray | None = None) -> FloatArray:
    """The noise model ``s0, f`` of each channel (rows), fitted to the squared residuals."""
    return noise_from_sums(noise_sums(measured, residual, gain))


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


@dataclass(frozen=True)
class InverseDetails:
    """What the inverse-model calibration did.

    windows, window_s, clusters : the windows fitted and their grouping for the covariance
    delay_s : the wheel stream's lag behind the reference that was found and applied (positive:
        the wheels are late); ``delay_std_s`` its standard deviation (nan: not determined)
    heading_offset_rad : the reference heading's rotation against the direction of travel, found
        on straight stretches and applied
    noise : the fitted noise model, per channel (distance, yaw): ``s0`` (revolutions per window)
        and ``f`` (fraction of the revolutions)
    downweighted : windows whose residual exceeded four standard deviations
    iterations, cost_history : of the final fit
    residual_rms : RMS of the channel residuals (revolutions per window)
    """

    windows: int
    window_s: float
    clusters: int
    delay_s: float
    delay_std_s: float
    heading_offset_rad: float
    noise: tuple[tuple[float, float], tuple[float, float]]
    downweighted: int
    iterations: int
    cost_history: tuple[float, ...]
    residual_rms: tuple[float, float]
    elapsed_s: float
    information: FloatArray = field(repr=False)
    scores: FloatArray = field(repr=False)
    cluster: IntArray = field(repr=False)
    measured: FloatArray = field(repr=False)
    """(W, 2): each window's measured revolutions in the distance and yaw channels."""
    residual: FloatArray = field(repr=False)
    """(W, 2): measured minus what the motion implies, same channels."""
    prewhitening: tuple[float, float] = (0.0, 0.0)
    """Each channel's moving-average coefficient of the errors that telescope across windows
    (0: none; near 1: rounding or a reference's own errors, differenced per window)."""
    smoothing_steps2: float = 0.0
    """The variance of the wheel stream's counting window beyond the lag, steps^2 (a moving
    average over w samples: (w^2 - 1) / 12)."""
    coupling: float = 0.0
    """``beta``: the share of the distance channel's errors that shows in the yaw channel, times
    the window's wheel difference over their mean (0: not used). A slip common to both wheels
    gives about 1 (less where other errors dilute the regression)."""

    def to_dict(self) -> dict[str, Any]:
        return {"windows": self.windows, "window_s": self.window_s, "clusters": self.clusters,
                "delay_s": self.delay_s, "delay_std_s": self.delay_std_s,
                "heading_offset_rad": self.heading_offset_rad,
                "noise": {"distance": {"s0_rev": self.noise[0][0], "f": self.noise[0][1]},
                          "yaw": {"s0_rev": self.noise[1][0], "f": self.noise[1][1]}},
                "downweighted_windows": self.downweighted, "iterations": self.iterations,
                "cost_history": list(self.cost_history),
                "residual_rms_rev": {"distance": self.residual_rms[0],
                                     "yaw": self.residual_rms[1]},
                "prewhitening": {"distance": self.prewhitening[0],
                                 "yaw": self.prewhitening[1]},
                "smoothing_steps2": self.smoothing_steps2,
                "coupling_beta": self.coupling,
                "elapsed_s": self.elapsed_s}


def inverse_calibration(drives: Sequence[Drive], *, settings: Settings,
                        held: Mapping[str, NotIdentified] | None = None,
                        distance_only: bool = False,
                        progress: Callable[[str, int, int], None] | None = None) -> Estimate:
    """Calibrate theta by fitting the wheel revolutions the reference motion implies.

    ``distance_only`` fits the distance channel alone (the wheels carry no differential signal:
    hold c_d, t_r and d). Returns an :class:`~odocal.estimate.Estimate` with
    :class:`InverseDetails`.
    """
    started = time.perf_counter()
    cfg = settings.inverse
    t_s = common_sampling_time(drives)
    datasheet = np.asarray(settings.identify.theta0, dtype=np.float64)
    held = dict(held or {})
    free = np.array([name not in held for name in PARAMETER_NAMES])
    offset, offset_samples = (reference_heading_offset(drives) if cfg.heading_offset == "estimate"
                              else (0.0, 0))
    if offset_samples < 200:          # five seconds of straight driving at least
        offset = 0.0
    steps = _steps(drives, heading_offset=offset)
    length = max(round(cfg.window_s / t_s), 1)
    # room for the lag scan and one step either way for the counting window's spread (the
    # online calibrator's windows start where these do)
    margin = math.ceil(cfg.max_delay_s / t_s - 1e-6) + 1 if cfg.delay == "estimate" else 0
    win = _windows(steps, length, margin, settings.segments.length)
    if win.start.size < 4:
        log.warning("inverse calibration: the drives hold fewer than four moving windows")
        return _nothing(settings, datasheet, held, started, win)

    noise = np.array([[1e-3, 1e-3], [1e-3, 1e-3]])
    ma = np.zeros((2, 2))
    coupling = 0.0
    channels = np.array([1.0, 0.0 if distance_only else 1.0])
    smooth = cfg.delay == "estimate" and not distance_only

    def solve(p: FloatArray, shift: float) -> _Fit:
        # (free, noise, ma and coupling as they are at the call)
        return _solve(p, steps, win, shift, np.append(free, smooth), noise, ma, coupling,
                      cfg.max_iterations, cfg.tolerance, channels)

    def error_model(fit: _Fit) -> tuple[float, FloatArray, FloatArray]:
        """The coupling, noise model and prewhitening from a fit's residuals."""
        new = 0.0
        if not distance_only and cfg.common_wheel_error == "estimate":
            new = coupling_from_sums(coupling_sums(win.measured, fit.residual, fit.weight))
        return (new, _fit_noise(win.measured, fit.residual,
                                coupling_gain(win.measured, fit.residual, new)),
                arma_from_sums(correlation_sums(fit.decoupled * np.sqrt(fit.weight),
                                                win.follows)))

    if progress:
        progress("inverse: fit", 0, 4)
    fit = solve(np.append(datasheet, 0.0), 0.0)
    noise = _fit_noise(win.measured, fit.residual)
    shift, shift_std = 0.0, float("nan")
    if cfg.delay == "estimate" and not distance_only:
        fit = solve(fit.theta, 0.0)
        shift, shift_std = _scan_delay(fit.theta[:4], steps, win, noise, coupling, margin - 1)
    if progress:
        progress("inverse: fit", 2, 4)
    for _ in range(2):                  # re-fit the error model at the final shift
        fit = solve(fit.theta, shift)
        coupling, noise, ma = error_model(fit)
    for _ in range(_SHIFT_ROUNDS - 1 if cfg.delay == "estimate" and not distance_only else 0):
        # the lag again with the theta fitted at it, until the two agree
        again, again_std = _scan_delay(fit.theta[:4], steps, win, noise, coupling, margin - 1)
        if abs(again - shift) < _SHIFT_SETTLED:
            break
        shift, shift_std = again, again_std
        for _ in range(2):
            fit = solve(fit.theta, shift)
            coupling, noise, ma = error_model(fit)
    fit = solve(fit.theta, shift)
    n_clusters = int(np.unique(win.cluster).size)
    for _ in range(len(PARAMETER_NAMES)):
        cov, info, scores = _covariance(fit, np.append(free, smooth), win.cluster, n_clusters)
        std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        if n_clusters < 2 and free.any() and settings.identify.judge_identifiability:
            for j in np.flatnonzero(free):
                held[PARAMETER_NAMES[j]] = NotIdentified(Reason.ONE_CLUSTER, float(std[j]),
                                                         detail=float(n_clusters))
            free[:] = False
        else:
            too_weak = weak(std, free, settings.identify)
            if not too_weak.any():
                break
            held.update(held_as_weak(std, too_weak, settings.identify))
            free = free & ~too_weak
        p = fit.theta.copy()
        p[:4][~free] = datasheet[~free]
        fit = solve(p, shift)
        if not free.any():
            cov = np.zeros((4, 4))
            break
    if progress:
        progress("inverse: fit", 4, 4)
    std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    rms = np.sqrt(np.mean(fit.residual**2, axis=0))
    z = np.abs(fit.decoupled) * np.sqrt(
        1.0 / window_variance(expected_revolutions(win.measured, fit.residual), noise))
    details = InverseDetails(
        windows=int(win.start.size), window_s=length * t_s, clusters=n_clusters,
        delay_s=shift * t_s, delay_std_s=shift_std * t_s, heading_offset_rad=offset,
        noise=((float(noise[0, 0]), float(noise[0, 1])), (float(noise[1, 0]),
                                                          float(noise[1, 1]))),
        downweighted=int((z > _HUBER).any(axis=1).sum()), iterations=fit.iterations,
        cost_history=tuple(fit.history), residual_rms=(float(rms[0]), float(rms[1])),
        elapsed_s=time.perf_counter() - started, information=info, scores=scores,
        cluster=win.cluster, measured=win.measured @ CHANNELS.T, residual=fit.residual,
        prewhitening=(float(ma[0, 0]), float(ma[1, 0])),
        smoothing_steps2=float(2.0 * fit.theta[4]),
        coupling=float(coupling))
    if not free.any():
        status = Status.NOTHING_IDENTIFIABLE
    elif float(np.max(rms)) < 1e-9:
        status = Status.EXACT
    else:
        status = Status.CONVERGED if fit.iterations < cfg.max_iterations \
            else Status.ITERATION_LIMIT
    theta = fit.theta[:4].copy()
    theta[~free] = datasheet[~free]
    return Estimate(method="inverse", theta=Parameters.from_array(theta),
                    datasheet=Parameters.from_array(datasheet), covariance=cov,
                    covariance_kind=(CovarianceKind.CLUSTER_ROBUST
                                     if n_clusters >= _MIN_CLUSTERS_FOR_ROBUST
                                     else CovarianceKind.RESIDUAL),
                    free=tuple(bool(f) for f in free),  # type: ignore[arg-type]
                    verdicts=judge(std, free, settings.identify, held=held), status=status,
                    details=details)


def _nothing(settings: Settings, datasheet: FloatArray, held: dict[str, NotIdentified],
             started: float, win: _Windows) -> Estimate:
    for name in PARAMETER_NAMES:
        held.setdefault(name, NotIdentified(Reason.NO_INFORMATION))
    details = InverseDetails(
        windows=int(win.start.size), window_s=win.length * 0.0, clusters=0, delay_s=0.0,
        delay_std_s=float("nan"), heading_offset_rad=0.0, noise=((0.0, 0.0), (0.0, 0.0)),
        downweighted=0, iterations=0, cost_history=(), residual_rms=(0.0, 0.0),
        elapsed_s=time.perf_counter() - started, information=np.zeros((0, 4, 4)),
        scores=np.zeros((0, 4)), cluster=np.zeros(0, dtype=np.int64),
        measured=np.zeros((0, 2)), residual=np.zeros((0, 2)))
    return Estimate(method="inverse", theta=Parameters.from_array(datasheet),
                    datasheet=Parameters.from_array(datasheet), covariance=np.zeros((4, 4)),
                    covariance_kind=CovarianceKind.NONE, free=(False, False, False, False),
                    verdicts=judge(np.zeros(4), np.zeros(4, dtype=bool), settings.identify,
                                   held=held),
                    status=Status.NOTHING_IDENTIFIABLE, details=details)


def _scan_delay(theta: FloatArray, steps: _Steps, win: _Windows, noise: FloatArray,
                coupling: float, limit: int) -> tuple[float, float]:
    """The shift (steps) of the reference side that fits the wheels best, and its std.

    The yaw channel's cost is scanned at half-step spacing with theta fixed, and the minimum
    refined by a parabola through it and its neighbours; the parabola's curvature gives the std
    (the cost is a weighted sum of squares with unit-variance residuals near the minimum). A
    shift within three standard deviations of zero, or a flat cost (no turning to time the
    wheels by), is not applied.
    """
    grid = np.arange(-limit, limit + 0.25, 0.5)
    costs = np.empty(grid.size)
    revs, _ = inverse_revolutions(theta, steps.ds, steps.dpsi, steps.a_y)
    for i, shift in enumerate(grid):
        r = (win.measured - _sums(revs, win, float(shift))) @ CHANNELS.T
        # the yaw channel times the wheels: slip that grows with acceleration is common to both
        # wheels and would pass for a lag in the distance channel
        gain = coupling_gain(win.measured, r, coupling)
        costs[i] = float(np.sum((window_weights(win.measured, r, noise, gain)
                                 * decouple(r, gain)**2)[:, 1]))
    i = int(np.argmin(costs))
    if i == 0 or i == grid.size - 1:
        log.warning("inverse calibration: the wheel clock offset lies at the edge of the search "
                    "range; none applied (widen [inverse] max_delay_s)")
        return 0.0, float("nan")
    c0, c1, c2 = costs[i - 1:i + 2]
    curvature = (c0 - 2.0 * c1 + c2) / 0.25            # d^2 cost / d shift^2
    if curvature <= 0:
        return 0.0, float("nan")
    best = float(grid[i] + 0.5 * 0.5 * (c0 - c2) / (c0 - 2.0 * c1 + c2))
    std = float(np.sqrt(2.0 / curvature))
    if abs(best) < 3.0 * std:                          # not distinguishable from no lag
        return 0.0, std
    return best, std


def _covariance(fit: _Fit, free: BoolArray, cluster: IntArray,
                n_clusters: int) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Sandwich covariance over clusters of windows, from the prewhitened residuals, each
    cluster's score adjusted for its leverage; theta's (4, 4) block, with the counting window's
    spread (``free[4]``) profiled out. Also each window's information and score in theta."""
    jw = fit.white_jac
    info = np.einsum("wcp,wcq->wpq", jw, jw)                   # (W, 5, 5)
    scores = np.einsum("wcp,wc->wp", jw, fit.white_residual)   # (W, 5)
    h = info.sum(axis=0)
    h_inv = np.zeros((_P, _P))
    cols = np.flatnonzero(free)
    if cols.size:
        h_inv[np.ix_(cols, cols)] = np.linalg.pinv(h[np.ix_(cols, cols)])
    if n_clusters >= _MIN_CLUSTERS_FOR_ROBUST:
        adjusted, labels = leverage_adjusted_scores(info, scores, free, cluster)
        cov = robust_covariance(h_inv, adjusted, free, labels, NEWEY_WEST)
    else:
        dof = max(fit.white_residual.size - int(free.sum()), 1)
        naive = (fit.cost / dof) * h_inv
        robust = robust_covariance(h_inv, scores, free, cluster, NEWEY_WEST) \
            if n_clusters >= 2 else naive
        s_n = np.sqrt(np.clip(np.diag(naive), 0.0, None))
        s_r = np.sqrt(np.clip(np.diag(robust), 0.0, None))
        with np.errstate(divide="ignore", invalid="ignore"):
            f = np.where(s_n > 0, np.maximum(s_n, s_r) / s_n, 1.0)
        # one cluster: no spread to inflate (the one-cluster rule leaves nothing identified)
        inflation = few_clusters_inflation(n_clusters) if n_clusters >= 2 else 1.0
        cov = naive * np.outer(f, f) * inflation**2
    return cov[:4, :4], info[:, :4, :4], scores[:, :4]


def run(prep: Prepared, settings: Settings,
        progress: ProgressCallback | None = None) -> MethodOutcome:
    """The default method on the prepared drives (every window of every piece, not only the
    selected segments). No bootstrap: its errors telescope (quantised counts, a reference's
    errors differenced over windows), which resampling clusters cannot see; the sandwich's
    neighbour terms do, and the noise matrix checks it against the truth."""
    return MethodOutcome(estimate=inverse_calibration(prep.drives, settings=settings,
                                                      held=prep.held, progress=progress))


def run_distance_only(prep: Prepared, settings: Settings,
                      progress: ProgressCallback | None = None) -> MethodOutcome:
    """The wheels carry no differential signal: c_e alone, from the distance channel.

    Every other method takes the heading from the wheels, so none of them can use such data;
    the distance channel needs the wheels' mean only.
    """
    held = {**prep.held, **{n: NotIdentified(Reason.NO_DIFFERENTIAL) for n in NEED_DIFFERENTIAL}}
    return MethodOutcome(estimate=inverse_calibration(prep.drives, settings=settings, held=held,
                                                      distance_only=True, progress=progress))
