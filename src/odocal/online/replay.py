"""Streaming a log through the online calibrator (``odocal replay``).

Drive files (Parquet, CSV) are read batch by batch; ROS bags and MCAP files message by message
(:func:`odocal.io.rosbag.iter_rosbag`), their streams put onto the drive's grid as they arrive
(:class:`GridResampler`). Neither is ever loaded whole: memory stays flat however long the log.
Every ``[online] update_s`` of data the estimate is taken and handed to ``on_update`` (the CLI
prints it and writes trace.csv).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from odocal import cancel
from odocal.arrays import BoolArray, FloatArray
from odocal.checks.findings import Severity
from odocal.data.drive import MODEL_INPUTS, REQUIRED_COLUMNS
from odocal.errors import ConfigError, DataError, InputFileError, input_file
from odocal.estimators.estimate import Estimate, Status
from odocal.io.streams import Stream
from odocal.model.parameters import PARAMETER_NAMES, Parameters
from odocal.online.calibrator import OnlineCalibrator, Updates
from odocal.online.changes import Alarm
from odocal.online.samples import MAX_PUSHED_RATE_REVPS
from odocal.settings import Settings

Chunk = dict[str, FloatArray]

#: Formats replay streams: the drive format (by file suffix) and bags.
REPLAY_FORMATS = ("drive", "rosbag")
#: The drive format's columns streamed beside the required ones (a model's inputs: the
#: four-wheel car's front wheels and steering).
STREAMED = ("beta", "piece", *MODEL_INPUTS)


@dataclass(frozen=True)
class TraceRow:
    """The estimate at one moment of the replay.

    ``status`` is the estimate's (:class:`~odocal.estimators.estimate.Status` by name): a
    ``REJECTED`` row holds numbers the checks or the gate refused, never published (the checks
    that refused it in ``rejected_by``, by their codes).
    """

    t: float
    distance_km: float
    theta: tuple[float, ...]
    std: tuple[float, ...]
    identified: tuple[bool, ...]
    status: str = Status.CONVERGED.name
    rejected_by: str = ""
    names: tuple[str, ...] = PARAMETER_NAMES
    """The parameters' names (the vehicle model's layout)."""

    @staticmethod
    def header(names: Sequence[str] = PARAMETER_NAMES) -> list[str]:
        """trace.csv's header for a model of parameters ``names``."""
        return ["t", "distance_km", *names, *(f"{n}_std" for n in names),
                *(f"{n}_identified" for n in names), "status", "rejected_by"]

    def values(self) -> list[float | bool | str]:
        return [self.t, self.distance_km, *self.theta, *self.std, *self.identified,
                self.status, self.rejected_by]

    @property
    def rejected(self) -> bool:
        return self.status == Status.REJECTED.name

    @staticmethod
    def of(t: float, distance_km: float, est: Estimate) -> TraceRow:
        """The row of ``est`` taken at ``t`` after ``distance_km``."""
        return TraceRow(t=t, distance_km=distance_km,
                        theta=tuple(est.theta.as_array().tolist()), std=tuple(est.std.tolist()),
                        identified=est.identified, status=est.status.name,
                        rejected_by=",".join(rejected_by(est)), names=est.names)


def rejected_by(est: Estimate) -> tuple[str, ...]:
    """The codes of the checks that refused ``est`` (none unless it is ``REJECTED``)."""
    if est.status is not Status.REJECTED or est.details is None:
        return ()
    fatal = [f.check.value for f in getattr(est.details, "findings", ())
             if f.severity is Severity.FATAL]
    return tuple(dict.fromkeys(fatal))


def publishable(est: Estimate) -> bool:
    """Whether an estimate may replace the last one published: converged (or exact), with
    something identified, and not refused by the checks or the gate."""
    return est.status in (Status.CONVERGED, Status.EXACT) and any(est.identified)


@dataclass(frozen=True)
class ReplayResult:
    """The estimate published at the end, its history and the alarms.

    ``estimate`` is what the replay publishes: the final estimate, except where that one was
    rejected by the checks or the gate while the calibrator went on (a front-wheel finding
    after a tyre change, say): then the last estimate that was not (``final`` keeps the
    rejected one; the trace marks every rejected row). Where the data contradicted the model
    and the calibrator halted, it is the rejection itself.
    """

    source: str
    estimate: Estimate
    trace: tuple[TraceRow, ...]
    alarms: tuple[Alarm, ...]
    samples: int
    duration_s: float
    distance_km: float
    elapsed_s: float
    final: Estimate | None = None
    """The final estimate as taken (``estimate`` where that one was published)."""
    published_km: float | None = None
    """The distance driven when ``estimate`` was taken (None: it is the final one)."""


