"""Every number the report shows, computed once from a calibration (also in calibration.json)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from odocal.estimators.validation import segment_errors, validation_data
from odocal.model.kinematics import rollout
from odocal.model.parameters import PARAMETER_NAMES, Inputs
from odocal.pipeline.result import CalibrationResult
from odocal.report.advice import ParameterAdvice, advise, coverage

FloatArray = NDArray[np.float64]
MAP_SEGMENTS = 3


@dataclass(frozen=True)
class MapSegment:
    """One validation segment dead-reckoned with the datasheet and the calibrated parameters."""

    drive: str
    start_s: float
    distance_m: float
    reference: FloatArray
    datasheet: FloatArray
    calibrated: FloatArray

    def to_dict(self) -> dict[str, Any]:
        return {"drive": self.drive, "start_s": self.start_s, "distance_m": self.distance_m,
                "final_error_m": {
                    "datasheet": float(np.hypot(*(self.datasheet[-1] - self.reference[-1]))),
                    "calibrated": float(np.hypot(*(self.calibrated[-1] - self.reference[-1])))}}


@dataclass(frozen=True)
class ReportData:
    verdict: str
    verdict_level: str
    advice: list[ParameterAdvice]
    coverage: dict[str, Any]
    speed_hist: tuple[FloatArray, FloatArray]
    yaw_hist: tuple[FloatArray, FloatArray]
    segment_errors: dict[str, FloatArray]
    maps: list[MapSegment]

    def to_dict(self) -> dict[str, Any]:
        return {
            "verdict": self.verdict, "verdict_level": self.verdict_level,
            "identifiability": [a.to_dict() for a in self.advice],
            "coverage": self.coverage,
            "speed_histogram": {"edges_mps": self.speed_hist[1].tolist(),
                                "seconds": self.speed_hist[0].tolist()},
            "yaw_rate_histogram": {"edges_radps": self.yaw_hist[1].tolist(),
                                   "seconds": self.yaw_hist[0].tolist()},
            "validation_segment_errors_m": {k: v.tolist() for k, v in
                                            self.segment_errors.items()},
            "map_segments": [m.to_dict() for m in self.maps],
        }


def verdict(result: CalibrationResult, raw_m: float | None = None) -> tuple[str, str]:
    """One line, and a level (good, partial, bad) for its colour.

    ``raw_m`` is E_p of the raw estimate the three-step method computed alongside, if any.
    """
    from odocal.checks.findings import Severity
    from odocal.estimators.estimate import Status
    from odocal.report.advice import finding_text

    est = result.estimate
    fatal = [f for f in result.diagnosis.findings if f.severity is Severity.FATAL]
    if fatal:
        return ("Do not use: " + "; ".join(finding_text(f, result.settings) for f in fatal)
                + ".", "bad")
    if result.diagnosis.standstill:
        return "Nothing to calibrate: the vehicle does not move.", "partial"
    if est.status is Status.NOTHING_IDENTIFIABLE:
        return f"Nothing calibrated: {est.message}; see the identifiability notes.", "partial"
    if not result.success:
        return f"Calibration failed: {est.message}.", "bad"
    missing = est.unidentified
    if result.validation is None or result.datasheet_validation is None:
        base = "Calibrated, but the drive holds no validation segment to check it on"
        level = "partial"
    else:
        before = result.datasheet_validation.mean_error_m
        after = result.validation.mean_error_m
        if after >= before:
            return (f"Do not use: the calibrated parameters validate no better than the datasheet "
                    f"values ({after:.2f} m against {before:.2f} m).", "bad")
        base = (f"Calibrated: the validation error E_p falls from {before:.2f} m to {after:.2f} m "
                f"(-{(1 - after / before) * 100:.0f}%) over {len(result.validation.segments)} "
                f"segments of ~{result.settings.segments.validation_distance_m:.0f} m")
        level = "good"
    if missing:
        base += f"; {', '.join(missing)} not identified (kept at the datasheet values)"
        level = "partial"
    else:
        base += "; all four parameters identified"
    km = sum(d.distance_m for d in result.drives) / 1000
    if km < MIN_DISTANCE_KM:
        # said first: the numbers after it look good and are not to be trusted yet
        base = (f"Drive too short to trust: {km:.2f} km of driving, less than the "
                f"{MIN_DISTANCE_KM:g} km a calibration should rest on (README, 'Real logs'); "
                f"check it on another drive. {base}")
        level = "partial" if level == "good" else level
    if result.bootstrap is not None and not all(result.bootstrap.agree):
        base += "; the bootstrap disagrees with the covariance"
        level = "partial" if level == "good" else level
    # (a difference within 2% is the validation segments' noise, not a better method)
    if raw_m is not None and result.validation is not None \
            and raw_m < 0.98 * result.validation.mean_error_m:
        base += (f". Batch G-N on the measured rates validates better ({raw_m:.2f} m): "
                 "consider --method raw")
        level = "partial" if level == "good" else level
    return base + ".", level


#: Less driving than this never gets the green verdict: its validation rests on a handful of
#: segments, and a few bends decide t_r and d (README, "Real logs").
MIN_DISTANCE_KM = 2.0


def build(result: CalibrationResult) -> ReportData:
    drives = result.drive_data
    settings = result.settings
    cov = coverage(drives, result.segments, settings)
    speeds = np.concatenate([np.hypot(np.gradient(d.x), np.gradient(d.y)) / d.t_s
                             for d in drives])
    yaws = np.concatenate([d.yaw_rate for d in drives])
    t_s = drives[0].t_s
    speed_hist = np.histogram(speeds, bins=np.arange(0.0, max(float(speeds.max()), 1.0) + 1.0,
                                                     1.0))
    yaw_edges = np.linspace(-0.6, 0.6, 25)
    yaw_hist = np.histogram(np.clip(yaws, -0.599, 0.599), bins=yaw_edges)
    errors: dict[str, FloatArray] = {}
    maps: list[MapSegment] = []
    if result.validation is not None and result.datasheet_validation is not None:
        errors["datasheet"] = result.datasheet_validation.errors.mean_m
        errors["calibrated"] = result.validation.errors.mean_m
        segs = result.validation.segments
        if result.three_step is not None:
            data = validation_data(drives, segs, settings)
            errors["raw"] = segment_errors(result.three_step.raw.theta.as_array(), data).mean_m
        maps = _maps(result, segs)
    line, level = verdict(result, float(errors["raw"].mean()) if "raw" in errors else None)
    return ReportData(
        verdict=line, verdict_level=level,
        advice=advise(result.estimate, cov, settings, settings.segments.length * t_s),
        coverage=cov.to_dict(),
        speed_hist=(speed_hist[0] * t_s, speed_hist[1]), yaw_hist=(yaw_hist[0] * t_s, yaw_edges),
        segment_errors=errors, maps=maps)


def _maps(result: CalibrationResult, segs: Any) -> list[MapSegment]:
    """The validation segments that turn most, dead-reckoned both ways."""
    drives = result.drive_data
    turn = np.array([abs(drives[int(d)].psi[s + k] - drives[int(d)].psi[s])
                     for d, s, k in zip(segs.drive, segs.start, segs.steps, strict=True)])
    chosen = np.argsort(-turn, kind="stable")[:MAP_SEGMENTS]
    out = []
    theta0 = result.estimate.datasheet.as_array()
    theta = result.theta.as_array()
    for i in sorted(chosen):
        d = drives[int(segs.drive[i])]
        s, k = int(segs.start[i]), int(segs.steps[i])
        u = Inputs(d.n_rl[s:s + k], d.n_rr[s:s + k], d.beta[s:s + k], d.a_y[s:s + k])
        x0 = np.array([d.x[s], d.y[s], d.psi[s]])
        ref = np.column_stack([d.x[s:s + k + 1], d.y[s:s + k + 1]])
        out.append(MapSegment(drive=d.name, start_s=float(d.t[s] - d.t[0]),
                              distance_m=float(segs.distance_m[i]), reference=ref,
                              datasheet=rollout(theta0, u, x0, d.t_s)[:, :2],
                              calibrated=rollout(theta, u, x0, d.t_s)[:, :2]))
    return out


def parameter_rows(result: CalibrationResult) -> list[dict[str, Any]]:
    """The parameter table: datasheet, calibrated, standard deviations, identified."""
    est = result.estimate
    boot = result.bootstrap
    rows = []
    for j, name in enumerate(PARAMETER_NAMES):
        rows.append({"name": name, "datasheet": float(est.datasheet.as_array()[j]),
                     "calibrated": float(est.theta.as_array()[j]),
                     "std": float(est.std[j]),
                     "bootstrap_std": float(boot.std[j]) if boot is not None else None,
                     "identified": bool(est.identified[j])})
    return rows
