"""The default method's problem: ``p``, the windows as the model takes them, their weighted
residuals and one Gauss-Newton solve (:mod:`odocal.estimators.core` runs the procedure).

``p = [theta, nuisance]``: the vehicle model's parameters, then the departures of
:mod:`odocal.estimators.departures` (a lag, a wheel unit's smoothing, wheel-rate offsets, a
reference point off the axle, ...), each with its columns in the same Jacobian. Beside the
wheels' two channels (distance and yaw), two channels of the reference alone: its motion
across its heading and a_y against the reference's ``v w``. The windows' residuals are weighted
by the error model and prewhitened (:mod:`odocal.estimators.error_model`); windows folded
into sums (:class:`Folded`, the online calibrator's older evidence) add their normal
equations.

Gauss-Newton stops when its step is below a thousandth of every parameter's standard
deviation (the cost's own scale: a reweighted fit approaches its fixed point geometrically, and
a relative tolerance on the parameters never reaches it).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from odocal.arrays import BoolArray, FloatArray
from odocal.estimators import departures as dep
from odocal.estimators.error_model import (
    CHANNELS,
    HUBER,
    ErrorModel,
    coupling_gain,
    decouple,
    prewhiten,
    window_weights,
)
from odocal.estimators.windows import (
    AT_ACCEL,
    AT_AREF,
    AT_BETA_TURN,
    AT_COS_TURN,
    AT_CURVE,
    AT_CUT,
    AT_LAT,
    AT_MOVING,
    AT_TURN2,
    WindowSet,
)
from odocal.model.vehicle import MODEL

#: The layout of p: theta, then the nuisance parameters of :mod:`.departures`.
LAYOUT = MODEL.layout
THETA = slice(0, LAYOUT.size)
P = dep.P
KAPPA, LAG, OFFSET = (dep.at(n) for n in ("spread", "lag", "offset"))
LEFT, RIGHT = dep.at("offset_left"), dep.at("offset_right")
ARM_X, ARM_Y, CURVE, CUT = (dep.at(n) for n in ("arm_x", "arm_y", "curve", "cut"))
LAT_OFFSET, LAT_SCALE, SLIP, DRIFT = (dep.at(n) for n in ("lateral_offset", "lateral_scale",
                                                          "slip", "drift"))
CHANGE = np.array([dep.at("change_e"), dep.at("change_d")])
#: theta's scale and difference in p (what a change inside a log moves)
SCALE, DIFFERENCE = LAYOUT.index(LAYOUT.scale), LAYOUT.index(LAYOUT.difference)
_STEP_SIGMAS = 1e-3       # Gauss-Newton has converged when no step exceeds this many std
_HALVINGS = 30            # a step that spoils the fit is halved at most so often


def pack(theta: FloatArray, kappa: float = 0.0, offset: float = 0.0) -> FloatArray:
    """p from theta (the departures at zero but the spread ``kappa`` and the wheel-rate
    ``offset``)."""
    p = np.zeros(P)
    p[THETA], p[KAPPA], p[OFFSET] = theta, kappa, offset
    return p


def free_of(theta_free: BoolArray, *, kappa: bool = False, offset: bool = False,
            entered: Sequence[str] = ()) -> BoolArray:
    """Which elements of p are fitted: theta's free ones and the departures entered."""
    free = np.zeros(P, dtype=bool)
    free[THETA] = np.asarray(theta_free, dtype=bool)
    free[KAPPA] |= kappa
    free[OFFSET] |= offset
    for name in entered:
        free[dep.at(name)] = True
    return free


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
    reference : (2, 2) the reference channels' sums of squared standardised residuals and
        their count
    half_h, half_b : (2, P, P), (2, P) the normal equations of each half of the folded
        clusters (alternate ones), for the departures' held-out test
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
    reference: FloatArray = field(default_factory=lambda: np.zeros((2, 2)))
    half_h: FloatArray = field(default_factory=lambda: np.zeros((2, P, P)))
    half_b: FloatArray = field(default_factory=lambda: np.zeros((2, P)))
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
        origin = np.asarray(origin, dtype=np.float64)
        if origin.size < P:
            origin = np.concatenate([origin, np.zeros(P - origin.size)])
        return Folded(origin=origin, h=np.diag(precision), meat=np.diag(precision),
                      offset_std=max(offset_std, 0.0))

    @property
    def offset_free(self) -> bool:
        """Whether the wheel-rate offset is fitted from the start (it has a prior)."""
        return self.offset_std > 0

    @property
    def windows(self) -> int:
        """Windows folded (each counts two wheel channels)."""
        return self.count // 2

    def decayed(self, factor: float) -> Folded:
        """The sums with older evidence faded by ``factor`` (forgetting)."""
        return dataclasses.replace(
            self, h=self.h * factor, b=self.b * factor, meat=self.meat * factor,
            recent=self.recent * math.sqrt(factor), noise=self.noise * factor,
            coupling=self.coupling * factor, correlation=self.correlation * factor,
            reference=self.reference * factor, half_h=self.half_h * factor,
            half_b=self.half_b * factor,
            scan=None if self.scan is None else self.scan * factor, cost=self.cost * factor)


