"""Unit and convention conversions for importers. Unknown units are DataErrors naming the stream."""

from __future__ import annotations

import numpy as np

from odocal.arrays import FloatArray
from odocal.errors import DataError

#: ``datetime``: a date-time column (ISO 8601 text, Parquet timestamps), read as seconds.
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9, "datetime": 1.0}
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


#: Widths of the tick counters a wrap is recognised for without being told (bits).
COUNTER_WIDTHS = (8, 12, 16, 24, 32)


def counter_modulus(counts: FloatArray, *, bits: int | None = None) -> float | None:
    """The modulus ``2**bits`` a cumulative tick counter wraps at, or None where it does not.

    ``bits`` as stated (a mapping's ``counter_bits``); else the narrowest of
    :data:`COUNTER_WIDTHS` whose unsigned ``[0, 2**b)`` or signed ``[-2**(b-1), 2**(b-1))``
    range holds every count, where some step of the counts (in time order) is larger than half
    that range: no wheel turns half a counter between two samples, a wrap does.
    """
    if bits is not None:
        return float(2.0**bits)
    v = counts[np.isfinite(counts)]
    if v.size < 2 or np.any(v != np.round(v)):
        return None
    lo, hi = float(v.min()), float(v.max())
    for width in COUNTER_WIDTHS:
        modulus = 2.0**width
        if (lo >= 0 and hi < modulus) or (lo >= -modulus / 2 and hi < modulus / 2):
            return modulus if np.any(np.abs(np.diff(v)) > modulus / 2) else None
    return None


def counter_steps(counts: FloatArray, modulus: float | None) -> FloatArray:
    """The steps of a tick counter (in the order given), a wrap undone: each step taken modulo
    ``modulus`` into ``[-modulus/2, modulus/2)``."""
    steps = np.diff(counts)
    if modulus is None:
        return steps
    return np.remainder(steps + modulus / 2, modulus) - modulus / 2


def wheel_rate_revps(values: FloatArray, unit: str, *, stream: str, t: FloatArray | None = None,
                     circumference_m: float | None = None,
                     ticks_per_rev: float | None = None,
                     counter_bits: int | None = None) -> FloatArray:
    """Wheel rotation rates in rev/s from rates, speeds (with a circumference) or tick counts.

    ``ticks`` are cumulative encoder counts; the rate is their change over time (``t`` needed).
    A counter that wraps (``counter_bits`` wide, or recognised: :func:`counter_modulus`) is
    unwrapped, whether it counts unsigned or signed.
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
        steps = counter_steps(vs, counter_modulus(vs, bits=counter_bits))
        with np.errstate(divide="ignore", invalid="ignore"):
            r = steps / dt / ticks_per_rev
        rate_sorted = np.concatenate([r[:1], r]) if r.size else np.zeros_like(vs)
        rate[order] = np.where(np.isfinite(rate_sorted), rate_sorted, np.nan)
        return rate
    raise _unknown(stream, "wheel", unit, list(WHEEL_UNITS))


def quaternion_yaw(w: FloatArray, x: FloatArray, y: FloatArray, z: FloatArray) -> FloatArray:
    """Yaw (rad, counter-clockwise about z) of body-to-world quaternions [w, x, y, z]."""
    return np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