def stream_drive_file(path: str | Path, *, rows: int) -> Iterator[Chunk]:
    """A drive-format file (Parquet or CSV; a path or a URL) in batches of about ``rows`` rows.
    An object is read range by range (a Parquet row group, a CSV block at a time), never whole."""
    from odocal.io.urls import is_remote

    if is_remote(path):
        from odocal.io.remote import open_input
        from odocal.io.urls import name_of, redact

        with open_input(str(path), "input file") as handle:
            yield from _stream_drive(handle, redact(path), Path(name_of(str(path))).suffix,
                                     rows=rows)
        return
    from odocal.io.urls import local_path

    p = input_file(local_path(path))
    if not p.is_file():
        raise InputFileError(f"input file '{p}' does not exist"
                             + (" (it is a folder)" if p.is_dir() else ""))
    from odocal.io.drivefile import suffix_of

    yield from _stream_drive(p, str(p), suffix_of(p), rows=rows)


def _stream_drive(source: Any, p: str, suffix: str, *, rows: int) -> Iterator[Chunk]:
    import pyarrow as pa
    import pyarrow.csv as pacsv
    import pyarrow.parquet as pq

    suffix = suffix.lower()
    try:
        if suffix in (".parquet", ".pq"):
            pfile = pq.ParquetFile(source)
            names = pfile.schema_arrow.names
            wanted = [n for n in (*REQUIRED_COLUMNS, *STREAMED) if n in names]
            # one row group at a time (odocal writes groups of 65,536 rows): memory stays flat
            batches: Iterator[Any] = (
                batch for group in range(pfile.num_row_groups)
                for batch in pfile.read_row_group(group, columns=wanted).to_batches(
                    max_chunksize=max(rows, 8192)))
        elif suffix == ".csv":
            reader = pacsv.open_csv(source, read_options=pacsv.ReadOptions(block_size=1 << 20))
            names = reader.schema.names
            batches = iter(reader)
        else:
            raise DataError(f"'{p}': replay streams .parquet and .csv drive files (or bags with "
                            "--from rosbag)")
        missing = [c for c in REQUIRED_COLUMNS if c not in names]
        if missing:
            raise DataError(f"'{p}' lacks column{'s' if len(missing) > 1 else ''} "
                            f"{', '.join(missing)}")
        for batch in batches:           # read in large batches, handed on in chunks of ``rows``
            cols = {name: _numbers(batch.column(name))
                    for name in (*REQUIRED_COLUMNS, *STREAMED) if name in names}
            for lo in range(0, batch.num_rows, rows):
                yield {k: v[lo:lo + rows] for k, v in cols.items()}
    except (pa.ArrowInvalid, pa.ArrowTypeError, ValueError, TypeError) as exc:
        if isinstance(exc, DataError):
            raise
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise DataError(f"'{p}' cannot be read as a drive file: {first}") from exc


_SECONDS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}


def _numbers(column: Any) -> FloatArray:
    """An Arrow column as float64 (nulls NaN; timestamps as seconds since the epoch), read from
    its buffers. Not ``to_numpy``: that checks whether pandas imports, and an interrupt landing
    in that import is swallowed by pyarrow (cli/interrupt.py)."""
    import pyarrow as pa
    import pyarrow.compute as pc

    scale = 1.0
    if pa.types.is_timestamp(column.type) or pa.types.is_duration(column.type):
        scale = _SECONDS[column.type.unit]
        column = pc.cast(column, pa.int64())
    if pa.types.is_integer(column.type) and scale != 1.0:
        # whole ticks since the epoch: seconds from the first one exactly, then the epoch added
        ticks = _buffer(pc.cast(column, pa.int64()), np.int64)
        valid = _validity(column)
        first = int(ticks[valid][0]) if valid.any() else 0
        values = (ticks - first) * scale + first * scale
    else:
        floats = pc.cast(column, pa.float64(), safe=False)   # (ns since the epoch: > 2^53)
        values = _buffer(floats, np.float64).copy()
        valid = _validity(floats)
    values = np.asarray(values, dtype=np.float64)
    values[~valid] = np.nan
    return values


def _buffer(column: Any, dtype: Any) -> Any:
    """A primitive Arrow array's values (nulls hold whatever their slot holds)."""
    size = np.dtype(dtype).itemsize
    return np.frombuffer(column.buffers()[1], dtype=dtype, count=len(column),
                         offset=column.offset * size)