@dataclass(frozen=True)
class View:
    """The windows as the model takes them at one shift and heading offset.

    at, first, second : (W, AT_WIDTH) the moments, their first and second difference in the
        shift
    before : (W,) the windows before a change inside the log (None: no change)
    tau_h : (W,) hours from each window to the end of its drive (c_e's drift), or None
    across, lateral : whether the reference's sideways motion and a_y are channels of their own
        (a heading that is not the course; an a_y that carries a lateral acceleration)
    """

    windows: WindowSet
    shift: float
    at: FloatArray
    first: FloatArray
    second: FloatArray
    before: BoolArray | None = None
    tau_h: FloatArray | None = None
    across: bool = False
    lateral: bool = False

    @staticmethod
    def of(windows: WindowSet, shift: float, heading_offset: float, *,
           before: BoolArray | None = None, tau_h: FloatArray | None = None,
           across: bool = False, lateral: bool = False) -> View:
        at, first, second = windows.around(shift, heading_offset)
        return View(windows, shift, at, first, second, before, tau_h, across, lateral)

    def moved(self, shift: float, heading_offset: float) -> View:
        """The same view at another shift."""
        return View.of(self.windows, shift, heading_offset, before=self.before,
                       tau_h=self.tau_h, across=self.across, lateral=self.lateral)


@dataclass(frozen=True)
class Fit:
    """The windows' residuals at ``p`` and what Gauss-Newton needs of them.

    residual : (W, 2) channel residuals, before the common wheel error is taken out
    jac : (W, 2, P) their Jacobian in p
    weight : (W, 2) the error model's weights
    stacked : (W, 2, 1 + P) the wheel channels' standardised rows ``[residual, Jacobian]``,
        before prewhitening
    white : (W, 4, 1 + P) every channel's rows as the fit takes them: the wheel channels
        prewhitened, then the reference's sideways motion and a_y (zero where not fitted)
    across : (W, 2) the reference channels' residuals (sideways motion, m; a_y, m/s)
    cost : the weighted sum of squares of the windows (the folded ones' is in Folded.cost)
    """

    p: FloatArray
    residual: FloatArray
    jac: FloatArray
    weight: FloatArray
    stacked: FloatArray
    white: FloatArray
    cost: float
    across: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    iterations: int = 0
    converged: bool = True
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
    return np.moveaxis(np.tensordot(MODEL.channel_map, per_wheel, axes=([1], [1])), 0, 1)


