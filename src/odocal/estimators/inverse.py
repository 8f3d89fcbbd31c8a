"""The default method (``inverse``): the wheel rates as the measurement, the motion as the model.

The paper's Gauss-Newton rolls the model out *with the measured wheel rates as inputs* and fits
the poses. Wheel-rate noise then sits in the regressors: integrated along a segment it blurs the
heading, which shrinks the rolled-out trajectory (c_e comes out too large) and attenuates the
yaw-rate gain (t_r comes out too large): the errors-in-variables bias, which grows with the
square of the noise. The three-step method inherits it from its step-1 sets; compensation cannot
remove what it does not know.

Here the model runs the other way: from the reference motion of each step (along-track
displacement ``ds`` and heading change ``dpsi``, by (1) inverted), (2)-(3) give the revolutions
each rear wheel must have turned::

    n_rl t_s = (ds - t_r dpsi / 2) / c_rl,      n_rr t_s = (ds + t_r dpsi / 2) / c_rr

and theta is fitted to the *measured* revolutions, summed over short windows (``window_s``).
Wheel errors of every kind that is independent of the reference (white, growing with the rate,
coloured, slip, quantisation) are now in the measurement, where least squares is unbiased; only
the reference's own errors sit in the regressors, and over a window of seconds they are tiny
against the motion.

This module is the batch front of the method: the drives become one window set
(:mod:`odocal.estimators.windows`), fitted by the core that the online calibrator runs too
(:mod:`odocal.estimators.core`: the lag, the error model of
:mod:`odocal.estimators.error_model`, the covariance, the identifiability verdict); a constant
heading offset of the reference is measured on straight stretches and applied.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from odocal.arrays import BoolArray, FloatArray, IntArray
from odocal.checks.departures import wheel_lag_s, wheel_step
from odocal.checks.findings import Check, Finding, Severity
from odocal.data.drive import Drive
from odocal.data.segments import common_sampling_time
from odocal.estimators import core, departures, fitting
from odocal.estimators.base import MethodOutcome, Prepared, ProgressCallback
from odocal.estimators.covariance import MIN_CLUSTERS_FOR_ROBUST
from odocal.estimators.error_model import (
    CHANNELS,
    HUBER,
    expected_revolutions,
    window_variance,
)
from odocal.estimators.estimate import (
    CovarianceKind,
    Estimate,
    NotIdentified,
    Reason,
    Status,
    judge,
)
from odocal.estimators.windows import (
    AT_LAT,
    WindowSet,
    heading_offset,
    windows_from_drives,
)
from odocal.model.parameters import PARAMETER_NAMES, PARAMETERS, Parameters
from odocal.model.vehicle import MODEL
from odocal.settings import Settings

log = logging.getLogger(__name__)

#: Fewer moving windows than this: nothing to fit.
MIN_WINDOWS = 4
LAYOUT = MODEL.layout


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
    delay_found_s: float = 0.0
    """The lag the scan found, applied or not."""
    wheel_offset_revps: float = 0.0
    """The wheel rates' constant offset while moving, rev/s (a biased speed signal; rates
    truncated towards zero read half a step low)."""
    wheel_offset_std: float = 0.0
    """Its standard deviation (about the prior's where the drive does not determine it)."""
    findings: tuple[Finding, ...] = ()
    """What the fit's residuals showed (a change inside the log, front wheels)."""
    delay_note: str = ""
    """Why the lag found was not applied: ``within noise`` (under three standard deviations),
    ``does not hold out`` (found on half the clusters, it does not lower the other half's
    cost), ``flat`` (no bends to time the wheels by), ``edge`` (beyond the search range)."""
    t0: FloatArray = field(default_factory=lambda: np.zeros(0), repr=False)
    """(W,): each window's first wheel step on its drive's clock, s (the drive is ``cluster //
    10**9``): where the fitted windows lie, for the report."""
    departures: tuple[tuple[str, float, float], ...] = ()
    """The departures fitted beside theta (:mod:`odocal.estimators.departures`): name, value
    and standard deviation, in the order they entered."""
    @property
    def fitted_departures(self) -> dict[str, float]:
        """The departures fitted, by name: what validation takes out of the drives."""
        return {name: value for name, value, _ in self.departures}

    tests: tuple[tuple[str, float, float], ...] = ()
    """Each departure's last held-out test: name, and how much it lowered the other half's
    cost fitted on either half (it enters where both are positive)."""

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
                "delay_found_s": self.delay_found_s, "delay_note": self.delay_note,
                "wheel_offset_revps": self.wheel_offset_revps,
                "wheel_offset_std_revps": self.wheel_offset_std,
                "departures": {name: {"value": value, "std": std}
                               for name, value, std in self.departures},
                "departure_tests": {name: {"held_out_gains": [first, second]}
                                    for name, first, second in self.tests},
                "elapsed_s": self.elapsed_s}


