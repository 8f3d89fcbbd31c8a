"""All of odocal's settings in one typed place, with the paper's defaults.

Every section is a frozen dataclass; :class:`Settings` groups them. A TOML file may set any
subset; unknown sections or keys, wrong types and out-of-range values are :class:`ConfigError`.
The defaults are those of Fazekas, Gáspár and Németh (IFAC 2022) as restated in METHOD.md.

Example ``odocal.toml``::

    [segments]
    length = 650
    yaw_rate_threshold_radps = 0.15

    [compensate]
    state_weights = [1.0, 1.0, 10.0]
"""

from __future__ import annotations

import dataclasses
import math
import tomllib
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from odocal.errors import ConfigError, input_file, shown
from odocal.model import registry
from odocal.model.layout import REAR_AXLE, Layout, ParameterSpec

#: Datasheet parameters of the paper, ``[c_e, c_d, t_r, d]`` (m, m, m, m per m/s^2).
DATASHEET_THETA: tuple[float, ...] = REAR_AXLE.placeholder
#: The names of theta's entries, in its order (``odocal.model.layout`` holds their units).
DATASHEET_NAMES: tuple[str, ...] = REAR_AXLE.names
#: The smallest datasheet uncertainty ``[identify] prior_std`` may state; the largest is each
#: parameter's ``prior_std_max`` in the model's layout (the width of its vehicle range: beyond
#: it no uncertainty of a vehicle, and its square is no number a fit can carry).
PRIOR_STD_MIN = 1e-9


def vehicle_problem(theta: Any, layout: Layout = REAR_AXLE) -> str | None:
    """None if a wheeled vehicle could have ``theta`` (the model's parameters, in its order),
    else what is wrong, in words. The ranges are generous (odocal's robots and trucks alike;
    c_d also less than c_e in size): a datasheet, a settings file's theta0 or a parameter file
    beyond them is a mistake (a unit, a typo), and no computation starts from it."""
    values = [float(v) for v in theta]
    if len(values) != layout.size:
        return f"{len(values)} values where the model has {layout.size}"
    for name, value in zip(layout.names, values, strict=True):
        problem = _out_of_range(name, value, layout)
        if problem is not None:
            return problem
    difference = layout.value(values, layout.difference)
    scale = layout.value(values, layout.scale)
    if abs(difference) >= scale:
        return (f"{layout.difference} = {difference:.6g} m is not smaller than "
                f"{layout.scale} = {scale:.6g} m: a circumference difference beyond the "
                "circumference itself")
    return None


def _named_layout(name: str) -> Layout:
    """The first registered model's layout that has parameter ``name``."""
    return next(registry.layout(m) for m in registry.names() if name in registry.layout(m).names)


def _datasheet_names() -> tuple[str, ...]:
    """Every registered model's parameter names, the rear axle's first."""
    out: list[str] = []
    for m in registry.names():
        out += [n for n in registry.layout(m).names if n not in out]
    return tuple(out)


def _out_of_range(name: str, value: float, layout: Layout | None = None) -> str | None:
    layout = layout or _named_layout(name)
    spec = layout.parameters[layout.index(name)]
    lo, hi = spec.vehicle_range
    if math.isfinite(value) and lo <= value <= hi:
        return None
    unit = "" if spec.unit == "1" else f" {spec.unit}"           # a ratio has no unit
    span = f"{lo:g} to {hi:g}{unit}" if lo > 0 else f"|{name}| up to {hi:g}{unit}"
    return f"{name} = {value:.6g} is not a wheeled vehicle's {spec.label} ({span})"


def datasheet_values(pairs: Any, *, source: str = "--datasheet") -> dict[str, float]:
    """Named datasheet values (``(name, value)`` pairs, as given, or a mapping), checked: names
    among the model's parameters, each given once, finite numbers within the vehicle ranges
    (:func:`vehicle_problem`). A one-line ConfigError names ``source``, the value and the
    valid range."""
    items = list(pairs.items()) if isinstance(pairs, dict) else list(pairs)
    values: dict[str, float] = {}
    known = _datasheet_names()
    for key, value in items:
        if key not in known:
            raise ConfigError(f"{source}: {shown(key)!r} is not one of {', '.join(known)}")
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"{source}: {key} = {shown(repr(value))} is not a number")
        if key in values:
            raise ConfigError(f"{source} gives {key} twice ({values[key]:g} and {value:g}): "
                              "give each value once")
        problem = _out_of_range(key, float(value))
        if problem is not None:
            raise ConfigError(f"{source}: {problem}")
        values[key] = float(value)
    return values


#: The names the localisation stacks give datasheet values (ROS 2's diff_drive_controller and
#: ackermann_steering_controller, Autoware's vehicle_info), by odocal's parameter they state.
STACK_NAMES: dict[str, str] = {"wheel_radius": "c_e", "wheel_separation": "t_r",
                               "wheel_tread": "t_r", "rear_wheels_radius": "c_e",
                               "rear_wheel_track": "t_r", "front_wheels_radius": "c_f",
                               "front_wheel_track": "t_f", "wheel_base": "L", "wheelbase": "L"}
#: The stacks' names that state a radius (the circumference over 2 pi).
RADII = frozenset({"wheel_radius", "rear_wheels_radius", "front_wheels_radius"})
#: A circumference difference beyond this share of the circumference is no pair of tyres of one
#: axle (a space-saver spare differs by about 5%): a c_d given in mm as metres is named.
MAX_DIFFERENCE_SHARE = 0.1


def datasheet_pairs(text: str, *, what: str = "--datasheet") -> list[tuple[str, float]]:
    """``c_e=1.84,t_r=1.52`` (or the stacks' names, ``wheel_radius=0.1,wheel_separation=0.4``)
    as ``(name, value)`` pairs by odocal's names, in the order given (a radius made a
    circumference); a one-line ConfigError naming ``what`` for text that is not such pairs or
    names no parameter. Values are checked by :func:`datasheet_values`."""
    pairs: list[tuple[str, float]] = []
    for item in text.split(","):
        key, sep, value = item.partition("=")
        try:
            pairs.append((key.strip(), float(value)))
        except ValueError:
            sep = ""
        if not sep:
            raise ConfigError(f"{what} {shown(text)!r}: write NAME=VALUE pairs separated by "
                              "commas, e.g. c_e=1.84,t_r=1.52 or "
                              "wheel_radius=0.1,wheel_separation=0.4 (metres)")
    known = _datasheet_names()
    unknown = [k for k, _ in pairs if k not in known and k not in STACK_NAMES]
    if unknown:
        raise ConfigError(f"{what}: {shown(unknown[0])!r} is not one of "
                          f"{', '.join((*known, *STACK_NAMES))}")
    return [(STACK_NAMES.get(k, k), v * 2.0 * math.pi if k in RADII else v) for k, v in pairs]


def parse_datasheet(text: str, *, what: str = "--datasheet") -> dict[str, float]:
    """:func:`datasheet_pairs` checked by :func:`datasheet_values` (each name once, within a
    vehicle's range): the datasheet values by odocal's names."""
    return datasheet_values(datasheet_pairs(text, what=what), source=what)


