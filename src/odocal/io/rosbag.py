"""ROS 1 bags, ROS 2 bags and MCAP files, read with the ``rosbags`` library (no ROS install).

Each source (a ``.bag`` file, a ROS 2 bag folder, or an ``.mcap`` file) is one log. Topics and
fields come from the mapping file (see :mod:`odocal.io.mapping`: ``topic`` and field paths such
as ``angular_velocity.z`` or ``velocity[2]``); without a section for a role, the first topic of a
standard type is used with these defaults:

================================ =========================================================
``sensor_msgs/msg/Imu``          imu: ``angular_velocity.z`` (rad/s), ``linear_acceleration.y``
``sensor_msgs/msg/NavSatFix``    gnss: ``latitude``, ``longitude``, ``altitude``, accuracy from
                                 ``position_covariance[0]``
``nav_msgs/msg/Odometry``        pose: ``pose.pose.position.x/y`` and the yaw of
                                 ``pose.pose.orientation``
``geometry_msgs/msg/PoseStamped`` pose: ``pose.position.x/y``, ``pose.orientation``
``sensor_msgs/msg/JointState``   wheels: ``velocity`` (rad/s) of the joints named by
                                 ``rear_left``/``rear_right``, else found by their names
                                 (:mod:`odocal.io.joints`, the live node's rule); a car's
                                 front wheels too (``front_left``/``front_right``, or
                                 found by their names), and the ``position`` of the joint
                                 ``steering`` names (the steering wheel's angle, in
                                 ``steering_unit``)
================================ =========================================================

Time stamps are the messages' ``header.stamp`` (``time = "header"``, the default when there is a
header) or the bag's receive time (``time = "receive"``).
"""

from __future__ import annotations

import re
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from odocal.arrays import FloatArray
from odocal.errors import ConfigError, DataError, InputFileError, MissingDependencyError
from odocal.io.joints import front_wheel_joints, named_joint, wheel_joints
from odocal.io.registry import ReadOptions
from odocal.io.streams import RawLog, Stream
from odocal.io.table import speed_metadata, stream_from_columns
from odocal.io.units import quaternion_yaw

TYPE_DEFAULTS: Mapping[str, Mapping[str, Mapping[str, str]]] = {
    "imu": {"sensor_msgs/msg/Imu": {"yaw_rate": "angular_velocity.z",
                                    "lateral_accel": "linear_acceleration.y"}},
    "gnss": {"sensor_msgs/msg/NavSatFix": {"latitude": "latitude", "longitude": "longitude",
                                           "altitude": "altitude",
                                           "std": "position_covariance[0]"}},
    "pose": {"nav_msgs/msg/Odometry": {"x": "pose.pose.position.x", "y": "pose.pose.position.y",
                                       "quaternion": "pose.pose.orientation"},
             "geometry_msgs/msg/PoseStamped": {"x": "pose.position.x", "y": "pose.position.y",
                                               "quaternion": "pose.orientation"}},
    "wheels": {"sensor_msgs/msg/JointState": {}},
}
_FIELD = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)(?:\[(\d+)\])?$")


def _get(msg: Any, path: str) -> Any:
    value = msg
    for part in path.split("."):
        m = _FIELD.match(part)
        if m is None:
            raise ConfigError(f"bad field path {path!r}")
        value = getattr(value, m.group(1))
        if m.group(2) is not None:
            value = value[int(m.group(2))]
    return value


def _normalise_type(msgtype: str) -> str:
    parts = msgtype.split("/")
    return f"{parts[0]}/msg/{parts[-1]}" if len(parts) == 2 else msgtype


def _stamp(msg: Any) -> float | None:
    header = getattr(msg, "header", None)
    if header is None:
        return None
    stamp = header.stamp
    return float(stamp.sec) + 1e-9 * float(stamp.nanosec)


