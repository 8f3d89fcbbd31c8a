"""What a live stream hands the online calibrator, made into drive-format samples on one grid.

* **Columns.** A pushed chunk (a mapping of column names to arrays, or a pandas DataFrame) as
  float arrays, or a :class:`~odocal.errors.DataError` naming what is wrong with it.
* **Time.** ``t`` in seconds, milliseconds, microseconds or nanoseconds (told apart by the
  sampling step: a drive log samples every 1 ms to 1 s, and each unit puts only one of them in
  that range), or as datetimes (numpy ``datetime64``, pandas timestamps with or without a time
  zone, ``datetime`` objects, ISO 8601 text): seconds from then on.
* **One grid.** The calibrator's windows count samples of one step, the first stream's. Samples
  that arrive at another rate (a logger reconfigured mid-stream) or with jittered timestamps are
  interpolated onto that grid (:class:`Regrid`); samples on it pass unchanged, bit for bit. A
  gap (a step longer than 1.5 times the stream's own recent step) ends a piece, as it always
  did: nothing is interpolated across it.
"""

from __future__ import annotations

import datetime as _dt
import math
from typing import Any

import numpy as np

from odocal.arrays import FloatArray
from odocal.errors import DataError

#: Drive-format columns a chunk must hold (``beta`` is optional: 0 where absent).
REQUIRED = ("t", "n_rl", "n_rr", "a_y", "x", "y", "psi")
#: The columns of a sample, in order.
SAMPLE = ("t", "n_rl", "n_rr", "a_y", "beta", "x", "y", "psi")
#: Wheel rates beyond this (rev/s) in a pushed chunk are in another unit, whatever else.
MAX_PUSHED_RATE_REVPS = 100.0
#: Time units told apart by the sampling step, and the step a drive log has (s).
TIME_UNITS = (("s", 1.0), ("ms", 1e-3), ("us", 1e-6), ("ns", 1e-9))
STEP_RANGE_S = (1e-3, 1.0)
#: A step longer than this many times the stream's recent step is a gap.
GAP_FACTOR = 1.5
#: Steps the stream's own recent step is the median of.
_RECENT_STEPS = 16
#: A sample this close to a grid time (in steps) is on it.
_ON_GRID = 1e-3
_EPOCH = _dt.datetime(1970, 1, 1)


def has_column(chunk: Any, key: str) -> bool:
    try:
        return key in chunk
    except TypeError:
        return False


def _datetimes_s(values: Any) -> FloatArray | None:
    """Datetimes (or durations) as seconds (since the epoch, UTC where a zone is given); None
    where ``values`` are not datetimes."""
    dt = getattr(values, "dt", None)                    # a pandas Series of datetimes
    if dt is not None and getattr(dt, "tz", None) is not None:
        values = dt.tz_convert("UTC").dt.tz_localize(None)
    try:
        array = np.asarray(values)
    except (TypeError, ValueError):
        return None
    array = array.ravel()
    if array.dtype.kind == "M":
        ns = array.astype("datetime64[ns]").astype(np.int64)
        return np.asarray(ns, dtype=np.float64) * 1e-9
    if array.dtype.kind == "m":
        return np.asarray(array.astype("timedelta64[ns]").astype(np.int64),
                          dtype=np.float64) * 1e-9
    if array.dtype.kind == "O" and array.size and all(
            isinstance(v, _dt.datetime) for v in array):
        return np.array([v.timestamp() if v.tzinfo is not None
                         else (v - _EPOCH).total_seconds() for v in array])
    if array.dtype.kind in "OUS" and array.size:
        try:
            parsed = np.array([str(v) for v in array], dtype="datetime64[ns]")
        except (TypeError, ValueError):
            return None
        return np.asarray(parsed.astype(np.int64), dtype=np.float64) * 1e-9
    return None


def _is_time(values: Any) -> bool:
    """Datetimes or durations by their type (numpy's, or a pandas column's)."""
    dtype = getattr(values, "dtype", None)
    return getattr(dtype, "kind", "") in ("M", "m") or getattr(values, "dt", None) is not None


def step_s(t: FloatArray) -> float:
    """The sampling step of times ``t`` (s): their median step, to the microsecond where it
    is that close to one (time stamps in ns or ms since the epoch, as floats, are rounded to a
    fraction of a microsecond; a step of 24.99986 ms is the logger's 25 ms)."""
    step = float(np.median(np.diff(t)))
    clean = round(step, 6)
    return clean if clean > 0 and abs(clean - step) <= 1e-5 * step else step


