"""The fleet's history: one SQLite file, written by one process in transactions.

SQLite because it is one file with no server, in the standard library (no extra dependency),
queried by anyone with the ``sqlite3`` command-line shell, and it has transactions: a result is
in the store whole or not at all, so a run killed at any moment loses nothing already stored.
The file is opened in WAL mode (readers, such as ``odocal fleet alarms``, never block the
writer).

Schema (version :data:`SCHEMA_VERSION`; ``meta`` holds it, :func:`open_store` migrates older
files in place):

``drives``
    one row per drive: ``drive_id`` (primary key: the hash of the vehicle and the content of
    the drive's log, ``content``, its SHA-256: the same bytes at another path or URL are the same
    drive), ``task_key`` (the hash of the inputs' content, the mapping, the settings, the
    method and odocal's version: the estimate's key; a rerun with other settings replaces the
    row), ``vehicle``, ``time`` (ISO 8601 in UTC, so that text order is time order),
    ``odometer_km``, ``source``, ``format``, ``event``, ``method``, ``status``, ``success``,
    ``message``, the model's parameters and their standard deviations (``c_e``, ``c_e_std``,
    ..., the four-wheel car's ten), ``c_e_identified`` (...), ``covariance`` (JSON, row-major in
    the model's order: c_e, c_d, t_r, d for the rear axle), ``e_p_m`` and ``datasheet_e_p_m``
    (validation errors), ``distance_km``, ``duration_s``,
    ``findings`` (JSON list of the checks' names), ``error``, ``input_hashes`` (JSON),
    ``settings_hash``, ``odocal_version``, ``report`` (the drive's own report.html, when
    written), ``out_of_range`` (JSON list of the parameters for which the quality gate rejected
    the drive, when that was its only reason: evidence for the drift detector),
    ``stored_at``. A drive is never moved to another vehicle; a new content at the same source
    of the same vehicle replaces the row of the old content.
``objects``
    what a remote object's version (``fingerprint``: its URL, size and ETag or version) was
    found to hold (``content``, the SHA-256): a rerun skips it without reading it
``pooled``
    a calibration per vehicle over its last drives (``drives`` JSON list of task keys), same
    parameter columns, and the calibrated odometry's speed and yaw-rate standard deviations
    (``speed_std_mps``, ``yaw_rate_std_radps``) for the exported parameter files
``baselines``
    per vehicle and parameter, each stretch of history between changes: ``since`` (time of its
    first drive), ``value``, ``std``, ``excess_std`` (the drive-to-drive scatter beyond the
    estimates' own uncertainty), ``drives``
``alarms``
    ``vehicle``, ``parameter``, ``kind`` (``step`` or ``trend``), ``time`` (the first drive after
    the change), ``detected_time``, ``change``, ``relative_change``, ``confidence``,
    ``drives_to_detect``, ``km_to_detect``, ``message``
``meta``
    ``schema_version``, ``created_at``, ``model`` (the vehicle model whose parameters the
    columns hold; a store without it is the rear axle's)
"""

from __future__ import annotations

import contextlib
import datetime as dt
import hashlib
import json
import sqlite3
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

from odocal.errors import DataError, OutputError, input_file, shown
from odocal.model import registry
from odocal.model.layout import Layout
from odocal.redaction import redact_text

SCHEMA_VERSION = 3