@contextmanager
def _opened(source: str | Path) -> Iterator[tuple[Path, Any, dict[str, str]]]:
    """The bag at ``source`` open for reading (a ROS 1 bag, a ROS 2 bag folder or an MCAP
    file): its path, the rosbags reader and its topics' message types; closed on leaving.
    A missing or unreadable bag is a one-line error."""
    try:
        from rosbags.highlevel import AnyReader
    except ImportError as err: # pragma: no cover - rosbags is a dependency
        raise MissingDependencyError("reading ROS bags needs 'rosbags' (pip install rosbags)") \
            from err
    path = Path(source)
    if not path.exists():
        raise InputFileError(f"bag '{path}' does not exist")
    try:
        reader = AnyReader([path])
        reader.open()
    except Exception as exc:  # rosbags raises several kinds for a corrupt or unknown file
        raise DataError(f"'{path}' cannot be read as a ROS bag or MCAP file: "
                        f"{type(exc).__name__}: {exc}") from exc
    try:
        yield path, reader, {c.topic: _normalise_type(c.msgtype) for c in reader.connections}
    finally:
        reader.close()


def read_rosbag(source: str | Path, mapping: Mapping[str, Mapping[str, Any]], *,
                circumference_m: float) -> RawLog:
    """One raw log from a ROS 1 bag, ROS 2 bag folder or MCAP file."""
    with _opened(source) as (path, reader, topics):
        plan = _plan(path, topics, mapping)
        raw = _collect(reader, plan, path)
    streams: dict[str, Stream] = {}
    origin: list[tuple[float, float, float]] = []
    for role in ("gnss", "wheels", "imu", "pose", "heading"):
        if role not in plan:
            continue
        topic, section = plan[role]
        table = raw[role]
        if table["time"].size == 0:
            raise DataError(f"'{path}': topic {topic} ({role}) holds no messages")
        streams[role] = stream_from_columns(role, table, section, name=f"{topic} ({role})",
                                            path_label=Path(topic), circumference_m=circumference_m,
                                            origin=origin)
    return RawLog(name=path.stem if path.is_file() else path.name, streams=streams,
                  origin_lla=origin[0] if origin else None,
                  metadata={"source_format": "rosbag", "bag": str(path),
                            "topics": {r: plan[r][0] for r in plan},
                            **speed_metadata({r: plan[r][1] for r in plan}, circumference_m)})


def iter_rosbag(source: str | Path, mapping: Mapping[str, Mapping[str, Any]], *,
                circumference_m: float, chunk_s: float = 5.0) -> Iterator[dict[str, Stream]]:
    """The streams of a bag in chunks of about ``chunk_s`` of receive time, message by message.

    The bag is never loaded whole: each chunk holds the messages of its span, converted as
    :func:`read_rosbag` converts them (encoder ticks, whose rates need neighbouring counts, are
    not supported here). GNSS positions are not streamed (they need the whole log's fusion).
    """
    with _opened(source) as (path, reader, topics):
        plan = {role: entry for role, entry in _plan(path, topics, mapping).items()
                if role in ("wheels", "imu", "pose")}
        if "pose" not in plan:
            raise DataError(f"'{path}': replay needs a fused pose topic (nav_msgs/Odometry or "
                            "geometry_msgs/PoseStamped); convert GNSS logs first (odocal convert)")
        if plan["wheels"][1].get("unit") == "ticks":
            raise DataError(f"'{path}': replay cannot stream encoder ticks; convert the log first "
                            "(odocal convert)")
        by_topic: dict[str, list[str]] = {}
        for role, (topic, _) in plan.items():
            by_topic.setdefault(topic, []).append(role)
        conns = [c for c in reader.connections if c.topic in by_topic]
        joint_index: dict[str, _Joints] = {}
        columns: dict[str, dict[str, list[float]]] = {role: {} for role in plan}
        chunk_end: float | None = None
        for conn, receive_ns, data in reader.messages(connections=conns):
            now = receive_ns * 1e-9
            if chunk_end is None:
                chunk_end = now + chunk_s
            if now >= chunk_end:
                yield _chunk_streams(columns, plan, circumference_m)
                columns = {role: {} for role in plan}
                chunk_end = now + chunk_s
            msg = reader.deserialize(data, conn.msgtype)
            for role in by_topic[conn.topic]:
                section = plan[role][1]
                stamp = _stamp(msg) if section["time"] == "header" else None
                cols = columns[role]
                cols.setdefault("time", []).append(stamp if stamp is not None else now)
                for key, value in _extract(role, section, msg, joint_index, conn.topic).items():
                    cols.setdefault(key, []).append(value)
        yield _chunk_streams(columns, plan, circumference_m)