def datasheet_theta(values: Any, base: Any = (), *, source: str = "datasheet",
                    layout: Layout = REAR_AXLE) -> tuple[float, ...]:
    """theta0 from named datasheet values (c_e, c_d, t_r, d; missing ones from ``base`` or the
    placeholder), or a one-line ConfigError naming ``source``: a vehicle no wheels make
    (:func:`vehicle_problem`), or a circumference difference beyond
    :data:`MAX_DIFFERENCE_SHARE` of the circumference (millimetres given as metres).
    ``layout``: the model's, whose theta ``base`` is (its rear axle's values are given)."""
    theta = [float(v) for v in (base if len(base) else layout.placeholder)]
    given = datasheet_values(values, source=source)
    other = [k for k in given if k not in layout.names]
    if other:
        model = next((m for m in registry.names() if registry.layout(m) is layout), "this")
        owner = next(m for m in registry.names() if other[0] in registry.layout(m).names)
        raise ConfigError(f"{source}: {other[0]} is a parameter of the {owner} model, not of "
                          f"the {model} model this run calibrates (choose the model with "
                          "[vehicle] model in a settings file)")
    for key, value in given.items():
        theta[layout.index(key)] = value
    problem = vehicle_problem(theta, layout)
    if problem is not None:
        raise ConfigError(f"{source}: {problem}")
    difference = REAR_AXLE.value(theta, REAR_AXLE.difference)
    scale = REAR_AXLE.value(theta, REAR_AXLE.scale)
    if REAR_AXLE.difference in given and abs(difference) > MAX_DIFFERENCE_SHARE * scale:
        raise ConfigError(
            f"{source}: {REAR_AXLE.difference} = {difference:g} m is {abs(difference) / scale:.0%} "
            f"of {REAR_AXLE.scale} = {scale:g} m, where two tyres of one axle differ by a few "
            f"millimetres; {REAR_AXLE.difference} is in metres ({difference:g} mm is "
            f"{REAR_AXLE.difference}={difference / 1000:g})")
    return tuple(theta)


def _check(condition: bool, section: str, key: str, value: object, expected: str) -> None:
    if not condition:
        raise ConfigError(f"setting [{section}] {key} = {value!r} is invalid: expected {expected}")


@dataclass(frozen=True)
class SegmentSettings:
    """METHOD 2: how a drive is cut into identification and validation segments."""

    length: int = 650
    """K, samples per identification segment (650 = 16.25 s at 40 Hz)."""
    step: int = 100
    """Samples between the starts of consecutive identification segments (2.5 s)."""
    yaw_rate_threshold_radps: float = 0.15
    """A segment is selected for identification if its peak |yaw rate| exceeds this."""
    min_selected: int = 1
    """With fewer selected segments than this, identification uses every segment (straight
    drives)."""
    validation_distance_m: float = 300.0
    """Travelled distance of each validation segment."""
    validation_offset: int = 50
    """Samples from a piece's start to its first validation segment (other start points than
    the identification segments')."""
    validation_min_fraction: float = 0.5
    """A trailing validation segment shorter than this fraction of the distance is dropped."""

    def __post_init__(self) -> None:
        s = "segments"
        _check(self.length >= 10, s, "length", self.length, "an integer >= 10")
        _check(self.step >= 1, s, "step", self.step, "an integer >= 1")
        _check(self.yaw_rate_threshold_radps >= 0, s, "yaw_rate_threshold_radps",
               self.yaw_rate_threshold_radps, "a number >= 0")
        _check(self.min_selected >= 1, s, "min_selected", self.min_selected, "an integer >= 1")
        _check(1.0 <= self.validation_distance_m <= 1e6, s, "validation_distance_m",
               self.validation_distance_m, "a distance from 1 m to 1000 km")
        _check(self.validation_offset >= 0, s, "validation_offset", self.validation_offset,
               "an integer >= 0")
        _check(0 < self.validation_min_fraction <= 1, s, "validation_min_fraction",
               self.validation_min_fraction, "a fraction in (0, 1]")


@dataclass(frozen=True)
class IdentifySettings:
    """METHOD 3: Gauss-Newton identification."""

    theta0: tuple[float, ...] = DATASHEET_THETA
    """Initial guess [c_e, c_d, t_r, d] (the model's parameters in its order:
    :data:`~odocal.model.layout.REAR_AXLE`): the datasheet values, (13) of the paper."""
    weights: tuple[float, float, float] = (1.0, 1.0, 1600.0)
    """Diagonal of W per sample, [w_px, w_py, w_psi] (the paper's [1, 1, 40^2], section 4.3)."""
    max_iterations: int = 5
    """i_max: at most this many G-N iterations (the paper: 5)."""
    step_tolerance: float = 1e-12
    """Stop when every relative parameter change is below this."""
    prior_std: tuple[float, ...] = REAR_AXLE.prior_std
    """How uncertain the datasheet values are; a parameter whose data standard deviation exceeds
    ``identifiable_ratio`` times this is reported as not identified by the drive."""
    identifiable_ratio: float = 0.5
    judge_identifiability: bool = True
    """Keep parameters the data determine too loosely at their initial values (and name them).
    Off, every parameter with full-rank normal equations is estimated, however loosely."""
    rcond: float = 1e-9
    """Relative singular value below which the scaled normal equations count as rank deficient."""

    def datasheet(self, name: str) -> float:
        """The datasheet value (``theta0``) of the parameter ``name``."""
        return REAR_AXLE.value(self.theta0, name)

    def __post_init__(self) -> None:
        s = "identify"                   # theta0 and prior_std: by the model (Settings)
        _check(all(w >= 0 for w in self.weights) and any(w > 0 for w in self.weights), s,
               "weights", self.weights, "non-negative weights, not all zero")
        _check(self.max_iterations >= 1, s, "max_iterations", self.max_iterations,
               "an integer >= 1")
        _check(self.step_tolerance >= 0, s, "step_tolerance", self.step_tolerance, "a number >= 0")
        _check(0 < self.identifiable_ratio <= 1, s, "identifiable_ratio",
               self.identifiable_ratio, "a fraction in (0, 1]")
        _check(0 < self.rcond < 1, s, "rcond", self.rcond, "a number in (0, 1)")


@dataclass(frozen=True)
class CompensateSettings:
    """METHOD 4: input compensation by optimal control (the QP)."""

    state_weights: tuple[float, float, float] = (1.0, 1.0, 10.0)
    """Q = diag(...), weight of the pose tracking error [px, py, psi], (14) of the paper."""
    rate_change_weights: tuple[float, float] = (1000.0, 1000.0)
    """R = diag(...), weight of the change of the estimated rates between samples, (14)."""
    state_bounds: tuple[float, float, float] = (5.0, 5.0, 0.5)
    """|x_k - y~_k| <= these (m, m, rad): the state bounds of (11)."""
    rate_bound: float = 0.05
    """(1 - b) n~_k <= n_k <= (1 + b) n~_k for both wheels: the input bounds of (11)."""
    linearisations: int = 1
    """How many times the model is linearised and the QP solved (1 = the paper; more
    re-linearise around the trajectory of the previous solution)."""
    solver: Literal["structured", "osqp"] = "structured"
    """``structured``: odocal's banded active-set solver; ``osqp``: the sparse reference."""
    max_active_set_iterations: int = 50
    """Iterations of the structured solver before it hands the problem to OSQP."""

    def __post_init__(self) -> None:
        s = "compensate"
        _check(all(q >= 0 for q in self.state_weights) and any(self.state_weights), s,
               "state_weights", self.state_weights, "non-negative weights, not all zero")
        _check(all(r > 0 for r in self.rate_change_weights), s, "rate_change_weights",
               self.rate_change_weights, "positive weights")
        _check(all(b > 0 for b in self.state_bounds), s, "state_bounds", self.state_bounds,
               "positive bounds (m, m, rad)")
        _check(0 < self.rate_bound < 1, s, "rate_bound", self.rate_bound, "a fraction in (0, 1)")
        _check(self.linearisations >= 1, s, "linearisations", self.linearisations,
               "an integer >= 1")
        _check(self.solver in ("structured", "osqp"), s, "solver", self.solver,
               "'structured' or 'osqp'")
        _check(self.max_active_set_iterations >= 1, s, "max_active_set_iterations",
               self.max_active_set_iterations, "an integer >= 1")


