"""Drift and change detection over a vehicle's drive estimates.

For each vehicle and parameter, the history is cut into stretches at declared events (a tyre
change restarts the baseline) and at detected changes. Each stretch starts with a **baseline**:
its first ``baseline_drives`` estimates (growing, up to ``baseline_max``, with every later drive
the detector has seen as ordinary), their weighted mean and the drive-to-drive scatter
beyond the estimates' own uncertainty (the DerSimonian-Laird moment estimate, never below
``excess_floor``: loads and temperatures move the parameters a little from drive to drive).

Every later drive is standardised against it,
``z = (x - baseline) / sqrt(std_drive^2 + excess^2 + std_baseline^2)``, clipped to +-``h``, and fed
to a two-sided **CUSUM** with allowance ``k`` and threshold ``h`` (Page 1954): ``S+ = max(0, S+ +
z - k)``, and mirrored. Because one drive adds at most ``h - k``, no single drive (a mis-mapped log
that slipped through the checks, say) raises an alarm: it takes two drives that agree. The change
starts at the drive that best splits the stretch into the baseline and a new level (the
likelihood-ratio change point, Hinkley 1971); the change's size is the weighted mean
of the drives since then minus the baseline, its confidence the normal probability of that
difference given both means' uncertainties.

Whether the change is a **step** (pressure, a tyre swap) or a **trend** (tread wear) is decided
by which fits the stretch better: a level that jumps at the change, or a line against the
odometer (or time, where no odometer is known). After an alarm the stretch restarts at the change.

Parameters not identified by a drive (or drives that failed) are skipped; they never alarm. A
drive the quality gate rejected only because a parameter left its plausible range (the fit went
well: a flat tyre moves c_d out of its range on every drive after it) is **evidence**: its
estimates are used like any other drive's, so the bigger the fault the louder the fleet.

Drives of two vehicles under one name give a stretch whose estimates fall into two **levels**
that alternate in time: no step, no trend, and a baseline that blends both. Such a stretch is
reported as an alarm of kind ``mixed`` (two groups of at least :data:`MIXED_MIN` drives whose
levels lie more than :data:`MIXED_SEPARATION` times the groups' own scatter apart, and that
take turns at least four times), with the two levels and what to check.

Times are ordered as instants (a catalog may mix UTC offsets).
"""

from __future__ import annotations

import datetime as dt
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from odocal.model import registry
from odocal.model.layout import REAR_AXLE, Layout
from odocal.settings import FleetSettings

#: What a change of each parameter (of every model) usually means, and what to do (alarm
#: messages; a parameter not named here: "recalibrate").
CAUSES = {
    "c_e": "tyre pressure or a tyre change; recalibrate",
    "c_d": "one tyre's pressure, or tyres of different wear; check the tyres and recalibrate",
    "t_r": "a changed axle, wheels or tyres; recalibrate",
    "d": "a changed load or suspension; recalibrate",
    "c_f": "the front tyres' pressure or a front tyre change; recalibrate",
    "c_fd": "one front tyre's pressure, or front tyres of different wear; check the tyres and "
            "recalibrate",
    "t_f": "a changed front axle, wheels or tyres, or the wheel alignment; recalibrate",
    "L": "a changed suspension, or wheel signals mapped anew; check the mapping and recalibrate",
    "ratio": "a steering repair or another steering-angle sensor; recalibrate",
    "s_0": "the wheel alignment or the steering-angle sensor's zero changed; recalibrate",
}
#: The circumferences (a change read as a share of the level, with its tread-wear trend).
_SCALES = frozenset({"c_e", "c_f"})
#: Circumference differences, near zero: a change read as a share of their scale's level.
_DIFFERENCES = {"c_d": "c_e", "c_fd": "c_f"}
#: Lengths read in mm.
_LENGTHS = frozenset({"t_r", "t_f", "L"})


@dataclass(frozen=True)
class Point:
    """One drive's estimate of one parameter."""

    index: int                 # position in the vehicle's history
    time: dt.datetime
    value: float
    std: float
    odometer_km: float | None
    distance_km: float
    rejected: bool = False     # the gate rejected the drive for a parameter's range


