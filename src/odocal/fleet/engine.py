"""Calibrating a fleet on Dask: every drive a task, results stored as they arrive.

The engine runs in the process that owns the store (SQLite has one writer): it reads the
catalog, works out each drive's task key, submits the drives the store does not hold yet, and
stores each result in its own transaction the moment it arrives. Killing the run at any moment
loses nothing already stored; the rerun skips it. Then it recomputes baselines and alarms from
the whole history, and calibrates each vehicle's latest drives together (pooled).

By default the tasks run on an embedded Dask cluster on this machine (one single-threaded worker
process per core, listening on the loopback address only); ``scheduler="tcp://HOST:PORT"`` runs
them on an existing cluster, whose workers must have odocal installed and see the drive files
at the catalog's paths, or reach the objects at its URLs (each worker reads its own drives;
the scheduler carries names and small results only).

Before the first computation every remote object of the catalog is looked at (its size and
version; no data is read): a missing object, a denied read or an endpoint that cannot be reached
is named by its catalog row (``refused``), and that row is left out. A log that turns out
unreadable on a worker (cut short, changed since, not a log) is named the same way. Nothing is
stored for such a row; the other drives are calibrated and stored.
"""

from __future__ import annotations

import collections
import contextlib
import logging
import os
import re
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from odocal import cancel
from odocal.errors import ConfigError, DataError, OdocalError, OutputError, shown
from odocal.estimators import DEFAULT_METHOD, METHOD_NAMES
from odocal.fleet.catalog import CatalogEntry, read_catalog
from odocal.fleet.drift import Alarm, Analysis, analyse, last_change, parse_stamp
from odocal.fleet.store import Store, open_store
from odocal.fleet.tasks import (
    DriveTask,
    PooledTask,
    drive_task,
    pooled_task,
    run_drive_task,
    run_pooled_task,
    with_content,
)
from odocal.io.atomic import check_fleet_folder, refuse_inputs
from odocal.io.urls import name_of
from odocal.settings import Settings

log = logging.getLogger(__name__)

#: ``progress(stage, done, total)``, as for :func:`odocal.pipeline.calibrate`.
Progress = Callable[[str, int, int], None]


@dataclass(frozen=True)
class FleetRun:
    """What one ``fleet calibrate`` did."""

    drives: int                  # in the catalog
    stored_before: int           # of those, already in the store (skipped)
    calibrated: int              # run now
    failed: int                  # of all the catalog's drives, stored with an error
    pooled: int                  # pooled calibrations run now
    alarms: tuple[Alarm, ...]
    dashboard: str | None
    elapsed_s: float
    written: tuple[Path, ...] = field(default=())
    refused: tuple[str, ...] = field(default=())     # catalog rows not read, one line each
    reasons: tuple[tuple[str, int], ...] = field(default=())   # why drives failed, how many
    bytes_read: int = 0          # read from object stores by the workers for the drives run now


#: Seconds to wait for a scheduler given by address before saying it does not answer.
CONNECT_TIMEOUT_S = 10.0

_ADDRESS = re.compile(r"^(tcp|tls|ws|wss|ucx)://(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+):\d{1,5}/?$")


def check_scheduler_address(address: str) -> None:
    """ConfigError unless ``address`` reads as PROTOCOL://HOST:PORT."""
    match = _ADDRESS.match(address) if isinstance(address, str) else None
    if match is None or not 0 < int(address.rstrip("/").rsplit(":", 1)[1]) < 65536:
        raise ConfigError(f"--scheduler {shown(address)!r} is not a scheduler address: write "
                          "tcp://HOST:PORT, e.g. tcp://10.0.0.5:8786")


