"""One fleet task: one drive (or one vehicle's recent drives) calibrated, as a small plain row.

Tasks run on Dask workers and read their own files: what travels through the scheduler is the
task's description (paths, settings, method) and its result row, never drive data.

A task's key is the SHA-256 of everything its answer depends on: the content of its input files
(a folder source, such as a nuScenes tree, by its files' names, sizes and modification times),
the mapping file's content, the format, the method, the settings and odocal's version. A rerun
skips every key already in the store; a changed file, setting or version is a new task.

A remote object's content is known once a worker has read it (the SHA-256 of its bytes, the
same as the same bytes on disk give); until then the task carries the object's version as seen
when the fleet was planned (``pin``) and its key is worked out when the result comes back. A
drive whose log cannot be read (missing, denied, unreachable, changed, cut short, not a log of
its format) comes back as ``unreadable``: named by its catalog row, never stored.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import traceback
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from odocal._version import __version__
from odocal.fleet.catalog import CatalogEntry
from odocal.model.registry import DEFAULT as DEFAULT_MODEL
from odocal.settings import Settings, settings_from_dict

log = logging.getLogger(__name__)


def settings_hash(settings: Settings) -> str:
    """The hash of the settings a calibration depends on (all but the fleet's own section; the
    vehicle model where it is the default rear axle, as every store before models were named:
    their drives are not calibrated again for a setting that did not change them)."""
    plain = {k: v for k, v in settings.to_dict().items()
             if k != "fleet" and not (k == "vehicle" and v == {"model": DEFAULT_MODEL})}
    text = json.dumps(plain, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()


def content_hash(path: Path) -> str:
    """SHA-256 of a file's bytes, or of a folder's listing (names, sizes, modification times)."""
    digest = hashlib.sha256()
    if path.is_dir():
        for p in sorted(path.rglob("*")):
            if p.is_file():
                st = p.stat()
                digest.update(f"{p.relative_to(path)}\0{st.st_size}\0{st.st_mtime_ns}\n".encode())
        return "dir:" + digest.hexdigest()
    with path.open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


@dataclass(frozen=True)
class DriveTask:
    """One drive to calibrate: its catalog entry, how, and the key of the answer (empty while
    a remote log's content is unknown: ``input_hashes`` then holds no ``source``)."""

    key: str
    entry: CatalogEntry
    method: str
    settings: dict[str, Any]
    input_hashes: dict[str, str]
    settings_hash: str
    report_dir: str | None = None
    pin: dict[str, Any] | None = None          # the remote object's version when planned
    fingerprint: str | None = None             # the remote object's version, as one hash
    report_root: str | None = None

    @property
    def name(self) -> str:
        """The task's name on the cluster (unique in the run)."""
        return self.key or f"row{self.entry.row}-{self.fingerprint}"


def task_key(hashes: dict[str, str], fmt: str, method: str, s_hash: str) -> str:
    """The key of a drive's estimate: its inputs' content, format, method, settings, version."""
    return hashlib.sha256(json.dumps({
        "inputs": hashes, "format": fmt, "method": method, "settings": s_hash,
        "version": __version__}, sort_keys=True).encode()).hexdigest()


@dataclass(frozen=True)
class PooledTask:
    """One vehicle's latest drives calibrated together (since its last declared event)."""

    key: str
    vehicle: str
    entries: tuple[CatalogEntry, ...]
    drive_keys: tuple[str, ...]
    method: str
    settings: dict[str, Any]
    pins: tuple[dict[str, Any] | None, ...] = ()
    contents: tuple[str | None, ...] = ()


def drive_task(entry: CatalogEntry, settings: Settings, method: str, *,
               report_root: Path | None = None, content: str | None = None,
               mapping_hash: str | None = None, pin: dict[str, Any] | None = None,
               fingerprint: str | None = None) -> DriveTask:
    """The task of one catalog row. A local log is hashed here; a remote one's ``content`` is
    given where the store knows its version (else the worker finds it)."""
    hashes: dict[str, str] = {}
    if not entry.remote:
        hashes["source"] = content_hash(Path(entry.path))
    elif content is not None:
        hashes["source"] = content
    if entry.mapping is not None:
        hashes["mapping"] = mapping_hash or content_hash(Path(entry.mapping))
    s_hash = settings_hash(settings)
    task = DriveTask(key="", entry=entry, method=method, settings=settings.to_dict(),
                     input_hashes=hashes, settings_hash=s_hash, pin=pin,
                     fingerprint=fingerprint,
                     report_root=str(report_root) if report_root is not None else None)
    return with_content(task, hashes["source"]) if "source" in hashes else task


def with_content(task: DriveTask, content: str) -> DriveTask:
    """The task once its log's content is known: its key and report folder."""
    import dataclasses

    hashes = {**task.input_hashes, "source": content}
    key = task_key(hashes, task.entry.format, task.method, task.settings_hash)
    report_dir = (str(Path(task.report_root) / _safe(task.entry.vehicle) / key[:16])
                  if task.report_root is not None else None)
    return dataclasses.replace(task, key=key, input_hashes=hashes, report_dir=report_dir)


def pooled_task(vehicle: str, tasks: Sequence[DriveTask], settings: Settings,
                method: str) -> PooledTask:
    keys = tuple(t.key for t in tasks)
    key = hashlib.sha256(json.dumps({"drives": keys, "method": method,
                                     "settings": settings_hash(settings),
                                     "version": __version__}).encode()).hexdigest()
    return PooledTask(key=key, vehicle=vehicle, entries=tuple(t.entry for t in tasks),
                      drive_keys=keys, method=method, settings=settings.to_dict(),
                      pins=tuple(t.pin for t in tasks),
                      contents=tuple(t.input_hashes.get("source") for t in tasks))


def _safe(name: str) -> str:
    from odocal.io.atomic import file_name

    return file_name(name)


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0] if text else ''}".rstrip(": ")