def inverse_calibration(drives: Sequence[Drive], *, settings: Settings,
                        held: Mapping[str, NotIdentified] | None = None,
                        distance_only: bool = False,
                        progress: Callable[[str, int, int], None] | None = None) -> Estimate:
    """Calibrate theta by fitting the wheel revolutions the reference motion implies, with the
    departures the drives show (:mod:`odocal.estimators.departures`).

    ``distance_only`` fits the distance channel alone (the wheels carry no differential signal:
    hold c_d, t_r and d). Returns an :class:`~odocal.estimators.estimate.Estimate` with
    :class:`InverseDetails`.
    """
    started = time.perf_counter()
    t_s = common_sampling_time(drives)
    if progress:
        progress("inverse: fit", 0, 2)
    windows, straight = windows_from_drives(drives, settings, reach_s=_reach(drives, settings))
    offset = heading_offset(straight) if settings.inverse.heading_offset == "estimate" else 0.0
    if windows.size < MIN_WINDOWS:
        log.warning("inverse calibration: the drives hold fewer than %d moving windows",
                    MIN_WINDOWS)
        return _nothing(settings, dict(held or {}), started, windows.length * t_s)
    if progress:
        progress("inverse: fit", 1, 2)
    prior = fitting.Folded.prior(_origin(settings),
                                 core.offset_prior_std(settings, wheel_step(drives, settings)))
    found, windows, departing = _fit_agreeing(windows, prior, settings, drives,
                                              heading_offset=offset, held=held,
                                              distance_only=distance_only)
    if progress:
        progress("inverse: fit", 2, 2)
    estimate = _estimate(found, windows, settings, started, method="inverse",
                         reference_shift_s=_shifted(drives))
    findings = [*departing,
                *_findings(found, windows, drives, reference_shift_s=_shifted(drives))]
    if findings:
        estimate = dataclasses.replace(estimate, details=dataclasses.replace(
            estimate.details, findings=tuple(findings)))
    return estimate


#: Most drives whose leaving out is tried (:func:`_fit_agreeing`).
_MAX_TRIED = 12