def available_cores() -> int:
    """The cores this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


@contextlib.contextmanager
def dask_client(scheduler: str | None = None, workers: int | None = None, *,
                connect_timeout_s: float = CONNECT_TIMEOUT_S) -> Iterator[Any]:
    """A Dask client: of an embedded local cluster (default, at most one worker per core), or
    of ``scheduler`` (given up after ``connect_timeout_s`` without an answer)."""
    from distributed import Client

    from odocal.fleet.cluster import local_client, probe_scheduler

    if scheduler:
        check_scheduler_address(scheduler)
        # asked first, within the timeout: Dask's client waits without end on a port that
        # accepts a connection and never answers
        probe_scheduler(scheduler, connect_timeout_s)
        try:
            client = Client(scheduler, timeout=f"{connect_timeout_s}s")
        except Exception as exc:       # refused, silent, or not a Dask scheduler at all
            why = (f"no answer within {connect_timeout_s:g} s" if isinstance(exc, TimeoutError)
                   else "what answers there is not a Dask scheduler"
                   if isinstance(exc, MemoryError)
                   else str(exc).splitlines()[0] if str(exc) else type(exc).__name__)
            raise ConfigError(f"cannot reach the Dask scheduler at {shown(scheduler)}: {why}"
                              ) from exc
        try:
            yield client
        finally:
            client.close()
        return
    n = workers or available_cores()
    if n < 1:
        raise ConfigError(f"--workers must be at least 1, not {n}")
    if n > available_cores():
        log.warning("--workers %d: this machine has %d cores; starting %d", n,
                    available_cores(), available_cores())
        n = available_cores()
    # worker processes that ignore Ctrl-C (this process stops them, at once) and die with
    # this process even when it is killed; a script without the __main__ guard named
    with local_client(n) as client:
        yield client


def _check_paths(store: Path, out: Path | None, catalog: Path | str,
                 entries: Sequence[CatalogEntry]) -> None:
    inputs: list[Path] = [p for p in (catalog, *(e.path for e in entries),
                                      *(e.mapping for e in entries if e.mapping is not None))
                          if isinstance(p, Path)]
    refuse_inputs(store, inputs)
    if out is not None:
        refuse_inputs(out, inputs, folder=True)
        check_fleet_folder(out)


def _unique(tasks: Sequence[DriveTask]) -> None:
    seen: dict[str, DriveTask] = {}
    for t in tasks:
        if not t.key:
            continue
        if t.key in seen:
            a, b = seen[t.key].entry, t.entry
            raise DataError(f"catalog rows {a.row} and {b.row} are the same drive "
                            f"('{name_of(a.path)}' and '{name_of(b.path)}' have the same "
                            "content)")
        seen[t.key] = t


class _SameSamples:
    """The drives' samples (:func:`odocal.data.copies.samples_digest`, which a task returns
    in its row's ``input_hashes``), stored before and stored now: a log of other bytes but the
    same samples as another drive (another format, a shifted clock) is that drive again."""

    def __init__(self, stored: Sequence[dict[str, Any]]) -> None:
        self.known: dict[str, tuple[str | None, str]] = {}
        for r in stored:
            digest = _samples_of(r.get("input_hashes"))
            if digest:
                self.known[digest] = (r.get("content"), f"the stored drive '{r.get('source')}' "
                                                        f"({shown(str(r.get('vehicle')), 40)})")

    def of(self, row: dict[str, Any], where: str) -> str | None:
        """What ``row``'s samples are a copy of (None: nothing), remembering them if new."""
        digest = _samples_of(row.get("input_hashes"))
        if not digest:
            return None
        other = self.known.get(digest)
        if other is not None and other[0] != row.get("content"):
            return other[1]
        self.known[digest] = (row.get("content"), f"{where} ('{row.get('source')}')")
        return None


def _samples_of(hashes: Any) -> str | None:
    if isinstance(hashes, str):
        import json

        try:
            hashes = json.loads(hashes)
        except ValueError:
            return None
    value = hashes.get("samples") if isinstance(hashes, dict) else None
    return value if isinstance(value, str) else None


def _row(entry: CatalogEntry) -> str:
    return f"catalog row {entry.row} ({shown(entry.vehicle, 40)})"


