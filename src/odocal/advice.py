"""Identifiability in plain words: what a drive determines, and what more driving would.

The standard deviation of an estimate shrinks about as one over the square root of the data
that informs it. c_e is informed by distance travelled, c_d by heading drift (any driving),
t_r and d by bends (segments whose yaw rate exceeds the selection threshold). For a parameter
that is not identified, or only loosely, the advice scales the informative driving this drive
had to what would bring the standard deviation to the identifiability limit.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from odocal.drive import Drive
from odocal.identify import IdentificationResult
from odocal.model import PARAMETER_LABELS, PARAMETER_NAMES
from odocal.segments import SegmentSet
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


def advise(ident: IdentificationResult, cov: Coverage, settings: Settings
           ) -> list[ParameterAdvice]:
    """One sentence or two per parameter."""
    prior = np.asarray(settings.identify.prior_std)
    limit = settings.identify.identifiable_ratio * prior
    threshold = settings.segments.yaw_rate_threshold_radps
    segment_s = settings.segments.length / settings.convert.rate_hz
    out = []
    for j, name in enumerate(PARAMETER_NAMES):
        label = PARAMETER_LABELS[j]
        what = NEEDS[name]
        amount, have = _amount(what, cov)
        std = float(ident.std[j])
        if ident.identified[j]:
            factor = (std / limit[j]) ** 2 if limit[j] > 0 else 0.0
            text = (f"{label} is identified to +-{_fmt(name, std)} from {have}; the limit for "
                    f"calling it identified is +-{_fmt(name, limit[j])}")
            if factor > 0.25:
                text += (f". It is close to that limit: {_more(what, amount, 4 * factor)} "
                         "would halve the uncertainty")
            out.append(ParameterAdvice(name, label, True, text + "."))
            continue
        reason = ident.reasons.get(name, "")
        if (what == "bends" and cov.bend_s <= 0.0) or "needs bends" in reason:
            text = (f"{label} needs bends: its effect shows only when the vehicle turns, and "
                    f"this drive's yaw rate exceeds {threshold} rad/s for {cov.bend_s:.0f} s. "
                    f"Drive through at least 10 bends or junction turns (each in a "
                    f"{segment_s:.0f} s segment, as the method's batches use) or a few "
                    "roundabouts, then calibrate again.")
        elif "only to +-" in reason:
            got = float(reason.split("only to +-")[1].split(" ")[0]) if "only to +-" in reason \
                else std
            factor = (got / limit[j]) ** 2
            text = (f"{label} is determined only to +-{_fmt(name, got)} by {have}, not better "
                    f"than the datasheet (+-{_fmt(name, prior[j])}): {_more(what, amount, factor)}"
                    f" would identify it (about {factor:.0f} times this drive's).")
        elif "rank-deficient" in reason:
            text = (f"{label} leaves no trace in these segments ({have}). "
                    f"It needs {'bends' if what == 'bends' else 'more varied driving'}.")
        else:
            text = f"{label} is not identified: {reason}."
        out.append(ParameterAdvice(name, label, False, text))
    return out


def _fmt(name: str, value: float) -> str:
    if name == "c_d":
        return f"{value * 1000:.3g} mm"
    if name == "d":
        return f"{value * 1000:.3g} mm per m/s^2"
    return f"{value * 1000:.3g} mm" if value < 0.1 else f"{value:.3g} m"
