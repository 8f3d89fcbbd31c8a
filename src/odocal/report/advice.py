"""Identifiability in plain words: what a drive determines, and what more driving would.

The standard deviation of an estimate shrinks about as one over the square root of the data
that informs it. c_e is informed by distance travelled, c_d by heading drift (any driving),
t_r and d by bends (segments whose yaw rate exceeds the selection threshold). For a parameter
that is not identified, or only loosely, the advice scales the informative driving this drive
had to what would bring the standard deviation to the identifiability limit.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from odocal.checks.findings import Check, Finding, Severity
from odocal.data.drive import Drive
from odocal.data.segments import SegmentSet
from odocal.estimators.estimate import Estimate, Identified, NotIdentified, Reason
from odocal.model.layout import REAR_AXLE as LAYOUT
from odocal.model.parameters import PARAMETER_LABELS, PARAMETER_NAMES
from odocal.settings import Settings

#: What informs each parameter.
NEEDS = {"c_e": "distance", "c_d": "driving", "t_r": "bends", "d": "bends"}


@dataclass(frozen=True)
class Coverage:
    """How much of each kind of driving the drives hold."""

    duration_s: float
    distance_m: float
    moving_s: float
    bend_s: float
    segments: int
    selected: int
    short_pieces_s: float

    def to_dict(self) -> dict[str, Any]:
        return {"duration_s": self.duration_s, "distance_m": self.distance_m,
                "moving_s": self.moving_s, "bend_s": self.bend_s, "segments": self.segments,
                "selected": self.selected, "not_selected": self.segments - self.selected,
                "time_in_pieces_too_short_s": self.short_pieces_s}


def coverage(drives: Sequence[Drive], segments: SegmentSet, settings: Settings) -> Coverage:
    threshold = settings.segments.yaw_rate_threshold_radps
    moving = bend = duration = distance = short = 0.0
    k = settings.segments.length
    for d in drives:
        speed = np.hypot(np.gradient(d.x), np.gradient(d.y)) / d.t_s
        moving += float(np.sum(speed > 0.5) * d.t_s)
        bend += float(np.sum((np.abs(d.yaw_rate) > threshold) & (speed > 0.5)) * d.t_s)
        duration += d.duration_s
        distance += d.distance_m
        short += sum((b - a) * d.t_s for a, b in d.pieces if b - a < k + 1)
    return Coverage(duration_s=duration, distance_m=distance, moving_s=moving, bend_s=bend,
                    segments=len(segments), selected=int(segments.selected.sum()),
                    short_pieces_s=short)


@dataclass(frozen=True)
class ParameterAdvice:
    name: str
    label: str
    identified: bool
    text: str

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "label": self.label, "identified": self.identified,
                "text": self.text}


def _amount(what: str, cov: Coverage) -> tuple[float, str]:
    if what == "distance":
        return cov.distance_m, f"{cov.distance_m / 1000:.2f} km"
    if what == "bends":
        return cov.bend_s, f"{cov.bend_s:.0f} s in bends"
    return cov.moving_s, f"{cov.moving_s / 60:.1f} min of driving"


def _more(what: str, amount: float, factor: float) -> str:
    extra = amount * max(factor - 1.0, 0.0)
    if what == "distance":
        return f"about {extra / 1000:.1f} km more"
    if what == "bends":
        return f"about {extra / 60:.1f} more minutes in bends"
    return f"about {extra / 60:.0f} more minutes of driving"


def advise(estimate: Estimate, cov: Coverage, settings: Settings,
           segment_s: float) -> list[ParameterAdvice]:
    """One sentence or two per parameter, from the typed verdicts.

    ``segment_s`` is the duration of one identification segment (K times the drive's sampling
    time).
    """
    threshold = settings.segments.yaw_rate_threshold_radps
    prior = np.asarray(settings.identify.prior_std)
    out = []
    for j, (name, verdict) in enumerate(zip(PARAMETER_NAMES, estimate.verdicts, strict=True)):
        label = PARAMETER_LABELS[j]
        what = NEEDS[name]
        amount, have = _amount(what, cov)
        if isinstance(verdict, Identified):
            factor = (verdict.std / verdict.limit) ** 2 if verdict.limit > 0 else 0.0
            text = (f"{label} is identified to +-{format_value(name, verdict.std)} from {have}; "
                    f"the limit for calling it identified is "
                    f"+-{format_value(name, verdict.limit)}")
            if factor > 0.25:
                text += (f". It is close to that limit: {_more(what, amount, 4 * factor)} "
                         "would halve the uncertainty")
            if name in consistent_with_zero(estimate):
                text += ". " + zero_text(name, estimate.theta.as_array()[j], verdict.std)
            out.append(ParameterAdvice(name, label, True, text + "."))
            continue
        out.append(ParameterAdvice(name, label, False, _not_identified(
            name, label, verdict, cov, have, what, amount, threshold, segment_s, prior[j])))
    return out


def _not_identified(name: str, label: str, verdict: NotIdentified, cov: Coverage, have: str,
                    what: str, amount: float, threshold: float, segment_s: float,
                    prior: float) -> str:
    reason = verdict.reason
    if reason is Reason.NEEDS_BENDS:
        return (f"{label} needs bends: its effect shows only when the vehicle turns, and this "
                f"drive's yaw rate exceeds {threshold} rad/s for {cov.bend_s:.0f} s (the "
                f"largest is {verdict.detail:.3f} rad/s). Drive through at least 10 bends or "
                "junction turns, or a few roundabouts, then calibrate again.")
    if reason is Reason.WEAK:
        factor = (verdict.std / verdict.limit) ** 2 if verdict.limit > 0 else float("inf")
        return (f"{label} is determined only to +-{format_value(name, verdict.std)} by {have}, "
                f"not well below the datasheet uncertainty (+-{format_value(name, prior)}): "
                f"{_more(what, amount, factor)} would identify it (about {factor:.0f} times "
                "this drive's).")
    if reason is Reason.NO_INFORMATION:
        return (f"{label} leaves no trace in these segments ({have}). "
                f"It needs {'bends' if what == 'bends' else 'more varied driving'}.")
    if reason is Reason.NO_DIFFERENTIAL:
        return (f"{label} is not calibrated: the two wheel signals carry no differential "
                "information (a locked axle, a single speed signal, or one column copied into "
                "the other), so only the distance scale c_e can be.")
    if reason is Reason.NO_LATERAL:
        return (f"{label} is not calibrated: the lateral acceleration a_y carries none (zero or "
                "constant: a missing or unplugged sensor, or a mapping that names no a_y). The "
                f"load transfer it stands for is still there: its datasheet uncertainty "
                f"(+-{format_value(name, prior)}) is carried by the other parameters' "
                "uncertainty, t_r's above all. Map a lateral acceleration (the IMU's) and "
                "calibrate again.")
    if reason is Reason.ONE_CLUSTER:
        return (f"{label} is not identified: all {cov.selected} segments overlap in time, one "
                "piece of independent evidence, which cannot say how uncertain the estimate "
                f"is. Drive at least {2 * segment_s:.0f} s more with bends.")
    if reason is Reason.FAILED:
        return f"{label} is not identified: the estimation failed."
    if reason is Reason.STANDSTILL:
        return f"{label} is not identified: the vehicle does not move."
    if reason is Reason.REJECTED:
        return f"{label} is not calibrated: the data contradict the model (see the checks)."
    return f"{label} is held at its datasheet value, as requested."


def reason_text(name: str, verdict: NotIdentified, *, threshold_radps: float) -> str:
    """Why a parameter is not identified, in one clause (for the CLI and warnings)."""
    reason = verdict.reason
    front = name in _FRONT_NEEDS          # (the four-wheel car's: judged on its windows)
    if front and (reason is Reason.NEEDS_BENDS
                  or (reason is Reason.WEAK and not math.isfinite(verdict.std))):
        return f"needs {_FRONT_NEEDS[name]}; kept at the datasheet value"
    if reason is Reason.NEEDS_BENDS:
        return (f"needs bends: the yaw rate never exceeds {threshold_radps} rad/s (at most "
                f"{verdict.detail:.3f} rad/s); kept at the datasheet value")
    if reason is Reason.WEAK:
        return (f"the data determine {name} only to +-{format_value(name, verdict.std)} (the "
                f"limit is +-{format_value(name, verdict.limit)}); kept at the datasheet value")
    if reason is Reason.NO_INFORMATION:
        return "these segments carry no information on it; kept at the datasheet value"
    if reason is Reason.NO_DIFFERENTIAL:
        return ("the wheel signals carry no differential information; only c_e is calibrated")
    if reason is Reason.NO_LATERAL:
        return ("a_y carries no lateral acceleration (zero or constant), so the load transfer "
                "cannot be seen; its datasheet uncertainty widens the others' (t_r's above all)")
    if reason is Reason.ONE_CLUSTER:
        return ("all segments overlap in time (one piece of independent evidence); kept at the "
                "datasheet value")
    if reason is Reason.FAILED:
        return "the estimation failed"
    if reason is Reason.STANDSTILL:
        return "the vehicle does not move"
    if reason is Reason.REJECTED:
        return "the data contradict the model"
    return "held at the datasheet value"


#: Why each front parameter of the four-wheel car needs what it needs, in plain words.
_FRONT_NEEDS = {
    "c_f": "distance on the front wheels",
    "c_fd": "bends on the front wheels (their difference turns with the yaw)",
    "t_f": ("bends: the front wheels' difference tells their track only while turning, and "
            "in bends it moves with the wheelbase and the load transfer alike"),
    "L": ("tight bends: the wheelbase shows only in the front wheels' longer path around a "
          "bend (a share of about (L x curvature)^2 / 2 of it), a few millimetres a turn"),
    "ratio": ("a known wheelbase: at the small angles of most driving the steering-wheel "
              "angle says ratio x L only, so the ratio is told from the wheelbase"),
    "s_0": "driving with the steering angle logged (its offset is its mean on straights)",
}


def front_advice(vehicle: Estimate) -> list[ParameterAdvice]:
    """One sentence per parameter the four-wheel car adds to the rear axle (its front axle and
    its steering): identified to what, or what the drives lack for it, in plain words."""
    layout = vehicle.theta.layout
    out = []
    for name in _FRONT_NEEDS:
        j = layout.index(name)
        label = layout.labels[j]
        verdict = vehicle.verdicts[j]
        if isinstance(verdict, Identified):
            text = (f"{label} is identified to +-{format_value(name, verdict.std)} (the limit "
                    f"for calling it identified is +-{format_value(name, verdict.limit)}).")
        elif verdict.reason is Reason.NO_INFORMATION and name in ("ratio", "s_0"):
            text = (f"{label} is not identified: the drives carry no steering-wheel angle "
                    "that can be used (none is mapped, or the one logged was left out: see "
                    "the notes); its datasheet value is kept.")
        elif name == "ratio" and _diluted(vehicle):
            text = (f"{label} is not identified: the reference heading's noise is too large a "
                    "share of the turning it would be judged against (see the notes); its "
                    "datasheet value is kept.")
        elif verdict.reason in (Reason.FAILED, Reason.REJECTED, Reason.STANDSTILL):
            text = f"{label} is not calibrated: {reason_text(name, verdict, threshold_radps=0)}."
        else:
            beside = [n for n in _FRONT_NEEDS if n != name
                      and not vehicle.identified[layout.index(n)]]
            also = (f" (or datasheet values of {', '.join(beside)}, held beside it: their "
                    "uncertainty is carried into it)" if beside else "")
            text = (f"{label} is not identified by these drives: it needs "
                    f"{_FRONT_NEEDS[name]}{also}. Its datasheet value is kept, and its "
                    "datasheet uncertainty is carried into the parameters identified beside "
                    "it.")
        out.append(ParameterAdvice(name, label, isinstance(verdict, Identified), text))
    return out


def _diluted(vehicle: Estimate) -> bool:
    """Whether the four-wheel fit held the steering ratio because the reference's noise
    dilutes it (:func:`odocal.estimators.front_axle.steering_attenuation`)."""
    from odocal.estimators.front_axle import MIN_ATTENUATION

    front = getattr(vehicle.details, "front", None)
    share = getattr(front, "steering_attenuation", None)
    return share is not None and share < MIN_ATTENUATION


#: Parameters whose zero means "no such effect" (the layout's wheel difference and load
#: transfer: c_d, d), and the effect.
ZERO_MEANS = {LAYOUT.difference: "difference between the two wheels' circumferences",
              LAYOUT.load: "load transfer"}
#: An identified value within this many standard deviations of zero is consistent with zero.
ZERO_SIGMAS = 2.0


def consistent_with_zero(estimate: Estimate) -> tuple[str, ...]:
    """Identified parameters whose zero means no effect (c_d, d) and whose value lies within
    :data:`ZERO_SIGMAS` standard deviations of it: identified, but no evidence of the
    effect."""
    theta = estimate.theta.as_array()
    return tuple(name for j, (name, ok) in enumerate(zip(PARAMETER_NAMES, estimate.identified,
                                                         strict=True))
                 if ok and name in ZERO_MEANS
                 and abs(theta[j]) <= ZERO_SIGMAS * float(estimate.std[j]))


def zero_text(name: str, value: float, std: float) -> str:
    """An identified parameter consistent with zero, in a sentence (report, CLI)."""
    sign = "-" if value < 0 else "+"
    bound = format_value(name, abs(value) + ZERO_SIGMAS * std)
    return (f"{name} = {sign}{format_value(name, abs(value))} +-{format_value(name, std)} is "
            f"identified but consistent with zero (within {ZERO_SIGMAS:g} standard "
            f"deviations): this drive shows no measurable {ZERO_MEANS[name]} (at most about "
            f"{bound} either way), not evidence of one")


def format_value(name: str, value: float) -> str:
    """A parameter value (or standard deviation) in the unit it reads best in."""
    if name == "c_d":
        return f"{value * 1000:.3g} mm"
    if name == "d":
        return f"{value * 1000:.3g} mm per m/s^2"
    return f"{value * 1000:.3g} mm" if value < 0.1 else f"{value:.3g} m"


#: Factors a wheel-speed unit or scale mistake produces, and what would cause them.
_SCALE_HINTS = ((60.0, "rpm given as rev/s"), (1 / 60.0, "rev/s given as rpm"),
                (2 * np.pi, "rad/s given as rev/s, or the radius given as the circumference"),
                (1 / (2 * np.pi), "rev/s given as rad/s, or the circumference as the radius"),
                (3.6, "km/h given as m/s"), (1 / 3.6, "m/s given as km/h"),
                (2.0, "the diameter given as the radius"), (0.5, "the radius as the diameter"))


def _range_text(finding: Finding, settings: Settings) -> str:
    """Which range a parameter left, and where that range comes from."""
    from odocal.checks.gate import plausible_range
    from odocal.settings import datasheet_stated

    name, v = finding.name, finding.value
    value = f"{name} = {format_value(name, abs(v))}{' (negative)' if v < 0 else ''}"
    if name in ("c_e", "t_r"):
        lo, hi = plausible_range(settings, name)
        span = f"{format_value(name, lo)} .. {format_value(name, hi)}"
        if (settings.gate.c_e_m if name == "c_e" else settings.gate.t_r_m) is not None:
            return f"{value} lies outside the range {span} set in [gate] {name}_m"
        nominal = settings.identify.datasheet(name)
        whose = ("the datasheet" if datasheet_stated(settings.identify.theta0)
                 else "odocal's placeholder datasheet (state yours with --datasheet)")
        return (f"{value} lies outside the range {span}: within a factor "
                f"{settings.gate.range_factor:g} of {whose} {name} "
                f"{format_value(name, nominal)} ([gate] range_factor, {name}_m)")
    return (f"{value} lies outside its plausible range (limit "
            f"{format_value(name, abs(finding.reference))}, [gate] in the settings)")


def finding_text(finding: Finding, settings: Settings) -> str:
    """One finding of the checks in plain words."""
    c, v, ref = finding.check, finding.value, finding.reference
    if c is Check.STANDSTILL:
        return (f"the vehicle does not move (the wheels turn {v:.1f} m in all): there is "
                "nothing to calibrate")
    if c is Check.WHEELS_SWAPPED:
        where = f" of '{finding.name}'" if finding.name else ""
        return (f"the yaw rate the wheels{where} imply turns against the reference's in bends "
                f"(correlation {v:+.2f}): the left and right wheel columns are swapped, or the "
                "heading is mirrored; fix the mapping and calibrate again")
    if c is Check.WHEELS_IDENTICAL:
        return ("the two wheel signals are identical (one column copied into the other, or one "
                "speed signal for both wheels): they carry no yaw, so only c_e is calibrated")
    if c is Check.NO_DIFFERENTIAL:
        return (f"the yaw rate the wheels imply does not follow the reference's in bends "
                f"(correlation {v:+.2f}): a locked axle or a single speed signal? Only c_e is "
                "calibrated")
    if c is Check.SPEED_SCALE:
        return _speed_scale_text(finding, settings)
    if c is Check.LATERAL_SIGN:
        return (f"a_y has the wrong sign against speed times yaw rate (slope {v:+.2f}): the "
                "lateral acceleration must be positive to the left")
    if c is Check.LATERAL_SCALE:
        hint = " (in g instead of m/s^2?)" if 0.07 < v < 0.14 else ""
        return f"a_y is {v:.3g} times speed times yaw rate{hint}"
    if c is Check.CLOCK_OFFSET:
        reach = ("no lag (the lag search is off: [inverse] delay)" if finding.reference == 0
                 else f"up to {finding.reference:g} s, [inverse] max_delay_s")
        return (f"the wheel stream lags the pose stream by {v:+.2f} s, more than the "
                f"calibration corrects ({reach}): align the clocks (the mapping's offset_s) "
                "and calibrate again")
    if c is Check.PARAMETER_RANGE:
        return _range_text(finding, settings)
    if c is Check.WORSE_THAN_DATASHEET:
        return (f"the calibrated parameters validate worse than the datasheet values "
                f"({v:.2f} m against {ref:.2f} m)")
    if c is Check.LARGE_ERROR:
        return (f"the validation error ({v:.2f} m) is a large share of the "
                f"{settings.segments.validation_distance_m:.0f} m segments (the limit is "
                f"{ref:.1f} m): the model does not describe these data")
    if c is Check.DATA_REPAIRED:
        return f"{finding.name}: {v:.0f} isolated spike(s) repaired"
    return _reference_and_sensor_text(finding)


def _speed_scale_text(finding: Finding, settings: Settings) -> str:
    """The wheels' distance against the reference's in plain words: a datasheet c_e that
    does not fit (a note), or a sign, unit or scale mistake, with its likely cause."""
    v, ref = finding.value, finding.reference
    if finding.severity is Severity.NOTE:
        c_e = settings.identify.datasheet("c_e")
        speeds = (" Or are they wheel speeds in m/s given as rev/s?"
                  if abs(np.log(v / c_e)) < 0.25 else "")
        return (f"with the datasheet c_e ({c_e:g} m) the wheels imply {v:.3f} times the "
                "distance the reference travels: is [identify] theta0 set for this "
                f"vehicle?{speeds}")
    if not v > 0:                     # (a log of it would be NaN, and a warning)
        if not v < 0:
            travelled = f" ({ref / 1000:.2f} km)" if ref > 1.0 else ""
            return (f"the wheels read no motion while the reference travels{travelled}: "
                    "the wheel columns are empty, unmapped or dead (or the vehicle was "
                    "carried); fix the mapping")
        scale = (f"; and by {abs(v):.3g} times its distance, also a wrong unit or scale"
                 if abs(np.log(abs(v))) > 0.25 else "")
        return (f"the wheels turn backwards while the reference moves forwards (they imply "
                f"{v:+.3g} times the distance it travels): the wheel rates' sign is "
                f"flipped{scale}; n_rl and n_rr count forward revolutions as positive "
                "(negate both columns, or fix the mapping)")
    c_e = settings.identify.datasheet("c_e")
    unit_hints = ((3.6 * c_e, 'wheel speeds in km/h given as rev/s: give the mapping\'s '
                              'unit = "km/h"'),
                  (c_e, 'wheel speeds in m/s given as rev/s: give the mapping\'s unit = "m/s"'),
                  (3.6 * c_e / 1.609344, 'wheel speeds in mph given as rev/s: give the '
                                         'mapping\'s unit = "mph"'))
    factor, cause = min((*_SCALE_HINTS, *unit_hints), key=lambda h: abs(np.log(v / h[0])))
    hint = f" ({cause}?)" if abs(np.log(v / factor)) < 0.25 else ""
    from odocal.settings import datasheet_stated

    sheet = ("" if datasheet_stated(settings.identify.theta0) else
             f", or a vehicle unlike odocal's placeholder datasheet (c_e "
             f"{settings.identify.datasheet('c_e'):g} m): state yours with --datasheet")
    return (f"the wheels imply {v:.3g} times the distance the reference travels: a wrong "
            f"wheel-speed unit or scale{hint}{sheet}")


#: A front wheel's own faults (``FRONT_AXLE`` findings named ``what-side|drive``): what the
#: value is, and what it means.
_FRONT_WHEEL_WORDS = {
    "dead": "reads nothing on {v:.0%} of the moving samples of {where} while the other turns: "
            "a dead sensor or an unmapped column",
    "frozen": "'s rate stays put for {v:.0f} s of {where} while the other's changes: a sensor "
              "that stopped updating",
    "rates": "turns {v:.3g} times as fast as the rear ones in {where}: its rates in another "
             "unit (m/s, km/h or rad/s given as rev/s?) or scaled",
    "backwards": "turns against the rear ones on {v:.0%} of the moving samples of {where}: its "
                 "sign is flipped",
}
#: The share of straight seconds moving against the heading on wheels without a sign beyond
#: which a refused heading names the wheels' sign as a cause.
BACKING_SHARE = 0.05
#: What a refusal of the four-wheel car ends with (what calibrate does about it).
NOTHING_CALIBRATED = _NOTHING = " (nothing is calibrated from these)"


def _four_wheel_text(finding: Finding) -> str:
    """The four-wheel car's findings (the wheels' mapping, the front axle, the steering) in
    plain words."""
    c, v, ref = finding.check, finding.value, finding.reference
    what, _, where = finding.name.partition("|")
    if c is Check.STEERING:
        return _steering_text(what, where, v, ref)
    if c is Check.WHEEL_MAPPING:
        return _mapping_text(what, where, v, ref)
    if what.startswith("datasheet-"):
        return _datasheet_text(what, where, v, ref)
    if what == "unsigned":
        return (f"the front wheels of {where} read forwards for {v:.0f} s while the rear ones "
                "turn backwards: front wheel speeds without a sign on a vehicle backing up; "
                "those samples are left out of the front axle's fit")
    if what == "no-front":
        return (f"{where} carries no front wheels' rates while other drives do: the front "
                "axle is calibrated on those")
    fault, _, side = what.partition("-")
    if fault in ("ahead", "change", "slid"):
        return _fit_text(fault, side, where, v, ref)
    if fault in _FRONT_WHEEL_WORDS:
        gap = "" if fault == "frozen" else " "
        return (f"the front {side} wheel{gap}"
                + _FRONT_WHEEL_WORDS[fault].format(v=v, where=where) + _NOTHING)
    if what == "scale":
        return (f"the front wheels imply a circumference of {ref:.4g} m, {v:.3g} times the "
                "rear ones': front wheel rates in another unit (m/s, km/h or rad/s given as "
                f"rev/s?) or scaled{_NOTHING}")
    if what == "scale-note":
        return (f"the front wheels roll {abs(v - 1.0):.1%} {'further' if v > 1 else 'less far'}"
                f" per turn than the rear ones (c_f {ref:.4g} m): staggered tyres differ by a "
                "few per cent; more is a front speed signal converted with another "
                "circumference, or wheel-speed rings of another tooth count (the calibration "
                "stands as the wheels report)")
    if what == "difference-note":
        return (f"the front wheels' circumferences differ by {v * 1e3:.4g} mm of {ref:.4g} m "
                f"({abs(v) / ref:.1%}), where two tyres of one axle differ by a few "
                "millimetres: a tyre of another size or wear, or one wheel's signal scaled? "
                "(the calibration stands as the wheels report)")
    if what == "difference":
        return (f"the front wheels' circumferences differ by {v * 1e3:.4g} mm of {ref:.4g} m, "
                "more than two tyres of one axle do: one front wheel reads a share of its "
                f"turns (another tooth count, a scaled signal), or another unit{_NOTHING}")
    return (f"the front wheels put the front axle {v:.4g} m ahead of the rear one, beyond any "
            f"vehicle's {ref:.0f} m{_NOTHING}")


def _fit_text(what: str, side: str, where: str, v: float, ref: float) -> str:
    """What the car's fit says beside its numbers: a side's front wheel ahead of its rear one
    (``ahead``), the front tyres changed within the drives (``change``), a sideslip the rear
    fit described (``slid``)."""
    if what == "ahead":
        return (f"the {side} front wheel travels further than the {side} rear one in bends in "
                f"{where}, as a wheel {math.sqrt(v):.2f} m (+-{ref / (2 * math.sqrt(v)):.2f}) "
                "ahead of it does: the front and rear columns are mapped as such (judged on the "
                "wheels alone)")
    if what == "change":
        return (f"the front wheels' circumference changed by {v:+.2%} within the drives (their "
                f"later half against the earlier, {abs(ref):.0f} standard deviations): a front "
                "tyre changed, or its pressure; c_f is a mix of the two, its std widened to "
                "cover either (calibrate on the drives after the change for its value now)")
    how = " and ".join(
        ([f"the rear axle sliding {math.degrees(v):+.2f} degrees per m/s^2 of lateral "
          "acceleration"] if v else [])
        + (["the wheels travelling more in bends than the reference's point"] if ref else []))
    return (f"the rear fit found {how}, a sideslip the log does not carry: the wheelbase "
            "and the steering ratio rest on the front wheels' path in bends, which that "
            "description gives to first order only; their stds carry the excess's share "
            "where one was found, not the rest (on simulated cars logged so, one drive in "
            "ten came out 3 to 7 stds off); give the sideslip (a beta column; the ROS 2 "
            "node's sideslip_from_reference) or state the wheelbase from the datasheet")


def _mapping_text(what: str, where: str, v: float, ref: float) -> str:
    """The four wheels' mapping (a wheel in another's column)."""
    if what == "front-sides-yaw":
        return (f"the front wheels' difference turns against the yaw rate (correlation "
                f"{v:+.2f}) in {where}: front left and right swapped? map them the other "
                f"way round{_NOTHING}")
    if what.startswith("front-behind-"):
        side = what.rpartition("-")[2]
        if side == "axles":
            return (f"the front wheels travel less than the rear ones in bends on both sides in "
                    f"{where} (as wheels {math.sqrt(-v):.1f} m behind them would): the front and "
                    f"rear axles exchanged? map them the other way round{_NOTHING}")
        return (f"the {side} front wheel travels less than the {side} rear one in bends in "
                f"{where} (as a wheel {math.sqrt(-v):.1f} m behind it would): the front {side} "
                f"and rear {side} wheels exchanged? map them the other way round{_NOTHING}")
    if what.startswith("axle-sides-"):
        axle = what.rpartition("-")[2]
        return (f"the {axle} wheels' difference does not follow the yaw rate in bends in "
                f"{where} (correlation {v:+.2f}), as an axle's does: two wheels of one side, or "
                f"a front and a rear wheel, in the {axle} columns? check the mapping of all "
                f"four{_NOTHING}")
    if what == "front-copy":
        return (f"the front left and right wheels' columns hold one signal in {where}: one "
                f"column mapped twice? map each front wheel to its own{_NOTHING}")
    if what == "front-sides":
        return (f"the front wheels' difference runs against the turning (t_f = {v:.2f} m "
                f"+-{ref:.2f}): front left and right swapped? map them the other way "
                f"round{_NOTHING}")
    return ("the rear wheels turn alike in bends while the car has four wheel signals: "
            "two wheels of one side mapped as an axle (a wheel among the four in the "
            f"wrong column)? check the mapping of all four{_NOTHING}")


def _datasheet_text(what: str, where: str, v: float, ref: float) -> str:
    """A datasheet value stated far from what the drives say of it (``datasheet-far``: the
    drives identify it; ``datasheet-held``: held at the statement, identified from odocal's
    placeholder)."""
    if what == "datasheet-held":
        return (f"the datasheet's {format_value(where, ref)} for {where} is kept, but the "
                f"drives put it at {format_value(where, v)} when fitted from odocal's "
                "placeholder (more than five of their stds apart): judged at the datasheet's "
                "value they could not tell it, as its signal grows with it. A typo in the "
                f"datasheet, or another car's? state {where} as the car has it, or leave it "
                "out, and calibrate again")
    return (f"the drives put {where} at {format_value(where, v)}, far from the datasheet's "
            f"{format_value(where, ref)} (more than five calibrated stds apart): a typo in the "
            "datasheet, or another car's? (the calibration stands as the drives say)")


def _steering_text(what: str, where: str, v: float, ref: float) -> str:
    """A steering angle left out (``STEERING`` findings), in plain words."""
    left = "it is left out: the steering ratio and offset are not calibrated, the wheels are"
    if what == "constant":
        return f"the steering angle of {where} does not change while moving: {left}"
    if what == "stuck":
        return (f"the steering angle of {where} holds one value through bends for {v:.0f} s "
                "in all, where a steering wheel turns: a sensor that stopped updating, or a "
                "column zeroed from some time on; those spans are left out of the steering's "
                "fit")
    if what == "no-steering":
        return (f"{where} carries no steering angle while other drives do: the steering is "
                "calibrated on those")
    if what == "diluted":
        return ("the steering ratio is not calibrated: the reference heading's noise makes "
                f"up {1.0 - v:.0%} of the turning the steering is judged against on these "
                f"drives (at most {1.0 - ref:.0%} is taken), and noise in the turning makes a "
                "fitted ratio come out low by about that share; bends (or a smoother "
                "reference) tell it; the offset is calibrated")
    if what == "straight":
        return (f"the steering angle of {where} stands {math.degrees(v):+.3g} degrees off "
                f"centre (spread {math.degrees(ref):.3g} degrees) while driving straight, "
                "where a car's steering wheel stays within a few degrees: in degrees given "
                f"as radians, or a sensor zeroed elsewhere? {left}")
    if what == "range":
        return (f"the steering angle says a steering ratio of {v:.3g}, which no steering has "
                "(0.5 to 40): a stuck or noisy sensor, a flipped sign, or too little turning "
                f"to tell it; {left}")
    if what == "sign":
        return (f"the steering angle of {where} turns against the reference's curvature (as a "
                f"ratio of {v:.3g}): its sign is flipped? negate the column or map it so; "
                f"{left}")
    return (f"the steering angle of {where} implies a steering ratio of {v:.4g} with the "
            f"datasheet's wheelbase of {ref:.4g} m (a steering has 0.5 to 40): in degrees "
            f"given as radians, or another unit? {left}")


def _departure_text(finding: Finding) -> str:
    """A departure the one fit took in (:mod:`odocal.estimators.departures`), in plain words;
    empty for any other finding."""
    c, v, ref = finding.check, finding.value, finding.reference
    fitted = "fitted with the parameters, its uncertainty in theirs"
    if c is Check.REFERENCE_LAG:
        way = "after" if v > 0 else "before"
        return (f"the reference reports each pose {abs(v):.3f} s (+-{ref:.3f}) {way} the wheels "
                f"turned for it (a localisation stack's latency, or two loggers' clocks): "
                f"{fitted}")
    if c is Check.WHEEL_SMOOTHING:
        return (f"the wheel rates are smoothed over about {v:.2f} s (+-{ref:.2f}) more than the "
                f"reference (a CAN gateway's filter, ticks counted over a window): {fitted}")
    if c is Check.WHEEL_SKEW:
        return (f"the {finding.name} wheel alone reads {v:+.4f} rev/s (+-{ref:.4f}) more than "
                f"its motion gives, at every speed (its sensor's offset): {fitted}")
    if c is Check.REFERENCE_ARM:
        return (f"the reference point is {v:+.2f} m (+-{ref:.2f}) {finding.name} of the rear "
                "axle's midpoint (a GNSS antenna, an INS, a camera): fitted, and taken out of "
                "validation and the exported trajectories; state it with [reference] offset_m")
    if c is Check.CURVE_EXCESS:
        if v > 0:
            return (f"the wheels travel more than the rear axle in bends, as wheels "
                    f"{math.sqrt(2.0 * v):.1f} m ahead of it do (front wheels mapped as the "
                    "rear ones, on a reference whose heading is its course?): fitted, so the "
                    "parameters are those of the wheels given; map the rear wheels for the "
                    "rear axle's")
        return (f"the wheels travel less than the reference in bends, as a reference "
                f"{math.sqrt(-2.0 * v):.1f} m ahead of the axle whose heading is its course "
                f"does (or tyres that slip in tight bends): {fitted}")
    if c is Check.FRONT_WHEELS:
        return (f"the wheel speeds turn as wheels {v:.1f} m (+-{ref:.1f}) ahead of the rear "
                "axle do in bends, on a reference with a heading of its own, and nothing else "
                "the fit took in (a lever arm, a smoothed reference, slip) explains it: front "
                "wheels mapped as the rear ones? odocal's model is the rear axle's; map the "
                "rear wheels (nothing is calibrated from these)")
    if c in (Check.WHEEL_MAPPING, Check.FRONT_AXLE, Check.STEERING):
        return _four_wheel_text(finding)
    if c is Check.REFERENCE_SMOOTHED:
        return (f"the reference travels less than the wheels in bends at speed, as a pose "
                f"smoothed over about {math.sqrt(2.0 * max(v, 0.0)):.2f} s does (it cuts the "
                f"bends short): {fitted}")
    if c is Check.LATERAL_GAIN:
        return (f"a_y reads {1.0 + v:.3f} (+-{ref:.3f}) times the reference's lateral "
                "acceleration (a body that rolls in bends, or an accelerometer's scale): the "
                "parameters are for a_y as logged, and d's uncertainty carries what it would "
                "be were the scale the sensor's")
    if c is Check.SIDESLIP:
        return (f"the rear axle slides {np.degrees(v):+.2f} degrees (+-{np.degrees(ref):.2f}) "
                f"sideways per m/s^2 of lateral acceleration: {fitted}")
    if c is Check.DRIFT:
        return (f"c_e grows by {v:+.2%} (+-{ref:.2%}) of itself per hour of the log (tyres "
                f"warming?): {fitted}; c_e is reported at the end of each drive")
    if c is Check.DRIVE_DEPARTS:
        why = (f"its windows depart from the others' fit ({v:.1f} against a limit of "
               f"{ref:.1f})" if ref > 0 else
               "without it the others identify more than with it")
        return (f"'{finding.name}' is left out: {why}; calibrate it on its own to see why "
                "(another tyre, a crawl in a tight turn, a slip)")
    return ""


def _reference_and_sensor_text(finding: Finding) -> str:
    """The checks of the reference pose, of the logs and of single sensors, and the departures
    the fit took in, in plain words."""
    sensor = _sensor_text(finding)
    if sensor:
        return sensor
    departure = _departure_text(finding)
    if departure:
        return departure
    c, v, ref = finding.check, finding.value, finding.reference
    if c is Check.CHANGE_IN_LOG:
        parameter, _, where = finding.name.partition("|")
        what = (f"c_e changed by {v:+.2%}" if parameter == "c_e" else
                f"the wheels' circumference difference c_d changed by {v:+.2%} of c_e (one "
                "tyre's pressure?)")
        return (f"{what} at t = {ref:.0f} s of {where}: the calibration is of the part after "
                "the change (the vehicle as it is now; the part before still informs t_r and "
                "d); calibrate the part before on its own if you need it")
    if c is Check.HEADING_ERROR:
        return (f"the reference heading's error varies with the heading by up to "
                f"{np.degrees(v):.1f} degrees against its course on straights (a compass or "
                "magnetometer heading?): taken out before the fit; a GNSS course or a fused "
                "pose is better")
    if c is Check.REFERENCE_SYNC:
        lag = (f"it matches them {abs(v):.0f} s {'later' if v > 0 else 'earlier'}: "
               "the pose stream's clock is off by that much"
               if np.isfinite(v) else "no shift of up to 10 minutes makes them match")
        return (f"the reference pose's speed does not follow the wheels' (correlation "
                f"{ref:+.2f}); {lag}. Align the clocks or give the matching logs")
    if c is Check.REFERENCE_HEADING:
        backing = (" or wheel speeds without a sign on a vehicle backing up (the wheels then "
                   "cannot say it moves backwards)?" if v > np.radians(150.0) else "")
        if ref >= BACKING_SHARE:
            backing = (f" or, as on {ref:.0%} of them the reference moves against its heading "
                       "while the wheels, which never turn backwards, turn forwards: wheel "
                       "speeds without a sign on a vehicle backing up? give them their sign")
        return (f"the reference heading does not point where the reference moves: on straights "
                f"they are {np.degrees(v):.0f} degrees apart (x and y swapped? a compass heading "
                f"in the 'enu' convention? another frame?{backing}); fix the mapping")
    if c is Check.POSE_JUMP:
        where = f" in '{finding.name}'" if finding.name else ""
        return (f"the reference pose jumps by {v:.1f} m at t = {ref:.2f} s{where}, far beyond "
                "what the wheels turn: a relocalisation or a glitch; split the log there (a "
                "'piece' column) or repair the reference")
    if c is Check.VEHICLES_DIFFER:
        first, _, second = finding.name.partition("|")
        return (f"the logs '{first}' and '{second}' disagree on the vehicle: on straights their "
                f"wheels differ by {v:.2%} of their mean more in one than in the other (the "
                f"limit is {ref:.1%}): two vehicles, or wheels changed between them? Calibrate "
                "each vehicle on its own logs")
    if c is Check.INVALID_INPUT:
        return finding.name
    return c.value


def _sensor_text(finding: Finding) -> str:
    """The checks of single sensors (a wheel speed, a_y), in plain words; empty for any
    other finding."""
    c, v, ref = finding.check, finding.value, finding.reference
    if c is Check.WHEEL_DEAD:
        side = {"n_rl": "rear-left", "n_rr": "rear-right"}.get(finding.name, finding.name)
        return (f"the {side} wheel speed ({finding.name}) reads nothing while the other wheel "
                f"turns, in {v:.0%} of the moving seconds: a dead wheel sensor or an unmapped "
                "signal; fix the log or the mapping (nothing is calibrated from it)")
    if c is Check.LATERAL_MISSING:
        return ("a_y carries no lateral acceleration (it is zero or constant while the "
                "vehicle turns: a missing or unplugged sensor?); d is not calibrated and its "
                "uncertainty widens t_r's")
    if c is Check.LATERAL_DELAY:
        way = "lags" if v > 0 else "leads"
        return (f"a_y {way} speed times the reference yaw rate by {abs(v):.2f} s: a "
                "calibration aligns it before the fit (aligning the IMU stream's clock, the "
                "mapping's offset_s, is better)")
    if c is Check.LATERAL_OFFSET:
        tilt = np.degrees(np.arcsin(np.clip(v / 9.81, -1.0, 1.0)))
        return (f"a_y reads {v:+.2f} m/s^2 (+-{ref:.2f}) more than the reference's turning "
                f"gives (a road's crossfall, or an IMU rolled by {abs(tilt):.1f} degrees?): the "
                "parameters are for a_y as logged, and c_d's uncertainty carries what it "
                "would be were the offset the sensor's")
    if c is Check.WHEEL_OFFSET:
        return (f"the wheels read {v:+.3f} and {ref:+.3f} rev/s (rear left, right) while the "
                "reference stands still: an offset of the speed signal, taken out of every "
                "sample before the fit")
    if c is Check.MOVING_OFFSET:
        return (f"the wheels read {v:+.4f} rev/s (+-{ref:.4f}) more than the reference's motion "
                "gives, at every speed (an offset of the speed signal; the drive did not stand "
                "still long enough to measure it at rest): fitted beside c_e, whose standard "
                "deviation carries it; a drive with stops measures it better")
    return ""