class _Planner:
    """Each catalog row's task: a local log hashed, a remote object looked at (size and
    version, no data) and its content taken from the store where it has read this version
    before. Rows whose object cannot be had are refused, by name."""

    def __init__(self, db: Store, settings: Settings, method: str,
                 report_root: Path | None, refuse: Callable[[str], None]) -> None:
        self.db, self.settings, self.method = db, settings, method
        self.report_root, self.refuse = report_root, refuse
        self.contents = db.contents()
        self.dead: dict[str, str] = {}            # endpoint -> why it cannot be reached

    def task(self, e: CatalogEntry) -> DriveTask | None:
        from odocal.io.remote import RemoteError, is_remote, stat

        pin = fingerprint = content = mapping_hash = None
        try:
            _check_local(e)
            if e.remote:
                endpoint = _endpoint(str(e.path))
                if endpoint in self.dead:
                    raise RemoteError(f"drive '{e.source}': {self.dead[endpoint]}")
                try:
                    info = stat(str(e.path), "drive")
                except RemoteError as exc:
                    if "cannot be reached" in str(exc):
                        self.dead[endpoint] = str(exc).split(": ", 1)[-1]
                    raise
                pin, fingerprint = info.pin(), info.fingerprint()
                content = self.contents.get(fingerprint)
            if e.mapping is not None and is_remote(e.mapping):
                mapping_hash = _remote_hash(str(e.mapping))
            task = drive_task(e, self.settings, self.method, report_root=self.report_root,
                              content=content, mapping_hash=mapping_hash, pin=pin,
                              fingerprint=fingerprint)
        except OdocalError as exc:
            self.refuse(f"{_row(e)}: {exc}")
            return None
        if task.key and not self.allowed(task, task.input_hashes["source"]):
            return None
        return task

    def allowed(self, task: DriveTask, content: str) -> bool:
        """False (and the row named) when the store holds this drive under another vehicle:
        a drive is never moved between vehicles."""
        others = sorted(self.db.vehicles_of(content) - {task.entry.vehicle})
        if others:
            self.refuse(f"{_row(task.entry)}: drive '{task.entry.source}' is stored under "
                        f"vehicle {shown(others[0], 40)}; a drive belongs to one vehicle: "
                        "correct the catalog (or remove that drive from the store first)")
            return False
        return True


def _check_local(e: CatalogEntry) -> None:
    """An InputFileError naming a local log or mapping file that is missing or not a file (a
    local catalog's were checked when it was read; a remote catalog's ``file://`` rows are
    checked here)."""
    from odocal.errors import InputFileError, input_file

    if isinstance(e.path, Path):
        if not e.path.exists():
            raise InputFileError(f"drive '{shown(e.path)}' does not exist")
        if not e.path.is_dir():
            input_file(e.path, "drive")
    if isinstance(e.mapping, Path):
        input_file(e.mapping, "mapping file")


def _endpoint(url: str) -> str:
    """Where a URL's requests go: one S3 (GCS, Azure) endpoint per scheme, one HTTP server per
    host."""
    import urllib.parse

    from odocal.io.urls import scheme_of

    scheme = scheme_of(url)
    return (f"{scheme}://{urllib.parse.urlsplit(url).netloc.rpartition('@')[2]}"
            if scheme in ("http", "https") else scheme)


def _remote_hash(url: str) -> str:
    """A small remote file's (a mapping's) SHA-256, read now."""
    from odocal.io.remote import local_copy

    with local_copy(url, "mapping file") as copy:
        return copy.sha256


#: The one line that adds what the fleet runs on.
FLEET_INSTALL_HINT = "pip install 'odocal[fleet]'"


def require_dask() -> None:
    """A one-line MissingDependencyError unless Dask's distributed scheduler is installed."""
    try:
        import distributed  # noqa: F401
    except ImportError as err:
        from odocal.errors import MissingDependencyError

        raise MissingDependencyError("the fleet runs its drives on Dask (dask.distributed), "
                                     f"which is not installed: {FLEET_INSTALL_HINT}") from err


