"""Raw logs as streams: what every importer produces before alignment.

A :class:`Stream` is one sensor's samples on its own clock, already converted to SI units and to
odocal's conventions (angles counter-clockwise from east / the x axis, left-positive lateral
quantities). A :class:`RawLog` holds the streams of one recording by role:

========== ==================================================================================
role       quantities (any subset the source has, SI units)
========== ==================================================================================
wheels     ``n_rl``, ``n_rr`` rear wheel rotation rates, rev/s
imu        ``yaw_rate`` rad/s (left-positive), ``a_y`` m/s^2 (left-positive)
pose       ``x``, ``y`` m in a local planar frame, ``psi`` rad (a fused reference pose);
           optionally ``vx``, ``vy`` m/s in the same frame (an independent course)
gnss       ``east``, ``north`` m in a local ENU frame (from latitude/longitude), ``speed`` m/s,
           ``course`` rad counter-clockwise from east, optional ``std`` m (horizontal accuracy)
heading    ``psi`` rad counter-clockwise from east (a compass or dual-antenna heading)
========== ==================================================================================
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from odocal.arrays import FloatArray
from odocal.errors import DataError

ROLES: tuple[str, ...] = ("wheels", "imu", "pose", "gnss", "heading")
QUANTITIES: Mapping[str, tuple[str, ...]] = {
    "wheels": ("n_rl", "n_rr", "n_fl", "n_fr", "steer"),   # the last three: more models
    "imu": ("yaw_rate", "a_y"),
    "pose": ("x", "y", "psi", "vx", "vy"),
    "gnss": ("east", "north", "speed", "course", "std"),
    "heading": ("psi",),
}
#: Quantities that are angles (unwrapped before interpolation).
ANGLES: frozenset[tuple[str, str]] = frozenset({("pose", "psi"), ("gnss", "course"),
                                                ("heading", "psi")})


@dataclass(frozen=True)
class Stream:
    """One sensor's samples on its own clock, in SI units.

    name : where it came from (message, topic or file), for messages
    role : one of :data:`ROLES`
    t : ndarray, shape (M,), seconds on the log's clock, as recorded (maybe unsorted, repeated)
    values : quantity name -> ndarray, shape (M,)
    units : quantity name -> the unit it was recorded in (for ``odocal inspect``)
    offset_s : constant added to ``t`` to bring the stream onto the common clock
    """

    name: str
    role: str
    t: FloatArray
    values: Mapping[str, FloatArray]
    units: Mapping[str, str] = field(default_factory=dict)
    offset_s: float = 0.0

    def __post_init__(self) -> None:
        if self.role not in ROLES:
            raise ValueError(f"unknown stream role {self.role!r}")
        for key, values in self.values.items():
            if key not in QUANTITIES[self.role]:
                raise ValueError(f"stream role {self.role} has no quantity {key!r}")
            if values.shape != self.t.shape:
                raise DataError(f"stream '{self.name}': {key} has {values.shape[0]} samples, "
                                f"its time stamps {self.t.shape[0]}")

    @property
    def span(self) -> tuple[float, float]:
        t = self.t + self.offset_s
        return (float(np.min(t)), float(np.max(t))) if t.size else (np.nan, np.nan)

    def rate_hz(self) -> float:
        t = np.unique(self.t)
        return float((t.size - 1) / (t[-1] - t[0])) if t.size > 1 and t[-1] > t[0] else 0.0


@dataclass(frozen=True)
class RawLog:
    """The streams of one recording, by role, and where they came from.

    name : a label for messages and for the drive made from it
    streams : role -> stream
    origin_lla : latitude, longitude (deg) and altitude (m) of the local ENU frame's origin, when
        positions came from GNSS
    metadata : free-form provenance (format, files, options)
    """

    name: str
    streams: Mapping[str, Stream]
    origin_lla: tuple[float, float, float] | None = None
    metadata: Mapping[str, Any] = field(default_factory=dict)

    def require(self, role: str, what: str) -> Stream:
        stream = self.streams.get(role)
        if stream is None:
            raise DataError(f"'{self.name}' has no {role} stream ({what}); found: "
                            f"{', '.join(sorted(self.streams)) or 'nothing'}")
        return stream
