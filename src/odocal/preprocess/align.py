"""Bringing streams with their own clocks and rates onto one uniform grid.

1. **Clean** each stream: samples are sorted by time (out-of-order stamps are counted), repeated
   stamps keep their first sample (counted), samples with missing values are dropped (counted).
2. **Offsets**: a constant per stream, given by the user, or for the wheel stream estimated by
   cross-correlating the yaw rate the wheels imply with the IMU's yaw rate.
3. **Span and gaps**: the grid covers the span every required stream covers; a stream gap longer
   than the limit makes the grid points inside it invalid, which splits the drive into pieces.
4. **Resampling**: linear interpolation (angles unwrapped first) onto the valid grid points.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from odocal.arrays import BoolArray, FloatArray
from odocal.correlation import correlations
from odocal.data.drive import MODEL_INPUTS
from odocal.errors import DataError
from odocal.io.streams import ANGLES, RawLog, Stream
from odocal.model.vehicle import MODEL


@dataclass(frozen=True)
class StreamReport:
    """What cleaning and alignment found in one stream (for ``inspect`` and the drive metadata)."""

    name: str
    role: str
    samples: int
    rate_hz: float
    start_s: float
    end_s: float
    out_of_order: int
    duplicates: int
    missing: int
    gaps: int
    longest_gap_s: float
    offset_s: float
    units: Mapping[str, str]
    dropped: tuple[str, ...] = ()
    """Further inputs left out for missing values (a model's beyond the rear axle's: a front
    wheel, the steering), so that they cost none of the rear wheels' samples."""

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self) | {"units": dict(self.units),
                                           "dropped": list(self.dropped)}


def clean(stream: Stream) -> tuple[Stream, StreamReport]:
    """Sort, drop repeated stamps and missing values; report what was done. A further input
    (:data:`~odocal.data.drive.MODEL_INPUTS`: a front wheel, the steering) with missing values
    is left out whole rather than cost the samples of the rear wheels."""
    t = np.asarray(stream.t, dtype=np.float64)
    finite_t = np.isfinite(t)
    order = np.argsort(t, kind="stable")
    out_of_order = int(np.sum(np.diff(t[finite_t]) < 0))
    t_sorted = t[order]
    keep = np.isfinite(t_sorted)
    keep[1:] &= np.diff(t_sorted) > 0
    duplicates = int(np.sum(np.isfinite(t_sorted)) - np.sum(keep))
    values = {k: np.asarray(v, dtype=np.float64)[order] for k, v in stream.values.items()}
    dropped = tuple(k for k, v in values.items()
                    if k in MODEL_INPUTS and not np.all(np.isfinite(v[keep])))
    values = {k: v for k, v in values.items() if k not in dropped}
    complete = keep.copy()
    for v in values.values():
        complete &= np.isfinite(v)
    missing = int(np.sum(keep) - np.sum(complete))
    t_clean = t_sorted[complete]
    values = {k: v[complete] for k, v in values.items()}
    dt = np.diff(t_clean)
    period = float(np.median(dt)) if dt.size else 0.0
    limit = max(2.5 * period, 1e-9)
    gap_mask = dt > limit
    cleaned = Stream(name=stream.name, role=stream.role, t=t_clean, values=values,
                     units=stream.units, offset_s=stream.offset_s)
    rate = 1.0 / period if period > 0 else 0.0
    report = StreamReport(
        name=stream.name, role=stream.role, samples=int(t_clean.size), rate_hz=rate,
        start_s=float(t_clean[0] + stream.offset_s) if t_clean.size else float("nan"),
        end_s=float(t_clean[-1] + stream.offset_s) if t_clean.size else float("nan"),
        out_of_order=out_of_order, duplicates=duplicates, missing=missing,
        gaps=int(gap_mask.sum()), longest_gap_s=float(dt.max()) if dt.size else 0.0,
        offset_s=stream.offset_s,
        units={k: u for k, u in stream.units.items() if k not in dropped}, dropped=dropped)
    return cleaned, report


def with_offset(stream: Stream, offset_s: float) -> Stream:
    return dataclasses.replace(stream, offset_s=offset_s)


@dataclass(frozen=True)
class OffsetEstimate:
    """The wheel stream's clock offset found against the IMU yaw rate.

    offset_s : add this to the wheel stamps (0 when not estimable)
    correlation : peak normalised cross-correlation (1 is a perfect match)
    estimated : False when the log has too little turning to tell
    message : plain-words summary
    """

    offset_s: float
    correlation: float
    estimated: bool
    message: str

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


#: A wheel/IMU lag found at a lower correlation than this is no clock offset: the two yaw
#: rates do not describe one motion (noise, a unit or mapping mistake), and none is applied.
MIN_OFFSET_CORRELATION = 0.3