def calibrate_fleet(catalog: str | Path, store: str | Path, *,
                    settings: Settings | None = None, method: str | None = None,
                    scheduler: str | None = None, workers: int | None = None,
                    out: str | Path | None = None, drive_reports: bool = True,
                    client: Any = None, progress: Progress | None = None,
                    echo: Callable[[str], None] | None = None,
                    connect_timeout_s: float = CONNECT_TIMEOUT_S,
                    refuse: Callable[[str], None] | None = None) -> FleetRun:
    """Calibrate every drive of a catalog into the store, then update baselines, alarms and the
    pooled calibrations; with ``out``, write the fleet report (and each drive's report) there.

    ``client``: an open Dask client to use instead of starting or joining a cluster.
    ``refuse(line)``: told of each catalog row left out (its log cannot be read, or it names a
    stored drive under another vehicle) as soon as that is known; the lines are also in
    :attr:`FleetRun.refused`. The catalog may be a URL, and so may its rows (docs/remote.md, "Fleets
    where the data lives"); the store and ``out`` are local.
    """
    require_dask()
    from odocal.fleet.cluster import refuse_unguarded_start

    refuse_unguarded_start()             # a worker process re-running an unguarded script
    started = time.perf_counter()
    settings = settings or Settings()
    method = method or DEFAULT_METHOD
    _check_run(method, scheduler, client, connect_timeout_s)
    catalog_path, store_path, out_path = _paths(catalog, store, out)
    entries = read_catalog(catalog_path)
    _check_paths(store_path, out_path, catalog_path, entries)
    report_root = out_path / "drives" if out_path is not None and drive_reports else None
    refused: list[str] = []

    def say(line: str) -> None:
        refused.append(line)
        if refuse is not None:
            refuse(line)

    with open_store(store_path, model=settings.vehicle.model) as db:
        planner = _Planner(db, settings, method, report_root, say)
        tasks, todo = _planned(db, planner, entries)
        stored_before = len(tasks) - len(todo)
        arrivals = _Arrivals(db, planner, tasks, todo, say)
        _ready_report_folder(out_path, report_root)
        try:
            with _cluster(client, scheduler, workers, connect_timeout_s=connect_timeout_s,
                          progress=progress, echo=echo) as (c, dashboard):
                _run(c, todo, run_drive_task, arrivals.store, "drives", progress)
                tasks = [arrivals.resolved[e.row] for e in entries if e.row in arrivals.resolved]
                analysis, pooled = _analysed_and_pooled(c, db, tasks, settings, method, progress)
        finally:
            # workers stopped mid-report (Ctrl-C, an error) leave their temporary folders
            _remove_report_leftovers(report_root)
        keys = {t.key for t in tasks}
        failures = [r for r in db.drives() if r["task_key"] in keys and not r["success"]]
        written = _write_outputs(db, out_path, settings)
    return FleetRun(drives=len(entries), stored_before=stored_before,
                    calibrated=len(arrivals.stored), failed=len(failures),
                    reasons=_reasons(failures), pooled=len(pooled),
                    alarms=analysis.alarms, dashboard=dashboard,
                    elapsed_s=time.perf_counter() - started, written=written,
                    refused=tuple(refused), bytes_read=sum(arrivals.bytes_read))


def _reasons(failures: Sequence[Mapping[str, Any]]) -> tuple[tuple[str, int], ...]:
    """Why the drives stored with an error failed: each reason (its first line; what it
    quotes, such as the log's path, as '...' where it stopped several drives) with how many
    drives it stopped, the commonest first."""
    said = [str(r.get("error") or r.get("message") or r.get("status")).splitlines()[0]
            for r in failures]

    def general(text: str) -> str:          # (a possessive's apostrophe is no quote)
        return re.sub(r"(?<!\w)'[^']+'(?!\w)", "'...'", text)

    counts = collections.Counter(general(s) for s in said)
    first = {general(s): s for s in reversed(said)}
    return tuple((reason if n > 1 else first[reason], n) for reason, n in counts.most_common())


