"""The drive format: one row per sample, CSV or Parquet (docs/drive-format.md)."""

from __future__ import annotations

import hashlib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
import pyarrow.parquet as pq

from odocal.data.drive import Drive
from odocal.errors import DataError, InputFileError, input_file, shown
from odocal.io.atomic import atomic_path
from odocal.io.urls import is_url

_FORMATS = {".csv": "csv", ".parquet": "parquet", ".pq": "parquet"}


def suffix_of(path: str | Path) -> str:
    """A drive file's type by its name's suffix, a query-like tail that a download left in the
    name (``d.parquet?X-Amz-Signature=...``) aside."""
    from odocal.redaction import redact_url

    return Path(redact_url(Path(path).name)).suffix


def _format_of(path: Path) -> str:
    suffix = suffix_of(path)
    fmt = _FORMATS.get(suffix.lower())
    if fmt is None:
        raise DataError(f"'{path}': unknown file type {suffix!r}; the drive format is "
                        "stored as .csv or .parquet")
    return fmt


ROW_GROUP_ROWS = 1 << 16


def _arrow_table(p: Path, *, text: bool) -> pa.Table:
    """A CSV or Parquet file as an Arrow table (``text``: every CSV column as strings)."""
    fmt = _format_of(p)
    if p.stat().st_size == 0:
        raise DataError(f"'{p}' is empty")
    try:
        if fmt != "csv":
            return pq.ParquetFile(p).read()     # (read_table imports pandas: 0.3 s)
        if not text:
            return pacsv.read_csv(p)
        names = pacsv.read_csv(p, read_options=pacsv.ReadOptions(skip_rows_after_names=0)
                               ).column_names
        return pacsv.read_csv(p, convert_options=pacsv.ConvertOptions(
            column_types={n: pa.string() for n in names}, strings_can_be_null=True))
    except (pa.ArrowInvalid, pa.ArrowTypeError, OSError, UnicodeDecodeError) as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise DataError(f"'{p}' cannot be read as {fmt.upper()}: {first}") from exc


class Columns(dict[str, np.ndarray]):
    """A table's float columns by name; ``datetimes`` names those that were date-times (read
    as seconds since 1970 UTC) or durations (seconds)."""

    datetimes: frozenset[str] = frozenset()


def read_table(path: str | Path) -> Columns:
    """Read a CSV or Parquet file (a path or a URL) into float columns (non-numeric columns
    raise DataError; date-times become seconds since 1970 UTC)."""
    if is_url(path):
        from odocal.io.remote import readable

        with readable(str(path), "input file") as (local, _):
            return read_table(local)
    p = Path(path)
    if p.is_dir():
        from odocal.io.registry import guess_format

        kind = guess_format(p)
        hint = (f": it looks like a {kind} log, read with --from {kind}" if kind else
                ": raw logs are read with --from FORMAT (nuscenes, comma2k19, rosbag, table)")
        raise InputFileError(f"input '{shown(p)}' is a folder, not a drive file (.csv or "
                             f".parquet){hint}")
    input_file(p)
    table = _arrow_table(p, text=False)
    try:
        names = table.column_names
    except UnicodeDecodeError as err:
        raise DataError(f"'{p}' has column names that are not UTF-8 text") from err
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise DataError(f"'{p}' names the column {_printable(twice[0])} more than once")
    columns = Columns()
    for name in names:
        col = table.column(name)
        if pa.types.is_boolean(col.type):
            raise DataError(f"'{p}' column {_printable(name)} holds true/false values, "
                            "not numbers")
        if _is_time(col.type):
            columns[name] = _seconds(col)
            columns.datetimes = columns.datetimes | {name}
            continue
        try:
            numeric = pa.types.is_integer(col.type) or pa.types.is_floating(col.type) \
                or pa.types.is_null(col.type)
            columns[name] = np.asarray(col.to_numpy(zero_copy_only=False),
                                       dtype=np.float64 if numeric else object)
        except (UnicodeDecodeError, pa.ArrowInvalid) as err:
            raise DataError(f"'{p}' column {_printable(name)} holds values that are neither "
                            "numbers nor text") from err
    for name, values in columns.items():
        if values.dtype == object:
            try:
                columns[name] = np.array([np.nan if v is None else float(v) for v in values])
            except (TypeError, ValueError) as err:
                bad = next(v for v in values if not _is_number(v))
                raise DataError(f"'{p}' column {_printable(name)} holds a non-numeric value "
                                f"'{_printable(str(bad))}'") from err
    return columns


