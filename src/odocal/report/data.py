"""Every number the report shows, computed once from a calibration (also in calibration.json)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from odocal.arrays import BoolArray, FloatArray, IntArray
from odocal.checks.findings import Check, Finding, Severity
from odocal.data.drive import Drive
from odocal.estimators.validation import segment_errors, validation_data
from odocal.model.kinematics import rollout
from odocal.model.parameters import PARAMETER_NAMES, Inputs
from odocal.pipeline.result import CalibrationResult
from odocal.report.advice import (
    ZERO_MEANS,
    ParameterAdvice,
    advise,
    consistent_with_zero,
    coverage,
    front_advice,
)

if TYPE_CHECKING:
    from odocal.checks.departures import Departures
    from odocal.estimators.inverse import InverseDetails

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
    turn_rad: float = 0.0
    """How far the reference's heading turns over the segment."""

    def to_dict(self) -> dict[str, Any]:
        return {"drive": self.drive, "start_s": self.start_s, "distance_m": self.distance_m,
                "final_error_m": {
                    "datasheet": float(np.hypot(*(self.datasheet[-1] - self.reference[-1]))),
                    "calibrated": float(np.hypot(*(self.calibrated[-1] - self.reference[-1])))}}


@dataclass(frozen=True)
class Fitted:
    """What the method that ran fitted, placed along the drives' time (one after another).

    unit : "window" (the default method) or "segment" (the segment methods)
    start_s, stop_s : (N,) where each window or segment lies on the time axis, s
    peak_yaw_radps : (N,) its largest |yaw rate|
    fitted : (N,) whether the method fitted it (the segment methods: the selection rule's
        choice; the default: every window it was given)
    cluster : (N,) its cluster label (neighbouring windows, overlapping segments)
    drives : (start, stop, name) of each drive on the time axis, s
    length_s : the duration of one window or segment
    after_change_s : where a change inside the log was found (on the time axis), if one was
    """

    unit: str
    start_s: FloatArray
    stop_s: FloatArray
    peak_yaw_radps: FloatArray
    fitted: BoolArray
    cluster: IntArray
    drives: tuple[tuple[float, float, str], ...]
    length_s: float
    after_change_s: float | None = None

    @property
    def count(self) -> int:
        return int(self.fitted.sum())

    @property
    def clusters(self) -> int:
        return int(np.unique(self.cluster[self.fitted]).size)

    def in_bends(self, threshold: float) -> int:
        return int((self.fitted & (self.peak_yaw_radps > threshold)).sum())

    def used_spans(self) -> FloatArray:
        """The time the fitted windows or segments cover, as sorted, disjoint (start, stop)
        rows on the time axis (overlaps and neighbours merged)."""
        a, b = self.start_s[self.fitted], self.stop_s[self.fitted]
        if not a.size:
            return np.zeros((0, 2))
        order = np.argsort(a, kind="stable")
        a, b = a[order], b[order]
        reach = np.maximum.accumulate(b)
        first = np.flatnonzero(np.concatenate([[True], a[1:] > reach[:-1]]))   # after a gap
        last = np.concatenate([first[1:], [a.size]]) - 1
        return np.column_stack([a[first], reach[last]])

    def fitted_s(self) -> float:
        """Seconds of driving the fitted windows or segments cover (overlaps counted once)."""
        spans = self.used_spans()
        return float(np.sum(spans[:, 1] - spans[:, 0]))

    def to_dict(self, threshold: float) -> dict[str, Any]:
        return {"unit": self.unit, "fitted": self.count, "not_fitted": int((~self.fitted).sum()),
                "clusters": self.clusters, "length_s": self.length_s,
                "fitted_s": self.fitted_s(), "fitted_in_bends": self.in_bends(threshold),
                "after_change_s": self.after_change_s}