def _read(entries: Sequence[CatalogEntry], settings: Settings,
          pins: Sequence[dict[str, Any] | None] = (),
          contents: Sequence[str | None] = ()) -> tuple[list[Any], list[str | None]]:
    """The entries' drives, and each log's content (SHA-256) as read; a log whose content is
    no longer what the fleet planned with is an error that names it."""
    drives: list[Any] = []
    found: list[str | None] = []
    for i, e in enumerate(entries):
        pin = pins[i] if i < len(pins) else None
        got, content = _read_one(e, settings, pin)
        planned = contents[i] if i < len(contents) else None
        if planned is not None and content is not None and content != planned:
            from odocal.errors import InputFileError

            raise InputFileError(f"'{e.source}' changed since the fleet was planned (its "
                                 "content is not what was hashed then): not read; run the "
                                 "fleet again")
        drives += got
        found.append(content)
    return drives, found


def _read_one(e: CatalogEntry, settings: Settings, pin: dict[str, Any] | None
              ) -> tuple[list[Any], str | None]:
    from odocal.io.drivefile import load_drive
    from odocal.io.remote import readable

    if e.format == "drive" and not Path(str(e.path)).is_dir():
        drive = load_drive(e.path, pin=pin)
        return [drive], str(drive.metadata.get("sha256") or "") or None
    from odocal.preprocess.convert import convert

    with contextlib.ExitStack() as stack:
        source, digest = stack.enter_context(readable(e.path, "drive", pin=pin))
        mapping = None
        if e.mapping is not None:
            mapping = stack.enter_context(_mapping_here(e.mapping))
        drives = convert(e.format, [source], mapping=mapping, settings=settings)
    return drives, digest if digest is not None else (
        content_hash(Path(e.path)) if e.format == "drive" else None)


@contextlib.contextmanager
def _mapping_here(mapping: Any) -> Any:
    """A mapping file on this machine (a remote one copied, with the files it names)."""
    from odocal.io.remote import is_remote, mapping_here

    if not is_remote(mapping):
        yield Path(mapping)
        return
    with mapping_here(str(mapping)) as local:
        yield local


def _parameter_columns(result: Any) -> dict[str, Any]:
    """The chosen model's parameters (the four-wheel car's, or the rear axle's), their
    uncertainty and the estimate's status, by the store's column names."""
    from odocal.estimators.estimate import Status

    est = result.model_estimate
    row: dict[str, Any] = {}
    for j, name in enumerate(est.theta.layout.names):
        row[name] = float(est.theta.as_array()[j])
        row[f"{name}_std"] = float(est.std[j])
        row[f"{name}_identified"] = bool(est.identified[j])
    row["covariance"] = np.asarray(est.covariance).tolist()
    row["status"] = est.status.name.lower()
    row["success"] = bool(est.success)
    row["message"] = _rejection(result) if est.status is Status.REJECTED else est.message
    row["method"] = est.method
    row["e_p_m"] = result.validation.mean_error_m if result.validation is not None else None
    return row


def _rejection(result: Any) -> str:
    """Why the checks or the gate rejected the drives, in the store's words: the first fatal
    finding (or gate warning) as the calibration's summary says it, and how many more (the
    estimate's own message points at lines printed above it, which a stored row has not)."""
    from odocal.checks.findings import Severity
    from odocal.report.advice import finding_text

    said = [finding_text(f, result.settings) for f in result.diagnosis.findings
            if f.severity is Severity.FATAL] or list(result.warnings)
    if not said:
        return str(result.model_estimate.message)
    more = f" (and {len(said) - 1} more)" if len(said) > 1 else ""
    return f"rejected: {said[0]}{more}"


def _limit_threads() -> None:
    # one process per core: compiled kernels must not each start a thread per core (also on
    # workers started by hand, whose environment odocal does not set)
    try:
        import numba
    except ImportError:                   # the base install: nothing is compiled
        return
    numba.set_num_threads(1)