def rows(chunk: Any, extra: tuple[str, ...] = ()) -> tuple[FloatArray, bool]:
    """A pushed chunk as samples (M, len(SAMPLE) + len(extra)) in :data:`SAMPLE` order (``beta``
    0 where absent), then the ``extra`` columns (a model's own inputs: NaN where absent or not
    measured), and whether ``t`` came as datetimes (then in seconds since the epoch); or a
    DataError naming what is wrong with it."""
    if not hasattr(chunk, "__getitem__") or isinstance(chunk, str | bytes):
        raise DataError(f"pushed samples must be a mapping of column names to arrays (or a "
                        f"DataFrame), not {type(chunk).__name__}")
    missing = [k for k in REQUIRED if not has_column(chunk, k)]
    if missing:
        raise DataError(f"pushed samples lack column{'s' if len(missing) > 1 else ''} "
                        f"{', '.join(missing)}")
    cols: list[FloatArray] = []
    stamped = False
    for key in SAMPLE:
        if key == "beta" and not has_column(chunk, key):
            cols.append(np.zeros(cols[0].size))
            continue
        values = chunk[key]
        if key == "t" and _is_time(values):
            seconds = _datetimes_s(values)
            if seconds is not None:
                cols.append(seconds)
                stamped = True
                continue
        try:
            cols.append(np.asarray(values, dtype=np.float64).ravel())
        except (TypeError, ValueError) as err:
            seconds = _datetimes_s(values) if key == "t" else None
            if seconds is None:
                raise DataError(f"pushed column {key} is not numeric") from err
            cols.append(seconds)
            stamped = True
    n = cols[0].size
    cols.extend(_extra(chunk, extra, n))
    names = (*SAMPLE, *extra)
    for key, values in zip(names, cols, strict=True):
        if values.size != n:
            raise DataError(f"pushed column {key} has {values.size} samples, t has {n}")
    out = np.column_stack(cols) if n else np.zeros((0, len(names)))
    if not np.isfinite(out[:, :len(SAMPLE)]).all():
        key = SAMPLE[int(np.flatnonzero(~np.isfinite(out[:, :len(SAMPLE)]).all(axis=0))[0])]
        raise DataError(f"pushed column {key} holds NaN or infinite values")
    if np.isinf(out[:, len(SAMPLE):]).any():
        key = extra[int(np.flatnonzero(np.isinf(out[:, len(SAMPLE):]).any(axis=0))[0])]
        raise DataError(f"pushed column {key} holds infinite values")
    wheels = [i for i, k in enumerate(names) if k.startswith("n_")]
    rates = np.abs(out[:, wheels])
    if n and np.nanmax(rates, initial=0.0) > MAX_PUSHED_RATE_REVPS:
        key = names[wheels[int(np.argmax(np.nanmax(rates, axis=0, initial=0.0)))]]
        raise DataError(f"pushed column {key} reaches {np.nanmax(rates):.4g}: wheel rates must "
                        "be in rev/s")
    return out, stamped


def _extra(chunk: Any, extra: tuple[str, ...], n: int) -> list[FloatArray]:
    """The ``extra`` columns of ``chunk`` as floats (NaN where a column is absent)."""
    out = []
    for key in extra:
        if not has_column(chunk, key):
            out.append(np.full(n, np.nan))
            continue
        try:
            out.append(np.asarray(chunk[key], dtype=np.float64).ravel())
        except (TypeError, ValueError) as err:
            raise DataError(f"pushed column {key} is not numeric") from err
    return out


def time_unit(step: float) -> tuple[str, float]:
    """The unit of a time column whose samples are ``step`` apart (in that unit), and its
    length in seconds; a DataError where no unit makes it a drive log's step."""
    lo, hi = STEP_RANGE_S
    for name, seconds in TIME_UNITS:
        if lo <= step * seconds <= hi:
            return name, seconds
    raise DataError(f"pushed t advances by {step:.6g} per sample: neither seconds, ms, us nor "
                    f"ns give a drive log's step ({lo:g} to {hi:g} s)")