@dataclass(frozen=True)
class CalibrateSettings:
    """METHOD 5: the three-step architecture, and what every calibration shares.

    The method itself is chosen per calibration (``odocal calibrate --method``, or
    ``odocal.calibrate(method=...)``), not here."""

    step1_batches: int = 50
    """Independent batches identified in step 1 (the paper: 50)."""
    step1_batch_size: int = 10
    """N of each step-1 batch (the paper: 10)."""
    step1_sets: int = 5
    """Parameter sets picked at equal steps through the sorted step-1 list (the paper: 5)."""
    step3_batch_size: int = 5
    """N of the per-batch step-3 experiment of ``odocal reproduce`` (the paper: 5)."""
    seed: int = 0
    """Seed of the batch draw (and every other random choice of a calibration)."""
    workers: int = 0
    """Processes for per-segment work; 0 uses every core. Results do not depend on it."""

    def __post_init__(self) -> None:
        s = "calibrate"
        for key in ("step1_batches", "step1_batch_size", "step1_sets", "step3_batch_size"):
            _check(getattr(self, key) >= 1, s, key, getattr(self, key), "an integer >= 1")
        _check(self.workers >= 0, s, "workers", self.workers, "an integer >= 0 (0 = all cores)")
        _check(0 <= self.seed < 2**63, s, "seed", self.seed, "an integer from 0 to 2**63 - 1")


@dataclass(frozen=True)
class MinimumSettings:
    """METHOD 6: the search for the reachable minimum validation error."""

    half_width: tuple[float, ...] = (0.10, 0.02, 0.30, 0.01)
    """The search box is theta_start +- these (m, m, m, m per m/s^2)."""
    max_generations: int = 200
    population: int = 15
    """Population size multiplier of differential evolution."""
    tolerance: float = 1e-7

    def __post_init__(self) -> None:
        s = "minimum"
        _check(all(h > 0 for h in self.half_width), s, "half_width", self.half_width,
               "positive half-widths, one per parameter")
        _check(self.max_generations >= 1, s, "max_generations", self.max_generations,
               "an integer >= 1")
        _check(4 <= self.population <= 1000, s, "population", self.population,
               "an integer from 4 to 1000")
        _check(self.max_generations <= 100_000, s, "max_generations", self.max_generations,
               "an integer up to 100000")
        _check(self.tolerance > 0, s, "tolerance", self.tolerance, "a positive number")


@dataclass(frozen=True)
class InverseSettings:
    """The default method (``inverse``): the wheel revolutions the reference motion implies,
    fitted to the measured ones over short windows."""

    window_s: float = 2.0
    """Length of the windows the revolutions are summed over. Longer windows make the
    reference's own errors smaller against the motion (use 5-10 s with a plain GNSS reference);
    shorter ones keep more of the lateral-acceleration detail."""
    delay: Literal["estimate", "off"] = "estimate"
    """Find the wheel stream's lag behind the reference and apply it."""
    max_delay_s: float = 1.0
    """Search range of that lag (either sign): a localisation stack's latency, or two loggers'
    clocks apart, by up to a second are found and taken out. A calibration first aligns the
    reference to the wheels' clock by cross-correlation (where it is further off than half of
    ``lag_scan_s``), then the fit scans ``lag_scan_s`` either way."""
    lag_scan_s: float = 0.4
    """How far the fit's own lag scan reaches either way around that alignment (every piece of
    a drive loses this much, and two steps, at either end: a whole second would take a tenth of
    a 20 s log)."""
    heading_offset: Literal["estimate", "off"] = "estimate"
    """Find a constant rotation of the reference heading against the direction of travel (a
    mounting yaw) on straight stretches and apply it."""
    common_wheel_error: Literal["estimate", "off"] = "estimate"
    """Find the share of the distance channel's errors that shows in the yaw channel (a slip
    common to both wheels is a yaw error in bends) and take it out where it stands out."""
    wheel_offset: Literal["encoded", "always", "off"] = "encoded"
    """Fit a constant offset of both wheel rates while moving: ``encoded`` where the rates lie
    on an encoding's grid (whole rpm, 0.1 km/h: truncated towards zero they read half a step
    low; rounded, not), with a prior of half the step; ``always``, with the prior
    ``wheel_offset_prior_revps``. An offset and c_e differ only in how they grow with speed, so
    fitting one costs c_e precision on a drive at few speeds: not done on rates that cannot be
    truncated."""
    wheel_offset_prior_revps: float = 0.02
    """The offset's prior standard deviation with ``wheel_offset = "always"`` (rev/s)."""
    max_iterations: int = 10
    tolerance: float = 1e-10
    """Stop when every relative parameter change is below this."""

    def __post_init__(self) -> None:
        s = "inverse"
        _check(0 < self.window_s <= 60, s, "window_s", self.window_s, "a time in (0, 60] s")
        _check(self.delay in ("estimate", "off"), s, "delay", self.delay, "'estimate' or 'off'")
        _check(0 < self.max_delay_s <= 2, s, "max_delay_s", self.max_delay_s,
               "a time in (0, 2] s")
        _check(0 < self.lag_scan_s <= self.max_delay_s, s, "lag_scan_s", self.lag_scan_s,
               "a time in (0, max_delay_s] s")
        _check(self.heading_offset in ("estimate", "off"), s, "heading_offset",
               self.heading_offset, "'estimate' or 'off'")
        _check(self.common_wheel_error in ("estimate", "off"), s, "common_wheel_error",
               self.common_wheel_error, "'estimate' or 'off'")
        _check(self.wheel_offset in ("encoded", "always", "off"), s, "wheel_offset",
               self.wheel_offset, "'encoded', 'always' or 'off'")
        _check(0 < self.wheel_offset_prior_revps <= 10, s, "wheel_offset_prior_revps",
               self.wheel_offset_prior_revps, "a rate in (0, 10] rev/s")
        _check(self.max_iterations >= 1, s, "max_iterations", self.max_iterations,
               "an integer >= 1")
        _check(self.tolerance >= 0, s, "tolerance", self.tolerance, "a number >= 0")