def _is_time(kind: pa.DataType) -> bool:
    return bool(pa.types.is_timestamp(kind) or pa.types.is_date(kind)
                or pa.types.is_duration(kind))


def _seconds(col: pa.ChunkedArray) -> np.ndarray:
    """A date-time column (Parquet timestamps, ISO 8601 text in a CSV, with or without a UTC
    offset) as seconds since 1970-01-01 UTC; a duration column as seconds."""
    kind = col.type
    if pa.types.is_date(kind):
        col = col.cast(pa.timestamp("s"))
    unit = col.type.unit
    ticks = col.cast(pa.duration(unit) if pa.types.is_duration(col.type) else
                     pa.timestamp(unit)).cast(pa.int64())
    values = np.asarray(ticks.to_numpy(zero_copy_only=False), dtype=np.float64)
    scale = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}[unit]
    return values * scale


def read_text_table(path: str | Path) -> dict[str, list[str | None]]:
    """A CSV or Parquet file's columns as text (empty cells as None), for tables of names."""
    if is_url(path):
        from odocal.io.remote import readable

        with readable(str(path), "input file") as (local, _):
            return read_text_table(local)
    p = Path(path)
    table = _arrow_table(p, text=True)
    try:
        if len(set(table.column_names)) != len(table.column_names):
            raise DataError(f"'{p}' names a column twice")
        return {name: [None if v is None else str(v) for v in table.column(name).to_pylist()]
                for name in table.column_names}
    except UnicodeDecodeError as err:
        raise DataError(f"'{p}' holds text that is not UTF-8") from err


def _printable(text: str, limit: int = 40) -> str:
    """A value from a user's file, safe to print: control characters escaped, shortened."""
    shown = "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)
    return shown[:limit] + ("..." if len(shown) > limit else "")


def _is_number(value: Any) -> bool:
    try:
        float(value)
    except (TypeError, ValueError):
        return value is None
    return True


def load_drive(path: str | Path, *, metadata: Mapping[str, Any] | None = None,
               circumference_m: float | None = None,
               pin: Mapping[str, Any] | None = None) -> Drive:
    """Read a drive-format file (CSV or Parquet; a path or a URL) into a checked
    :class:`Drive` (``circumference_m``: the datasheet's wheel, see
    :meth:`Drive.from_columns`; ``pin``: the remote object's version it must still be,
    :meth:`odocal.io.remote.ObjectInfo.pin`)."""
    if is_url(path):
        from odocal.io.remote import readable
        from odocal.io.urls import redact

        with readable(str(path), "drive file", pin=pin) as (local, digest):
            label = redact(path) if digest is not None else str(local)
            return _drive(local, label, digest, metadata, circumference_m)
    p = Path(path)
    return _drive(p, str(p), None, metadata, circumference_m)


def _drive(p: Path, label: str, digest: str | None, metadata: Mapping[str, Any] | None,
           circumference_m: float | None) -> Drive:
    columns = read_table(p)
    return Drive.from_columns(columns, name=label, metadata={
        "source": label, "sha256": digest or file_sha256(p), **(metadata or {})},
        circumference_m=circumference_m)


def file_sha256(path: str | Path) -> str:
    """SHA-256 of a file's bytes, hex."""
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for block in iter(lambda: handle.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def save_drive(drive: Drive, path: str | Path, *, owned: bool = False) -> Path:
    """Write ``drive`` in the drive format, atomically; the format follows the file suffix.
    ``owned``: a file of the user's folder (:func:`odocal.io.atomic.atomic_path`)."""
    p = Path(path)
    fmt = _format_of(p)
    table = pa.table({k: pa.array(np.asarray(v)) for k, v in drive.columns().items()})
    with atomic_path(p, owned=owned) as tmp:
        if fmt == "csv":
            pacsv.write_csv(table, tmp)
        else:
            # row groups of 65,536 rows (27 min at 40 Hz): readers that stream (odocal replay)
            # hold one group in memory, not the whole drive
            pq.write_table(table, tmp, row_group_size=ROW_GROUP_ROWS)
    return p