def _chunk_streams(columns: Mapping[str, Mapping[str, list[float]]],
                   plan: Mapping[str, tuple[str, dict[str, Any]]],
                   circumference_m: float) -> dict[str, Stream]:
    out: dict[str, Stream] = {}
    for role, cols in columns.items():
        if not cols.get("time"):
            continue
        topic, section = plan[role]
        table = {k: np.asarray(v, dtype=np.float64) for k, v in cols.items()}
        named = {**section, **{k: k for k in table}, "time_unit": "s"}
        out[role] = stream_from_columns(role, table, named, name=f"{topic} ({role})",
                                        path_label=Path(topic), circumference_m=circumference_m,
                                        origin=[])
    return out


def _plan(path: Path, topics: Mapping[str, str], mapping: Mapping[str, Mapping[str, Any]]
          ) -> dict[str, tuple[str, dict[str, Any]]]:
    """Role -> (topic, mapping section with type defaults filled in)."""
    plan: dict[str, tuple[str, dict[str, Any]]] = {}
    for role in ("wheels", "imu", "pose", "gnss", "heading"):
        section = dict(mapping.get(role, {}))
        topic = section.get("topic")
        if topic is None:
            if role in mapping:
                raise ConfigError(f"mapping [{role}] needs a 'topic' for the rosbag format")
            candidates = [t for t, ty in topics.items() if ty in TYPE_DEFAULTS.get(role, {})]
            if not candidates:
                continue
            topic = sorted(candidates)[0]
        if topic not in topics:
            raise DataError(f"'{path}' has no topic {topic} (mapping [{role}]); topics: "
                            f"{', '.join(sorted(topics)) or 'none'}")
        msgtype = topics[topic]
        if "type" in section and _normalise_type(str(section["type"])) != msgtype:
            raise DataError(f"'{path}': topic {topic} holds {msgtype}, not {section['type']}")
        for key, value in TYPE_DEFAULTS.get(role, {}).get(msgtype, {}).items():
            section.setdefault(key, value)
        if role == "wheels" and msgtype == "sensor_msgs/msg/JointState":
            section.setdefault("unit", "rad/s")
        section.setdefault("time", "header")
        section["_type"] = msgtype
        plan[role] = (str(topic), section)
    if "wheels" not in plan:
        raise DataError(f"'{path}': no wheel-speed topic; name it in the mapping ([wheels] topic, "
                        f"rear_left, rear_right); topics: {', '.join(sorted(topics))}")
    return plan


def _collect(reader: Any, plan: Mapping[str, tuple[str, dict[str, Any]]],
             path: Path) -> dict[str, dict[str, FloatArray]]:
    """Read every planned topic once into columns named by the mapping's keys."""
    by_topic: dict[str, list[str]] = {}
    for role, (topic, _) in plan.items():
        by_topic.setdefault(topic, []).append(role)
    columns: dict[str, dict[str, list[float]]] = {role: {} for role in plan}
    joint_index: dict[str, _Joints] = {}
    conns = [c for c in reader.connections if c.topic in by_topic]
    for conn, receive_ns, data in reader.messages(connections=conns):
        msg = reader.deserialize(data, conn.msgtype)
        for role in by_topic[conn.topic]:
            section = plan[role][1]
            cols = columns[role]
            stamp = _stamp(msg) if section["time"] == "header" else None
            if section["time"] not in ("header", "receive"):
                raise ConfigError(f"mapping [{role}] time must be 'header' or 'receive' for "
                                  "bags")
            cols.setdefault("time", []).append(stamp if stamp is not None
                                               else receive_ns * 1e-9)
            for key, value in _extract(role, section, msg, joint_index, conn.topic).items():
                cols.setdefault(key, []).append(value)
    out: dict[str, dict[str, FloatArray]] = {}
    for role, cols in columns.items():
        table = {k: np.asarray(v, dtype=np.float64) for k, v in cols.items()}
        if "time" not in table:
            table["time"] = np.zeros(0)
        out[role] = table
        # from here on the mapping refers to these columns, named by their keys
        section = plan[role][1]
        for key in table:
            section[key] = key
        section["time_unit"] = "s"
    return out


