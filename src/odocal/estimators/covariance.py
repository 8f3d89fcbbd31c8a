"""How sure a calibration is: the default method's sandwich covariance, its doubts, and the
bootstrap that checks a covariance.

* **The default method's covariance** (:func:`covariance`): a sandwich over clusters of windows
  (each cluster's score scaled by its leverage, cross products of neighbouring clusters with
  Newey and West's weights, the folded clusters' meat included), what it adds beyond the error
  model's own variance widened by Student's t for the clusters each parameter rests on; and the
  doubts the data cannot settle added to it (:func:`lateral_doubt`, :func:`doubted`).
* **The bootstrap** (:func:`bootstrap`): the covariance a calibration reports is cluster-robust
  (see :mod:`odocal.estimators.gauss_newton`): residuals of overlapping segments are summed into
  clusters, because a rollout's errors are strongly correlated and a white-noise covariance is
  far too small (10 to 50 times, on simulated drives). The bootstrap is an independent check:
  clusters of segments are drawn with replacement and theta is re-estimated, by one
  Gauss-Newton step from the estimate (``one-step``) or by rerunning the identification
  (``full``). For the three-step method the five step-1 parameter sets are also drawn with
  replacement from all step-1 batches, because the compensated rates inherit them.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from odocal.arrays import BoolArray, FloatArray, IntArray
from odocal.estimators.estimate import Estimate, tail_inflation
from odocal.estimators.fitting import (
    LAT_OFFSET,
    LAT_SCALE,
    LAYOUT,
    OFFSET,
    THETA,
    Fit,
    Folded,
    P,
)
from odocal.estimators.windows import WindowSet
from odocal.model.parameters import PARAMETER_NAMES, PARAMETERS
from odocal.settings import UncertaintySettings

#: Cross-product weights of clusters one, two and three apart: Newey and West's (Bartlett)
#: weights over three clusters, used by the default method. Where errors telescope (rounded
#: counts, a reference's errors differenced over windows) neighbouring clusters' scores nearly
#: cancel, and at full weight the long-run covariance is a difference of nearly equal terms: on
#: the reference-error profile c_d's reported std came out 4-7 times too small on 2 of 20 drives
#: (RMS z 1.97, largest |z| 6.7; with these weights 0.80 and 1.8). The taper also reaches
#: errors slower than a cluster (a smoother's output drifting over a minute).
NEWEY_WEST = (0.75, 0.5, 0.25)
#: Fewer clusters than this: a covariance is the larger of the sandwich and the residual
#: formula, widened for the clusters' small number (the default method's and the segment
#: methods' alike).
MIN_CLUSTERS_FOR_ROBUST = 10


def long_run_meat(g: FloatArray, weights: Sequence[float] = (1.0,)) -> FloatArray:
    """``sum_c g_c g_c^T`` over the rows of ``g`` (clusters in time order) plus the cross
    products of clusters ``j`` apart weighted by ``weights[j - 1]``."""
    meat = g.T @ g
    for j, w in enumerate(weights, start=1):
        if j >= g.shape[0]:
            break
        cross = w * (g[:-j].T @ g[j:])
        meat += cross + cross.T
    return meat


def added_meat(recent: FloatArray, new: FloatArray,
               weights: Sequence[float] = NEWEY_WEST) -> FloatArray:
    """What clusters ``new`` add to :func:`long_run_meat` after ``recent`` (the latest clusters
    already counted): their outer products, and their cross products with each other and with
    ``recent``. Folded cluster by cluster, it builds the batch meat exactly."""
    return long_run_meat(np.vstack([recent, new]), weights) - long_run_meat(recent, weights)


def robust_covariance(h_inv: FloatArray, scores: FloatArray, free: BoolArray,
                      clusters: IntArray, weights: Sequence[float] = (1.0,)) -> FloatArray:
    """Sandwich ``H^-1 M H^-1`` with M the long-run covariance of per-cluster scores.

    Residuals of one segment are strongly correlated (a rollout integrates its errors), and
    overlapping segments share samples, so the white-noise covariance is too small. Scores are
    summed into clusters of overlapping (or neighbouring) units, and ``M`` is the clusters'
    outer products plus the cross products of clusters up to ``len(weights)`` apart, weighted
    (default: neighbours at full weight; :data:`NEWEY_WEST` for the default method). ``M`` is
    made positive semi-definite by clipping its eigenvalues.
    """
    labels, index = np.unique(clusters, return_inverse=True)
    g = np.zeros((labels.shape[0], scores.shape[1]))
    np.add.at(g, index, scores)
    g[:, ~free] = 0.0
    g -= g.mean(axis=0)
    meat = long_run_meat(g, weights)
    if g.shape[0] > 1:
        values, vectors = np.linalg.eigh(meat)
        meat = (vectors * np.clip(values, 0.0, None)) @ vectors.T
    c = g.shape[0]
    correction = c / (c - 1) if c > 1 else 1.0
    return correction * (h_inv @ meat @ h_inv)


def leverage_adjusted_scores(information: FloatArray, scores: FloatArray, free: BoolArray,
                             clusters: IntArray, total: FloatArray | None = None
                             ) -> tuple[FloatArray, IntArray]:
    """Per-cluster scores scaled up by their leverage, for :func:`robust_covariance`.

    A cluster that carries much of a parameter's information pulls the fit towards itself, so
    its own residuals understate its errors and the plain sandwich comes out too small (the
    load-transfer term ``d`` is seen in a few hard bends only). Each cluster's score ``g`` is
    replaced by ``H (H - H_g)^-1 g``: the change of the estimate when that cluster is left out,
    in score units (the jackknife form of the CR3 correction). ``total``: the whole fit's
    information where the clusters given are part of it (default: theirs summed). Returns the
    adjusted scores, one row per cluster, and the clusters' labels in order.
    """
    labels, index = np.unique(clusters, return_inverse=True)
    p = scores.shape[1]
    h_g = np.zeros((labels.size, p, p))
    g = np.zeros((labels.size, p))
    np.add.at(h_g, index, information)
    np.add.at(g, index, scores)
    cols = np.flatnonzero(free)
    out = np.zeros_like(g)
    if cols.size == 0:
        return out, labels
    h = (h_g.sum(axis=0) if total is None else total)[np.ix_(cols, cols)]
    for k in range(labels.size):
        rest = h - h_g[k][np.ix_(cols, cols)]
        out[k, cols] = h @ np.linalg.lstsq(rest, g[k, cols], rcond=None)[0]
    return out, labels


@dataclass(frozen=True)
class BootstrapResult:
    """The bootstrap's spread and its agreement with the covariance.

    samples : ndarray, shape (B, n), theta of every resample
    std : ndarray, shape (n,), standard deviation over the resamples
    covariance_std : ndarray, shape (n,), from the reported covariance
    ratio : ndarray, shape (n,), bootstrap std over covariance std (nan where not identified)
    agree : for each parameter, whether the two are within the disagreement factor
    message : plain-words summary
    """

    mode: str
    samples: FloatArray
    std: FloatArray
    covariance_std: FloatArray
    ratio: FloatArray
    agree: tuple[bool, ...]
    message: str

    @property
    def count(self) -> int:
        return int(self.samples.shape[0])

    def to_dict(self) -> dict[str, Any]:
        return {"mode": self.mode, "count": self.count,
                "std": dict(zip(PARAMETER_NAMES, self.std.tolist(), strict=True)),
                "covariance_std": dict(zip(PARAMETER_NAMES, self.covariance_std.tolist(),
                                           strict=True)),
                "ratio": dict(zip(PARAMETER_NAMES, self.ratio.tolist(), strict=True)),
                "agree": dict(zip(PARAMETER_NAMES, self.agree, strict=True)),
                "covariance": np.cov(self.samples.T).tolist() if self.count > 1 else None,
                "message": self.message}


def bootstrap(result: Estimate, information: FloatArray, scores: FloatArray, clusters: IntArray,
              *, settings: UncertaintySettings, seed: int,
              refit: Callable[[IntArray], FloatArray] | None = None,
              step1_thetas: FloatArray | None = None, step1_sets: int = 0) -> BootstrapResult:
    """Resample clusters of units (segments or windows, and step-1 sets); re-estimate theta.

    Parameters
    ----------
    result : the estimate to check
    information : ndarray, shape (N, n, n), each unit's ``J^T W J`` at the estimate
    scores : ndarray, shape (N, n), each unit's ``J^T W R`` at the estimate
    clusters : group label per unit (units that overlap or correlate share a label)
    refit : for ``bootstrap_mode = "full"``: theta re-estimated from the units with the given
        indices (repeats allowed); one Gauss-Newton step from the estimate when None
    step1_thetas : ndarray, shape (B, n), every step-1 batch's theta (three-step method only)
    step1_sets : how many step-1 sets the compensation averaged
    """
    theta = result.theta.as_array()
    free = np.array(result.free)
    rng = np.random.default_rng(seed)
    count = settings.bootstrap_count
    samples, n_clusters = _resampled(theta, free, information, scores, clusters, count=count,
                                     rng=rng, refit=refit if settings.bootstrap_mode == "full"
                                     else None)
    if step1_thetas is not None and step1_sets > 0 and step1_thetas.shape[0] > 1:
        # the compensated rates inherit the mean of the step-1 sets: redraw those sets
        centre = step1_thetas.mean(axis=0)
        for b in range(count):
            pick = rng.integers(0, step1_thetas.shape[0], step1_sets)
            samples[b, free] += (step1_thetas[pick].mean(axis=0) - centre)[free]
    std = samples.std(axis=0, ddof=1) if count > 1 else np.zeros(PARAMETERS)
    cov_std = result.std
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(free & (cov_std > 0), std / cov_std, np.nan)
    factor = settings.disagreement_factor
    agree = tuple(bool(not f or (1 / factor <= r <= factor)) for f, r in zip(free, ratio,
                                                                              strict=True))
    off = [f"{n} (bootstrap {r:.2g}x the covariance)" for n, f, r, a in
           zip(PARAMETER_NAMES, free, ratio, agree, strict=True) if f and not a]
    if n_clusters <= 1:
        message = "one cluster of segments only: the bootstrap cannot resample; no check"
    elif off:
        message = (f"the bootstrap and the covariance disagree by more than a factor "
                   f"{factor:g} for {', '.join(off)}; trust the larger")
    else:
        message = (f"the bootstrap ({count} resamples of {n_clusters} segment clusters) agrees "
                   f"with the covariance within a factor {factor:g}")
    return BootstrapResult(mode=settings.bootstrap_mode, samples=samples, std=std,
                           covariance_std=cov_std, ratio=ratio,
                           agree=agree, message=message)


def _resampled(theta: FloatArray, free: BoolArray, information: FloatArray, scores: FloatArray,
               clusters: IntArray, *, count: int, rng: np.random.Generator,
               refit: Callable[[IntArray], FloatArray] | None) -> tuple[FloatArray, int]:
    """``count`` thetas (count, n), each from the clusters drawn with replacement: refitted by
    ``refit`` where given, else one Gauss-Newton step from ``theta``; and the clusters' number.
    With one cluster or nothing free, every sample is ``theta``."""
    labels, index = np.unique(clusters, return_inverse=True)
    n_clusters = labels.shape[0]
    samples = np.tile(theta, (count, 1))
    if not free.any() or n_clusters <= 1:
        return samples, n_clusters
    draws = [np.bincount(rng.integers(0, n_clusters, n_clusters), minlength=n_clusters)
             for _ in range(count)]
    if refit is not None:
        members = [np.flatnonzero(index == c) for c in range(n_clusters)]
        for b, w in enumerate(draws):
            take = np.concatenate([np.tile(members[c], int(k)) for c, k in enumerate(w) if k])
            samples[b] = refit(take)
        return samples, n_clusters
    h = np.zeros((n_clusters, PARAMETERS, PARAMETERS))
    g = np.zeros((n_clusters, PARAMETERS))
    np.add.at(h, index, information)
    np.add.at(g, index, scores)
    cols = np.flatnonzero(free)
    for b, w in enumerate(draws):
        hw = np.einsum("c,cij->ij", w.astype(float), h)[np.ix_(cols, cols)]
        samples[b, cols] = theta[cols] + np.linalg.lstsq(hw, w @ g[:, cols], rcond=None)[0]
    return samples, n_clusters


def lateral_doubt(found: Uncertainty, p: FloatArray, free: BoolArray) -> Uncertainty:
    """theta is for a_y as logged. Where a_y departs from the reference's ``v w`` (an offset
    ``o``, a scale ``1 + s``), that is a road's crossfall or a body's roll the tyres feel, or an
    IMU's tilt or scale they do not: the two cannot be told apart, and the sensor's reading
    would make c_d ``2 d o / (1 + s)`` and d ``d s / (1 + s)`` other than they are. That much is
    added to their variance (zero where a_y holds to ``v w``)."""
    offset, scale = float(p[LAT_OFFSET]), float(p[LAT_SCALE])
    if not (offset or scale):
        return found
    i_d, i_l = LAYOUT.index(LAYOUT.difference), LAYOUT.index(LAYOUT.load)
    d = float(p[i_l])
    extra = np.zeros(LAYOUT.size)
    extra[i_d] = 2.0 * d * offset / (1.0 + scale)
    extra[i_l] = d * scale / (1.0 + scale)
    extra[~np.asarray(free, dtype=bool)] = 0.0
    return doubted(found, extra)


def doubted(found: Uncertainty, shift: FloatArray) -> Uncertainty:
    """``found`` with ``shift`` (n,), what a cause the data cannot tell would move theta by,
    squared into theta's variance (its widening and p's standard deviations with it)."""
    cov = found.covariance + np.diag(shift ** 2)
    before = np.sqrt(np.clip(np.diag(found.covariance), 0.0, None))
    after = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    with np.errstate(divide="ignore", invalid="ignore"):
        widening = found.widening * np.where(before > 0, after / before, 1.0)
    p_std = found.p_std.copy()
    p_std[THETA] = after
    return dataclasses.replace(found, covariance=cov, widening=widening, p_std=p_std)


@dataclass(frozen=True)
class Uncertainty:
    """The covariance of theta (n, n), the clusters it rests on, each window's information
    (W, n, n) and score (W, n), how much each standard deviation was widened for the
    parameters held at their datasheet values (1: not), the wheel-rate offset's standard
    deviation (rev/s; zero where not fitted) and every element of p's (P,)."""

    covariance: FloatArray
    clusters: int
    information: FloatArray
    scores: FloatArray
    widening: FloatArray
    offset_std: float = 0.0
    p_std: FloatArray = field(default_factory=lambda: np.zeros(P))
    p_cov: FloatArray = field(default_factory=lambda: np.zeros((P, P)))


