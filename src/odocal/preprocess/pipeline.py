"""A raw log to a :class:`~odocal.data.drive.Drive`: clean, align, fuse, estimate sideslip."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from odocal.arrays import BoolArray, FloatArray
from odocal.data.drive import MODEL_INPUTS, Drive
from odocal.errors import DataError
from odocal.io.streams import RawLog, Stream
from odocal.preprocess.align import (
    OffsetEstimate,
    StreamReport,
    clean_log,
    common_grid,
    estimate_wheel_offset,
    resample,
    with_offset,
)
from odocal.preprocess.fusion import fuse
from odocal.preprocess.sideslip import estimate_sideslip
from odocal.settings import Settings, datasheet_stated


@dataclass(frozen=True)
class ConversionReport:
    """How a raw log became a drive (stored in the drive's metadata as ``conversion``)."""

    log: str
    streams: dict[str, StreamReport]
    reference: str
    wheel_offset: OffsetEstimate | None
    pieces: list[tuple[float, float]]
    dropped_s: float
    sideslip: str
    fusion: list[dict[str, Any]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return {"log": self.log,
                "streams": {k: v.to_dict() for k, v in self.streams.items()},
                "reference": self.reference,
                "wheel_offset": self.wheel_offset.to_dict() if self.wheel_offset else None,
                "pieces_s": [list(p) for p in self.pieces], "dropped_s": self.dropped_s,
                "sideslip": self.sideslip, "fusion": self.fusion, "notes": list(self.notes)}


def _reference_mode(log: RawLog, requested: str) -> str:
    has_pose = "pose" in log.streams
    if requested == "auto" and not has_pose and "gnss" not in log.streams:
        raise DataError(f"'{log.name}' has no reference pose: neither a fused pose (a mapping's "
                        "[pose] section: x, y, heading) nor GNSS positions for odocal's own "
                        "fusion (a [gnss] section: latitude, longitude); found: "
                        f"{', '.join(sorted(log.streams)) or 'nothing'}")
    if requested == "auto":
        return "fused" if has_pose else "gnss-imu"
    if requested == "fused" and not has_pose:
        raise DataError(f"'{log.name}' has no fused pose stream for --reference fused; use "
                        "--reference gnss-imu (odocal's own fusion of GNSS and IMU)")
    return requested


def build_drive(log: RawLog, settings: Settings, *,
                offsets: Mapping[str, float] | None = None) -> Drive:
    """Clean, align and resample ``log`` onto the grid, build its reference pose, and check the
    result like any drive file (units, NaNs, ...). ``offsets`` (s, by role) shift stream clocks;
    a wheel offset given there is used instead of the estimate."""
    cs = settings.convert
    mode = _reference_mode(log, cs.reference)
    log, reports = clean_log(log, offsets)
    notes: list[str] = []
    wheels, imu, reference_stream = _streams(log, mode)

    offset_estimate = None
    if imu is not None and "yaw_rate" in imu.values and not (offsets and "wheels" in offsets) \
            and cs.wheel_offset == "estimate":
        wheels, offset_estimate = _wheel_clock(wheels, imu, settings)
        reports["wheels"] = dataclasses.replace(reports["wheels"],
                                                offset_s=offset_estimate.offset_s)
        notes.append(offset_estimate.message)

    required = [wheels, reference_stream] + ([imu] if imu is not None else [])
    grid = common_grid(required, rate_hz=cs.rate_hz, max_gap_s=cs.max_gap_s,
                       max_gnss_gap_s=cs.max_gnss_gap_s, min_piece_s=cs.min_piece_s,
                       name=log.name)
    t = grid.t[grid.valid]
    dropped = float((grid.t.size - t.size) / cs.rate_hz)
    piece_col, piece_ranges = _pieces(grid.pieces)

    w = resample(wheels, t)
    columns: dict[str, FloatArray] = {"t": t, "n_rl": w["n_rl"], "n_rr": w["n_rr"],
                                      "piece": piece_col,
                                      **{k: w[k] for k in MODEL_INPUTS if k in w}}
    imu_values = resample(imu, t) if imu is not None else {}
    reference, yaw_rate, speed, course, fusion_summaries = _reference_columns(
        log, mode, reference_stream, t, piece_ranges, imu_values, settings)
    columns.update(reference)

    if "a_y" in imu_values:
        columns["a_y"] = imu_values["a_y"]
    else:
        notes.append("no IMU lateral acceleration: a_y is derived from the reference as speed "
                     "times yaw rate")
        columns["a_y"] = _derived_lateral_accel(columns, piece_ranges, cs.rate_hz)
    if yaw_rate is not None:
        columns["yaw_rate"] = yaw_rate

    columns["beta"], slip_note = _sideslip(log.name, columns, course, speed, yaw_rate,
                                           settings)

    report = ConversionReport(
        log=log.name, streams=reports, reference=mode, wheel_offset=offset_estimate,
        pieces=[(float(t[a]), float(t[b - 1])) for a, b in piece_ranges], dropped_s=dropped,
        sideslip=slip_note, fusion=fusion_summaries, notes=notes)
    stated = settings.identify.datasheet("c_e") if datasheet_stated(settings.identify.theta0) \
        else None
    return Drive.from_columns(columns, name=log.name, metadata=_metadata(log, report),
                              circumference_m=stated)


def _streams(log: RawLog, mode: str) -> tuple[Stream, Stream | None, Stream]:
    """The wheel stream, the IMU's (None where the log has none) and the reference's (the
    pose stream for ``fused``, GNSS for ``gnss-imu``, which also needs the IMU's yaw rate)."""
    wheels = log.require("wheels", "rear wheel rotation rates")
    imu = log.streams.get("imu")
    if mode == "gnss-imu":
        log.require("gnss", "GNSS positions, for --reference gnss-imu")
        if imu is None or "yaw_rate" not in imu.values:
            raise DataError(f"'{log.name}' has no IMU yaw rate, which --reference gnss-imu needs")
    reference_stream = log.streams["pose"] if mode == "fused" else log.streams["gnss"]
    return wheels, imu, reference_stream


def _pieces(pieces: tuple[tuple[int, int], ...]
            ) -> tuple[FloatArray, list[tuple[int, int]]]:
    """The grid's pieces on the valid points alone: the ``piece`` column (each point's piece
    number) and each piece's index range [start, stop)."""
    piece_col = np.concatenate([np.full(b - a, i, dtype=np.float64)
                                for i, (a, b) in enumerate(pieces)])
    bounds = np.concatenate([[0], np.cumsum([b - a for a, b in pieces])])
    return piece_col, [(int(bounds[i]), int(bounds[i + 1])) for i in range(len(pieces))]


def _reference_columns(log: RawLog, mode: str, reference_stream: Stream, t: FloatArray,
                       piece_ranges: list[tuple[int, int]], imu_values: dict[str, FloatArray],
                       settings: Settings
                       ) -> tuple[dict[str, FloatArray], FloatArray | None, FloatArray | None,
                                  FloatArray | None, list[dict[str, Any]]]:
    """The reference on the grid ``t``: a given pose (``fused``) resampled, its course and
    speed from its velocity where it has one, or odocal's own from GNSS and the IMU
    (:func:`_gnss_imu_reference`).

    Returns the pose columns, the yaw rate, the speed, the course over ground (each None
    where not known) and each piece's fusion summary (none for a given pose).
    """
    if mode != "fused":
        return _gnss_imu_reference(log, reference_stream, t, piece_ranges, imu_values, settings)
    course: FloatArray | None = None
    speed: FloatArray | None = None
    pose = resample(reference_stream, t)
    columns = {"x": pose["x"], "y": pose["y"], "psi": pose["psi"]}
    if "vx" in pose and "vy" in pose:
        course = np.arctan2(pose["vy"], pose["vx"])
        speed = np.hypot(pose["vx"], pose["vy"])
    return columns, imu_values.get("yaw_rate"), speed, course, []


def _metadata(log: RawLog, report: ConversionReport) -> dict[str, Any]:
    """The drive's metadata: the log's, with the conversion report and the ENU origin."""
    metadata = {**dict(log.metadata), "conversion": report.to_dict()}
    if log.origin_lla is not None:
        metadata["origin_lla"] = list(log.origin_lla)
    return metadata


def _wheel_clock(wheels: Stream, imu: Stream, settings: Settings
                 ) -> tuple[Stream, OffsetEstimate]:
    """The wheel stream shifted by its clock offset against the IMU yaw rate (estimated)."""
    ident = settings.identify
    estimate = estimate_wheel_offset(wheels, imu, theta=ident.theta0,
                                     max_offset_s=settings.convert.max_wheel_offset_s)
    return with_offset(wheels, estimate.offset_s), estimate


def _gnss_imu_reference(log: RawLog, gnss: Stream, t: FloatArray,
                        piece_ranges: list[tuple[int, int]], imu_values: dict[str, FloatArray],
                        settings: Settings
                        ) -> tuple[dict[str, FloatArray], FloatArray, FloatArray, FloatArray,
                                   list[dict[str, Any]]]:
    """odocal's own reference: GNSS and the IMU fused piece by piece (EKF and RTS smoother).

    Returns the pose columns (with their standard deviations), the bias-corrected yaw rate,
    the speed and course over ground, and each piece's fusion summary.
    """
    heading = log.streams.get("heading")
    x, y, psi = (np.empty(t.size) for _ in range(3))
    std = np.empty((t.size, 3))
    yaw_rate = np.empty(t.size)
    speed = np.empty(t.size)
    course = np.empty(t.size)
    summaries: list[dict[str, Any]] = []
    for a, b in piece_ranges:
        tg = gnss.t + gnss.offset_s
        inside = (tg >= t[a] - 1.0) & (tg <= t[b - 1] + 1.0)
        ht = heading.t + heading.offset_s if heading is not None else None
        fused = fuse(t[a:b], imu_values["yaw_rate"][a:b], gnss_t=tg[inside],
                     east=gnss.values["east"][inside], north=gnss.values["north"][inside],
                     gnss_speed=_opt(gnss, "speed", inside),
                     gnss_course=_opt(gnss, "course", inside),
                     gnss_std=_opt(gnss, "std", inside),
                     heading_t=ht, heading=heading.values["psi"] if heading else None,
                     settings=settings.fusion, name=log.name)
        x[a:b], y[a:b], psi[a:b], std[a:b] = fused.x, fused.y, fused.psi, fused.std
        yaw_rate[a:b] = imu_values["yaw_rate"][a:b] - fused.gyro_bias
        speed[a:b] = fused.speed
        course[a:b] = fused.psi + fused.sideslip      # the smoothed course over ground
        summaries.append(fused.summary())
    columns = {"x": x, "y": y, "psi": psi, "x_std": std[:, 0], "y_std": std[:, 1],
               "psi_std": std[:, 2]}
    return columns, yaw_rate, speed, course, summaries


def _sideslip(name: str, columns: dict[str, FloatArray], course: FloatArray | None,
              speed: FloatArray | None, yaw_rate: FloatArray | None,
              settings: Settings) -> tuple[FloatArray, str]:
    """The sideslip column (course over ground against heading, in bends) and a note on it."""
    sideslip, rate_hz = settings.sideslip, settings.convert.rate_hz
    t_size = columns["t"].size
    has_course = course is not None and speed is not None
    if sideslip.mode == "on" and not has_course:
        raise DataError(f"'{name}': sideslip estimation needs a course over ground "
                        "independent of the heading (GNSS velocity or a pose velocity)")
    if sideslip.mode == "off" or not has_course:
        note = "off" if sideslip.mode == "off" else \
            "off: the log has no course over ground independent of the heading"
        return np.zeros(t_size), note
    assert course is not None and speed is not None
    rate = yaw_rate if yaw_rate is not None else np.gradient(np.unwrap(columns["psi"]),
                                                             1.0 / rate_hz)
    beta = estimate_sideslip(course, np.unwrap(columns["psi"]), rate, speed, rate_hz=rate_hz,
                             settings=sideslip)
    note = (f"estimated in bends (|yaw rate| > {sideslip.bend_yaw_rate_radps} rad/s): "
            f"{np.mean(beta != 0) * 100:.1f}% of samples, max "
            f"{np.degrees(np.max(np.abs(beta))):.2f} deg")
    return beta, note


def _opt(stream: Stream, key: str, mask: BoolArray) -> FloatArray | None:
    values = stream.values.get(key)
    return None if values is None else values[mask]


def _derived_lateral_accel(columns: Mapping[str, FloatArray],
                           pieces: list[tuple[int, int]], rate_hz: float) -> FloatArray:
    out = np.zeros(columns["t"].size)
    for a, b in pieces:
        if b - a < 3:
            continue
        speed = np.hypot(np.gradient(columns["x"][a:b]), np.gradient(columns["y"][a:b])) * rate_hz
        out[a:b] = speed * np.gradient(np.unwrap(columns["psi"][a:b])) * rate_hz
    return out
