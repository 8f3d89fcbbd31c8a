"""The quality gate after a fit: plausible ranges and the validation error (docs/checks.md,
"When odocal refuses"). A failing check rejects the calibration (exit 3) with the reason."""

from __future__ import annotations

from odocal.arrays import FloatArray
from odocal.checks.findings import Check, Finding, Severity
from odocal.model.layout import REAR_AXLE as LAYOUT
from odocal.settings import Settings


def plausible_range(settings: Settings, name: str) -> tuple[float, float]:
    """The [low, high] range of ``c_e`` or ``t_r``: ``[gate]`` ``c_e_m`` / ``t_r_m`` where set,
    else the datasheet value divided and multiplied by ``range_factor`` (a robot's 0.44 m
    wheel and a truck's 3.5 m one are both plausible against their own datasheets)."""
    given = getattr(settings.gate, f"{name}_m")
    if given is not None:
        return (float(given[0]), float(given[1]))
    nominal = settings.identify.datasheet(name)
    return nominal / settings.gate.range_factor, nominal * settings.gate.range_factor


def gate(theta: FloatArray, settings: Settings, *, error_m: float | None,
         datasheet_error_m: float | None, segment_m: float | None) -> list[Finding]:
    """The checks after the fit: physical ranges and the validation error."""
    lim = settings.gate
    out: list[Finding] = []
    value = LAYOUT.named(list(theta))
    for name in LAYOUT.lengths:
        lo, hi = plausible_range(settings, name)
        if not lo <= value[name] <= hi:
            out.append(Finding(Check.PARAMETER_RANGE, Severity.FATAL, value[name],
                               float(hi if value[name] > hi else lo), name))
    scale, difference, load = value[LAYOUT.scale], value[LAYOUT.difference], value[LAYOUT.load]
    if abs(difference) > lim.max_abs_c_d_fraction * abs(scale):
        out.append(Finding(Check.PARAMETER_RANGE, Severity.FATAL, difference,
                           lim.max_abs_c_d_fraction * abs(scale), LAYOUT.difference))
    if abs(load) > lim.max_abs_d:
        out.append(Finding(Check.PARAMETER_RANGE, Severity.FATAL, load, lim.max_abs_d,
                           LAYOUT.load))
    if error_m is not None and datasheet_error_m is not None:
        if error_m > datasheet_error_m * (1.0 + lim.worse_tolerance) + 1e-6:
            out.append(Finding(Check.WORSE_THAN_DATASHEET, Severity.FATAL, error_m,
                               datasheet_error_m))
        if segment_m and error_m > lim.max_error_share * segment_m:
            out.append(Finding(Check.LARGE_ERROR, Severity.FATAL, error_m,
                               lim.max_error_share * segment_m))
    return out