def _check_run(method: str, scheduler: str | None, client: Any,
               connect_timeout_s: float) -> None:
    """A ConfigError for an unknown method, a scheduler address that is not one or a connect
    timeout out of range; a scheduler given by address (and no client) must answer in time,
    before the store is touched."""
    if method not in METHOD_NAMES:
        raise ConfigError(f"unknown method {method!r}; choose one of {', '.join(METHOD_NAMES)}")
    if scheduler:
        check_scheduler_address(scheduler)
    if not 0 < connect_timeout_s <= 3600:
        raise ConfigError(f"connect timeout {connect_timeout_s!r} s: give 0 < seconds <= 3600")
    if scheduler and client is None:     # before the store is touched: it answers, in time
        from odocal.fleet.cluster import probe_scheduler

        probe_scheduler(scheduler, connect_timeout_s)


def _paths(catalog: str | Path, store: str | Path, out: str | Path | None
           ) -> tuple[Path | str, Path, Path | None]:
    """The catalog's path (a URL stays text), the store's and the output folder's."""
    from odocal.io.urls import is_url

    catalog_path: Path | str = catalog if isinstance(catalog, str) and is_url(catalog) \
        else Path(catalog)
    return catalog_path, Path(store), Path(out) if out is not None else None


def _planned(db: Store, planner: _Planner, entries: Sequence[CatalogEntry]
             ) -> tuple[list[DriveTask], list[DriveTask]]:
    """The catalog's tasks (rows refused by the planner left out; two rows of one drive
    refused) and of those the ones to run: the store does not hold them yet. The catalog's
    fields of the drives stored before are updated in the store.

    Returns ``(tasks, todo)``.
    """
    planned = [planner.task(e) for e in entries]
    tasks = [t for t in planned if t is not None]
    _unique(tasks)
    done = db.done_keys()
    todo = [t for t in tasks if not t.key or t.key not in done]
    db.update_catalog_fields([t for t in tasks if t.key and t.key in done])
    return tasks, todo


def _ready_report_folder(out: Path | None, report_root: Path | None) -> None:
    """The fleet folder claimed (with its marker) before the workers write the drives' reports
    into it, and what a killed run's report writers left there removed."""
    if report_root is not None and out is not None:
        _claim(out)                  # marked before the workers write into it
    _remove_report_leftovers(report_root)          # of a run that was killed


def _write_outputs(db: Store, out: Path | None, settings: Settings) -> tuple[Path, ...]:
    """The fleet report written into ``out`` from the store (nothing without ``out``), the
    datasheet values those of ``settings``; the files written."""
    if out is None:
        return ()
    from odocal.fleet.report import write_fleet_outputs
    from odocal.model.parameters import Parameters

    return write_fleet_outputs(db, out, datasheet=Parameters(*settings.identify.theta0,
                                                             layout=db.layout))


