"""The default method's core, for batch and live alike: one procedure over a window set.

The windows (:mod:`odocal.estimators.windows`) predict their revolutions for any theta; this
module fits them. Batch calibration hands it every window of the drives and nothing folded;
the online calibrator hands it the windows in memory and the older ones folded into sums
(:class:`Folded`): normal equations linearised at the estimate of their time, the clusters'
scores for the covariance, and the error model's sums. With nothing folded, the two are the
same computation, to the last digit.

The procedure (:func:`fit`):

1. Gauss-Newton on the windows' channel residuals (distance and yaw), weighted by the error
   model and prewhitened (:mod:`odocal.estimators.error_model`), from the datasheet values;
   ``p = [theta, kappa, o]``, with ``kappa`` the spread of the window the wheel unit counts its
   ticks over (half its variance, steps^2; fitted with the lag) and ``o`` a constant offset of
   both wheel rates while moving (rev/s: a biased speed signal, or rates truncated towards zero
   by their encoding), held near zero by a prior (``[inverse] wheel_offset_prior_revps``) that
   the data overrule where they determine it. (An offset of one wheel alone would be a c_d at
   one speed: left to c_d.)
2. **The lag.** A wheel stream that lags the reference biases the yaw terms in every bend. The
   yaw channel's cost is scanned over a half-step grid of shifts of the reference side (which
   carries no wheel noise), the minimum refined by a parabola. It is applied only where the data
   determine it: beyond three standard deviations of zero, and only if it holds out, i.e. the
   lag found on either half of the clusters (alternate ones) lowers the other half's cost too.
   theta is refitted at the lag and the scan repeated until the lag settles.
3. The error model refitted twice at each lag; then the covariance, a sandwich over clusters of
   windows (Newey-West weights on neighbours, each cluster's score scaled by its leverage), and
   the identifiability verdict: parameters the data do not determine well enough keep their
   datasheet values and are named, and the rest is refitted.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from odocal.estimators.covariance import NEWEY_WEST, added_meat, leverage_adjusted_scores
from odocal.estimators.error_model import (
    CHANNELS,
    ErrorModel,
    arma_from_sums,
    correlation_sums,
    coupling_from_sums,
    coupling_gain,
    coupling_moments,
    coupling_sums,
    coupling_sums_at,
    decouple,
    noise_from_sums,
    noise_sums,
    prewhiten,
    window_weights,
)
from odocal.estimators.estimate import (
    NotIdentified,
    Reason,
    hold_unidentified,
    numerically_free,
    tail_inflation,
)
from odocal.estimators.windows import AT_MOVING, WindowSet
from odocal.model.vehicle import MODEL
from odocal.settings import Settings

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]
log = logging.getLogger(__name__)

#: The layout of p: theta, the counting window's spread kappa, the wheel-rate offset.
LAYOUT = MODEL.layout
THETA = slice(0, LAYOUT.size)
KAPPA = LAYOUT.size
OFFSET = KAPPA + 1
P = KAPPA + 2
#: Fewer clusters than this: the covariance is the larger of the sandwich and the residual
#: formula, widened for the clusters' small number.
MIN_CLUSTERS_FOR_ROBUST = 10
_SHIFT_ROUNDS = 6         # the lag scanned and theta refitted in turn at most so often
_SHIFT_SETTLED = 1e-3     # steps
_LAG_SIGMAS = 3.0         # a lag within this many standard deviations of zero is not applied
#: The parameters that act through the wheels' difference, in p.
_DIFFERENTIAL = np.array(LAYOUT.indices(LAYOUT.differential))
#: Why a held parameter is known (its datasheet value is taken as exact): held on request.
#: Every other held parameter is uncertain by its datasheet uncertainty, which widens the free
#: ones as far as the data cannot tell them apart (:func:`covariance`).
_KNOWN = (Reason.HELD,)


def pack(theta: FloatArray, kappa: float = 0.0, offset: float = 0.0) -> FloatArray:
    """p from its parts (see the module docstring)."""
    p = np.zeros(P)
    p[THETA], p[KAPPA], p[OFFSET] = theta, kappa, offset
    return p


def free_of(theta_free: BoolArray, *, kappa: bool, offset: bool = False) -> BoolArray:
    """Which elements of p are fitted, from theta's and the nuisance parameters'."""
    return np.concatenate([np.asarray(theta_free, dtype=bool), [kappa, offset]])


@dataclass(frozen=True)
class Folded:
    """Windows folded into sums (the online calibrator's older evidence); empty in batch.

    h, b : normal equations in information form (``b = g0 + H0 p_lin``)
    meat, recent : the sandwich's long-run covariance of cluster scores, and the latest folded
        clusters' scores (as many as its cross products reach)
    clusters : clusters folded
    noise, coupling, correlation : the error model's sums (see
        :func:`~odocal.estimators.error_model.noise_sums`,
        :func:`~odocal.estimators.error_model.coupling_moments` about ``origin``,
        :func:`~odocal.estimators.error_model.correlation_sums`)
    scan : (2, G) the yaw channel's cost on the lag grid, per half of the clusters, or None
    cost, count : the weighted sum of squared residuals and their number
    last : the last folded window, for the prewhitening to run on: the p it was linearised at,
        its row unfiltered and filtered ((2, 1 + P) each: residual, Jacobian)
    peak_yaw_radps : the largest window yaw rate folded
    offset_std : the wheel-rate offset's prior standard deviation (rev/s; 0: not fitted)
    """

    origin: FloatArray
    h: FloatArray = field(default_factory=lambda: np.zeros((P, P)))
    b: FloatArray = field(default_factory=lambda: np.zeros(P))
    meat: FloatArray = field(default_factory=lambda: np.zeros((P, P)))
    recent: FloatArray = field(default_factory=lambda: np.zeros((0, P)))
    clusters: int = 0
    noise: FloatArray = field(default_factory=lambda: np.zeros((2, 5)))
    coupling: FloatArray = field(default_factory=lambda: np.zeros((2, 1 + P, 1 + P)))
    correlation: FloatArray = field(default_factory=lambda: np.zeros((2, 6)))
    scan: FloatArray | None = None
    cost: float = 0.0
    count: int = 0
    last: tuple[FloatArray, FloatArray, FloatArray] | None = None
    peak_yaw_radps: float = 0.0
    offset_std: float = 0.0

    @staticmethod
    def prior(origin: FloatArray, offset_std: float) -> Folded:
        """Nothing folded yet but the wheel-rate offset's prior (zero mean, ``offset_std``
        rev/s; 0: the offset is not fitted): information in h, and as much in the meat (a prior
        observation's score varies as much as it informs), so an offset the data do not
        determine keeps the prior's spread and passes it on to c_e."""
        precision = np.zeros(P)
        if offset_std > 0:
            precision[OFFSET] = offset_std ** -2.0
        return Folded(origin=np.asarray(origin, dtype=np.float64), h=np.diag(precision),
                      meat=np.diag(precision), offset_std=max(offset_std, 0.0))

    @property
    def offset_free(self) -> bool:
        """Whether the wheel-rate offset is fitted (it has a prior)."""
        return self.offset_std > 0

    def decayed(self, factor: float) -> Folded:
        """The sums with older evidence faded by ``factor`` (forgetting)."""
        return dataclasses.replace(
            self, h=self.h * factor, b=self.b * factor, meat=self.meat * factor,
            recent=self.recent * math.sqrt(factor), noise=self.noise * factor,
            coupling=self.coupling * factor, correlation=self.correlation * factor,
            scan=None if self.scan is None else self.scan * factor, cost=self.cost * factor)


@dataclass(frozen=True)
class View:
    """The windows as the model takes them at one shift and heading offset."""

    windows: WindowSet
    shift: float
    at: FloatArray          # (W, 2 SERIES)
    second: FloatArray      # (W, 2 SERIES): the moments' second difference in the shift

    @staticmethod
    def of(windows: WindowSet, shift: float, heading_offset: float) -> View:
        at, second = windows.at(shift, heading_offset)
        return View(windows, shift, at, second)


@dataclass(frozen=True)
class Fit:
    """The windows' residuals at ``p`` and what Gauss-Newton needs of them.

    residual : (W, 2) channel residuals, before the common wheel error is taken out
    jac : (W, 2, P) their Jacobian in p
    weight : (W, 2) the error model's weights
    stacked, white : (W, 2, 1 + P) the standardised rows ``[residual, Jacobian]``, before and
        after prewhitening
    cost : the weighted sum of squares of the windows (the folded ones' is in Folded.cost)
    """

    p: FloatArray
    residual: FloatArray
    jac: FloatArray
    weight: FloatArray
    stacked: FloatArray
    white: FloatArray
    cost: float
    iterations: int = 0
    history: tuple[float, ...] = ()

    @property
    def decoupled(self) -> FloatArray:
        """(W, 2): the standardised residuals, the common wheel error taken out."""
        return np.asarray(self.stacked[..., 0] / np.sqrt(np.maximum(self.weight, 1e-300)))

    def normal_equations(self, folded: Folded) -> tuple[FloatArray, FloatArray]:
        """``H`` and ``g`` of the step, windows and folded sums together."""
        jj, rr = self.white[..., 1:], self.white[..., 0]
        rows, res = jj.reshape(-1, jj.shape[-1]), rr.reshape(-1)
        h = rows.T @ rows + folded.h
        g = rows.T @ res + folded.b - folded.h @ self.p
        return h, g


def _channels(per_wheel: FloatArray) -> FloatArray:
    """(W, 2, ...) per wheel -> per channel: the wheels' mean (distance) and their difference
    (yaw), as :data:`~odocal.estimators.error_model.CHANNELS` says."""
    left, right = per_wheel[:, 0], per_wheel[:, 1]
    return np.stack([0.5 * (left + right), right - left], axis=1)


def evaluate(p: FloatArray, view: View, model: ErrorModel, folded: Folded,
             channels: FloatArray, *, smooth: bool, unseen_d: bool = False) -> Fit:
    """Residuals, weights and prewhitened rows of every window at ``p``. ``unseen_d``: the a_y
    column carries no lateral acceleration, so d's Jacobian is taken with the reference's own
    (``v w``): what a load transfer the data cannot show would do (d is held, its datasheet
    uncertainty widens the others')."""
    win = view.windows
    theta = p[THETA]
    pred, jac4 = MODEL.predict(theta, view.at)
    if unseen_d:
        jac4[..., LAYOUT.index(LAYOUT.load)] = MODEL.load_transfer_column(theta, view.at)
    spread = np.zeros_like(pred)
    if smooth:
        spread, _ = MODEL.predict(theta, view.second)
        pred = pred + p[KAPPA] * spread
    # the offset: each wheel reads o more for every second it moves
    moving = np.repeat(view.at[:, AT_MOVING, None], 2, axis=1)                  # (W, 2)
    pred = pred + p[OFFSET] * moving
    jac = np.concatenate([jac4, spread[..., None], moving[..., None]], axis=2)
    r = (win.measured - pred) @ CHANNELS.T
    j = _channels(jac)
    gain = coupling_gain(win.measured, r, model.coupling)
    w = window_weights(win.measured, r, model.noise, gain) * channels * win.weight[:, None]
    stacked = decouple(np.concatenate([r[..., None], j], axis=2), gain) * np.sqrt(w)[..., None]
    before = None
    if folded.last is not None:
        # the filter runs on from the last folded window, moved to p to first order
        moved = p - folded.last[0]
        before = tuple(row - np.concatenate([(row[:, 1:] @ moved)[:, None],
                                             np.zeros_like(row[:, 1:])], axis=1)
                       for row in folded.last[1:])
    white = prewhiten(stacked, win.follows, model.ma, before)
    return Fit(p=p, residual=r, jac=j, weight=w, stacked=stacked, white=white,
               cost=float(np.sum(white[..., 0] ** 2)))


def solve(p0: FloatArray, view: View, free: BoolArray, model: ErrorModel, folded: Folded,
          channels: FloatArray, *, max_iterations: int, tolerance: float,
          unseen_d: bool = False) -> Fit:
    """Gauss-Newton on the prewhitened residuals of the windows and the folded normal
    equations (nearly linear in p); ``free`` (P,) marks the free parameters of p."""
    smooth = bool(free[KAPPA])
    p = p0.copy()

    def evaluate_at(p: FloatArray) -> Fit:
        return evaluate(p, view, model, folded, channels, smooth=smooth, unseen_d=unseen_d)

    fit = evaluate_at(p)
    history = [fit.cost]
    iterations = 0
    for iterations in range(1, max_iterations + 1):
        if not free.any():
            iterations = 0
            break
        h, g = fit.normal_equations(folded)
        cols = np.flatnonzero(free)
        scale = np.sqrt(np.maximum(np.diag(h)[cols], 1e-300))
        step = np.zeros(P)
        step[cols] = np.linalg.lstsq(h[np.ix_(cols, cols)] / np.outer(scale, scale),
                                     g[cols] / scale, rcond=None)[0] / scale
        p = p + step
        fit = evaluate_at(p)
        history.append(fit.cost)
        if np.max(np.abs(step) / np.maximum(np.abs(p), 1e-3)) < tolerance:
            break
    return dataclasses.replace(fit, iterations=iterations, history=tuple(history))


@dataclass(frozen=True)
class LagScan:
    """The yaw channel's cost on the lag grid (steps), per half of the clusters (2, G)."""

    grid: FloatArray
    costs: FloatArray


def scan_lag(windows: WindowSet, theta: FloatArray, heading_offset: float, model: ErrorModel,
             folded: Folded, offset: float = 0.0) -> LagScan:
    """The yaw channel's weighted cost at every half step of shift of the reference side, with
    theta fixed (the distance channel is left out: a slip that grows with acceleration is
    common to both wheels and would pass for a lag there).

    The prediction is linear in the moments, so it is made once at every whole-step shift and
    interpolated between them, as the moments are. ``offset``: the wheel-rate offset of the fit
    (rev/s; none by default).
    """
    limit = windows.shifts
    grid = np.arange(-limit, limit + 0.25, 0.5)
    half = (windows.cluster % 2).astype(np.int64)
    costs = np.zeros((2, grid.size))
    w_count, shifts = windows.size, windows.moments.shape[1]
    if w_count and limit > 0:
        rotated = windows.rotated(heading_offset)                    # (W, S, 2 SERIES + 2)
        flat = rotated.reshape(w_count * shifts, -1)
        whole, _ = MODEL.predict(theta, flat)
        whole += offset * flat[:, AT_MOVING, None]
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
    """The lag found: ``shift`` steps applied (0: none), its standard deviation (nan: not
    determined), and why it was not applied where it was not."""

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
    """The lag to apply: determined by the data (beyond three standard deviations of zero) and
    holding out (see the module docstring); else none, with the reason."""
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
    if abs(best) < _LAG_SIGMAS * std:
        return Lag(std=std, found=best, note="within noise")
    for half in (0, 1):
        mine, other = scan.costs[half], scan.costs[1 - half]
        if not other.any() or not mine.any():
            continue                                    # one half only: nothing to hold out
        own = _minimum(scan.grid, mine)
        if own is None or np.interp(own[0], scan.grid, other) >= np.interp(0.0, scan.grid,
                                                                           other):
            return Lag(std=std, found=best, note="does not hold out")
    return Lag(shift=best, std=std, found=best)


@dataclass(frozen=True)
class CoreFit:
    """What :func:`fit` found.

    fit : the final fit (theta and kappa in ``fit.p``)
    free : the parameters of theta estimated; ``held`` why the others were not
    uncertainty : the covariance of theta and what it rests on
    lag : the wheel stream's lag behind the reference, in steps
    model : the error model of the final fit
    heading_offset : the reference heading's offset applied (rad)
    """

    fit: Fit
    free: BoolArray
    held: dict[str, NotIdentified]
    uncertainty: Uncertainty
    lag: Lag
    model: ErrorModel
    heading_offset: float

    @property
    def theta(self) -> FloatArray:
        return np.asarray(self.fit.p[THETA])

    @property
    def offset(self) -> tuple[float, float]:
        """The wheel-rate offset (rev/s) and its standard deviation."""
        return float(self.fit.p[OFFSET]), self.uncertainty.offset_std

    @property
    def covariance(self) -> FloatArray:
        return self.uncertainty.covariance

    @property
    def clusters(self) -> int:
        return self.uncertainty.clusters


def offset_prior_std(settings: Settings, wheel_step_revps: float) -> float:
    """The wheel-rate offset's prior standard deviation (rev/s; 0: not fitted) by ``[inverse]
    wheel_offset`` and the step of the rates' encoding (0 where they lie on no grid)."""
    mode = settings.inverse.wheel_offset
    if mode == "always":
        return settings.inverse.wheel_offset_prior_revps
    if mode == "encoded" and wheel_step_revps > 0:
        return 0.5 * wheel_step_revps
    return 0.0


def fit(windows: WindowSet, folded: Folded, settings: Settings, *, heading_offset: float,
        held: Mapping[str, NotIdentified] | None = None, distance_only: bool = False) -> CoreFit:
    """The default method's estimate from ``windows`` and ``folded`` (see the module docstring).

    ``distance_only`` fits the distance channel alone (the wheels carry no differential signal:
    c_d, t_r and d held by the caller).
    """
    cfg = settings.inverse
    datasheet = np.asarray(settings.identify.theta0, dtype=np.float64)
    held = dict(held or {})
    peak = max(float(windows.peak_yaw_radps.max(initial=0.0)), folded.peak_yaw_radps)
    if peak <= settings.segments.yaw_rate_threshold_radps:
        # t_r and d act on the yaw rate only in bends (METHOD 2)
        for name in LAYOUT.bends:
            held.setdefault(name, NotIdentified(Reason.NEEDS_BENDS, detail=peak))
    free = np.array([name not in held for name in LAYOUT.names])
    lag_on = cfg.delay == "estimate" and not distance_only and windows.shifts > 0
    offsets_on = folded.offset_free

    def with_nuisance(free: BoolArray) -> BoolArray:
        return free_of(free, kappa=lag_on, offset=offsets_on)

    free_p = with_nuisance(free)
    channels = np.array([1.0, 0.0 if distance_only else 1.0])
    coupling = not distance_only and cfg.common_wheel_error == "estimate"
    p = pack(datasheet)

    unseen_d = LAYOUT.load in held and held[LAYOUT.load].reason is Reason.NO_LATERAL

    def solve_at(p: FloatArray, lag: Lag, model: ErrorModel, free_p: BoolArray) -> Fit:
        # where no parameter the wheels' difference shows (c_d, t_r, d) is fitted, the yaw
        # channel holds nothing to learn, only the held ones' errors: the distance channel alone
        theirs = channels if free_p[_DIFFERENTIAL].any() else np.array([1.0, 0.0])
        return solve(p, View.of(windows, lag.shift, heading_offset), free_p, model, folded,
                     theirs, max_iterations=cfg.max_iterations, tolerance=cfg.tolerance,
                     unseen_d=unseen_d)

    model = ErrorModel()
    lag = Lag()
    current = solve_at(p, lag, model, free_p)
    h, _ = current.normal_equations(folded)
    informed = numerically_free(h[THETA, THETA], settings.identify.prior_std, free)
    if not np.array_equal(informed, free):
        # a parameter the windows say nothing about (a_y zero throughout: d): named, not fitted
        for j in np.flatnonzero(free & ~informed):
            held[LAYOUT.names[j]] = NotIdentified(Reason.NO_INFORMATION)
        free = informed
        free_p = with_nuisance(free)
        current = solve_at(p, lag, model, free_p)
    model = dataclasses.replace(model, noise=noise_from_sums(
        folded.noise + noise_sums(windows.measured, current.residual)))
    if lag_on:
        current = solve_at(current.p, lag, model, free_p)
        lag = choose_lag(scan_lag(windows, current.p[THETA], heading_offset, model, folded,
                                  float(current.p[OFFSET])))
    for _ in range(2):                  # the error model refitted at the lag
        current = solve_at(current.p, lag, model, free_p)
        model = refit_model(current, windows, folded, coupling=coupling)
    for _ in range(_SHIFT_ROUNDS - 1 if lag_on else 0):
        # the lag again with the theta fitted at it, until the two agree
        again = choose_lag(scan_lag(windows, current.p[THETA], heading_offset, model, folded,
                                    float(current.p[OFFSET])))
        if abs(again.shift - lag.shift) < _SHIFT_SETTLED:
            break
        lag = again
        for _ in range(2):
            current = solve_at(current.p, lag, model, free_p)
            model = refit_model(current, windows, folded, coupling=coupling)
    current = solve_at(current.p, lag, model, free_p)

    def lag_spread(p: FloatArray, free: BoolArray) -> FloatArray:
        # how far theta moves with the lag, times the lag's own uncertainty: a lag found to
        # +-0.5 steps on a short drive moves t_r by as much as its noise does
        variance = _lag_variance(lag, windows.shifts) if lag_on else 0.0
        if variance <= 0 or not free.any():
            return np.zeros(LAYOUT.size)
        ahead, behind = (solve_at(p, dataclasses.replace(lag, shift=lag.shift + step), model,
                                  with_nuisance(free)).p[THETA]
                         for step in (_LAG_STEP, -_LAG_STEP))
        return np.asarray((ahead - behind) / (2.0 * _LAG_STEP) * math.sqrt(variance))

    free, held, current, uncertainty = _identified(
        current, windows, folded, settings, free, held, lambda p, f: solve_at(
            p, lag, model, with_nuisance(f)), with_nuisance, lag_spread)
    return CoreFit(fit=current, free=free, held=held, uncertainty=uncertainty, lag=lag,
                   model=model, heading_offset=heading_offset)


def refit_model(current: Fit, windows: WindowSet, folded: Folded, *,
                coupling: bool) -> ErrorModel:
    """The error model from the residuals of ``current`` (and the folded windows' sums)."""
    beta = 0.0
    if coupling:
        beta = coupling_from_sums(coupling_sums_at(folded.coupling, current.p - folded.origin)
                                  + coupling_sums(windows.measured, current.residual,
                                                  current.weight))
    gain = coupling_gain(windows.measured, current.residual, beta)
    noise = noise_from_sums(folded.noise + noise_sums(windows.measured, current.residual, gain))
    # the prewhitening from the residuals as the fit standardised them (with its own coupling)
    ma = arma_from_sums(folded.correlation
                        + correlation_sums(current.stacked[..., 0], windows.follows))
    return ErrorModel(noise=noise, ma=ma, coupling=beta)


#: Steps the lag is moved either way to see how theta follows it.
_LAG_STEP = 0.5


def _lag_variance(lag: Lag, shifts: int) -> float:
    """The variance (steps^2) of the lag the fit stands on: that of the lag applied, or, where
    the one found was not applied (within noise, or not holding out), of taking none in its
    place: its std and its own size; never more than a lag spread evenly over the searched
    range (``shifts`` steps either way: the checks refuse a larger one). Zero where no lag
    could be timed (no bends)."""
    if not math.isfinite(lag.std):
        return 0.0
    variance = lag.std ** 2 if lag.shift != 0.0 else lag.std ** 2 + lag.found ** 2
    return min(variance, shifts ** 2 / 3.0)


def _identified(current: Fit, windows: WindowSet, folded: Folded, settings: Settings,
                free: BoolArray, held: dict[str, NotIdentified],
                refit: Callable[[FloatArray, BoolArray], Fit],
                with_nuisance: Callable[[BoolArray], BoolArray],
                lag_spread: Callable[[FloatArray, BoolArray], FloatArray],
                ) -> tuple[BoolArray, dict[str, NotIdentified], Fit, Uncertainty]:
    """The identifiability verdict (:func:`~odocal.estimators.estimate.hold_unidentified`)
    with this core's covariance. Parameters held because the windows cannot see them widen the
    free ones by their datasheet uncertainty (:func:`covariance`)."""
    datasheet = np.asarray(settings.identify.theta0, dtype=np.float64)
    prior = np.asarray(settings.identify.prior_std, dtype=np.float64)
    # parameters held at their datasheet values that the free ones are sensitive to (a_y
    # missing: d; one turning rate: t_r against c_d; one speed in every bend: t_r against d,
    # judged too weak) widen them by their datasheet uncertainty: a free parameter that cannot
    # be told apart from a held one is not identified either
    known = np.array([n in held and held[n].reason in _KNOWN for n in LAYOUT.names])
    fits, uncertainties = [current], []

    def covariance_of(free: BoolArray) -> tuple[FloatArray, int]:
        found = covariance(fits[-1], windows, folded, with_nuisance(free),
                           np.where(~known & ~free, prior, 0.0))
        spread = lag_spread(fits[-1].p, free)
        if spread.any():
            # the lag's uncertainty is the wheels' timing: theta's covariance takes it in
            base = np.sqrt(np.clip(np.diag(found.covariance), 0.0, None))
            cov = found.covariance + np.outer(spread, spread)
            std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
            with np.errstate(divide="ignore", invalid="ignore"):
                more = np.where(base > 0, std / base, 1.0)
            found = dataclasses.replace(found, covariance=cov, widening=found.widening * more)
        uncertainties.append(found)
        return uncertainties[-1].covariance, uncertainties[-1].clusters

    def refit_at(free: BoolArray) -> None:
        p = fits[-1].p.copy()
        p[THETA][~free] = datasheet[~free]
        fits.append(refit(p, free))

    free, held = hold_unidentified(free, held, settings.identify, covariance_of=covariance_of,
                                   refit=refit_at)
    found = uncertainties[-1]
    if not free.any():
        n = LAYOUT.size
        found = dataclasses.replace(found, covariance=np.zeros((n, n)), widening=np.ones(n))
    return free, held, fits[-1], found


@dataclass(frozen=True)
class Uncertainty:
    """The covariance of theta (n, n), the clusters it rests on, each window's information
    (W, n, n) and score (W, n), how much each standard deviation was widened for the
    parameters held at their datasheet values (1: not), and the wheel-rate offsets' standard
    deviation (rev/s; zero where not fitted)."""

    covariance: FloatArray
    clusters: int
    information: FloatArray
    scores: FloatArray
    widening: FloatArray
    offset_std: float = 0.0


def covariance(current: Fit, windows: WindowSet, folded: Folded, free: BoolArray,
               nuisance: FloatArray | None = None) -> Uncertainty:
    """Sandwich covariance of theta over clusters of windows (folded clusters' meat included),
    from the prewhitened rows, each cluster's score scaled by its leverage, cross products of
    clusters up to three apart with Newey and West's weights; kappa and the offset profiled
    out (the offset's prior is in ``folded``). What it adds beyond the residual-variance
    formula is widened by Student's t for the clusters each parameter's information comes from
    (with fewer than :data:`MIN_CLUSTERS_FOR_ROBUST` clusters in all, the larger of the two).

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
    cov = correction * (h_inv @ meat @ h_inv)
    # the residual-variance (model-based) covariance: the error model's, from every window
    count = current.white[..., 0].size + folded.count
    naive = (current.cost + folded.cost) / max(count - int(free.sum()), 1) * h_inv
    s_n = np.sqrt(np.clip(np.diag(naive), 0.0, None))
    s_r = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    # The sandwich is needed where the errors are not what the error model says (correlated
    # over seconds, a reference's own): what it adds beyond the model-based variance rests on
    # the clusters the parameter's information comes from, few for t_r and d on a short drive
    # (Satterthwaite's effective number; t_r's from the few clusters with bends), so it is
    # widened by Student's t at the three-sigma tail for them. Where the two agree the error
    # model holds, and its variance, from every window, needs no widening. With fewer than
    # MIN_CLUSTERS_FOR_ROBUST clusters the larger of the two is taken as it stands.
    effective = _effective_clusters(info, windows.cluster, folded, h_inv) if windows.size \
        else np.full(P, float(clusters))
    f = np.array([tail_inflation(max(round(e), 2)) if e > 0 else 1.0 for e in effective])
    if clusters < 2:
        f[:] = 1.0                # one cluster: the one-cluster rule leaves nothing identified
    with np.errstate(divide="ignore", invalid="ignore"):
        if clusters < MIN_CLUSTERS_FOR_ROBUST:
            target = np.maximum(s_n, s_r) * f
        else:
            target = np.sqrt(s_n ** 2 + f ** 2 * np.clip(s_r ** 2 - s_n ** 2, 0.0, None))
        scale = np.where(s_r > 0, target / s_r, 1.0)
    cov = cov * np.outer(scale, scale)
    base = np.sqrt(np.clip(np.diag(cov)[THETA], 0.0, None))
    if nuisance is not None:
        for j in np.flatnonzero(nuisance > 0):
            shift = -h_inv @ h[:, j]                   # d p_free / d theta_j (held)
            cov = cov + nuisance[j] ** 2 * np.outer(shift, shift)
    std = np.sqrt(np.clip(np.diag(cov)[THETA], 0.0, None))
    with np.errstate(divide="ignore", invalid="ignore"):
        widening = np.where(base > 0, std / base, 1.0)
    return Uncertainty(cov[THETA, THETA], clusters, info[:, THETA, THETA], scores[:, THETA],
                       widening, float(np.sqrt(max(cov[OFFSET, OFFSET], 0.0))))


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


def fold(folded: Folded, windows: WindowSet, p: FloatArray, shift: float, heading_offset: float,
         model: ErrorModel, *, smooth: bool, total_h: FloatArray | None,
         scan: LagScan | None) -> Folded:
    """``folded`` with ``windows`` (one complete cluster, the oldest) folded in, linearised at
    ``p`` with the error model and lag of now; ``total_h`` the information of the whole fit so
    far (for the cluster's leverage), ``scan`` the windows' own lag-grid costs."""
    channels = np.ones(2)
    current = evaluate(p, View.of(windows, shift, heading_offset), model, folded, channels,
                       smooth=smooth)
    jj, rr = current.white[..., 1:], current.white[..., 0]
    rows, res = jj.reshape(-1, jj.shape[-1]), rr.reshape(-1)
    h, g = rows.T @ rows, rows.T @ res
    free = free_of(np.ones(KAPPA, dtype=bool), kappa=smooth, offset=folded.offset_free)
    if not folded.offset_free:             # no offset fitted: nothing of it folded either
        h[OFFSET, :] = h[:, OFFSET] = g[OFFSET] = 0.0
    adjusted = leverage_adjusted_scores(h[None], g[None], free, np.zeros(1, dtype=np.int64),
                                        total=total_h if total_h is not None else h + folded.h
                                        )[0][0]
    gain = coupling_gain(windows.measured, current.residual, model.coupling)
    folded_scan = None if scan is None else (scan.costs if folded.scan is None
                                             else folded.scan + scan.costs)
    return dataclasses.replace(
        folded, h=folded.h + h, b=folded.b + g + h @ p,
        meat=folded.meat + added_meat(folded.recent, adjusted[None]),
        recent=np.vstack([folded.recent, adjusted])[-len(NEWEY_WEST):],
        clusters=folded.clusters + 1,
        noise=folded.noise + noise_sums(windows.measured, current.residual, gain),
        coupling=folded.coupling + coupling_moments(windows.measured, current.residual,
                                                    current.jac, p - folded.origin,
                                                    current.weight),
        correlation=folded.correlation + correlation_sums(current.stacked[..., 0],
                                                          windows.follows),
        scan=folded_scan, cost=folded.cost + current.cost,
        count=folded.count + current.white[..., 0].size,
        last=(p.copy(), current.stacked[-1].copy(), current.white[-1].copy()),
        peak_yaw_radps=max(folded.peak_yaw_radps,
                           float(windows.peak_yaw_radps.max(initial=0.0))))
