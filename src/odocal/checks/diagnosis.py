"""The data against the model, before any fit: what every entry point checks first.

:func:`check_drives` runs on whole drives (``calibrate``, the fleet's tasks) and on the recent
samples of a live stream (the online calibrator, ``replay``) alike. With the datasheet
parameters, one-second windows of the drives are compared with the model's expectations, in
this order (a reference that is wrong says nothing about the wheels, so the reference comes
first):

* **the reference itself**: a position that jumps (a relocalisation, a glitch); a heading that
  does not point along the direction of travel on straights (x and y swapped, a compass
  heading, another frame); a reference whose speed does not follow the wheels' (out of sync by
  more than the clock check reaches, or another drive's);
* **the wheels' distance** against the reference's: a ratio far from one is a unit or scale
  mistake (rpm or rad/s for rev/s, radius for circumference, km/h for m/s); one wheel that reads
  zero while the other turns is a dead sensor;
* **the wheels' yaw** against the reference's in bends: turning the wrong way means the wheels
  are swapped (or the heading mirrored); identical wheel signals or none of the reference's
  turning in them mean the wheels carry no differential information (a copied column, a locked
  axle, one speed signal), and only c_e is calibrated;
* **the lateral acceleration** against speed times yaw rate: a flipped sign, a unit (g), a
  delay, or none at all (zero, constant, unplugged: then d is not fitted);
* **the clock offset** between the wheel and pose streams, by cross-correlating their yaw rates;
* a vehicle that does not move at all.

Findings carry numbers and a :class:`~odocal.checks.findings.Check` code; words are made from
them in :mod:`odocal.report.advice` (for the CLI and the report). Every threshold is a setting,
with its reason: ``[checks]`` (:class:`~odocal.settings.ChecksSettings`) and the first checks'
in ``[gate]``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from odocal.arrays import BoolArray, FloatArray
from odocal.checks.departures import lateral_delay, wheel_lag_s
from odocal.checks.findings import Check, Diagnosis, Finding, Severity
from odocal.checks.seconds import pieces
from odocal.correlation import correlations
from odocal.data.drive import Drive
from odocal.model.kinematics import body_rates, motion_increments
from odocal.model.layout import REAR_AXLE as LAYOUT
from odocal.model.vehicle import MODEL
from odocal.settings import ChecksSettings, GateSettings, Settings


@dataclass(frozen=True)
class _Windows:
    """One-second windows of every drive: reference and wheel quantities."""

    t: FloatArray             # start time, s
    ds: FloatArray            # reference along-track distance, m
    dpsi: FloatArray          # reference heading change, rad
    course_gap: FloatArray    # the reference's course less its heading (and sideslip), rad
    wheel_ds: FloatArray      # distance the wheels imply (datasheet theta), m
    wheel_dpsi: FloatArray    # heading change the wheels imply, rad
    diff_revs: FloatArray     # right minus left revolutions
    left_revs: FloatArray     # revolutions of each wheel
    right_revs: FloatArray
    a_y: FloatArray           # mean lateral acceleration, m/s^2
    v_w: FloatArray           # mean of speed times yaw rate (reference), m/s^2
    series: FloatArray        # index of the run of consecutive windows each belongs to
    drive: FloatArray         # index of the drive each belongs to


def _windows(drives: Sequence[Drive], theta: FloatArray) -> _Windows:
    names = ("t", "ds", "dpsi", "gap", "wds", "wdpsi", "diff", "left", "right", "ay", "vw",
             "series", "drive")
    parts: dict[str, list[FloatArray]] = {k: [] for k in names}
    for series, piece in enumerate(pieces(drives)):
        d, a, b, n = piece.drive, piece.a, piece.b, piece.count
        ds, dpsi = motion_increments(d.x[a:b], d.y[a:b], d.psi[a:b], d.beta[a:b])
        v, w = body_rates(theta, d.n_rl[a:b - 1], d.n_rr[a:b - 1], d.a_y[a:b - 1])
        _, _, gap = piece.course()
        wsum = piece.sums
        parts["t"].append(d.t[piece.starts])
        parts["ds"].append(wsum(ds))
        parts["dpsi"].append(wsum(dpsi))
        parts["gap"].append(gap)
        parts["wds"].append(wsum(v * d.t_s))
        parts["wdpsi"].append(wsum(w * d.t_s))
        revs = np.column_stack([d.n_rl[a:b - 1], d.n_rr[a:b - 1]]) * d.t_s
        parts["diff"].append(wsum(revs @ MODEL.channel_map[1]))    # the yaw channel
        parts["left"].append(wsum(d.n_rl[a:b - 1] * d.t_s))
        parts["right"].append(wsum(d.n_rr[a:b - 1] * d.t_s))
        parts["ay"].append(wsum(d.a_y[a:b - 1]) / piece.size)
        parts["vw"].append(wsum(ds * dpsi) / (piece.size * d.t_s**2))
        parts["series"].append(np.full(n, float(series)))
        parts["drive"].append(np.full(n, float(piece.index)))
    cat = {k: np.concatenate(v) if v else np.zeros(0) for k, v in parts.items()}
    return _Windows(t=cat["t"], ds=cat["ds"], dpsi=cat["dpsi"], course_gap=cat["gap"],
                    wheel_ds=cat["wds"], wheel_dpsi=cat["wdpsi"], diff_revs=cat["diff"],
                    left_revs=cat["left"], right_revs=cat["right"], a_y=cat["ay"],
                    v_w=cat["vw"], series=cat["series"], drive=cat["drive"])


def _agreement(a: FloatArray, b: FloatArray) -> float:
    """The cosine of the angle between two series (their correlation about zero, not about
    their means): a car circling at one rate agrees with its reference, whatever the spread."""
    denominator = float(np.sqrt((a @ a) * (b @ b)))
    return float(a @ b) / denominator if denominator > 0 else 0.0


def check_drives(drives: Sequence[Drive], settings: Settings) -> Diagnosis:
    """The checks before the fit (see the module docstring)."""
    lim = settings.gate
    theta = np.asarray(settings.identify.theta0, dtype=np.float64)
    win = _windows(drives, theta)
    findings = _repaired(drives)
    wheel_m = float(np.abs(win.wheel_ds).sum())
    if wheel_m < lim.min_distance_m:
        reference_m = float(np.abs(win.ds).sum())
        extent_m = max((float(np.hypot(np.ptp(d.x), np.ptp(d.y))) for d in drives if d.x.size),
                       default=0.0)
        if extent_m >= 10.0 * lim.min_distance_m:     # the reference drives, the wheels not
            # (judged by how far apart its positions lie: a parked pose's jitter adds up)
            findings.append(Finding(Check.SPEED_SCALE, Severity.FATAL,
                                    wheel_m / reference_m, reference_m))
        else:
            findings.append(Finding(Check.STANDSTILL, Severity.FALLBACK, wheel_m,
                                    lim.min_distance_m))
        return Diagnosis(tuple(findings))
    moving = np.abs(win.ds) > lim.min_speed_mps * 1.0        # windows of one second
    reference = _pose_jumps(drives, settings.checks)
    if not reference:                                         # a jump would distort the rest
        reference = [*_heading(win, moving, settings.checks), *_sync(win, settings.checks)]
    findings += reference
    if any(f.severity is Severity.FATAL for f in reference):
        return Diagnosis(tuple(findings))                     # the rest would compare nonsense
    findings += _distance(win, moving, settings)
    findings += _vehicles(drives, win, moving, theta, settings.checks)
    if any(f.severity is Severity.FATAL for f in findings):
        return Diagnosis(tuple(findings))
    bends = moving & (np.abs(win.dpsi) > lim.bend_yaw_rate_radps)
    if not np.any(np.abs(win.diff_revs) > 1e-12):            # zero but for rounding: a copy
        findings.append(Finding(Check.WHEELS_IDENTICAL, Severity.FALLBACK, 0.0))
    elif bends.sum() >= lim.min_bend_windows:
        agree = _agreement(win.wheel_dpsi[bends], win.dpsi[bends])
        swapped = _swapped_drives(drives, win, bends, lim) if agree < lim.min_yaw_correlation \
            else []
        if swapped:              # one log's swapped wheels cancel another's in the pooled sum
            findings += swapped
        elif agree < -lim.min_yaw_correlation:
            findings.append(Finding(Check.WHEELS_SWAPPED, Severity.FATAL, agree, 1.0))
        elif agree < lim.min_yaw_correlation:
            findings.append(Finding(Check.NO_DIFFERENTIAL, Severity.FALLBACK, agree, 1.0))
        else:
            lateral = _lateral(win, bends, settings.checks)
            findings += lateral or lateral_delay(drives, settings)
            findings += _clock(drives, theta, settings)
    return Diagnosis(tuple(findings))


def _swapped_drives(drives: Sequence[Drive], win: _Windows, bends: BoolArray,
                    lim: GateSettings) -> list[Finding]:
    """Among several drives, each one whose own wheels turn against its reference in bends
    (named): beside good logs, their pooled agreement only looked like no differential
    information."""
    if len(drives) < 2:
        return []
    out = []
    for index, d in enumerate(drives):
        mine = bends & (win.drive == index)
        if mine.sum() < lim.min_bend_windows:
            continue
        agree = _agreement(win.wheel_dpsi[mine], win.dpsi[mine])
        if agree < -lim.min_yaw_correlation:
            out.append(Finding(Check.WHEELS_SWAPPED, Severity.FATAL, agree, 1.0, d.name))
    return out


def _repaired(drives: Sequence[Drive]) -> list[Finding]:
    out: list[Finding] = []
    for d in drives:
        repaired = d.metadata.get("repaired")
        if isinstance(repaired, dict):
            for column, count in repaired.items():
                out.append(Finding(Check.DATA_REPAIRED, Severity.NOTE, float(count),
                                   name=f"{d.name}:{column}"))
    return out


def _pose_jumps(drives: Sequence[Drive], lim: ChecksSettings) -> list[Finding]:
    """Reference steps that move much further than the wheels turn (``pose_jump_m``, beyond
    ``pose_jump_m_per_rev`` of their revolutions): value the jump (m), reference the time of the
    largest (s), name the drive."""
    out = []
    for d in drives:
        worst, when = 0.0, float("nan")
        for a, b in d.pieces:
            if b - a < 2:
                continue
            step = np.hypot(np.diff(d.x[a:b]), np.diff(d.y[a:b]))
            revs = 0.5 * np.abs(d.n_rl[a:b - 1] + d.n_rr[a:b - 1]) * d.t_s
            wheels = revs * lim.pose_jump_m_per_rev
            excess = step - wheels
            k = int(np.argmax(excess))
            if excess[k] > worst:
                worst, when = float(step[k]), float(d.t[a + k + 1])
        if worst > lim.pose_jump_m:
            out.append(Finding(Check.POSE_JUMP, Severity.FATAL, worst, when, d.name))
    return out


def _heading(win: _Windows, moving: BoolArray, lim: ChecksSettings) -> list[Finding]:
    """On straight seconds, the reference heading against the direction it moves in (where
    the wheels turn backwards, against the opposite direction: a car backing up moves against
    its heading); refused where it is off either way."""
    straight = moving & (np.abs(win.dpsi) < lim.straight_turn_rad) \
        & (np.abs(win.ds) > lim.straight_speed_mps)
    if straight.sum() < lim.heading_min_seconds:
        return []
    backwards = win.wheel_ds < 0.0
    turned = np.where(backwards, np.remainder(win.course_gap, 2.0 * np.pi) - np.pi,
                      win.course_gap)
    # the heading is wrong only where it is wrong either way: a reference moving along its
    # heading while the wheels turn backwards is a wheel sign flipped (the scale check names it)
    gap = min(float(np.median(np.abs(turned[straight]))),
              float(np.median(np.abs(win.course_gap[straight]))))
    if gap > lim.heading_max_gap_rad:
        # (reference: where the wheels never turn backwards and the straight seconds go
        # either along the heading or against it, the share against: wheel speeds without a
        # sign on a car backing up; a rotated or mirrored frame spreads the gaps between)
        course = np.abs(win.course_gap[straight])
        against = course > BACKING_GAP_RAD
        either = against | (course <= lim.heading_max_gap_rad)
        share = (float(against.mean()) if not backwards.any()
                 and either.mean() >= BACKING_EITHER_SHARE else 0.0)
        return [Finding(Check.REFERENCE_HEADING, Severity.FATAL, gap, share)]
    return []


#: A course against the heading by more than this (rad, 150 degrees) is a car backing up.
BACKING_GAP_RAD = float(np.radians(150.0))
#: The share of straight seconds along the heading or against it beyond which a drive is one
#: of a car going forwards and backing up (not of another frame).
BACKING_EITHER_SHARE = 0.9


def _sync(win: _Windows, lim: ChecksSettings) -> list[Finding]:
    """The reference's speed against the wheels' (second by second): a reference out of step
    with the wheels, by more than the clock check reaches, shows as no correlation at lag 0;
    the lag that restores it is searched within ``sync_max_search_s`` (value: the lag, s,
    positive where the reference is late; nan where none does)."""
    wheels, ref = np.abs(win.wheel_ds), np.abs(win.ds)
    spread = lim.sync_min_speed_spread_mps
    if wheels.size < lim.sync_min_seconds or ref.std() < spread or wheels.std() < spread:
        return []
    pairs = [(wheels[win.series == k], ref[win.series == k]) for k in np.unique(win.series)]
    here = float(correlations(pairs, 0).values[0])
    if here >= lim.sync_min_correlation:
        return []
    found = correlations(pairs, min(int(lim.sync_max_search_s), wheels.size // 2))
    peak = found.peak((found.overlap >= lim.sync_min_seconds) & (found.lags != 0))
    lag = float("nan")
    if peak is not None and peak.correlation > here \
            and peak.correlation >= lim.sync_lag_min_correlation:
        lag = peak.steps                               # steps of one second
    return [Finding(Check.REFERENCE_SYNC, Severity.FATAL, lag, here)]


def _distance(win: _Windows, moving: BoolArray, settings: Settings) -> list[Finding]:
    """The wheels' distance against the reference's: scale and units, and a dead wheel."""
    lim, check = settings.gate, settings.checks
    out = []
    for name, mine, other in (("n_rl", win.left_revs, win.right_revs),
                              ("n_rr", win.right_revs, win.left_revs)):
        turning = moving & (np.abs(other) > check.dead_wheel_turning_revs)
        dead = turning & (np.abs(mine) < check.dead_wheel_reading * np.abs(other))
        if turning.sum() >= check.dead_wheel_min_seconds \
                and dead.sum() > check.dead_wheel_share * turning.sum():
            out.append(Finding(Check.WHEEL_DEAD, Severity.FATAL, dead.sum() / turning.sum(),
                               check.dead_wheel_share, name))
    if out:
        return out
    ratio = (float(np.median(win.wheel_ds[moving] / win.ds[moving]))
             if moving.sum() >= check.scale_min_seconds
             else float(np.abs(win.wheel_ds).sum() / max(np.abs(win.ds).sum(), 1e-9)))
    if not lim.min_scale <= ratio <= lim.max_scale:
        return [Finding(Check.SPEED_SCALE, Severity.FATAL, ratio, 1.0)]
    if abs(ratio - 1.0) > lim.datasheet_scale_note:
        return [Finding(Check.SPEED_SCALE, Severity.NOTE, ratio, 1.0)]
    return []


def _wheel_ratio(win: _Windows, mask: BoolArray, theta: FloatArray) -> tuple[float, float]:
    """The wheels' difference over their mean, less what the reference's turning explains
    (``t_r dpsi / c_e``, datasheet values): about ``-c_d / c_e``. Its median over the seconds of
    ``mask`` and that median's standard error."""
    left, right, turn = win.left_revs[mask], win.right_revs[mask], win.dpsi[mask]
    track, scale = LAYOUT.value(theta, LAYOUT.track), LAYOUT.value(theta, LAYOUT.scale)
    ratio = (left - right + track * turn / scale) / (0.5 * (left + right))
    median = float(np.median(ratio))
    spread = 1.4826 * float(np.median(np.abs(ratio - median)))      # a normal's sigma
    return median, 1.2533 * spread / np.sqrt(ratio.size)         # sqrt(pi/2): a median's