class _Arrivals:
    """Each drive's result as it arrives from a worker: stored in its own transaction, or its
    catalog row named (``say``) where its log could not be read, its task was lost before its
    log's content was known, or it turns out a drive already seen (the same content, the same
    samples) or one stored under another vehicle.

    ``resolved`` (catalog row: task) holds the drives known by their content, stored before or
    now; ``stored`` the rows stored now and ``bytes_read`` what each of them read.
    """

    def __init__(self, db: Store, planner: _Planner, tasks: Sequence[DriveTask],
                 todo: Sequence[DriveTask], say: Callable[[str], None]) -> None:
        self.db, self.planner, self.say = db, planner, say
        self.resolved: dict[int, DriveTask] = {t.entry.row: t for t in tasks if t.key}
        self.seen: dict[str, int] = {t.input_hashes["source"]: t.entry.row
                                     for t in tasks if t.key}
        self.samples = _SameSamples(db.drives())
        self.by_row = {t.entry.row: t for t in todo}
        self.stored: list[int] = []
        self.bytes_read: list[int] = []

    def store(self, row: dict[str, Any]) -> None:
        """Store one task's ``row`` (its catalog row in ``row["_row"]``), or name why not."""
        say = self.say
        task = self.by_row[row["_row"]]
        if "unwritable" in row:
            raise OutputError(f"cannot write the report of {_row(task.entry)}: "
                              f"{row['unwritable']} (what was stored before stays)")
        if "unreadable" in row:
            say(f"{_row(task.entry)}: {row['unreadable']}")
            return
        if not row.get("task_key"):         # lost before its log's content was known
            say(f"{_row(task.entry)}: {row.get('message')}: {row.get('error')}")
            return
        content = row.get("content")
        if content and not task.key:      # a remote log read for the first time
            task = with_content(task, content)
            if self.seen.get(content, task.entry.row) != task.entry.row:
                say(f"{_row(task.entry)}: drive '{task.entry.source}' is the same drive "
                    f"as catalog row {self.seen[content]} (the same content)")
                return
            if not self.planner.allowed(task, content):
                return
            self.seen[content] = task.entry.row
        copied = self.samples.of(row, _row(task.entry))
        if copied:
            say(f"{_row(task.entry)}: drive '{task.entry.source}' holds the same samples as "
                f"{copied} (the same recording in another file: another format, or its "
                "clock shifted); not stored: give each drive once")
            return
        self.resolved[task.entry.row] = task
        self.db.add_drive({k: v for k, v in row.items() if k != "_row"},
                          fingerprint=task.fingerprint)
        self.stored.append(task.entry.row)
        self.bytes_read.append(int(row.get("bytes_read") or 0))


@contextlib.contextmanager
def _cluster(client: Any, scheduler: str | None, workers: int | None, *,
             connect_timeout_s: float, progress: Progress | None,
             echo: Callable[[str], None] | None) -> Iterator[tuple[Any, str | None]]:
    """The Dask client to run on and its dashboard's link: ``client`` as given, else an
    embedded cluster started (or ``scheduler`` joined) for the run, its start reported as the
    :data:`_STARTING` stage; the dashboard's link is echoed."""
    if progress and client is None:
        progress(_STARTING, 0, 1)
    with (contextlib.nullcontext(client) if client is not None
          else dask_client(scheduler, workers, connect_timeout_s=connect_timeout_s)) as c:
        if progress and client is None:
            progress(_STARTING, 1, 1)
        dashboard = getattr(c, "dashboard_link", None)
        if echo is not None and dashboard:
            echo(f"Dask dashboard: {dashboard}")
        yield c, dashboard


def _analysed_and_pooled(client: Any, db: Store, tasks: Sequence[DriveTask],
                         settings: Settings, method: str, progress: Progress | None
                         ) -> tuple[Analysis, list[PooledTask]]:
    """Baselines and alarms recomputed from the store's whole history (and stored), then the
    pooled calibrations the store does not hold yet run and stored.

    Returns the analysis and the pooled tasks run now.
    """
    rows = db.drives()
    analysis = analyse(rows, settings.fleet, db.layout)
    db.replace_analysis([b.to_row() for b in analysis.baselines],
                        [a.to_row() for a in analysis.alarms])
    pooled = [p for p in _pooled_tasks(tasks, rows, analysis.alarms, settings, method)
              if p.key not in db.pooled_keys()]
    _run(client, pooled, run_pooled_task, db.add_pooled, "pooled", progress)
    return analysis, pooled


#: The progress stage while the cluster starts (or a scheduler is joined): a few seconds.
_STARTING = "starting the Dask workers"


