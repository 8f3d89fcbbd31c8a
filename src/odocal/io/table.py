"""The ``table`` format: one CSV or Parquet file per stream, described by a mapping file."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from odocal.arrays import FloatArray
from odocal.errors import ConfigError, DataError, InputFileError, input_file
from odocal.io.drivefile import read_table
from odocal.io.geodesy import check_lla, lla_to_enu
from odocal.io.registry import ReadOptions
from odocal.io.streams import RawLog, Stream
from odocal.io.units import (
    accel_mps2,
    angle_rad,
    angular_rate_radps,
    counter_modulus,
    heading_enu,
    time_seconds,
    wheel_rate_revps,
)


def _resolve(section: Mapping[str, Any], role: str, sources: Sequence[Path]) -> Path:
    if "file" not in section:
        raise ConfigError(f"mapping [{role}] needs a 'file' (one of the table files)")
    name = str(section["file"])
    for src in sources:
        if src.name == Path(name).name or str(src) == name:
            return src
    base = section.get("_base")
    candidate = (base / name) if base is not None else Path(name)
    if candidate.is_file():
        return candidate
    raise InputFileError(f"mapping [{role}] file '{name}' is neither among the sources nor "
                         f"beside the mapping file")


def _column(table: Mapping[str, FloatArray], section: Mapping[str, Any], key: str, role: str,
            path: Path, *, required: bool = True) -> FloatArray | None:
    name = section.get(key)
    if name is None:
        if required:
            raise ConfigError(f"mapping [{role}] needs '{key}' (a column of '{path.name}')")
        return None
    if name not in table:
        raise DataError(f"stream '{role}' ({path.name}): no column {name!r} (mapping [{role}] "
                        f"{key}); columns: {', '.join(table)}")
    return table[name]


def _counter_note(counts: FloatArray, t: FloatArray, bits: int | None) -> str:
    """``ticks``, and where the counter wraps, its width and how often it wrapped."""
    ordered = counts[np.argsort(t, kind="stable")]
    modulus = counter_modulus(ordered, bits=bits)
    if modulus is None:
        return "ticks"
    wraps = int(np.sum(np.abs(np.diff(ordered)) > modulus / 2))
    return f"ticks ({int(np.log2(modulus))}-bit counter, {wraps} wraps undone)"


class _Columns:
    """The columns of one stream's table by their mapping keys: called with ``key``, the column
    the mapping section names for it (None for an optional key it does not name)."""

    def __init__(self, table: Mapping[str, FloatArray], section: Mapping[str, Any], role: str,
                 path: Path) -> None:
        self.table, self.section, self.role, self.path = table, section, role, path

    def __call__(self, key: str, required: bool = True) -> FloatArray | None:
        return _column(self.table, self.section, key, self.role, self.path, required=required)


_Values = dict[str, FloatArray]
_Units = dict[str, str]


def stream_from_columns(role: str, table: Mapping[str, FloatArray], section: Mapping[str, Any],
                        *, name: str, path_label: Path, circumference_m: float,
                        origin: list[tuple[float, float, float]]) -> Stream:
    """Build one stream from already-read columns (shared by the table and rosbag readers).

    ``origin`` holds the ENU origin once the first GNSS stream has set it.
    """
    t = _stream_time(role, table, section, name=name, path_label=path_label)
    col = _Columns(table, section, role, path_label)
    if role == "wheels":
        values, units = _wheel_values(col, section, name=name, t=t,
                                      circumference_m=circumference_m)
    elif role == "imu":
        values, units = _imu_values(col, section, name=name)
    elif role == "pose":
        values, units = _pose_values(col, section, name=name)
    elif role == "gnss":
        values, units = _gnss_values(col, section, name=name, origin=origin)
    else:  # heading
        values, units = _heading_values(col, section, name=name)
    return Stream(name=name, role=role, t=t, values=values, units=units)


def _stream_time(role: str, table: Mapping[str, FloatArray], section: Mapping[str, Any], *,
                 name: str, path_label: Path) -> FloatArray:
    """The stream's time column in seconds (``time_unit``; date-times carry their own)."""
    t_raw = _column(table, section, "time", role, path_label)
    assert t_raw is not None
    unit = str(section.get("time_unit", "s"))
    if section.get("time") in getattr(table, "datetimes", ()) and unit not in ("s", "datetime"):
        raise ConfigError(f"mapping [{role}] time column {section['time']!r} of "
                          f"'{path_label.name}' holds date-times, which carry their own unit: "
                          f"drop time_unit = {unit!r} (or write \"datetime\")")
    return time_seconds(t_raw, unit, stream=name)


