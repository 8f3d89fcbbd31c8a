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
