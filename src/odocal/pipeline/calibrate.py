"""METHOD 5: calibrating a vehicle from one or more drives.

:func:`calibrate` is the front door: it checks its arguments once, cuts the drives into
identification and validation segments, runs the chosen method (the one place a method is
chosen) and validates the answer.

Methods (:data:`METHODS`)
-------------------------
``raw``
    Batch Gauss-Newton on every selected segment with the measured wheel rates.
``compensated``
    The paper's three-step architecture (see :mod:`odocal.estimators.compensated`): step-1 batches
    on measured
    rates, input compensation of every selected segment with five step-1 parameter sets, and a
    final batch Gauss-Newton on all selected segments with the compensated rates.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import logging
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from odocal import __version__
from odocal.checks.diagnosis import Diagnosis, check_drives, gate
from odocal.data.drive import Drive
from odocal.data.segments import (
    RaggedSegments,
    SegmentBatch,
    SegmentSet,
    common_sampling_time,
    gather,
    identification_segments,
    validation_segments,
)
from odocal.errors import ConfigError, DataError
from odocal.estimators import DEFAULT_METHOD
from odocal.estimators.covariance import BootstrapResult, bootstrap
from odocal.estimators.estimate import (
    Estimate,
    NotIdentified,
    Reason,
    Status,
    held_as_weak,
    refused_estimate,
    weak,
)
from odocal.estimators.validation import (
    MinimumResult,
    ValidationResult,
    segment_errors,
    validation_data,
)
from odocal.io.drivefile import load_drive
from odocal.model.parameters import PARAMETER_NAMES, Parameters
from odocal.settings import Settings

if TYPE_CHECKING:
    from odocal.estimators.compensated import ThreeStepOutcome
    from odocal.pipeline.compare import Comparison

# The estimators are imported where they are run: a calibration loads only its own method.
log = logging.getLogger(__name__)

#: ``progress(stage, done, total)``: called as long steps advance (the CLI draws bars from it).
ProgressCallback = Callable[[str, int, int], None]
IntArray = NDArray[np.int64]
BoolArray = NDArray[np.bool_]

#: Parameters observable only through the yaw equation in bends (METHOD 2).
NEED_BENDS = ("t_r", "d")
#: Parameters that need the two wheels' difference (all but the distance scale).
NEED_DIFFERENTIAL = ("c_d", "t_r", "d")


@dataclass(frozen=True)
class DriveSummary:
    """What a calibration read: one entry per drive."""

    name: str
    samples: int
    duration_s: float
    distance_m: float
    pieces: int
    sha256: str | None

    def to_dict(self) -> dict[str, object]:
        return {"name": self.name, "samples": self.samples, "duration_s": self.duration_s,
                "distance_m": self.distance_m, "pieces": self.pieces, "sha256": self.sha256}


@dataclass(frozen=True)
class Prepared:
    """The drives cut into segments, ready for any method.

    drives : the drives
    segments : every identification segment (with the selection rule's verdict)
    used : mask over ``segments`` of those to identify from
    held : parameters the selection already knows the data cannot identify (no bends)
    batch : the used segments' data, measured rates
    clusters : cluster label of each used segment (overlapping segments share one)
    validation_segments, validation : the validation segments and their data (None without any)
    warnings : what the user should know about the data
    """

    drives: tuple[Drive, ...]
    segments: SegmentSet
    used: BoolArray
    held: Mapping[str, NotIdentified]
    clusters: IntArray
    validation_segments: SegmentSet
    validation: RaggedSegments | None
    warnings: tuple[str, ...]

    @functools.cached_property
    def batch(self) -> SegmentBatch:
        """The used segments' data (gathered when a segment-based method asks for it)."""
        return gather(self.drives, self.segments.subset(self.used))


@dataclass(frozen=True)
class BootstrapTerms:
    """What the bootstrap resamples: per-unit information and scores at the estimate.

    information : ndarray, shape (N, 4, 4); scores : ndarray, shape (N, 4); clusters : (N,)
    refit : theta from a resample of the units (``bootstrap_mode = "full"``), or None
    step1_thetas, step1_sets : the three-step method's step-1 sets (redrawn too)
    """

    information: NDArray[np.float64]
    scores: NDArray[np.float64]
    clusters: IntArray
    refit: Callable[[IntArray], NDArray[np.float64]] | None = None
    step1_thetas: NDArray[np.float64] | None = None
    step1_sets: int = 0


@dataclass(frozen=True)
class MethodOutcome:
    """What a method returns to the front door."""

    estimate: Estimate
    three_step: ThreeStepOutcome | None = None
    warnings: tuple[str, ...] = ()
    bootstrap: BootstrapTerms | None = None
    """What to bootstrap over; None: the method has no bootstrap."""


def _gn_terms(rates: SegmentBatch, estimate: Estimate, prep: Prepared, settings: Settings,
              **extra: Any) -> BootstrapTerms:
    """Bootstrap terms of a Gauss-Newton estimate on ``rates`` (the segments it used)."""
    from odocal.estimators.gauss_newton import gauss_newton, linearise

    lin = linearise(rates, estimate.theta.as_array(), np.asarray(settings.identify.weights))
    held = {n: NotIdentified(Reason.HELD) for n, f in zip(PARAMETER_NAMES, estimate.free,
                                                         strict=True) if not f}
    loose = dataclasses.replace(settings.identify, judge_identifiability=False, max_iterations=3)

    def refit(take: IntArray) -> NDArray[np.float64]:
        return gauss_newton(rates.take(take), settings=loose, start=estimate.theta.as_array(),
                            held=held).theta.as_array()

    return BootstrapTerms(information=lin.information, scores=lin.scores,
                          clusters=prep.clusters, refit=refit, **extra)


def _run_raw(prep: Prepared, settings: Settings,
             progress: ProgressCallback | None) -> MethodOutcome:
    from odocal.estimators.gauss_newton import gauss_newton

    if progress:
        progress("identify", 0, 1)
    est = gauss_newton(prep.batch, settings=settings.identify, clusters=prep.clusters,
                       held=prep.held, method="raw")
    if progress:
        progress("identify", 1, 1)
    return MethodOutcome(estimate=est, bootstrap=_gn_terms(prep.batch, est, prep, settings))


def _run_compensated(prep: Prepared, settings: Settings,
                     progress: ProgressCallback | None) -> MethodOutcome:
    from odocal.estimators.compensated import three_step

    outcome = three_step(prep.batch, prep.validation, settings=settings, clusters=prep.clusters,
                         held=prep.held, progress=progress)
    s1 = outcome.step1
    rates = prep.batch.with_wheel_rates(outcome.compensation.n_rl, outcome.compensation.n_rr)
    return MethodOutcome(estimate=outcome.final, three_step=outcome, warnings=outcome.warnings,
                         bootstrap=_gn_terms(rates, outcome.final, prep, settings,
                                             step1_thetas=s1.thetas[s1.success],
                                             step1_sets=int(s1.picked.size)))


def _run_inverse(prep: Prepared, settings: Settings,
                 progress: ProgressCallback | None) -> MethodOutcome:
    from odocal.estimators.inverse import inverse_calibration

    # No bootstrap: its errors telescope (quantised counts, a reference's errors differenced
    # over windows), which resampling clusters cannot see; the sandwich's full neighbour term
    # does, and the noise matrix checks it against the truth (benchmarks/bench_matrix.py).
    est = inverse_calibration(prep.drives, settings=settings, held=prep.held, progress=progress)
    return MethodOutcome(estimate=est)


#: The estimator behind each name of :data:`odocal.estimators.METHOD_NAMES`.
METHODS: Mapping[str, Callable[[Prepared, Settings, ProgressCallback | None], MethodOutcome]] = {
    "inverse": _run_inverse,
    "compensated": _run_compensated,
    "raw": _run_raw,
}


@dataclass(frozen=True)
class CalibrationResult:
    """Everything a calibration found, and how.

    estimate : the calibrated parameters, their covariance and the identifiability verdicts
    validation : E_p of the estimate on the validation segments (None without any)
    datasheet_validation : E_p of the datasheet values on the same segments
    segments : the identification segments (with the selection rule's verdict)
    used : mask over ``segments`` of those identified from
    drives : what was read
    warnings : things the user should know (weak data, failed solves, fallbacks)
    bootstrap : the bootstrap check of the covariance (None when off or not applicable)
    three_step : the three-step method's intermediate results (``compensated`` only)
    batch : the identification segments' data with the measured rates
    drive_data : the drives themselves (for plots)
    timings_s : wall time of each stage (read, segments, the method's steps, bootstrap,
        validation)
    diagnosis : the checks of the data against the model, before and after the fit
    comparison : every method scored on held-out data (``--compare``; see
    :mod:`odocal.pipeline.compare`)
    """

    estimate: Estimate
    validation: ValidationResult | None
    datasheet_validation: ValidationResult | None
    segments: SegmentSet
    used: BoolArray
    drives: tuple[DriveSummary, ...]
    settings: Settings
    warnings: tuple[str, ...]
    elapsed_s: float
    bootstrap: BootstrapResult | None = None
    three_step: ThreeStepOutcome | None = None
    batch: SegmentBatch | None = field(default=None, repr=False)
    drive_data: tuple[Drive, ...] = field(default=(), repr=False)
    timings_s: dict[str, float] = field(default_factory=dict)
    diagnosis: Diagnosis = field(default_factory=lambda: Diagnosis(()))
    comparison: Comparison | None = None

    @property
    def theta(self) -> Parameters:
        return self.estimate.theta

    @property
    def method(self) -> str:
        return self.estimate.method

    @property
    def success(self) -> bool:
        return self.estimate.success

    @property
    def segments_used(self) -> int:
        return int(self.used.sum())

    def to_dict(self) -> dict[str, Any]:
        """The content of ``calibration.json``."""
        est = self.estimate
        out: dict[str, Any] = {"odocal_version": __version__, **est.to_dict()}
        out["unidentified_reasons"] = {n: est.verdict(n).reason.value  # type: ignore[union-attr]
                                       for n in est.unidentified}
        out["segments_used"] = self.segments_used
        out["segments_total"] = len(self.segments)
        out["segments_selected"] = int(self.segments.selected.sum())
        out["validation"] = (self.validation.to_dict() if self.validation is not None
                             else {"E_p_m": None, "segments": 0})
        out["datasheet"] = {
            "theta": est.datasheet.as_dict(),
            "validation": ({"E_p_m": self.datasheet_validation.mean_error_m,
                            "segments": len(self.datasheet_validation.segments)}
                           if self.datasheet_validation is not None else None)}
        out["status"]["warnings"] = list(self.warnings)
        details = est.details
        out["details"] = details.to_dict() if hasattr(details, "to_dict") else None
        out["inputs"] = [d.to_dict() for d in self.drives]
        out["elapsed_s"] = self.elapsed_s
        out["timings_s"] = dict(self.timings_s)
        out["diagnosis"] = self.diagnosis.to_dict()
        out["settings"] = self.settings.to_dict()
        out["bootstrap"] = self.bootstrap.to_dict() if self.bootstrap is not None else None
        if self.three_step is not None:
            out["three_step"] = self.three_step.to_dict()
        if self.comparison is not None:
            out["comparison"] = self.comparison.to_dict()
        return out


def load_drives(sources: Drive | str | Path | Sequence[Drive | str | Path]) -> list[Drive]:
    """Drives as given, or read from drive-format files."""
    if isinstance(sources, Drive | str | Path):
        sources = [sources]
    drives = [s if isinstance(s, Drive) else load_drive(s) for s in sources]
    if not drives:
        raise DataError("no drives were given")
    common_sampling_time(drives)
    seen: dict[str, str] = {}
    for d in drives:                 # the same bytes twice (a copy, a link) would count twice
        digest = d.metadata.get("sha256")
        if digest is None:
            continue
        if digest in seen:
            raise DataError(f"the logs '{seen[digest]}' and '{d.name}' are the same drive "
                            "(identical content); give each drive once")
        seen[digest] = d.name
    return drives


def summarise(drives: Sequence[Drive]) -> tuple[DriveSummary, ...]:
    return tuple(DriveSummary(name=d.name, samples=d.n_samples, duration_s=d.duration_s,
                              distance_m=d.distance_m, pieces=len(d.pieces),
                              sha256=d.metadata.get("sha256")) for d in drives)


def segment_clusters(segments: SegmentSet, block: int) -> IntArray:
    """Group label per segment: segments starting in the same ``block`` samples of a drive.

    Segments in one group overlap in time; the robust covariance treats each group as one
    independent observation.
    """
    return (segments.drive * (10**9) + segments.start // max(block, 1)).astype(np.int64)


def select_identification(segments: SegmentSet, settings: Settings
                          ) -> tuple[BoolArray, dict[str, NotIdentified], tuple[str, ...]]:
    """The selection rule, with the weak-data fallback to every segment.

    Returns the mask of segments to identify from, the parameters to keep at their datasheet
    values (without bends, t_r and d are not observable: the load transfer and the track width
    act on the yaw rate only when the vehicle turns), and warnings.
    """
    seg = settings.segments
    if len(segments) == 0:
        raise DataError(
            f"no drive is long enough for one identification segment of K = {seg.length} steps "
            f"({seg.length} samples); shorten [segments] length or give longer logs")
    selected = segments.selected
    if int(selected.sum()) >= seg.min_selected:
        return selected.copy(), {}, ()
    peak = float(segments.peak_yaw_rate_radps.max())
    warning = (f"only {int(selected.sum())} of {len(segments)} segments have a peak yaw rate "
               f"above {seg.yaw_rate_threshold_radps} rad/s; identifying from all of them")
    held = {name: NotIdentified(Reason.NEEDS_BENDS, detail=peak) for name in NEED_BENDS}
    return np.ones(len(segments), dtype=bool), held, (warning,)


def prepare(drives: Sequence[Drive], settings: Settings) -> Prepared:
    """Cut the drives into identification and validation segments (METHOD 2)."""
    id_segments = identification_segments(drives, settings.segments)
    used, held, warnings = select_identification(id_segments, settings)
    val_segments = validation_segments(drives, settings.segments)
    val_data = (validation_data(drives, val_segments, settings) if len(val_segments)
                else None)
    if val_data is None:
        shortest = (settings.segments.validation_min_fraction
                    * settings.segments.validation_distance_m)
        warnings += (f"the drives hold no validation segment of {shortest:.0f} m or more; "
                     "E_p is not available",)
    return Prepared(drives=tuple(drives), segments=id_segments, used=used, held=held,
                    clusters=segment_clusters(id_segments.subset(used), settings.segments.length),
                    validation_segments=val_segments, validation=val_data, warnings=warnings)


def validate_theta(drives: Drive | str | Path | Sequence[Drive | str | Path],
                   theta: Parameters | NDArray[np.float64], *,
                   settings: Settings | None = None) -> ValidationResult:
    """E_p of ``theta`` on the validation segments of ``drives`` (METHOD 6)."""
    from odocal.io.results import plausible

    settings = settings or Settings()
    plausible(theta if isinstance(theta, Parameters) else Parameters.from_array(theta))
    drive_list = load_drives(drives)
    segs = validation_segments(drive_list, settings.segments)
    data = validation_data(drive_list, segs, settings)
    return validation(theta, data, segs, drive_list)


def minimum(drives: Drive | str | Path | Sequence[Drive | str | Path], *,
            start: Parameters | None = None, settings: Settings | None = None) -> MinimumResult:
    """The reachable minimum of E_p on the validation segments of ``drives`` (METHOD 6).

    Differential evolution in a box of ``[minimum] half_width`` around ``start`` (default the
    datasheet values), seeded by ``[calibrate] seed``.
    """
    from odocal.estimators.parallel import resolve_workers
    from odocal.estimators.validation import reachable_minimum

    settings = settings or Settings()
    drive_list = load_drives(drives)
    data = validation_data(drive_list, validation_segments(drive_list, settings.segments),
                           settings)
    centre = start.as_array() if start is not None else np.asarray(settings.identify.theta0)
    return reachable_minimum(data, centre, settings=settings.minimum,
                             seed=settings.calibrate.seed,
                             workers=resolve_workers(settings.calibrate.workers))


def validation(theta: Parameters | NDArray[np.float64], data: RaggedSegments, segs: SegmentSet,
               drives: Sequence[Drive]) -> ValidationResult:
    """E_p of ``theta`` on already gathered validation segments."""
    params = theta if isinstance(theta, Parameters) else Parameters.from_array(theta)
    errors = segment_errors(params.as_array(), data)
    start_s = np.array([drives[int(d)].t[int(s)] for d, s in zip(segs.drive, segs.start,
                                                                   strict=True)])
    return ValidationResult(theta=params, mean_error_m=float(errors.mean_m.mean()), errors=errors,
                            segments=segs, drive_names=tuple(d.name for d in drives),
                            start_s=start_s)


def calibrate(drives: Drive | str | Path | Sequence[Drive | str | Path], *,
              settings: Settings | None = None, method: str | None = None,
              progress: ProgressCallback | None = None) -> CalibrationResult:
    """Calibrate the odometry parameters of one vehicle from its drives.

    Parameters
    ----------
    drives : one or more :class:`Drive` objects or drive-format files of the same vehicle;
        segments are drawn from all of them, never across a file boundary or a gap
    settings : all settings (default: the paper's)
    method : one of :data:`odocal.estimators.METHOD_NAMES` (default
        :data:`odocal.estimators.DEFAULT_METHOD`)
    progress : optional ``progress(stage, done, total)`` callback for long steps

    Returns
    -------
    CalibrationResult
        Never raises for weak data: unidentifiable parameters and failed steps are reported in it.
        Raises :class:`DataError` or :class:`ConfigError` for inputs it cannot use at all.
    """
    started = time.perf_counter()
    settings = settings or Settings()
    method = method or DEFAULT_METHOD
    if method not in METHODS:
        raise ConfigError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")
    clock = Stopwatch(progress)
    with clock.stage("read"):
        drive_list = load_drives(drives)
    with clock.stage("checks"):
        diagnosis = check_drives(drive_list, settings)
    with clock.stage("segments"):
        prep = prepare(drive_list, settings)
    boot = None
    if diagnosis.fatal or diagnosis.standstill:
        # the data contradict the model (or say nothing): no fit, and no time spent on one
        reason = Reason.STANDSTILL if diagnosis.standstill else Reason.REJECTED
        status = Status.NOTHING_IDENTIFIABLE if diagnosis.standstill else Status.REJECTED
        outcome = MethodOutcome(estimate=refused_estimate(method, settings.identify, status,
                                                          reason))
        estimate = outcome.estimate
    elif diagnosis.no_differential:
        outcome = _run_distance_only(prep, settings, clock)
        estimate = outcome.estimate
    else:
        outcome, estimate, boot = _checked_by_bootstrap(method, prep, settings, clock)
    warnings = [*prep.warnings, *outcome.warnings]
    if boot is not None and not all(boot.agree):
        warnings.append(boot.message)
    val = datasheet = None
    with clock.stage("validation"):
        if prep.validation is not None:
            val = validation(estimate.theta, prep.validation, prep.validation_segments,
                             drive_list)
            datasheet = validation(estimate.datasheet, prep.validation,
                                   prep.validation_segments, drive_list)
    if estimate.success:
        diagnosis, estimate = _gated(diagnosis, estimate, settings, val, datasheet)
    for w in warnings:
        log.warning("%s", w)
    return CalibrationResult(
        estimate=estimate, validation=val, datasheet_validation=datasheet,
        segments=prep.segments, used=prep.used, drives=summarise(drive_list), settings=settings,
        warnings=tuple(warnings), elapsed_s=time.perf_counter() - started, bootstrap=boot,
        three_step=outcome.three_step, batch=prep.__dict__.get("batch"),
        drive_data=tuple(drive_list),
        timings_s=dict(clock.seconds), diagnosis=diagnosis)


def _run_distance_only(prep: Prepared, settings: Settings,
                       progress: ProgressCallback | None) -> MethodOutcome:
    """The wheels carry no differential signal: c_e alone, from the distance channel.

    Every method but the inverse one takes the heading from the wheels, so none of them can use
    such data; the inverse method's distance channel needs the wheels' mean only.
    """
    from odocal.estimators.inverse import inverse_calibration

    held = {**prep.held, **{n: NotIdentified(Reason.NO_DIFFERENTIAL) for n in NEED_DIFFERENTIAL}}
    est = inverse_calibration(prep.drives, settings=settings, held=held, distance_only=True,
                              progress=progress)
    return MethodOutcome(estimate=est)


def _gated(diagnosis: Diagnosis, estimate: Estimate, settings: Settings,
           val: ValidationResult | None, datasheet: ValidationResult | None,
           ) -> tuple[Diagnosis, Estimate]:
    """The quality gate after the fit: a failing check rejects the estimate (exit 3)."""
    segment_m = settings.segments.validation_distance_m
    if val is None or datasheet is None:
        error = reference = None
    elif diagnosis.no_differential:        # the wheels give no heading: judge the distance
        error, reference = val.mean_distance_error_m, datasheet.mean_distance_error_m
    else:
        error, reference = val.mean_error_m, datasheet.mean_error_m
    findings = gate(estimate.theta.as_array(), settings, error_m=error,
                    datasheet_error_m=reference, segment_m=segment_m)
    diagnosis = diagnosis.plus(findings)
    if diagnosis.fatal:
        estimate = dataclasses.replace(estimate, status=Status.REJECTED)
    return diagnosis, estimate


class Stopwatch:
    """A progress callback that also times each stage (and passes progress on).

    A stage starts when it first reports ``done == 0`` (or enters :meth:`stage`) and its time
    accumulates until it reports ``done >= total``.
    """

    def __init__(self, progress: ProgressCallback | None = None) -> None:
        self.progress = progress
        self.seconds: dict[str, float] = {}
        self._open: dict[str, float] = {}

    def __call__(self, stage: str, done: int, total: int) -> None:
        now = time.perf_counter()
        if stage not in self._open and done < total:
            self._open[stage] = now
        if done >= total and stage in self._open:
            self.seconds[stage] = self.seconds.get(stage, 0.0) + now - self._open.pop(stage)
        if self.progress:
            self.progress(stage, done, total)

    @contextlib.contextmanager
    def stage(self, name: str) -> Iterator[None]:
        begun = time.perf_counter()
        if self.progress:
            self.progress(name, 0, 1)
        try:
            yield
        finally:
            self.seconds[name] = self.seconds.get(name, 0.0) + time.perf_counter() - begun
        if self.progress:
            self.progress(name, 1, 1)


def _checked_by_bootstrap(method: str, prep: Prepared, settings: Settings,
                          progress: ProgressCallback | None
                          ) -> tuple[MethodOutcome, Estimate, BootstrapResult | None]:
    """Run the method, check it by the bootstrap over segment clusters, keep the larger spread.

    Where the bootstrap's spread exceeds the covariance's by more than the disagreement factor,
    the standard deviation is widened to the bootstrap's (what is printed and exported is the
    larger); a parameter that is then beyond the identifiability limit is held at its datasheet
    value and the method runs again without it.
    """
    for _ in range(len(PARAMETER_NAMES)):
        outcome = METHODS[method](prep, settings, progress)
        estimate = outcome.estimate
        terms = outcome.bootstrap
        if settings.uncertainty.bootstrap_count <= 1 or terms is None or not estimate.success \
                or estimate.status is Status.EXACT or not any(estimate.free):
            return outcome, estimate, None
        if progress:
            progress("bootstrap", 0, 1)
        boot = bootstrap(estimate, terms.information, terms.scores, terms.clusters,
                         settings=settings.uncertainty, seed=settings.calibrate.seed,
                         refit=terms.refit, step1_thetas=terms.step1_thetas,
                         step1_sets=terms.step1_sets)
        if progress:
            progress("bootstrap", 1, 1)
        factor = np.where(np.isfinite(boot.ratio)
                          & (boot.ratio > settings.uncertainty.disagreement_factor),
                          boot.ratio, 1.0)
        if (factor == 1.0).all():
            return outcome, estimate, boot
        widened = estimate.with_covariance(estimate.covariance * np.outer(factor, factor),
                                           estimate.covariance_kind,
                                           widening=estimate.widening * factor)
        too_weak = weak(widened.std, widened.free, settings.identify)
        if not too_weak.any():
            return outcome, widened, boot
        prep = dataclasses.replace(prep, held={**prep.held, **held_as_weak(
            widened.std, too_weak, settings.identify)})
    return outcome, widened, boot