def _vehicles(drives: Sequence[Drive], win: _Windows, moving: BoolArray,
              theta: FloatArray, lim: ChecksSettings) -> list[Finding]:
    """Drives that disagree on the vehicle: their wheels differ by other amounts where the
    turning does not explain it (two cars, or wheels swapped or re-tyred between the logs). One
    calibration would average them; value the difference, name the two drives."""
    usable = moving & (np.abs(win.dpsi) < lim.vehicles_max_turn_rad) \
        & (np.minimum(win.left_revs, win.right_revs) > lim.vehicles_min_wheel_revs)
    ratios = {}
    for k in range(len(drives)):
        mine = usable & (win.drive == k)
        if mine.sum() >= lim.vehicles_min_seconds:
            ratios[k] = _wheel_ratio(win, mine, theta)
    worst: tuple[float, int, int] | None = None
    for i in ratios:
        for j in ratios:
            if j <= i:
                continue
            gap = abs(ratios[i][0] - ratios[j][0])
            noise = float(np.hypot(ratios[i][1], ratios[j][1]))
            enough = max(lim.vehicles_max_ratio_gap, lim.vehicles_sigmas * noise)
            if gap > enough and (worst is None or gap > worst[0]):
                worst = (gap, i, j)
    if worst is None:
        return []
    gap, i, j = worst
    return [Finding(Check.VEHICLES_DIFFER, Severity.FATAL, gap, lim.vehicles_max_ratio_gap,
                    f"{drives[i].name}|{drives[j].name}")]


