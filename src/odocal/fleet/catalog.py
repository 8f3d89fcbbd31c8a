"""The fleet's catalog: which drive of which vehicle, when, where its log lies.

A catalog is a CSV or Parquet table with the columns ``vehicle`` (text), ``path`` (a drive file
or a raw log, relative to the catalog's folder or absolute) and ``time`` (ISO 8601), and
optionally ``odometer_km``, ``format`` (as ``--from``; empty: the drive format), ``mapping`` (a
mapping file, for the ``table`` and ``rosbag`` formats) and ``event`` (free text, e.g.
``tyre change``: that vehicle's baseline restarts from this drive on). A folder laid out as
``VEHICLE/DATE_*.parquet`` (or ``.csv``) is a catalog too, the date read from each file name.

The catalog, and each ``path`` and ``mapping`` in it, may be a URL (``s3://``, ``gs://``,
``az://``, ``https://``, ...: :mod:`odocal.io.remote`); a relative entry of a catalog that is
itself a URL resolves against the catalog's URL. A local path must exist when the catalog is
read; an object is looked at when the fleet is planned (a missing one is named by its row).
Times are instants: ``2026-03-02T09:00:00+01:00`` and ``2026-03-02T08:00:00Z`` are the same.
"""

from __future__ import annotations

import datetime as dt
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from odocal.errors import DataError, InputFileError, input_file, shown
from odocal.io.registry import FORMATS
from odocal.io.urls import check_url, is_remote, join, local_path, redact

#: A drive's or mapping's location: a local path, or the URL of an object.
Location = Path | str

REQUIRED = ("vehicle", "path", "time")
OPTIONAL = ("odometer_km", "format", "mapping", "event")
_DATE = re.compile(r"^(\d{4}-\d{2}-\d{2}(?:[T_]\d{2}[-:]?\d{2}(?:[-:]?\d{2})?)?)")


@dataclass(frozen=True)
class CatalogEntry:
    """One drive of the fleet."""

    vehicle: str
    path: Location
    time: dt.datetime
    odometer_km: float | None = None
    format: str = "drive"
    mapping: Location | None = None
    event: str | None = None
    row: int = 0

    @property
    def source(self) -> str:
        """The drive's location as it may be shown and stored (a URL without credentials or
        query)."""
        return redact(self.path)

    @property
    def remote(self) -> bool:
        return is_remote(self.path)

    def to_dict(self) -> dict[str, Any]:
        return {"vehicle": self.vehicle, "path": self.source, "time": self.time.isoformat(),
                "odometer_km": self.odometer_km, "format": self.format,
                "mapping": redact(self.mapping) if self.mapping else None, "event": self.event,
                "row": self.row}


def parse_time(text: str, *, where: str) -> dt.datetime:
    """ISO 8601 (a date, or date and time; UTC unless an offset is given), as the instant in
    UTC: stored times then sort as text in the order of the instants."""
    value = text.strip().replace("_", "T")
    m = re.fullmatch(r"(\d{4}-\d{2}-\d{2})T(\d{2})-?(\d{2})(?:-?(\d{2}))?", value)
    if m:                                 # file-name times: 2026-03-02T08-15-00
        value = f"{m[1]}T{m[2]}:{m[3]}:{m[4] or '00'}"
    try:
        stamp = dt.datetime.fromisoformat(value)
    except ValueError as err:
        raise DataError(f"{where}: time {text!r} is not an ISO 8601 date or time "
                        "(e.g. 2026-03-02 or 2026-03-02T08:15:00)") from err
    return stamp.astimezone(dt.UTC) if stamp.tzinfo else stamp.replace(tzinfo=dt.UTC)


def read_catalog(source: str | Path) -> list[CatalogEntry]:
    """The catalog's drives, sorted by vehicle and time (see the module docstring)."""
    local = local_path(source)
    if local is None:
        url = str(source)
        check_url(url, "catalog")
        from odocal.io.remote import stat

        if url.endswith("/") or stat(url, "catalog").folder:
            return _from_remote_folder(url)
        return _read_table(url, redact(url), lambda text: _beside_url(url, text), local=False)
    path = local
    if path.is_dir():
        return _from_folder(path)
    input_file(path, "catalog")
    return _read_table(path, path, lambda text: _resolve(path.parent, text))


def _read_table(path: Location, label: object, resolve: Callable[[str], Location], *,
                local: bool = True) -> list[CatalogEntry]:
    """The rows of a catalog table; ``local``: the catalog is a local file, whose local drive
    files must exist now (a remote catalog's rows, ``file://`` ones included, are looked at
    when the fleet is planned, and one that cannot be had is named by its row)."""
    from odocal.io.drivefile import read_text_table

    columns = read_text_table(path)
    missing = [c for c in REQUIRED if c not in columns]
    if missing:
        raise DataError(f"catalog '{label}' lacks column{'s' if len(missing) > 1 else ''} "
                        f"{', '.join(missing)} (a catalog needs {', '.join(REQUIRED)})")
    unknown = [c for c in columns if c not in (*REQUIRED, *OPTIONAL)]
    if unknown:
        hint = (": a catalog row is one whole drive; to use single nuScenes scenes, convert "
                "each (odocal convert --scene) and list the files" if "scene" in unknown else "")
        raise DataError(f"catalog '{label}' has a column odocal does not know: "
                        f"{shown(unknown[0])} (known: {', '.join((*REQUIRED, *OPTIONAL))})"
                        f"{hint}")
    n = len(columns["vehicle"])
    if n == 0:
        raise DataError(f"catalog '{label}' lists no drive")
    entries = []
    for i in range(n):
        row = {k: (columns[k][i] if k in columns else None) for k in (*REQUIRED, *OPTIONAL)}
        entries.append(_catalog_entry(row, i + 1, label, resolve, local=local))
    return sorted(entries, key=lambda e: (e.vehicle, e.time, e.row))