def _validity(column: Any) -> BoolArray:
    if column.null_count == 0:
        return np.ones(len(column), dtype=bool)
    bits = np.unpackbits(np.frombuffer(column.buffers()[0], dtype=np.uint8), bitorder="little")
    return bits[column.offset:column.offset + len(column)].astype(bool)


class GridResampler:
    """Raw streams (wheels, imu, pose) onto the drive's uniform grid, as they arrive.

    The grid runs from the wheel stream's first sample in steps of ``t_s`` (grid time ``k``
    is ``origin + k t_s``, never a sum of steps): wheel rates logged on a steady clock pass
    onto it unresampled, whatever the clock's epoch, as a drive file's rows do in
    ``odocal replay``. A grid time is emitted once every stream has samples on both sides of
    it (at the end of a log, ``final``: up to the last sample every stream has); where a stream
    has a gap longer than ``max_gap_s`` the grid skips (the calibrator starts a new piece).
    """

    def __init__(self, *, t_s: float, max_gap_s: float) -> None:
        self.t_s = t_s
        self.max_gap_s = max_gap_s
        self.buffers: dict[str, dict[str, FloatArray]] = {}
        self.origin: float | None = None          # the wheel stream's first sample, s
        self.next_k: int | None = None            # the next grid time's index
        self.last_psi: float | None = None

    def add(self, streams: Mapping[str, Stream], *, final: bool = False) -> Chunk | None:
        for role, stream in streams.items():
            order = np.argsort(stream.t, kind="stable")
            new = {"t": stream.t[order], **{k: v[order] for k, v in stream.values.items()}}
            old = self.buffers.get(role)
            if old is not None:
                new = {k: np.concatenate([old[k], new[k]]) for k in new if k in old}
            keep = np.concatenate([[True], np.diff(new["t"]) > 0])
            self.buffers[role] = {k: v[keep] for k, v in new.items()}
            if role == "wheels" and self.origin is None and self.buffers[role]["t"].size:
                self.origin = float(self.buffers[role]["t"][0])
        if not {"wheels", "pose"} <= set(self.buffers) or self.origin is None:
            return None
        roles = [r for r in ("wheels", "pose", "imu") if r in self.buffers]
        grid = self._grid(roles, final)
        if grid is None:
            return None
        return self._sample(grid, roles)

    def _grid(self, roles: Sequence[str], final: bool) -> FloatArray | None:
        """The grid times every stream now covers (and the next index moved past them)."""
        assert self.origin is not None
        origin, t_s = self.origin, self.t_s
        if self.next_k is None:
            start = max(float(self.buffers[r]["t"][0]) for r in roles)
            self.next_k = max(math.ceil((start - origin) / t_s - 1e-9), 0)
        horizon = min(float(self.buffers[r]["t"][-1]) for r in roles)
        end = (math.floor((horizon - origin) / t_s + 1e-9) + 1 if final    # up to it
               else math.ceil((horizon - origin) / t_s - 1e-9))            # before it
        if end <= self.next_k:
            return None
        grid = origin + t_s * np.arange(self.next_k, end, dtype=np.float64)
        self.next_k = end
        return grid

    def _sample(self, grid: FloatArray, roles: Sequence[str]) -> Chunk | None:
        valid = np.ones(grid.size, dtype=bool)
        out: Chunk = {"t": grid}
        for role in roles:
            buf = self.buffers[role]
            t = buf["t"]
            after = np.clip(np.searchsorted(t, grid), 1, t.size - 1)
            valid &= (t[after] - t[after - 1] <= self.max_gap_s) & (grid >= t[0])
            for key, values in buf.items():
                if key == "t":
                    continue
                if key == "psi":
                    values = np.unwrap(values)
                out[key] = np.interp(grid, t, values)
            # keep what the next grid times still need
            cut = max(int(np.searchsorted(t, grid[-1])) - 1, 0)
            self.buffers[role] = {k: v[cut:] for k, v in buf.items()}
        if "psi" in out:
            if self.last_psi is not None and out["psi"].size:
                # continue the unwrapping across chunks
                out["psi"] += 2 * np.pi * np.round((self.last_psi - out["psi"][0]) / (2 * np.pi))
            if out["psi"].size:
                self.last_psi = float(out["psi"][-1])
        if "a_y" not in out:
            out["a_y"] = np.zeros(grid.size)
        chunk = {k: v[valid] for k, v in out.items()
                 if k in ("t", "n_rl", "n_rr", "a_y", "x", "y", "psi", "yaw_rate", *MODEL_INPUTS)}
        return chunk if chunk["t"].size else None


