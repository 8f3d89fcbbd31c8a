"""The raw-log formats odocal reads, by name (light: the command line lists them cheaply).

Each format is one reader module exposing ``read(sources, *, mapping, options) -> list[RawLog]``
(see :class:`odocal.convert.Reader`); a new format is a new module and one line here.
"""

from __future__ import annotations

from types import MappingProxyType

#: format name -> the module that reads it
READERS: MappingProxyType[str, str] = MappingProxyType({
    "nuscenes": "odocal.io.nuscenes",
    "comma2k19": "odocal.io.comma2k19",
    "rosbag": "odocal.io.rosbag",
    "table": "odocal.io.table",
})
FORMATS: tuple[str, ...] = tuple(READERS)
