"""Unit and convention conversions for importers. Unknown units are DataErrors naming the stream."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from odocal.errors import DataError

FloatArray = NDArray[np.float64]

TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
ANGLE_UNITS = {"rad": 1.0, "deg": np.pi / 180.0}
ANGULAR_RATE_UNITS = {"rad/s": 1.0, "deg/s": np.pi / 180.0}
ACCEL_UNITS = {"m/s^2": 1.0, "m/s2": 1.0, "g": 9.80665}
#: Wheel-rate units that need no extra information, as factors to rev/s.
WHEEL_RATE_UNITS = {"rev/s": 1.0, "rpm": 1.0 / 60.0, "rad/s": 1.0 / (2.0 * np.pi),
                    "deg/s": 1.0 / 360.0}
#: Wheel units that are speeds and need a circumference, as factors to m/s.
WHEEL_SPEED_UNITS = {"m/s": 1.0, "km/h": 1.0 / 3.6, "mph": 0.44704}
WHEEL_UNITS = (*WHEEL_RATE_UNITS, *WHEEL_SPEED_UNITS, "ticks")
HEADING_CONVENTIONS = ("enu", "compass")


def _unknown(stream: str, what: str, unit: str, known: tuple[str, ...] | list[str]) -> DataError:
    return DataError(f"stream '{stream}': unknown {what} unit {unit!r}; use one of "
                     f"{', '.join(known)}")


def _scaled(values: FloatArray, unit: str, table: dict[str, float], what: str,
            stream: str) -> FloatArray:
    if unit not in table:
        raise _unknown(stream, what, unit, list(table))
    return np.asarray(values, dtype=np.float64) * table[unit]


def time_seconds(values: FloatArray, unit: str, *, stream: str) -> FloatArray:
    return _scaled(values, unit, TIME_UNITS, "time", stream)


def angle_rad(values: FloatArray, unit: str, *, stream: str) -> FloatArray:
    return _scaled(values, unit, ANGLE_UNITS, "angle", stream)


def angular_rate_radps(values: FloatArray, unit: str, *, stream: str) -> FloatArray:
    return _scaled(values, unit, ANGULAR_RATE_UNITS, "angular rate", stream)


def accel_mps2(values: FloatArray, unit: str, *, stream: str) -> FloatArray:
    return _scaled(values, unit, ACCEL_UNITS, "acceleration", stream)


def heading_enu(values_rad: FloatArray, convention: str, *, stream: str) -> FloatArray:
    """A heading in odocal's convention: counter-clockwise from east (the x axis)."""
    if convention == "enu":
        return values_rad
    if convention == "compass":             # clockwise from north
        return np.pi / 2.0 - values_rad
    raise DataError(f"stream '{stream}': unknown heading convention {convention!r}; use "
                    f"{' or '.join(HEADING_CONVENTIONS)}")


def wheel_rate_revps(values: FloatArray, unit: str, *, stream: str, t: FloatArray | None = None,
                     circumference_m: float | None = None,
                     ticks_per_rev: float | None = None) -> FloatArray:
    """Wheel rotation rates in rev/s from rates, speeds (with a circumference) or tick counts.

    ``ticks`` are cumulative encoder counts; the rate is their change over time (``t`` needed).
    """
    v = np.asarray(values, dtype=np.float64)
    if unit in WHEEL_RATE_UNITS:
        return v * WHEEL_RATE_UNITS[unit]
    if unit in WHEEL_SPEED_UNITS:
        if not circumference_m or circumference_m <= 0:
            raise DataError(f"stream '{stream}': wheel speeds in {unit} need a nominal wheel "
                            "circumference (circumference_m) to become rotation rates")
        return v * WHEEL_SPEED_UNITS[unit] / circumference_m
    if unit == "ticks":
        if not ticks_per_rev or ticks_per_rev <= 0:
            raise DataError(f"stream '{stream}': encoder ticks need ticks_per_rev")
        if t is None or t.shape != v.shape:
            raise DataError(f"stream '{stream}': encoder ticks need their time stamps")
        order = np.argsort(t, kind="stable")
        ts, vs = t[order], v[order]
        rate = np.empty_like(v)
        dt = np.diff(ts)
        with np.errstate(divide="ignore", invalid="ignore"):
            r = np.diff(vs) / dt / ticks_per_rev
        rate_sorted = np.concatenate([r[:1], r]) if r.size else np.zeros_like(vs)
        rate[order] = np.where(np.isfinite(rate_sorted), rate_sorted, np.nan)
        return rate
    raise _unknown(stream, "wheel", unit, list(WHEEL_UNITS))


def quaternion_yaw(w: FloatArray, x: FloatArray, y: FloatArray, z: FloatArray) -> FloatArray:
    """Yaw (rad, counter-clockwise about z) of body-to-world quaternions [w, x, y, z]."""
    return np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