def wheels(p: FloatArray, view: View, *, smooth: bool, unseen_d: bool = False,
           jacobian: bool = True) -> tuple[FloatArray, FloatArray]:
    """Each window's predicted revolutions per wheel (W, 2) and their Jacobian in p
    (W, 2, P), the departures included (:mod:`.departures`)."""
    theta = p[THETA]
    base = view.at
    # the load transfer acts on a_y as logged (the specific force the tyres carry: a road's
    # crossfall is in it as much as the turning); a_y's offset and scale against the
    # reference's v w are the a_y channel's alone (:func:`reference_rows`), and what they would
    # make of c_d and d were they the sensor's is in their uncertainty
    # (:func:`odocal.estimators.covariance.lateral_doubt`)
    moments = np.array(base, dtype=np.float64, copy=True)
    # the axle's travel from the reference point's (the chord the point turns through, along
    # the axle's direction of travel: ds + arm_y 2 sin(dpsi/2) cos(beta) - arm_x ... sin(beta)),
    # and the wheels' excess in bends (``curve``)
    turn, beta_turn, curve = base[:, AT_COS_TURN], base[:, AT_BETA_TURN], base[:, AT_CURVE]
    cut = base[:, AT_CUT]
    moments[:, 0] += (p[ARM_Y] * turn - p[ARM_X] * beta_turn + p[CURVE] * curve
                      + p[CUT] * cut)
    pred, jac_theta = MODEL.predict(theta, moments)
    if unseen_d:
        jac_theta[..., LAYOUT.index(LAYOUT.load)] = MODEL.load_transfer_column(theta, moments)
    jac = np.zeros((pred.shape[0], 2, P)) if jacobian else np.zeros((0, 2, P))
    before = view.before
    if before is not None and before.any():
        early = theta.copy()
        early[[SCALE, DIFFERENCE]] += p[CHANGE]
        pred_b, jac_b = MODEL.predict(early, moments[before])
        pred[before] = pred_b
        if jacobian:
            jac[before[:, None] & np.ones(2, dtype=bool)[None, :], :] = 0.0
            jac[before, :, CHANGE[0]] = jac_b[..., SCALE]
            jac[before, :, CHANGE[1]] = jac_b[..., DIFFERENCE]
            jac_theta[before] = jac_b
    moving = base[:, AT_MOVING]
    pred[:, 0] += (p[OFFSET] + p[LEFT]) * moving
    pred[:, 1] += (p[OFFSET] + p[RIGHT]) * moving
    tau = view.tau_h
    if tau is not None:
        drift_col = jac_theta[..., SCALE] * float(theta[SCALE]) * tau[:, None]
        pred += p[DRIFT] * drift_col
    spread = np.zeros_like(pred)
    if smooth:
        spread, _ = MODEL.predict(theta, view.second)
        pred += p[KAPPA] * spread
    if not jacobian:
        return pred, jac
    jac[..., THETA] = jac_theta
    gain = MODEL.along_gain(theta)[None, :]
    jac[..., ARM_Y] = turn[:, None] * gain
    jac[..., ARM_X] = -beta_turn[:, None] * gain
    jac[..., CURVE] = curve[:, None] * gain
    jac[..., CUT] = cut[:, None] * gain
    jac[:, 0, OFFSET] = jac[:, 1, OFFSET] = moving
    jac[:, 0, LEFT], jac[:, 1, RIGHT] = moving, moving
    if tau is not None:
        jac[..., DRIFT] = drift_col
    jac[..., KAPPA] = spread
    return pred, jac


def _lag_column(p: FloatArray, view: View) -> FloatArray:
    """The channels' derivative in the reference side's shift (W, 2). Whether a lag is fitted
    is judged on the yaw channel alone (:mod:`odocal.estimators.core`: a slip that grows with
    acceleration is common to both wheels and would pass for a lag in the distance channel);
    once fitted, it moves both."""
    d_pred, _ = MODEL.predict(p[THETA], view.first)
    return np.asarray(d_pred @ CHANNELS.T)


def reference_rows(p: FloatArray, view: View) -> tuple[FloatArray, FloatArray]:
    """The reference channels' residuals (W, 2) and their Jacobian (W, 2, P): the reference's
    motion across its heading (``arm_x dpsi + arm_y beta dpsi + slip sum ds a``), and a_y's sum
    against ``(1 + s) v w + o`` (zero where the view has no such channel)."""
    at = view.at
    count = at.shape[0]
    residual, jac = np.zeros((count, 2)), np.zeros((count, 2, P))
    if view.across:
        turn, beta_turn, lateral = at[:, AT_COS_TURN], at[:, AT_BETA_TURN], at[:, 1]
        residual[:, 0] = at[:, AT_LAT] - (p[ARM_X] * turn + p[ARM_Y] * beta_turn
                                           + p[SLIP] * lateral)
        jac[:, 0, ARM_X], jac[:, 0, ARM_Y], jac[:, 0, SLIP] = turn, beta_turn, lateral
    if view.lateral:
        # a_y against the axle's own v w: the reference point's, less what its being beside
        # the axle adds (arm_y w^2)
        span = view.windows.length * view.windows.t_s
        axle = at[:, AT_AREF] + p[ARM_Y] * at[:, AT_TURN2]
        residual[:, 1] = at[:, AT_ACCEL] - ((1.0 + p[LAT_SCALE]) * axle + p[LAT_OFFSET] * span)
        jac[:, 1, LAT_SCALE], jac[:, 1, LAT_OFFSET] = axle, span
        jac[:, 1, ARM_Y] = (1.0 + p[LAT_SCALE]) * at[:, AT_TURN2]
    return residual, jac


