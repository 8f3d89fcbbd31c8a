"""METHOD 3: Gauss-Newton identification of theta from segments (pure and batch).

Minimises ``V(theta) = sum_k (y~_k - y^_k)^T W (y~_k - y^_k)`` over the segments of a batch
(one segment: *pure* G-N; several: *batch* G-N, their J and R stacked). Each iteration solves the
weighted linear least-squares problem (7)-(8) by QR (a tall-skinny QR accumulated chunk by chunk, so
memory stays bounded on long drives), iterating while the cost decreases, at most ``i_max`` times.
A step that would raise the cost is halved until it does not (up to ten times) before the
iteration stops; near the solution the full step is always taken, so this only guards the first
steps from a poor initial guess.

Parameters the data cannot identify are found two ways and kept at their initial values:
numerically (the scaled normal equations are rank deficient, e.g. no bends at all) and
statistically (the data's standard deviation of a parameter is not much smaller than the datasheet
uncertainty ``prior_std``). They are named in the result, never silently estimated.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import qr, solve_triangular

from odocal.model import PARAMETER_NAMES, Parameters, pose_residuals, rollout_with_jacobian
from odocal.segments import SegmentBatch
from odocal.settings import IdentifySettings

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
log = logging.getLogger(__name__)

_CHUNK_SEGMENTS = 128
_MIN_CLUSTERS_FOR_ROBUST = 10
_MAX_HALVINGS = 10


@dataclass(frozen=True)
class Linearisation:
    """The weighted least-squares problem of one G-N iteration at ``theta``.

    cost : V(theta)
    r_factor : ndarray, shape (5, 5)
        Upper-triangular R of the QR factorisation of ``[sqrt(W) J | sqrt(W) R]``.
    scores : ndarray, shape (N, 4)
        Per-segment ``J_s^T W R_s``.
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
    scores: FloatArray
    residual_ss: FloatArray
    samples: int
    lag1: float


def _weighted_chunks(batch: SegmentBatch, theta: FloatArray, weights: FloatArray,
                     ) -> Iterator[tuple[int, FloatArray, FloatArray, FloatArray]]:
    """Per chunk of segments: (first index, sqrt(W) J (n, K, 3, 4), sqrt(W) R (n, K, 3), R)."""
    sqrt_w = np.sqrt(np.asarray(weights, dtype=np.float64))
    for lo in range(0, len(batch), _CHUNK_SEGMENTS):
        part = batch.take(slice(lo, lo + _CHUNK_SEGMENTS))
        poses, jac = rollout_with_jacobian(theta, part.inputs, part.reference[:, 0], batch.t_s)
        r = pose_residuals(part.reference[:, 1:], poses[:, 1:])          # (n, K, 3)
        yield lo, jac[:, 1:] * sqrt_w[:, None], r * sqrt_w, r


def linearise(batch: SegmentBatch, theta: FloatArray, weights: FloatArray) -> Linearisation:
    """Residuals and Jacobians of every segment at ``theta``, reduced to a 5x5 R factor."""
    n = len(batch)
    scores = np.empty((n, 4))
    residual_ss = np.zeros(3)
    stacked: list[FloatArray] = []
    cost = 0.0
    lagged = 0.0
    for lo, a, rw, r in _weighted_chunks(batch, theta, weights):
        residual_ss += np.einsum("nki,nki->i", r, r)
        centred = rw - rw.mean(axis=1, keepdims=True)
        lagged += float(np.einsum("nki,nki->", centred[:, 1:], centred[:, :-1]))
        cost += float(np.einsum("nki,nki->", rw, rw))
        scores[lo:lo + a.shape[0]] = np.einsum("nkij,nki->nj", a, rw)
        # [A | r] in Fortran order, so that LAPACK factorises it in place
        block = np.empty((rw.size, 5), order="F")
        block[:, :4] = a.reshape(-1, 4)
        block[:, 4] = rw.ravel()
        stacked.append(qr(block, mode="r", check_finite=False, overwrite_a=True)[0][:5])
    r_factor = stacked[0] if len(stacked) == 1 else qr(np.concatenate(stacked), mode="r",
                                                       check_finite=False)[0][:5]
    if r_factor.shape[0] < 5:  # fewer rows than columns (a degenerate, tiny batch)
        r_factor = np.vstack([r_factor, np.zeros((5 - r_factor.shape[0], 5))])
    return Linearisation(theta=np.asarray(theta, dtype=np.float64).copy(), cost=cost,
                         r_factor=r_factor, scores=scores, residual_ss=residual_ss,
                         samples=n * batch.steps, lag1=lagged / cost if cost > 0 else 0.0)