def _schema(layout: Layout) -> str:
    """The store's tables for a model of this ``layout`` (its parameters' columns)."""
    params = ", ".join(f"{n} REAL, {n}_std REAL, {n}_identified INTEGER" for n in layout.names)
    return f"""
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS drives (
    drive_id TEXT PRIMARY KEY, content TEXT, task_key TEXT NOT NULL, vehicle TEXT NOT NULL,
    time TEXT NOT NULL, odometer_km REAL,
    source TEXT NOT NULL, format TEXT, event TEXT, method TEXT, status TEXT NOT NULL,
    success INTEGER NOT NULL, message TEXT, {params}, covariance TEXT, e_p_m REAL,
    datasheet_e_p_m REAL, distance_km REAL, duration_s REAL, findings TEXT, error TEXT,
    input_hashes TEXT, settings_hash TEXT, odocal_version TEXT, report TEXT, out_of_range TEXT,
    stored_at TEXT NOT NULL);
CREATE INDEX IF NOT EXISTS drives_by_vehicle ON drives (vehicle, time);
CREATE INDEX IF NOT EXISTS drives_by_task ON drives (task_key);
CREATE INDEX IF NOT EXISTS drives_by_content ON drives (content);
CREATE TABLE IF NOT EXISTS objects (
    fingerprint TEXT PRIMARY KEY, content TEXT NOT NULL, seen_at TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS pooled (
    task_key TEXT PRIMARY KEY, vehicle TEXT NOT NULL, time TEXT NOT NULL, drives TEXT NOT NULL,
    method TEXT, status TEXT NOT NULL, success INTEGER NOT NULL, message TEXT, {params},
    covariance TEXT, e_p_m REAL, speed_std_mps REAL, yaw_rate_std_radps REAL, error TEXT,
    stored_at TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS baselines (
    vehicle TEXT NOT NULL, parameter TEXT NOT NULL, since TEXT NOT NULL, value REAL, std REAL,
    excess_std REAL, drives INTEGER, PRIMARY KEY (vehicle, parameter, since));
CREATE TABLE IF NOT EXISTS alarms (
    vehicle TEXT NOT NULL, parameter TEXT NOT NULL, kind TEXT NOT NULL, time TEXT NOT NULL,
    detected_time TEXT NOT NULL, change REAL, relative_change REAL, confidence REAL,
    drives_to_detect INTEGER, km_to_detect REAL, message TEXT,
    PRIMARY KEY (vehicle, parameter, kind, time));
"""


def _parameter_columns(layout: Layout) -> tuple[str, ...]:
    return tuple(f"{n}{suffix}" for n in layout.names for suffix in ("", "_std", "_identified"))


def drive_columns(layout: Layout) -> tuple[str, ...]:
    """Columns of ``drives`` a task result fills (besides the bookkeeping ones)."""
    return ("drive_id", "content", "task_key", "vehicle", "time", "odometer_km", "source",
            "format", "event", "method", "status", "success", "message",
            *_parameter_columns(layout), "covariance", "e_p_m", "datasheet_e_p_m",
            "distance_km", "duration_s", "findings", "error", "input_hashes", "settings_hash",
            "odocal_version", "report", "out_of_range")


def pooled_columns(layout: Layout) -> tuple[str, ...]:
    """Columns of ``pooled`` a pooled task's result fills."""
    return ("task_key", "vehicle", "time", "drives", "method", "status", "success", "message",
            *_parameter_columns(layout), "covariance", "e_p_m", "speed_std_mps",
            "yaw_rate_std_radps", "error")


def _now() -> str:
    return dt.datetime.now(dt.UTC).isoformat(timespec="seconds")


def drive_id(vehicle: str, content: str) -> str:
    """A drive's identity: its vehicle and the content of its log."""
    return hashlib.sha256(f"{vehicle}\0{content}".encode()).hexdigest()


def utc_text(text: str) -> str:
    """An ISO 8601 time as the same instant in UTC (text order is then time order); text that
    is not a time is kept."""
    try:
        stamp = dt.datetime.fromisoformat(text)
    except (TypeError, ValueError):
        return text
    stamp = stamp.astimezone(dt.UTC) if stamp.tzinfo else stamp.replace(tzinfo=dt.UTC)
    return stamp.isoformat()