def _catalog_entry(row: dict[str, str | None], number: int, label: object,
                   resolve: Callable[[str], Location], *, local: bool) -> CatalogEntry:
    """Row ``number`` (1 = the first) of a catalog table, checked: a vehicle, a drive that
    exists (a local one, of a local catalog), a known format, a mapping file, a plausible
    odometer reading and a time."""
    where = f"catalog '{label}' row {number}"
    vehicle = (row["vehicle"] or "").strip()
    if not vehicle:
        raise DataError(f"{where}: the vehicle is empty")
    text = (row["path"] or "").strip()
    if not text:
        raise DataError(f"{where}: the path is empty")
    drive = resolve(text)
    if isinstance(drive, str):
        check_url(drive, f"{where}: drive")
    elif not local:
        pass
    elif not drive.exists():
        raise InputFileError(f"{where}: '{shown(drive)}' does not exist")
    elif not drive.is_dir():
        input_file(drive, f"{where}: drive")
    fmt = (row["format"] or "").strip() or "drive"
    if fmt != "drive" and fmt not in FORMATS:
        raise DataError(f"{where}: unknown format {fmt!r}; use drive or one of "
                        f"{', '.join(FORMATS)}")
    mapping = (row["mapping"] or "").strip()
    mapping_at = resolve(mapping) if mapping else None
    if isinstance(mapping_at, str):
        check_url(mapping_at, f"{where}: mapping file")
    elif mapping_at is not None and local:   # named now, not as a crash when it is hashed
        input_file(mapping_at, f"{where}: mapping file")
    odometer = (row["odometer_km"] or "").strip()
    try:
        km = float(odometer) if odometer else None
    except ValueError as err:
        raise DataError(f"{where}: odometer_km {odometer!r} is not a number") from err
    if km is not None and not (km >= 0 and km < 1e8):
        raise DataError(f"{where}: odometer_km {odometer!r} is not a plausible reading")
    event = (row["event"] or "").strip() or None
    return CatalogEntry(vehicle=vehicle, path=drive,
                        time=parse_time(row["time"] or "", where=where),
                        odometer_km=km, format=fmt,
                        mapping=mapping_at,
                        event=event, row=number)


def _beside_url(base: str, text: str) -> Location:
    """A remote catalog's entry: resolved against the catalog's URL (a URL as it is, with its
    query); a ``file://`` URL is the local path it names."""
    resolved = join(base, text)
    local = local_path(resolved)
    return local if local is not None else resolved


def _resolve(base: Path, text: str) -> Location:
    """A local catalog's entry: a URL as it is, a path beside the catalog."""
    if is_remote(text):
        return text
    local = local_path(text)
    assert local is not None
    return (local if local.is_absolute() else base / local).resolve()


def _from_remote_folder(url: str) -> list[CatalogEntry]:
    """A folder of an object store laid out as ``VEHICLE/DATE_*.parquet`` (listed, not read)."""
    from odocal.io.remote import list_folder

    base = url.rstrip("/") + "/"
    entries: list[CatalogEntry] = []
    for name in list_folder(url, "catalog folder"):
        parts = name.split("/")
        if len(parts) != 2 or Path(parts[1]).suffix.lower() not in (".parquet", ".csv"):
            continue
        m = _DATE.match(Path(parts[1]).stem)
        if not m:
            raise DataError(f"'{redact(base + name)}': a fleet folder's files are named "
                            "DATE_*.parquet (e.g. 2026-03-02_morning.parquet)")
        entries.append(CatalogEntry(vehicle=parts[0], path=join(base, name),
                                    time=parse_time(m[1], where=redact(base + name)),
                                    row=len(entries) + 1))
    if not entries:
        raise DataError(f"folder '{redact(url)}' holds no VEHICLE/DATE_*.parquet drive files")
    return sorted(entries, key=lambda e: (e.vehicle, e.time, e.row))


def _from_folder(root: Path) -> list[CatalogEntry]:
    entries: list[CatalogEntry] = []
    for vehicle_dir in sorted(p for p in root.iterdir() if p.is_dir()):
        for file in sorted(vehicle_dir.iterdir()):
            if file.suffix.lower() not in (".parquet", ".csv"):
                continue
            m = _DATE.match(file.stem)
            if not m:
                raise DataError(f"'{file}': a fleet folder's files are named DATE_*.parquet "
                                "(e.g. 2026-03-02_morning.parquet)")
            entries.append(CatalogEntry(vehicle=vehicle_dir.name, path=file.resolve(),
                                        time=parse_time(m[1], where=str(file)),
                                        row=len(entries) + 1))
    if not entries:
        raise DataError(f"folder '{root}' holds no VEHICLE/DATE_*.parquet drive files")
    return sorted(entries, key=lambda e: (e.vehicle, e.time, e.row))