def run_drive_task(task: DriveTask) -> dict[str, Any]:
    """Calibrate one drive; a failure is a row with its error, never an exception. A log that
    cannot be read gives a row with only ``unreadable`` (the reason) and the catalog fields."""
    _limit_threads()
    e = task.entry
    row: dict[str, Any] = {
        "task_key": task.key, "vehicle": e.vehicle, "time": e.time.isoformat(),
        "odometer_km": e.odometer_km, "source": e.source, "format": e.format,
        "event": e.event, "method": task.method, "input_hashes": task.input_hashes,
        "settings_hash": task.settings_hash, "odocal_version": __version__}
    settings = settings_from_dict(task.settings)
    from odocal.io.remote import bytes_read

    before = bytes_read()
    try:
        drives, (content,) = _read([e], settings, [task.pin],
                                   [task.input_hashes.get("source")])
    except Exception as exc:                       # named by its row, nothing stored
        log.debug("drive %s cannot be read", row.get("_row"), exc_info=True)
        return {**row, "unreadable": _reason(exc)}
    row["bytes_read"] = bytes_read() - before      # from a store (0 for a local file)
    if content is not None and not task.key:
        task = with_content(task, content)
        row.update(task_key=task.key, input_hashes=task.input_hashes)
    row["content"] = task.input_hashes.get("source")
    from odocal.data.copies import samples_digest

    # what the log holds, whatever its format and clock (the same recording twice is one drive)
    row["input_hashes"] = {**row["input_hashes"],
                           "samples": ",".join(samples_digest(d) for d in drives)}
    try:
        from odocal.pipeline.calibrate import calibrate

        result = calibrate(drives, settings=settings, method=task.method)
        row.update(_parameter_columns(result))
        row["datasheet_e_p_m"] = (result.datasheet_validation.mean_error_m
                                  if result.datasheet_validation is not None else None)
        row["distance_km"] = sum(d.distance_m for d in result.drives) / 1000.0
        row["duration_s"] = sum(d.duration_s for d in result.drives)
        row["findings"] = [f["check"] for f in result.diagnosis.to_dict()]
        row["out_of_range"] = out_of_range(result)
        if task.report_dir is not None:
            try:
                row["report"] = _write_drive_report(result, Path(task.report_dir))
            except OSError as exc:                 # the outputs' disk said no: the run stops
                return {**row, "unwritable": _reason(exc)}
    except Exception as exc:                       # one drive's failure never stops the fleet
        log.debug("drive %s could not be calibrated", row.get("_row"), exc_info=True)
        row.update(status="error", success=False, message="the drive could not be calibrated",
                   error=_one_line(exc))
        if not isinstance(exc, _expected_errors()):
            row["error"] += " | " + traceback.format_exc(limit=-1).strip().splitlines()[-2]
    return row


def _reason(exc: BaseException) -> str:
    """A read failure in one line, without secrets."""
    from odocal.errors import OdocalError
    from odocal.io.urls import clean

    return clean(str(exc) if isinstance(exc, OdocalError) and str(exc) else _one_line(exc))


def out_of_range(result: Any) -> list[str] | None:
    """The parameters the quality gate found implausible, when that alone rejected the drive
    (the fit itself went well): the drift detector takes such a drive as evidence of a change
    (a flat tyre moves c_d out of its range on every drive after it)."""
    from odocal.checks.findings import Check, Severity

    fatal = [f for f in result.diagnosis.findings if f.severity is Severity.FATAL]
    if not fatal or any(f.check is not Check.PARAMETER_RANGE for f in fatal):
        return None
    return sorted({f.name for f in fatal})


def _expected_errors() -> tuple[type[BaseException], ...]:
    from odocal.errors import OdocalError

    return (OdocalError,)


def _write_drive_report(result: Any, out: Path) -> str:
    from odocal.io.atomic import results_folder
    from odocal.output.results import write_calibration
    from odocal.report import write_report

    with results_folder(out) as tmp:
        report = write_report(result, tmp)
        write_calibration(result, tmp, report=report.data.to_dict())
    return str(out / "report.html")


def run_pooled_task(task: PooledTask) -> dict[str, Any]:
    """Calibrate a vehicle's recent drives together (segments from all of them)."""
    _limit_threads()
    last = task.entries[-1]
    row: dict[str, Any] = {"task_key": task.key, "vehicle": task.vehicle,
                           "time": last.time.isoformat(), "drives": list(task.drive_keys),
                           "method": task.method}
    try:
        from odocal.pipeline.calibrate import calibrate

        settings = settings_from_dict(task.settings)
        drives, _ = _read(task.entries, settings, task.pins, task.contents)
        result = calibrate(drives, settings=settings, method=task.method)
        row.update(_parameter_columns(result))
        if result.success:
            noise = result.odometry_noise
            if noise is not None:
                row["speed_std_mps"] = noise.speed_std_mps
                row["yaw_rate_std_radps"] = noise.yaw_rate_std_radps
    except Exception as exc:
        row.update(status="error", success=False, message="the drives could not be calibrated",
                   error=_reason(exc))
    return row
