"""What the checks find: a code, a severity and the numbers behind it.

Words are made from findings in :mod:`odocal.report.advice` (for the CLI and the report); the
only exception is :attr:`Check.INVALID_INPUT`, whose ``name`` carries the data layer's own
one-line message (the live path meets a malformed log only when it checks its samples).
"""

from __future__ import annotations

import enum
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any


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
    WHEEL_DEAD = "wheel-dead"
    LATERAL_MISSING = "lateral-missing"
    LATERAL_DELAY = "lateral-delay"
    REFERENCE_SYNC = "reference-sync"
    REFERENCE_HEADING = "reference-heading"
    POSE_JUMP = "pose-jump"
    VEHICLES_DIFFER = "vehicles-differ"
    INVALID_INPUT = "invalid-input"
    PARAMETER_RANGE = "parameter-range"
    WORSE_THAN_DATASHEET = "worse-than-datasheet"
    LARGE_ERROR = "large-error"
    DATA_REPAIRED = "data-repaired"
    LATERAL_OFFSET = "lateral-offset"
    HEADING_ERROR = "heading-error"
    WHEEL_OFFSET = "wheel-offset"
    MOVING_OFFSET = "moving-offset"
    CHANGE_IN_LOG = "change-in-log"
    FRONT_WHEELS = "front-wheels"
    REFERENCE_LAG = "reference-lag"
    WHEEL_SMOOTHING = "wheel-smoothing"
    WHEEL_SKEW = "wheel-skew"
    REFERENCE_ARM = "reference-arm"
    CURVE_EXCESS = "curve-excess"
    LATERAL_GAIN = "lateral-gain"
    SIDESLIP = "sideslip"
    DRIFT = "drift"
    DRIVE_DEPARTS = "drive-departs"
    REFERENCE_SMOOTHED = "reference-smoothed"
    WHEEL_MAPPING = "wheel-mapping"
    FRONT_AXLE = "front-axle"
    STEERING = "steering"


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

    @property
    def lateral_missing(self) -> bool:
        """a_y carries no lateral acceleration (zero, constant, unplugged): d is not fitted."""
        return any(f.check is Check.LATERAL_MISSING for f in self.findings)

    @property
    def fatal_findings(self) -> tuple[Finding, ...]:
        return tuple(f for f in self.findings if f.severity is Severity.FATAL)

    def plus(self, more: Sequence[Finding]) -> Diagnosis:
        return Diagnosis(findings=(*self.findings, *more))

    def to_dict(self) -> list[dict[str, Any]]:
        return [f.to_dict() for f in self.findings]
