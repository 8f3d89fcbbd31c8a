"""Moderate departures of the sensors from the model, measured against the reference and taken out.

Before any fit, three properties of a log that the model assumes away are measured from the
data themselves, on every path alike:

* **the lateral acceleration's clock** against the reference's: the lag of ``a_y`` behind speed
  times the reference yaw rate (cross-correlation over every piece of 20 s or more). The wheel
  stream's own lag is found later, by the estimator, shifting the reference side with ``a_y``
  on it: so ``a_y`` is first brought onto the reference's clock.
* **a heading error that varies with the heading** (a magnetometer's hard- and soft-iron
  errors): the gap between the reference's course and its heading on straight seconds, fitted
  with the first two harmonics of the heading. A constant gap (a mounting yaw) is the
  estimator's to take out; the varying part is taken out of ``psi`` here, where it is
  determined (beyond four standard deviations, larger than half a degree, and the straight
  seconds cover the headings well enough to tell the harmonics apart).

and of the wheel rates:

* **an offset at standstill**: where the reference stands still for seconds at a time, wheels
  that read a steady rate (both the same sign, most of the time) have an offset; it is taken
  out of every sample (a biased speed signal reads it moving too).
* **the step of their encoding**: rates that all lie on a grid (whole rpm, 0.1 km/h) may be
  truncated towards zero, half a step low while moving, or rounded, which biases nothing; the
  two cannot be told apart from the values, so the estimator fits a constant offset with a
  prior of half the step (:mod:`odocal.estimators.core`): determined where the drive's speeds
  tell it from the circumference, carried in c_e's uncertainty where they do not.

Each is applied where the data determine it (:func:`corrected`), and named by a finding where
it is large enough to matter to a user (:func:`findings`): the calibration then stands on the
corrected data, and the report says what was taken out. The thresholds, with their reasons, are
settings (``[checks]``: :class:`~odocal.settings.ChecksSettings`).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from odocal.arrays import BoolArray, FloatArray
from odocal.checks.findings import Check, Finding, Severity
from odocal.checks.seconds import pieces
from odocal.correlation import correlations
from odocal.data.drive import Drive
from odocal.model.kinematics import body_rates, motion_increments
from odocal.settings import ChecksSettings, Settings


@dataclass(frozen=True)
class Departures:
    """What was measured.

    lateral_lag_s : a_y's lag behind the reference (positive: a_y late); 0 where not determined
    heading_harmonics : (a1, b1, a2, b2) of the heading error's varying part (rad): the
        reference heading reads ``-(a1 cos psi + b1 sin psi + a2 cos 2 psi + b2 sin 2 psi)``
        more than the course; zeros where not determined
    heading_amplitude_rad : the largest |error| of that varying part over the headings
    reference_shift_s : the wheel stream's lag behind the reference (positive: the wheels late)
        by cross-correlation, taken out by delaying the reference as much (0: not applied: within
        half the fit's own lag scan, ``[inverse] lag_scan_s``, or not determined)
    """

    reference_shift_s: float = 0.0
    lateral_lag_s: float = 0.0
    heading_harmonics: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0)   # a1, b1, a2, b2 (not theta)
    heading_amplitude_rad: float = 0.0
    standstill_offset_revps: tuple[float, float] = (0.0, 0.0)
    wheel_step_revps: float = 0.0

    @property
    def any(self) -> bool:
        return bool(self.reference_shift_s or self.lateral_lag_s
                    or self.heading_amplitude_rad
                    or any(self.standstill_offset_revps))

    def to_dict(self) -> dict[str, object]:
        return {"reference_shift_s": self.reference_shift_s,
                "lateral_lag_s": self.lateral_lag_s,
                "heading_harmonics_rad": list(self.heading_harmonics),
                "heading_amplitude_rad": self.heading_amplitude_rad,
                "standstill_offset_revps": list(self.standstill_offset_revps),
                "wheel_step_revps": self.wheel_step_revps}


def _long_pieces(drives: Sequence[Drive], seconds: float) -> list[tuple[Drive, int, int]]:
    return [(d, a, b) for d in drives for a, b in d.pieces if b - a >= round(seconds / d.t_s)]


def best_lag(pairs: Sequence[tuple[FloatArray, FloatArray]], span: int, t_s: float,
             min_correlation: float) -> float | None:
    """The lag (s) of ``b`` behind ``a`` within ``span`` steps either way that correlates them
    best over the pairs of series (:mod:`odocal.correlation`'s tapered estimate: a clock
    offset is a few steps over long pieces); None where even the best correlation is below
    ``min_correlation`` (a signal that hardly varies, a circle at one rate, has no timing to
    find)."""
    peak = correlations(pairs, span, estimate="tapered").peak()
    if peak is None or peak.correlation < min_correlation:
        return None
    return peak.steps * t_s


def lateral_lag_s(drives: Sequence[Drive], settings: Settings) -> float | None:
    """The lag (s) of a_y behind speed times the reference yaw rate (up to
    ``lateral_lag_search_s``), over every piece of at least ``lag_min_piece_s``; None where not
    determined."""
    lim = settings.checks
    long = _long_pieces(drives, lim.lag_min_piece_s)
    if not long:
        return None
    t_s = drives[0].t_s
    pairs = []
    for d, a, b in long:
        ds, dpsi = motion_increments(d.x[a:b], d.y[a:b], d.psi[a:b], d.beta[a:b])
        pairs.append((ds * dpsi / t_s**2, np.asarray(d.a_y[a:b - 1])))
    return best_lag(pairs, round(lim.lateral_lag_search_s / t_s), t_s, lim.lag_min_correlation)


def wheel_lag_s(drives: Sequence[Drive], theta: FloatArray, settings: Settings) -> float | None:
    """The lag (s) of the wheels' yaw rate (``theta``) behind the reference's, up to
    ``wheel_lag_search_s``, over every piece of at least ``lag_min_piece_s`` (positive: the
    wheel stream late); None where not determined."""
    lim = settings.checks
    long = _long_pieces(drives, lim.lag_min_piece_s)
    if not long:
        return None
    t_s = drives[0].t_s
    pairs = []
    for d, a, b in long:
        _, w = body_rates(theta, d.n_rl[a:b], d.n_rr[a:b], d.a_y[a:b])
        pairs.append((np.gradient(d.psi[a:b], d.t_s), np.asarray(w)))
    return best_lag(pairs, round(lim.wheel_lag_search_s / t_s), t_s, lim.lag_min_correlation)


def _seconds(drives: Sequence[Drive]) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """One-second sums of every piece: distance, turn, the course's gap to the heading (rad)
    and the heading at the middle."""
    out: list[list[FloatArray]] = [[], [], [], []]
    for piece in pieces(drives):
        d = piece.drive
        ds, _ = motion_increments(d.x[piece.a:piece.b], d.y[piece.a:piece.b],
                                  d.psi[piece.a:piece.b], d.beta[piece.a:piece.b])
        turn, heading, gap = piece.course()
        out[0].append(piece.sums(ds))
        out[1].append(turn)
        out[2].append(gap)
        out[3].append(heading)
    cat = [np.concatenate(x) if x else np.zeros(0) for x in out]
    return cat[0], cat[1], cat[2], cat[3]


def _harmonics(gap: FloatArray, heading: FloatArray,
               lim: ChecksSettings) -> tuple[FloatArray, float]:
    """The heading error's first two harmonics (a1, b1, a2, b2) where they are determined, and
    the largest |error| of their sum; zeros otherwise."""
    zero = np.zeros(4)                  # a1, b1, a2, b2 (not theta)
    if gap.size < lim.heading_harmonic_min_seconds:
        return zero, 0.0
    regressors = np.column_stack([np.ones_like(heading), np.cos(heading), np.sin(heading),
                                  np.cos(2 * heading), np.sin(2 * heading)])
    singular = np.linalg.svd(regressors[:, 1:] / math.sqrt(gap.size), compute_uv=False)
    if singular[-1] < lim.heading_harmonic_min_coverage:
        return zero, 0.0                          # too few headings to tell the harmonics apart
    coef, *_ = np.linalg.lstsq(regressors, gap, rcond=None)
    residual = gap - regressors @ coef
    # a robust spread (a normal's sigma from the MAD), and groups of error_correlation_s
    # seconds: neighbouring seconds share their errors
    spread = 1.4826 * float(np.median(np.abs(residual - np.median(residual))))
    cov = np.linalg.pinv(regressors.T @ regressors) * spread**2 * float(lim.error_correlation_s)
    std = np.sqrt(np.clip(np.diag(cov)[1:], 0.0, None))
    harmonics = coef[1:]
    if not (np.abs(harmonics) > lim.heading_harmonic_sigmas * std).any():
        return zero, 0.0
    grid = np.linspace(-math.pi, math.pi, 721)
    varying = (harmonics[0] * np.cos(grid) + harmonics[1] * np.sin(grid)
               + harmonics[2] * np.cos(2 * grid) + harmonics[3] * np.sin(2 * grid))
    amplitude = float(np.max(np.abs(varying)))
    if amplitude < lim.heading_harmonic_min_rad:
        return zero, 0.0
    return harmonics, amplitude


def standstill_offset(drives: Sequence[Drive], settings: Settings) -> tuple[float, float]:
    """What each wheel reads (rev/s) while the reference stands still, where it reads it
    steadily (see the module docstring); zeros otherwise."""
    lim = settings.checks
    rates: list[FloatArray] = []
    for d in drives:
        size = max(round(1.0 / d.t_s), 1)
        for a, b in d.pieces:
            n = (b - a - 1) // size
            if n < 1:
                continue
            starts = a + size * np.arange(n)
            moved = np.hypot(d.x[starts + size] - d.x[starts], d.y[starts + size] - d.y[starts])
            still = starts[moved < lim.standstill_speed_mps]
            if still.size:
                rows = still[:, None] + np.arange(size)[None, :]
                rates.append(np.column_stack([d.n_rl[rows].mean(axis=1),
                                              d.n_rr[rows].mean(axis=1)]))
    if not rates:
        return 0.0, 0.0
    seconds = np.concatenate(rates)
    if seconds.shape[0] < lim.standstill_min_seconds:
        return 0.0, 0.0
    median = np.median(seconds, axis=0)
    same_sign = (np.sign(seconds) == np.sign(median)).mean(axis=0)
    if (np.abs(median) >= lim.standstill_min_offset_revps).all() \
            and (same_sign >= lim.standstill_min_share).all():
        return float(median[0]), float(median[1])
    return 0.0, 0.0


def wheel_step(drives: Sequence[Drive], settings: Settings | None = None) -> float:
    """The grid the nonzero wheel rates lie on (rev/s), where they lie on one no coarser than
    ``encoding_max_step_revps`` (``settings``: the defaults where None); 0 otherwise. A drive's
    metadata may state it (``"wheel_step_revps"``, where an importer knows the encoding)."""
    lim = (settings or Settings()).checks
    stated = [d.metadata.get("wheel_step_revps") for d in drives]
    numbers = [float(v) for v in stated if isinstance(v, int | float)]
    if numbers and len(numbers) == len(stated):
        return max(numbers)
    values = np.concatenate([np.concatenate([d.n_rl, d.n_rr]) for d in drives])
    values = values[values != 0.0]
    if values.size < lim.encoding_min_samples:
        return 0.0
    unique = np.unique(np.round(np.abs(values), 9))             # to the nano: rounding only
    if unique.size > values.size // lim.encoding_samples_per_value \
            or unique.size < lim.encoding_min_values:
        return 0.0
    steps = np.diff(unique)
    step = float(np.min(steps))
    if not 0 < step <= lim.encoding_max_step_revps:
        return 0.0
    ratio = unique / step
    on_grid = np.abs(ratio - np.round(ratio)) < lim.encoding_grid_tolerance
    return step if on_grid.mean() > lim.encoding_min_on_grid else 0.0


def measure(drives: Sequence[Drive], settings: Settings, *,
            lateral: bool = True) -> Departures:
    """The departures of :mod:`the module docstring <odocal.checks.departures>` on ``drives``;
    ``lateral`` False where a_y carries no lateral acceleration (nothing to measure in it)."""
    lim = settings.checks
    # the reference on the wheels' clock first (the fit scans only lag_scan_s around it)
    drives, shift = _on_wheels_clock(drives, settings)
    lag = (lateral_lag_s(drives, settings) or 0.0) if lateral else 0.0
    if abs(lag) <= 0.5 * drives[0].t_s:
        lag = 0.0                          # within half a step: nothing the data can tell
    ds, turn, gap, heading = _seconds(drives)
    straight = (np.abs(ds) > lim.straight_speed_mps) & (np.abs(turn) < lim.straight_turn_rad)
    harmonics, amplitude = _harmonics(gap[straight], heading[straight], lim)
    return Departures(reference_shift_s=shift, lateral_lag_s=lag,
                      heading_harmonics=tuple(float(h) for h in harmonics),
                      heading_amplitude_rad=amplitude,
                      standstill_offset_revps=standstill_offset(drives, settings),
                      wheel_step_revps=wheel_step(drives, settings))


def _on_wheels_clock(drives: Sequence[Drive], settings: Settings
                     ) -> tuple[list[Drive], float]:
    """The drives with the reference on the wheels' clock, where the wheels' yaw rate lags it
    by more than half the fit's own lag scan (up to ``[inverse] max_delay_s``), and the shift
    (s; 0 where none is applied)."""
    if settings.inverse.delay != "estimate":
        return list(drives), 0.0
    found = wheel_lag_s(drives, np.asarray(settings.identify.theta0, dtype=np.float64),
                        settings)
    if found is None or not 0.5 * settings.inverse.lag_scan_s < abs(found) \
            <= settings.inverse.max_delay_s:
        return list(drives), 0.0
    return [shifted_reference(d, found) for d in drives], found


def shifted_reference(drive: Drive, lag_s: float) -> Drive:
    """The drive with its reference pose (x, y, psi, their std) delayed by ``lag_s`` (the wheel
    stream's lag behind it: at each sample the reference then shows where the vehicle was when
    the wheels turned); samples whose shifted time falls outside their piece are left out, and
    the drive's metadata records the shift (``reference_shift_s``)."""
    pose = np.column_stack([drive.x, drive.y, drive.psi]).astype(np.float64)
    keep = np.zeros(drive.n_samples, dtype=bool)
    for a, b in drive.pieces:
        pose[a:b], keep[a:b] = pose_at(drive.t[a:b], pose[a:b], drive.t[a:b] - lag_s,
                                       drive.t_s)
    if not keep.any():
        return drive
    out = drive.select(keep, x=pose[:, 0], y=pose[:, 1], psi=pose[:, 2])
    return dataclasses.replace(out, metadata={**drive.metadata,
                                              "reference_shift_s": float(lag_s)})


def pose_at(t: FloatArray, pose: FloatArray, at: FloatArray, t_s: float
            ) -> tuple[FloatArray, BoolArray]:
    """The reference pose ``pose`` (N, 3: x, y, psi), sampled at the times ``t`` of one piece
    on a grid of ``t_s``, at the times ``at``: linearly interpolated (the heading along its
    shorter way round), and which of ``at`` fall within the piece (to a billionth of a step).
    The one computation behind batch's :func:`shifted_reference` and the live
    :class:`odocal.online.departures.ReferenceAligner`."""
    slack = 1e-9 * t_s
    inside = (at >= t[0] - slack) & (at <= t[-1] + slack)
    out = np.column_stack([np.interp(at, t, pose[:, 0]), np.interp(at, t, pose[:, 1]),
                           np.interp(at, t, np.unwrap(pose[:, 2]))])
    return out, inside


def heading_correction(psi: FloatArray, harmonics: Sequence[float]) -> FloatArray:
    """What to add to a heading to take the varying error out (the course's gap to it)."""
    a1, b1, a2, b2 = harmonics
    return np.asarray(a1 * np.cos(psi) + b1 * np.sin(psi) + a2 * np.cos(2 * psi)
                      + b2 * np.sin(2 * psi))


def corrected(drives: Sequence[Drive], found: Departures) -> list[Drive]:
    """The drives with what ``found`` determined taken out: a_y on the reference's clock and
    without its offset, the heading without its varying error."""
    if not found.any:
        return list(drives)
    out = []
    for d in drives:
        if found.reference_shift_s:
            d = shifted_reference(d, found.reference_shift_s)
        a_y = np.array(d.a_y, dtype=np.float64)
        psi = np.array(d.psi, dtype=np.float64)
        if found.lateral_lag_s:
            for a, b in d.pieces:
                a_y[a:b] = np.interp(d.t[a:b] + found.lateral_lag_s, d.t[a:b], d.a_y[a:b])
        if found.heading_amplitude_rad:
            psi += heading_correction(psi, found.heading_harmonics)
        o_rl, o_rr = found.standstill_offset_revps
        out.append(dataclasses.replace(d, a_y=a_y, psi=psi, n_rl=np.asarray(d.n_rl) - o_rl,
                                       n_rr=np.asarray(d.n_rr) - o_rr))
    return out


def findings(found: Departures, settings: Settings) -> list[Finding]:
    """The departures worth naming: each a note (the calibration stands, on corrected data).
    a_y's lag is named by the checks of every path (:func:`lateral_delay`)."""
    lim = settings.checks
    out = []
    if found.heading_amplitude_rad:
        out.append(Finding(Check.HEADING_ERROR, Severity.NOTE, found.heading_amplitude_rad,
                           lim.heading_harmonic_min_rad))
    if any(found.standstill_offset_revps):
        o_rl, o_rr = found.standstill_offset_revps
        out.append(Finding(Check.WHEEL_OFFSET, Severity.NOTE, o_rl, o_rr))
    return out


def lateral_delay(drives: Sequence[Drive], settings: Settings) -> list[Finding]:
    """a_y's lag behind the reference, named where it exceeds ``lateral_delay_named_s`` (value:
    the lag, s; positive: a_y late), and a_y is off the wheels' clock as well: a_y in step
    with the wheels, with the reference late, is the reference's lag (the fit names it), not
    a_y's."""
    lag = lateral_lag_s(drives, settings)
    limit = settings.checks.lateral_delay_named_s
    if lag is None or abs(lag) <= limit:
        return []
    aligned, shift = _on_wheels_clock(drives, settings)
    if shift:
        behind_wheels = lateral_lag_s(aligned, settings)
        if behind_wheels is not None and abs(behind_wheels) <= limit:
            return []
    return [Finding(Check.LATERAL_DELAY, Severity.NOTE, lag, 0.0, "a_y")]
