"""What a calibration hands on: the result types of the pipeline.

:class:`CalibrationResult` holds everything :func:`odocal.pipeline.calibrate.calibrate` found;
:class:`Comparison` every method scored on held-out data (``--compare``). Words are made from
them in :mod:`odocal.report` and :mod:`odocal.cli`, files in :mod:`odocal.output`.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from odocal._version import __version__
from odocal.arrays import BoolArray
from odocal.checks.departures import Departures
from odocal.checks.findings import Diagnosis
from odocal.data.drive import Drive
from odocal.data.segments import SegmentBatch, SegmentSet
from odocal.estimators import DEFAULT_METHOD
from odocal.estimators.covariance import BootstrapResult
from odocal.estimators.estimate import Estimate
from odocal.estimators.inverse import InverseDetails
from odocal.estimators.validation import ValidationResult
from odocal.model.parameters import PARAMETER_NAMES, Parameters
from odocal.pipeline.odometry import OdometryNoise, Trajectories, odometry_noise, trajectories
from odocal.settings import Settings

if TYPE_CHECKING:
    from odocal.estimators.compensated import ThreeStepOutcome
    from odocal.output.results import Written



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


def summarise(drives: Sequence[Drive]) -> tuple[DriveSummary, ...]:
    return tuple(DriveSummary(name=d.name, samples=d.n_samples, duration_s=d.duration_s,
                              distance_m=d.distance_m, pieces=len(d.pieces),
                              sha256=d.metadata.get("sha256")) for d in drives)


@dataclass(frozen=True)
class SpeedScale:
    """The calibration of a speed signal: wheel speeds given in m/s or km/h (comma2k19's CAN, a
    mapping's ``unit = "km/h"``) were turned into wheel rates with an assumed circumference,
    so the wheels' own circumference is unknown and c_e is that assumption times the factor
    the speed signal is off by (c_d relative to it alike; t_r is in metres).

    factor : the true speed over the reported one (c_e over ``circumference_m``): Autoware's
        ``speed_scale_factor``
    std : its standard deviation
    circumference_m : the circumference the speeds were turned into rates with
    unit : the speeds' unit as logged
    """

    factor: float
    std: float
    circumference_m: float
    unit: str

    def to_dict(self) -> dict[str, Any]:
        return {"factor": self.factor, "std": self.std,
                "circumference_m": self.circumference_m, "unit": self.unit}


def speed_signal(drives: Sequence[Drive]) -> tuple[float, str] | None:
    """The circumference and unit the drives' wheel speeds were turned into wheel rates with,
    where every drive's wheels were speeds (m/s, km/h) turned with one circumference; else
    None (the wheels' own rates, or drives that differ)."""
    found = {(d.metadata.get("wheel_circumference_m"), d.metadata.get("wheel_speed_unit", "m/s"))
             for d in drives}
    if len(found) != 1:
        return None
    circumference, unit = found.pop()
    if not isinstance(circumference, int | float) or circumference <= 0:
        return None
    return float(circumference), str(unit)


#: Held-out E_p within this share of the best counts as equally good.
TIE = 0.03


@dataclass(frozen=True)
class MethodScore:
    method: str
    theta: Parameters
    std: tuple[float, ...]
    identified: tuple[bool, ...]
    status: str
    held_out_e_p_m: float | None
    folds_e_p_m: tuple[float | None, ...]
    truth_error: dict[str, float] | None
    elapsed_s: float
    error: str | None = None

    def to_dict(self) -> dict[str, Any]:
        return {"method": self.method, "theta": self.theta.as_dict(),
                "std": dict(zip(PARAMETER_NAMES, self.std, strict=True)),
                "identified": dict(zip(PARAMETER_NAMES, self.identified, strict=True)),
                "status": self.status, "held_out_E_p_m": self.held_out_e_p_m,
                "folds_E_p_m": list(self.folds_e_p_m), "truth_error": self.truth_error,
                "elapsed_s": self.elapsed_s, "error": self.error}


@dataclass(frozen=True)
class Comparison:
    scores: tuple[MethodScore, ...]
    block_s: float
    favoured: tuple[str, ...]          # the best held-out E_p, and those within TIE of it
    datasheet_e_p_m: float | None

    @property
    def verdict(self) -> str:
        usable = [s for s in self.scores if s.held_out_e_p_m is not None]
        if not usable:
            return "no method could be validated on held-out data"
        best = min(usable, key=lambda s: s.held_out_e_p_m or 0.0)
        default = next((s for s in usable if s.method == DEFAULT_METHOD), None)
        if len(self.favoured) > 1:
            text = (f"held-out E_p: {', '.join(self.favoured)} are equally good "
                    f"(within {TIE:.0%} of {best.held_out_e_p_m:.3f} m)")
        else:
            text = f"held-out E_p favours {best.method} ({best.held_out_e_p_m:.3f} m)"
        if default is not None and DEFAULT_METHOD not in self.favoured:
            text += f"; the default {DEFAULT_METHOD} reaches {default.held_out_e_p_m:.3f} m"
        return text

    def to_dict(self) -> dict[str, Any]:
        return {"block_s": self.block_s, "favoured": list(self.favoured),
                "verdict": self.verdict, "datasheet_held_out_E_p_m": self.datasheet_e_p_m,
                "methods": [s.to_dict() for s in self.scores]}


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
    departures : the sensors' departures measured and taken out before the fit (a_y's clock and
        offset, a heading error varying with the heading: :mod:`odocal.checks.departures`)
    vehicle_estimate : for a model beyond the rear axle (``[vehicle] model = "four_wheel"``),
        its estimate: :attr:`estimate` is its rear axle's, fitted as the rear-axle model's and
        validated, reported and exported as that; None for the rear axle
    model_settings : the settings of that model (:attr:`settings` are its rear axle's)
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
    departures: Departures | None = None
    vehicle_estimate: Estimate | None = None
    model_settings: Settings | None = None

    @property
    def model_estimate(self) -> Estimate:
        """The chosen vehicle model's estimate (``[vehicle] model``): the four-wheel car's
        (the rear axle's :attr:`estimate` joined with its front axle and steering), or the
        rear axle's :attr:`estimate` itself."""
        return self.vehicle_estimate if self.vehicle_estimate is not None else self.estimate

    @property
    def theta(self) -> Parameters:
        return self.estimate.theta

    @property
    def reference_arm(self) -> tuple[float, float]:
        """Where the reference reports, forward and left of the rear axle (m): as stated
        (``[reference] offset_m``) or as the default method's fit found it (0 where neither)."""
        stated = self.settings.reference.offset_m
        if stated is not None:
            return float(stated[0]), float(stated[1])
        fitted = dict(getattr(self.estimate.details, "fitted_departures", {}) or {})
        return float(fitted.get("arm_x", 0.0)), float(fitted.get("arm_y", 0.0))

    @functools.cached_property
    def odometry_noise(self) -> OdometryNoise | None:
        """The calibrated wheel odometry's speed and yaw-rate noise against the reference
        motion over 1 s windows (robust standard deviations); None without drives enough."""
        return odometry_noise(self.drive_data, self.theta)

    def trajectories(self) -> Iterator[Trajectories]:
        """Every drive's reference poses and its wheels dead-reckoned with the calibrated and
        the datasheet parameters, from where the reference reports (:attr:`reference_arm`),
        one drive at a time."""
        return trajectories(self.drive_data, self.estimate.theta, self.estimate.datasheet,
                            arm=self.reference_arm)

    @property
    def speed_scale(self) -> SpeedScale | None:
        """Where the wheels were speeds turned into rates with an assumed circumference, the
        factor the speed signal is off by (what c_e means then); None where the wheels' own
        rates were logged, or c_e is not identified."""
        signal = speed_signal(self.drive_data)
        if signal is None or not self.estimate.identified[0]:
            return None
        circumference, unit = signal
        return SpeedScale(factor=float(self.theta.c_e) / circumference,
                          std=float(self.estimate.std[0]) / circumference,
                          circumference_m=circumference, unit=unit)

    def save(self, folder: str | Path, *, exports: Sequence[str] = (), report: bool = True,
             save_inputs: bool = False, wheel_joints: tuple[str, str] | None = None,
             inputs: Sequence[Any] = (),
             progress: Callable[[str, int, int], None] | None = None,
             renderer: Any = None) -> Written:
        """Write the results folder, as ``odocal calibrate --out folder`` does:
        calibration.json, report.html with its figures (``report``), the ``exports``
        (``"autoware"``, ``"ros2_control"``, ``"robot_localization"``, ``"yaml"``, ``"json"``,
        ``"tum"``).

        The folder is built beside ``folder`` and swapped in whole when complete; a folder
        that holds anything odocal did not write, or that is or holds one of the drive files
        read (or ``inputs``), is refused before anything is written
        (:class:`odocal.OutputError`). Returns what was written
        (:class:`odocal.output.results.Written`: ``paths`` relative to the folder, ``files``
        where they are).

        (The output layer writes it: :func:`odocal.output.results.save_results`; the one call
        from the pipeline's result type up to it, so that what a calibration returns can be
        saved where it is held.)
        """
        from odocal.output.results import save_results

        return save_results(self, folder, exports=exports, report=report,
                            save_inputs=save_inputs, wheel_joints=wheel_joints, inputs=inputs,
                            progress=progress, renderer=renderer)

    def summary(self) -> list[str]:
        """The lines ``odocal calibrate`` prints (:func:`odocal.report.summary.summary_lines`
        has the same words with a simulated drive's truth)."""
        lines = [self.read_text(), f"method: {self.method}, identified from {self.used_text()}",
                 "", *self.estimate.table(speed_scale=self.speed_scale is not None)]
        if self.vehicle_estimate is not None:
            lines += ["", f"the {self.vehicle_estimate.model} model (the rear axle above, "
                          "joined with the front axle and the steering):",
                      *self.vehicle_estimate.table()]
        if self.validation is not None and self.datasheet_validation is not None:
            lines += ["", f"validation error E_p over {self.validation_text()}: datasheet "
                          f"{self.datasheet_validation.mean_error_m:.2f} m -> calibrated "
                          f"{self.validation.mean_error_m:.2f} m"]
        return lines

    def __repr__(self) -> str:
        head = (f"CalibrationResult(method={self.method!r}, "
                f"status={self.estimate.status.name.lower()}, "
                f"drives={len(self.drives)}, elapsed_s={self.elapsed_s:.2f})")
        return "\n".join([head, *self.summary()])

    def read_text(self) -> str:
        """What was read, in a few words ("read 4 drives: 1.3 min, 0.67 km")."""
        km = sum(d.distance_m for d in self.drives) / 1000
        minutes = sum(d.duration_s for d in self.drives) / 60
        n = len(self.drives)
        return f"read {n} drive{'s' if n != 1 else ''}: {minutes:.1f} min, {km:.2f} km"

    def validation_text(self) -> str:
        """The validation segments in a few words ("2 segments (0.46 km, up to 300 m each)")."""
        if self.validation is None:
            return "no validation segment"
        seg = self.validation.segments
        n = len(seg)
        return (f"{n} segment{'s' if n != 1 else ''} "
                f"({float(seg.distance_m.sum()) / 1000:.2f} km, up to "
                f"{self.settings.segments.validation_distance_m:.0f} m each)")

    @property
    def method(self) -> str:
        return self.estimate.method

    @property
    def success(self) -> bool:
        return self.estimate.success

    @property
    def segments_used(self) -> int:
        """Identification segments the segment-based methods fitted (see :attr:`used_data`)."""
        return int(self.used.sum())

    @property
    def used_data(self) -> dict[str, Any]:
        """What the method really fitted: the default method its windows (every one of every
        drive, straight or not), the segment methods their selected segments; with the
        independent clusters they form and the drives they come from."""
        details = self.estimate.details
        if isinstance(details, InverseDetails):
            return {"unit": "windows", "count": details.windows,
                    "length_s": details.window_s, "clusters": details.clusters,
                    "drives": len(self.drives)}
        clusters = getattr(details, "clusters", None)
        steps = int(self.segments.steps[0]) if len(self.segments) else 0
        return {"unit": "segments", "count": self.segments_used,
                "length_s": steps * (self.drive_data[0].t_s if self.drive_data else 0.0),
                "clusters": clusters, "drives": len(self.drives)}

    def used_text(self) -> str:
        """:attr:`used_data` in a few words ("39 windows of 2 s, 8 clusters, 5 drives")."""
        u = self.used_data
        clusters = f", {u['clusters']} clusters" if u["clusters"] is not None else ""
        return (f"{u['count']} {u['unit']} of {u['length_s']:.3g} s{clusters}, "
                f"{u['drives']} drive{'s' if u['drives'] != 1 else ''}")

    def to_dict(self) -> dict[str, Any]:
        """The content of ``calibration.json``."""
        est = self.model_estimate
        out: dict[str, Any] = {"odocal_version": __version__, **est.to_dict()}
        out["unidentified_reasons"] = {n: est.verdict(n).reason.value  # type: ignore[union-attr]
                                       for n in est.unidentified}
        out["used"] = self.used_data
        speed = self.speed_scale
        out["speed_scale"] = speed.to_dict() if speed is not None else None
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
        out["departures"] = self.departures.to_dict() if self.departures is not None else None
        out["settings"] = (self.model_settings or self.settings).to_dict()
        out["bootstrap"] = self.bootstrap.to_dict() if self.bootstrap is not None else None
        if self.three_step is not None:
            out["three_step"] = self.three_step.to_dict()
        if self.comparison is not None:
            out["comparison"] = self.comparison.to_dict()
        return out