@dataclass(frozen=True)
class Baseline:
    vehicle: str
    parameter: str
    since: dt.datetime
    value: float
    std: float
    excess_std: float
    drives: int

    def to_row(self) -> dict[str, Any]:
        return {"vehicle": self.vehicle, "parameter": self.parameter,
                "since": self.since.isoformat(), "value": self.value, "std": self.std,
                "excess_std": self.excess_std, "drives": self.drives}


@dataclass(frozen=True)
class Alarm:
    vehicle: str
    parameter: str
    kind: str                  # "step" or "trend"
    time: dt.datetime          # the first drive after the change
    detected_time: dt.datetime
    change: float              # in the parameter's unit
    relative_change: float     # of the baseline value (c_d: of the baseline c_e)
    confidence: float
    drives_to_detect: int
    km_to_detect: float
    message: str

    def to_row(self) -> dict[str, Any]:
        return {"vehicle": self.vehicle, "parameter": self.parameter, "kind": self.kind,
                "time": self.time.isoformat(), "detected_time": self.detected_time.isoformat(),
                "change": self.change, "relative_change": self.relative_change,
                "confidence": self.confidence, "drives_to_detect": self.drives_to_detect,
                "km_to_detect": self.km_to_detect, "message": self.message}


@dataclass(frozen=True)
class Analysis:
    baselines: tuple[Baseline, ...]
    alarms: tuple[Alarm, ...]


def _weighted_mean(x: np.ndarray, var: np.ndarray) -> tuple[float, float]:
    w = 1.0 / var
    return float(np.sum(w * x) / np.sum(w)), float(math.sqrt(1.0 / np.sum(w)))


def excess_scatter(x: np.ndarray, var: np.ndarray) -> float:
    """DerSimonian-Laird estimate of the scatter beyond the estimates' own variances."""
    if len(x) < 2:
        return 0.0
    w = 1.0 / var
    mean = np.sum(w * x) / np.sum(w)
    q = float(np.sum(w * (x - mean) ** 2))
    denom = float(np.sum(w) - np.sum(w**2) / np.sum(w))
    return math.sqrt(max(0.0, (q - (len(x) - 1)) / denom)) if denom > 0 else 0.0


def parse_stamp(text: str) -> dt.datetime:
    """A stored time as an instant (a time without an offset is UTC)."""
    stamp = dt.datetime.fromisoformat(text)
    return stamp if stamp.tzinfo else stamp.replace(tzinfo=dt.UTC)


def _evidence(row: Mapping[str, Any]) -> bool:
    """A drive rejected only for a parameter's range (see the module docstring)."""
    value = row.get("out_of_range")
    if isinstance(value, str):
        import json

        try:
            value = json.loads(value)
        except ValueError:
            return False
    return bool(value)


def points(rows: Sequence[Mapping[str, Any]], parameter: str) -> tuple[list[Point], list[int]]:
    """The usable estimates of one parameter, and the history indices where events reset."""
    out: list[Point] = []
    resets: list[int] = []
    for i, r in enumerate(rows):
        if r.get("event"):
            resets.append(i)
        value, std = r.get(parameter), r.get(f"{parameter}_std")
        evidence = not r.get("success") and _evidence(r)
        if not ((r.get("success") or evidence) and r.get(f"{parameter}_identified")):
            continue
        if value is None or std is None or not (math.isfinite(value) and std > 0):
            continue
        out.append(Point(index=i, time=parse_stamp(r["time"]), value=float(value), std=float(std),
                         odometer_km=r.get("odometer_km"),
                         distance_km=float(r.get("distance_km") or 0.0), rejected=evidence))
    return out, resets


def analyse_vehicle(vehicle: str, rows: Sequence[Mapping[str, Any]],
                    settings: FleetSettings, layout: Layout = REAR_AXLE) -> Analysis:
    """Baselines and alarms of one vehicle (``rows``: its drive rows, in time order), for each
    parameter of the model of ``layout`` (``settings.excess_floor`` in its order)."""
    baselines: list[Baseline] = []
    alarms: list[Alarm] = []
    for j, name in enumerate(layout.names):
        pts, resets = points(rows, name)
        floor = settings.excess_floor[j]
        for stretch in _stretches(pts, resets):
            mixed = _mixed(vehicle, name, stretch, floor, rows)
            b, a = _detect(vehicle, name, stretch, floor, settings, rows)
            baselines += b
            alarms += [mixed] if mixed is not None else a
    return Analysis(tuple(baselines), tuple(alarms))


