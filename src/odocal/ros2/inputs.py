"""The node's inputs as they arrive: which joints are the wheels, what each topic's stamps say.

Nothing here knows ROS 2: the node hands in stamps (seconds from its time origin) and values
as it reads them from the messages (:mod:`odocal.ros2.cdr`).

* :func:`wheel_joints`: which two joints of a ``JointState`` are the wheels the model's
  ``n_rl`` and ``n_rr`` are (named by the parameters, or found by their names).
* :class:`Continuity`: what a topic's stamps say about what did not arrive: a message whose
  stamp is not after the last one's (a clock that jumped back) is refused and counted; a step
  between stamps of more than one and a half of the topic's own period counts the messages that
  should have come in between (lost on the way, or never sent).
* :class:`Buffer`: one input's values since the last push, as a
  :class:`~odocal.io.streams.Stream` for the grid.
* :class:`Rates`: wheel rates from joint positions, for drivers that publish no velocities.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from odocal.errors import ConfigError
from odocal.io import joints
from odocal.io.streams import Stream

TWO_PI = 2.0 * math.pi
#: A step between stamps longer than this many periods means messages are missing.
MISSING_AFTER = 1.5
#: A topic's period is the 10th percentile of this many recent steps between its stamps (a
#: low quantile: it stays the period while up to nine in ten messages are lost).
_PERIOD_STEPS = 64


def wheel_joints(names: Sequence[str], left: str, right: str, topic: str) -> tuple[int, int]:
    """The indices of the left and right wheel joints in a JointState's names, by the rule of
    :mod:`odocal.io.joints` (the bag reader's): those named (``left_wheel_joint``,
    ``right_wheel_joint``), else found by their names; a ConfigError naming the joints and the
    parameter to set where that finds none or several."""
    return joints.wheel_joints(names, (left, right), where=topic,
                               setting=lambda side: f"{side}_wheel_joint", error=ConfigError)


def tenth_percentile(values: Sequence[float]) -> float:
    """``np.percentile(values, 10)`` (its default, linear method, in its arithmetic), without
    numpy's overhead on a few dozen values (70 us against 2 us)."""
    ordered = sorted(values)
    virtual = (len(ordered) - 1) * 0.1
    below = math.floor(virtual)
    if below >= len(ordered) - 1:
        return float(ordered[-1])
    gamma = virtual - below
    a, b = ordered[below], ordered[below + 1]
    diff = b - a
    return float(b - diff * (1.0 - gamma) if gamma >= 0.5 else a + diff * gamma)


@dataclass(slots=True)
class Continuity:
    """What one topic's stamps say: messages taken, missing between them, and refused.

    ``check(t)`` is asked per message with its stamp (s); True: take it.
    """

    received: int = 0
    missing: int = 0
    back: int = 0                     # refused: the stamp is not after the last one's
    back_max_s: float = 0.0           # ... by at most this much
    invalid: int = 0                  # refused: a value is NaN or infinite
    last_t: float | None = None
    last_missing_t: float | None = None   # the stamp after the latest gap
    period_s: float | None = None
    _steps: list[float] = field(default_factory=list)
    _refused: int = 0                 # refused since the last message taken (not missing)

    def check(self, t: float) -> bool:
        last = self.last_t
        if last is not None:
            if not t > last:
                self.back += 1
                self.back_max_s = max(self.back_max_s, last - t)
                self._refused += 1
                return False
            step = t - last
            period = self.period_s
            if period is not None and step > MISSING_AFTER * period:
                missing = round(step / period) - 1 - self._refused
                if missing > 0:
                    self.missing += missing
                    self.last_missing_t = t
            steps = self._steps
            steps.append(step)
            if len(steps) >= _PERIOD_STEPS:
                self.period_s = tenth_percentile(steps)
                steps.clear()
            elif period is None and len(steps) >= 8:
                self.period_s = tenth_percentile(steps)
        self.last_t = t
        self.received += 1
        self._refused = 0
        return True

    def refuse_invalid(self) -> None:
        """A message with a NaN or infinite value (its stamp was taken)."""
        self.invalid += 1

    @property
    def missing_share(self) -> float:
        """The share of the messages the stamps call for that did not arrive."""
        total = self.received + self.missing
        return self.missing / total if total else 0.0


@dataclass
class Buffer:
    """One input's samples since the last push: its stream name and role for the grid."""

    name: str
    role: str
    keys: tuple[str, ...]
    columns: dict[str, list[float]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.columns = {k: [] for k in ("t", *self.keys)}

    def add(self, t: float, values: Sequence[float]) -> None:
        self.columns["t"].append(t)
        for key, value in zip(self.keys, values, strict=True):
            self.columns[key].append(value)

    def newest(self) -> float | None:
        t = self.columns["t"]
        return t[-1] if t else None

    def take(self) -> Stream | None:
        if not self.columns["t"]:
            return None
        arrays = {k: np.asarray(v, dtype=np.float64) for k, v in self.columns.items()}
        self.columns = {k: [] for k in self.columns}
        return Stream(name=self.name, role=self.role, t=arrays.pop("t"), values=arrays)

    def trim(self, keep_after_t: float) -> None:
        t = self.columns["t"]
        cut = next((i for i, v in enumerate(t) if v > keep_after_t), len(t))
        if cut:
            self.columns = {k: v[cut:] for k, v in self.columns.items()}


class Rates:
    """Wheel rates (rev/s) from wheel joint positions (rad): the change over the step between
    two messages, at the step's middle (and an angle read beside them, a steering joint's, as
    its mean over the step). A step longer than ``max_gap_s``, or of other joints, starts
    over."""

    def __init__(self, max_gap_s: float) -> None:
        self.max_gap_s = max_gap_s
        self._last: tuple[float, tuple[float, ...], tuple[float, ...]] | None = None

    def add(self, t: float, *positions_rad: float, angles: tuple[float, ...] = ()
            ) -> tuple[float, ...] | None:
        """(t of the middle of the step, each joint's rate in rev/s, then each of ``angles``
        at the step's middle), or None for the first of a piece."""
        last, self._last = self._last, (t, positions_rad, angles)
        if last is None or not 0.0 < t - last[0] <= self.max_gap_s \
                or len(last[1]) != len(positions_rad) or len(last[2]) != len(angles):
            return None
        turn = TWO_PI * (t - last[0])
        return (0.5 * (t + last[0]),
                *((now - was) / turn for now, was in zip(positions_rad, last[1], strict=True)),
                *(0.5 * (now + was) for now, was in zip(angles, last[2], strict=True)))

    @property
    def last_t(self) -> float | None:
        """The time of the angles the next step starts from (None: none kept)."""
        return None if self._last is None else self._last[0]

    def reset(self) -> None:
        self._last = None