class Store:
    """An open fleet database (use :func:`open_store`)."""

    def __init__(self, connection: sqlite3.Connection, path: Path,
                 model: str = registry.DEFAULT) -> None:
        self.db = connection
        self.path = path
        self.model = model                     # whose parameters the columns hold
        self.layout = registry.layout(model)

    def close(self) -> None:
        self.db.close()

    def __enter__(self) -> Store:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @contextlib.contextmanager
    def transaction(self) -> Iterator[sqlite3.Connection]:
        """Everything inside is stored together, or (on any error) not at all. A write the
        disk refuses (full, read-only, an I/O error) is an OutputError naming the store."""
        try:
            self.db.execute("BEGIN IMMEDIATE")
            yield self.db
            self.db.execute("COMMIT")
        except BaseException as exc:
            # a Ctrl-C may come before BEGIN took effect: roll back only what was begun, and
            # never let the rollback's own error hide why the transaction ended
            if self.db.in_transaction:
                with contextlib.suppress(sqlite3.Error):
                    self.db.execute("ROLLBACK")
            if isinstance(exc, sqlite3.DatabaseError) and _disk_said_no(exc):
                raise store_error(self.path, exc) from exc
            raise

    def done_keys(self) -> set[str]:
        return {r[0] for r in self.db.execute("SELECT task_key FROM drives")}

    def contents(self) -> dict[str, str]:
        """Remote objects' fingerprints -> the content they were found to hold."""
        return dict(self.db.execute("SELECT fingerprint, content FROM objects"))

    def vehicles_of(self, content: str) -> set[str]:
        """The vehicles a drive of this content is stored under (at most one)."""
        return {r[0] for r in self.db.execute("SELECT vehicle FROM drives WHERE content = ?",
                                              (content,))}

    def pooled_keys(self) -> set[str]:
        return {r[0] for r in self.db.execute("SELECT task_key FROM pooled")}

    def add_drive(self, row: Mapping[str, Any], *, fingerprint: str | None = None) -> None:
        """Store one drive's result (in its own transaction): it replaces the row of the same
        drive (vehicle and content), and a row of the same vehicle and source whose content
        was another (the file changed)."""
        row = {k: _free_text(k, v) for k, v in row.items()}
        content = row.get("content")
        row.setdefault("drive_id", drive_id(row["vehicle"], content or row["task_key"]))
        if row.get("time"):
            row["time"] = utc_text(row["time"])
        columns = drive_columns(self.layout)
        values = [_sql(row.get(c)) for c in columns]
        with self.transaction() as db:
            db.execute("DELETE FROM drives WHERE vehicle = ? AND source = ? AND drive_id != ?",
                       (row["vehicle"], row.get("source"), row["drive_id"]))
            db.execute(f"INSERT OR REPLACE INTO drives ({', '.join(columns)}, stored_at) "
                       f"VALUES ({', '.join('?' * len(columns))}, ?)", [*values, _now()])
            if fingerprint and content:
                db.execute("INSERT OR REPLACE INTO objects VALUES (?, ?, ?)",
                           (fingerprint, content, _now()))

    def add_pooled(self, row: Mapping[str, Any]) -> None:
        row = {k: _free_text(k, v) for k, v in row.items()}
        columns = pooled_columns(self.layout)
        values = [_sql(row.get(c)) for c in columns]
        with self.transaction() as db:
            db.execute(f"INSERT OR REPLACE INTO pooled ({', '.join(columns)}, stored_at) "
                       f"VALUES ({', '.join('?' * len(columns))}, ?)", [*values, _now()])

    def update_catalog_fields(self, tasks: Sequence[Any]) -> None:
        """Catalog fields of drives already stored (a corrected time, odometer or event needs
        no recalibration)."""
        with self.transaction() as db:
            # never the vehicle: a drive stays with the vehicle it was stored under
            db.executemany("UPDATE drives SET time = ?, odometer_km = ?, event = ?, source = ? "
                           "WHERE task_key = ? AND vehicle = ?",
                           [(utc_text(t.entry.time.isoformat()), t.entry.odometer_km,
                             t.entry.event, t.entry.source, t.key, t.entry.vehicle)
                            for t in tasks])

    def drives(self, vehicle: str | None = None) -> list[dict[str, Any]]:
        """Stored drive rows (of one vehicle), by vehicle and time."""
        return self._select("drives", vehicle, "vehicle, time, task_key")

    def vehicles(self) -> list[str]:
        return [r[0] for r in self.db.execute("SELECT DISTINCT vehicle FROM drives ORDER BY 1")]

    def replace_analysis(self, baselines: Sequence[Mapping[str, Any]],
                         alarms: Sequence[Mapping[str, Any]]) -> None:
        """Baselines and alarms, recomputed from the history, replaced in one transaction."""
        with self.transaction() as db:
            db.execute("DELETE FROM baselines")
            db.execute("DELETE FROM alarms")
            db.executemany("INSERT INTO baselines VALUES (:vehicle, :parameter, :since, :value, "
                           ":std, :excess_std, :drives)", baselines)
            db.executemany("INSERT INTO alarms VALUES (:vehicle, :parameter, :kind, :time, "
                           ":detected_time, :change, :relative_change, :confidence, "
                           ":drives_to_detect, :km_to_detect, :message)", alarms)

    def _select(self, table: str, vehicle: str | None, order: str) -> list[dict[str, Any]]:
        query = f"SELECT * FROM {table}" + (" WHERE vehicle = ?" if vehicle else "") \
            + f" ORDER BY {order}"
        cursor = self.db.execute(query, (vehicle,) if vehicle else ())
        names = [c[0] for c in cursor.description]
        return [dict(zip(names, r, strict=True)) for r in cursor]

    def alarms(self, vehicle: str | None = None) -> list[dict[str, Any]]:
        return self._select("alarms", vehicle, "vehicle, time, parameter")

    def baselines(self, vehicle: str | None = None) -> list[dict[str, Any]]:
        return self._select("baselines", vehicle, "vehicle, parameter, since")

    def pooled(self, vehicle: str | None = None) -> list[dict[str, Any]]:
        return self._select("pooled", vehicle, "vehicle, time")