def _wheel_values(col: _Columns, section: Mapping[str, Any], *, name: str, t: FloatArray,
                  circumference_m: float) -> tuple[_Values, _Units]:
    """The rear wheels' rates ``n_rl``, ``n_rr`` in rev/s from the mapping's unit (rates,
    speeds or encoder ticks, a wrapping counter undone), with the units as logged; where the
    mapping names them, the front wheels' (``front_left``, ``front_right``: ``n_fl``,
    ``n_fr``, in the same unit) and the steering-wheel angle (``steering``, in
    ``steering_unit``: ``steer`` in rad), the four-wheel model's further inputs."""
    values: _Values = {}
    units: _Units = {}
    unit = str(section.get("unit", "rev/s"))
    bits = section.get("counter_bits")
    if ("front_left" in section) != ("front_right" in section):
        named = "front_left" if "front_left" in section else "front_right"
        raise ConfigError(f"mapping [wheels] names {named} without the other front wheel: "
                          "name both, or neither")
    for side, key in (("n_rl", "rear_left"), ("n_rr", "rear_right"), ("n_fl", "front_left"),
                      ("n_fr", "front_right")):
        raw = col(key, required=side in ("n_rl", "n_rr"))
        if raw is None:
            continue
        values[side] = wheel_rate_revps(
            raw, unit, stream=name, t=t,
            circumference_m=float(section.get("circumference_m", circumference_m)),
            ticks_per_rev=section.get("ticks_per_rev"), counter_bits=bits)
        units[side] = _counter_note(raw, t, bits) if unit == "ticks" else unit
    steering = col("steering", required=False)
    if steering is not None:
        steering_unit = str(section.get("steering_unit", "rad"))
        if steering_unit not in ("rad", "deg"):
            raise ConfigError(f"mapping [wheels] steering_unit = {steering_unit!r}: 'rad' or "
                              "'deg' (of the steering wheel)")
        values["steer"] = np.deg2rad(steering) if steering_unit == "deg" else steering
        units["steer"] = steering_unit
    return values, units


def _imu_values(col: _Columns, section: Mapping[str, Any], *, name: str
                ) -> tuple[_Values, _Units]:
    """The IMU's ``yaw_rate`` (rad/s) and ``a_y`` (m/s^2), either or both, in the x forward,
    y left, z up frame (a frd IMU's signs turned)."""
    values: _Values = {}
    units: _Units = {}
    frame = str(section.get("frame", "flu"))
    if frame not in ("flu", "frd"):
        raise DataError(f"stream '{name}': unknown IMU frame {frame!r}; use 'flu' (x forward, "
                        "y left, z up) or 'frd' (x forward, y right, z down)")
    sign = 1.0 if frame == "flu" else -1.0
    yaw = col("yaw_rate", required=False)
    if yaw is not None:
        unit = str(section.get("yaw_rate_unit", "rad/s"))
        values["yaw_rate"] = sign * angular_rate_radps(yaw, unit, stream=name)
        units["yaw_rate"] = unit
    acc = col("lateral_accel", required=False)
    if acc is not None:
        unit = str(section.get("lateral_accel_unit", "m/s^2"))
        values["a_y"] = sign * accel_mps2(acc, unit, stream=name)
        units["a_y"] = unit
    if not values:
        raise ConfigError("mapping [imu] needs yaw_rate and/or lateral_accel")
    return values, units


def _pose_values(col: _Columns, section: Mapping[str, Any], *, name: str
                 ) -> tuple[_Values, _Units]:
    """A pose stream's ``x``, ``y`` (m), heading ``psi`` (rad, ENU) and optional ``vx``,
    ``vy``."""
    values: _Values = {}
    units: _Units = {}
    for key in ("x", "y"):
        raw = col(key)
        assert raw is not None
        values[key] = raw
        units[key] = "m"
    heading = col("heading")
    assert heading is not None
    unit = str(section.get("heading_unit", "rad"))
    values["psi"] = heading_enu(angle_rad(heading, unit, stream=name),
                                str(section.get("heading_convention", "enu")), stream=name)
    units["psi"] = unit
    for key in ("vx", "vy"):
        raw = col(key, required=False)
        if raw is not None:
            values[key] = raw
    return values, units


