"""The default method's core, for batch and live alike: one fit of the model and its departures.

The windows (:mod:`odocal.estimators.windows`) predict their revolutions for any theta; this
module fits them. Batch calibration hands it every window of the drives and nothing folded;
the online calibrator hands it the windows in memory and the older ones folded into sums
(:class:`~odocal.estimators.fitting.Folded`): normal equations linearised at the estimate of
their time, the clusters' scores for the covariance, and the error model's sums. With nothing
folded, the two are the same computation, to the last digit.

The procedure (:func:`fit`):

1. Gauss-Newton on the windows' channel residuals (distance and yaw), weighted by the error
   model and prewhitened (:mod:`odocal.estimators.error_model`), from the datasheet values,
   over ``p = [theta, nuisance]``: the departures of :mod:`odocal.estimators.departures`
   (a lag, a wheel unit's smoothing, wheel-rate offsets, a reference point off the axle, ...),
   each with its columns in the same Jacobian. Beside the wheels' two channels, two channels
   of the reference alone: its motion across its heading (a lever arm, the axle's sideslip)
   and a_y against the reference's ``v w`` (a_y's offset and scale).
2. **Which departures.** None at first (but the encoding's offset, where the rates lie on a
   grid); then one rule: the one whose score statistic exceeds Schwarz's penalty most enters,
   the fit is redone, and the rest tested again (:mod:`odocal.estimators.departures`). The
   lag, once in, is found on a half-step grid of the yaw channel's cost first
   (:mod:`odocal.estimators.lag`: a lag beyond the linear range is not found by a gradient),
   then fitted jointly.
3. The error model refitted at each fit; then the covariance of everything fitted, a sandwich
   over clusters of windows (:func:`odocal.estimators.covariance.covariance`), and the
   identifiability verdict: parameters the data do not determine well enough keep their
   datasheet values and are named, and the rest is refitted.

p, the windows' residuals and one Gauss-Newton solve are :mod:`odocal.estimators.fitting`'s.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from odocal.arrays import BoolArray, FloatArray, IntArray
from odocal.estimators import departures as dep
from odocal.estimators.covariance import (
    NEWEY_WEST,
    Uncertainty,
    added_meat,
    covariance,
    doubted,
    lateral_doubt,
    leverage_adjusted_scores,
)
from odocal.estimators.error_model import (
    HUBER,
    ErrorModel,
    arma_from_sums,
    correlation_sums,
    coupling_from_sums,
    coupling_gain,
    coupling_moments,
    coupling_sums,
    coupling_sums_at,
    noise_from_sums,
    noise_sums,
)
from odocal.estimators.estimate import (
    NotIdentified,
    Reason,
    hold_unidentified,
    numerically_free,
)
from odocal.estimators.fitting import (
    CHANGE,
    DIFFERENCE,
    KAPPA,
    LAG,
    LAYOUT,
    LEFT,
    OFFSET,
    RIGHT,
    SCALE,
    THETA,
    Fit,
    Folded,
    P,
    View,
    evaluate,
    free_of,
    pack,
    solve,
)
from odocal.estimators.lag import Lag, LagScan, choose_lag, lag_test, scan_lag
from odocal.estimators.windows import WindowSet
from odocal.settings import Settings

_SHIFT_ROUNDS = 6         # the lag scanned and theta refitted in turn at most so often
_SHIFT_SETTLED = 1e-3     # steps
#: The parameters that act through the wheels' difference, in p.
_DIFFERENTIAL = np.array(LAYOUT.indices(LAYOUT.differential))
#: Why a held parameter is known (its datasheet value is taken as exact): held on request.
#: Every other held parameter is uncertain by its datasheet uncertainty, which widens the free
#: ones as far as the data cannot tell them apart (:func:`.covariance.covariance`).
_KNOWN = (Reason.HELD,)
#: The least spread the reference channels' residuals are given (a millimetre of sideways
#: motion, a thousandth of a m/s of a_y's sum per window): a simulated a_y that is exactly the
#: reference's ``v w`` would otherwise weigh infinitely.
_REFERENCE_FLOOR = np.array([1e-3, 1e-3])
#: Most change locations a test tries (cluster boundaries, evenly spread).
_CHANGE_LOCATIONS = 60


@dataclass(frozen=True)
class CoreFit:
    """What :func:`fit` found.

    fit : the final fit (theta and the departures in ``fit.p``)
    free : the parameters of theta estimated; ``held`` why the others were not
    uncertainty : the covariance of theta and what it rests on
    lag : the wheel stream's lag behind the reference, in steps
    model : the error model of the final fit
    heading_offset : the reference heading's offset applied (rad)
    entered : the departures fitted (:mod:`.departures`), in the order they entered
    statistics : each departure's last score test (entered or not)
    change : the first window after a change inside the log (-1: none)
    rivals : for each departure entered, every other's held-out gain in the round it entered
        (its own among them, and its penalty): how far ahead of the next explanation it was
    before_verdict : the fit of every parameter the data inform, before the identifiability
        verdict held any (what the drives' agreement is judged on), and which were free
    """

    fit: Fit
    free: BoolArray
    held: dict[str, NotIdentified]
    uncertainty: Uncertainty
    lag: Lag
    model: ErrorModel
    heading_offset: float
    entered: tuple[str, ...] = ()
    statistics: tuple[dep.Statistic, ...] = ()
    change: int = -1
    before_verdict: tuple[Fit, BoolArray] | None = None
    rivals: Mapping[str, Mapping[str, float]] = field(default_factory=dict)

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

    @property
    def nuisance_std(self) -> FloatArray:
        """(P,): the standard deviation of every element of p (0 where not fitted)."""
        return self.uncertainty.p_std


def offset_prior_std(settings: Settings, wheel_step_revps: float) -> float:
    """The wheel-rate offset's prior standard deviation (rev/s; 0: not fitted from the start)
    by ``[inverse] wheel_offset`` and the step of the rates' encoding (0 where they lie on no
    grid)."""
    mode = settings.inverse.wheel_offset
    if mode == "always":
        return settings.inverse.wheel_offset_prior_revps
    if mode == "encoded" and wheel_step_revps > 0:
        return 0.5 * wheel_step_revps
    return 0.0


@dataclass(frozen=True)
class Setup:
    """What a fit is asked to do beyond the windows (:func:`fit`'s options, prepared).

    blocks : the departures it may fit (:data:`.departures.BLOCKS` in batch)
    across, lateral : the reference channels it has (:class:`View`)
    stated : nuisance parameters stated by the user (held at these values; e.g. the lever arm)
    tau_h : hours to each window's drive's end (c_e's drift), or None
    coupled : whether the live path took a common wheel error's coupling before (kept at a
        lower Wald statistic: :data:`~odocal.estimators.error_model.COUPLING_KEEP_WALD`)
    """

    blocks: tuple[tuple[str, ...], ...] = dep.BLOCKS
    across: bool = False
    lateral: bool = False
    stated: Mapping[str, float] = field(default_factory=dict)
    tau_h: FloatArray | None = None
    coupled: bool = False


def fit(windows: WindowSet, folded: Folded, settings: Settings, *, heading_offset: float,
        held: Mapping[str, NotIdentified] | None = None, distance_only: bool = False,
        setup: Setup | None = None) -> CoreFit:
    """The default method's estimate from ``windows`` and ``folded`` (see the module docstring).

    ``distance_only`` fits the distance channel alone (the wheels carry no differential signal:
    c_d, t_r and d held by the caller).
    """
    setup = setup or Setup(blocks=())
    held = _held_without_bends(windows, folded, settings, held or {})
    free = np.array([name not in held for name in LAYOUT.names])
    timing = settings.inverse.delay == "estimate" and not distance_only and windows.shifts > 0
    blocks = _allowed_blocks(setup, timing=timing, distance_only=distance_only)
    channels = np.array([1.0, 0.0 if distance_only else 1.0])
    unseen_d = LAYOUT.load in held and held[LAYOUT.load].reason is Reason.NO_LATERAL
    p0 = pack(np.asarray(settings.identify.theta0, dtype=np.float64))
    for name, value in setup.stated.items():
        p0[dep.at(name)] = value
    ctx = _Context(windows, folded, settings, heading_offset, channels, unseen_d, setup)
    entered = _Entered([], folded.offset_free)
    state = ctx.run(p0, free, entered.free(), change=-1)
    h_theta = state.fit.normal_equations(folded)[0][THETA, THETA]
    informed = numerically_free(h_theta, settings.identify.prior_std, free)
    if not np.array_equal(informed, free):
        # a parameter the windows say nothing about (a_y zero throughout: d): named, not fitted
        for j in np.flatnonzero(free & ~informed):
            held[LAYOUT.names[j]] = NotIdentified(Reason.NO_INFORMATION)
        free = informed
        state = ctx.run(p0, free, entered.free(), change=-1)
    state, entered = _enter_departures(ctx, state, free, blocks, folded.offset_free)
    with_nuisance = entered.free()
    before_verdict = (state.fit, free_of(free, entered=[n for n in entered.names if n != "lag"])
                      | (with_nuisance & (np.arange(P) == OFFSET)))
    if folded.clusters:
        # live, with windows folded: their sums stand at the shifts of their time, so the lag
        # is the windows' shift (found on the scan of every window, folded or not), not a
        # parameter whose information the sums could share with theta's
        with_nuisance[LAG] = False
    free, held, state, uncertainty = _identified(state, ctx, free, held, with_nuisance,
                                                 entered.change)
    uncertainty = lateral_doubt(uncertainty, state.fit.p, free)
    if "spread" in entered.names and not folded.clusters:
        uncertainty = _skew_doubt(uncertainty, state, ctx, free_of(free) | with_nuisance)
    lag = state.lag
    if "lag" in entered.names:
        lag = dataclasses.replace(lag, shift=lag.shift + float(state.fit.p[LAG]),
                                  std=float(uncertainty.p_std[LAG]))
    return CoreFit(fit=state.fit, free=free, held=held, uncertainty=uncertainty, lag=lag,
                   model=state.model, heading_offset=heading_offset,
                   entered=tuple(entered.names), statistics=entered.statistics,
                   change=entered.change, before_verdict=before_verdict, rivals=entered.rivals)


def _held_without_bends(windows: WindowSet, folded: Folded, settings: Settings,
                        held: Mapping[str, NotIdentified]) -> dict[str, NotIdentified]:
    """``held`` and the parameters that act on the yaw rate only in bends (t_r and d,
    METHOD 2), where no window turns faster than ``[segments] yaw_rate_threshold_radps``."""
    out = dict(held)
    peak = max(float(windows.peak_yaw_radps.max(initial=0.0)), folded.peak_yaw_radps)
    if peak <= settings.segments.yaw_rate_threshold_radps:
        for name in LAYOUT.bends:
            out.setdefault(name, NotIdentified(Reason.NEEDS_BENDS, detail=peak))
    return out


def _allowed_blocks(setup: Setup, *, timing: bool,
                    distance_only: bool) -> list[tuple[str, ...]]:
    """The departures a fit may take: those whose channels it has (timing, the reference's
    sideways motion, a_y), none the user stated, and on the distance channel alone none that
    only the wheels' difference shows."""
    return [b for b in setup.blocks
            if (timing or b[0] not in dep.TIMING)
            and (setup.lateral or b[0] not in dep.LATERAL)
            and (setup.across or b[0] not in dep.ACROSS)
            and not (distance_only and b[0] in ("offset_left", "lag", "spread", "arm_y",
                                                "curve", "cut"))
            and not any(n in setup.stated for n in b)]


@dataclass
class _Entered:
    """The departures entered so far (in the order they entered), their last score tests, the
    change's window (-1: none) and, per departure, its rivals' held-out gains."""

    names: list[str]
    offset_free: bool
    statistics: tuple[dep.Statistic, ...] = ()
    change: int = -1
    rivals: dict[str, dict[str, float]] = field(default_factory=dict)

    def free(self) -> BoolArray:
        """The elements of p beyond theta that are fitted."""
        return free_of(np.zeros(LAYOUT.size, dtype=bool), offset=self.offset_free,
                       entered=self.names)


def _enter_departures(ctx: _Context, state: _State, free: BoolArray,
                      blocks: Sequence[tuple[str, ...]],
                      offset_free: bool) -> tuple[_State, _Entered]:
    """The departures' one rule, in rounds, from none: the one whose held-out test holds out
    most above its penalty enters and the fit is redone; one that leaves the fit unacceptable
    or not determined is taken out again and not tried again. The fit and the departures
    entered (``offset_free``: the folded sums' wheel-rate offset is fitted throughout)."""
    entered = _Entered([], offset_free)
    excluded: set[tuple[str, ...]] = set()
    for _ in range(len(blocks)):
        statistics = ctx.tests(state, free, entered.free(),
                               [b for b in blocks
                                if b[0] not in entered.names and b not in excluded])
        entered.statistics = statistics
        # the one that holds out most, less its penalty (one wheel's offset or both wheels'
        # alike: the one that needs fewer parameters where both explain as much)
        best = max((s for s in statistics if s.holds), key=lambda s: s.value - s.penalty,
                   default=None)
        if best is None:
            break
        entered.names.extend(best.block)
        entered.rivals[best.block[0]] = {st.block[0]: st.value for st in statistics}
        entered.rivals[best.block[0]]["penalty"] = best.penalty
        trial = ctx.run(state.fit.p, free, entered.free(),
                        change=best.where if best.block[0] == "change_e" else entered.change)
        if not _acceptable(trial, ctx.settings) or not _determined(
                trial, ctx.windows, ctx.folded, free_of(free) | entered.free(), best.block):
            del entered.names[-len(best.block):]
            excluded.add(best.block)
            continue
        state = trial
        if best.block[0] == "change_e":
            entered.change = best.where
    return state, entered


#: A drive departs from the others where its windows' evidence against their fit is beyond
#: this chance (chi-square: one drive in a thousand that agrees is left out).
_DEPARTING = 1e-3


def departing_drive(found: CoreFit, windows: WindowSet) -> tuple[int, float, float] | None:
    """The drive whose windows depart most from the others' fit, where one does (with two
    drives or more): its index (``cluster // 10**9``), its statistic and the limit. The
    statistic is how far the drive moves the fit from the others', in the others' own
    information (``g_d' (H - H_d)^-1 g_d``, the drive's gradient ``g_d`` at the fit of all,
    every parameter the data inform free, before the identifiability verdict):
    chi-square with as many degrees of freedom as parameters fitted where the drive agrees
    with the others. A scene that stands still but for one tight crawl, or a log of another
    tyre, is named and left out, not allowed to spoil what the others identify."""
    from scipy.special import chdtri

    drive = windows.cluster // 10**9
    labels = np.unique(drive)
    if labels.size < 2 or found.before_verdict is None:
        return None
    fit, free = found.before_verdict
    cols = np.flatnonzero(free)
    if not cols.size:
        return None
    rows, res = fit.white[..., 1:][..., cols], fit.white[..., 0]
    h = np.einsum("wck,wcl->kl", rows, rows)
    limit = float(chdtri(cols.size, _DEPARTING))
    worst: tuple[int, float, float] | None = None
    for label in labels:
        mine = drive == label
        h_d = np.einsum("wck,wcl->kl", rows[mine], rows[mine])
        g_d = np.einsum("wck,wc->k", rows[mine], res[mine])
        statistic = float(g_d @ np.linalg.pinv(h - h_d) @ g_d)
        if statistic > limit and (worst is None or statistic > worst[1]):
            worst = (int(label), statistic, limit)
    return worst


def _skew_doubt(found: Uncertainty, state: _State, ctx: _Context,
                free_p: BoolArray) -> Uncertainty:
    """The wheels' smoothing is fitted by its first two cumulants (a delay and a spread
    ``kappa_2``, as ``p[spread] = kappa_2 / 2``); the filter's shape beyond them is not in the
    data's reach. A first-order low-pass (a CAN gateway's) skews by ``kappa_3 = 2 kappa_2^1.5``,
    which moves the moments by ``kappa_3 / 6`` times their third derivative; a counting window
    does not skew at all. theta refitted with that skew taken in moves by ``delta``: its square
    is added to theta's variance (a 0.5 s low-pass left t_r at z -1.7 to -3.0 without it)."""
    p = state.fit.p
    kappa_2 = 2.0 * max(float(p[KAPPA]), 0.0)
    if kappa_2 <= 0.0:
        return found
    view = state.view
    third = ctx.windows.third(view.shift, ctx.heading_offset)
    skewed = dataclasses.replace(view, second=view.second
                                 + (2.0 / 3.0) * math.sqrt(kappa_2) * third)
    free_p = free_p.copy()
    free_p[LAG] = False
    plain = ctx.solve(p, view, state.model, free_p)
    moved = ctx.solve(p, skewed, state.model, free_p)
    delta = moved.p[THETA] - plain.p[THETA]
    delta[~free_p[THETA] | ~np.isfinite(delta)] = 0.0
    return doubted(found, delta)


#: A departure fitted must lie this many of its standard deviations from zero (one a drive
#: cannot pin down is not one it shows: fitted, it would only move theta).
_DETERMINED = 3.0


def _determined(state: _State, windows: WindowSet, folded: Folded, free_p: BoolArray,
                block: Sequence[str]) -> bool:
    """Whether the departure ``block`` just entered is determined by the fit: its values
    beyond :data:`_DETERMINED` of their standard deviations from zero, jointly (Wald's
    statistic against the chi-square quantile of a normal's three-sigma tail: one wheel's
    offset is told well by the wheels' difference even where which wheel it is is not); the
    lag's value is its shift from the scan's start, which is the reference's own alignment."""
    from scipy.special import chdtri, ndtr

    found = covariance(state.fit, windows, folded, free_p, few=False)
    index = [dep.at(name) for name in block]
    values = np.array([state.lag.shift + float(state.fit.p[j]) if name == "lag"
                       else float(state.fit.p[j]) for name, j in zip(block, index, strict=True)])
    cov = found.p_cov[np.ix_(index, index)]
    wald = float(values @ np.linalg.pinv(cov) @ values)
    return wald > float(chdtri(len(block), 2.0 * (1.0 - ndtr(_DETERMINED))))


def _acceptable(state: _State, settings: Settings) -> bool:
    """Whether a fit with a departure just entered can stand: finite, every departure within
    its bound (a change at least ``[checks] change_min`` of c_e), theta within any wheeled
    vehicle's range (the layout's; whether it is this vehicle's is the gate's, after the fit:
    a tyre that lost 2% is named, and then refused there)."""
    p = state.fit.p
    if not np.all(np.isfinite(p)) or np.any(np.abs(p[LAYOUT.size:]) > dep.BOUNDS):
        return False
    if np.any(p[CHANGE]) and np.all(np.abs(p[CHANGE]) < settings.checks.change_min
                                    * abs(float(p[SCALE]))):
        return False                   # a step that small is no change of the wheels
    return all(spec.vehicle_range[0] <= float(v) <= spec.vehicle_range[1]
               for spec, v in zip(LAYOUT.parameters, p[THETA], strict=True))


@dataclass(frozen=True)
class _State:
    """One fit of the procedure: the fit, its error model, its lag and view."""

    fit: Fit
    model: ErrorModel
    lag: Lag
    view: View


@dataclass(frozen=True)
class _Context:
    """What every fit of one procedure shares."""

    windows: WindowSet
    folded: Folded
    settings: Settings
    heading_offset: float
    channels: FloatArray
    unseen_d: bool
    setup: Setup

    def view(self, shift: float, change: int) -> View:
        before = None
        if change > 0:
            before = np.arange(self.windows.size) < change
        return View.of(self.windows, shift, self.heading_offset, before=before,
                       tau_h=self.setup.tau_h, across=self.setup.across,
                       lateral=self.setup.lateral)

    def solve(self, p: FloatArray, view: View, model: ErrorModel, free_p: BoolArray) -> Fit:
        # where no parameter the wheels' difference shows (c_d, t_r, d) is fitted, the yaw
        # channel holds nothing to learn, only the held ones' errors: the distance channel alone
        differential = free_p[_DIFFERENTIAL].any() or free_p[[LEFT, RIGHT, LAG, KAPPA]].any()
        theirs = self.channels if differential else np.array([1.0, 0.0])
        reference = bool(free_p[[dep.at(n) for n in dep.REFERENCE_CHANNEL]].any())
        cfg = self.settings.inverse
        return solve(p, view, free_p, model, self.folded, theirs,
                     max_iterations=cfg.max_iterations, tolerance=cfg.tolerance,
                     unseen_d=self.unseen_d, reference=reference)

    def run(self, p0: FloatArray, free: BoolArray, nuisance: BoolArray, *, change: int,
            model: ErrorModel | None = None) -> _State:
        """A fit of theta's ``free`` parameters and the departures ``nuisance`` from ``p0``:
        the error model refitted twice, the lag (where fitted) found on its grid and fitted
        with the rest until the two agree."""
        free_p = free_of(free) | nuisance
        p = p0.copy()
        # a departure not fitted is zero (or as the user stated it)
        p[(np.arange(P) >= LAYOUT.size) & ~free_p & ~_stated_mask(self.setup)] = 0.0
        model = model or ErrorModel()
        lag = Lag()
        view = self.view(0.0, change)
        current = self.solve(p, view, model, free_p)
        model = dataclasses.replace(model, noise=noise_from_sums(
            self.folded.noise + noise_sums(self.windows.measured, current.residual)))
        model = refit_reference(model, current, self.folded)
        lag_on = bool(free_p[LAG])
        if lag_on:
            lag = choose_lag(scan_lag(self.windows, current.p, self.heading_offset, model,
                                      self.folded))
            view = view.moved(lag.shift, self.heading_offset)
            current = dataclasses.replace(current, p=_with(current.p, LAG, 0.0))
        for _ in range(2):                 # the error model refitted at the lag
            current = self.solve(current.p, view, model, free_p)
            model = refit_model(current, self.windows, self.folded,
                                coupling=self._coupling(), kept=self.setup.coupled)
        for _ in range(_SHIFT_ROUNDS if lag_on else 0):
            # the lag's fine step taken into the view, until it settles
            step = float(current.p[LAG])
            if abs(step) < _SHIFT_SETTLED:
                break
            limit = self.windows.shifts
            shift = min(max(view.shift + step, -limit), limit)
            view = view.moved(shift, self.heading_offset)
            lag = dataclasses.replace(lag, shift=shift)
            current = self.solve(_with(current.p, LAG, 0.0), view, model, free_p)
            model = refit_model(current, self.windows, self.folded, coupling=self._coupling(),
                                kept=self.setup.coupled)
        current = self.solve(current.p, view, model, free_p)
        return _State(fit=current, model=model, lag=lag, view=view)

    def _coupling(self) -> bool:
        return bool(self.channels[1]) and self.settings.inverse.common_wheel_error == "estimate"

    def tests(self, state: _State, free: BoolArray, nuisance: BoolArray,
              blocks: Sequence[tuple[str, ...]]) -> tuple[dep.Statistic, ...]:
        """Each departure's held-out test at ``state`` (:func:`.departures.held_out`)."""
        if not blocks:
            return ()
        free_p = free_of(free) | nuisance
        current = evaluate(state.fit.p, state.view, state.model, self.folded, self.channels,
                           smooth=True, unseen_d=self.unseen_d, reference=True)
        half = _halves(self.windows)
        rows, res = current.white[..., 1:].copy(), current.white[..., 0]
        rows[:, 0, LAG] = 0.0            # a lag is judged on the yaw channel alone
        halves = []
        p = state.fit.p
        folded = self.folded
        for k in (0, 1):
            mine = half == k
            jj, rr = rows[mine].reshape(-1, P), res[mine].reshape(-1)
            # the folded clusters of this half beside the windows of this half
            h_k, b_k = folded.half_h[k], folded.half_b[k]
            halves.append((jj.T @ jj + h_k, jj.T @ rr + b_k - h_k @ p))
        rest_h = folded.h - folded.half_h.sum(axis=0)         # (a prior: in both trainings)
        common = (rest_h, folded.b - folded.half_b.sum(axis=0) - rest_h @ p)
        white = current.white
        out = []
        for block in blocks:
            index = ([dep.at(name) for name in block] if block[0] != "change_e"
                     else [SCALE, DIFFERENCE])
            n = _informing(white, index) + float(folded.windows)
            if block[0] == "lag":
                timed = lag_test(scan_lag(self.windows, p, self.heading_offset, state.model,
                                          folded))
                out.append(dataclasses.replace(timed, penalty=dep.penalty(1, n)))
                continue
            if block[0] == "change_e":
                found = _change_test(current, self.windows, half, halves, free_p, common,
                                     self.settings)
                if found is not None:
                    out.append(dataclasses.replace(found, penalty=dep.penalty(
                        2, n, _change_locations(self.windows, self.settings))))
                continue
            gains = dep.held_out(halves, free_p, index, common)
            out.append(dep.Statistic(block, gains, penalty=dep.penalty(len(block), n)))
        return tuple(out)


def _halves(windows: WindowSet) -> IntArray:
    """(W,): each window's half of the clusters: alternate ones in time, counted within each
    drive (a drive added to a calibration does not move the others' windows between halves;
    the lag's scan splits them so too)."""
    return np.asarray(windows.cluster % 2, dtype=np.int64)


def _informing(white: FloatArray, index: Sequence[int]) -> float:
    """The effective number of windows that inform the parameters ``index`` of p: ``(sum
    i_w)^2 / sum i_w^2`` with ``i_w`` a window's information in them (its rows' squared
    columns). A drive that stands still or drives straight adds windows that say nothing of a
    lag or a lever arm: it does not raise their penalty."""
    info = np.sum(white[..., [1 + i for i in index]] ** 2, axis=(1, 2))
    squares = float(np.sum(info ** 2))
    return float(np.sum(info)) ** 2 / squares if squares > 0 else 0.0


def _stated_mask(setup: Setup) -> BoolArray:
    mask = np.zeros(P, dtype=bool)
    for name in setup.stated:
        mask[dep.at(name)] = True
    return mask


def _with(p: FloatArray, index: int, value: float) -> FloatArray:
    out = p.copy()
    out[index] = value
    return out


def change_sought(windows: WindowSet, settings: Settings) -> bool:
    """Whether the windows hold enough clusters for a change inside the log to be sought:
    ``[checks] change_min_side_clusters`` either side of one at least."""
    side = settings.checks.change_min_side_clusters
    return bool(np.unique(windows.cluster).size >= 2 * side + 2)


def _change_locations(windows: WindowSet, settings: Settings) -> int:
    """How many times a change is sought at (:func:`_change_test`)."""
    clusters = np.unique(windows.cluster).size
    side = settings.checks.change_min_side_clusters
    return int(min(max(clusters - 2 * side + 1, 1), _CHANGE_LOCATIONS))


def _change_test(current: Fit, windows: WindowSet, half: IntArray, halves: dep.Halves,
                 free_p: BoolArray, common: tuple[FloatArray, FloatArray],
                 settings: Settings) -> dep.Statistic | None:
    """The held-out test of a change of c_e and c_d inside the log: on each half of the
    clusters, the change's time is where that half's evidence for one is largest (its score
    statistic, over cluster boundaries at least ``[checks] change_min_side_clusters``
    clusters from either end), and the change fitted there must lower the other half's cost
    (:func:`.departures.held_out`). The time reported is the one of the half that gains more."""
    if not change_sought(windows, settings):
        return None
    _, first = np.unique(windows.cluster, return_index=True)
    order = np.sort(first)
    side = settings.checks.change_min_side_clusters
    candidates = order[side:order.size - side + 1]
    if candidates.size > _CHANGE_LOCATIONS:
        candidates = candidates[np.linspace(0, candidates.size - 1,
                                            _CHANGE_LOCATIONS).round().astype(int)]
    jw, rw = current.white[..., 1:], current.white[..., 0]
    cols = np.flatnonzero(free_p)
    rows = jw[..., [SCALE, DIFFERENCE]]                                      # (W, C, 2)
    per_h = np.einsum("wck,wcp->wkp", rows, jw)                   # (W, 2, P)
    per_g = np.einsum("wck,wc->wk", rows, rw)                     # (W, 2)
    cums = []
    for k in (0, 1):
        mine = (half == k)[:, None, None]
        cums.append((np.concatenate([np.zeros((1, 2, P)), np.cumsum(per_h * mine, axis=0)]),
                     np.concatenate([np.zeros((1, 2)),
                                     np.cumsum(per_g * mine[:, :, 0], axis=0)])))

    def extended(k: int, where: int) -> tuple[FloatArray, FloatArray]:
        h, g = halves[k]
        block_h, block_g = cums[k][0][where], cums[k][1][where]
        out_h = np.zeros((P + 2, P + 2))
        out_h[:P, :P], out_h[P:, :P], out_h[:P, P:] = h, block_h, block_h.T
        out_h[P:, P:] = block_h[:, [SCALE, DIFFERENCE]]
        return out_h, np.concatenate([g, block_g])

    def statistic(k: int, where: int) -> float:
        h, g = extended(k, where)
        h[:P, :P] += common[0]
        g[:P] += common[1]
        inv = np.linalg.pinv(h[np.ix_(cols, cols)])
        proj = h[P:, cols] @ inv
        score = g[P:] - proj @ g[cols]
        info = h[P:, P:] - proj @ h[P:, cols].T
        return float(score @ np.linalg.pinv(info, rcond=1e-10) @ score)

    free_ext = np.concatenate([free_p, [False, False]])
    ext_common = (np.pad(common[0], (0, 2)), np.pad(common[1], (0, 2)))
    gains, places = [], []
    for k in (0, 1):
        where = max(candidates.tolist(), key=lambda c: statistic(k, c))
        pair = [extended(0, where), extended(1, where)]
        gains.append(dep.held_out(pair, free_ext, [P, P + 1], ext_common)[k])
        places.append(where)
    return dep.Statistic(("change_e", "change_d"), (gains[0], gains[1]),
                         int(places[int(np.argmax(gains))]))


def refit_model(current: Fit, windows: WindowSet, folded: Folded, *,
                coupling: bool, kept: bool = False) -> ErrorModel:
    """The error model from the residuals of ``current`` (and the folded windows' sums);
    ``kept``: a coupling taken before is kept at a lower Wald statistic."""
    beta = 0.0
    if coupling:
        beta = coupling_from_sums(coupling_sums_at(folded.coupling, current.p - folded.origin)
                                  + coupling_sums(windows.measured, current.residual,
                                                  current.weight), kept=kept)
    gain = coupling_gain(windows.measured, current.residual, beta)
    noise = noise_from_sums(folded.noise + noise_sums(windows.measured, current.residual, gain))
    # the prewhitening from the residuals as the fit standardised them (with its own coupling)
    ma = arma_from_sums(folded.correlation
                        + correlation_sums(current.stacked[..., 0], windows.follows))
    model = ErrorModel(noise=noise, ma=ma, coupling=beta)
    return refit_reference(model, current, folded)


def reference_sums(across: FloatArray, model: ErrorModel) -> FloatArray:
    """(2, 2): per reference channel the sum of its squared residuals (Huber-limited at the
    model's spread) and their number; sums of parts add up."""
    out = np.zeros((2, 2))
    spread = np.asarray(model.reference, dtype=np.float64)
    for c in range(2):
        r = across[:, c]
        if not r.size:
            continue
        limit = HUBER * spread[c] if np.isfinite(spread[c]) and spread[c] > 0 else np.inf
        out[c] = float(np.sum(np.minimum(r * r, limit * limit))), float(r.size)
    return out


def refit_reference(model: ErrorModel, current: Fit, folded: Folded) -> ErrorModel:
    """The reference channels' spread from the residuals of ``current`` (and the folded
    sums): their RMS, Huber-limited, twice (a first pass without a limit)."""
    if not current.across.size:
        return model
    for _ in range(2):
        sums = folded.reference + reference_sums(current.across, model)
        with np.errstate(divide="ignore", invalid="ignore"):
            spread = np.sqrt(np.where(sums[:, 1] > 0, sums[:, 0] / sums[:, 1], np.inf))
        spread = np.where(spread > 0, np.maximum(spread, _REFERENCE_FLOOR), np.inf)
        model = dataclasses.replace(model, reference=spread)
    return model


def _identified(state: _State, ctx: _Context, free: BoolArray, held: dict[str, NotIdentified],
                nuisance: BoolArray, change: int,
                ) -> tuple[BoolArray, dict[str, NotIdentified], _State, Uncertainty]:
    """The identifiability verdict (:func:`~odocal.estimators.estimate.hold_unidentified`)
    with this core's covariance. Parameters held because the windows cannot see them widen the
    free ones by their datasheet uncertainty (:func:`.covariance.covariance`)."""
    settings = ctx.settings
    datasheet = np.asarray(settings.identify.theta0, dtype=np.float64)
    prior = np.asarray(settings.identify.prior_std, dtype=np.float64)
    # parameters held at their datasheet values that the free ones are sensitive to (a_y
    # missing: d; one turning rate: t_r against c_d; one speed in every bend: t_r against d,
    # judged too weak) widen them by their datasheet uncertainty: a free parameter that cannot
    # be told apart from a held one is not identified either
    known = np.array([n in held and held[n].reason in _KNOWN for n in LAYOUT.names])
    states, uncertainties = [state], []

    def covariance_of(free: BoolArray) -> tuple[FloatArray, int]:
        found = covariance(states[-1].fit, ctx.windows, ctx.folded, free_of(free) | nuisance,
                           np.where(~known & ~free, prior, 0.0))
        uncertainties.append(found)
        return found.covariance, found.clusters

    def refit_at(free: BoolArray) -> None:
        p = states[-1].fit.p.copy()
        p[THETA][~free] = datasheet[~free]
        states.append(ctx.run(p, free, nuisance, change=change, model=states[-1].model))

    free, held = hold_unidentified(free, held, settings.identify, covariance_of=covariance_of,
                                   refit=refit_at)
    found = uncertainties[-1]
    if not free.any():
        n = LAYOUT.size
        found = dataclasses.replace(found, covariance=np.zeros((n, n)), widening=np.ones(n))
    return free, held, states[-1], found


def fold(folded: Folded, windows: WindowSet, p: FloatArray, shift: float, heading_offset: float,
         model: ErrorModel, *, smooth: bool, total_h: FloatArray | None,
         scan: LagScan | None, free: BoolArray | None = None,
         setup: Setup | None = None) -> Folded:
    """``folded`` with ``windows`` (one complete cluster, the oldest) folded in, linearised at
    ``p`` with the error model and lag of now; ``total_h`` the information of the whole fit so
    far (for the cluster's leverage), ``scan`` the windows' own lag-grid costs, ``free`` the
    elements of p the live fit takes (default theta, the spread where ``smooth``, the offset
    where it has a prior)."""
    setup = setup or Setup(blocks=())
    channels = np.ones(2)
    view = View.of(windows, shift, heading_offset, across=setup.across, lateral=setup.lateral)
    if free is None:
        free = free_of(np.ones(LAYOUT.size, dtype=bool), kappa=smooth,
                       offset=folded.offset_free)
    reference = bool(free[[dep.at(n) for n in dep.REFERENCE_CHANNEL]].any())
    current = evaluate(p, view, model, folded, channels, smooth=smooth, reference=reference)
    jj, rr = current.white[..., 1:], current.white[..., 0]
    rows, res = jj.reshape(-1, jj.shape[-1]), rr.reshape(-1)
    h, g = rows.T @ rows, rows.T @ res
    if not folded.offset_free:             # no offset fitted: nothing of it folded either
        h[OFFSET, :] = h[:, OFFSET] = g[OFFSET] = 0.0
    # the lag is the windows' shift when they are folded, not a parameter of their sums: they
    # keep what they say of its precision, not how it moved the rest at that shift
    own = h[LAG, LAG]
    h[LAG, :] = h[:, LAG] = g[LAG] = 0.0
    h[LAG, LAG] = own
    half = folded.clusters % 2
    half_h, half_b = folded.half_h.copy(), folded.half_b.copy()
    half_h[half] += h
    half_b[half] += g + h @ p
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
        reference=folded.reference + reference_sums(current.across, model),
        half_h=half_h, half_b=half_b, scan=folded_scan, cost=folded.cost + current.cost,
        count=folded.count + current.white[:, :2, 0].size,
        last=(p.copy(), current.stacked[-1].copy(), current.white[-1, :2].copy()),
        peak_yaw_radps=max(folded.peak_yaw_radps,
                           float(windows.peak_yaw_radps.max(initial=0.0))))