class Regrid:
    """Samples, as they come, onto the grid of step ``t_s`` (see the module docstring).

    A piece's grid starts at its first sample; grid times between two samples are interpolated
    (the heading along its shorter way round); a sample on a grid time passes as it is, and the
    grid goes on from its time (float time stamps never drift off it).
    """

    def __init__(self, t_s: float) -> None:
        self.t_s = t_s
        self._last: FloatArray | None = None       # the last sample (SAMPLE order)
        self._next: float | None = None             # the next grid time of the piece
        self._steps: list[float] = []               # the stream's recent steps

    def add(self, samples: FloatArray) -> FloatArray:
        """Samples (M, len(SAMPLE) and any model inputs), in time order, continuing the stream;
        the grid's samples they complete (K, as many columns)."""
        if samples.shape[0] and self._last is not None and self._next is not None:
            t = samples[:, 0]
            steps = np.diff(t, prepend=self._last[0])
            tol = _ON_GRID * self.t_s
            if abs(float(t[0]) - self._next) <= tol and np.all(np.abs(steps - self.t_s) <= tol):
                # every sample on the grid (the usual case): as they are
                self._steps.extend(steps[-_RECENT_STEPS:].tolist())
                del self._steps[:-_RECENT_STEPS]
                self._last = samples[-1].copy()
                self._next = float(t[-1]) + self.t_s
                return samples
        out: list[FloatArray] = []
        for row in samples:
            out.extend(self._one(row))
        return np.array(out, dtype=np.float64).reshape(-1, samples.shape[1])

    def _gap(self, step: float) -> bool:
        local = float(np.median(self._steps)) if self._steps else self.t_s
        return step > GAP_FACTOR * max(self.t_s, local)

    def _one(self, row: FloatArray) -> list[FloatArray]:
        row = row.copy()
        last, self._last = self._last, row
        if last is None or self._next is None:
            self._next = float(row[0]) + self.t_s
            return [row]
        step = float(row[0] - last[0])
        gap = self._gap(step)
        self._steps.append(step)
        del self._steps[:-_RECENT_STEPS]
        if gap:                                    # a new piece starts with this sample
            self._next = float(row[0]) + self.t_s
            return [row]
        out: list[FloatArray] = []
        tol = _ON_GRID * self.t_s
        while self._next <= float(row[0]) + tol:
            g = self._next
            if abs(g - float(row[0])) <= tol:        # on the grid: the sample as it is
                out.append(row)
                self._next = float(row[0]) + self.t_s
                break
            frac = (g - float(last[0])) / step
            mid = last + frac * (row - last)
            turn = math.remainder(float(row[7] - last[7]), 2.0 * math.pi)
            mid[7] = last[7] + frac * turn
            mid[0] = g
            out.append(mid)
            self._next = g + self.t_s
        return out


class Intake:
    """The pushed chunks as samples on one grid: the time unit told from the first two samples
    (a lone first sample waits for the next), every chunk's ``t`` checked to continue the ones
    before, and the samples put onto the first ones' grid (:class:`Regrid`).

    ``samples`` counts every sample pushed; ``first_t`` and ``last_t`` are the first and the
    latest sample's time in seconds; ``unit`` how ``t`` came; ``t_s`` the grid's step (None
    until two samples have come). ``extra``: a model's own inputs, taken after :data:`SAMPLE`
    (:func:`rows`).
    """

    def __init__(self, extra: tuple[str, ...] = ()) -> None:
        self.extra = extra
        self.samples = 0
        self.unit: str | None = None
        self.t_s: float | None = None
        self.first_t: float | None = None
        self.last_t: float | None = None
        self._scale = 1.0
        self._pending: FloatArray | None = None
        self._regrid: Regrid | None = None

    def take(self, chunk: Any) -> FloatArray:
        """The chunk's samples, ``t`` in seconds (none where it is empty or a lone first
        sample); a DataError, with nothing taken, where ``t`` does not increase."""
        data, stamped = rows(chunk, self.extra)
        count = data.shape[0]
        if count == 0:
            return data
        if count > 1 and np.any(np.diff(data[:, 0]) <= 0):
            raise DataError(_NOT_INCREASING)
        if self.unit is None:
            return self._first(data, stamped)
        if not stamped:
            data[:, 0] *= self._scale
        if self.last_t is not None and data[0, 0] <= self.last_t:
            raise DataError(_NOT_INCREASING)
        self.samples += count
        self.last_t = float(data[-1, 0])
        return data

    def _first(self, data: FloatArray, stamped: bool) -> FloatArray:
        """The first samples: the unit and the grid's step from the first two."""
        count = data.shape[0]
        if self._pending is not None:
            data = np.vstack([self._pending, data])
            if data[1, 0] <= data[0, 0]:
                raise DataError(_NOT_INCREASING)
        if data.shape[0] < 2:                         # one sample so far: wait for more
            self.samples += count
            self._pending = data.copy()
            return data[:0]
        unit, scale = ("datetime", 1.0) if stamped else time_unit(
            float(np.median(np.diff(data[:, 0]))))
        data[:, 0] *= scale
        self.first_t = float(data[0, 0])
        self._pending = None
        self.unit, self._scale = unit, scale
        self.t_s = step_s(data[:, 0])
        self._regrid = Regrid(self.t_s)
        self.samples += count
        self.last_t = float(data[-1, 0])
        return data

    def grid(self, data: FloatArray) -> FloatArray:
        """Samples taken (in seconds) onto the grid (:class:`Regrid`)."""
        assert self._regrid is not None
        return self._regrid.add(data)


_NOT_INCREASING = "pushed samples' t must increase strictly (and continue the previous chunk)"
