"""Real logs in: the front door of every importer (``odocal convert``, ``inspect``,
``calibrate --from``).

Formats: ``nuscenes`` (the CAN bus expansion), ``comma2k19`` (a segment folder), ``rosbag`` (ROS 1,
ROS 2, MCAP), ``table`` (CSV/Parquet files with a mapping). Each source becomes one or more raw
logs, each raw log one drive (see :mod:`odocal.preprocess.pipeline`).
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from odocal.data.drive import Drive
from odocal.errors import ConfigError, DataError
from odocal.io.mapping import check_mapping, load_mapping, offsets
from odocal.io.registry import FORMATS, READERS, Reader, ReadOptions
from odocal.io.streams import RawLog
from odocal.preprocess.align import StreamReport, clean
from odocal.preprocess.pipeline import build_drive
from odocal.settings import Settings


def _circumference(settings: Settings, mapping: Mapping[str, Mapping[str, Any]]) -> float:
    wheels = mapping.get("wheels", {})
    if "circumference_m" in wheels:
        return float(wheels["circumference_m"])
    if settings.convert.wheel_circumference_m is not None:
        return settings.convert.wheel_circumference_m
    return settings.identify.datasheet("c_e")


def read_logs(fmt: str, sources: Sequence[str | Path], *,
              mapping: str | Path | Mapping[str, Mapping[str, Any]] | None = None,
              scenes: Sequence[str] | None = None,
              settings: Settings | None = None) -> list[RawLog]:
    """The raw logs in ``sources`` (one per nuScenes scene, comma2k19 segment, bag, table set)."""
    settings = settings or Settings()
    if fmt not in FORMATS:
        raise ConfigError(f"unknown format {fmt!r}; choose one of {', '.join(FORMATS)}")
    if not sources:
        raise DataError(f"no {fmt} source was given")
    table = check_mapping(mapping) if isinstance(mapping, Mapping) else load_mapping(mapping)
    circumference = _circumference(settings, table)
    if scenes and fmt != "nuscenes":
        raise ConfigError("--scene applies to the nuscenes format only")
    reader: Reader = importlib.import_module(READERS[fmt]).read
    return reader(sources, mapping=table,
                  options=ReadOptions(circumference_m=circumference,
                                      scenes=tuple(scenes or ())))


def convert(fmt: str, sources: Sequence[str | Path], *,
            mapping: str | Path | Mapping[str, Mapping[str, Any]] | None = None,
            scenes: Sequence[str] | None = None, settings: Settings | None = None) -> list[Drive]:
    """Drives from raw logs: aligned onto the grid, with a reference pose and sideslip.

    The conversion report (streams, repaired stamps, gaps, offsets, fusion) is in each drive's
    ``metadata["conversion"]``.
    """
    settings = settings or Settings()
    table = check_mapping(mapping) if isinstance(mapping, Mapping) else load_mapping(mapping)
    logs = read_logs(fmt, sources, mapping=table, scenes=scenes, settings=settings)
    return [build_drive(log, settings, offsets=offsets(table)) for log in logs]


@dataclass(frozen=True)
class Inspection:
    """What a raw log holds, before any conversion."""

    log: RawLog
    streams: dict[str, StreamReport]

    def to_dict(self) -> dict[str, Any]:
        return {"log": self.log.name, "metadata": dict(self.log.metadata),
                "streams": {k: v.to_dict() for k, v in self.streams.items()}}


def inspect(fmt: str, sources: Sequence[str | Path], *,
            mapping: str | Path | Mapping[str, Mapping[str, Any]] | None = None,
            scenes: Sequence[str] | None = None,
            settings: Settings | None = None) -> list[Inspection]:
    """The streams of every log: rates, spans, gaps, repaired stamps and units."""
    logs = read_logs(fmt, sources, mapping=mapping, scenes=scenes, settings=settings)
    return [Inspection(log=log, streams={role: clean(s)[1] for role, s in log.streams.items()})
            for log in logs]
