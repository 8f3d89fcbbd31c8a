"""Checks of the data against the model, before and after a fit, and the quality gate.

Before the fit (:func:`check_drives`), with the datasheet parameters, one-second windows of the
drives are compared with the model's expectations:

* the yaw rate the wheels imply against the reference's: a negative correlation in bends means
  the left and right wheels are swapped (or the heading is mirrored); identical wheel signals, or
  no correlation at all while the reference turns, mean the wheels carry no differential
  information (a column copied into the other, a locked axle, a single speed signal);
* the distance the wheels imply against the reference's: a ratio far from one is a unit or scale
  mistake (rpm for rev/s, radius for circumference, km/h for m/s);
* the lateral acceleration against speed times yaw rate: a negative slope is a flipped sign, a
  slope near 1/9.81 an acceleration in g;
* the clock offset between the wheel and pose streams, by cross-correlating their yaw rates;
* a vehicle that does not move at all.

After the fit (:func:`gate`): parameters outside physical ranges, a validation error worse than
the datasheet values', or one that is a large share of the segments' length fail the calibration.

Findings carry numbers and a :class:`Check` code; words are made from them in
:mod:`odocal.report.advice` (for the CLI and the report).
"""

from __future__ import annotations

import enum
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from odocal.data.drive import Drive
from odocal.model.kinematics import body_rates, motion_increments
from odocal.settings import Settings

FloatArray = NDArray[np.float64]


class Check(enum.Enum):
    """What a finding is about."""

    STANDSTILL = "standstill"
    WHEELS_SWAPPED = "wheels-swapped"
    WHEELS_IDENTICAL = "wheels-identical"
    NO_DIFFERENTIAL = "no-differential"
    SPEED_SCALE = "speed-scale"
    LATERAL_SIGN = "lateral-sign"
    LATERAL_SCALE = "lateral-scale"
    CLOCK_OFFSET = "clock-offset"
    HEADING_OFFSET = "heading-offset"
    PARAMETER_RANGE = "parameter-range"
    WORSE_THAN_DATASHEET = "worse-than-datasheet"
    LARGE_ERROR = "large-error"
    DATA_REPAIRED = "data-repaired"


class Severity(enum.IntEnum):
    NOTE = 0
    """Worth knowing; the calibration stands."""
    FALLBACK = 1
    """The calibration does less than asked, and says what (e.g. c_e alone)."""
    FATAL = 2
    """The data contradict the model: the calibration fails (exit 3)."""


@dataclass(frozen=True)
class Finding:
    """One check's outcome.

    check : what was checked
    severity : what it means for the calibration
    value : the number behind it (a correlation, a ratio, seconds, metres, ...)
    reference : what the value should be near (for the words)
    name : the parameter, column or drive concerned, where one is
    """

    check: Check
    severity: Severity
    value: float = float("nan")
    reference: float = float("nan")
    name: str = ""

    def to_dict(self) -> dict[str, Any]:
        return {"check": self.check.value, "severity": self.severity.name.lower(),
                "value": self.value, "reference": self.reference, "name": self.name}


@dataclass(frozen=True)
class Diagnosis:
    """Every finding of the checks before (and after) the fit."""

    findings: tuple[Finding, ...]

    @property
    def fatal(self) -> bool:
        return any(f.severity is Severity.FATAL for f in self.findings)

    @property
    def no_differential(self) -> bool:
        return any(f.check in (Check.WHEELS_IDENTICAL, Check.NO_DIFFERENTIAL)
                   for f in self.findings)

    @property
    def standstill(self) -> bool:
        return any(f.check is Check.STANDSTILL for f in self.findings)

    def plus(self, more: Sequence[Finding]) -> Diagnosis:
        return Diagnosis(findings=(*self.findings, *more))

    def to_dict(self) -> list[dict[str, Any]]:
        return [f.to_dict() for f in self.findings]


