"""The departures from the model, as nuisance parameters of the default method's one fit.

A real log departs from the model of METHOD 1 in ways that do not change the vehicle: the
reference is late, the wheel unit smooths its rates, a wheel reads an offset, the reference
point is not at the rear axle, the lateral acceleration is offset or scaled, the axle slips
sideways, the tyres warm up, or change inside the log. Each is a few *nuisance parameters*
beside theta in the same window fit (:mod:`odocal.estimators.core`), with its columns in the
same Jacobian:

==================  ==============================================================  ========
name                what it does to a window                                          unit
==================  ==============================================================  ========
``spread``          the wheels count over a wider window than the reference smooths     steps^2
                    over: ``+ kappa`` times the revolutions' second difference in the
                    shift (a filter's width; negative: the reference is the smoother)
``lag``             the reference side shifted (the wheels late): timed on the yaw    steps
                    channel (a slip that grows with acceleration is common to both
                    wheels and would pass for a lag in the distance channel)
``offset``          both wheels read ``o`` more per second of moving                 rev/s
``offset_left``     the left one reads ``o`` more per second of moving, and ...       rev/s
``offset_right``    ... the right one its own (the two enter together)                 rev/s
``arm_x, arm_y``    the reference point ahead of and left of the axle: the axle       m
                    travels ``ds + arm_y dpsi - arm_x beta dpsi``, and the reference
                    moves ``arm_x dpsi + arm_y beta dpsi`` across its heading
``curve``           the wheels travel ``q dpsi^2 / ds`` more than the axle: wheels a  m^2
                    distance ``L`` ahead (``q = L^2 / 2``), or a reference whose
                    heading is its course, ``arm_x`` ahead (``q = -arm_x^2 / 2``)
``cut``             the reference travels ``c w^2 ds`` less than the axle: smoothed  s^2
                    in time over ``sigma`` it cuts bends short (``c = sigma^2 / 2``)
``lateral_offset``  a_y reads ``o`` more than the reference's ``v w`` ...             m/s^2
``lateral_scale``   ... and ``1 + s`` times it (the window's a_y against its ``v w``;   1
                    theta is for a_y as logged, and what the two would make of c_d
                    and d were they the sensor's is in their uncertainty)
``slip``            the axle moves ``k a`` sideways of its heading                   rad/(m/s^2)
``drift``           c_e grows by ``r`` of itself per hour (tyres warming)             1/h
``change_e, _d``    before a time in the log, c_e and c_d differ by these             m
==================  ==============================================================  ========

One rule decides which enter (:func:`held_out`): a departure enters where it *holds out*.
The clusters of windows are split in two halves (alternate ones, in time); fitted on either
half with the departure and without it, the fit with it must lower the other half's cost more,
on either half by more than half of Schwarz's penalty (``k ln n`` for ``k`` parameters and
``n`` the effective number of windows that inform them, and the log of the times tried for a
change: the cost is a sum of squares of
standardised residuals, so a departure that is not there gains about nothing, and one of twelve
tried passes by chance on few windows otherwise). Of those that hold out, the one that lowers
the held-out cost most enters first, the fit is redone with it, and the others are tested
again. What enters is estimated jointly with theta, and its uncertainty is in theta's
covariance (the joint information's inverse, sandwiched over clusters); what does not enter
moves nothing. A change's time, and a lag (nonlinear: found on a grid), are chosen on the half
they are fitted on. A departure the fit with it does not determine (within three of its
standard deviations of zero: it would only move theta), or whose fit it spoils (not finite,
a departure beyond any vehicle's, theta beyond any vehicle) is left out. The encoding's offset
is the exception a log's format states: where the wheel rates lie on an encoding's grid,
``offset`` is in the fit with a prior of half a step from the start.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from odocal.arrays import BoolArray, FloatArray
from odocal.checks.findings import Check, Finding, Severity
from odocal.data.drive import Drive, derivative_pieces
from odocal.model.vehicle import MODEL


@dataclass(frozen=True)
class Nuisance:
    """One nuisance parameter: its name (calibration.json's key), unit, label, and the largest
    magnitude it can have on a vehicle (a fit that needs more is not this departure)."""

    name: str
    unit: str
    label: str
    bound: float


#: The nuisance parameters, in their order in p (after theta).
NUISANCES: tuple[Nuisance, ...] = (
    Nuisance("spread", "steps^2", "the wheel unit's counting window beyond the lag", 1e4),
    Nuisance("lag", "steps", "the wheel stream's lag behind the reference", 1e3),
    Nuisance("offset", "rev/s", "both wheels' rate offset while moving", 1.0),
    Nuisance("offset_left", "rev/s", "the left wheel's own rate offset while moving", 1.0),
    Nuisance("offset_right", "rev/s", "the right wheel's own rate offset while moving", 1.0),
    Nuisance("arm_x", "m", "the reference point ahead of the rear axle", 20.0),
    Nuisance("arm_y", "m", "the reference point left of the rear axle", 20.0),
    Nuisance("curve", "m^2", "the wheels' excess travel per unit of curvature squared", 50.0),
    Nuisance("cut", "s^2", "the reference's shortfall in bends per unit of yaw rate squared",
             10.0),
    Nuisance("lateral_offset", "m/s^2", "a_y's offset", 5.0),
    Nuisance("lateral_scale", "1", "a_y's scale less one", 0.9),
    Nuisance("slip", "rad/(m/s^2)", "the rear axle's sideslip per m/s^2", 0.1),
    Nuisance("drift", "1/h", "c_e's relative change per hour", 0.015),
    Nuisance("change_e", "m", "c_e before the change less after it", 1.0),
    Nuisance("change_d", "m", "c_d before the change less after it", 1.0),
)
#: (len(NUISANCES),): each one's bound.
BOUNDS = np.array([n.bound for n in NUISANCES])
NAMES: tuple[str, ...] = tuple(n.name for n in NUISANCES)
THETA_SIZE = MODEL.size
#: The size of p: theta and every nuisance parameter.
P = THETA_SIZE + len(NUISANCES)


def at(name: str) -> int:
    """The position of nuisance ``name`` in p."""
    return THETA_SIZE + NAMES.index(name)


#: The groups that enter together (a change is a step of c_e and c_d at one time; each wheel's
#: own offset with the other's: the wheels' difference tells one wheel's offset well, and
#: which wheel it is, their mean against c_e, poorly, so neither is left out of the other).
BLOCKS: tuple[tuple[str, ...], ...] = (
    ("spread",), ("lag",), ("offset",), ("offset_left", "offset_right"), ("arm_x",),
    ("arm_y",), ("curve",), ("cut",), ("lateral_offset",), ("lateral_scale",), ("slip",),
    ("drift",), ("change_e", "change_d"))
#: Those that act through the reference channels (the reference's sideways motion, a_y).
REFERENCE_CHANNEL = ("arm_x", "slip", "lateral_offset", "lateral_scale")
#: Those the live path tries (a change it detects, and a drift it follows, over time).
LIVE: tuple[tuple[str, ...], ...] = tuple(b for b in BLOCKS if b[0] not in ("drift",
                                                                            "change_e"))
#: Those that move the wheels' timing (fitted only where the windows have a margin).
TIMING = ("spread", "lag")
#: Those that need a_y (a lateral acceleration column that carries one).
LATERAL = ("lateral_offset", "lateral_scale")
#: Those the sideways motion of the reference shows (a heading of its own, not the course).
ACROSS = ("arm_x", "slip")


@dataclass(frozen=True)
class Statistic:
    """A departure's held-out test: how much it lowers the other half's cost, fitted on either
    half of the clusters (``gains``, one per half; > 0 on both: it enters), and where (the
    change's first window after it; -1 where nothing is searched)."""

    block: tuple[str, ...]
    gains: tuple[float, float]
    where: int = -1
    penalty: float = 0.0

    @property
    def holds(self) -> bool:
        return min(self.gains) > 0.5 * self.penalty

    @property
    def value(self) -> float:
        return float(sum(self.gains))


Halves = Sequence[tuple[FloatArray, FloatArray]]


def held_out(halves: Halves, free: BoolArray, block: Sequence[int],
             common: tuple[FloatArray, FloatArray] | None = None) -> tuple[float, float]:
    """The held-out test of the parameters ``block`` (positions in p) at a fit over the
    ``free`` ones: on each half of the clusters (``halves``: its information and gradient at
    the fit, (P, P) and (P,)), the block's step fitted on that half along its own direction
    (what the free parameters already explain projected out, through the whole fit's
    information, ``common`` evidence such as folded sums included), and how much it lowers the
    *other* half's cost (to second order: ``2 g' d - d' H' d``). Returns the gain per half
    (> 0: the block holds out); -inf where a half cannot determine the block."""
    cols = np.flatnonzero(free)
    b = np.asarray(block, dtype=np.int64)
    total_h = np.asarray(halves[0][0] + halves[1][0], dtype=np.float64)
    if common is not None:
        total_h = total_h + common[0]
    if cols.size:
        project = total_h[np.ix_(b, cols)] @ np.linalg.pinv(total_h[np.ix_(cols, cols)])
        rows = np.concatenate([-project, np.eye(b.size)], axis=1)
    else:
        rows = np.eye(b.size)
    index = np.concatenate([cols, b])
    own = []
    for k in (0, 1):
        h, g = halves[k]
        own.append((rows @ h[np.ix_(index, index)] @ rows.T, rows @ g[index]))
    gains = []
    for k in (0, 1):
        info, score = own[k]
        scale = np.sqrt(np.clip(np.diag(info), 0.0, None))
        if not np.all(scale > 0):
            gains.append(-math.inf)
            continue
        scaled = info / np.outer(scale, scale)
        if np.linalg.cond(scaled) > 1e8:
            gains.append(-math.inf)
            continue
        step = np.linalg.solve(scaled, score / scale) / scale
        other_info, other_score = own[1 - k]
        gains.append(float(2.0 * other_score @ step - step @ other_info @ step))
    return gains[0], gains[1]


def penalty(size: int, windows: float, locations: int = 1) -> float:
    """Schwarz's penalty for ``size`` parameters on ``windows`` windows, and the log of the
    ``locations`` searched for one (a change's time)."""
    return size * math.log(max(windows, 3.0)) + math.log(max(locations, 1))


def corrected(drives: Sequence[Drive], values: Mapping[str, float],
              theta: FloatArray) -> list[Drive]:
    """The drives as the model sees them once the fitted departures ``values`` (name: value,
    as :data:`NUISANCES` keys them) are taken out: the reference on the wheels' clock and at
    the rear axle, the wheel rates without their offsets,
    their excess in bends and c_e's drift (theta at the end of each drive), the sideslip the
    axle's slip adds. What validation rolls out, and the exports' trajectories, so that the
    parameters are judged as they were fitted. A smoothing of the wheels is not undone."""
    from odocal.checks.departures import shifted_reference

    if not any(values.get(n, 0.0) for n in NAMES if n not in ("spread",)):
        return list(drives)
    out = []
    gain = MODEL.along_gain(np.asarray(theta, dtype=np.float64))
    for d in drives:
        t_s = d.t_s
        if values.get("lag"):
            d = shifted_reference(d, float(values["lag"]) * t_s)
        x, y, psi = (np.array(v, dtype=np.float64) for v in (d.x, d.y, d.psi))
        arm_x, arm_y = float(values.get("arm_x", 0.0)), float(values.get("arm_y", 0.0))
        x -= arm_x * np.cos(psi) - arm_y * np.sin(psi)
        y -= arm_x * np.sin(psi) + arm_y * np.cos(psi)
        a_y = np.asarray(d.a_y)                    # (theta is for a_y as logged)
        speed = np.hypot(derivative_pieces(x, t_s, d.pieces),
                         derivative_pieces(y, t_s, d.pieces))
        moving = np.where(speed > 0.5, 1.0, 0.0)
        n_rl, n_rr = np.array(d.n_rl, dtype=np.float64), np.array(d.n_rr, dtype=np.float64)
        offset = float(values.get("offset", 0.0))
        sign = np.sign(n_rl + n_rr) * moving
        n_rl -= (offset + float(values.get("offset_left", 0.0))) * sign
        n_rr -= (offset + float(values.get("offset_right", 0.0))) * sign
        curve = float(values.get("curve", 0.0))
        if curve:
            excess = np.zeros(d.n_samples)
            for a, b in d.pieces:                  # (never differenced across a gap)
                if b - a >= 2:
                    excess[a:b] = curve_excess(d.t[a:b], x[a:b], y[a:b], psi[a:b], curve)
            n_rl -= excess * gain[0]
            n_rr -= excess * gain[1]
            d = _front_less(d, excess * float(gain.mean()))
        drift = float(values.get("drift", 0.0))
        if drift:
            factor = 1.0 + drift * (d.t - d.t[-1]) / 3600.0
            n_rl, n_rr = n_rl * factor, n_rr * factor
        beta = np.asarray(d.beta) + float(values.get("slip", 0.0)) * a_y
        out.append(dataclasses.replace(d, x=x, y=y, a_y=a_y, n_rl=n_rl, n_rr=n_rr, beta=beta))
    return out


def excess_doubt(fitted: Mapping[str, float], stated_arm_x: float | None = None) -> float:
    """The ``curve`` departure (m^2) whose excess in bends the front fit carries as a
    systematic error, from the rear fit's departures ``fitted`` (name: value): the one it took
    in; else, where it took in the axle's slip (it described a sideslip the log lacks), the
    excess by geometry of a point at its lever arm (fitted, or ``stated_arm_x``, m, the
    settings' ``[reference] offset_m``): ``arm_x^2 / 2`` (a point ``a`` metres ahead of an axle
    that does not slide travels ``(a kappa)^2 / 2`` further in a bend, where its course is
    taken for its heading; the simulated cars without their sideslip column fit 0.65-0.94 m^2
    beside a lever arm of about 1.5 m, and where the held-out test left the excess out, the
    wheelbase came out 3-7 stds off); else 0 (no slip taken in: with a sideslip column the
    lever arm takes the point's motion back whole)."""
    curve = float(fitted.get("curve", 0.0))
    if curve or "slip" not in fitted:
        return curve
    arm = fitted.get("arm_x", stated_arm_x if stated_arm_x is not None else 0.0)
    return 0.5 * float(arm) ** 2


def curve_excess(t: FloatArray, x: FloatArray, y: FloatArray, psi: FloatArray,
                 curve: float) -> FloatArray:
    """The wheels' excess speed (m/s) over the reference's point (at ``x``, ``y``, heading
    ``psi``) that a ``curve`` departure (m^2) gives at each sample: ``curve kappa^2 v`` where
    moving (the curvature clipped to 0.5 1/m)."""
    speed = np.hypot(np.gradient(x, t), np.gradient(y, t))
    moving = np.where(speed > 0.5, 1.0, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        kappa = np.where(moving > 0, np.gradient(np.unwrap(psi), t) / speed, 0.0)
    return np.asarray(curve * np.clip(kappa, -0.5, 0.5) ** 2 * speed * moving)


def _front_less(d: Drive, excess_revps: FloatArray) -> Drive:
    """``d`` with its front wheels' rates (where it has them) less ``excess_revps``: the
    wheels' excess in bends over what the reference's point travels is the reference's
    (a point off the axle, a heading that is the course), so every wheel reads it."""
    if "n_fl" not in d.inputs:
        return d
    inputs = dict(d.inputs)
    for key in ("n_fl", "n_fr"):
        rate = np.asarray(inputs[key], dtype=np.float64)
        inputs[key] = rate - excess_revps * np.sign(rate)
    return dataclasses.replace(d, inputs=inputs)


#: Wheels whose excess in bends puts them this far ahead of the rear axle (m, a short car's
#: wheelbase) ...
FRONT_MIN_M = 1.5
#: ... determined beyond this many standard deviations, are front wheels mapped as rear ones.
_FRONT_SIGMAS = 5.0


def findings(p: FloatArray, std: FloatArray, entered: Sequence[str], *, t_s: float,
             reference_shift_s: float = 0.0, change: tuple[float, str] | None = None,
             heading_own: bool = False,
             rivals: Mapping[str, Mapping[str, float]] | None = None) -> list[Finding]:
    """What the entered departures say, each named with its value and standard deviation
    (``std`` (P,)). ``change``: the change's time and drive; ``heading_own``: the reference's
    heading is its own, not its course (front wheels can then be told from a lever arm);
    ``rivals``: each entered departure's rivals' held-out gains in the round it entered."""
    out: list[Finding] = []
    rivals = rivals or {}
    names = set(entered)

    def value(name: str) -> tuple[float, float]:
        return float(p[at(name)]), float(std[at(name)])

    if "lag" in names:
        lag, lag_std = value("lag")
        out.append(Finding(Check.REFERENCE_LAG, Severity.NOTE,
                           reference_shift_s + lag * t_s, lag_std * t_s, "reference"))
    if "spread" in names:
        spread, spread_std = value("spread")
        out.append(Finding(Check.WHEEL_SMOOTHING, Severity.NOTE,
                           math.sqrt(2.0 * max(spread, 0.0)) * t_s,
                           spread_std / max(math.sqrt(2.0 * max(spread, 1e-12)), 1e-12) * t_s,
                           "wheels"))
    if "offset" in names:
        out.append(Finding(Check.MOVING_OFFSET, Severity.NOTE, *value("offset")))
    for name, wheel in (("offset_left", "left"), ("offset_right", "right")):
        if name in names:
            out.append(Finding(Check.WHEEL_SKEW, Severity.NOTE, *value(name), wheel))
    for name, label in (("arm_x", "ahead"), ("arm_y", "left")):
        if name in names:
            out.append(Finding(Check.REFERENCE_ARM, Severity.NOTE, *value(name), label))
    if "curve" in names:
        q, q_std = value("curve")
        out.append(_curve_finding(q, q_std, rivals.get("curve", {}), heading_own=heading_own))
    if "cut" in names:
        out.append(Finding(Check.REFERENCE_SMOOTHED, Severity.NOTE, *value("cut")))
    if "lateral_offset" in names:
        out.append(Finding(Check.LATERAL_OFFSET, Severity.NOTE, *value("lateral_offset"),
                           "a_y"))
    if "lateral_scale" in names:
        out.append(Finding(Check.LATERAL_GAIN, Severity.NOTE, *value("lateral_scale"), "a_y"))
    if "slip" in names:
        out.append(Finding(Check.SIDESLIP, Severity.NOTE, *value("slip")))
    if "drift" in names:
        out.append(Finding(Check.DRIFT, Severity.NOTE, *value("drift"), "c_e"))
    if "change_e" in names and change is not None:
        out.append(_change_finding(p, std, change))
    return out


def _curve_finding(q: float, q_std: float, mine: Mapping[str, float], *,
                   heading_own: bool) -> Finding:
    """The curve departure ``q`` (m^2): wheels that travel more, or less, than the rear axle in
    bends, or front wheels mapped as the rear ones where nothing else explains them (``mine``:
    the held-out gains of the curve's rivals in the round it entered)."""
    distance = math.sqrt(2.0 * q) if q > 0 else 0.0
    ahead = mine.get("curve", math.inf) - mine.get("cut", -math.inf)
    if heading_own and distance >= FRONT_MIN_M and q > _FRONT_SIGMAS * q_std \
            and ahead > mine.get("penalty", 0.0):
        # wheels a wheelbase ahead of the axle, on a reference with its own heading (no
        # course for a lever arm to hide in), and nothing else explains them: a smoothed
        # reference (``cut``, which grows with speed) held out by less, by more than the
        # penalty of a parameter, when they entered (the one rule, between the two)
        return Finding(Check.FRONT_WHEELS, Severity.FATAL, distance,
                       q_std / max(2.0 * distance, 1e-9))
    return Finding(Check.CURVE_EXCESS, Severity.NOTE, q, q_std)


def as_excess(findings: Sequence[Finding]) -> list[Finding]:
    """``findings`` with front wheels named in the rear columns (the fatal
    :attr:`~odocal.checks.findings.Check.FRONT_WHEELS`) turned into the note of the wheels'
    excess in bends that it was judged from: for a car whose four wheels show each front one
    travelling further in bends than its rear one
    (:func:`odocal.estimators.front_axle.front_ahead`), that excess is the reference's."""
    out = []
    for f in findings:
        if f.check is Check.FRONT_WHEELS and f.severity is Severity.FATAL:
            distance = float(f.value)
            f = Finding(Check.CURVE_EXCESS, Severity.NOTE, 0.5 * distance ** 2,
                        float(f.reference) * 2.0 * distance)
        out.append(f)
    return out


def _change_finding(p: FloatArray, std: FloatArray, change: tuple[float, str]) -> Finding:
    """The step of c_e and c_d at ``change`` (its time and drive), named by the parameter whose
    step stands out more against its standard deviation."""
    # as the parameter's relative change (c_e), or its change over c_e (c_d), after less
    # before: the calibration is of the part after it
    when, where = change
    lay = MODEL.layout
    c_e = float(p[lay.index(lay.scale)])
    step_e, step_d = float(p[at("change_e")]), float(p[at("change_d")])
    sizes = {"c_e": -step_e / max(c_e + step_e, 1e-9), "c_d": -step_d / max(c_e, 1e-9)}
    stds = {"c_e": float(std[at("change_e")]) / max(c_e, 1e-9),
            "c_d": float(std[at("change_d")]) / max(c_e, 1e-9)}
    parameter = max(sizes, key=lambda k: abs(sizes[k]) / max(stds[k], 1e-12))
    return Finding(Check.CHANGE_IN_LOG, Severity.FALLBACK, sizes[parameter], when,
                   f"{parameter}|{where}")