@dataclass(frozen=True)
class ReferenceSettings:
    """Where the reference pose is on the vehicle (``--reference-offset``)."""

    offset_m: tuple[float, float] | None = None
    """The reference point's offset from the rear axle's midpoint, forward and left (m): a GNSS
    antenna on the roof, an INS reporting at its IMU, a camera on the windscreen. Unset, odocal
    estimates it where the drive's bends show it (and says so), and takes it as zero where they
    do not."""

    def __post_init__(self) -> None:
        if self.offset_m is not None:
            _check(len(self.offset_m) == 2 and all(abs(v) <= 20.0 for v in self.offset_m),
                   "reference", "offset_m", self.offset_m,
                   "two lengths (forward, left) within 20 m of the rear axle")


@dataclass(frozen=True)
class OnlineSettings:
    """The online calibrator (``odocal replay``, ``odocal.OnlineCalibrator``)."""

    max_windows: int = 600
    """Windows kept in memory for exact relinearisation (600 windows of 2 s: 20 minutes);
    older ones are folded into the normal equations."""
    forgetting_s: float | None = None
    """Time constant with which older evidence fades (unset: none; the online estimate then
    agrees with the batch one at the end of a drive)."""
    warmup_clusters: int = 10
    """Clusters (of a segment's length) the estimate takes in before the change detector
    watches (after a start or a detected change)."""
    cusum_k: float = 0.75
    """The change detector's allowance, in standard deviations of one cluster's estimate."""
    cusum_h: float = 8.0
    """The change detector's threshold (larger: fewer false alarms, later detection)."""
    chunk_s: float = 1.0
    """Samples per push when ``odocal replay`` streams a log."""
    update_s: float = 30.0
    """How often ``odocal replay`` asks for the estimate (a row of trace.csv)."""

    def __post_init__(self) -> None:
        s = "online"
        _check(self.max_windows >= 30, s, "max_windows", self.max_windows, "an integer >= 30")
        _check(self.warmup_clusters >= 2, s, "warmup_clusters", self.warmup_clusters,
               "an integer >= 2")
        _check(self.forgetting_s is None or 0 < self.forgetting_s < float("inf"), s,
               "forgetting_s", self.forgetting_s, "a positive time in s (or unset)")
        for key in ("cusum_k", "cusum_h", "chunk_s", "update_s"):
            _check(0 < getattr(self, key) < float("inf"), s, key, getattr(self, key),
                   "a positive finite number")


@dataclass(frozen=True)
class FleetSettings:
    """``odocal fleet``: the pooled calibrations and the drift detector (see
    :mod:`odocal.fleet.drift`). Changing them reruns no drive."""

    pooled_drives: int = 5
    """Drives in each vehicle's pooled calibration (its latest, since its last change)."""
    baseline_drives: int = 4
    """Drives that form a baseline (after the start, a declared event or an alarm)."""
    baseline_max: int = 20
    """The baseline grows with ordinary drives up to this many."""
    cusum_k: float = 1.0
    """The detector's allowance, in standard deviations of one drive's estimate."""
    cusum_h: float = 4.0
    """The detector's threshold; one drive adds at most this much, so no single drive alarms."""
    excess_floor: tuple[float, ...] = (0.0002, 0.0002, 0.002, 0.0001)
    """Least drive-to-drive scatter assumed beyond each estimate's own uncertainty (c_e, c_d,
    t_r in m; d in m per m/s^2): loads and temperatures change a little from drive to drive."""

    def __post_init__(self) -> None:
        s = "fleet"
        _check(self.pooled_drives >= 1, s, "pooled_drives", self.pooled_drives,
               "an integer >= 1")
        _check(self.baseline_drives >= 2, s, "baseline_drives", self.baseline_drives,
               "an integer >= 2")
        _check(self.baseline_max >= self.baseline_drives, s, "baseline_max", self.baseline_max,
               "an integer >= baseline_drives")
        for key in ("cusum_k", "cusum_h"):
            _check(0 < getattr(self, key) < float("inf"), s, key, getattr(self, key),
                   "a positive finite number")
        _check(all(0 <= v < 1 for v in self.excess_floor), s, "excess_floor",
               self.excess_floor, "numbers in [0, 1), one per parameter")


@dataclass(frozen=True)
class GateSettings:
    """The checks of the data against the model and the quality gate (docs/checks.md, "When odocal
    refuses"). A calibration outside these limits fails (exit 3) with the reason."""

    c_e_m: tuple[float, float] | None = None
    """Plausible range of the effective wheel circumference, m (default: the datasheet c_e
    divided and multiplied by ``range_factor``)."""
    t_r_m: tuple[float, float] | None = None
    """Plausible range of the rear track width, m (default: from the datasheet t_r, as c_e's)."""
    range_factor: float = 2.0
    """Without ``c_e_m`` / ``t_r_m``: c_e and t_r within this factor of the datasheet values."""
    max_abs_c_d_fraction: float = 0.02
    """|c_d| at most this fraction of c_e."""
    max_abs_d: float = 0.02
    """|d| at most this, m per m/s^2."""
    worse_tolerance: float = 0.02
    """A calibrated E_p more than this fraction above the datasheet values' fails."""
    max_error_share: float = 0.05
    """A calibrated E_p above this share of the validation distance fails (the model does not
    describe the data)."""
    min_distance_m: float = 5.0
    """Less wheel travel than this: the vehicle does not move, nothing to calibrate."""
    min_speed_mps: float = 2.0
    """Windows slower than this are left out of the scale check."""
    min_scale: float = 0.4
    max_scale: float = 2.5
    """Distance the wheels imply (datasheet c_e) over the reference's outside [min, max]: a unit
    or scale mistake (rpm, radius for circumference, km/h)."""
    datasheet_scale_note: float = 0.1
    """Within the range but further than this from 1: a note that theta0 may not fit the car."""
    bend_yaw_rate_radps: float = 0.1
    """One-second windows turning faster than this count as bends for the wheel checks."""
    min_bend_windows: int = 10
    """Fewer bend windows than this: the wheels' differential signal is not checked."""
    min_yaw_correlation: float = 0.5
    """Correlation of the wheels' and the reference's yaw in bends: below minus this the wheels
    are swapped, below this they carry no differential information."""
    max_clock_offset_s: float = 1.0
    """A lag between the wheel and pose streams beyond this fails (align the clocks); so does
    one beyond the lag the calibration corrects (``[inverse] max_delay_s``)."""

    def __post_init__(self) -> None:
        s = "gate"
        for key in ("c_e_m", "t_r_m"):
            if getattr(self, key) is None:
                continue
            lo, hi = getattr(self, key)
            _check(0 < lo < hi, s, key, getattr(self, key), "[low, high] with 0 < low < high")
        _check(1 < self.range_factor < 1e3, s, "range_factor", self.range_factor,
               "a number in (1, 1000)")
        for key in ("max_abs_c_d_fraction", "max_abs_d", "worse_tolerance", "max_error_share",
                    "min_distance_m", "min_speed_mps", "datasheet_scale_note",
                    "bend_yaw_rate_radps", "max_clock_offset_s"):
            _check(0 < getattr(self, key) < float("inf"), s, key, getattr(self, key),
                   "a positive finite number")
        _check(0 < self.min_scale < 1 < self.max_scale < float("inf"), s, "min_scale/max_scale",
               (self.min_scale, self.max_scale), "0 < min_scale < 1 < max_scale")
        _check(self.min_bend_windows >= 1, s, "min_bend_windows", self.min_bend_windows,
               "an integer >= 1")
        _check(0 < self.min_yaw_correlation < 1, s, "min_yaw_correlation",
               self.min_yaw_correlation, "a number in (0, 1)")