def estimate_wheel_offset(wheels: Stream, imu: Stream, *, theta: Sequence[float],
                          max_offset_s: float,
                          rate_hz: float = 200.0) -> OffsetEstimate:
    """Cross-correlate the wheels' yaw rate (the model's, with the datasheet ``theta``; for
    the rear axle ``(n_rr - n_rl) c / t_r``) with the IMU's.

    Both are resampled to ``rate_hz`` over their common span; the lag with the highest
    correlation (:mod:`odocal.correlation`), refined by a parabola through its neighbours, is
    the offset to add to the wheel stamps. Without enough turning (IMU yaw-rate spread below
    0.02 rad/s), or where even the best lag correlates below :data:`MIN_OFFSET_CORRELATION`,
    nothing is applied.
    """
    tw = wheels.t + wheels.offset_s
    ti = imu.t + imu.offset_s
    lo, hi = max(tw[0], ti[0]) + max_offset_s, min(tw[-1], ti[-1]) - max_offset_s
    if hi - lo < 10.0:
        return OffsetEstimate(0.0, float("nan"), False,
                              "wheel and IMU streams overlap too briefly to estimate an offset")
    grid = np.arange(lo, hi, 1.0 / rate_hz)
    yaw_imu = np.interp(grid, ti, imu.values["yaw_rate"])
    if np.std(yaw_imu) < 0.02:
        return OffsetEstimate(0.0, float("nan"), False,
                              "too little turning to estimate the wheel clock offset; none "
                              "applied")
    rates = np.column_stack([wheels.values[c] for c in MODEL.wheel_inputs])
    _, yaw_wheels_t = MODEL.body_rates(np.asarray(theta, dtype=float), rates, 0.0)
    reach = int(max_offset_s * rate_hz)
    # the wheels' yaw rate reaches beyond the grid: every lag compares the whole grid
    wide = np.interp(grid[0] + np.arange(-reach, grid.size + reach) / rate_hz, tw, yaw_wheels_t)
    peak = correlations([(yaw_imu, wide)], reach).peak()
    correlation = peak.correlation if peak is not None else float("nan")
    delay = peak.steps / rate_hz if peak is not None else 0.0
    if peak is None or correlation < MIN_OFFSET_CORRELATION:
        return OffsetEstimate(0.0, correlation, False,
                              f"the wheels' yaw rate hardly follows the IMU's (best correlation "
                              f"{correlation:.3f} at {delay * 1000:+.0f} ms); no offset "
                              "applied (check the wheel units, a wrapping tick counter, or "
                              "which wheel is which)")
    if peak.at_edge:
        return OffsetEstimate(0.0, correlation, False,
                              f"the best wheel/IMU lag lies at the edge of the search range "
                              f"(+-{max_offset_s} s); no offset applied")
    return OffsetEstimate(-delay, correlation, True,
                          f"wheel stamps are {delay * 1000:+.1f} ms late against the IMU "
                          f"(correlation {correlation:.3f}); corrected")


@dataclass(frozen=True)
class Grid:
    """The common time grid and which of its points every required stream covers.

    t : ndarray, shape (G,), uniform with step 1/rate
    pieces : index ranges [start, stop) of runs of valid points, each long enough
    """

    t: FloatArray
    pieces: tuple[tuple[int, int], ...]

    @property
    def valid(self) -> BoolArray:
        mask = np.zeros(self.t.shape, dtype=bool)
        for a, b in self.pieces:
            mask[a:b] = True
        return mask


def common_grid(streams: Sequence[Stream], *, rate_hz: float, max_gap_s: float,
                max_gnss_gap_s: float, min_piece_s: float, name: str) -> Grid:
    """The grid over the span all ``streams`` cover, split where any has a gap."""
    spans = [(s.name, s.t[0] + s.offset_s, s.t[-1] + s.offset_s) for s in streams]
    start = max(a for _, a, _ in spans)
    end = min(b for _, _, b in spans)
    if not end > start:
        first_end = min(spans, key=lambda s: s[2])
        last_start = max(spans, key=lambda s: s[1])
        raise DataError(
            f"'{name}': stream '{last_start[0]}' ({last_start[1]:.3f}-{last_start[2]:.3f} s) does "
            f"not overlap stream '{first_end[0]}' ({first_end[1]:.3f}-{first_end[2]:.3f} s); "
            "check the time stamps or set a time offset")
    step = 1.0 / rate_hz
    t = start + step * np.arange(int(np.floor((end - start) / step)) + 1)
    valid = np.ones(t.shape, dtype=bool)
    for s in streams:
        ts = s.t + s.offset_s
        dt = np.diff(ts)
        period = float(np.median(dt)) if dt.size else step
        limit = max_gnss_gap_s if s.role == "gnss" else max(max_gap_s, 2.5 * period)
        for i in np.flatnonzero(dt > limit):
            valid &= ~((t > ts[i]) & (t < ts[i + 1]))
    edges = np.flatnonzero(np.diff(np.concatenate([[0], valid.astype(np.int8), [0]])))
    runs = [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]
    min_len = max(int(np.ceil(min_piece_s * rate_hz)), 3)
    pieces = tuple((a, b) for a, b in runs if b - a >= min_len)
    if not pieces:
        longest = max(((b - a) * step for a, b in runs), default=0.0)
        raise DataError(f"'{name}': the streams share no stretch of at least {min_piece_s:g} s "
                        f"without gaps (longest {longest:.1f} s)")
    return Grid(t=t, pieces=pieces)


def resample(stream: Stream, grid: FloatArray) -> dict[str, FloatArray]:
    """Every quantity of ``stream`` linearly interpolated at ``grid`` (angles unwrapped)."""
    ts = stream.t + stream.offset_s
    out: dict[str, FloatArray] = {}
    for key, values in stream.values.items():
        v = np.unwrap(values) if (stream.role, key) in ANGLES else values
        out[key] = np.interp(grid, ts, v)
    return out


def clean_log(log: RawLog, offsets: Mapping[str, float] | None = None
              ) -> tuple[RawLog, dict[str, StreamReport]]:
    """Clean every stream of ``log`` and apply user offsets (by role)."""
    streams: dict[str, Stream] = {}
    reports: dict[str, StreamReport] = {}
    for role, stream in log.streams.items():
        if offsets and role in offsets:
            stream = with_offset(stream, float(offsets[role]))
        cleaned, report = clean(stream)
        if cleaned.t.size < 2:
            raise DataError(f"'{log.name}': stream '{stream.name}' has {cleaned.t.size} usable "
                            "samples")
        streams[role] = cleaned
        reports[role] = report
    return dataclasses.replace(log, streams=streams), reports