def _stretches(pts: list[Point], resets: list[int]) -> list[list[Point]]:
    cuts = sorted(set(resets))
    out: list[list[Point]] = []
    current: list[Point] = []
    k = 0
    for p in pts:
        while k < len(cuts) and p.index >= cuts[k]:
            if current:
                out.append(current)
            current = []
            k += 1
        current.append(p)
    if current:
        out.append(current)
    return out


def _baseline(pts: list[Point], floor: float) -> tuple[float, float, float]:
    x = np.array([p.value for p in pts])
    var = np.array([p.std**2 for p in pts])
    excess = max(excess_scatter(x, var), floor)
    m0, se0 = _weighted_mean(x, var + excess**2)
    return m0, se0, excess


def _detect(vehicle: str, name: str, pts: list[Point], floor: float,
            settings: FleetSettings, rows: Sequence[Mapping[str, Any]]
            ) -> tuple[list[Baseline], list[Alarm]]:
    """Baselines and alarms of one stretch; the baseline grows (up to ``baseline_max``) with
    every drive that is not part of the CUSUM's current excursion."""
    baselines: list[Baseline] = []
    alarms: list[Alarm] = []
    start = 0
    nb, k, h = settings.baseline_drives, settings.cusum_k, settings.cusum_h
    while start + nb <= len(pts):
        s_up = s_down = 0.0
        calm = start + nb                    # drives before this are the baseline's
        alarm = None
        m0, se0, excess = _baseline(pts[start:calm], floor)
        for i in range(start + nb, len(pts)):
            m0, se0, excess = _baseline(pts[start:min(calm, start + settings.baseline_max)],
                                        floor)
            p = pts[i]
            z = (p.value - m0) / math.sqrt(p.std**2 + excess**2 + se0**2)
            z = min(max(z, -h), h)
            s_up = max(0.0, s_up + z - k)
            s_down = max(0.0, s_down - z - k)
            if s_up > h or s_down > h:
                first = _change_point(pts, calm, i, m0, excess)
                alarm = _alarm(vehicle, name, pts, start, first, i, m0, se0, excess, rows)
                break
            if s_up == 0.0 and s_down == 0.0:
                calm = i + 1
        used = min(calm, start + settings.baseline_max) - start
        baselines.append(Baseline(vehicle, name, pts[start].time, m0, se0, excess, used))
        if alarm is None:
            break
        alarms.append(alarm[0])
        start = alarm[1]
    return baselines, alarms


def _change_point(pts: list[Point], lo: int, last: int, m0: float, excess: float) -> int:
    """The most likely first drive of a step away from ``m0`` among drives ``lo..last``."""
    x = np.array([p.value for p in pts[lo:last + 1]]) - m0
    w = 1.0 / (np.array([p.std**2 for p in pts[lo:last + 1]]) + excess**2)
    tail_sum = np.cumsum((w * x)[::-1])[::-1]
    tail_w = np.cumsum(w[::-1])[::-1]
    return lo + int(np.argmax(tail_sum**2 / tail_w))


def _alarm(vehicle: str, name: str, pts: list[Point], start: int, first: int, last: int,
           m0: float, se0: float, excess: float, rows: Sequence[Mapping[str, Any]]
           ) -> tuple[Alarm, int]:
    after = pts[first:last + 1]
    x1 = np.array([p.value for p in after])
    var1 = np.array([p.std**2 for p in after]) + excess**2
    m1, se1 = _weighted_mean(x1, var1)
    change = m1 - m0
    z = abs(change) / math.sqrt(se0**2 + se1**2)
    confidence = math.erf(z / math.sqrt(2.0))
    reference = _reference(name, rows, pts[start].time, m0)
    relative = change / abs(reference) if reference else float("nan")
    kind, per_1000 = _kind(pts[start:last + 1], first - start, excess)
    km = sum(p.distance_km for p in after)
    since = pts[first].time.date().isoformat()
    amount = _amount(name, change, relative)
    verb = "fell" if change < 0 else "rose"
    if kind == "trend":
        # (a share of a circumference's own level; a difference's level is near zero, a
        # share of it says nothing)
        rate = (f" ({abs(per_1000) * 100:.2f}% per 1000 km)" if per_1000 is not None
                and name in _SCALES else "")
        message = (f"{name} {verb} {amount} since {since}, gradually{rate}: "
                   f"{'tread wear' if name in _SCALES else 'a slow change'}; recalibrate")
    else:
        message = f"{name} {verb} {amount} since {since}: {CAUSES.get(name, 'recalibrate')}"
    rejected = sum(p.rejected for p in after)
    if rejected:
        message += (f" ({rejected} of the {len(after)} drives since were rejected for an "
                     "implausible parameter: calibrated values are not published for them)")
    return (Alarm(vehicle=vehicle, parameter=name, kind=kind, time=pts[first].time,
                  detected_time=pts[last].time, change=change, relative_change=relative,
                  confidence=confidence, drives_to_detect=last - first + 1, km_to_detect=km,
                  message=message), first)