@dataclass(frozen=True)
class ChecksSettings:
    """Every other threshold of the checks (``odocal/checks/``), each with its reason.

    The checks compare one-second windows of the drives, so a count of seconds is a count of
    windows. The keys go in the order the checks run, grouped by prefix: the reference pose
    (``pose_jump_``, ``straight_``, ``heading_``, ``sync_``), the wheels (``dead_wheel_``,
    ``scale_``), a_y (``lateral_``), several drives (``vehicles_``), the streams' clocks
    (``lag_``, ``wheel_lag_``, ``lateral_lag_``, ``lateral_delay_``); then the departures
    measured and taken out before the fit (``heading_harmonic_``, ``standstill_``,
    ``encoding_``, with ``error_correlation_s``) and where the one fit seeks a change
    (``change_``). The first checks' limits stay in
    ``[gate]``, where they were: ``min_distance_m``, ``min_speed_mps`` (the moving seconds
    every check here means), ``min_scale``/``max_scale``, ``datasheet_scale_note``,
    ``bend_yaw_rate_radps``, ``min_bend_windows``, ``min_yaw_correlation`` and
    ``max_clock_offset_s``."""

    # the reference pose
    pose_jump_m: float = 5.0
    """A reference step this long (m), beyond what the wheels allow it, is a jump (a
    relocalisation, a glitch): refused, named with its size and time."""
    pose_jump_m_per_rev: float = 2.5
    """What the wheels allow a reference step: this many metres per revolution they turn in it
    (generous for a car's 2 m wheel; it is not scaled by the datasheet c_e)."""
    straight_speed_mps: float = 3.0
    """Straight seconds move faster than this (m/s) ..."""
    straight_turn_rad: float = 0.05
    """... and turn less than this (rad over the second). On them the reference heading is
    compared with its course (here, and for a heading error that varies with the heading)."""
    heading_min_seconds: int = 10
    """Fewer straight seconds than this: the reference heading is not checked."""
    heading_max_gap_rad: float = 0.5
    """A median gap this large (rad) between the reference heading and its course on straights:
    the heading is in another frame (x and y swapped, a compass heading); refused."""
    sync_min_correlation: float = 0.5
    """Below this correlation of the wheels' and the reference's speed, second by second, the
    reference is out of step with the wheels (by more than the clock check reaches, or another
    drive's); refused."""
    sync_min_speed_spread_mps: float = 0.5
    """... judged only where both speeds vary by at least this much (m/s, their standard
    deviation over the seconds): at one speed there is nothing to correlate."""
    sync_min_seconds: int = 30
    """... on at least this many seconds; a lag is tried only with this many seconds of the same
    piece overlapping."""
    sync_max_search_s: float = 600.0
    """The lag that puts such a reference back in step is searched this far either way (s) ..."""
    sync_lag_min_correlation: float = 0.8
    """... and named only where it restores this correlation (else the lag is unknown)."""

    # the wheels
    dead_wheel_share: float = 0.2
    """One wheel reading nothing while the other turns on more than this share of those
    seconds is a dead sensor; refused."""
    dead_wheel_reading: float = 0.01
    """'Nothing': less than this share of the other wheel's revolutions in the second."""
    dead_wheel_turning_revs: float = 0.1
    """'The other turns': more than this many revolutions in a moving second."""
    dead_wheel_min_seconds: int = 5
    """Fewer moving seconds with the other wheel turning than this: no wheel is judged dead."""
    scale_min_seconds: int = 5
    """The wheels' distance over the reference's is the median over the moving seconds where
    there are this many, else the ratio of the totals (checked against ``[gate] min_scale``,
    ``max_scale``)."""

    # the lateral acceleration, in bends
    lateral_min_share: float = 0.1
    """a_y's size about zero, or its spread, below this share of speed times yaw rate's: no
    lateral acceleration (zero, constant, unplugged); d is not fitted."""
    lateral_min_vw_spread_mps2: float = 0.3
    """a_y's spread is judged only where speed times yaw rate varies by more than this (m/s^2,
    standard deviation over the bends): a circle at one rate has no spread to compare."""
    lateral_min_correlation: float = 0.5
    """a_y's agreement with speed times yaw rate (their correlation about zero) below minus
    this: its sign is flipped; refused. Above this, its slope is judged."""
    lateral_min_slope: float = 0.5
    """a_y over speed times yaw rate below this ..."""
    lateral_max_slope: float = 2.0
    """... or above this is a unit mistake (g for m/s^2); refused."""

    # several drives of one vehicle
    vehicles_max_turn_rad: float = 0.1
    """Seconds that compare the wheels of several drives turn less than this (rad) ..."""
    vehicles_min_wheel_revs: float = 0.5
    """... with each wheel turning more than this many revolutions."""
    vehicles_min_seconds: int = 8
    """A drive with fewer such seconds is not compared."""
    vehicles_max_ratio_gap: float = 0.005
    """Two drives whose wheels differ (their difference over their mean, less what the turning
    explains: about -c_d/c_e) by more than this ..."""
    vehicles_sigmas: float = 5.0
    """... and more than this many standard errors of that difference are not one vehicle (two
    cars, wheels swapped or re-tyred between the logs); refused: one calibration would average
    them."""

    # the streams' clocks
    lag_min_piece_s: float = 10.0
    """Pieces at least this long (s) are cross-correlated for a stream's clock (the wheels' yaw
    rate, a_y) against the reference's (a 20 s scene of a public dataset holds one)."""
    lag_min_correlation: float = 0.5
    """A lag is taken only where the correlation at it reaches this (a signal that hardly
    varies, a circle at one rate, has no timing to find)."""
    wheel_lag_search_s: float = 2.0
    """The wheel stream's lag behind the reference is searched this far either way (s); a lag
    beyond what the calibration corrects is refused (``[gate] max_clock_offset_s``)."""
    lateral_lag_search_s: float = 2.0
    """a_y's lag behind the reference is searched this far either way (s), and taken out."""
    lateral_delay_named_s: float = 0.25
    """a_y's lag beyond this (s) is named."""

    # departures measured and taken out before the fit
    error_correlation_s: int = 30
    """Neighbouring seconds share their errors (a reference's drift, a slip that lasts): the
    standard errors of the heading harmonics are taken from groups of this many seconds."""
    heading_harmonic_min_seconds: int = 60
    """A heading error varying with the heading is fitted on at least this many straight
    seconds ..."""
    heading_harmonic_min_coverage: float = 0.15
    """... spread over the headings: the smallest singular value of the harmonics' regressors
    (over the square root of their count) at least this, or they cannot be told apart ..."""
    heading_harmonic_sigmas: float = 4.0
    """... taken out where a harmonic is this many standard errors from zero ..."""
    heading_harmonic_min_rad: float = math.radians(0.5)
    """... and the error is at least this large (rad, 0.5 degree); then also named."""
    standstill_speed_mps: float = 0.05
    """The reference stands still: it moves less than this (m) in a second ..."""
    standstill_min_seconds: int = 10
    """... for this many seconds in all: then what the wheels read is measured ..."""
    standstill_min_offset_revps: float = 0.005
    """... and taken out as their offset from this size on (rev/s, both wheels) ..."""
    standstill_min_share: float = 0.8
    """... where they read it with one sign on at least this share of the still seconds."""
    encoding_max_step_revps: float = 0.05
    """Wheel rates whose nonzero values lie on a grid no coarser than this (rev/s) are an
    encoding's steps (whole rpm, 0.1 km/h; a truncation reads half a step low, so the default
    method fits an offset); coarser grids are tick counts over a sample, whose errors
    telescope."""
    encoding_min_samples: int = 100
    """The grid is looked for on at least this many nonzero rates ..."""
    encoding_samples_per_value: int = 5
    """... that repeat: at least this many rates per distinct value ..."""
    encoding_min_values: int = 3
    """... with at least this many distinct values ..."""
    encoding_grid_tolerance: float = 1e-3
    """... a rate lying on the grid within this share of a step ..."""
    encoding_min_on_grid: float = 0.99
    """... and more than this share of the distinct values on it."""

    # the one fit's departures (the default method)
    change_min_side_clusters: int = 4
    """A change inside the log is sought only with at least this many clusters on either side
    (:mod:`odocal.estimators.departures`) ..."""
    change_min: float = 0.003
    """... and fitted only where it is at least this share of c_e (in c_e, or in c_d: a tyre's
    pressure or a tyre change; smaller steps between a log's parts are what a reference's slow
    errors and the tyres' warming make of them)."""

    def __post_init__(self) -> None:
        s = "checks"
        positive = ("pose_jump_m", "pose_jump_m_per_rev", "straight_speed_mps",
                    "sync_min_speed_spread_mps", "sync_max_search_s", "dead_wheel_turning_revs",
                    "lateral_min_vw_spread_mps2", "vehicles_min_wheel_revs",
                    "vehicles_max_ratio_gap", "vehicles_sigmas", "lag_min_piece_s",
                    "wheel_lag_search_s", "lateral_lag_search_s", "lateral_delay_named_s",
                    "heading_harmonic_sigmas", "standstill_speed_mps",
                    "standstill_min_offset_revps", "encoding_max_step_revps", "change_min")
        for key in positive:
            _check(0 < getattr(self, key) < float("inf"), s, key, getattr(self, key),
                   "a positive finite number")
        angles = ("straight_turn_rad", "heading_max_gap_rad", "vehicles_max_turn_rad",
                  "heading_harmonic_min_rad")
        for key in angles:
            _check(0 < getattr(self, key) < math.pi, s, key, getattr(self, key),
                   "an angle in (0, pi) rad")
        fractions = ("sync_min_correlation", "dead_wheel_share", "dead_wheel_reading",
                     "lateral_min_share", "lateral_min_correlation", "lag_min_correlation",
                     "heading_harmonic_min_coverage", "encoding_grid_tolerance")
        for key in fractions:
            _check(0 < getattr(self, key) < 1, s, key, getattr(self, key), "a number in (0, 1)")
        for key in ("sync_lag_min_correlation", "standstill_min_share", "encoding_min_on_grid"):
            _check(0 < getattr(self, key) <= 1, s, key, getattr(self, key), "a number in (0, 1]")
        _check(0 < self.lateral_min_slope < 1 < self.lateral_max_slope < float("inf"), s,
               "lateral_min_slope/lateral_max_slope",
               (self.lateral_min_slope, self.lateral_max_slope),
               "0 < lateral_min_slope < 1 < lateral_max_slope")
        counts = {"heading_min_seconds": 1, "sync_min_seconds": 3, "dead_wheel_min_seconds": 1,
                  "scale_min_seconds": 1, "vehicles_min_seconds": 1, "error_correlation_s": 1,
                  "heading_harmonic_min_seconds": 5,
                  "standstill_min_seconds": 1, "encoding_min_samples": 2,
                  "encoding_samples_per_value": 1, "encoding_min_values": 2,
                  "change_min_side_clusters": 1}
        for key, least in counts.items():
            _check(least <= getattr(self, key) <= 10**9, s, key, getattr(self, key),
                   f"an integer from {least} to 10**9")