def _extract(role: str, section: Mapping[str, Any], msg: Any,
             joint_index: dict[str, _Joints], topic: str) -> dict[str, float]:
    values: dict[str, float] = {}
    if role == "wheels" and section.get("_type") == "sensor_msgs/msg/JointState":
        if topic not in joint_index:
            joint_index[topic] = _joints(list(msg.name), section, topic)
        for key, index in joint_index[topic].velocities.items():
            if index >= len(msg.velocity):
                raise DataError(f"topic {topic}: the joint {msg.name[index]!r} ({key}) has no "
                                f"velocity ({len(msg.velocity)} velocities for "
                                f"{len(msg.name)} joints)")
            values[key] = float(msg.velocity[index])
        steering = joint_index[topic].steering
        if steering is not None:
            if steering >= len(msg.position):
                raise DataError(f"topic {topic}: the steering joint {msg.name[steering]!r} "
                                f"has no position ({len(msg.position)} positions for "
                                f"{len(msg.name)} joints)")
            values["steering"] = float(msg.position[steering])
        return values
    for key in ("rear_left", "rear_right", "yaw_rate", "lateral_accel", "x", "y", "heading",
                "vx", "vy", "latitude", "longitude", "altitude", "speed", "course", "std"):
        path = section.get(key)
        if isinstance(path, str):
            values[key] = float(_get(msg, path))
    if role == "gnss" and section.get("std") == "position_covariance[0]":
        values["std"] = float(np.sqrt(max(values.get("std", np.nan), 0.0))) \
            if np.isfinite(values.get("std", np.nan)) and values["std"] > 0 else np.nan
    quat = section.get("quaternion")
    if role == "pose" and isinstance(quat, str):
        q = _get(msg, quat)
        values["heading"] = float(quaternion_yaw(*(np.array([float(getattr(q, a))])
                                                   for a in ("w", "x", "y", "z")))[0])
    return values


@dataclass(frozen=True)
class _Joints:
    """Where a JointState's wheels are: the velocities' indices by column (``rear_left``,
    ``rear_right``, and a car's ``front_left``, ``front_right``) and the steering joint's."""

    velocities: dict[str, int]
    steering: int | None = None


def _joints(names: Sequence[str], section: Mapping[str, Any], topic: str) -> _Joints:
    """The wheels' joints by :mod:`odocal.io.joints`' rule (the live node's), and the steering
    joint the mapping names (``[wheels] steering``)."""
    def named(key: str) -> str:
        value = section.get(key)
        return value if isinstance(value, str) else ""

    def setting(side: str, axle: str) -> str:
        return f"the mapping's [wheels] {axle}_{side}"

    where = f"topic {topic}"
    left, right = wheel_joints(names, (named("rear_left"), named("rear_right")), where=where,
                               setting=lambda side: setting(side, "rear"), error=DataError)
    velocities = {"rear_left": left, "rear_right": right}
    front = front_wheel_joints(names, (named("front_left"), named("front_right")),
                               where=where, setting=lambda side: setting(side, "front"),
                               error=DataError)
    if front is not None:
        if {left, right} & set(front):
            raise DataError(f"{where}: the same joint is taken for a rear and a front wheel "
                            f"({', '.join(names[i] for i in sorted({left, right} & set(front)))}"
                            "); name them in the mapping's [wheels] rear_left, rear_right, "
                            "front_left, front_right")
        velocities |= {"front_left": front[0], "front_right": front[1]}
    steering = None
    if named("steering"):
        steering = named_joint(names, named("steering"), where=where,
                               setting="the mapping's [wheels] steering", error=DataError)
    return _Joints(velocities, steering)


def read(sources: Sequence[str | Path], *, mapping: Mapping[str, Mapping[str, Any]],
         options: ReadOptions) -> list[RawLog]:
    """The :class:`odocal.io.registry.Reader` of ROS 1 bags, ROS 2 bags and MCAP files."""
    return [read_rosbag(s, mapping, circumference_m=options.circumference_m) for s in sources]
