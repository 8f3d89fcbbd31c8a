"""How sure a calibration is: the bootstrap over segments, checked against the covariance.

The covariance a calibration reports is cluster-robust (see :mod:`odocal.estimators.gauss_newton`):
residuals of
overlapping segments are summed into clusters, because a rollout's errors are strongly correlated
and a white-noise covariance is far too small (10 to 50 times, on simulated drives). The
bootstrap is an independent check: clusters of segments are drawn with replacement and theta is
re-estimated, by one Gauss-Newton step from the estimate (``one-step``) or by rerunning the
identification (``full``). For the three-step method the five step-1 parameter sets are also
drawn with replacement from all step-1 batches, because the compensated rates inherit them.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from odocal.arrays import BoolArray, FloatArray, IntArray
from odocal.estimators.estimate import Estimate
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
    labels, index = np.unique(clusters, return_inverse=True)
    n_clusters = labels.shape[0]
    count = settings.bootstrap_count
    samples = np.tile(theta, (count, 1))
    if free.any() and n_clusters > 1:
        draws = [np.bincount(rng.integers(0, n_clusters, n_clusters), minlength=n_clusters)
                 for _ in range(count)]
        if settings.bootstrap_mode == "full" and refit is not None:
            members = [np.flatnonzero(index == c) for c in range(n_clusters)]
            for b, w in enumerate(draws):
                take = np.concatenate([np.tile(members[c], int(k)) for c, k in enumerate(w)
                                       if k])
                samples[b] = refit(take)
        else:
            h = np.zeros((n_clusters, PARAMETERS, PARAMETERS))
            g = np.zeros((n_clusters, PARAMETERS))
            np.add.at(h, index, information)
            np.add.at(g, index, scores)
            cols = np.flatnonzero(free)
            for b, w in enumerate(draws):
                hw = np.einsum("c,cij->ij", w.astype(float), h)[np.ix_(cols, cols)]
                samples[b, cols] = theta[cols] + np.linalg.lstsq(hw, w @ g[:, cols],
                                                                 rcond=None)[0]
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