@dataclass(frozen=True)
class UncertaintySettings:
    """How sure a calibration is: the bootstrap over segments that checks the covariance."""

    bootstrap_count: int = 200
    """Resamples (0 turns the bootstrap off)."""
    bootstrap_mode: Literal["one-step", "full"] = "one-step"
    """``one-step``: one Gauss-Newton step from the estimate per resample (fast);
    ``full``: the identification rerun on every resample (slow, includes the nonlinearity)."""
    disagreement_factor: float = 2.0
    """Bootstrap and covariance standard deviations further apart than this factor disagree."""

    def __post_init__(self) -> None:
        s = "uncertainty"
        _check(0 <= self.bootstrap_count <= 100_000, s, "bootstrap_count", self.bootstrap_count,
               "an integer from 0 to 100000")
        _check(self.bootstrap_mode in ("one-step", "full"), s, "bootstrap_mode",
               self.bootstrap_mode, "'one-step' or 'full'")
        _check(self.disagreement_factor > 1, s, "disagreement_factor", self.disagreement_factor,
               "a factor > 1")


@dataclass(frozen=True)
class ConvertSettings:
    """METHOD 7: turning raw logs into the drive format (alignment and resampling)."""

    rate_hz: float = 40.0
    """Rate of the common grid every stream is resampled to (the paper's 40 Hz)."""
    max_gap_s: float = 0.5
    """A stream gap longer than this (or 2.5 of its own sample periods) splits the drive."""
    max_gnss_gap_s: float = 5.0
    """GNSS outages up to this long are bridged by the fusion (its uncertainty grows)."""
    min_piece_s: float = 5.0
    """Pieces shorter than this after splitting are dropped."""
    wheel_offset: Literal["estimate", "off"] = "estimate"
    """Estimate the wheel stream's clock offset against the IMU yaw rate."""
    max_wheel_offset_s: float = 0.5
    """Search range of that estimate."""
    wheel_circumference_m: float | None = None
    """Nominal circumference for wheel speeds given in m/s or km/h (default: the datasheet c_e)."""
    reference: Literal["auto", "fused", "gnss-imu"] = "auto"
    """``fused``: a fused pose stream of the log; ``gnss-imu``: odocal's own GNSS/IMU fusion;
    ``auto``: the fused pose when there is one."""

    def __post_init__(self) -> None:
        s = "convert"
        _check(10.0 <= self.rate_hz <= 1000.0, s, "rate_hz", self.rate_hz,
               "a rate in [10, 1000] Hz (a drive's: the model holds the wheel rates over a step)")
        _check(self.max_gap_s > 0, s, "max_gap_s", self.max_gap_s, "a positive time in s")
        _check(self.max_gnss_gap_s > 0, s, "max_gnss_gap_s", self.max_gnss_gap_s,
               "a positive time in s")
        _check(self.min_piece_s >= 0, s, "min_piece_s", self.min_piece_s, "a time >= 0 s")
        _check(self.wheel_offset in ("estimate", "off"), s, "wheel_offset", self.wheel_offset,
               "'estimate' or 'off'")
        _check(self.max_wheel_offset_s > 0, s, "max_wheel_offset_s", self.max_wheel_offset_s,
               "a positive time in s")
        _check(self.wheel_circumference_m is None or self.wheel_circumference_m > 0, s,
               "wheel_circumference_m", self.wheel_circumference_m, "a positive length in m")
        _check(self.reference in ("auto", "fused", "gnss-imu"), s, "reference", self.reference,
               "'auto', 'fused' or 'gnss-imu'")