@dataclass(frozen=True)
class _Windows:
    """One-second windows of every drive: reference and wheel quantities."""

    ds: FloatArray            # reference along-track distance, m
    dpsi: FloatArray          # reference heading change, rad
    wheel_ds: FloatArray      # distance the wheels imply (datasheet theta), m
    wheel_dpsi: FloatArray    # heading change the wheels imply, rad
    diff_revs: FloatArray     # right minus left revolutions
    a_y: FloatArray           # mean lateral acceleration, m/s^2
    v_w: FloatArray           # mean of speed times yaw rate (reference), m/s^2
    duration_s: float


def _windows(drives: Sequence[Drive], theta: FloatArray) -> _Windows:
    parts: dict[str, list[FloatArray]] = {k: [] for k in ("ds", "dpsi", "wds", "wdpsi", "diff",
                                                           "ay", "vw")}
    duration = 0.0
    for d in drives:
        length = max(round(1.0 / d.t_s), 1)
        for a, b in d.pieces:
            n = (b - a - 1) // length
            if n < 1:
                continue
            ds, dpsi = motion_increments(d.x[a:b], d.y[a:b], d.psi[a:b], d.beta[a:b])
            v, w = body_rates(theta, d.n_rl[a:b - 1], d.n_rr[a:b - 1], d.a_y[a:b - 1])
            cut = n * length

            def wsum(x: FloatArray, cut: int = cut, length: int = length) -> FloatArray:
                return x[:cut].reshape(-1, length).sum(axis=1)

            parts["ds"].append(wsum(ds))
            parts["dpsi"].append(wsum(dpsi))
            parts["wds"].append(wsum(v * d.t_s))
            parts["wdpsi"].append(wsum(w * d.t_s))
            parts["diff"].append(wsum((d.n_rr[a:b - 1] - d.n_rl[a:b - 1]) * d.t_s))
            parts["ay"].append(wsum(d.a_y[a:b - 1]) / length)
            parts["vw"].append(wsum(ds * dpsi) / (length * d.t_s**2))
            duration += cut * d.t_s
    cat = {k: np.concatenate(v) if v else np.zeros(0) for k, v in parts.items()}
    return _Windows(ds=cat["ds"], dpsi=cat["dpsi"], wheel_ds=cat["wds"],
                    wheel_dpsi=cat["wdpsi"], diff_revs=cat["diff"], a_y=cat["ay"],
                    v_w=cat["vw"], duration_s=duration)


def _correlation(a: FloatArray, b: FloatArray) -> float:
    a = a - a.mean()
    b = b - b.mean()
    denominator = float(np.sqrt((a @ a) * (b @ b)))
    return float(a @ b) / denominator if denominator > 0 else 0.0


def check_drives(drives: Sequence[Drive], settings: Settings) -> Diagnosis:
    """The checks before the fit (see the module docstring)."""
    lim = settings.gate
    theta = np.asarray(settings.identify.theta0, dtype=np.float64)
    win = _windows(drives, theta)
    findings: list[Finding] = []
    for d in drives:
        repaired = d.metadata.get("repaired")
        if isinstance(repaired, dict):
            for column, count in repaired.items():
                findings.append(Finding(Check.DATA_REPAIRED, Severity.NOTE, float(count),
                                        name=f"{d.name}:{column}"))
    wheel_m = float(np.abs(win.wheel_ds).sum())
    if wheel_m < lim.min_distance_m:
        findings.append(Finding(Check.STANDSTILL, Severity.FALLBACK, wheel_m,
                                lim.min_distance_m))
        return Diagnosis(tuple(findings))
    moving = np.abs(win.ds) > lim.min_speed_mps * 1.0        # windows of one second
    ratio = float(np.median(win.wheel_ds[moving] / win.ds[moving])) if moving.sum() >= 5 \
        else float(np.abs(win.wheel_ds).sum() / max(np.abs(win.ds).sum(), 1e-9))
    if not lim.min_scale <= ratio <= lim.max_scale:
        findings.append(Finding(Check.SPEED_SCALE, Severity.FATAL, ratio, 1.0))
    elif abs(ratio - 1.0) > lim.datasheet_scale_note:
        findings.append(Finding(Check.SPEED_SCALE, Severity.NOTE, ratio, 1.0))

    bends = moving & (np.abs(win.dpsi) > lim.bend_yaw_rate_radps)
    if not np.any(np.abs(win.diff_revs) > 1e-12):
        findings.append(Finding(Check.WHEELS_IDENTICAL, Severity.FALLBACK, 0.0))
    elif bends.sum() >= lim.min_bend_windows:
        corr = _correlation(win.wheel_dpsi[bends], win.dpsi[bends])
        if corr < -lim.min_yaw_correlation:
            findings.append(Finding(Check.WHEELS_SWAPPED, Severity.FATAL, corr, 1.0))
        elif corr < lim.min_yaw_correlation:
            findings.append(Finding(Check.NO_DIFFERENTIAL, Severity.FALLBACK, corr, 1.0))
        else:
            findings += _lateral(win, bends, lim.min_yaw_correlation)
            findings += _clock(drives, theta, settings)
    return Diagnosis(tuple(findings))