#: Least drives in each level of a ``mixed`` stretch, and the least distance between the levels
#: in units of their own scatter.
MIXED_MIN = 3
MIXED_SEPARATION = 8.0


def _mixed(vehicle: str, name: str, pts: list[Point], floor: float,
           rows: Sequence[Mapping[str, Any]]) -> Alarm | None:
    """Two levels that take turns within one stretch (two vehicles under one name), or None."""
    n = len(pts)
    if n < 2 * MIXED_MIN:
        return None
    x = np.array([p.value for p in pts])
    var = np.array([p.std**2 for p in pts]) + floor**2
    order = np.argsort(x, kind="stable")
    best: tuple[float, int] | None = None
    for k in range(MIXED_MIN, n - MIXED_MIN + 1):        # low group: order[:k]
        lo, hi = order[:k], order[k:]
        m_lo, _ = _weighted_mean(x[lo], var[lo])
        m_hi, _ = _weighted_mean(x[hi], var[hi])
        rss = float(np.sum((x[lo] - m_lo) ** 2) + np.sum((x[hi] - m_hi) ** 2))
        if best is None or rss < best[0]:
            best = (rss, k)
    assert best is not None
    rss, k = best
    lo, hi = order[:k], order[k:]
    m_lo, se_lo = _weighted_mean(x[lo], var[lo])
    m_hi, se_hi = _weighted_mean(x[hi], var[hi])
    spread = max(math.sqrt(rss / (n - 2)), float(np.sqrt(np.median(var))))
    if (m_hi - m_lo) < MIXED_SEPARATION * spread:
        return None
    labels = np.zeros(n, dtype=int)
    labels[hi] = 1
    turns = int(np.sum(labels[1:] != labels[:-1]))
    if turns < 4:                        # a step (1), or a step and back (2, 3): not a blend
        return None
    change = m_hi - m_lo
    reference = _reference(name, rows, pts[0].time, m_lo)
    relative = change / abs(reference) if reference else float("nan")
    z = change / math.sqrt(se_lo**2 + se_hi**2)
    unit = _amount(name, change, relative)
    message = (f"{name} of the drives named {vehicle} falls into two levels {unit} apart that "
               f"take turns ({len(lo)} drives at {_level(name, m_lo)}, {len(hi)} at "
               f"{_level(name, m_hi)}, since {pts[0].time.date().isoformat()}): two vehicles "
               "under one name, or drives of another vehicle in its catalog rows; check the "
               "catalog (the baseline blends both)")
    return Alarm(vehicle=vehicle, parameter=name, kind="mixed", time=pts[0].time,
                 detected_time=pts[-1].time, change=change, relative_change=relative,
                 confidence=math.erf(z / math.sqrt(2.0)), drives_to_detect=n,
                 km_to_detect=sum(p.distance_km for p in pts), message=message)


def _level(name: str, value: float) -> str:
    if name in _SCALES or name in _LENGTHS:
        return f"{value:.4f} m"
    if name in _DIFFERENCES:
        return f"{value * 1000:.2f} mm"
    return _in_display_unit(name, value)