def segment_information(batch: SegmentBatch, theta: FloatArray,
                        weights: FloatArray) -> FloatArray:
    """Per-segment ``J_s^T W J_s`` at ``theta``, shape (N, 4, 4) (for bootstrap and diagnostics)."""
    out = np.empty((len(batch), 4, 4))
    for lo, a, _, _ in _weighted_chunks(batch, theta, weights):
        out[lo:lo + a.shape[0]] = np.einsum("nkij,nkil->njl", a, a)
    return out


@dataclass(frozen=True)
class IdentificationResult:
    """The outcome of a Gauss-Newton identification.

    theta : the identified parameters (unidentified ones keep their datasheet values)
    theta0 : the datasheet values
    success : False when the iteration could not improve on the initial guess or broke down
    message : why the iteration stopped
    iterations : accepted G-N steps
    cost_history : V at the initial guess and after each accepted step
    identified : for each of c_e, c_d, t_r, d, whether the data identified it
    reasons : for each unidentified parameter, why (plain words)
    covariance : ndarray, shape (4, 4)
        Parameter covariance (zero rows and columns for unidentified parameters); cluster-robust
        over groups of non-overlapping segments when there are enough groups, else from the
        residual variance (see ``covariance_kind``).
    covariance_naive : ndarray, shape (4, 4)
        ``sigma^2 (J^T W J)^-1`` with ``sigma^2 = V / (m - p)``, inflated by (1 + rho) / (1 - rho)
        for the residuals' lag-1 autocorrelation rho.
    segments : number of segments identified from
    residual_rms : RMS of the p_x, p_y (m) and psi (rad) residuals at the final theta
    segment_scores : per-segment ``J^T W R`` at the final theta
    """

    theta: Parameters
    theta0: Parameters
    success: bool
    message: str
    iterations: int
    cost_history: tuple[float, ...]
    identified: tuple[bool, bool, bool, bool]
    reasons: dict[str, str]
    covariance: FloatArray
    covariance_kind: str
    covariance_naive: FloatArray
    segments: int
    residual_rms: tuple[float, float, float]
    segment_scores: FloatArray = field(repr=False)

    @property
    def std(self) -> FloatArray:
        """Standard deviations of c_e, c_d, t_r, d from ``covariance``."""
        return np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))

    @property
    def unidentified(self) -> tuple[str, ...]:
        return tuple(n for n, ok in zip(PARAMETER_NAMES, self.identified, strict=True) if not ok)

    def to_dict(self) -> dict[str, object]:
        return {
            "success": self.success,
            "message": self.message,
            "iterations": self.iterations,
            "cost_history": list(self.cost_history),
            "identified": dict(zip(PARAMETER_NAMES, self.identified, strict=True)),
            "unidentified_reasons": dict(self.reasons),
            "covariance": self.covariance.tolist(),
            "covariance_kind": self.covariance_kind,
            "covariance_naive": self.covariance_naive.tolist(),
            "std": dict(zip(PARAMETER_NAMES, self.std.tolist(), strict=True)),
            "segments": self.segments,
            "residual_rms": {"p_x_m": self.residual_rms[0], "p_y_m": self.residual_rms[1],
                             "psi_rad": self.residual_rms[2]},
        }


