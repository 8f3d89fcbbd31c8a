"""The raw-log formats odocal reads, by name (light: the command line lists them cheaply).

Each format is one reader module exposing ``read(sources, *, mapping, options) -> list[RawLog]``
(the :class:`Reader` protocol): ``sources`` as the user gave them, ``mapping`` the checked
mapping file (empty where the format needs none), ``options`` the :class:`ReadOptions`. A new
format is a new module and one line here.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, Protocol

if TYPE_CHECKING:
    from odocal.io.streams import RawLog


@dataclass(frozen=True)
class ReadOptions:
    """What a reader may need besides its sources and mapping.

    circumference_m : nominal wheel circumference, to turn wheel speeds (m/s, km/h) into rev/s
    scenes : the scenes to read, for formats that hold several (empty: all)
    """

    circumference_m: float
    scenes: tuple[str, ...] = ()


class Reader(Protocol):
    def __call__(self, sources: Sequence[str | Path], *,
                 mapping: Mapping[str, Mapping[str, Any]],
                 options: ReadOptions) -> list[RawLog]: ...

#: format name -> the module that reads it
READERS: MappingProxyType[str, str] = MappingProxyType({
    "nuscenes": "odocal.io.nuscenes",
    "comma2k19": "odocal.io.comma2k19",
    "rosbag": "odocal.io.rosbag",
    "table": "odocal.io.table",
})
FORMATS: tuple[str, ...] = tuple(READERS)


def guess_format(path: str | Path) -> str | None:
    """The raw-log format a folder or file looks like by its names alone (nothing is read), or
    None: a nuScenes CAN bus folder, a comma2k19 route or segment folder, a ROS 2 bag folder or
    a ROS bag file."""
    p = Path(path)
    if p.suffix in (".bag", ".mcap", ".db3"):
        return "rosbag"
    if not p.is_dir():
        return None
    try:
        names = {c.name for c in p.iterdir()}
        inner = {c.name for c in (p / "can_bus").iterdir()} if "can_bus" in names else names
    except OSError:
        return None
    if any(n.startswith("scene-") and n.endswith(".json") for n in inner):
        return "nuscenes"
    if "processed_log" in names or next(p.glob("*/processed_log"), None) is not None \
            or next(p.glob("*/*/processed_log"), None) is not None:
        return "comma2k19"
    if "metadata.yaml" in names:
        return "rosbag"
    return None