def _lateral(win: _Windows, bends: NDArray[np.bool_], min_correlation: float) -> list[Finding]:
    """a_y against speed times yaw rate, in bends: sign and unit."""
    if not np.any(np.abs(win.a_y) > 0):
        return []
    corr = _correlation(win.a_y[bends], win.v_w[bends])
    vw = win.v_w[bends]
    slope = float(win.a_y[bends] @ vw / max(float(vw @ vw), 1e-12))
    if corr < -min_correlation:
        return [Finding(Check.LATERAL_SIGN, Severity.FATAL, slope, 1.0, "a_y")]
    if corr > min_correlation and not 0.5 <= slope <= 2.0:
        return [Finding(Check.LATERAL_SCALE, Severity.FATAL, slope, 1.0, "a_y")]
    return []


def _clock(drives: Sequence[Drive], theta: FloatArray, settings: Settings) -> list[Finding]:
    """Lag of the wheels' yaw rate behind the reference's, by cross-correlation (up to 2 s).

    The cross products are summed over every piece of at least 20 s; a positive lag means the
    wheel stream is late.
    """
    lim = settings.gate
    t_s = drives[0].t_s
    span = round(2.0 / t_s)
    lags = np.arange(-span, span + 1)
    scores = np.zeros(lags.size)
    used = 0
    for d in drives:
        for a, b in d.pieces:
            if b - a < round(20.0 / d.t_s):
                continue
            _, w = body_rates(theta, d.n_rl[a:b], d.n_rr[a:b], d.a_y[a:b])
            ref = np.gradient(d.psi[a:b], d.t_s)
            wc, rc = w - w.mean(), ref - ref.mean()
            n = wc.size
            for i, k in enumerate(lags):
                scores[i] += float(np.dot(wc[max(k, 0):n + min(k, 0)],
                                          rc[max(-k, 0):n - max(k, 0)]))
            used += 1
    if not used:
        return []
    lag = float(lags[int(np.argmax(scores))] * t_s)
    if abs(lag) > lim.max_clock_offset_s:
        return [Finding(Check.CLOCK_OFFSET, Severity.FATAL, lag, 0.0)]
    if abs(lag) > settings.inverse.max_delay_s:
        return [Finding(Check.CLOCK_OFFSET, Severity.NOTE, lag, 0.0)]
    return []


def gate(theta: FloatArray, settings: Settings, *, error_m: float | None,
         datasheet_error_m: float | None, segment_m: float | None) -> list[Finding]:
    """The checks after the fit: physical ranges and the validation error."""
    lim = settings.gate
    out: list[Finding] = []
    ranges = {"c_e": lim.c_e_m, "t_r": lim.t_r_m}
    for j, name in ((0, "c_e"), (2, "t_r")):
        lo, hi = ranges[name]
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
