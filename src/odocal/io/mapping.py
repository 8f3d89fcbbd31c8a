"""The mapping file: where each stream's quantities are in a user's files or bag topics.

A TOML file with one section per stream role. Every section may set ``offset_s`` (added to the
stream's clock). For the ``table`` format each section names a ``file`` (a CSV or Parquet file,
matched against the sources given on the command line by name, else relative to the mapping
file) and columns; for ``rosbag`` a ``topic`` and field paths (``angular_velocity.z``,
``velocity[2]``; the defaults of the standard message types are filled in). Example::

    [wheels]
    file = "wheels.csv"
    time = "stamp"           # column with the time
    time_unit = "ms"         # s, ms, us, ns; a date-time column (ISO 8601 text, Parquet
                             # timestamps) is read as seconds whatever this says
    rear_left = "rl_rpm"
    rear_right = "rr_rpm"
    unit = "rpm"             # rev/s, rpm, rad/s, deg/s, m/s, km/h, mph, ticks
    # circumference_m = 1.95 # for m/s, km/h, mph (default: [convert] / the datasheet c_e)
    # ticks_per_rev = 96     # for ticks (cumulative counts)
    # counter_bits = 16      # a tick counter that wraps (8, 12, 16, 24 and 32 bits, unsigned
    #                        # or signed, are recognised without it)
    # front_left = "fl_rpm"  # optional, both or neither: the front wheels (the same unit)
    # front_right = "fr_rpm"
    # steering = "steer_deg" # optional: the steering-wheel angle
    # steering_unit = "deg"  # rad or deg

    [imu]
    file = "imu.csv"
    time = "t"
    yaw_rate = "gyro_z"
    yaw_rate_unit = "deg/s"  # rad/s or deg/s
    lateral_accel = "acc_y"
    lateral_accel_unit = "g" # m/s^2 or g
    frame = "flu"            # flu: x forward, y left, z up; frd: x forward, y right, z down

    [pose]                   # a fused reference pose in a local frame
    file = "pose.csv"
    time = "t"
    x = "x"
    y = "y"
    heading = "yaw"
    heading_unit = "rad"
    heading_convention = "enu"   # enu: counter-clockwise from x; compass: clockwise from north

    [gnss]                   # or GNSS fixes, fused with the IMU by odocal
    file = "gnss.csv"
    time = "t"
    latitude = "lat"
    longitude = "lon"
    altitude = "alt"         # optional
    speed = "speed"          # optional, m/s (speed_unit)
    course = "track"         # optional (course_unit, course_convention)
    course_unit = "deg"
    course_convention = "compass"
    std = "h_acc"            # optional horizontal accuracy, m
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

from odocal.errors import ConfigError, OdocalError
from odocal.settings import read_toml

_COMMON = {"offset_s", "file", "topic", "time", "time_unit", "type"}
KEYS: Mapping[str, set[str]] = {
    "wheels": _COMMON | {"rear_left", "rear_right", "unit", "circumference_m", "ticks_per_rev",
                         "counter_bits", "front_left", "front_right", "steering",
                         "steering_unit"},
    "imu": _COMMON | {"yaw_rate", "yaw_rate_unit", "lateral_accel", "lateral_accel_unit", "frame"},
    "pose": _COMMON | {"x", "y", "heading", "heading_unit", "heading_convention", "vx", "vy",
                       "quaternion"},
    "gnss": _COMMON | {"latitude", "longitude", "altitude", "speed", "speed_unit", "course",
                       "course_unit", "course_convention", "std"},
    "heading": _COMMON | {"heading", "heading_unit", "heading_convention"},
}


def load_mapping(path: str | Path | None) -> dict[str, dict[str, Any]]:
    """Read and check a mapping file; None gives an empty mapping."""
    if path is None:
        return {}
    p = Path(path)
    return check_mapping(read_toml(p, "mapping file"), source=str(p), base=p.parent)


def check_mapping(data: Mapping[str, Any], *, source: str = "mapping",
                  base: Path | None = None) -> dict[str, dict[str, Any]]:
    out: dict[str, dict[str, Any]] = {}
    for role, section in data.items():
        if role not in KEYS:
            raise ConfigError(f"{source}: unknown section [{role}]; known: "
                              f"{', '.join(sorted(KEYS))}")
        if not isinstance(section, dict):
            raise ConfigError(f"{source}: [{role}] must be a table")
        unknown = sorted(k for k in set(section) - KEYS[role] if not k.startswith("_"))
        if unknown:
            raise ConfigError(f"{source}: unknown key [{role}] {unknown[0]!r}; known: "
                              f"{', '.join(sorted(KEYS[role]))}")
        checked = dict(section)
        for key in ("offset_s", "circumference_m", "ticks_per_rev"):
            if key in checked and (not isinstance(checked[key], int | float)
                                   or isinstance(checked[key], bool)):
                raise ConfigError(f"{source}: [{role}] {key} = {checked[key]!r} must be a number")
        bits = checked.get("counter_bits")
        if bits is not None and (isinstance(bits, bool) or not isinstance(bits, int)
                                 or not 2 <= bits <= 52):
            raise ConfigError(f"{source}: [{role}] counter_bits = {bits!r} must be the width of "
                              "the tick counter in bits, an integer from 2 to 52")
        if base is not None:
            checked["_base"] = base
        out[role] = checked
    return out


def offsets(mapping: Mapping[str, Mapping[str, Any]]) -> dict[str, float]:
    """The per-role clock offsets the mapping sets."""
    return {role: float(section["offset_s"]) for role, section in mapping.items()
            if "offset_s" in section}


def mapping_files(path: str | Path | None) -> list[Path]:
    """The files a mapping file names (beside it), for checking outputs against; a mapping
    that cannot be read names none (reading it later reports why)."""
    if path is None:
        return []
    p = Path(path)
    try:
        data = read_toml(p, "mapping file")
    except OdocalError:
        return []
    return [p.parent / str(section["file"]) for section in data.values()
            if isinstance(section, dict) and "file" in section]