@dataclass(frozen=True)
class FusionSettings:
    """METHOD 7: the reference-pose Kalman filter and RTS smoother over GNSS and IMU."""

    gnss_position_std_m: float = 1.5
    """Position noise when the receiver reports no accuracy."""
    gnss_speed_std_mps: float = 0.3
    gnss_course_std_rad: float = 0.03
    heading_std_rad: float = 0.02
    gyro_noise_radps: float = 0.01
    """Yaw-rate noise density, rad/s per sqrt(Hz)."""
    gyro_bias_walk_radps: float = 1e-4
    """Gyro bias random walk, rad/s per sqrt(s)."""
    accel_noise_mps2: float = 1.0
    """Speed random walk (unmodelled acceleration), m/s^2 per sqrt(Hz)."""
    position_noise_m: float = 0.05
    """Position process noise (unmodelled sideslip), m per sqrt(s)."""
    min_course_speed_mps: float = 3.0
    """Below this speed the GNSS course is ignored."""
    outlier_chi2: float = 16.0
    """A measurement whose normalised innovation squared per dimension exceeds this is rejected."""

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            _check(value > 0, "fusion", f.name, value, "a positive number")


@dataclass(frozen=True)
class SideslipSettings:
    """METHOD 7: sideslip from course over ground versus heading, in bends."""

    mode: Literal["auto", "on", "off"] = "auto"
    """``auto``: estimate it when the log has a course independent of the heading."""
    bend_yaw_rate_radps: float = 0.1
    """Samples with a larger yaw rate (and enough speed) are in a bend; elsewhere beta = 0."""
    min_speed_mps: float = 3.0
    smoothing_s: float = 1.0
    """Moving-average window of the estimate."""
    max_abs_rad: float = 0.2
    """Estimates beyond this are treated as course errors and set to 0."""

    def __post_init__(self) -> None:
        s = "sideslip"
        _check(self.mode in ("auto", "on", "off"), s, "mode", self.mode, "'auto', 'on' or 'off'")
        for key in ("bend_yaw_rate_radps", "min_speed_mps", "smoothing_s", "max_abs_rad"):
            _check(getattr(self, key) > 0, s, key, getattr(self, key), "a positive number")


@dataclass(frozen=True)
class VehicleSettings:
    """The vehicle model (:mod:`odocal.model.registry`): its equations and its parameters,
    which every per-parameter setting (``[identify] theta0``, ``prior_std``, ``[minimum]
    half_width``, ``[fleet] excess_floor``) lists in the model's order."""

    model: str = registry.DEFAULT
    """The model's name: ``rear_axle`` (two rear wheel rates, METHOD 1)."""

    def __post_init__(self) -> None:
        try:
            registry.entry(self.model)
        except ConfigError as err:
            raise ConfigError(f"setting [vehicle] model = {self.model!r} is invalid: "
                              f"{err}") from None


@dataclass(frozen=True)
class Settings:
    """Every setting of odocal. ``Settings()`` holds the paper's defaults."""

    vehicle: VehicleSettings = field(default_factory=VehicleSettings)
    segments: SegmentSettings = field(default_factory=SegmentSettings)
    identify: IdentifySettings = field(default_factory=IdentifySettings)
    compensate: CompensateSettings = field(default_factory=CompensateSettings)
    calibrate: CalibrateSettings = field(default_factory=CalibrateSettings)
    minimum: MinimumSettings = field(default_factory=MinimumSettings)
    uncertainty: UncertaintySettings = field(default_factory=UncertaintySettings)
    inverse: InverseSettings = field(default_factory=InverseSettings)
    reference: ReferenceSettings = field(default_factory=ReferenceSettings)
    gate: GateSettings = field(default_factory=GateSettings)
    checks: ChecksSettings = field(default_factory=ChecksSettings)
    online: OnlineSettings = field(default_factory=OnlineSettings)
    fleet: FleetSettings = field(default_factory=FleetSettings)
    convert: ConvertSettings = field(default_factory=ConvertSettings)
    fusion: FusionSettings = field(default_factory=FusionSettings)
    sideslip: SideslipSettings = field(default_factory=SideslipSettings)

    def __post_init__(self) -> None:
        # every number of every section must be finite, however the settings were built
        for name in _SECTIONS:
            section = getattr(self, name)
            for f in dataclasses.fields(section):
                value = getattr(section, f.name)
                values = value if isinstance(value, tuple) else (value,)
                for v in values:
                    if isinstance(v, float) and not math.isfinite(v):
                        raise ConfigError(f"setting [{name}] {f.name} = {value!r} is invalid: "
                                          "expected finite numbers")
        self._check_per_parameter(registry.layout(self.vehicle.model))

    def _check_per_parameter(self, lay: Layout) -> None:
        """The per-parameter settings list the chosen model's parameters, each in its range."""
        theta0, prior_std = self.identify.theta0, self.identify.prior_std
        problem = vehicle_problem(theta0, lay)
        _check(problem is None, "identify", "theta0", theta0,
               f"a wheeled vehicle's values ({problem})")
        highest = [p.prior_std_max for p in lay.parameters]
        _check(len(prior_std) == lay.size
               and all(PRIOR_STD_MIN <= p <= hi for p, hi in zip(prior_std, highest,
                                                                 strict=True)),
               "identify", "prior_std", prior_std,
               f"{lay.size} standard deviations from {PRIOR_STD_MIN:g} up to "
               + ", ".join(f"{n} {hi:g}" for n, hi in zip(lay.names, highest, strict=True)))
        for name, key in PER_PARAMETER:
            value = getattr(getattr(self, name), key)
            _check(len(value) == lay.size, name, key, value,
                   f"{lay.size} values, one per parameter of the {self.vehicle.model} model "
                   f"({', '.join(lay.names)})")

    @property
    def layout(self) -> Any:
        """The chosen model's parameter layout (:class:`odocal.model.layout.Layout`)."""
        return registry.layout(self.vehicle.model)

    def replace(self, **sections: Any) -> Settings:
        """A copy with whole sections or single keys replaced.

        ``settings.replace(calibrate={"seed": 3})`` changes one key of one section.
        """
        updates: dict[str, Any] = {}
        for name, value in sections.items():
            if name not in _SECTIONS:
                raise ConfigError(f"unknown settings section {name!r}; known: {sorted(_SECTIONS)}")
            if not isinstance(value, dict | _SECTIONS[name]):
                raise ConfigError(f"settings section {name!r} takes a dict of its keys (e.g. "
                                  f"{name}={{...}}) or a {_SECTIONS[name].__name__}, not "
                                  f"{value!r}")
            current = getattr(self, name)
            if isinstance(value, dict):
                value = _build_section(name, _SECTIONS[name], value, base=current)
            updates[name] = value
        model = updates.get("vehicle", self.vehicle).model
        if model != self.vehicle.model:
            given = {(n, k) for n, v in sections.items() if isinstance(v, dict) for k in v}
            given |= {(n, k) for n, k in PER_PARAMETER
                      if n in sections and not isinstance(sections[n], dict)}
            updates = _resized(updates, self, self.vehicle.model, model, given)
        return dataclasses.replace(self, **updates)

    def to_dict(self) -> dict[str, dict[str, Any]]:
        """Plain, JSON- and TOML-friendly nested dict of every setting."""
        return {name: _to_plain(dataclasses.asdict(getattr(self, name))) for name in _SECTIONS}


