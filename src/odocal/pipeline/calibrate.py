"""METHOD 5: calibrating a vehicle from one or more drives.

:func:`calibrate` is the front door: it checks its arguments once, cuts the drives into
identification and validation segments, runs the chosen method (the one place a method is
chosen) and validates the answer.

Methods (:data:`METHODS`; each is a module of :mod:`odocal.estimators` with the same ``run``)
-----------------------------------------------------------------------------------------------
``inverse`` (the default)
    The errors-in-variables method (:mod:`odocal.estimators.inverse`): the wheel revolutions the
    reference motion implies, summed over every 2 s window of every drive, fitted to the
    measured ones; a change inside the log is named and the part after it calibrated.
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
import logging
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from odocal import cancel
from odocal.arrays import FloatArray
from odocal.checks.departures import Departures, corrected
from odocal.checks.departures import findings as departure_findings
from odocal.checks.departures import measure as measure_departures
from odocal.checks.diagnosis import check_drives
from odocal.checks.findings import Check, Diagnosis, Finding
from odocal.checks.gate import gate
from odocal.data.drive import Drive
from odocal.data.segments import (
    RaggedSegments,
    SegmentSet,
    common_sampling_time,
    validation_segments,
)
from odocal.errors import ConfigError, DataError
from odocal.estimators import DEFAULT_METHOD
from odocal.estimators.base import (
    MethodOutcome,
    Prepared,
    ProgressCallback,
    held_by_checks,
    prepare,
)
from odocal.estimators.covariance import BootstrapResult, bootstrap
from odocal.estimators.departures import corrected as corrected_drives
from odocal.estimators.estimate import (
    Estimate,
    Reason,
    Status,
    held_as_weak,
    identifiability_limits,
    refused_estimate,
    weak,
)
from odocal.estimators.front_axle import (
    four_wheel_estimate,
    front_checks,
    mapping_findings,
    require_front_wheels,
)
from odocal.estimators.validation import (
    MinimumResult,
    ValidationResult,
    segment_errors,
    validation_data,
)
from odocal.io.drivefile import load_drive
from odocal.model import registry
from odocal.model.parameters import PARAMETER_NAMES, Parameters
from odocal.model.vehicle import MODEL
from odocal.pipeline.result import CalibrationResult, summarise
from odocal.settings import Settings, datasheet_theta

if TYPE_CHECKING:
    from odocal.estimators.inverse import Screen

log = logging.getLogger(__name__)
LAYOUT = MODEL.layout
Runner = Callable[[Prepared, Settings, ProgressCallback | None], MethodOutcome]


def _inverse(prep: Prepared, settings: Settings, progress: ProgressCallback | None
             ) -> MethodOutcome:
    from odocal.estimators.inverse import run

    return run(prep, settings, progress)


def _raw(prep: Prepared, settings: Settings, progress: ProgressCallback | None) -> MethodOutcome:
    from odocal.estimators.raw import run

    return run(prep, settings, progress)


def _compensated(prep: Prepared, settings: Settings, progress: ProgressCallback | None
                 ) -> MethodOutcome:
    from odocal.estimators.compensated import run

    return run(prep, settings, progress)


#: The estimator behind each name of :data:`odocal.estimators.METHOD_NAMES`; each module is
#: imported when its method runs, so a calibration loads only its own.
METHODS: Mapping[str, Runner] = {"inverse": _inverse, "compensated": _compensated, "raw": _raw}


def load_drives(sources: Drive | str | Path | Sequence[Drive | str | Path], *,
                settings: Settings | None = None) -> list[Drive]:
    """Drives as given, or read from drive-format files (their wheel rates judged with the
    datasheet ``c_e`` the ``settings`` state, else a car's wheel)."""
    if isinstance(sources, Drive | str | Path):
        sources = [sources]
    wheel = stated_circumference(settings)
    drives = [s if isinstance(s, Drive) else load_drive(s, circumference_m=wheel)
              for s in sources]
    if not drives:
        raise DataError("no drives were given")
    common_sampling_time(drives)
    _refuse_copies(drives)
    return drives


def _refuse_copies(drives: Sequence[Drive]) -> None:
    """A DataError naming two logs of one recording (:mod:`odocal.data.copies`): the same bytes
    (a copy, a link), the same samples (another format, a shifted clock), or one holding a
    stretch of the other's samples: each would count its evidence twice."""
    from odocal.data.copies import piece_digests, samples_digest, shared_stretch

    if len(drives) < 2 and len(drives[0].pieces) < 2:
        return                               # (one run of samples: nothing to be a copy of)
    seen: dict[str, str] = {}
    for d in drives:
        for digest in {d.metadata.get("sha256"), samples_digest(d)} - {None}:
            if digest in seen:
                raise DataError(f"the logs '{seen[digest]}' and '{d.name}' are the same drive "
                                "(the same samples); give each drive once")
            seen[str(digest)] = d.name
    pieces: dict[str, tuple[str, int]] = {}
    for d in drives:
        for k, digest in (piece_digests(d) if len(d.pieces) > 1 else {}).items():
            if digest in pieces:
                name, other = pieces[digest]
                where = (f"'{d.name}' holds one run of samples twice (its pieces {other + 1} "
                         f"and {k + 1})" if name == d.name else
                         f"piece {k + 1} of '{d.name}' is piece {other + 1} of '{name}'")
                raise DataError(f"{where}: one recording counted twice; cut one of them out")
            pieces[digest] = (d.name, k)
    copy = shared_stretch(drives)
    if copy is not None:
        a, b = drives[copy.first], drives[copy.second]
        raise DataError(
            f"the log '{b.name}' is a copy of a stretch of '{a.name}': from "
            f"{copy.start_second_s:.1f} s of it and {copy.start_first_s:.1f} s of '{a.name}', "
            f"{copy.shared_s:.0f} s of driving agree within {copy.difference_revps:.2g} rev/s, "
            f"less than the wheels' own noise ({copy.noise_revps:.2g} rev/s): one recording "
            "counted twice; give each drive once (cut the shared stretch out of one)")


def stated_circumference(settings: Settings | None) -> float | None:
    """The wheel circumference ``settings`` state (``--datasheet c_e`` or ``[identify]
    theta0``), or None for odocal's placeholder car."""
    from odocal.settings import datasheet_stated

    if settings is None or not datasheet_stated(settings.identify.theta0):
        return None
    return settings.identify.datasheet("c_e")


def validate_theta(drives: Drive | str | Path | Sequence[Drive | str | Path],
                   theta: Parameters | FloatArray, *,
                   settings: Settings | None = None,
                   std: Sequence[float] | FloatArray | None = None) -> ValidationResult:
    """E_p of ``theta`` on the validation segments of ``drives`` (METHOD 6).

    A four-wheel ``theta`` (:data:`~odocal.model.layout.FOUR_WHEEL`) is judged on the
    odometry of all four wheels (:func:`odocal.pipeline.odometry.on_four_wheels`, each axle
    weighted by ``std``, its standard deviations: infinite for a parameter not identified,
    the default), the result's theta being its rear axle's. Four wheels that dead-reckon
    :data:`EXCHANGED_GAIN` times better with two of their columns exchanged (the axles, or a
    front wheel with the rear one of its side) are a one-line DataError naming the exchange:
    an E_p of a log mapped wrong says nothing of ``theta``."""
    from odocal.io.json_files import plausible

    settings = settings or Settings()
    four = isinstance(theta, Parameters) and theta.layout.names != PARAMETER_NAMES
    rear = theta
    if four:
        assert isinstance(theta, Parameters)
        rear = Parameters.from_array(theta.as_array()[:len(PARAMETER_NAMES)])
    plausible(rear if isinstance(rear, Parameters) else Parameters.from_array(rear))
    drive_list = load_drives(drives, settings=settings)
    if not four:
        return _dead_reckoned(rear, drive_list, settings)
    assert isinstance(theta, Parameters)
    from odocal.pipeline.odometry import EXCHANGES, exchanged, on_four_wheels

    spread = np.full(theta.layout.size, np.inf) if std is None else np.asarray(std, float)
    result = _dead_reckoned(rear, on_four_wheels(drive_list, theta, spread), settings)
    other, words = min((_dead_reckoned(rear, on_four_wheels(
        [exchanged(d, order) for d in drive_list], theta, spread), settings).mean_error_m, words)
        for words, order in EXCHANGES)
    if other * EXCHANGED_GAIN < result.mean_error_m:
        raise DataError(f"the four wheels dead-reckon {other:.2f} m with the {words} exchanged "
                        f"against {result.mean_error_m:.2f} m as mapped: the wheel columns look "
                        "mapped wrong (check which is front_left, front_right, rear_left and "
                        "rear_right)")
    return result


#: How many times better four wheels dead-reckon with two of their columns exchanged before
#: the log is refused as mapped wrong: on simulated drives an exchange of the axles costs 13
#: times the E_p of a calibrated car, and with a datasheet's (nothing identified) exchanges
#: are within 20% of each other.
EXCHANGED_GAIN = 3.0


def _dead_reckoned(theta: Parameters | FloatArray, drives: list[Drive],
                   settings: Settings) -> ValidationResult:
    segs = validation_segments(drives, settings.segments)
    return validation(theta, validation_data(drives, segs, settings), segs, drives)


def minimum(drives: Drive | str | Path | Sequence[Drive | str | Path], *,
            start: Parameters | None = None, settings: Settings | None = None,
            progress: ProgressCallback | None = None) -> MinimumResult:
    """The reachable minimum of E_p on the validation segments of ``drives`` (METHOD 6).

    Differential evolution in a box of ``[minimum] half_width`` around ``start`` (default the
    datasheet values), seeded by ``[calibrate] seed``.
    """
    from odocal.estimators.parallel import resolve_workers
    from odocal.estimators.validation import reachable_minimum

    settings = settings or Settings()
    drive_list = load_drives(drives, settings=settings)
    data = validation_data(drive_list, validation_segments(drive_list, settings.segments),
                           settings)
    centre = start.as_array() if start is not None else np.asarray(settings.identify.theta0)
    return reachable_minimum(data, centre, settings=settings.minimum,
                             seed=settings.calibrate.seed,
                             workers=resolve_workers(settings.calibrate.workers),
                             progress=progress)


def validation(theta: Parameters | FloatArray, data: RaggedSegments, segs: SegmentSet,
               drives: Sequence[Drive]) -> ValidationResult:
    """E_p of ``theta`` on already gathered validation segments."""
    params = theta if isinstance(theta, Parameters) else Parameters.from_array(theta)
    errors = segment_errors(params.as_array(), data)
    start_s = np.array([drives[int(d)].t[int(s)] for d, s in zip(segs.drive, segs.start,
                                                                   strict=True)])
    return ValidationResult(theta=params, mean_error_m=float(errors.mean_m.mean()), errors=errors,
                            segments=segs, drive_names=tuple(d.name for d in drives),
                            start_s=start_s)


def with_stated_datasheet(drives: Sequence[Drive], settings: Settings) -> Settings:
    """``settings`` with the datasheet values the drives' metadata state (``"datasheet"``:
    ``{"c_e": .., "t_r": ..}``, set by an importer or the caller), where the settings
    leave ``[identify] theta0`` at odocal's placeholder; drives that state different values are
    refused by name."""
    from odocal.settings import DATASHEET_THETA

    stated: dict[str, dict[str, Any]] = {d.name: dict(d.metadata["datasheet"]) for d in drives
                                         if isinstance(d.metadata.get("datasheet"), dict)}
    if not stated or tuple(settings.identify.theta0) != DATASHEET_THETA:
        return settings
    values = {name: tuple(sorted(v.items())) for name, v in stated.items()}
    if len(set(values.values())) > 1:
        first, *rest = values
        other = next(n for n in rest if values[n] != values[first])
        raise DataError(f"drives '{first}' and '{other}' state different datasheet values "
                        f"({dict(values[first])} and {dict(values[other])}): calibrate each "
                        "vehicle on its own, or give --datasheet")
    return settings.replace(identify={"theta0": datasheet_theta(next(iter(stated.values())))})


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
    _check_method(method := method or DEFAULT_METHOD)
    model_settings, settings = _rear_axle_settings(settings, method)   # a car: its rear axle
    clock = Stopwatch(progress)
    with clock.stage("read"):
        drive_list = _loaded(drives, settings, model_settings)
    settings = with_stated_datasheet(drive_list, settings)
    drive_list = _arm_taken_out(drive_list, settings, method)
    with clock.stage("checks"):
        drive_list, diagnosis, departures, screened = _checked(drive_list, settings, method)
    with clock.stage("segments"):
        prep = prepare(drive_list, settings)
        prep = dataclasses.replace(prep, held={**prep.held, **held_by_checks(diagnosis)})
    outcome, estimate, boot = _fitted(method, prep, settings, clock, diagnosis=diagnosis,
                                      departures=departures, screened=screened,
                                      drives=drive_list)
    diagnosis, estimate, fitted = _with_fit_findings(
        diagnosis, estimate, ahead=_front_ahead(drive_list, model_settings))
    warnings = _warnings(method, prep, outcome, boot, drive_list)
    with clock.stage("validation"):
        val, datasheet = _validated(estimate, fitted, drive_list, prep, settings, method)
    if estimate.success:
        diagnosis, estimate = _gated(diagnosis, estimate, settings, val, datasheet)
    vehicle = None
    if model_settings is not None:
        with clock.stage("front axle"):
            diagnosis, estimate, vehicle = _the_car(_as_fitted(
                drive_list, estimate, fitted, settings, method), diagnosis, estimate,
                model_settings)
    for w in warnings:
        log.warning("%s", w)
    return CalibrationResult(
        estimate=estimate, validation=val, datasheet_validation=datasheet,
        segments=prep.segments, used=prep.used, drives=summarise(drive_list), settings=settings,
        warnings=tuple(warnings), elapsed_s=time.perf_counter() - started, bootstrap=boot,
        three_step=outcome.three_step, batch=prep.__dict__.get("batch"),
        drive_data=tuple(drive_list), timings_s=dict(clock.seconds), diagnosis=diagnosis,
        departures=departures,
        vehicle_estimate=vehicle, model_settings=model_settings)


def _front_ahead(drives: Sequence[Drive], model_settings: Settings | None) -> bool:
    """Whether a car's four wheels show each front one travelling further in bends than its
    rear one (:func:`~odocal.estimators.front_axle.front_ahead`; False for the rear axle)."""
    if model_settings is None:
        return False
    from odocal.estimators.front_axle import front_ahead, front_checks

    return front_ahead(front_checks(drives, model_settings).findings)


def _with_fit_findings(diagnosis: Diagnosis, estimate: Estimate, *, ahead: bool = False
                       ) -> tuple[Diagnosis, Estimate, tuple[Finding, ...]]:
    """What the fit's residuals showed (front wheels: refused; a change inside the log) added
    to the diagnosis, the estimate refused where it is fatal; and those findings. ``ahead``:
    a car whose front wheels travel further in bends than its rear ones, whose rear columns
    then hold no front wheel (the wheels' excess is a note)."""
    fitted = tuple(getattr(estimate.details, "findings", ()))
    if ahead and fitted:
        from odocal.estimators.departures import as_excess

        fitted = tuple(as_excess(fitted))
        estimate = dataclasses.replace(
            estimate, details=dataclasses.replace(estimate.details, findings=fitted))
    if fitted:
        diagnosis = diagnosis.plus(fitted)
        if diagnosis.fatal:
            estimate = dataclasses.replace(estimate, status=Status.REJECTED)
    return diagnosis, estimate, fitted


def _the_car(drives: Sequence[Drive], diagnosis: Diagnosis, estimate: Estimate,
             model_settings: Settings) -> tuple[Diagnosis, Estimate, Estimate]:
    """The four-wheel car on the drives as the rear fit fitted them: its front wheels and
    steering checked (a refusal refuses the rear axle too: the mapping is wrong), its front
    axle and steering fitted and joined, and what that fit shows of the mapping. Returns the
    diagnosis, the rear axle's estimate and the car's."""
    checked = front_checks(drives, model_settings)
    diagnosis = diagnosis.plus(checked.findings)
    if diagnosis.fatal:
        estimate = dataclasses.replace(estimate, status=Status.REJECTED)
    vehicle = four_wheel_estimate(estimate, checked.drives, model_settings)
    diagnosis = diagnosis.plus(mapping_findings(
        vehicle, diagnosis, max_difference=model_settings.gate.max_abs_c_d_fraction))
    if diagnosis.fatal:                 # the wheels' mapping: nothing of the car stands
        estimate = dataclasses.replace(estimate, status=Status.REJECTED)
        vehicle = dataclasses.replace(vehicle, status=Status.REJECTED)
    return diagnosis, estimate, vehicle


def _rear_axle_settings(settings: Settings, method: str) -> tuple[Settings | None, Settings]:
    """For the four-wheel model: its settings, and the rear-axle model's that the default
    method fits its rear axle with (the per-parameter settings' rear values); for the rear
    axle: None and the settings as given. A method other than the default is refused for the
    four-wheel model in one line."""
    if settings.vehicle.model == registry.DEFAULT:
        return None, settings
    if method != DEFAULT_METHOD:
        raise ConfigError(f"the {settings.vehicle.model} model is calibrated by the default "
                          f"method only ({DEFAULT_METHOD}), not --method {method}")
    return settings, settings.replace(vehicle={"model": registry.DEFAULT})


def _check_method(method: str) -> None:
    """A ConfigError for a method :data:`METHODS` does not hold; for the compensated method,
    the compiled kernels its QP needs, required before anything is read."""
    if method not in METHODS:
        raise ConfigError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")
    if method == "compensated":                  # its QP is compiled: before anything is read
        from odocal.model._jit import require

        require("the compensated method (--method compensated)")


def _arm_taken_out(drives: list[Drive], settings: Settings, method: str) -> list[Drive]:
    """The drives with the reference moved to the axle by the stated lever arm
    (``[reference] offset_m``) for a segment method; as given for the default method, or
    where no arm is stated."""
    arm = settings.reference.offset_m
    if arm is None or method == "inverse":
        return drives
    # a segment method rolls the axle out: the reference moved to it first (the default
    # method holds the stated lever arm in its fit)
    return corrected_drives(drives, {"arm_x": arm[0], "arm_y": arm[1]},
                            np.asarray(settings.identify.theta0, dtype=np.float64))


def _checked(drives: list[Drive], settings: Settings, method: str
             ) -> tuple[list[Drive], Diagnosis, Departures | None, Screen | None]:
    """The checks before any fit: the drives' diagnosis, the departures measured against the
    reference and taken out of the drives, and for a segment method the default method's
    screen (its findings added, the drives cut after a change inside the log it names).

    Returns the drives to fit, the diagnosis, the departures (None where the checks refuse
    the drives) and the screen (None for the default method or where no fit will run).
    """
    diagnosis = check_drives(drives, settings)
    departures = None
    if not (diagnosis.fatal or diagnosis.standstill):
        # a_y's clock and offset and a heading error varying with the heading, measured
        # against the reference and taken out before any method fits (and validates)
        departures = measure_departures(drives, settings,
                                        lateral=not diagnosis.lateral_missing)
        drives = corrected(drives, departures)
        diagnosis = diagnosis.plus(departure_findings(departures, settings))
    screened = None
    if method != "inverse" and not (diagnosis.fatal or diagnosis.standstill
                                    or diagnosis.no_differential):
        # front wheels and a change inside the log show in the default method's residuals
        # only: a segment method is refused, or fits the part after the change, as it is;
        # the default's uncertainty is what a segment method's may not undercut
        from odocal.estimators.inverse import screen

        screened = screen(drives, settings)
        found = screened.findings if screened is not None else ()
        diagnosis = diagnosis.plus(found)
        changed = [f for f in found if f.check is Check.CHANGE_IN_LOG]
        if changed and not diagnosis.fatal:
            drives = _after_change(drives, changed[0])
            screened = screen(drives, settings)
    return drives, diagnosis, departures, screened


def _fitted(method: str, prep: Prepared, settings: Settings, clock: Stopwatch, *,
            diagnosis: Diagnosis, departures: Departures | None, screened: Screen | None,
            drives: Sequence[Drive]) -> tuple[MethodOutcome, Estimate, BootstrapResult | None]:
    """The fit the diagnosis allows: none where the data contradict the model or say nothing
    (a refused estimate), the distance scale alone where the wheels give no heading, else the
    method checked by the bootstrap, its scale widened for wheel rates on an encoding's grid
    (:func:`_encoding_widened`) for a segment method."""
    if diagnosis.fatal or diagnosis.standstill:
        # the data contradict the model (or say nothing): no fit, and no time spent on one
        reason = Reason.STANDSTILL if diagnosis.standstill else Reason.REJECTED
        status = Status.NOTHING_IDENTIFIABLE if diagnosis.standstill else Status.REJECTED
        outcome = MethodOutcome(estimate=refused_estimate(method, settings.identify, status,
                                                          reason))
        return outcome, outcome.estimate, None
    if diagnosis.no_differential:
        from odocal.estimators.inverse import run_distance_only

        outcome = run_distance_only(prep, settings, clock)
        return outcome, outcome.estimate, None
    outcome, estimate, boot = _checked_by_bootstrap(method, prep, settings, clock, screened)
    step = departures.wheel_step_revps if departures is not None else 0.0
    if step and method != "inverse" and estimate.success:
        estimate, said = _encoding_widened(estimate, drives, step)
        outcome = dataclasses.replace(outcome, warnings=(*outcome.warnings, said))
    return outcome, estimate, boot


def _loaded(drives: Drive | str | Path | Sequence[Drive | str | Path], settings: Settings,
            model_settings: Settings | None) -> list[Drive]:
    """The drives read; for the four-wheel model (``model_settings``), a one-line error where
    none carries front wheels, before any time is spent on a fit."""
    drive_list = load_drives(drives, settings=settings)
    if model_settings is not None:
        require_front_wheels(drive_list)
    return drive_list


def _warnings(method: str, prep: Prepared, outcome: MethodOutcome,
              boot: BootstrapResult | None, drives: Sequence[Drive] = ()) -> list[str]:
    """The run's warnings: the columns the reader left out of the ``drives``, the segment
    selection's (a segment method's only: the default fits every window), the preparation's,
    the method's, and the bootstrap's where it disagrees."""
    selection = prep.selection_warnings if method != "inverse" else ()
    left_out = [str(said) for d in drives for said in d.metadata.get("left_out", ())]
    warnings = [*left_out, *selection, *prep.warnings, *outcome.warnings]
    if boot is not None and not all(boot.agree):
        warnings.append(boot.message)
    return warnings


def _validated(estimate: Estimate, fitted: Sequence[Finding], drives: Sequence[Drive],
               prep: Prepared, settings: Settings, method: str
               ) -> tuple[ValidationResult | None, ValidationResult | None]:
    """E_p of the estimate and of the datasheet values, judged as the estimate was fitted: on
    the drives with the departures the fit found (and a stated lever arm, for the default
    method) taken out, and after a change inside the log where it calibrated that part.

    Returns ``(estimate's, datasheet's)``, both None where no validation segment remains.
    """
    val_segs, val_data = prep.validation_segments, prep.validation
    judged = _as_fitted(drives, estimate, fitted, settings, method)
    if judged is not drives:
        val_segs = validation_segments(judged, settings.segments)
        val_data = validation_data(judged, val_segs, settings) if len(val_segs) else None
    if val_data is None:
        return None, None
    return (validation(estimate.theta, val_data, val_segs, judged),
            validation(estimate.datasheet, val_data, val_segs, judged))


def _as_fitted(drives: Sequence[Drive], estimate: Estimate, fitted: Sequence[Finding],
               settings: Settings, method: str) -> Sequence[Drive]:
    """The drives as the estimate was fitted on them: the departures the fit found (and a
    stated lever arm, for the default method) taken out, and the part after a change inside
    the log where it calibrated that part; ``drives`` itself where neither applies."""
    changed = [f for f in fitted if f.check is Check.CHANGE_IN_LOG]
    fitted_departures = dict(getattr(estimate.details, "fitted_departures", {}) or {})
    if settings.reference.offset_m is not None and method == "inverse":
        # a lever arm stated: held in the fit, taken out of what is judged as fitted ones are
        fitted_departures.update(arm_x=settings.reference.offset_m[0],
                                 arm_y=settings.reference.offset_m[1])
    if not (changed or fitted_departures):
        return drives
    judged = corrected_drives(drives, fitted_departures, estimate.theta.as_array())
    return _after_change(judged, changed[0]) if changed else judged


def _against_the_default(estimate: Estimate, screened: Screen,
                         settings: Settings) -> FloatArray:
    """Per parameter, the factor (>= 1) that widens a segment method's standard deviation to
    the default method's on the same drives (at the information's bound: no unbiased method is
    surer; where the default does not identify a parameter, past the identifiability limit),
    and, where both identify it, to half the distance between their estimates and a third of
    that distance plus two of the default's standard deviations: the default is unbiased where
    the segment methods depart from the model, so the segment method's answer then lies within
    three of its standard deviations of the truth wherever the default's lies within two."""
    std = estimate.std
    free = np.asarray(estimate.free, dtype=bool) & (std > 0)
    past = 1.01 * identifiability_limits(settings.identify)
    floor = np.where(screened.free, screened.std,
                     np.fmax(np.nan_to_num(screened.std, nan=0.0), past))
    target = np.where(free, np.maximum(std, floor), std)
    both = free & screened.free
    apart = np.abs(estimate.theta.as_array() - screened.theta)
    # within three of them of the truth wherever the default lies within two of its own
    reach = np.maximum(0.5 * apart, (apart + 2.0 * np.nan_to_num(screened.std)) / 3.0)
    target = np.where(both, np.maximum(target, reach), target)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(free, target / np.where(std > 0, std, 1.0), 1.0)


def _encoding_widened(estimate: Estimate, drives: Sequence[Drive], step_revps: float
                      ) -> tuple[Estimate, str]:
    """A segment method's estimate on wheel rates that lie on an encoding's grid of
    ``step_revps``: a truncating encoder reads them up to a step low (half a step on average),
    an offset the default method fits (prior half a step) and the segment methods do not. Its
    effect on the distance scale (the offset over the mean wheel rate while moving, times the
    scale) is added to the scale's variance, as the default's prior would carry it, with the
    words that say so."""
    rates = np.concatenate([0.5 * np.abs(d.n_rl + d.n_rr) for d in drives])
    moving = rates[rates > step_revps]
    if not moving.size:
        return estimate, ""
    k = LAYOUT.index(LAYOUT.scale)
    extra = 0.5 * step_revps / float(moving.mean()) * float(estimate.theta.as_array()[k])
    cov = estimate.covariance.copy()
    before = float(np.sqrt(max(cov[k, k], 0.0)))
    cov[k, k] += extra ** 2
    widening = estimate.widening.copy()
    if before > 0:
        widening[k] *= float(np.sqrt(cov[k, k])) / before
    said = (f"the wheel rates lie on a {step_revps:.4g} rev/s grid (an encoding's steps): a "
            f"truncating encoder reads them up to a step low, an offset {estimate.method} does "
            f"not fit, so {LAYOUT.scale}'s standard deviation includes up to "
            f"{extra * 1e3:.2g} mm for it (the default method fits the offset)")
    return dataclasses.replace(estimate, covariance=cov, widening=widening), said


def _after_change(drives: Sequence[Drive], change: Finding) -> list[Drive]:
    """The drives from a change inside the log on: its drive from the change's time, and the
    drives after it (``change.name`` is ``parameter|drive name``, ``reference`` the time)."""
    where = change.name.partition("|")[2]
    names = [d.name for d in drives]
    k = names.index(where) if where in names else 0
    return [drives[k].since(change.reference), *drives[k + 1:]]


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
    accumulates until it reports ``done >= total``. Every report is also a point where a run
    asked to stop stops (:func:`odocal.cancel.check`).
    """

    def __init__(self, progress: ProgressCallback | None = None) -> None:
        self.progress = progress
        self.seconds: dict[str, float] = {}
        self._open: dict[str, float] = {}

    def __call__(self, stage: str, done: int, total: int) -> None:
        cancel.check()
        now = time.perf_counter()
        if stage not in self._open and done < total:
            self._open[stage] = now
        if done >= total and stage in self._open:
            self.seconds[stage] = self.seconds.get(stage, 0.0) + now - self._open.pop(stage)
        if self.progress:
            self.progress(stage, done, total)

    @contextlib.contextmanager
    def stage(self, name: str) -> Iterator[None]:
        cancel.check()
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
                          progress: ProgressCallback | None, screened: Screen | None = None,
                          ) -> tuple[MethodOutcome, Estimate, BootstrapResult | None]:
    """Run the method, check it by the bootstrap over segment clusters, keep the larger spread.

    Where the bootstrap's spread exceeds the covariance's by more than the disagreement factor,
    the standard deviation is widened to the bootstrap's (what is printed and exported is the
    larger); where the default method's (``screened``) is larger, or the two estimates lie
    further apart than two of the segment method's standard deviations, it is widened to that
    (:func:`_against_the_default`). A parameter that is then beyond the identifiability limit
    is held at its datasheet value and the method runs again without it.
    """
    boot = None
    for _ in range(len(PARAMETER_NAMES)):
        outcome = METHODS[method](prep, settings, progress)
        estimate = outcome.estimate
        terms = outcome.bootstrap
        if not estimate.success or estimate.status is Status.EXACT or not any(estimate.free):
            return outcome, estimate, None
        factor = np.ones(len(PARAMETER_NAMES))
        if settings.uncertainty.bootstrap_count > 1 and terms is not None:
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
        if screened is not None:
            factor = np.maximum(factor, _against_the_default(estimate, screened, settings))
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