#: Columns that name a drive or a result (never rewritten); every other text of a row is
#: stored as it may be shown (:func:`odocal.redaction.redact_text`: no URL's credentials or
#: query, no credential variable's value).
_IDENTITY = frozenset({"drive_id", "content", "task_key", "vehicle", "time", "settings_hash",
                       "input_hashes", "drives", "odocal_version"})


def _free_text(column: str, value: Any) -> Any:
    if column in _IDENTITY:
        return value
    if isinstance(value, str):
        return redact_text(value)
    if isinstance(value, list | tuple):
        return [_free_text(column, v) for v in value]
    if isinstance(value, dict):
        return {k: _free_text(column, v) for k, v in value.items()}
    return value


def _sql(value: Any) -> Any:
    if isinstance(value, list | tuple | dict):
        return json.dumps(value)
    if isinstance(value, bool):
        return int(value)
    if isinstance(value, float) and value != value:      # nan
        return None
    return value


def _check_path(p: Path, *, create: bool, read_only: bool) -> None:
    """A one-line error where ``p`` cannot be a store opened so: none there (and not to be
    created, or its folder missing), a folder, an empty file opened read-only."""
    if not p.exists():
        if not create or read_only:
            raise DataError(f"fleet store '{shown(p)}' does not exist")
        if not p.parent.exists():
            raise OutputError(f"cannot create the fleet store '{shown(p)}': its folder does "
                              "not exist")
    elif p.is_dir():
        raise DataError(f"fleet store '{shown(p)}' is a folder, not a database file")
    else:
        input_file(p, "fleet store")
        if read_only and p.stat().st_size == 0:
            raise DataError(f"'{shown(p)}' is empty, not an odocal fleet store")


def _migrate(store: Store, version: int) -> None:
    """The store's schema from ``version`` to this odocal's (SQLite's DDL is transactional:
    the migration and the new tables land together or not at all)."""
    with store.transaction() as tx:
        if version == 1:
            _migrate_1_to_2(tx)
        if version in (1, 2):
            _migrate_2_to_3(tx)
        _create_tables(tx, store.layout)
        tx.execute("INSERT OR REPLACE INTO meta VALUES ('schema_version', ?)",
                   (str(SCHEMA_VERSION),))
        tx.execute("INSERT OR IGNORE INTO meta VALUES ('created_at', ?)", (_now(),))