def _amount(name: str, change: float, relative: float) -> str:
    if name in _SCALES:
        return f"{abs(relative) * 100:.2f}% ({abs(change) * 1000:.2f} mm)"
    if name in _DIFFERENCES:                 # a difference near zero: its share is of c_e
        return (f"{abs(change) * 1000:.2f} mm ({abs(relative) * 100:.2f}% of "
                f"{_DIFFERENCES[name]})")
    if name in _LENGTHS:
        return f"{abs(change) * 1000:.1f} mm"
    return _in_display_unit(name, abs(change))


def _in_display_unit(name: str, value: float) -> str:
    """``value`` of parameter ``name`` in the unit its model shows it in (d in mm per m/s^2,
    the steering's offset in degrees)."""
    for model in registry.names():
        shown = registry.layout(model).display.get(name)
        if shown is not None:
            scale, unit = shown
            return f"{value * scale:.3g} {unit}".rstrip()
    return f"{value:.3g}"


def _reference(name: str, rows: Sequence[Mapping[str, Any]], since: dt.datetime,
               level: float) -> float:
    """What a change of ``name`` is a share of: its own level, a difference's scale's level
    (its own is near zero) in the first successful drive since ``since``."""
    scale = _DIFFERENCES.get(name)
    if scale is None:
        return level
    for r in rows:
        if r.get(scale) and parse_stamp(r["time"]) >= since and r.get("success"):
            return float(r[scale])
    return level


def _kind(pts: list[Point], change_at: int, excess: float) -> tuple[str, float | None]:
    """'step' or 'trend': which explains the stretch better (weighted residuals)."""
    x = np.array([p.value for p in pts])
    w = 1.0 / (np.array([p.std**2 for p in pts]) + excess**2)
    odometer = [p.odometer_km for p in pts]
    has_km = all(o is not None for o in odometer)
    t = (np.array(odometer, dtype=float) if has_km else
         np.array([(p.time - pts[0].time).total_seconds() / 86400.0 for p in pts]))
    if len(pts) < 4 or np.ptp(t) <= 0:
        return "step", None
    level = np.where(np.arange(len(pts)) < change_at, 0.0, 1.0)
    step_rss = _wls_rss(np.column_stack([np.ones(len(pts)), level]), x, w)
    line_design = np.column_stack([np.ones(len(pts)), t])
    line_rss = _wls_rss(line_design, x, w)
    if line_rss >= step_rss:
        return "step", None
    # the rate as a share of the level over the stretch (the line's value at its weighted
    # centre: at odometer 0 km, tens of thousands of km back, the line says nothing)
    sw = np.sqrt(w)
    centre = float(np.sum(w * t) / np.sum(w))
    centred = np.column_stack([np.ones(len(pts)), t - centre])
    level_at, slope = np.linalg.lstsq(centred * sw[:, None], x * sw, rcond=None)[0]
    per_1000 = float(slope * 1000.0 / level_at) if has_km and level_at else None
    return "trend", per_1000


def _wls_rss(design: np.ndarray, x: np.ndarray, w: np.ndarray) -> float:
    sw = np.sqrt(w)
    coef, *_ = np.linalg.lstsq(design * sw[:, None], x * sw, rcond=None)
    return float(np.sum(w * (x - design @ coef) ** 2))


def analyse(rows: Sequence[Mapping[str, Any]], settings: FleetSettings,
            layout: Layout = REAR_AXLE) -> Analysis:
    """Baselines and alarms of every vehicle in ``rows`` (drive rows of a model of
    ``layout``, any order)."""
    by_vehicle: dict[str, list[Mapping[str, Any]]] = {}
    for r in sorted(rows, key=lambda r: (r["vehicle"], parse_stamp(r["time"]), r["task_key"])):
        by_vehicle.setdefault(r["vehicle"], []).append(r)
    baselines: list[Baseline] = []
    alarms: list[Alarm] = []
    for vehicle, history in by_vehicle.items():
        result = analyse_vehicle(vehicle, history, settings, layout)
        baselines += result.baselines
        alarms += result.alarms
    return Analysis(tuple(baselines), tuple(alarms))


def last_change(rows: Sequence[Mapping[str, Any]], alarms: Sequence[Alarm]) -> dt.datetime | None:
    """When the vehicle's current state began: its latest declared event or detected change."""
    times = [parse_stamp(r["time"]) for r in rows if r.get("event")]
    times += [a.time for a in alarms if a.kind != "mixed"]
    return max(times) if times else None
