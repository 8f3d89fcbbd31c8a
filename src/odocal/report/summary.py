"""A calibration in a few lines of text: what the command line prints after a calibration.

The same words every path shows (``calibrate``, ``demo``, the fleet's per-drive summary): the
drives read, the method and what it fitted, the parameters beside their datasheet values with
their uncertainty, the validation error, and every finding of the checks and every parameter
not identified, with its reason. The command line only prints these lines.
"""

from __future__ import annotations

from collections.abc import Sequence

from odocal.checks.findings import Finding, Severity
from odocal.estimators.estimate import (
    Estimate,
    NotIdentified,
    Reason,
    Status,
    parameter_table,
    parameter_text,
    std_text,
)
from odocal.model.parameters import PARAMETER_NAMES, PARAMETER_UNITS, Parameters
from odocal.pipeline.result import CalibrationResult, SpeedScale
from odocal.report.advice import (
    consistent_with_zero,
    finding_text,
    front_advice,
    reason_text,
    zero_text,
)
from odocal.settings import Settings, datasheet_stated

#: The words before each finding by its severity.
SEVERITY_WORDS = {0: "note", 1: "warning", 2: "error"}


def datasheet_note(datasheet: Parameters) -> str | None:
    """A line saying the datasheet values are odocal's placeholder, or None when stated."""
    if datasheet_stated(datasheet):
        return None
    return (f"note: no datasheet values given: the 'datasheet' column is odocal's placeholder "
            f"car (c_e {datasheet.c_e:g} m, t_r {datasheet.t_r:g} m), not yours; state them "
            "with --datasheet c_e=..,t_r=..")


def summary_lines(result: CalibrationResult, *, truth: Parameters | None = None,
                  truth_error_m: float | None = None,
                  best_std: Sequence[float] | None = None) -> list[str]:
    """The calibration as a small table and its notes; ``truth`` (a simulated drive's) adds the
    true values and the errors, ``best_std`` (its Cramér-Rao bound) the least std possible.

    A refused calibration (the data contradict the model) publishes no parameters: it says
    what was read and why it was refused, never a table of datasheet values as if fitted."""
    est = result.estimate
    segs = result.settings.segments
    first = result.read_text()
    if result.method != "inverse":           # the segment methods' words
        first += (f"; {len(result.segments)} segments of {segs.length} samples, "
                  f"{int(result.segments.selected.sum())} with bends "
                  f"(peak yaw rate > {segs.yaw_rate_threshold_radps} rad/s)")
    lines = [first]
    findings = [f"{SEVERITY_WORDS[int(f.severity)]}: {finding_text(f, result.settings)}"
                for f in result.diagnosis.findings]
    if est.status is Status.REJECTED:
        return [*lines, *findings, *[f"warning: {w}" for w in result.warnings],
                f"calibration failed: {est.message}"]
    speed = result.speed_scale
    lines += [f"method: {result.method}, identified from {result.used_text()} "
              f"in {result.elapsed_s:.1f} s", "",
              *parameter_table(est, truth=truth, best_std=best_std,
                               speed_scale=speed is not None)]
    if best_std is not None:
        lines.append("best std: the smallest std an unbiased calibration of this drive can "
                     "have (its wheel errors' Cramér-Rao bound, the reference taken as exact)")
    note = datasheet_note(est.datasheet) if truth is None else None
    if note:
        lines.append(note)
    if speed is not None:
        lines.append(speed_note(speed, float(est.theta.c_e)))
    lines.append("")
    if result.validation is not None and result.datasheet_validation is not None:
        line = (f"validation error E_p over {result.validation_text()}: "
                f"datasheet {result.datasheet_validation.mean_error_m:.2f} m -> calibrated "
                f"{result.validation.mean_error_m:.2f} m")
        if truth_error_m is not None:
            line += f" (true parameters: {truth_error_m:.2f} m)"
        lines.append(line)
    else:
        lines.append("validation error E_p: not available (no validation segment)")
    if est.status is Status.EXACT:
        lines.append(f"note: {est.message}")
    lines += findings
    for j, (name, verdict) in enumerate(zip(PARAMETER_NAMES, est.verdicts, strict=True)):
        if isinstance(verdict, NotIdentified) and verdict.reason not in (
                Reason.REJECTED, Reason.STANDSTILL, Reason.FAILED):
            why = reason_text(name, verdict, threshold_radps=segs.yaw_rate_threshold_radps)
            lines.append(f"note: {name} ({PARAMETER_UNITS[j]}) is not identified: {why}")
    for name in consistent_with_zero(est):       # identified, but no evidence of the effect
        j = PARAMETER_NAMES.index(name)
        lines.append(f"note: {zero_text(name, float(est.theta.as_array()[j]), float(est.std[j]))}")
    lines += _car_lines(result, truth)
    lines += [f"warning: {w}" for w in result.warnings]
    if not result.success and est.status is not Status.NOTHING_IDENTIFIABLE:
        lines.append(f"calibration failed: {est.message}")
    return lines


def _car_lines(result: CalibrationResult, truth: Parameters | None) -> list[str]:
    """The whole car's table (a model beyond the rear axle: its truth beside it where
    ``truth`` is that model's) and what it lacks, in notes; none for the rear-axle model."""
    vehicle = result.vehicle_estimate
    if vehicle is None or vehicle.status is Status.REJECTED:
        return []
    whole = truth if truth is not None and truth.layout.names == vehicle.names else None
    return ["", f"the {vehicle.model} model: the rear axle above joined with the front axle "
                "and the steering", *parameter_table(vehicle, truth=whole),
            *(f"note: {a.text}" for a in front_advice(vehicle) if not a.identified)]


def speed_note(speed: SpeedScale, c_e: float) -> str:
    """What c_e means where the wheels were speeds turned into rates with an assumed
    circumference."""
    return (f"note: the wheel speeds were logged in {speed.unit} and turned into wheel rates "
            f"with an assumed circumference of {speed.circumference_m:g} m (--circumference, "
            "else the datasheet c_e): the wheels' own circumference is not in the log, so the "
            f"calibration is a scale factor on the speed signal, {speed.factor:.5f} "
            f"+-{speed.std:.5f} (the true speed over the reported one: Autoware's "
            f"speed_scale_factor); c_e = {c_e:.5f} m is that factor times the assumed "
            "circumference, and c_d is relative to it alike")


def rejection_line(estimate: Estimate, findings: Sequence[Finding],
                   settings: Settings) -> str | None:
    """One line that says why a calibration publishes no parameters (None: it does): the first
    contradiction the checks found, and how many more the report lists."""
    if estimate.status is not Status.REJECTED:
        return None
    fatal = [f for f in findings if f.severity is Severity.FATAL]
    if not fatal:
        return f"calibration failed: {estimate.message}"
    more = f" (and {len(fatal) - 1} more: see the report)" if len(fatal) > 1 else ""
    return f"error: {finding_text(fatal[0], settings)}{more}"


__all__ = ["SEVERITY_WORDS", "datasheet_note", "parameter_text", "rejection_line",
           "speed_note", "std_text", "summary_lines"]