def _lateral(win: _Windows, bends: BoolArray, lim: ChecksSettings) -> list[Finding]:
    """a_y against speed times yaw rate, in bends: present, sign and unit.

    Missing: a_y's size about zero is a small share of speed times yaw rate's, or a_y does not
    vary where speed times yaw rate does (stuck at a constant). Sign and unit: their agreement
    about zero (a car circling at one rate has no spread to correlate) and the slope.
    """
    ay, vw = win.a_y[bends], win.v_w[bends]
    size = float(np.sqrt(np.mean(ay**2) / max(float(np.mean(vw**2)), 1e-12)))
    spread = float(np.std(ay) / max(float(np.std(vw)), 1e-12))
    least = lim.lateral_min_share
    if size < least or (np.std(vw) > lim.lateral_min_vw_spread_mps2 and spread < least):
        return [Finding(Check.LATERAL_MISSING, Severity.FALLBACK, min(size, spread), least,
                        "a_y")]
    agree = _agreement(ay, vw)
    slope = float(ay @ vw / max(float(vw @ vw), 1e-12))
    if agree < -lim.lateral_min_correlation:
        return [Finding(Check.LATERAL_SIGN, Severity.FATAL, slope, 1.0, "a_y")]
    if agree > lim.lateral_min_correlation \
            and not lim.lateral_min_slope <= slope <= lim.lateral_max_slope:
        return [Finding(Check.LATERAL_SCALE, Severity.FATAL, slope, 1.0, "a_y")]
    return []


def _clock(drives: Sequence[Drive], theta: FloatArray, settings: Settings) -> list[Finding]:
    """Lag of the wheels' yaw rate behind the reference's, by cross-correlation (up to
    ``wheel_lag_search_s``) summed over every piece of at least ``lag_min_piece_s``; a positive
    lag means the wheel stream is late."""
    lim = settings.gate
    lag = wheel_lag_s(drives, theta, settings)
    if lag is None:
        return []
    t_s = drives[0].t_s
    corrected = settings.inverse.max_delay_s if settings.inverse.delay == "estimate" else 0.0
    if abs(lag) > min(lim.max_clock_offset_s, max(corrected, t_s)):
        # beyond what the calibration takes out (its lag scan reaches a step further)
        return [Finding(Check.CLOCK_OFFSET, Severity.FATAL, lag, corrected)]
    return []