def open_store(path: str | Path, *, create: bool = True, read_only: bool = False,
               model: str | None = None) -> Store:
    """Open (or create) a fleet database, migrating an older schema in place.

    ``read_only``: open the file read-only (SQLite's ``mode=ro``): no journal-mode switch, no
    schema, no migration; a file that is not an odocal store of this version is refused.
    ``model``: the vehicle model the run calibrates; a store of another model's parameters is
    refused (one store holds one model's columns), a new one is marked with it.
    """
    p = Path(path)
    _check_path(p, create=create, read_only=read_only)
    db, tables = _connect(p, read_only)
    version = 0
    if "meta" in tables:
        row = db.execute("SELECT value FROM meta WHERE key = 'schema_version'").fetchone()
        version = int(row[0]) if row else 0
    if read_only and version < SCHEMA_VERSION:
        db.close()
        raise DataError(f"fleet store '{shown(p)}' has schema version {version}: open it once "
                        "with `odocal fleet calibrate` to migrate it" if version
                        else f"'{shown(p)}' is not an odocal fleet store")
    if version > SCHEMA_VERSION:
        db.close()
        raise DataError(f"fleet store '{p}' has schema version {version}, newer than this "
                        f"odocal's ({SCHEMA_VERSION}); upgrade odocal")
    empty = _holds_nothing(db, tables)
    stated = _stated_model(db, None if empty else model, p) if "meta" in tables else None
    if empty and model is not None and not read_only:
        # a store that holds no estimate (a run stopped before its first drive, or one whose
        # drives all failed, such as logs without a model's inputs) takes the run's model,
        # columns too: what it held were errors, which the run redoes
        stated = model
        _tables_for(db, model, tables)
    store = Store(db, p, stated or model or registry.DEFAULT)
    if version < SCHEMA_VERSION:
        _migrate(store, version)
    if model is not None and not read_only:
        try:
            with store.transaction() as tx:
                tx.execute("INSERT OR REPLACE INTO meta VALUES ('model', ?)", (model,))
        except BaseException:
            db.close()
            raise
    return store