@dataclass(frozen=True)
class Correction:
    """One departure of the sensors from the model that was measured before (or in) the fit:
    what, the number, and whether it was taken out of the data."""

    what: str
    measured: str
    taken_out: bool
    note: str

    def to_dict(self) -> dict[str, Any]:
        return {"what": self.what, "measured": self.measured, "taken_out": self.taken_out,
                "note": self.note}


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
    fitted: Fitted | None = None
    corrections: tuple[Correction, ...] = ()
    zero: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        return {
            "verdict": self.verdict, "verdict_level": self.verdict_level,
            "identifiability": [a.to_dict() for a in self.advice],
            "consistent_with_zero": list(self.zero),
            "coverage": self.coverage,
            "corrections": [c.to_dict() for c in self.corrections],
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
    Green ("good") only where the calibration is all it was asked to be: a finding that makes
    it do less (a change inside the log, wheels without a differential signal, no lateral
    acceleration) keeps it amber, and says so.
    """
    unusable = _no_calibration(result)
    if unusable is not None:
        return unusable
    est = result.estimate
    change = next((f for f in result.diagnosis.findings if f.check is Check.CHANGE_IN_LOG),
                  None)
    whole = result.model_estimate           # the four-wheel car's: its front and steering too
    missing = whole.unidentified
    if result.validation is None or result.datasheet_validation is None:
        base = "Calibrated, but the drive holds no validation segment to check it on"
        level = "partial"
    else:
        before = result.datasheet_validation.mean_error_m
        after = result.validation.mean_error_m
        if after >= before:
            return (f"Do not use: the calibrated parameters validate no better than the datasheet "
                    f"values ({after:.2f} m against {before:.2f} m).", "bad")
        worse = int(np.sum(np.asarray(result.validation.errors.mean_m)
                           > np.asarray(result.datasheet_validation.errors.mean_m)))
        n = len(result.validation.segments)
        base = (f"Calibrated: the validation error E_p falls from {before:.2f} m to {after:.2f} m "
                f"(-{(1 - after / before) * 100:.0f}%) over {result.validation_text()}"
                + (" after the change" if change is not None else "")
                + (f", though {worse} of the {n} got worse" if worse and n > 1 else ""))
        level = "good" if not worse else "partial"
    zero = consistent_with_zero(est)
    said_zero = (f" ({', '.join(zero)} consistent with zero: no measurable "
                 f"{' or '.join(ZERO_MEANS[n] for n in zero)})" if zero else "")
    if missing:
        base += (f"; {', '.join(missing)} not identified (kept at the datasheet values)"
                 + (f"; {said_zero.strip(' ()')}" if zero else ""))
        level = "partial"
    else:
        base += f"; all {len(whole.names)} parameters identified" + said_zero
    base, level = _caveats(result, base, level, change, raw_m)
    return base + ".", level


def _no_calibration(result: CalibrationResult) -> tuple[str, str] | None:
    """The verdict where there is no calibration to use (a fatal finding, a standstill,
    nothing identifiable, a failed solve); None where there is one."""
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
    return None


def _caveats(result: CalibrationResult, base: str, level: str, change: Finding | None,
             raw_m: float | None) -> tuple[str, str]:
    """The verdict line ``base`` with what qualifies it (a change inside the log, a short
    drive, the bootstrap's doubt, departures taken out, a better raw estimate), and its
    level: kept from green by any of them but the departures, and by a fallback finding."""
    from odocal.report.advice import finding_text

    findings = result.diagnosis.findings
    if change is not None:
        # the numbers are of the vehicle after the change: said first, as the short drive is
        base = (f"A change inside the log: {finding_text(change, result.settings)}. {base}")
        level = "partial" if level == "good" else level
    if any(f.severity is Severity.FALLBACK for f in findings):
        level = "partial" if level == "good" else level    # the calibration does less
    km = sum(d.distance_m for d in result.drives) / 1000
    if km < MIN_DISTANCE_KM:
        # said first: the numbers after it look good and are not to be trusted yet
        base = (f"Drive too short to trust: {km:.2f} km of driving, less than the "
                f"{MIN_DISTANCE_KM:g} km a calibration should rest on (docs: real logs); "
                f"check it on another drive. {base}")
        level = "partial" if level == "good" else level
    if result.bootstrap is not None and not all(result.bootstrap.agree):
        base += "; the bootstrap disagrees with the covariance"
        level = "partial" if level == "good" else level
    taken = [_taken_out(f) for f in findings if f.check in TAKEN_OUT]
    if taken:
        base += f"; measured and taken out before the fit: {', '.join(taken)}"
    # (a difference within 2% is the validation segments' noise, not a better method)
    if raw_m is not None and result.validation is not None \
            and raw_m < 0.98 * result.validation.mean_error_m:
        base += (f". Batch G-N on the measured rates validates better ({raw_m:.2f} m): "
                 "consider --method raw")
        level = "partial" if level == "good" else level
    return base, level


#: The notes of departures measured and taken out before the fit (the checks' findings).
TAKEN_OUT = (Check.LATERAL_DELAY, Check.HEADING_ERROR, Check.WHEEL_OFFSET)


def _taken_out(f: Finding) -> str:
    """A departure taken out before the fit, in a few words (the verdict line)."""
    if f.check is Check.LATERAL_DELAY:
        return f"a_y's {'lag' if f.value > 0 else 'lead'} of {abs(f.value):.2f} s"
    if f.check is Check.HEADING_ERROR:
        return (f"a heading error varying with the heading (up to "
                f"{np.degrees(f.value):.1f} degrees)")
    return f"the wheel rates' offset at standstill ({f.value:+.3f}, {f.reference:+.3f} rev/s)"


#: Less driving than this never gets the green verdict: its validation rests on a handful of
#: segments, and a few bends decide t_r and d (docs/real-logs.md).
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
        judged = validated_drives(result)
        if result.three_step is not None:
            data = validation_data(judged, segs, settings)
            errors["raw"] = segment_errors(result.three_step.raw.theta.as_array(), data).mean_m
        maps = _maps(result, judged, segs)
    line, level = verdict(result, float(errors["raw"].mean()) if "raw" in errors else None)
    fitted = fitted_data(result)
    threshold = settings.segments.yaw_rate_threshold_radps
    return ReportData(
        verdict=line, verdict_level=level,
        advice=[*advise(result.estimate, cov, settings, settings.segments.length * t_s),
                *(front_advice(result.vehicle_estimate)
                  if result.vehicle_estimate is not None else [])],
        coverage={**cov.to_dict(),
                  "fitted": fitted.to_dict(threshold) if fitted is not None else None},
        speed_hist=(speed_hist[0] * t_s, speed_hist[1]), yaw_hist=(yaw_hist[0] * t_s, yaw_edges),
        segment_errors=errors, maps=maps, fitted=fitted, corrections=corrections(result),
        zero=consistent_with_zero(result.estimate))


def change_in_log(result: CalibrationResult) -> Finding | None:
    """The change inside the log the fit found, if any (the calibration is of the part after
    it)."""
    return next((f for f in result.diagnosis.findings if f.check is Check.CHANGE_IN_LOG), None)


def _change_drive(drives: Sequence[Drive], change: Finding) -> int:
    """The index of the drive a change inside the log lies in (as the pipeline finds it)."""
    names = [d.name for d in drives]
    where = change.name.partition("|")[2]
    return names.index(where) if where in names else 0


def validated_drives(result: CalibrationResult) -> list[Drive]:
    """The drives the validation segments index into: the drives, or after a change inside
    the log the part after it (its drive from the change on, and the drives after it), as the
    pipeline validated them."""
    drives = list(result.drive_data)
    change = change_in_log(result)
    if change is None:
        return drives
    k = _change_drive(drives, change)
    return [drives[k].since(change.reference), *drives[k + 1:]]


def _axis(drives: Sequence[Drive]) -> tuple[list[float], tuple[tuple[float, float, str], ...]]:
    """Each drive's place on one time axis (one after another, s): its offset from its own
    clock, and (start, stop, name) of each."""
    offsets, spans, at = [], [], 0.0
    for d in drives:
        offsets.append(at - float(d.t[0]))
        spans.append((at, at + d.duration_s, Path(d.name).name))
        at += d.duration_s
    return offsets, tuple(spans)


def _peak_yaw(d: Drive, start: IntArray, steps: int) -> FloatArray:
    """The largest |yaw rate| over ``steps + 1`` samples from each of ``start``."""
    rate = np.abs(np.asarray(d.yaw_rate, dtype=np.float64))
    if rate.size <= steps:
        return np.full(start.size, float(rate.max()) if rate.size else 0.0)
    peaks = sliding_window_view(rate, steps + 1).max(axis=1)
    return np.asarray(peaks[np.clip(start, 0, peaks.size - 1)], dtype=np.float64)


def fitted_data(result: CalibrationResult) -> Fitted | None:
    """What the method that ran fitted (see :class:`Fitted`); None where nothing was (the
    checks refused the data, the vehicle stands still)."""
    from odocal.estimators.base import segment_clusters
    from odocal.estimators.inverse import InverseDetails

    drives = result.drive_data
    if not drives or result.diagnosis.fatal or result.diagnosis.standstill:
        return None
    offsets, spans = _axis(drives)
    details = result.estimate.details
    change = change_in_log(result)
    at_change = (float(change.reference + offsets[_change_drive(drives, change)])
                 if change is not None else None)
    if isinstance(details, InverseDetails):
        t0 = np.asarray(details.t0, dtype=np.float64)
        if details.windows == 0 or t0.size != details.windows:
            return None
        drive = (details.cluster // 10**9).astype(np.int64)
        steps = max(round(details.window_s / drives[0].t_s), 1)
        start = t0 + np.asarray(offsets)[drive]
        peak = np.zeros(t0.size)
        for k, d in enumerate(drives):
            mine = drive == k
            if mine.any():
                index = np.searchsorted(d.t, t0[mine] - 0.5 * d.t_s).astype(np.int64)
                peak[mine] = _peak_yaw(d, index, steps)
        return Fitted(unit="window", start_s=start, stop_s=start + details.window_s,
                      peak_yaw_radps=peak, fitted=np.ones(t0.size, dtype=bool),
                      cluster=np.asarray(details.cluster, dtype=np.int64), drives=spans,
                      length_s=float(details.window_s), after_change_s=at_change)
    segs = result.segments
    if len(segs) == 0:
        return None
    t_s = drives[0].t_s
    start = np.array([float(drives[int(k)].t[int(i)]) + offsets[int(k)]
                      for k, i in zip(segs.drive, segs.start, strict=True)])
    stop = start + np.asarray(segs.steps, dtype=np.float64) * t_s
    return Fitted(unit="segment", start_s=start, stop_s=stop,
                  peak_yaw_radps=np.asarray(segs.peak_yaw_rate_radps, dtype=np.float64),
                  fitted=np.asarray(result.used, dtype=bool),
                  cluster=segment_clusters(segs, result.settings.segments.length),
                  drives=spans, length_s=float(segs.steps[0]) * t_s, after_change_s=at_change)


def corrections(result: CalibrationResult) -> tuple[Correction, ...]:
    """Every departure of the sensors from the model that was measured, with its number and
    whether it was taken out (:mod:`odocal.checks.departures`, and what the default method
    estimates in its fit: the wheel stream's clock, the heading's constant offset, the wheel
    rates' offset while moving)."""
    from odocal.estimators.inverse import InverseDetails

    out: list[Correction] = []
    if result.departures is not None:
        out += _measured_before_fit(result.departures)
    details = result.estimate.details
    if isinstance(details, InverseDetails) and details.windows:
        out += _estimated_in_fit(details)
    return tuple(out)


def _measured_before_fit(dep: Departures) -> list[Correction]:
    """The departures the checks measured before the fit: a_y's clock, a heading error
    varying with the heading, the wheel rates at standstill and their encoding step."""
    out: list[Correction] = []
    lag = dep.lateral_lag_s
    out.append(Correction(
        "a_y's clock against the reference's (speed times yaw rate)",
        f"{abs(lag):.2f} s {'late' if lag > 0 else 'early'}" if lag else "in step",
        bool(lag), "a_y moved onto the reference's clock" if lag else "nothing to move"))
    out.append(Correction(
        "the reference heading's error varying with the heading (a compass)",
        f"up to {np.degrees(dep.heading_amplitude_rad):.1f} degrees"
        if dep.heading_amplitude_rad else "none found",
        bool(dep.heading_amplitude_rad),
        "taken out of the heading" if dep.heading_amplitude_rad else "nothing taken out"))
    o_rl, o_rr = dep.standstill_offset_revps
    still = bool(o_rl or o_rr)
    out.append(Correction(
        "the wheel rates while the reference stands still",
        f"{o_rl:+.3f}, {o_rr:+.3f} rev/s (rear left, right)" if still else "zero",
        still, "subtracted from every sample" if still else "nothing taken out"))
    if dep.wheel_step_revps:
        out.append(Correction(
            "the wheel rates' encoding step",
            f"{dep.wheel_step_revps:.4f} rev/s", False,
            "rates on a grid may be truncated (half a step low): the fit estimates an "
            "offset, with half a step as its prior"))
    return out


def _estimated_in_fit(details: InverseDetails) -> list[Correction]:
    """The departures the default method estimated in its fit: the wheel stream's clock, the
    heading's constant offset, the wheel rates' offset while moving and the nuisances that
    held out."""
    from odocal.estimators.departures import NAMES, NUISANCES

    out: list[Correction] = []
    applied = bool(details.delay_s)
    shown = details.delay_s if applied else details.delay_found_s
    std = (f" +-{details.delay_std_s:.3f}" if applied and np.isfinite(details.delay_std_s)
           else "")
    note = ("the reference shifted to match it" if applied else
            f"not applied ({details.delay_note})" if details.delay_note else "not applied")
    out.append(Correction("the wheel stream's clock against the reference's (in the fit)",
                          f"{abs(shown):.3f}{std} s {'late' if shown > 0 else 'early'}"
                          if shown else "in step", applied, note))
    out.append(Correction("the reference heading's constant offset (in the fit)",
                          f"{np.degrees(details.heading_offset_rad):+.2f} degrees",
                          bool(details.heading_offset_rad),
                          "taken out of the heading on every window"
                          if details.heading_offset_rad else "nothing taken out"))
    if details.wheel_offset_std > 0 and "offset" not in details.fitted_departures:
        out.append(Correction("the wheel rates' offset while moving (in the fit)",
                              f"{details.wheel_offset_revps:+.4f} "
                              f"+-{details.wheel_offset_std:.4f} rev/s", True,
                              "the encoding's: estimated with the parameters, with half "
                              "a step as its prior; its uncertainty is in c_e's"))
    for key, number, spread in details.departures:
        if key == "lag":
            continue                            # (the wheel stream's clock, above)
        spec = NUISANCES[NAMES.index(key)]
        unit = "" if spec.unit == "1" else f" {spec.unit}"
        out.append(Correction(f"{spec.label} (in the fit)",
                              f"{number:+.4g} +-{spread:.2g}{unit}", True,
                              "it held out on both halves of the drive: estimated with "
                              "the parameters, its uncertainty in theirs"))
    return out


def _maps(result: CalibrationResult, drives: Sequence[Drive], segs: Any) -> list[MapSegment]:
    """The validation segments that turn most, dead-reckoned both ways (``drives``: those the
    segments index into, :func:`validated_drives`)."""
    turn = np.array([abs(drives[int(d)].psi[s + k] - drives[int(d)].psi[s])
                     for d, s, k in zip(segs.drive, segs.start, segs.steps, strict=True)])
    chosen = np.argsort(-turn, kind="stable")[:MAP_SEGMENTS]
    out = []
    theta0 = result.estimate.datasheet.as_array()
    theta = result.theta.as_array()
    first = {d.name: float(d.t[0]) for d in reversed(result.drive_data)}   # the logs' starts
    for i in sorted(chosen):
        d = drives[int(segs.drive[i])]
        s, k = int(segs.start[i]), int(segs.steps[i])
        u = Inputs(d.n_rl[s:s + k], d.n_rr[s:s + k], d.beta[s:s + k], d.a_y[s:s + k])
        x0 = np.array([d.x[s], d.y[s], d.psi[s]])
        ref = np.column_stack([d.x[s:s + k + 1], d.y[s:s + k + 1]])
        began = first.get(d.name, float(d.t[0]))
        out.append(MapSegment(drive=d.name, start_s=float(d.t[s]) - began,
                              distance_m=float(segs.distance_m[i]), reference=ref,
                              turn_rad=float(turn[i]),
                              datasheet=rollout(theta0, u, x0, d.t_s)[:, :2],
                              calibrated=rollout(theta, u, x0, d.t_s)[:, :2]))
    return out


def parameter_rows(result: CalibrationResult) -> list[dict[str, Any]]:
    """The parameter table: datasheet, calibrated, standard deviations, identified (and
    whether an identified c_d or d is consistent with zero)."""
    est = result.estimate
    boot = result.bootstrap
    zero = consistent_with_zero(est)
    rows = []
    for j, name in enumerate(PARAMETER_NAMES):
        rows.append({"name": name, "datasheet": float(est.datasheet.as_array()[j]),
                     "calibrated": float(est.theta.as_array()[j]),
                     "std": float(est.std[j]),
                     "bootstrap_std": float(boot.std[j]) if boot is not None else None,
                     "identified": bool(est.identified[j]),
                     "consistent_with_zero": name in zero})
    return rows