def covariance(current: Fit, windows: WindowSet, folded: Folded, free: BoolArray,
               nuisance: FloatArray | None = None, *, few: bool = True) -> Uncertainty:
    """Sandwich covariance of p over clusters of windows (folded clusters' meat included),
    from the prewhitened rows, each cluster's score scaled by its leverage, cross products of
    clusters up to three apart with Newey and West's weights; theta's block is the one
    reported (the departures fitted beside it profiled out: their uncertainty is in it). What
    it adds beyond the residual-variance formula is widened by Student's t for the clusters
    each parameter's information comes from (with fewer than :data:`MIN_CLUSTERS_FOR_ROBUST`
    clusters in all, the larger of the two).

    ``few`` False leaves the widening for few clusters out (what a departure's own value is
    judged by: whether the fit determines it, not how far a rare error reaches).

    ``nuisance`` (n,): the datasheet uncertainty of each parameter held at its datasheet value
    (0 for the free ones). A held parameter that is wrong by that much moves the free ones by
    ``-H_ff^-1 H_fj`` times it: that spread is added, so a free parameter that cannot be told
    apart from a held one (a circle at one rate, a missing a_y) carries its uncertainty.
    """
    jw, rw = current.white[..., 1:], current.white[..., 0]
    info = np.einsum("wcp,wcq->wpq", jw, jw)
    scores = np.einsum("wcp,wc->wp", jw, rw)
    h = info.sum(axis=0) + folded.h
    cols = np.flatnonzero(free)
    h_inv = np.zeros((P, P))
    if cols.size:
        h_inv[np.ix_(cols, cols)] = np.linalg.pinv(h[np.ix_(cols, cols)])
    cov, clusters = _sandwich(info, scores, h, h_inv, windows, folded, free)
    # the residual-variance (model-based) covariance: the error model's, from every row that
    # counts in the cost
    count = int(np.count_nonzero(current.white[..., 0])) + folded.count
    naive = (current.cost + folded.cost) / max(count - int(free.sum()), 1) * h_inv
    effective = _effective_clusters(info, windows.cluster, folded, h_inv) if windows.size \
        else np.full(P, float(clusters))
    cov = widened(cov, naive, effective, clusters, few=few)
    base = np.sqrt(np.clip(np.diag(cov)[THETA], 0.0, None))
    if nuisance is not None:
        for j in np.flatnonzero(nuisance > 0):
            shift = -h_inv @ h[:, j]                   # d p_free / d theta_j (held)
            cov = cov + nuisance[j] ** 2 * np.outer(shift, shift)
    std = np.sqrt(np.clip(np.diag(cov)[THETA], 0.0, None))
    with np.errstate(divide="ignore", invalid="ignore"):
        widening = np.where(base > 0, std / base, 1.0)
    p_std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return Uncertainty(cov[THETA, THETA], clusters, info[:, THETA, THETA], scores[:, THETA],
                       widening, float(p_std[OFFSET]), p_std, cov)


