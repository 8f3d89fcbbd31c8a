"""METHOD 5: calibrating a vehicle from one or more drives.

:func:`calibrate` is the front door: it checks its arguments once, cuts the drives into
identification and validation segments, runs the chosen method and validates the answer.

Methods
-------
``raw``
    Batch Gauss-Newton on every selected segment with the measured wheel rates.
``compensated`` (default)
    The paper's three-step architecture (see :mod:`odocal.threestep`): step-1 batches on measured
    rates, input compensation of every selected segment with five step-1 parameter sets, and a
    final batch Gauss-Newton on all selected segments with the compensated rates.
``joint``
    The errors-in-variables MAP estimator over the whole drive (see :mod:`odocal.joint`).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from odocal import __version__
from odocal.drive import Drive
from odocal.errors import ConfigError, DataError
from odocal.identify import IdentificationResult, gauss_newton
from odocal.io.drivefile import load_drive
from odocal.model import PARAMETER_NAMES, Parameters
from odocal.segments import (
    SegmentBatch,
    SegmentSet,
    common_sampling_time,
    gather,
    gather_ragged,
    identification_segments,
    validation_segments,
)
from odocal.settings import Settings
from odocal.threestep import ThreeStepOutcome, three_step
from odocal.uncertainty import BootstrapResult, bootstrap
from odocal.validate import ValidationResult, segment_errors

log = logging.getLogger(__name__)

#: ``progress(stage, done, total)``: called as long steps advance (the CLI draws bars from it).
ProgressCallback = Callable[[str, int, int], None]
IntArray = NDArray[np.int64]

METHODS = ("compensated", "raw", "joint")


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
class CalibrationResult:
    """Everything a calibration found, and how.

    theta : the calibrated parameters
    method : ``raw``, ``compensated`` or ``joint``
    identification : the final identification (status, covariance, identifiability)
    validation : E_p of ``theta`` on the validation segments (None without any)
    datasheet_validation : E_p of the initial (datasheet) parameters on the same segments
    segments : the identification segments (with the selection rule's verdict)
    used : mask over ``segments`` of those identified from
    drives : what was read
    warnings : things the user should know (weak data, failed solves, fallbacks)
    bootstrap : the bootstrap check of the covariance (None when off or not applicable)
    three_step : the three-step method's intermediate results (``compensated`` only)
    joint : the joint estimator's results (``joint`` only)
    batch : the identification segments' data with the measured rates
    drive_data : the drives themselves (for plots)
    """

    theta: Parameters
    method: str
    identification: IdentificationResult
    validation: ValidationResult | None
    datasheet_validation: ValidationResult | None
    segments: SegmentSet
    used: NDArray[np.bool_]
    drives: tuple[DriveSummary, ...]
    settings: Settings
    warnings: tuple[str, ...]
    elapsed_s: float
    bootstrap: BootstrapResult | None = None
    three_step: ThreeStepOutcome | None = None
    joint: Any = None
    batch: SegmentBatch | None = field(default=None, repr=False)
    drive_data: tuple[Drive, ...] = field(default=(), repr=False)

    @property
    def success(self) -> bool:
        return self.identification.success

    @property
    def segments_used(self) -> int:
        return int(self.used.sum())

    def to_dict(self) -> dict[str, Any]:
        """The content of ``calibration.json``."""
        ident = self.identification
        out: dict[str, Any] = {
            "odocal_version": __version__,
            "method": self.method,
            "theta": self.theta.as_dict(),
            "std": dict(zip(PARAMETER_NAMES, ident.std.tolist(), strict=True)),
            "covariance": ident.covariance.tolist(),
            "covariance_kind": ident.covariance_kind,
            "identified": dict(zip(PARAMETER_NAMES, ident.identified, strict=True)),
            "unidentified_reasons": dict(ident.reasons),
            "segments_used": self.segments_used,
            "segments_total": len(self.segments),
            "segments_selected": int(self.segments.selected.sum()),
            "validation": (self.validation.to_dict() if self.validation is not None
                           else {"E_p_m": None, "segments": 0}),
            "datasheet": {
                "theta": ident.theta0.as_dict(),
                "validation": ({"E_p_m": self.datasheet_validation.mean_error_m,
                                "segments": len(self.datasheet_validation.segments)}
                               if self.datasheet_validation is not None else None),
            },
            "status": {"success": self.success, "message": ident.message,
                       "warnings": list(self.warnings)},
            "identification": ident.to_dict(),
            "inputs": [d.to_dict() for d in self.drives],
            "elapsed_s": self.elapsed_s,
            "settings": self.settings.to_dict(),
        }
        out["bootstrap"] = self.bootstrap.to_dict() if self.bootstrap is not None else None
        if self.three_step is not None:
            out["three_step"] = self.three_step.to_dict()
        if self.joint is not None:
            out["joint"] = self.joint.to_dict()
        return out


def load_drives(sources: Drive | str | Path | Sequence[Drive | str | Path]) -> list[Drive]:
    """Drives as given, or read from drive-format files."""
    if isinstance(sources, Drive | str | Path):
        sources = [sources]
    drives = [s if isinstance(s, Drive) else load_drive(s) for s in sources]
    if not drives:
        raise DataError("no drives were given")
    common_sampling_time(drives)
    names = [d.name for d in drives]
    duplicates = sorted({n for n in names if names.count(n) > 1})
    if duplicates and all(isinstance(s, str | Path) for s in sources):
        raise DataError(f"the log '{duplicates[0]}' was given more than once")
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


#: Parameters observable only through the yaw equation in bends (METHOD 2).
NEED_BENDS = ("t_r", "d")


def select_identification(segments: SegmentSet, settings: Settings, warnings: list[str]
                          ) -> tuple[NDArray[np.bool_], dict[str, str]]:
    """The selection rule, with the weak-data fallback to every segment.

    Returns the mask of segments to identify from and the parameters to keep at their datasheet
    values with the reason: without bends, t_r and d are not observable (the load transfer and the
    track width act on the yaw rate only when the vehicle turns).
    """
    seg = settings.segments
    if len(segments) == 0:
        raise DataError(
            f"no drive is long enough for one identification segment of K = {seg.length} steps "
            f"({seg.length} samples); shorten [segments] length or give longer logs")
    selected = segments.selected
    if int(selected.sum()) >= seg.min_selected:
        return selected.copy(), {}
    peak = float(segments.peak_yaw_rate_radps.max())
    warnings.append(
        f"only {int(selected.sum())} of {len(segments)} segments have a peak yaw rate above "
        f"{seg.yaw_rate_threshold_radps} rad/s; identifying from all of them")
    reason = (f"needs bends: no segment has a peak yaw rate above "
              f"{seg.yaw_rate_threshold_radps} rad/s (the largest is {peak:.3f} rad/s); kept at "
              "the datasheet value")
    return np.ones(len(segments), dtype=bool), {name: reason for name in NEED_BENDS}


def validate_theta(drives: Drive | str | Path | Sequence[Drive | str | Path],
                   theta: Parameters | NDArray[np.float64], *,
                   settings: Settings | None = None) -> ValidationResult:
    """E_p of ``theta`` on the validation segments of ``drives`` (METHOD 6)."""
    settings = settings or Settings()
    drive_list = load_drives(drives)
    segs = validation_segments(drive_list, settings.segments)
    data = gather_ragged(drive_list, segs)
    return _validation(theta, data, segs, drive_list)


def _validation(theta: Parameters | NDArray[np.float64], data: Any, segs: SegmentSet,
                drives: Sequence[Drive]) -> ValidationResult:
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
    settings : all settings (default: the paper's); ``settings.calibrate.method`` picks the method
    method : overrides ``settings.calibrate.method``: ``compensated``, ``raw`` or ``joint``
    progress : optional ``progress(stage, done, total)`` callback for long steps

    Returns
    -------
    CalibrationResult
        Never raises for weak data: unidentifiable parameters and failed steps are reported in it.
        Raises :class:`DataError` or :class:`ConfigError` for inputs it cannot use at all.
    """
    started = time.perf_counter()
    settings = settings or Settings()
    method = method or settings.calibrate.method
    if method not in METHODS:
        raise ConfigError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")
    settings = settings.replace(calibrate={"method": method})
    drive_list = load_drives(drives)
    warnings: list[str] = []

    id_segments = identification_segments(drive_list, settings.segments)
    used, fixed = select_identification(id_segments, settings, warnings)
    val_segments = validation_segments(drive_list, settings.segments)
    val_data = gather_ragged(drive_list, val_segments) if len(val_segments) else None
    if val_data is None:
        shortest = (settings.segments.validation_min_fraction
                    * settings.segments.validation_distance_m)
        warnings.append(f"the drives hold no validation segment of {shortest:.0f} m or more; "
                        "E_p is not available")
    batch = gather(drive_list, id_segments.subset(used))
    clusters = segment_clusters(id_segments.subset(used), settings.segments.length)
    outcome: ThreeStepOutcome | None = None
    joint: Any = None

    if method == "raw":
        if progress:
            progress("identify", 0, 1)
        ident = gauss_newton(batch, settings=settings.identify, clusters=clusters, fixed=fixed)
        if progress:
            progress("identify", 1, 1)
    elif method == "compensated":
        outcome = three_step(batch, val_data, settings=settings, clusters=clusters,
                             fixed=fixed, progress=progress)
        ident = outcome.final
        warnings.extend(outcome.warnings)
    else:
        from odocal.joint import joint_calibration

        joint = joint_calibration(drive_list, settings=settings, fixed=fixed, progress=progress)
        ident = joint.identification
        warnings.extend(joint.warnings)

    for name in ident.unidentified:
        warnings.append(f"{name} is not identified by these drives: {ident.reasons[name]}")
    boot = None
    if settings.uncertainty.bootstrap_count > 1 and method != "joint":
        if progress:
            progress("bootstrap", 0, 1)
        rates = batch if outcome is None else batch.with_wheel_rates(
            outcome.compensation.n_rl, outcome.compensation.n_rr)
        boot = bootstrap(rates, ident, clusters, identify=settings.identify,
                         settings=settings.uncertainty, seed=settings.calibrate.seed,
                         step1_thetas=None if outcome is None else
                         outcome.step1.thetas[outcome.step1.success],
                         step1_sets=0 if outcome is None else int(outcome.step1.picked.size))
        if progress:
            progress("bootstrap", 1, 1)
        if not all(boot.agree):
            warnings.append(boot.message)
    validation = datasheet = None
    if val_data is not None:
        validation = _validation(ident.theta, val_data, val_segments, drive_list)
        datasheet = _validation(ident.theta0, val_data, val_segments, drive_list)
    for w in warnings:
        log.warning("%s", w)
    return CalibrationResult(
        theta=ident.theta, method=method, identification=ident, validation=validation,
        datasheet_validation=datasheet, segments=id_segments, used=used,
        drives=summarise(drive_list), settings=settings, warnings=tuple(warnings),
        elapsed_s=time.perf_counter() - started, bootstrap=boot, three_step=outcome, joint=joint,
        batch=batch,
        drive_data=tuple(drive_list))