def _gnss_values(col: _Columns, section: Mapping[str, Any], *, name: str,
                 origin: list[tuple[float, float, float]]) -> tuple[_Values, _Units]:
    """A GNSS stream's ``east``, ``north`` (m, ENU about ``origin``, which the first valid
    fix sets where it is empty) and optional ``speed`` (m/s), ``course`` (rad, ENU) and
    ``std`` (m)."""
    values: _Values = {}
    units: _Units = {}
    lat, lon = col("latitude"), col("longitude")
    assert lat is not None and lon is not None
    check_lla(lat, lon, stream=name)
    alt = col("altitude", required=False)
    alt = np.zeros_like(lat) if alt is None else alt
    if not origin:
        first = int(np.flatnonzero(np.isfinite(lat) & np.isfinite(lon))[0])
        origin.append((float(lat[first]), float(lon[first]), float(np.nan_to_num(alt[first]))))
    east, north, _ = lla_to_enu(lat, lon, alt, origin[0])
    values.update(east=east, north=north)
    units.update(east="deg (latitude/longitude)", north="deg (latitude/longitude)")
    speed = col("speed", required=False)
    if speed is not None:
        unit = str(section.get("speed_unit", "m/s"))
        if unit not in ("m/s", "km/h", "knots"):
            raise DataError(f"stream '{name}': unknown speed unit {unit!r}; use m/s, km/h "
                            "or knots")
        values["speed"] = speed * {"m/s": 1.0, "km/h": 1 / 3.6, "knots": 0.514444}[unit]
        units["speed"] = unit
    course = col("course", required=False)
    if course is not None:
        unit = str(section.get("course_unit", "deg"))
        values["course"] = heading_enu(angle_rad(course, unit, stream=name),
                                       str(section.get("course_convention", "compass")),
                                       stream=name)
        units["course"] = unit
    std = col("std", required=False)
    if std is not None:
        values["std"] = std
        units["std"] = "m"
    return values, units


def _heading_values(col: _Columns, section: Mapping[str, Any], *, name: str
                    ) -> tuple[_Values, _Units]:
    """A heading stream's ``psi`` (rad, ENU; compass degrees unless the mapping says)."""
    heading = col("heading")
    assert heading is not None
    unit = str(section.get("heading_unit", "deg"))
    psi = heading_enu(angle_rad(heading, unit, stream=name),
                      str(section.get("heading_convention", "compass")), stream=name)
    return {"psi": psi}, {"psi": unit}


def speed_metadata(mapping: Mapping[str, Mapping[str, Any]], circumference_m: float
                   ) -> dict[str, Any]:
    """What a log's metadata says of wheel speeds (m/s, km/h, mph) turned into rates: the
    circumference used and the unit (the calibration is then a scale factor on the speed
    signal); empty for wheel rates."""
    from odocal.io.units import WHEEL_SPEED_UNITS

    section = mapping.get("wheels", {})
    unit = str(section.get("unit", "rev/s"))
    if unit not in WHEEL_SPEED_UNITS:
        return {}
    return {"wheel_circumference_m": float(section.get("circumference_m", circumference_m)),
            "wheel_speed_unit": unit}


def read_table_log(sources: Sequence[str | Path], mapping: Mapping[str, Mapping[str, Any]], *,
                   circumference_m: float, name: str | None = None) -> RawLog:
    """Streams from CSV/Parquet files as the mapping describes them."""
    if not mapping:
        raise ConfigError("the table format needs a mapping file (--mapping) that says which "
                          "file and columns hold each stream")
    paths = [Path(s) for s in sources]
    for p in paths:
        input_file(p)
    streams: dict[str, Stream] = {}
    origin: list[tuple[float, float, float]] = []
    for role in ("gnss", "wheels", "imu", "pose", "heading"):
        section = mapping.get(role)
        if section is None:
            continue
        path = _resolve(section, role, paths)
        table = read_table(path)
        if not table or next(iter(table.values())).size == 0:
            raise DataError(f"stream '{role}' ({path.name}) has no rows")
        streams[role] = stream_from_columns(role, table, section, name=f"{role} ({path.name})",
                                            path_label=path, circumference_m=circumference_m,
                                            origin=origin)
    label = name or (paths[0].stem if paths else "table")
    return RawLog(name=label, streams=streams, origin_lla=origin[0] if origin else None,
                  metadata={"source_format": "table", "files": [str(p) for p in paths],
                            **speed_metadata(mapping, circumference_m)})


def read(sources: Sequence[str | Path], *, mapping: Mapping[str, Mapping[str, Any]],
         options: ReadOptions) -> list[RawLog]:
    """The :class:`odocal.io.registry.Reader` of CSV/Parquet tables (one log from them all)."""
    return [read_table_log(sources, mapping, circumference_m=options.circumference_m)]