def stream_source(source: str | Path, *, fmt: str | None, settings: Settings,
                  mapping: str | Path | Mapping[str, Mapping[str, Any]] | None = None,
                  ) -> Iterator[Chunk]:
    """Drive-format chunks from a drive file or a bag."""
    fmt = fmt or "drive"
    if fmt not in REPLAY_FORMATS:
        raise ConfigError(f"replay reads {' and '.join(REPLAY_FORMATS)} sources, not {fmt!r}; "
                          "convert other logs first (odocal convert)")
    if fmt == "drive":
        rows = max(int(settings.online.chunk_s * settings.convert.rate_hz), 1)
        yield from stream_drive_file(source, rows=rows)
        return
    from odocal.io.mapping import check_mapping, load_mapping
    from odocal.io.remote import local_inputs
    from odocal.io.rosbag import iter_rosbag

    # a bag at a URL is copied here first, in chunks (rosbags reads files); then streamed
    with local_inputs([source], None if isinstance(mapping, Mapping) else mapping) as (
            (local,), mapping_file):
        table = check_mapping(mapping) if isinstance(mapping, Mapping) \
            else load_mapping(mapping_file)
        circumference = (settings.convert.wheel_circumference_m
                         or settings.identify.datasheet("c_e"))
        grid = GridResampler(t_s=1.0 / settings.convert.rate_hz,
                             max_gap_s=settings.convert.max_gap_s)
        for streams in iter_rosbag(local, table, circumference_m=circumference,
                                   chunk_s=settings.online.chunk_s):
            chunk = grid.add(streams)
            if chunk is not None:
                yield chunk
        last = grid.add({}, final=True)            # the end: up to the last sample
        if last is not None:
            yield last


def _one_piece(chunk: Chunk, piece: float | None, source: str | Path, read: int
               ) -> float | None:
    """The chunk's ``piece`` (a drive-format column that marks separate runs of one log), or a
    DataError where a new piece starts: the live calibrator takes one run of samples, and
    would see the step between two runs as a jump of the pose."""
    values = chunk.get("piece")
    if values is None or not np.asarray(values).size:
        return piece
    values = np.asarray(values, dtype=np.float64)
    first = float(values[0]) if piece is None else piece
    change = np.flatnonzero(values != first)
    if change.size:
        from odocal.io.urls import redact

        i = int(change[0])
        raise DataError(f"'{redact(source)}' starts a new piece at row {read + i + 1} "
                        f"(t={chunk['t'][i]:.6g}; column piece {first:g} -> {values[i]:g}): "
                        "replay streams one run of samples; replay each piece on its own, or "
                        "calibrate the log (batch keeps its pieces apart)")
    return first


def located(exc: DataError, source: str | Path, chunk: Chunk, read: int,
            previous_t: float | None) -> DataError:
    """A push's DataError about a chunk of ``source`` (``read`` samples came before it, the last
    at ``previous_t``), as batch says it: the log, the column, the first bad row (1 = the first
    sample) and its time (as the log's t has it)."""
    from odocal.io.urls import redact

    name = redact(source)
    t = np.asarray(chunk["t"], dtype=np.float64)

    def at(i: int) -> str:
        return f"row {read + i + 1}" + (f", t={t[i]:.6g}" if np.isfinite(t[i]) else "")

    for key in ("t", "n_rl", "n_rr", "a_y", "beta", "x", "y", "psi"):
        values = chunk.get(key)
        if values is None:
            continue
        bad = ~np.isfinite(np.asarray(values, dtype=np.float64))
        if bad.any():
            i = int(np.argmax(bad))
            return DataError(f"'{name}' column {key} holds {int(bad.sum())} NaN or infinite "
                             f"values in rows {read + 1}-{read + t.size} (first at {at(i)})")
    before = np.concatenate([[previous_t], t]) if previous_t is not None else t
    back = np.flatnonzero(np.diff(before) <= 0)
    if back.size:
        from odocal.data.drive import check_time_precision

        check_time_precision(name, before)        # (stamps that lost their precision)
        j = int(back[0])                          # before[j + 1] does not follow before[j]
        i = j if previous_t is not None else j + 1            # its index in this chunk
        return DataError(f"'{name}' column t is not strictly increasing: t={before[j + 1]:.6g} "
                         f"follows t={before[j]:.6g} at row {read + i + 1}; sort the log or "
                         "drop duplicate stamps")
    for key in ("n_rl", "n_rr"):
        rates = np.abs(np.asarray(chunk[key], dtype=np.float64))
        too_fast = rates > MAX_PUSHED_RATE_REVPS
        if too_fast.any():
            i = int(np.argmax(too_fast))
            return DataError(f"'{name}' column {key} reaches {float(rates.max()):.4g} (first "
                             f"beyond {MAX_PUSHED_RATE_REVPS:g} at {at(i)}): wheel rates must be "
                             "in rev/s")
    text = str(exc).replace("pushed samples' ", "").replace("pushed ", "")
    return DataError(f"'{name}' rows {read + 1}-{read + t.size} (t={t[0]:.6g} to "
                     f"{t[-1]:.6g}): {text}")


