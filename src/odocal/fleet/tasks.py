"""One fleet task: one drive (or one vehicle's recent drives) calibrated, as a small plain row.

Tasks run on Dask workers and read their own files: what travels through the scheduler is the
task's description (paths, settings, method) and its result row, never drive data.

A task's key is the SHA-256 of everything its answer depends on: the content of its input files
(a folder source, such as a nuScenes tree, by its files' names, sizes and modification times),
the mapping file's content, the format, the method, the settings and odocal's version. A rerun
skips every key already in the store; a changed file, setting or version is a new task.
"""

from __future__ import annotations

import hashlib
import json
import traceback
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from odocal._version import __version__
from odocal.fleet.catalog import CatalogEntry
from odocal.model.parameters import PARAMETER_NAMES
from odocal.settings import Settings, settings_from_dict


def settings_hash(settings: Settings) -> str:
    """The hash of the settings a calibration depends on (all but the fleet's own section)."""
    plain = {k: v for k, v in settings.to_dict().items() if k != "fleet"}
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
    """One drive to calibrate: its catalog entry, how, and the key of the answer."""

    key: str
    entry: CatalogEntry
    method: str
    settings: dict[str, Any]
    input_hashes: dict[str, str]
    settings_hash: str
    report_dir: str | None = None


@dataclass(frozen=True)
class PooledTask:
    """One vehicle's latest drives calibrated together (since its last declared event)."""

    key: str
    vehicle: str
    entries: tuple[CatalogEntry, ...]
    drive_keys: tuple[str, ...]
    method: str
    settings: dict[str, Any]


def drive_task(entry: CatalogEntry, settings: Settings, method: str, *,
               report_root: Path | None = None) -> DriveTask:
    hashes = {"source": content_hash(entry.path)}
    if entry.mapping is not None:
        hashes["mapping"] = content_hash(entry.mapping)
    s_hash = settings_hash(settings)
    key = hashlib.sha256(json.dumps({
        "inputs": hashes, "format": entry.format, "method": method, "settings": s_hash,
        "version": __version__}, sort_keys=True).encode()).hexdigest()
    report_dir = (str(report_root / _safe(entry.vehicle) / key[:16])
                  if report_root is not None else None)
    return DriveTask(key=key, entry=entry, method=method, settings=settings.to_dict(),
                     input_hashes=hashes, settings_hash=s_hash, report_dir=report_dir)


def pooled_task(vehicle: str, tasks: Sequence[DriveTask], settings: Settings,
                method: str) -> PooledTask:
    keys = tuple(t.key for t in tasks)
    key = hashlib.sha256(json.dumps({"drives": keys, "method": method,
                                     "settings": settings_hash(settings),
                                     "version": __version__}).encode()).hexdigest()
    return PooledTask(key=key, vehicle=vehicle, entries=tuple(t.entry for t in tasks),
                      drive_keys=keys, method=method, settings=settings.to_dict())


def _safe(name: str) -> str:
    from odocal.io.atomic import file_name

    return file_name(name)


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0] if text else ''}".rstrip(": ")


def _read(entries: Sequence[CatalogEntry], settings: Settings) -> list[Any]:
    from odocal.pipeline.calibrate import load_drives

    drives: list[Any] = []
    for e in entries:
        if e.format == "drive":
            drives += load_drives(e.path)
        else:
            from odocal.preprocess.convert import convert

            drives += convert(e.format, [e.path], mapping=e.mapping, settings=settings)
    return drives


def _parameter_columns(result: Any) -> dict[str, Any]:
    est = result.estimate
    row: dict[str, Any] = {}
    for j, name in enumerate(PARAMETER_NAMES):
        row[name] = float(est.theta.as_array()[j])
        row[f"{name}_std"] = float(est.std[j])
        row[f"{name}_identified"] = bool(est.identified[j])
    row["covariance"] = np.asarray(est.covariance).tolist()
    row["status"] = est.status.name.lower()
    row["success"] = bool(est.success)
    row["message"] = est.message
    row["method"] = est.method
    row["e_p_m"] = result.validation.mean_error_m if result.validation is not None else None
    return row


def _limit_threads() -> None:
    # one process per core: compiled kernels must not each start a thread per core (also on
    # workers started by hand, whose environment odocal does not set)
    import numba

    numba.set_num_threads(1)


def run_drive_task(task: DriveTask) -> dict[str, Any]:
    """Calibrate one drive; a failure is a row with its error, never an exception."""
    _limit_threads()
    e = task.entry
    row: dict[str, Any] = {
        "task_key": task.key, "vehicle": e.vehicle, "time": e.time.isoformat(),
        "odometer_km": e.odometer_km, "source": str(e.path), "format": e.format,
        "event": e.event, "method": task.method, "input_hashes": task.input_hashes,
        "settings_hash": task.settings_hash, "odocal_version": __version__}
    try:
        from odocal.pipeline.calibrate import calibrate

        settings = settings_from_dict(task.settings)
        drives = _read([e], settings)
        result = calibrate(drives, settings=settings, method=task.method)
        row.update(_parameter_columns(result))
        row["datasheet_e_p_m"] = (result.datasheet_validation.mean_error_m
                                  if result.datasheet_validation is not None else None)
        row["distance_km"] = sum(d.distance_m for d in result.drives) / 1000.0
        row["duration_s"] = sum(d.duration_s for d in result.drives)
        row["findings"] = [f["check"] for f in result.diagnosis.to_dict()]
        if task.report_dir is not None:
            row["report"] = _write_drive_report(result, Path(task.report_dir))
    except Exception as exc:                       # one drive's failure never stops the fleet
        row.update(status="error", success=False, message="the drive could not be calibrated",
                   error=_one_line(exc))
        if not isinstance(exc, _expected_errors()):
            row["error"] += " | " + traceback.format_exc(limit=-1).strip().splitlines()[-2]
    return row


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
        drives = _read(task.entries, settings)
        result = calibrate(drives, settings=settings, method=task.method)
        row.update(_parameter_columns(result))
        if result.success:
            from odocal.output.export import odometry_noise

            noise = odometry_noise(drives, result.theta)
            if noise is not None:
                row["speed_std_mps"] = noise.speed_std_mps
                row["yaw_rate_std_radps"] = noise.yaw_rate_std_radps
    except Exception as exc:
        row.update(status="error", success=False, message="the drives could not be calibrated",
                   error=_one_line(exc))
    return row