def _claim(out: Path) -> None:
    """Create the fleet folder with its marker now: a run killed while its workers write the
    drives' reports leaves a folder the next run knows as odocal's."""
    from odocal.io.atomic import FLEET_MARKER, write_text

    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"cannot create the output folder '{shown(out)}': "
                          f"{exc.strerror or exc}") from exc
    if not (out / FLEET_MARKER).exists():
        write_text(out / FLEET_MARKER, "written by odocal fleet calibrate; updated in place\n")


def _remove_report_leftovers(report_root: Path | None) -> None:
    """The drive reports' temporary folders whose writer is gone (``VEHICLE/.KEY.PID.*``)."""
    from odocal.io.atomic import remove_leftovers

    if report_root is None or not report_root.is_dir():
        return
    for folder in report_root.iterdir():
        if not folder.is_dir() or folder.is_symlink():
            continue
        with contextlib.suppress(OSError):
            targets = {p.name.split(".")[1] for p in folder.iterdir()
                       if p.name.startswith(".") and p.name.count(".") >= 3}
            for name in targets:
                remove_leftovers(folder / name)


def _run(client: Any, tasks: Sequence[DriveTask] | Sequence[PooledTask],
         function: Callable[[Any], dict[str, Any]], store: Callable[[dict[str, Any]], None],
         stage: str, progress: Progress | None) -> None:
    """Submit ``tasks``; store each result as it arrives (a lost worker is the task's error)."""
    if not tasks:
        return
    from distributed import as_completed

    futures = {client.submit(function, t, key=f"odocal-{stage}-{getattr(t, 'name', t.key)}",
                             pure=False, retries=0): t for t in tasks}
    if progress:
        progress(stage, 0, len(tasks))
    for n, future in enumerate(as_completed(futures), start=1):
        cancel.check()                           # a stop asked for (odocal.cancel)
        task = futures[future]
        try:
            row = future.result()
        except Exception as exc:                 # the worker died or the task could not run
            log.debug("a fleet task was lost", exc_info=True)
            row = _lost(task, exc)
        if isinstance(task, DriveTask):
            row["_row"] = task.entry.row
        store(row)
        future.release()
        if progress:
            progress(stage, n, len(tasks))


def _lost(task: DriveTask | PooledTask, exc: BaseException) -> dict[str, Any]:
    error = f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
    if isinstance(task, PooledTask):
        return {"task_key": task.key, "vehicle": task.vehicle,
                "time": task.entries[-1].time.isoformat(), "drives": list(task.drive_keys),
                "method": task.method, "status": "error", "success": False, "error": error}
    e = task.entry
    return {"task_key": task.key, "vehicle": e.vehicle, "time": e.time.isoformat(),
            "content": task.input_hashes.get("source"),
            "odometer_km": e.odometer_km, "source": e.source, "format": e.format,
            "event": e.event, "method": task.method, "status": "error", "success": False,
            "message": "the task was lost", "error": error, "input_hashes": task.input_hashes,
            "settings_hash": task.settings_hash}


def _pooled_tasks(tasks: Sequence[DriveTask], rows: Sequence[dict[str, Any]],
                  alarms: Sequence[Alarm], settings: Settings, method: str) -> list[PooledTask]:
    """Per vehicle of the catalog: its latest successful drives since its latest change."""
    by_key = {t.key: t for t in tasks}
    out: list[PooledTask] = []
    for vehicle in sorted({t.entry.vehicle for t in tasks}):
        history = [r for r in rows if r["vehicle"] == vehicle]
        since = last_change(history, [a for a in alarms if a.vehicle == vehicle])
        usable = [by_key[r["task_key"]] for r in history
                  if r["success"] and r["task_key"] in by_key
                  and (since is None or parse_stamp(r["time"]) >= since)]
        chosen = usable[-settings.fleet.pooled_drives:]
        if chosen:
            out.append(pooled_task(vehicle, chosen, settings, method))
    return out


def store_of(path: str | Path) -> Store:
    """An existing store, opened read-only (``fleet alarms``, ``fleet history``): nothing in
    the file changes, whatever it holds."""
    return open_store(path, create=False, read_only=True)