def gauss_newton(batch: SegmentBatch, *, settings: IdentifySettings,
                 start: FloatArray | None = None, clusters: IntArray | None = None,
                 fixed: Mapping[str, str] | None = None) -> IdentificationResult:
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
    fixed : parameters to keep at their datasheet values regardless of the data, with the
        reason (reported with the result)
    """
    datasheet = np.asarray(settings.theta0, dtype=np.float64)
    theta_init = datasheet.copy() if start is None else np.asarray(start, dtype=np.float64)
    weights = np.asarray(settings.weights, dtype=np.float64)
    prior = np.asarray(settings.prior_std, dtype=np.float64)
    fixed = dict(fixed or {})
    free = np.array([name not in fixed for name in PARAMETER_NAMES])
    reasons = dict(fixed)
    if clusters is None:
        clusters = np.arange(len(batch), dtype=np.int64)

    theta_init[~free] = datasheet[~free]
    lin0 = linearise(batch, theta_init, weights)
    numeric_free, why = _numerically_free(lin0.r_factor, prior, settings.rcond, free)
    reasons.update(why)
    if not np.array_equal(numeric_free, free):
        free = numeric_free
        theta_init[~free] = datasheet[~free]
        lin0 = linearise(batch, theta_init, weights)

    while True:
        theta, lin, history, iterations, success, message = _iterate(
            batch, theta_init, lin0, free, weights, settings)
        cov_naive = _naive_covariance(lin, free)
        cov_robust = _robust_covariance(lin, free, clusters)
        n_clusters = int(np.unique(clusters).shape[0])
        if n_clusters >= _MIN_CLUSTERS_FOR_ROBUST:
            cov, kind = cov_robust, "cluster-robust"
        else:
            cov, kind = cov_naive, "residual (autocorrelation-corrected)"
        std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        weak = free & (std > settings.identifiable_ratio * prior)
        if not settings.judge_identifiability:
            weak[:] = False
        if not weak.any() or not _settled(history, message, settings):
            # before the iteration settles, residuals measure the misfit of the estimate, not
            # the noise, and say nothing about what the data can identify
            break
        for j in np.flatnonzero(weak):
            name = PARAMETER_NAMES[j]
            reasons[name] = (f"the data determine {name} only to +-{std[j]:.3g} "
                             f"(datasheet uncertainty {prior[j]:.3g}); kept at the datasheet "
                             f"value {datasheet[j]:.6g}")
        free = free & ~weak
        theta_init = theta.copy()
        theta_init[~free] = datasheet[~free]
        if not free.any():
            lin = linearise(batch, theta_init, weights)
            theta, history = theta_init, [lin.cost]
            iterations, success = 0, False
            message = "no parameter is identifiable from these segments"
            cov = cov_naive = np.zeros((4, 4))
            kind = "residual (autocorrelation-corrected)"
            break
        lin0 = linearise(batch, theta_init, weights)

    rms = np.sqrt(lin.residual_ss / max(lin.samples, 1))
    if not success:
        log.warning("identification: %s", message)
    return IdentificationResult(
        theta=Parameters.from_array(theta), theta0=Parameters.from_array(datasheet),
        success=success, message=message, iterations=iterations,
        cost_history=tuple(history), identified=tuple(bool(f) for f in free),  # type: ignore[arg-type]
        reasons=reasons, covariance=cov, covariance_kind=kind, covariance_naive=cov_naive,
        segments=len(batch), residual_rms=(float(rms[0]), float(rms[1]), float(rms[2])),
        segment_scores=lin.scores)


def _iterate(batch: SegmentBatch, theta_init: FloatArray, lin0: Linearisation,
             free: NDArray[np.bool_], weights: FloatArray, settings: IdentifySettings,
             ) -> tuple[FloatArray, Linearisation, list[float], int, bool, str]:
    """G-N iterations (8) on the free parameters, from ``theta_init``."""
    theta, lin = theta_init.copy(), lin0
    history = [lin.cost]
    scale = np.maximum(np.abs(theta_init), np.asarray(settings.prior_std))
    message = f"reached the iteration limit i_max = {settings.max_iterations}"
    iterations = 0
    for _ in range(settings.max_iterations):
        delta = np.zeros(4)
        delta[free] = _solve_step(lin.r_factor, free)
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
            message = "the cost no longer decreases"
            break
        theta, lin = theta + delta, trial
        history.append(lin.cost)
        iterations += 1
        if np.max(np.abs(delta) / scale) < settings.step_tolerance:
            message = "converged (the step is below the tolerance)"
            break
    success = iterations > 0 or lin.cost == 0.0
    if not success:
        message = f"could not improve on the initial guess: {message}"
    return theta, lin, history, iterations, success, message


def _settled(history: list[float], message: str, settings: IdentifySettings) -> bool:
    """Whether the iteration reached a minimum rather than stopping on the iteration limit."""
    if len(history) < 2:
        return False
    if not message.startswith("reached the iteration limit"):
        return True
    return history[-2] - history[-1] <= 1e-3 * history[-1]


def _solve_step(r_factor: FloatArray, free: NDArray[np.bool_]) -> FloatArray:
    """Least-squares step of the free parameters from the R factor of ``[A | r]``.

    Since ``[A | r] = Q R``, ``min ||A_F d - r||`` equals ``min ||R[:, F] d - R[:, 4]||``.
    """
    cols = np.flatnonzero(free)
    step, *_ = np.linalg.lstsq(r_factor[:, cols], r_factor[:, 4], rcond=None)
    return np.asarray(step)


def _numerically_free(r_factor: FloatArray, prior: FloatArray, rcond: float,
                      free: NDArray[np.bool_]) -> tuple[NDArray[np.bool_], dict[str, str]]:
    """Drop parameters until the scaled normal equations of the rest have full rank."""
    free = free.copy()
    reasons: dict[str, str] = {}
    while free.any():
        cols = np.flatnonzero(free)
        a = r_factor[:4, cols] * prior[cols]          # columns in units of the prior std
        _, s, vt = np.linalg.svd(a)
        s_max = s[0] if s.size else 0.0
        if s_max > 0 and s[-1] > rcond * s_max:
            break
        worst = cols[int(np.argmax(np.abs(vt[-1])))] if s_max > 0 else cols[0]
        name = PARAMETER_NAMES[worst]
        reasons[name] = (f"these segments carry no information on {name} (rank-deficient "
                         "normal equations); kept at the datasheet value")
        free[worst] = False
    return free, reasons


def _information_inverse(lin: Linearisation, free: NDArray[np.bool_]) -> FloatArray:
    """(J^T W J)^-1 of the free parameters from the R factor, embedded in 4x4."""
    cols = np.flatnonzero(free)
    out = np.zeros((4, 4))
    if cols.size == 0:
        return out
    _, r = np.linalg.qr(lin.r_factor[:4, cols])
    if np.min(np.abs(np.diag(r))) == 0.0:
        return out
    r_inv = solve_triangular(r, np.eye(cols.size))
    out[np.ix_(cols, cols)] = r_inv @ r_inv.T
    return out


def _naive_covariance(lin: Linearisation, free: NDArray[np.bool_]) -> FloatArray:
    """``sigma^2 (J^T W J)^-1``, inflated for the residuals' autocorrelation.

    Rollout residuals are far from white (errors integrate along a segment); with lag-1
    autocorrelation rho, the residuals carry about (1 - rho) / (1 + rho) as much independent
    information as white ones, so the white-noise covariance is scaled by (1 + rho) / (1 - rho).
    """
    p = int(free.sum())
    dof = max(3 * lin.samples - p, 1)
    rho = min(max(lin.lag1, 0.0), 0.999)
    return (lin.cost / dof) * (1 + rho) / (1 - rho) * _information_inverse(lin, free)


def _robust_covariance(lin: Linearisation, free: NDArray[np.bool_],
                       clusters: IntArray) -> FloatArray:
    """Sandwich ``H^-1 M H^-1`` with M the outer products of per-cluster scores.

    Residuals of one segment are strongly correlated (a rollout integrates its errors), and
    overlapping segments share samples, so the white-noise covariance is too small. Summing the
    scores of overlapping segments into clusters and adding the Bartlett-weighted products of
    neighbouring clusters gives a covariance that holds under that correlation.
    """
    h_inv = _information_inverse(lin, free)
    labels, index = np.unique(clusters, return_inverse=True)
    g = np.zeros((labels.shape[0], 4))
    np.add.at(g, index, lin.scores)
    g[:, ~free] = 0.0
    g -= g.mean(axis=0)
    meat = g.T @ g
    if g.shape[0] > 1:
        cross = g[:-1].T @ g[1:]
        meat += 0.5 * (cross + cross.T)
    c = g.shape[0]
    correction = c / (c - 1) if c > 1 else 1.0
    return correction * (h_inv @ meat @ h_inv)
