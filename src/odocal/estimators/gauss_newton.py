"""METHOD 3: Gauss-Newton identification of theta from segments (pure and batch).

Minimises ``V(theta) = sum_k (y~_k - y^_k)^T W (y~_k - y^_k)`` over the segments of a batch
(one segment: *pure* G-N; several: *batch* G-N, their J and R stacked). Each iteration solves the
weighted linear least-squares problem (7)-(8) by QR: every segment's ``[sqrt(W) J | sqrt(W) R]``
is reduced to a 5x5 R factor (:func:`odocal.model.jacobians.segment_r_factors`, vectorised),
and the stacked factors once more (a tall-skinny QR), iterating while the cost decreases, at most
``i_max`` times. A step that would raise the cost is halved until it does not (up to ten times)
before the iteration stops; near the solution the full step is always taken, so this only guards
the first steps from a poor initial guess.

Parameters the data cannot identify are found two ways and kept at their initial values:
numerically (the scaled normal equations are rank deficient, e.g. no bends at all) and
statistically (the data's standard deviation of a parameter is not much smaller than the datasheet
uncertainty ``prior_std``: :func:`odocal.estimators.estimate.judge`). The verdict is applied
however the
iteration ended.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.linalg import lapack, qr

from odocal.arrays import BoolArray, FloatArray, IntArray
from odocal.data.segments import SegmentBatch
from odocal.estimators.base import BootstrapTerms
from odocal.estimators.covariance import MIN_CLUSTERS_FOR_ROBUST, robust_covariance
from odocal.estimators.estimate import (
    CovarianceKind,
    Estimate,
    GaussNewtonDetails,
    NotIdentified,
    Reason,
    Status,
    few_clusters_inflation,
    hold_unidentified,
    judge,
)
from odocal.model.jacobians import CHUNK_STEPS, segment_r_factors
from odocal.model.parameters import PARAMETER_NAMES, PARAMETERS, Parameters
from odocal.settings import IdentifySettings, Settings

log = logging.getLogger(__name__)

_MAX_HALVINGS = 10
#: A weighted RMS residual below this (m, or rad times the heading weight's root) is numerically
#: zero: the data fit the model exactly.
_EXACT_RMS = 1e-9
#: Relative changes of the cost below this are its rounding (sums over millions of samples
#: vary by about 1e-12 from the order of summation); a step predicted to gain less is at most
#: about 0.01 of a standard deviation even on a 4 h drive.
_COST_ROUNDING = 1e-11
#: Columns of a segment's least-squares problem: the Jacobian's, then the residual.
_COLS = PARAMETERS + 1


@dataclass(frozen=True)
class Linearisation:
    """The weighted least-squares problem of one G-N iteration at ``theta``.

    cost : V(theta)
    r_factor : ndarray, shape (n+1, n+1)
        Upper-triangular R of the QR factorisation of ``[sqrt(W) J | sqrt(W) R]``.
    segment_r : ndarray, shape (N, n+1, n+1)
        The same per segment.
    residual_ss : ndarray, shape (3,)
        Unweighted sums of squared residuals of p_x, p_y, psi.
    samples : int
        Number of residual samples (segments times K).
    lag1 : float
        Lag-1 autocorrelation of the weighted residuals along each segment (pooled).
    """

    theta: FloatArray
    cost: float
    r_factor: FloatArray
    segment_r: FloatArray
    residual_ss: FloatArray
    samples: int
    lag1: float

    @property
    def scores(self) -> FloatArray:
        """Per-segment ``J_s^T W R_s``, shape (N, n)."""
        n = PARAMETERS
        return np.einsum("nij,ni->nj", self.segment_r[:, :n, :n], self.segment_r[:, :n, n])

    @property
    def information(self) -> FloatArray:
        """Per-segment ``J_s^T W J_s``, shape (N, n, n)."""
        a = self.segment_r[:, :PARAMETERS, :PARAMETERS]
        return np.einsum("nki,nkj->nij", a, a)


def linearise(batch: SegmentBatch, theta: FloatArray, weights: FloatArray) -> Linearisation:
    """Residuals and Jacobians of every segment at ``theta``, reduced to R factors."""
    parts = [segment_r_factors(theta, part.inputs, part.reference, batch.t_s, weights)
             for part in batch.parts(max(1, CHUNK_STEPS // max(batch.steps, 1)))]
    segment_r = np.concatenate([r for r, _ in parts])
    stats = np.concatenate([s for _, s in parts])
    stacked = segment_r.reshape(-1, _COLS)
    r_factor = qr(stacked, mode="r", check_finite=False)[0][:_COLS]
    if r_factor.shape[0] < _COLS:  # fewer rows than columns (a degenerate, tiny batch)
        r_factor = np.vstack([r_factor, np.zeros((_COLS - r_factor.shape[0], _COLS))])
    cost = float(stats[:, 0].sum())
    lagged = float(stats[:, 4].sum())
    return Linearisation(theta=np.asarray(theta, dtype=np.float64).copy(), cost=cost,
                         r_factor=r_factor, segment_r=segment_r,
                         residual_ss=stats[:, 1:4].sum(axis=0), samples=len(batch) * batch.steps,
                         lag1=lagged / cost if cost > 0 else 0.0)


@dataclass(frozen=True)
class _Iteration:
    theta: FloatArray
    lin: Linearisation
    history: list[float]
    iterations: int
    status: Status


def gauss_newton(batch: SegmentBatch, *, settings: IdentifySettings,
                 start: FloatArray | None = None, clusters: IntArray | None = None,
                 held: Mapping[str, NotIdentified] | None = None,
                 method: str = "raw", keep: list[Linearisation] | None = None) -> Estimate:
    """Pure (one segment) or batch (several) Gauss-Newton identification.

    Parameters
    ----------
    batch : the segments, with the wheel rates to identify from (measured or compensated)
    settings : weights, iteration limit, identifiability thresholds; ``settings.theta0`` holds the
        datasheet values, which parameters the data cannot identify keep
    start : initial guess (default: the datasheet values)
    clusters : ndarray of int, shape (N,), optional
        Group label of each segment for the cluster-robust covariance: segments that overlap in
        time belong together. Each segment is its own group when None.
    held : parameters to keep at their datasheet values regardless of the data, with the reason
    method : the method name the estimate carries
    keep : where given, the linearisation at the estimate is appended to it (what
        :func:`bootstrap_terms` needs, so it is not computed twice)

    Returns
    -------
    Estimate
        With :class:`~odocal.estimate.GaussNewtonDetails`.
    """
    datasheet = np.asarray(settings.theta0, dtype=np.float64)
    theta_init = datasheet.copy() if start is None else np.array(start, dtype=np.float64)
    weights = np.asarray(settings.weights, dtype=np.float64)
    held = dict(held or {})
    free = np.array([name not in held for name in PARAMETER_NAMES])
    if clusters is None:
        clusters = np.arange(len(batch), dtype=np.int64)
    n_clusters = int(np.unique(clusters).shape[0])

    theta_init, lin0, free, held = _informed_start(batch, theta_init, datasheet, weights,
                                                   free=free, held=held, settings=settings)
    it, free, held, covariance = _fit_holding_unidentified(
        batch, theta_init, lin0, datasheet, weights, free=free, held=held, settings=settings,
        clusters=clusters, n_clusters=n_clusters)
    if keep is not None:
        keep.append(it.lin)
    return _estimate(it, covariance, datasheet, free=free, held=held, settings=settings,
                     method=method, segments=len(batch), n_clusters=n_clusters)


def _informed_start(batch: SegmentBatch, theta_init: FloatArray, datasheet: FloatArray,
                    weights: FloatArray, *, free: BoolArray, held: Mapping[str, NotIdentified],
                    settings: IdentifySettings
                    ) -> tuple[FloatArray, Linearisation, BoolArray, dict[str, NotIdentified]]:
    """The start with every parameter not free at its datasheet value, and its linearisation;
    a free parameter the data carry no numerical information on (:func:`_numerically_free`)
    is held too (:attr:`Reason.NO_INFORMATION`) and the start linearised again without it.

    Returns ``(theta, linearisation, free, held)``.
    """
    theta_init, held = theta_init.copy(), dict(held)
    prior = np.asarray(settings.prior_std, dtype=np.float64)
    theta_init[~free] = datasheet[~free]
    lin0 = linearise(batch, theta_init, weights)
    numeric_free = _numerically_free(lin0.r_factor, prior, settings.rcond, free)
    for j in np.flatnonzero(free & ~numeric_free):
        held[PARAMETER_NAMES[j]] = NotIdentified(Reason.NO_INFORMATION)
    if not np.array_equal(numeric_free, free):
        free = numeric_free
        theta_init[~free] = datasheet[~free]
        lin0 = linearise(batch, theta_init, weights)
    return theta_init, lin0, free, held


def _fit_holding_unidentified(
        batch: SegmentBatch, theta_init: FloatArray, lin0: Linearisation,
        datasheet: FloatArray, weights: FloatArray, *, free: BoolArray,
        held: Mapping[str, NotIdentified], settings: IdentifySettings, clusters: IntArray,
        n_clusters: int,
) -> tuple[_Iteration, BoolArray, dict[str, NotIdentified],
           tuple[FloatArray, FloatArray, CovarianceKind]]:
    """The iteration from the start, refitted with the datasheet values of the parameters the
    identifiability verdict holds (:func:`hold_unidentified`) until none more is held.

    Returns the last fit, the free parameters and the held ones, and the last fit's
    covariance, the residual formula's and which it is (zeros and
    :attr:`CovarianceKind.NONE` where nothing is free).
    """
    fits = [_iterate(batch, theta_init, lin0, free, weights, settings)]
    kinds: list[tuple[FloatArray, FloatArray, CovarianceKind]] = []

    def covariance_of(free: BoolArray) -> tuple[FloatArray, int]:
        kinds.append(_covariance(fits[-1].lin, free, clusters, n_clusters))
        return kinds[-1][0], n_clusters

    def refit(free: BoolArray) -> None:
        theta = fits[-1].theta.copy()
        theta[~free] = datasheet[~free]
        if free.any():
            fits.append(_iterate(batch, theta, linearise(batch, theta, weights), free,
                                 weights, settings))
        else:
            lin = linearise(batch, theta, weights)
            fits.append(_Iteration(theta, lin, [lin.cost], 0, Status.NOTHING_IDENTIFIABLE))

    free, held = hold_unidentified(free, held, settings, covariance_of=covariance_of,
                                   refit=refit)
    none = np.zeros((PARAMETERS, PARAMETERS))
    return fits[-1], free, held, kinds[-1] if free.any() else (none, none, CovarianceKind.NONE)


def _estimate(it: _Iteration, covariance: tuple[FloatArray, FloatArray, CovarianceKind],
              datasheet: FloatArray, *, free: BoolArray, held: Mapping[str, NotIdentified],
              settings: IdentifySettings, method: str, segments: int,
              n_clusters: int) -> Estimate:
    """The :class:`Estimate` of the fit ``it``, with its :class:`GaussNewtonDetails` and the
    identifiability verdicts (a fit that did not succeed is logged)."""
    cov, cov_naive, kind = covariance
    lin = it.lin
    rms = np.sqrt(lin.residual_ss / max(lin.samples, 1))
    if not it.status.success:
        log.warning("identification: %s", it.status.name)
    details = GaussNewtonDetails(
        iterations=it.iterations, cost_history=tuple(it.history), segments=segments,
        clusters=n_clusters, residual_rms=(float(rms[0]), float(rms[1]), float(rms[2])),
        covariance_naive=cov_naive)
    std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return Estimate(
        method=method, theta=Parameters.from_array(it.theta),
        datasheet=Parameters.from_array(datasheet), covariance=cov, covariance_kind=kind,
        free=tuple(bool(f) for f in free),
        verdicts=judge(std, free, settings, held=held), status=it.status, details=details)


def _iterate(batch: SegmentBatch, theta_init: FloatArray, lin0: Linearisation,
             free: BoolArray, weights: FloatArray, settings: IdentifySettings) -> _Iteration:
    """G-N iterations (8) on the free parameters, from ``theta_init``."""
    theta, lin = theta_init.copy(), lin0
    history = [lin.cost]
    scale = np.maximum(np.abs(theta_init), np.asarray(settings.prior_std))
    status = Status.ITERATION_LIMIT
    iterations = 0
    for _ in range(settings.max_iterations):
        delta = np.zeros(PARAMETERS)
        delta[free] = _solve_step(lin.r_factor, free)
        if _predicted_decrease(lin.r_factor, delta) <= _COST_ROUNDING * lin.cost:
            # the cost cannot tell this step from none (on a 4 h drive halving it took 14
            # linearisations): the G-N step, which is exact this close, is taken unverified
            theta = theta + delta
            lin = linearise(batch, theta, weights)
            history.append(lin.cost)
            iterations += 1
            status = Status.CONVERGED
            break
        trial: Linearisation | None = None
        # (8), with the step halved while it would raise the cost (the full step when it does not)
        for _halving in range(_MAX_HALVINGS + 1):
            candidate = theta + delta
            if np.isfinite(candidate).all() and candidate[0] > 0 and candidate[2] > 0:
                trial = linearise(batch, candidate, weights)
                if np.isfinite(trial.cost) and trial.cost < lin.cost:
                    break
            trial = None
            delta = 0.5 * delta
        if trial is None:
            status = Status.SETTLED
            break
        theta, lin = theta + delta, trial
        history.append(lin.cost)
        iterations += 1
        if np.max(np.abs(delta) / scale) < settings.step_tolerance:
            status = Status.CONVERGED
            break
    if np.sqrt(lin.cost / max(3 * lin.samples, 1)) < _EXACT_RMS:
        status = Status.EXACT
    elif iterations == 0:
        status = Status.NO_IMPROVEMENT
    return _Iteration(theta, lin, history, iterations, status)


def _covariance(lin: Linearisation, free: BoolArray, clusters: IntArray,
                n_clusters: int) -> tuple[FloatArray, FloatArray, CovarianceKind]:
    """The covariance of a fit (cluster-robust with enough clusters; else the larger of it and
    the residual formula, widened for the clusters' small number), the residual formula's, and
    which it is."""
    naive = _naive_covariance(lin, free)
    if n_clusters >= MIN_CLUSTERS_FOR_ROBUST:
        return _robust_covariance(lin, free, clusters), naive, CovarianceKind.CLUSTER_ROBUST
    if n_clusters >= 2:
        return (_larger(naive, _robust_covariance(lin, free, clusters))
                * few_clusters_inflation(n_clusters) ** 2, naive, CovarianceKind.RESIDUAL)
    return naive, naive, CovarianceKind.RESIDUAL


def _predicted_decrease(r_factor: FloatArray, delta: FloatArray) -> float:
    """The cost decrease the linearisation predicts for ``delta``: ``||r||^2 - ||r - A d||^2``
    in terms of the R factor of ``[A | r]``."""
    n = PARAMETERS
    after = r_factor[:, n] - r_factor[:, :n] @ delta
    return float(r_factor[:, n] @ r_factor[:, n] - after @ after)


def _solve_step(r_factor: FloatArray, free: BoolArray) -> FloatArray:
    """Least-squares step of the free parameters from the R factor of ``[A | r]``.

    Since ``[A | r] = Q R``, ``min ||A_F d - r||`` equals ``min ||R[:, F] d - R[:, n]||``.
    """
    cols = np.flatnonzero(free)
    step, *_ = np.linalg.lstsq(r_factor[:, cols], r_factor[:, PARAMETERS], rcond=None)
    return np.asarray(step)


def _numerically_free(r_factor: FloatArray, prior: FloatArray, rcond: float,
                      free: BoolArray) -> BoolArray:
    """Drop parameters until the scaled normal equations of the rest have full rank."""
    free = free.copy()
    while free.any():
        cols = np.flatnonzero(free)
        a = r_factor[:PARAMETERS, cols] * prior[cols]     # columns in units of the prior std
        _, s, vt = np.linalg.svd(a)
        s_max = s[0] if s.size else 0.0
        if s_max > 0 and s[-1] > rcond * s_max:
            break
        worst = cols[int(np.argmax(np.abs(vt[-1])))] if s_max > 0 else cols[0]
        free[worst] = False
    return free


def information_inverse(r_factor: FloatArray, free: BoolArray) -> FloatArray:
    """(J^T W J)^-1 of the free parameters from an R factor, embedded in 4x4."""
    cols = np.flatnonzero(free)
    out = np.zeros((PARAMETERS, PARAMETERS))
    if cols.size == 0:
        return out
    _, r = np.linalg.qr(r_factor[:PARAMETERS, cols])
    if np.min(np.abs(np.diag(r))) == 0.0:
        return out
    # LAPACK's triangular inverse: scipy's solve_triangular takes milliseconds for a 4x4
    r_inv, info = lapack.dtrtri(r, lower=0)
    if info != 0:
        return out
    out[np.ix_(cols, cols)] = r_inv @ r_inv.T
    return out


def _naive_covariance(lin: Linearisation, free: BoolArray) -> FloatArray:
    """``sigma^2 (J^T W J)^-1``, inflated for the residuals' autocorrelation.

    Rollout residuals are far from white (errors integrate along a segment); with lag-1
    autocorrelation rho, the residuals carry about (1 - rho) / (1 + rho) as much independent
    information as white ones, so the white-noise covariance is scaled by (1 + rho) / (1 - rho).
    """
    p = int(free.sum())
    dof = max(3 * lin.samples - p, 1)
    rho = min(max(lin.lag1, 0.0), 0.999)
    return (lin.cost / dof) * (1 + rho) / (1 - rho) * information_inverse(lin.r_factor, free)


def _robust_covariance(lin: Linearisation, free: BoolArray, clusters: IntArray) -> FloatArray:
    return robust_covariance(information_inverse(lin.r_factor, free), lin.scores, free, clusters)


def _larger(a: FloatArray, b: FloatArray) -> FloatArray:
    """``a`` with each standard deviation raised to the larger of ``a``'s and ``b``'s."""
    sa = np.sqrt(np.clip(np.diag(a), 0.0, None))
    sb = np.sqrt(np.clip(np.diag(b), 0.0, None))
    with np.errstate(divide="ignore", invalid="ignore"):
        f = np.where(sa > 0, np.maximum(sa, sb) / sa, 1.0)
    return a * np.outer(f, f)


def bootstrap_terms(rates: SegmentBatch, estimate: Estimate, clusters: IntArray,
                    settings: Settings, *, at_estimate: Linearisation | None = None,
                    **extra: Any) -> BootstrapTerms:
    """What the bootstrap resamples for a Gauss-Newton estimate on ``rates`` (the segments it
    used, with their ``clusters``): per-segment information and scores, and a refit.
    ``at_estimate``: the fit's own linearisation at the estimate (``gauss_newton(keep=...)``),
    used instead of linearising again where it is at the estimate's theta."""
    theta = estimate.theta.as_array()
    lin = (at_estimate if at_estimate is not None and np.array_equal(at_estimate.theta, theta)
           else linearise(rates, theta, np.asarray(settings.identify.weights)))
    held = {n: NotIdentified(Reason.HELD) for n, f in zip(PARAMETER_NAMES, estimate.free,
                                                         strict=True) if not f}
    loose = dataclasses.replace(settings.identify, judge_identifiability=False, max_iterations=3)

    def refit(take: IntArray) -> FloatArray:
        return gauss_newton(rates.subset(take), settings=loose, start=estimate.theta.as_array(),
                            held=held).theta.as_array()

    return BootstrapTerms(information=lin.information, scores=lin.scores, clusters=clusters,
                          refit=refit, **extra)