def _connect(p: Path, read_only: bool) -> tuple[sqlite3.Connection, set[str]]:
    """The database at ``p`` (read-only: SQLite's ``mode=ro``; else in WAL mode) and its
    tables; a one-line error for a file that is not an SQLite database of a fleet store."""
    try:
        if read_only:
            db = sqlite3.connect(f"{p.resolve().as_uri()}?mode=ro", uri=True,
                                 isolation_level=None, timeout=30.0)
        else:
            db = sqlite3.connect(p, isolation_level=None, timeout=30.0)
        tables = {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type='table'")}
        if tables and "meta" not in tables:
            db.close()
            raise DataError(f"'{shown(p)}' is an SQLite database, but not an odocal fleet store")
        if not read_only:
            db.execute("PRAGMA journal_mode=WAL")
    except sqlite3.OperationalError as exc:
        if not read_only and _disk_said_no(exc):
            raise store_error(p, exc) from exc
        raise DataError(f"'{shown(p)}' is not an odocal fleet store (SQLite: {exc})") from exc
    except sqlite3.DatabaseError as exc:
        raise DataError(f"'{shown(p)}' is not an odocal fleet store (SQLite: {exc})") from exc
    return db, tables


def _holds_nothing(db: sqlite3.Connection, tables: set[str]) -> bool:
    """Whether the store holds no estimate: no drive and no pooled calibration with
    parameters (drives stored with only an error, such as a model's inputs missing, hold
    none), or is new."""
    return not any(db.execute(f"SELECT 1 FROM {t} WHERE c_e IS NOT NULL LIMIT 1").fetchone()
                   for t in ("drives", "pooled") if t in tables)


def _tables_for(db: sqlite3.Connection, model: str, tables: set[str]) -> None:
    """An empty store's result tables made anew with ``model``'s parameter columns (where they
    have another's), in one transaction."""
    if "drives" not in tables:
        return
    columns = [r[1] for r in db.execute("PRAGMA table_info(drives)")]
    if {c.removesuffix("_identified") for c in columns if c.endswith("_identified")} \
            == set(registry.layout(model).names):
        return
    store = Store(db, Path(), model)
    with store.transaction() as tx:
        for table in ("drives", "pooled", "baselines", "alarms"):
            tx.execute(f"DROP TABLE IF EXISTS {table}")
        _create_tables(tx, store.layout)


def _create_tables(db: sqlite3.Connection, layout: Layout) -> None:
    """Every table of the schema not there yet, with ``layout``'s parameter columns."""
    for statement in _schema(layout).split(";"):
        if statement.strip():
            db.execute(statement)


def _stated_model(db: sqlite3.Connection, model: str | None, p: Path) -> str | None:
    """The model the store's ``meta`` names (None: it names none, a new store, or one of
    before models were named: the rear axle's if it holds rows); with ``model`` given, a store
    of another model's parameters closes the database with a one-line DataError naming both."""
    row = db.execute("SELECT value FROM meta WHERE key = 'model'").fetchone()
    stated = row[0] if row else None
    try:
        if model is not None:
            registry.check_stated(stated, model, f"fleet store '{shown(p)}'")
        elif stated is not None:
            registry.check_stated(stated, stated, f"fleet store '{shown(p)}'")
    except DataError:
        db.close()
        raise
    return stated


def _disk_said_no(exc: BaseException) -> bool:
    text = str(exc).lower()
    return any(w in text for w in ("full", "disk i/o", "readonly", "read-only"))


def store_error(path: Path, exc: BaseException) -> OutputError:
    """The one line for a store the disk will not take (full, read-only, failing)."""
    import shutil

    why = str(exc)
    with contextlib.suppress(OSError):       # SQLite calls a full disk in WAL mode an I/O error
        if shutil.disk_usage(path.parent).free < (1 << 20) and "full" not in why:
            why += ": no space left on the device"
    hint = "; free space and run again" if ("full" in why or "space" in why) else ""
    return OutputError(f"cannot write the fleet store '{shown(path)}': {why} (what was stored "
                       f"before stays{hint})")


def _migrate_2_to_3(db: sqlite3.Connection) -> None:
    """Version 2 keyed drives by their estimate (a rerun with other settings added a second
    row of the same drive), stored times with their offsets (sorted as text) and let a catalog
    move a drive to another vehicle. Rows become one per drive (the latest stored), keyed by
    vehicle and content, times in UTC."""
    names = [r[1] for r in db.execute("PRAGMA table_info(drives)")]
    old = [dict(zip(names, r, strict=True))
           for r in db.execute("SELECT * FROM drives ORDER BY stored_at")]
    db.execute("ALTER TABLE drives RENAME TO drives_v2")
    rear = registry.layout(registry.DEFAULT)          # (version 2 knew no other model)
    for statement in _schema(rear).split(";"):
        if statement.strip() and "drives" in statement and "INDEX" not in statement:
            db.execute(statement)
    db.execute("DROP INDEX IF EXISTS drives_by_vehicle")
    for row in old:
        try:
            hashes = json.loads(row.get("input_hashes") or "{}")
        except ValueError:
            hashes = {}
        content = hashes.get("source") if isinstance(hashes, dict) else None
        row["content"] = content
        row["drive_id"] = drive_id(row["vehicle"], content or row["task_key"])
        row["time"] = utc_text(row["time"])
        columns = [c for c in (*drive_columns(rear), "stored_at") if c in row]
        db.execute(f"INSERT OR REPLACE INTO drives ({', '.join(columns)}) VALUES "
                   f"({', '.join('?' * len(columns))})", [row[c] for c in columns])
    db.execute("DROP TABLE drives_v2")


def _migrate_1_to_2(db: sqlite3.Connection) -> None:
    """Version 1 kept no checks' findings and no report per drive, and no pooled calibrations
    (the ``pooled`` table is created with the rest of the schema)."""
    columns = {r[1] for r in db.execute("PRAGMA table_info(drives)")}
    for name in ("findings", "report"):
        if name not in columns:
            db.execute(f"ALTER TABLE drives ADD COLUMN {name} TEXT")