def _sandwich(info: FloatArray, scores: FloatArray, h: FloatArray, h_inv: FloatArray,
              windows: WindowSet, folded: Folded, free: BoolArray) -> tuple[FloatArray, int]:
    """The cluster-robust covariance of p (P, P), ``H^-1 meat H^-1`` with the windows' clusters'
    leverage-scaled scores and the folded meat, small-sample corrected; and the clusters."""
    meat = folded.meat.copy()
    clusters = folded.clusters
    if windows.size:
        adjusted, labels = leverage_adjusted_scores(info, scores, free, windows.cluster, total=h)
        clusters += labels.size
        meat += added_meat(folded.recent, adjusted)
    meat[~free, :] = 0.0
    meat[:, ~free] = 0.0
    values, vectors = np.linalg.eigh(meat)
    meat = (vectors * np.clip(values, 0.0, None)) @ vectors.T
    correction = clusters / (clusters - 1) if clusters > 1 else 1.0
    return correction * (h_inv @ meat @ h_inv), clusters


def widened(cov: FloatArray, naive: FloatArray, effective: FloatArray, clusters: int, *,
             few: bool) -> FloatArray:
    """The sandwich ``cov`` scaled so that what it adds beyond the model-based ``naive`` is
    widened by Student's t for the ``effective`` clusters each element rests on."""
    s_n = np.sqrt(np.clip(np.diag(naive), 0.0, None))
    s_r = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    # The sandwich is needed where the errors are not what the error model says (correlated
    # over seconds, a reference's own): what it adds beyond the model-based variance rests on
    # the clusters the parameter's information comes from, few for t_r and d on a short drive
    # (Satterthwaite's effective number; t_r's from the few clusters with bends), so it is
    # widened by Student's t at the three-sigma tail for them. Where the two agree the error
    # model holds, and its variance, from every window, needs no widening. With fewer than
    # MIN_CLUSTERS_FOR_ROBUST clusters the larger of the two is taken as it stands.
    f = np.array([tail_inflation(max(float(e), 2.0)) if e > 0 else 1.0 for e in effective])
    if clusters < 2 or not few:
        f[:] = 1.0                # one cluster: the one-cluster rule leaves nothing identified
    with np.errstate(divide="ignore", invalid="ignore"):
        if clusters < MIN_CLUSTERS_FOR_ROBUST:
            target = np.maximum(s_n, s_r) * f
        else:
            target = np.sqrt(s_n ** 2 + f ** 2 * np.clip(s_r ** 2 - s_n ** 2, 0.0, None))
        scale = np.where(s_r > 0, target / s_r, 1.0)
    return np.asarray(cov * np.outer(scale, scale))


def _effective_clusters(info: FloatArray, cluster: IntArray, folded: Folded,
                        h_inv: FloatArray) -> FloatArray:
    """Per element of p, the effective number of independent clusters its variance rests on:
    ``(sum_k e_k)^2 / sum_k e_k^2`` with ``e_k`` the share of cluster k's information in it
    (``(H^-1 I_k H^-1)_jj``); folded clusters count as equal shares of the folded information.
    One cluster that carries it all counts one; many equal ones count as many."""
    labels, index = np.unique(cluster, return_inverse=True)
    per = np.zeros((labels.size, P, P))
    np.add.at(per, index, info)
    shares = np.einsum("ip,kpq,iq->ki", h_inv, per, h_inv)          # (K, P): e_k per element
    total = shares.sum(axis=0)
    squares = (shares ** 2).sum(axis=0)
    if folded.clusters:
        folded_share = np.einsum("ip,pq,iq->i", h_inv, folded.h, h_inv)
        total = total + folded_share
        squares = squares + folded_share ** 2 / folded.clusters
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(squares > 0, total ** 2 / squares, 0.0)