def _fit_agreeing(windows: WindowSet, prior: fitting.Folded, settings: Settings,
                  drives: Sequence[Drive], *, heading_offset: float,
                  held: Mapping[str, NotIdentified] | None, distance_only: bool,
                  ) -> tuple[core.CoreFit, WindowSet, list[Finding]]:
    """The one fit of the drives that agree. A drive departs where its windows depart from
    the others' fit (:func:`odocal.estimators.core.departing_drive`), or where the others
    without it identify a parameter they do not with it (it takes knowledge away: a scene that
    stands still but for one tight crawl, a log of another tyre): it is named and left out,
    and the rest fitted again, while two drives or more are left. More data never makes the
    calibration know less."""
    named: list[Finding] = []

    def one(win: WindowSet) -> core.CoreFit:
        return core.fit(win, prior, settings, heading_offset=heading_offset, held=held,
                        distance_only=distance_only, setup=fit_setup(win, settings, held))

    found = one(windows)
    while True:
        labels = np.unique(windows.cluster // 10**9)
        if labels.size < 2:
            return found, windows, named
        departing = core.departing_drive(found, windows)
        choice: tuple[int, float, float, core.CoreFit | None] | None = None
        if departing is not None:
            choice = (*departing, None)
        elif not found.free.all() and labels.size <= _MAX_TRIED:
            knows = set(np.flatnonzero(found.free))
            for label in labels:
                rest = windows.take(windows.cluster // 10**9 != label)
                if rest.size < MIN_WINDOWS:
                    continue
                others = one(rest)
                gained = set(np.flatnonzero(others.free)) - knows
                if gained and knows <= set(np.flatnonzero(others.free)) \
                        and (choice is None or len(gained) > choice[1]):
                    choice = (int(label), float(len(gained)), 0.0, others)
        if choice is None:
            return found, windows, named
        label, statistic, limit, refit = choice
        kept = windows.take(windows.cluster // 10**9 != label)
        if kept.size < MIN_WINDOWS:
            return found, windows, named
        log.warning("%s departs from the other drives: left out", drives[label].name)
        named.append(Finding(Check.DRIVE_DEPARTS, Severity.NOTE, statistic, limit,
                             drives[label].name))
        windows = kept
        found = one(windows) if refit is None else refit


def fit_setup(windows: WindowSet, settings: Settings,
              held: Mapping[str, NotIdentified] | None = None, *,
              blocks: tuple[tuple[str, ...], ...] = departures.BLOCKS) -> core.Setup:
    """What the one fit may take beside theta on these windows: every departure of ``blocks``
    (:mod:`odocal.estimators.departures`); the reference's sideways motion as a channel where
    its heading is its own (not the course: a course has no sideways motion at all); a_y as a
    channel where it carries a lateral acceleration; the lever arm where the settings state it;
    each window's hours to its drive's end (c_e's drift)."""
    lateral = not (held and LAYOUT.load in held
                   and held[LAYOUT.load].reason is Reason.NO_LATERAL)
    at, _ = windows.at(0.0, 0.0)
    across = float(np.sqrt(np.mean(at[:, AT_LAT] ** 2))) if windows.size else 0.0
    along = float(np.sqrt(np.mean(at[:, 0] ** 2))) if windows.size else 0.0
    stated: dict[str, float] = {}
    if settings.reference.offset_m is not None:
        stated = {"arm_x": settings.reference.offset_m[0],
                  "arm_y": settings.reference.offset_m[1]}
    drive = windows.cluster // 10**9
    span = windows.length * windows.t_s
    ends = {int(k): float((windows.t0[drive == k] + span).max()) for k in np.unique(drive)}
    tau = (windows.t0 + 0.5 * span - np.array([ends[int(k)] for k in drive])) / 3600.0
    return core.Setup(blocks=blocks, across=across > _COURSE_RATIO * along, lateral=lateral,
                      stated=stated, tau_h=tau)


#: A reference whose motion across its heading is smaller than this share of its motion along
#: it has no heading of its own (its heading is its course): the sideways channel is left out.
_COURSE_RATIO = 1e-4


def _findings(found: core.CoreFit, windows: WindowSet, drives: Sequence[Drive], *,
              reference_shift_s: float) -> list[Finding]:
    """What the fit's departures say (:func:`odocal.estimators.departures.findings`)."""
    change = None
    if found.change > 0:
        drive = drives[int(windows.cluster[found.change] // 10**9)]
        change = (float(windows.t0[found.change]), drive.name)
        log.warning("the drives change at t = %.0f s of %s: calibrating the part after it",
                    change[0], drive.name)
    return departures.findings(_total(found), found.nuisance_std, found.entered,
                               t_s=windows.t_s, reference_shift_s=reference_shift_s,
                               change=change, heading_own=fit_setup(windows, Settings()).across,
                               rivals=found.rivals)


def _total(found: core.CoreFit) -> FloatArray:
    """The fit's p with the lag as a whole (the shift the fit stands at, in steps)."""
    p = found.fit.p.copy()
    p[fitting.LAG] = found.lag.shift if "lag" in found.entered else 0.0
    return p


@dataclass(frozen=True)
class Screen:
    """What the default method's windows and one fit say of drives a segment method calibrates
    (:func:`screen`).

    findings : the departures it found (a change inside the log among them)
    theta, std : its estimate and standard deviations; for a parameter it holds, what the data
        determine it to where they give a number (nan otherwise)
    free : the parameters it identifies
    """

    findings: tuple[Finding, ...]
    theta: FloatArray
    std: FloatArray
    free: BoolArray


def screen(drives: Sequence[Drive], settings: Settings) -> Screen | None:
    """The default method's departures and estimate on ``drives``, for the methods that fit
    segments: their own residuals show no change inside the log (a segment's fit takes a
    change into its theta), and the default's standard deviations are at the information's
    bound, which no unbiased method beats. None where the drives hold too few moving
    windows."""
    windows, straight = windows_from_drives(drives, settings, reach_s=_reach(drives, settings))
    if windows.size < MIN_WINDOWS:
        return None
    offset = heading_offset(straight) if settings.inverse.heading_offset == "estimate" else 0.0
    prior = fitting.Folded.prior(_origin(settings),
                                 core.offset_prior_std(settings, wheel_step(drives, settings)))
    found = core.fit(windows, prior, settings, heading_offset=offset,
                     setup=fit_setup(windows, settings))
    findings = _findings(found, windows, drives, reference_shift_s=_shifted(drives))
    std = np.sqrt(np.clip(np.diag(found.covariance), 0.0, None))
    held = np.array([found.held[n].std if n in found.held else np.nan
                     for n in PARAMETER_NAMES])
    return Screen(findings=tuple(findings), theta=found.theta.copy(),
                  std=np.where(found.free, std, held), free=np.asarray(found.free, dtype=bool))


def _reach(drives: Sequence[Drive], settings: Settings) -> float:
    """How far the lag scan must reach: ``[inverse] lag_scan_s`` around the lag the
    cross-correlation finds (none on drives already on the wheels' clock, as a calibration
    aligns them: :mod:`odocal.checks.departures`), at most ``max_delay_s``."""
    cfg = settings.inverse
    if cfg.delay != "estimate":
        return cfg.lag_scan_s
    coarse = wheel_lag_s(drives, np.asarray(settings.identify.theta0, dtype=np.float64),
                         settings)
    if coarse is None or abs(coarse) <= 0.5 * cfg.lag_scan_s:
        return cfg.lag_scan_s
    return min(abs(coarse) + 0.5 * cfg.lag_scan_s, cfg.max_delay_s)


def _shifted(drives: Sequence[Drive]) -> float:
    """The reference shift a calibration applied to these drives before the fit (their
    metadata's ``reference_shift_s``; 0 where none)."""
    shifts = {float(d.metadata.get("reference_shift_s", 0.0)) for d in drives}
    return shifts.pop() if len(shifts) == 1 else 0.0


def _origin(settings: Settings) -> FloatArray:
    """Where folded coupling moments are taken (the datasheet values, kappa and the offsets
    0)."""
    theta0 = np.asarray(settings.identify.theta0, dtype=np.float64)
    return np.concatenate([theta0, np.zeros(fitting.P - theta0.size)])


def _estimate(found: core.CoreFit, windows: WindowSet, settings: Settings,
              started: float, *, method: str, reference_shift_s: float = 0.0) -> Estimate:
    datasheet = np.asarray(settings.identify.theta0, dtype=np.float64)
    fit, free = found.fit, found.free
    noise = found.model.noise
    rms = np.sqrt(np.mean(fit.residual**2, axis=0))
    z = np.abs(fit.decoupled) * np.sqrt(
        1.0 / window_variance(expected_revolutions(windows.measured, fit.residual), noise))
    t_s = windows.t_s
    details = InverseDetails(
        windows=windows.size, window_s=windows.length * t_s, clusters=found.clusters,
        delay_s=found.lag.shift * t_s + reference_shift_s, delay_std_s=found.lag.std * t_s,
        heading_offset_rad=found.heading_offset,
        noise=((float(noise[0, 0]), float(noise[0, 1])), (float(noise[1, 0]),
                                                          float(noise[1, 1]))),
        downweighted=int((z > HUBER).any(axis=1).sum()), iterations=fit.iterations,
        cost_history=fit.history, residual_rms=(float(rms[0]), float(rms[1])),
        elapsed_s=time.perf_counter() - started, information=found.uncertainty.information,
        scores=found.uncertainty.scores, cluster=windows.cluster,
        measured=windows.measured @ CHANNELS.T, residual=fit.residual,
        prewhitening=(float(found.model.ma[0, 0]), float(found.model.ma[1, 0])),
        smoothing_steps2=float(2.0 * fit.p[fitting.KAPPA]), coupling=float(found.model.coupling),
        delay_found_s=found.lag.found * t_s + reference_shift_s, delay_note=found.lag.note,
        wheel_offset_revps=found.offset[0], wheel_offset_std=found.offset[1], t0=windows.t0,
        departures=tuple((name, float(_total(found)[departures.at(name)]),
                          float(found.nuisance_std[departures.at(name)]))
                         for name in found.entered),
        tests=tuple(("+".join(s.block), *s.gains) for s in found.statistics))
    if not free.any():
        status = Status.NOTHING_IDENTIFIABLE
    elif float(np.max(rms)) < 1e-9:
        status = Status.EXACT
    else:
        status = Status.CONVERGED if fit.converged else Status.ITERATION_LIMIT
    theta = found.theta.copy()
    theta[~free] = datasheet[~free]
    std = np.sqrt(np.clip(np.diag(found.covariance), 0.0, None))
    return Estimate(method=method, theta=Parameters.from_array(theta),
                    datasheet=Parameters.from_array(datasheet), covariance=found.covariance,
                    covariance_kind=(CovarianceKind.CLUSTER_ROBUST
                                     if found.clusters >= MIN_CLUSTERS_FOR_ROBUST
                                     else CovarianceKind.RESIDUAL),
                    free=tuple(bool(f) for f in free),
                    verdicts=judge(std, free, settings.identify, held=found.held),
                    status=status, details=details, widening=found.uncertainty.widening)


def _nothing(settings: Settings, held: dict[str, NotIdentified], started: float,
             window_s: float) -> Estimate:
    for name in PARAMETER_NAMES:
        held.setdefault(name, NotIdentified(Reason.NO_INFORMATION))
    datasheet = np.asarray(settings.identify.theta0, dtype=np.float64)
    details = InverseDetails(
        windows=0, window_s=window_s, clusters=0, delay_s=0.0, delay_std_s=float("nan"),
        heading_offset_rad=0.0, noise=((0.0, 0.0), (0.0, 0.0)), downweighted=0, iterations=0,
        cost_history=(), residual_rms=(0.0, 0.0), elapsed_s=time.perf_counter() - started,
        information=np.zeros((0, PARAMETERS, PARAMETERS)), scores=np.zeros((0, PARAMETERS)),
        cluster=np.zeros(0, dtype=np.int64), measured=np.zeros((0, 2)),
        residual=np.zeros((0, 2)))
    return Estimate(method="inverse", theta=Parameters.from_array(datasheet),
                    datasheet=Parameters.from_array(datasheet),
                    covariance=np.zeros((PARAMETERS, PARAMETERS)),
                    covariance_kind=CovarianceKind.NONE, free=(False,) * PARAMETERS,
                    verdicts=judge(np.zeros(PARAMETERS), np.zeros(PARAMETERS, dtype=bool),
                                   settings.identify, held=held),
                    status=Status.NOTHING_IDENTIFIABLE, details=details)


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
    """The wheels carry no differential signal: c_e alone, from the distance channel (the
    parameters that need it are held in ``prep.held``, :func:`~odocal.estimators.base.
    held_by_checks`).

    Every other method takes the heading from the wheels, so none of them can use such data;
    the distance channel needs the wheels' mean only.
    """
    return MethodOutcome(estimate=inverse_calibration(prep.drives, settings=settings,
                                                      held=prep.held, distance_only=True,
                                                      progress=progress))
