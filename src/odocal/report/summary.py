"""A calibration in a few lines of text: what the command line prints after a calibration.

The same words every path shows (``calibrate``, ``demo``, the fleet's per-drive summary): the
drives read, the method and what it fitted, the parameters beside their datasheet values with
their uncertainty, the validation error, and every finding of the checks and every parameter
not identified, with its reason. The command line only prints these lines.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from odocal.checks.findings import Finding, Severity
from odocal.estimators.estimate import Estimate, NotIdentified, Reason, Status
from odocal.model.parameters import PARAMETER_DISPLAY, PARAMETER_NAMES, PARAMETER_UNITS, Parameters
from odocal.pipeline.result import CalibrationResult
from odocal.report.advice import consistent_with_zero, finding_text, reason_text, zero_text
from odocal.settings import Settings, datasheet_stated

#: The words before each finding by its severity.
SEVERITY_WORDS = {0: "note", 1: "warning", 2: "error"}


def parameter_text(name: str, value: float) -> str:
    """A parameter's value in the unit it reads best in (c_d, d in mm), signed where a sign
    means something."""
    scale, unit = PARAMETER_DISPLAY[name]
    return f"{value * scale:+.3f} {unit}" if scale != 1.0 else f"{value:.5f} {unit}"


def std_text(name: str, std: float) -> str:
    """A standard deviation in the parameter's display unit, as ``+-value``."""
    scale, _ = PARAMETER_DISPLAY[name]
    return f"+-{std * scale:.3f}" if scale != 1.0 else f"+-{std:.5f}"


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
    true values and the errors, ``best_std`` (its Cramér-Rao bound) the least std possible."""
    est = result.estimate
    drives = result.drives
    total_km = sum(d.distance_m for d in drives) / 1000
    total_min = sum(d.duration_s for d in drives) / 60
    segs = result.settings.segments
    lines = [f"read {len(drives)} drive(s): {total_min:.1f} min, {total_km:.2f} km; "
             f"{len(result.segments)} segments of {segs.length} samples, "
             f"{int(result.segments.selected.sum())} with bends "
             f"(peak yaw rate > {segs.yaw_rate_threshold_radps} rad/s)",
             f"method: {result.method}, identified from {result.used_text()} "
             f"in {result.elapsed_s:.1f} s", ""]
    header = f"{'parameter':<10} {'datasheet':>16} {'calibrated':>16} {'std':>10}"
    if best_std is not None:
        header += f" {'best std':>10}"
    if truth is not None:
        header += f" {'true':>16} {'error':>10}"
    lines.append(header)
    theta0, theta = est.datasheet.as_dict(), est.theta.as_dict()
    true = truth.as_dict() if truth is not None else None
    std = dict(zip(PARAMETER_NAMES, est.std, strict=True))
    exact = est.status is Status.EXACT
    for j, (name, ok) in enumerate(zip(PARAMETER_NAMES, est.identified, strict=True)):
        if ok:
            cal = parameter_text(name, theta[name])
            sd = "exact" if exact else std_text(name, std[name])
        else:
            cal, sd = "not identified", ""
        line = f"{name:<10} {parameter_text(name, theta0[name]):>16} {cal:>16} {sd:>10}"
        if best_std is not None:
            best = best_std[j]
            line += f" {std_text(name, best) if math.isfinite(best) else '-':>10}"
        if true is not None:
            err = std_text(name, abs(theta[name] - true[name])).replace("+-", "") if ok else ""
            line += f" {parameter_text(name, true[name]):>16} {err:>10}"
        lines.append(line)
    if best_std is not None:
        lines.append("best std: the smallest std an unbiased calibration of this drive can "
                     "have (its wheel errors' Cramér-Rao bound, the reference taken as exact)")
    note = datasheet_note(est.datasheet) if truth is None else None
    if note:
        lines.append(note)
    lines.append("")
    if result.validation is not None and result.datasheet_validation is not None:
        seg = result.validation.segments
        line = (f"validation error E_p over {len(seg)} segments of "
                f"~{segs.validation_distance_m:.0f} m: "
                f"datasheet {result.datasheet_validation.mean_error_m:.2f} m -> calibrated "
                f"{result.validation.mean_error_m:.2f} m")
        if truth_error_m is not None:
            line += f" (true parameters: {truth_error_m:.2f} m)"
        lines.append(line)
    else:
        lines.append("validation error E_p: not available (no validation segment)")
    if exact:
        lines.append(f"note: {est.message}")
    lines += [f"{SEVERITY_WORDS[int(f.severity)]}: {finding_text(f, result.settings)}"
              for f in result.diagnosis.findings]
    for j, (name, verdict) in enumerate(zip(PARAMETER_NAMES, est.verdicts, strict=True)):
        if isinstance(verdict, NotIdentified) and verdict.reason not in (
                Reason.REJECTED, Reason.STANDSTILL, Reason.FAILED):
            why = reason_text(name, verdict, threshold_radps=segs.yaw_rate_threshold_radps)
            lines.append(f"note: {name} ({PARAMETER_UNITS[j]}) is not identified: {why}")
    for name in consistent_with_zero(est):       # identified, but no evidence of the effect
        j = PARAMETER_NAMES.index(name)
        lines.append(f"note: {zero_text(name, float(est.theta.as_array()[j]), float(est.std[j]))}")
    lines += [f"warning: {w}" for w in result.warnings]
    if not result.success and est.status is not Status.NOTHING_IDENTIFIABLE:
        lines.append(f"calibration failed: {est.message}")
    return lines


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