def replay(source: str | Path, *, fmt: str | None = None, settings: Settings | None = None,
           mapping: str | Path | Mapping[str, Mapping[str, Any]] | None = None,
           theta0: Parameters | None = None,
           on_update: Callable[[TraceRow, Estimate], None] | None = None) -> ReplayResult:
    """Stream ``source`` through an :class:`~odocal.online.calibrator.OnlineCalibrator`.

    ``on_update(row, estimate)`` is called every ``[online] update_s`` of data and at the end.
    The trace returned holds those rows (one per update: a few thousand for a day of driving).
    Where the checks find the data contradicting the model, the replay stops there: the final
    estimate is ``REJECTED`` with the findings in ``estimate.details.findings``.
    """
    started = time.perf_counter()
    settings = settings or Settings()
    from odocal.io.urls import redact

    calibrator = OnlineCalibrator(settings, theta0, source=redact(source))
    trace: list[TraceRow] = []
    good: list[tuple[Estimate, float]] = []       # the latest publishable estimate, and where

    def update(t: float, *, final: bool = False) -> Estimate:
        est = calibrator.estimate(running=not final)
        row = TraceRow.of(t, calibrator.distance_km, est)
        trace.append(row)
        if publishable(est):
            good[:] = [(est, calibrator.distance_km)]
        if on_update is not None:
            on_update(row, est)
        return est

    span = _feed(calibrator, source, fmt=fmt, settings=settings, mapping=mapping, update=update)
    if span is None:
        raise DataError(f"'{redact(source)}' holds no samples (or a single one)")
    first_t, last_t = span
    final = update(last_t, final=True)
    published, published_km = final, None
    if final.status is Status.REJECTED and not calibrator.halted and good:
        published, published_km = good[0]
    return ReplayResult(source=redact(source), estimate=published, trace=tuple(trace),
                        alarms=calibrator.alarms, samples=calibrator.details_samples(),
                        duration_s=last_t - first_t, distance_km=calibrator.distance_km,
                        elapsed_s=time.perf_counter() - started, final=final,
                        published_km=published_km)


def _feed(calibrator: OnlineCalibrator, source: str | Path, *, fmt: str | None,
          settings: Settings, mapping: str | Path | Mapping[str, Mapping[str, Any]] | None,
          update: Callable[[float], Estimate]) -> tuple[float, float] | None:
    """Push ``source``'s chunks into ``calibrator``, calling ``update(t)`` every ``[online]
    update_s`` of data, until the log ends or the checks halt it; the span of t pushed (in
    seconds), None for no samples or a single one."""
    first_t: float | None = None
    last_t = 0.0
    updates = Updates(settings.online.update_s)
    read = 0                                      # samples read before this chunk
    piece: float | None = None                    # the drive format's piece, if it has one
    previous_t: float | None = None               # the last one's t, as the log has it
    for chunk in stream_source(source, fmt=fmt, settings=settings, mapping=mapping):
        cancel.check()                            # a stop asked for (odocal.cancel)
        if chunk["t"].size == 0:
            continue
        piece = _one_piece(chunk, piece, source, read)
        try:
            calibrator.push(chunk)
        except DataError as exc:                  # named by the log, the row and the time
            raise located(exc, source, chunk, read, previous_t) from exc
        read += int(chunk["t"].size)
        previous_t = float(chunk["t"][-1])
        span = calibrator.span_s                  # in seconds, whatever unit the log's t has
        if span is None:
            continue                              # (a lone first sample)
        first_t, last_t = span
        if calibrator.halted:
            break                 # the data contradict the model: it publishes that, not numbers
        if updates.due(span):
            update(last_t)
    if first_t is None:
        return None
    return first_t, last_t