def _to_plain(obj: Any) -> Any:
    if isinstance(obj, dict):
        return {k: _to_plain(v) for k, v in obj.items()}
    if isinstance(obj, tuple | list):
        return [_to_plain(v) for v in obj]
    return obj


#: The settings that hold one value per parameter of the model, by section and key.
PER_PARAMETER: tuple[tuple[str, str], ...] = (("identify", "theta0"), ("identify", "prior_std"),
                                               ("minimum", "half_width"),
                                               ("fleet", "excess_floor"))

_SECTIONS: dict[str, type] = {f.name: typing.get_type_hints(Settings)[f.name]
                              for f in dataclasses.fields(Settings)}


def _coerce(section: str, key: str, value: Any, hint: Any) -> Any:
    """Convert a TOML value to the annotated type, or raise ConfigError."""
    origin = typing.get_origin(hint)
    if hint is float:
        _check(isinstance(value, int | float) and not isinstance(value, bool)
               and math.isfinite(value), section, key, value, "a finite number")
        return float(value)
    if hint is int:
        _check(isinstance(value, int) and not isinstance(value, bool), section, key, value,
               "an integer")
        return int(value)
    if hint is bool:
        _check(isinstance(value, bool), section, key, value, "true or false")
        return value
    if hint is str:
        _check(isinstance(value, str), section, key, value, "a string")
        return value
    if origin is Literal:
        allowed = typing.get_args(hint)
        _check(value in allowed, section, key, value, " or ".join(repr(a) for a in allowed))
        return value
    if origin is tuple:
        args = typing.get_args(hint)
        _check(isinstance(value, list | tuple), section, key, value, "a list")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_coerce(section, key, v, args[0]) for v in value)
        _check(len(value) == len(args), section, key, value, f"a list of {len(args)} values")
        return tuple(_coerce(section, key, v, a) for v, a in zip(value, args, strict=True))
    if origin in (types.UnionType, typing.Union):
        args = typing.get_args(hint)
        if value is None and type(None) in args:
            return None
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _coerce(section, key, value, arg)
            except ConfigError:
                continue
        raise ConfigError(f"setting [{section}] {key} = {value!r} is invalid: expected {hint}")
    raise ConfigError(f"setting [{section}] {key}: unsupported type {hint}")  # pragma: no cover


def _build_section(name: str, cls: type, values: dict[str, Any], *, base: Any = None) -> Any:
    hints = typing.get_type_hints(cls)
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(values) - known)
    if name == "calibrate" and "method" in unknown:
        raise ConfigError("setting [calibrate] method is no longer a setting: choose the method "
                          "with --method (or odocal.calibrate(method=...))")
    if unknown:
        raise ConfigError(
            f"unknown setting [{name}] {unknown[0]!r}; known keys: {', '.join(sorted(known))}")
    converted = {k: _coerce(name, k, v, hints[k]) for k, v in values.items()}
    if base is None:
        return cls(**converted)
    return dataclasses.replace(base, **converted)


def settings_from_dict(data: dict[str, Any], *, source: str = "settings") -> Settings:
    """Build :class:`Settings` from a nested dict (as read from TOML), rejecting unknown keys."""
    unknown = sorted(set(data) - set(_SECTIONS))
    if unknown:
        raise ConfigError(f"unknown section [{unknown[0]}] in {source}; known sections: "
                          f"{', '.join(sorted(_SECTIONS))}")
    sections: dict[str, Any] = {}
    for name, values in data.items():
        if not isinstance(values, dict):
            raise ConfigError(f"{source}: [{name}] must be a table of settings, got {values!r}")
        sections[name] = _build_section(name, _SECTIONS[name], values)
    model = sections["vehicle"].model if "vehicle" in sections else registry.DEFAULT
    if model != registry.DEFAULT:
        given = {(n, k) for n, v in data.items() for k in v}
        sections = _resized(sections, Settings(), registry.DEFAULT, model, given)
    return Settings(**sections)


def _per_parameter_default(key: str, spec: ParameterSpec) -> float:
    """A per-parameter setting's default for a parameter the rear axle does not have: the
    datasheet placeholder, its uncertainty (also the minimum search's half width), no floor."""
    return {"theta0": spec.placeholder, "prior_std": spec.prior_std,
            "half_width": spec.prior_std, "excess_floor": 0.0}[key]


def _resized(sections: dict[str, Any], base: Settings, before: str, after: str,
             given: set[tuple[str, str]]) -> dict[str, Any]:
    """``sections`` with the per-parameter settings not ``given`` anew listed for model
    ``after``'s parameters: by name from model ``before``'s values (``sections``' or
    ``base``'s), a parameter ``before`` has not from its default. One line of settings
    (``[vehicle] model = "four_wheel"``) then takes a model with the rear axle's values kept."""
    old, new = registry.layout(before), registry.layout(after)
    out = dict(sections)
    for name, key in PER_PARAMETER:
        if (name, key) in given:
            continue
        section = out.get(name, getattr(base, name))
        values = dict(zip(old.names, getattr(section, key), strict=False))
        resized = tuple(values[p.name] if p.name in values else _per_parameter_default(key, p)
                        for p in new.parameters)
        out[name] = dataclasses.replace(section, **{key: resized})
    return out


def read_toml(path: str | Path, kind: str) -> dict[str, Any]:
    """A TOML file's content; a missing or malformed file is named as ``kind`` in the error."""
    p = input_file(path, kind)
    try:
        return tomllib.loads(p.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{kind} '{shown(p)}' is not valid TOML: {exc}") from exc
    except RecursionError as exc:
        raise ConfigError(f"{kind} '{shown(p)}' nests tables or arrays too deeply to read") \
            from exc


def load_settings(path: str | Path | None) -> Settings:
    """Read a TOML settings file; ``None`` gives the defaults."""
    if path is None:
        return Settings()
    return settings_from_dict(read_toml(path, "settings file"), source=f"'{path}'")


def datasheet_stated(theta0: Any) -> bool:
    """False for odocal's placeholder datasheet (``[identify] theta0`` left at its default, no
    ``--datasheet``): a ratio to it says nothing about the user's vehicle. ``theta0``: the four
    values, or anything with ``as_array()``."""
    values = theta0.as_array().tolist() if hasattr(theta0, "as_array") else list(theta0)
    # a model's theta begins with the rear axle's four (the four-wheel car's front axle and
    # steering after them): those are what the datasheet check is about
    return tuple(float(v) for v in values[:len(DATASHEET_THETA)]) != DATASHEET_THETA
