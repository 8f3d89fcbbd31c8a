"""The quality gate after a fit: plausible ranges and the validation error (README, "When odocal
refuses"). A failing check rejects the calibration (exit 3) with the reason."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from odocal.checks.findings import Check, Finding, Severity
from odocal.settings import Settings

FloatArray = NDArray[np.float64]


def plausible_range(settings: Settings, name: str) -> tuple[float, float]:
    """The [low, high] range of ``c_e`` or ``t_r``: ``[gate]`` ``c_e_m`` / ``t_r_m`` where set,
    else the datasheet value divided and multiplied by ``range_factor`` (a robot's 0.44 m
    wheel and a truck's 3.5 m one are both plausible against their own datasheets)."""
    given = settings.gate.c_e_m if name == "c_e" else settings.gate.t_r_m
    if given is not None:
        return given
    nominal = settings.identify.theta0[0 if name == "c_e" else 2]
    return nominal / settings.gate.range_factor, nominal * settings.gate.range_factor


def gate(theta: FloatArray, settings: Settings, *, error_m: float | None,
         datasheet_error_m: float | None, segment_m: float | None) -> list[Finding]:
    """The checks after the fit: physical ranges and the validation error."""
    lim = settings.gate
    out: list[Finding] = []
    for j, name in ((0, "c_e"), (2, "t_r")):
        lo, hi = plausible_range(settings, name)
        if not lo <= theta[j] <= hi:
            out.append(Finding(Check.PARAMETER_RANGE, Severity.FATAL, float(theta[j]),
                               float(hi if theta[j] > hi else lo), name))
    if abs(theta[1]) > lim.max_abs_c_d_fraction * abs(theta[0]):
        out.append(Finding(Check.PARAMETER_RANGE, Severity.FATAL, float(theta[1]),
                           lim.max_abs_c_d_fraction * abs(theta[0]), "c_d"))
    if abs(theta[3]) > lim.max_abs_d:
        out.append(Finding(Check.PARAMETER_RANGE, Severity.FATAL, float(theta[3]),
                           lim.max_abs_d, "d"))
    if error_m is not None and datasheet_error_m is not None:
        if error_m > datasheet_error_m * (1.0 + lim.worse_tolerance) + 1e-6:
            out.append(Finding(Check.WORSE_THAN_DATASHEET, Severity.FATAL, error_m,
                               datasheet_error_m))
        if segment_m and error_m > lim.max_error_share * segment_m:
            out.append(Finding(Check.LARGE_ERROR, Severity.FATAL, error_m,
                               lim.max_error_share * segment_m))
    return out
