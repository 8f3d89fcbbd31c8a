"""The nuScenes CAN bus expansion: ``can_bus/scene-XXXX_<message>.json``.

Each message file is a JSON list of records ordered by ``utime`` (microseconds, Unix epoch, the
time the message was received). Used here:

* ``zoe_veh_info``: ``RL_wheel_speed``, ``RR_wheel_speed`` in rpm (rear wheels, ~100 Hz); where
  every record has them, also ``FL_wheel_speed``, ``FR_wheel_speed`` (rpm) and
  ``steer_corrected`` (the steering-wheel angle, degrees), the four-wheel model's inputs
* ``ms_imu``: ``rotation_rate`` [x, y, z] rad/s and ``linear_accel`` [x, y, z] m/s^2 in the ego
  frame (x forward, y left, z up), ~100 Hz
* ``pose``: ``pos`` [x, y, z] m in the map frame and ``orientation`` [w, x, y, z] ego to map,
  ~50 Hz, from lidar-map localisation (the reference). Its ``vel`` is forward-only, so there is no
  course independent of the heading: sideslip stays off.
"""

from __future__ import annotations

import json
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from odocal.errors import DataError, InputFileError
from odocal.io.registry import ReadOptions
from odocal.io.streams import RawLog, Stream
from odocal.io.units import quaternion_yaw

MESSAGES = ("zoe_veh_info", "ms_imu", "pose")
_SCENE = re.compile(r"^(scene-\d+)_(.+)\.json$")


def _can_bus_dir(source: Path) -> Path:
    if not source.exists():
        raise InputFileError(f"nuScenes source '{source}' does not exist")
    if source.is_file():
        return source.parent
    if (source / "can_bus").is_dir():
        return source / "can_bus"
    return source


def find_scenes(sources: Sequence[str | Path]) -> dict[str, dict[str, Path]]:
    """Scene name -> message name -> file, from folders or message files."""
    scenes: dict[str, dict[str, Path]] = {}
    for src in sources:
        src_path = Path(src)
        folder = _can_bus_dir(src_path)
        files = [src_path] if src_path.is_file() else sorted(folder.glob("scene-*_*.json"))
        for f in files:
            m = _SCENE.match(f.name)
            if m:
                scenes.setdefault(m.group(1), {})[m.group(2)] = f
    if not scenes:
        raise DataError(f"no nuScenes CAN bus files (scene-XXXX_<message>.json) in "
                        f"{', '.join(str(s) for s in sources)}")
    return scenes


def _records(path: Path, scene: str, message: str) -> list[dict[str, Any]]:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise DataError(f"{scene}: message {message} ('{path.name}') is not valid JSON: "
                        f"{exc}") from exc
    except RecursionError as err:
        raise DataError(f"{scene}: message {message} ('{path.name}') nests too deeply to "
                        "read") from err
    if not isinstance(data, list) or not data:
        raise DataError(f"{scene}: message {message} ('{path.name}') holds no records")
    return data


def _field(records: list[dict[str, Any]], key: str, scene: str, message: str) -> np.ndarray:
    try:
        return np.array([r[key] for r in records], dtype=np.float64)
    except KeyError as err:
        raise DataError(f"{scene}: message {message} lacks the field '{key}'") from err
    except (TypeError, ValueError) as err:
        raise DataError(f"{scene}: message {message} field '{key}' is not numeric") from err


def read_scene(scene: str, files: dict[str, Path]) -> RawLog:
    missing = [m for m in MESSAGES if m not in files]
    if missing:
        raise DataError(f"{scene}: message {missing[0]} is missing "
                        f"(expected can_bus/{scene}_{missing[0]}.json)")
    veh = _records(files["zoe_veh_info"], scene, "zoe_veh_info")
    imu = _records(files["ms_imu"], scene, "ms_imu")
    pose = _records(files["pose"], scene, "pose")
    rot = _field(imu, "rotation_rate", scene, "ms_imu")
    acc = _field(imu, "linear_accel", scene, "ms_imu")
    pos = _field(pose, "pos", scene, "pose")
    q = _field(pose, "orientation", scene, "pose")
    if rot.ndim != 2 or acc.ndim != 2 or pos.ndim != 2 or q.shape[1:] != (4,):
        raise DataError(f"{scene}: unexpected shapes in ms_imu or pose records")
    rpm_to_revps = 1.0 / 60.0
    more = {}
    if all(k in r for r in veh for k in ("FL_wheel_speed", "FR_wheel_speed")):
        more = {"n_fl": _field(veh, "FL_wheel_speed", scene, "zoe_veh_info") * rpm_to_revps,
                "n_fr": _field(veh, "FR_wheel_speed", scene, "zoe_veh_info") * rpm_to_revps}
    if all("steer_corrected" in r for r in veh):
        more["steer"] = np.deg2rad(_field(veh, "steer_corrected", scene, "zoe_veh_info"))
    streams = {
        "wheels": Stream(name=f"{scene} zoe_veh_info", role="wheels",
                         t=_field(veh, "utime", scene, "zoe_veh_info") * 1e-6,
                         values={"n_rl": _field(veh, "RL_wheel_speed", scene, "zoe_veh_info")
                                 * rpm_to_revps,
                                 "n_rr": _field(veh, "RR_wheel_speed", scene, "zoe_veh_info")
                                 * rpm_to_revps, **more},
                         units={"n_rl": "rpm", "n_rr": "rpm",
                                **{k: "deg" if k == "steer" else "rpm" for k in more}}),
        "imu": Stream(name=f"{scene} ms_imu", role="imu",
                      t=_field(imu, "utime", scene, "ms_imu") * 1e-6,
                      values={"yaw_rate": rot[:, 2], "a_y": acc[:, 1]},
                      units={"yaw_rate": "rad/s", "a_y": "m/s^2"}),
        "pose": Stream(name=f"{scene} pose", role="pose",
                       t=_field(pose, "utime", scene, "pose") * 1e-6,
                       values={"x": pos[:, 0], "y": pos[:, 1],
                               "psi": quaternion_yaw(q[:, 0], q[:, 1], q[:, 2], q[:, 3])},
                       units={"x": "m (map)", "y": "m (map)", "psi": "quaternion"}),
    }
    return RawLog(name=scene, streams=streams,
                  metadata={"source_format": "nuscenes", "scene": scene,
                            "files": [str(files[m]) for m in MESSAGES]})


def read_nuscenes(sources: Sequence[str | Path], *, scenes: Sequence[str] | None = None
                  ) -> list[RawLog]:
    """One raw log per scene found in ``sources`` (restricted to ``scenes`` if given)."""
    found = find_scenes(sources)
    wanted = list(scenes) if scenes else sorted(found)
    unknown = [s for s in wanted if s not in found]
    if unknown:
        raise DataError(f"scene {unknown[0]} is not in {', '.join(str(s) for s in sources)}; "
                        f"found {', '.join(sorted(found))}")
    return [read_scene(s, found[s]) for s in wanted]


def read(sources: Sequence[str | Path], *, mapping: Mapping[str, Mapping[str, Any]],
         options: ReadOptions) -> list[RawLog]:
    """The :class:`odocal.io.registry.Reader` of the nuScenes CAN bus expansion."""
    del mapping                                    # the format is fixed
    return read_nuscenes(sources, scenes=options.scenes or None)