def evaluate(p: FloatArray, view: View, model: ErrorModel, folded: Folded,
             channels: FloatArray, *, smooth: bool, unseen_d: bool = False,
             reference: bool = False) -> Fit:
    """Residuals, weights and prewhitened rows of every window at ``p``. ``unseen_d``: the a_y
    column carries no lateral acceleration, so d's Jacobian is taken with the reference's own
    (``v w``): what a load transfer the data cannot show would do (d is held, its datasheet
    uncertainty widens the others'). ``reference``: the reference channels count in the cost
    (a departure they show is fitted); their rows are there for the score tests either way."""
    win = view.windows
    pred, jac_w = wheels(p, view, smooth=smooth, unseen_d=unseen_d)
    r = (win.measured - pred) @ CHANNELS.T
    j = _channels(jac_w)
    lag_col = _lag_column(p, view)
    r -= p[LAG] * lag_col
    j[:, :, LAG] = lag_col
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
    across, across_jac = reference_rows(p, view)
    rows = _reference_weighted(across, across_jac, model, win.weight)
    full = np.concatenate([white, rows], axis=1)
    cost = float(np.sum(white[..., 0] ** 2))
    if reference:
        cost += float(np.sum(rows[..., 0] ** 2))
    else:
        full[:, 2:, 0] = 0.0             # the channels say nothing of what is fitted now
    return Fit(p=p, residual=r, jac=j, weight=w, stacked=stacked, white=full, cost=cost,
               across=across)


def _reference_weighted(residual: FloatArray, jac: FloatArray, model: ErrorModel,
                        weight: FloatArray) -> FloatArray:
    """The reference channels' rows ``[residual, Jacobian]`` (W, 2, 1 + P), standardised by
    their spread (:attr:`ErrorModel.reference`), Huber-limited."""
    spread = np.asarray(model.reference, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.abs(residual) / spread[None, :]
        w = np.where(spread[None, :] > 0, 1.0 / spread[None, :] ** 2, 0.0) \
            * np.minimum(1.0, HUBER / np.maximum(z, 1e-300)) * weight[:, None]
    w = np.where(np.isfinite(w), w, 0.0)
    return np.concatenate([residual[..., None], jac], axis=2) * np.sqrt(w)[..., None]


def solve(p0: FloatArray, view: View, free: BoolArray, model: ErrorModel, folded: Folded,
          channels: FloatArray, *, max_iterations: int, tolerance: float,
          unseen_d: bool = False, reference: bool = False) -> Fit:
    """Gauss-Newton on the prewhitened residuals of the windows and the folded normal
    equations (nearly linear in p); ``free`` (P,) marks the free parameters of p. It stops
    when no step exceeds a thousandth of the parameter's standard deviation (or its relative
    change ``tolerance``), and says whether it did."""
    smooth = bool(free[KAPPA])
    p = p0.copy()

    def evaluate_at(p: FloatArray) -> Fit:
        return evaluate(p, view, model, folded, channels, smooth=smooth, unseen_d=unseen_d,
                        reference=reference)

    fit = evaluate_at(p)
    history = [fit.cost]
    iterations, converged = 0, True
    for iterations in range(1, max_iterations + 1):
        if not free.any():
            iterations = 0
            break
        h, g = fit.normal_equations(folded)
        # (a free element nothing informs yet, a reference channel before its spread is
        # known, takes no step)
        cols = np.flatnonzero(free & (np.diag(h) > 0))
        if not cols.size:
            break
        scale = np.sqrt(np.diag(h)[cols])
        step = np.zeros(P)
        step[cols] = np.linalg.lstsq(h[np.ix_(cols, cols)] / np.outer(scale, scale),
                                     g[cols] / scale, rcond=None)[0] / scale
        trial = evaluate_at(p + step)
        for _ in range(_HALVINGS):
            # a step that spoils the fit (not finite, or far worse: a departure the windows
            # barely show, linearised too far) is halved
            if math.isfinite(trial.cost) and np.all(np.isfinite(trial.white)) \
                    and trial.cost <= 2.0 * fit.cost + 10.0:
                break
            step = 0.5 * step
            trial = evaluate_at(p + step)
        p, fit = p + step, trial
        history.append(fit.cost)
        std = np.sqrt(np.clip(np.diag(np.linalg.pinv(h[np.ix_(cols, cols)])), 0.0, None))
        if (np.all(np.abs(step[cols]) <= _STEP_SIGMAS * std)
                or np.max(np.abs(step) / np.maximum(np.abs(p), 1e-3)) < tolerance):
            break
    else:
        converged = not free.any()
    return dataclasses.replace(fit, iterations=iterations, converged=converged,
                               history=tuple(history))
