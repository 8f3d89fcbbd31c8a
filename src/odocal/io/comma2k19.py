"""A comma2k19 segment folder: ``processed_log/`` and ``global_pose/`` (NumPy arrays).

* ``processed_log/CAN/wheel_speed`` (N, 4) [FL, FR, RL, RR] m/s (the car's own conversion with its
  nominal circumference): turned into rotation rates with a nominal circumference; the front
  two and ``CAN/steering_angle`` (degrees) are the four-wheel model's further inputs
* ``processed_log/IMU/gyro``, ``accelerometer`` in the phone frame [forward, right, down]: the
  left-positive yaw rate is ``-gyro[:, 2]``, the left-positive lateral acceleration
  ``-accelerometer[:, 1]``
* ``processed_log/GNSS/live_gnss_ublox`` (N, 6) [lat deg, lon deg, speed m/s, UTC ms, alt m,
  bearing deg clockwise from north]
* ``global_pose/frame_positions`` ECEF m, ``frame_velocities`` ECEF m/s,
  ``frame_orientations`` quaternion [w, x, y, z] camera (forward, right, down) to ECEF, at 20 Hz:
  comma's fused pose. Its velocity gives a course independent of the orientation.

Times are device boot time in seconds. Positions become a local ENU frame about the first pose.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from odocal.arrays import FloatArray
from odocal.errors import DataError, InputFileError, shown
from odocal.io.geodesy import check_lla, ecef_origin, ecef_to_enu, ecef_vectors_to_enu, lla_to_enu
from odocal.io.registry import ReadOptions
from odocal.io.streams import RawLog, Stream
from odocal.io.units import wheel_rate_revps


def _load(folder: Path, rel: str) -> FloatArray:
    path = folder / rel
    if not path.is_file():
        raise DataError(f"comma2k19 segment '{folder}' lacks {rel}")
    try:
        return np.asarray(np.load(path, allow_pickle=False), dtype=np.float64)
    except (ValueError, OSError) as exc:
        raise DataError(f"comma2k19 segment '{folder}': {rel} cannot be read: {exc}") from exc


def _series(folder: Path, name: str) -> tuple[FloatArray, FloatArray]:
    t = _load(folder, f"{name}/t")
    v = _load(folder, f"{name}/value")
    if v.shape[0] != t.shape[0]:
        raise DataError(f"comma2k19 segment '{folder}': {name} has {v.shape[0]} values and "
                        f"{t.shape[0]} times")
    return t, v


def _wheels(log_dir: Path, tw: FloatArray, ws: FloatArray, circumference_m: float) -> Stream:
    """The four wheels' speeds as rates of a ``circumference_m`` wheel, and the steering-wheel
    angle (degrees, taken at the wheels' clock) where the segment has it."""
    rates = {name: wheel_rate_revps(ws[:, column], "m/s", stream="wheel_speed",
                                    circumference_m=circumference_m)
             for name, column in (("n_fl", 0), ("n_fr", 1), ("n_rl", 2), ("n_rr", 3))}
    units = {name: f"m/s (circumference {circumference_m} m)" for name in rates}
    if (log_dir / "CAN" / "steering_angle").is_dir():
        ts, angle = _series(log_dir, "CAN/steering_angle")
        if angle.ndim == 1 and ts.size > 1 and np.all(np.diff(ts) > 0):
            rates["steer"] = np.deg2rad(np.interp(tw, ts, angle))
            units["steer"] = "deg"
    return Stream(name="CAN/wheel_speed", role="wheels", t=tw, values=rates, units=units)


def read_comma2k19(source: str | Path, *, circumference_m: float) -> RawLog:
    folder = Path(source)
    if not folder.is_dir():
        raise InputFileError(f"comma2k19 segment folder '{folder}' does not exist")
    log_dir = folder / "processed_log"
    tw, ws = _series(log_dir, "CAN/wheel_speed")
    if ws.ndim != 2 or ws.shape[1] != 4:
        raise DataError(f"comma2k19 segment '{folder}': CAN/wheel_speed must be (N, 4)")
    tg, gyro = _series(log_dir, "IMU/gyro")
    ta, acc = _series(log_dir, "IMU/accelerometer")
    if not np.array_equal(tg, ta):
        acc = np.column_stack([np.interp(tg, ta, acc[:, i]) for i in range(3)])
    tu, ublox = _series(log_dir, "GNSS/live_gnss_ublox")
    if ublox.ndim != 2 or ublox.shape[1] != 6:
        raise DataError(f"comma2k19 segment '{folder}': GNSS/live_gnss_ublox must be (N, 6)")
    check_lla(ublox[:, 0], ublox[:, 1], stream="live_gnss_ublox")

    streams: dict[str, Stream] = {
        "wheels": _wheels(log_dir, tw, ws, circumference_m),
        "imu": Stream(name="IMU/gyro+accelerometer", role="imu", t=tg,
                      values={"yaw_rate": -gyro[:, 2], "a_y": -acc[:, 1]},
                      units={"yaw_rate": "rad/s (phone frame, -z)",
                             "a_y": "m/s^2 (phone frame, -y)"}),
    }
    pose_dir = folder / "global_pose"
    if pose_dir.is_dir():
        tp = _load(pose_dir, "frame_times")
        pos = _load(pose_dir, "frame_positions")
        vel = _load(pose_dir, "frame_velocities")
        quat = _load(pose_dir, "frame_orientations")
        origin = ecef_origin(*pos[0])
        east, north, _ = ecef_to_enu(pos[:, 0], pos[:, 1], pos[:, 2], origin)
        forward = Rotation.from_quat(quat[:, [1, 2, 3, 0]]).apply([1.0, 0.0, 0.0])
        fe, fn, _ = ecef_vectors_to_enu(forward[:, 0], forward[:, 1], forward[:, 2], origin)
        ve, vn, _ = ecef_vectors_to_enu(vel[:, 0], vel[:, 1], vel[:, 2], origin)
        streams["pose"] = Stream(name="global_pose", role="pose", t=tp,
                                 values={"x": east, "y": north, "psi": np.arctan2(fn, fe),
                                         "vx": ve, "vy": vn},
                                 units={"x": "ECEF m", "y": "ECEF m", "psi": "quaternion",
                                        "vx": "ECEF m/s", "vy": "ECEF m/s"})
    else:
        origin = (float(ublox[0, 0]), float(ublox[0, 1]), float(ublox[0, 4]))
    e, n, _ = lla_to_enu(ublox[:, 0], ublox[:, 1], ublox[:, 4], origin)
    streams["gnss"] = Stream(name="GNSS/live_gnss_ublox", role="gnss", t=tu,
                             values={"east": e, "north": n, "speed": ublox[:, 2],
                                     "course": np.pi / 2 - np.deg2rad(ublox[:, 5])},
                             units={"east": "deg", "north": "deg", "speed": "m/s",
                                    "course": "deg (compass)"})
    name = f"{folder.parent.name}/{folder.name}" if folder.name.isdigit() else folder.name
    return RawLog(name=name or str(folder), streams=streams,
                  origin_lla=origin,
                  metadata={"source_format": "comma2k19", "segment": str(folder),
                            "wheel_circumference_m": circumference_m,
                            "wheel_speed_unit": "m/s"})


def read(sources: Sequence[str | Path], *, mapping: Mapping[str, Mapping[str, Any]],
         options: ReadOptions) -> list[RawLog]:
    """The :class:`odocal.io.registry.Reader` of comma2k19 segment folders."""
    del mapping                                    # the format is fixed
    return [read_comma2k19(s, circumference_m=options.circumference_m)
            for source in sources for s in segment_folders(source)]


def segment_folders(source: str | Path) -> list[Path]:
    """``source`` if it is a segment folder (it holds ``processed_log/``), else the segment
    folders below it (a route folder ``ROUTE/N/``, or a dongle's ``DONGLE/ROUTE/N/``), in route
    and segment order; a DataError naming what was expected when there is none."""
    folder = Path(source)
    if not folder.is_dir():
        raise InputFileError(f"comma2k19 segment folder '{shown(folder)}' does not exist")
    if (folder / "processed_log").is_dir():
        return [folder]
    found = [p.parent for depth in ("*", "*/*", "*/*/*")
             for p in folder.glob(f"{depth}/processed_log") if p.is_dir()]
    if not found:
        raise DataError(f"'{shown(folder)}' is not a comma2k19 segment folder (no "
                        "processed_log/ in it or below it): give a segment folder such as "
                        "ROUTE/40/, or the route folder that holds them")

    def order(p: Path) -> tuple[str, int, str]:
        return (str(p.parent), int(p.name) if p.name.isdigit() else -1, p.name)

    return sorted(set(found), key=order)
