"""METHOD 2: cutting drives into identification and validation segments.

Identification segments have ``K`` steps (``K+1`` poses), start every ``step`` samples and are
selected when their peak absolute yaw rate exceeds the threshold. Validation segments are cut
afresh at other start points, each covering about ``validation_distance_m`` of travel; all of them
are used. No segment crosses a piece boundary of its drive (a gap or the end of a file).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from odocal.arrays import BoolArray, FloatArray, IntArray
from odocal.data.drive import Drive
from odocal.errors import DataError
from odocal.model.parameters import Inputs
from odocal.settings import SegmentSettings


@dataclass(frozen=True)
class SegmentSet:
    """Where segments lie in a list of drives.

    drive : ndarray of int, shape (N,)
        Index of the drive each segment belongs to.
    start : ndarray of int, shape (N,)
        Index of the segment's first pose in its drive.
    steps : ndarray of int, shape (N,)
        Number of model steps K; the segment spans poses ``start .. start + steps``.
    peak_yaw_rate_radps : ndarray, shape (N,)
        Largest absolute yaw rate in the segment.
    distance_m : ndarray, shape (N,)
        Travelled distance of the reference in the segment.
    selected : ndarray of bool, shape (N,)
        Whether the segment passes the selection rule (identification segments).
    """

    drive: IntArray
    start: IntArray
    steps: IntArray
    peak_yaw_rate_radps: FloatArray
    distance_m: FloatArray
    selected: BoolArray

    def __len__(self) -> int:
        return int(self.start.shape[0])

    def subset(self, index: IntArray | BoolArray | slice) -> SegmentSet:
        return SegmentSet(drive=self.drive[index], start=self.start[index],
                          steps=self.steps[index],
                          peak_yaw_rate_radps=self.peak_yaw_rate_radps[index],
                          distance_m=self.distance_m[index], selected=self.selected[index])


def common_sampling_time(drives: Sequence[Drive]) -> float:
    """The sampling time all drives share, or a DataError naming the odd one out."""
    if not drives:
        raise DataError("no drives were given")
    t_s = drives[0].t_s
    for d in drives[1:]:
        if abs(d.t_s - t_s) > 1e-6 * t_s:
            raise DataError(f"'{d.name}' is sampled every {d.t_s:.6g} s but '{drives[0].name}' "
                            f"every {t_s:.6g} s; resample the logs to one rate")
    return t_s


def _cumulative_distance(drive: Drive) -> FloatArray:
    step = np.hypot(np.diff(drive.x), np.diff(drive.y))
    return np.concatenate([[0.0], np.cumsum(step)])


def identification_segments(drives: Sequence[Drive], settings: SegmentSettings) -> SegmentSet:
    """Every K-step segment starting every ``step`` samples inside each piece of each drive."""
    k = settings.length
    drive_idx: list[IntArray] = []
    starts: list[IntArray] = []
    peaks: list[FloatArray] = []
    dists: list[FloatArray] = []
    for i, drive in enumerate(drives):
        abs_yaw = np.abs(drive.yaw_rate)
        cum = _cumulative_distance(drive)
        for a, b in drive.pieces:
            if b - a < k + 1:
                continue
            s = np.arange(a, b - k, settings.step, dtype=np.int64)
            windows = np.lib.stride_tricks.sliding_window_view(abs_yaw[a:b], k + 1)
            peaks.append(windows[s - a].max(axis=1))
            dists.append(cum[s + k] - cum[s])
            starts.append(s)
            drive_idx.append(np.full(s.shape, i, dtype=np.int64))
    return _make_set(drive_idx, starts, [np.full(s.shape, k, dtype=np.int64) for s in starts],
                     peaks, dists, settings.yaw_rate_threshold_radps)


def validation_segments(drives: Sequence[Drive], settings: SegmentSettings) -> SegmentSet:
    """Consecutive segments of about ``validation_distance_m`` of travel each.

    The first starts ``validation_offset`` samples into each piece; each next one starts where the
    previous one ended. A trailing remainder shorter than ``validation_min_fraction`` of the
    distance is dropped; a piece shorter than that yields one segment over all of it if it covers
    at least that fraction, and none otherwise.
    """
    target = settings.validation_distance_m
    minimum = settings.validation_min_fraction * target
    drive_idx: list[IntArray] = []
    starts: list[IntArray] = []
    steps: list[IntArray] = []
    peaks: list[FloatArray] = []
    dists: list[FloatArray] = []
    for i, drive in enumerate(drives):
        cum = _cumulative_distance(drive)
        abs_yaw = np.abs(drive.yaw_rate)
        for a, b in drive.pieces:
            first = a + settings.validation_offset
            if first >= b - 1:
                first = a
            seg_start: list[int] = []
            seg_end: list[int] = []
            s = first
            while s < b - 1:
                # first index whose distance from s reaches the target
                e = int(np.searchsorted(cum[s:b], cum[s] + target, side="left")) + s
                if e >= b:
                    e = b - 1
                    if cum[e] - cum[s] < minimum:
                        break
                seg_start.append(s)
                seg_end.append(e)
                s = e
            if not seg_start:
                continue
            s_arr = np.asarray(seg_start, dtype=np.int64)
            e_arr = np.asarray(seg_end, dtype=np.int64)
            starts.append(s_arr)
            steps.append(e_arr - s_arr)
            dists.append(cum[e_arr] - cum[s_arr])
            peaks.append(np.array([abs_yaw[p:q + 1].max() for p, q in zip(s_arr, e_arr,
                                                                            strict=True)]))
            drive_idx.append(np.full(s_arr.shape, i, dtype=np.int64))
    segset = _make_set(drive_idx, starts, steps, peaks, dists, 0.0)
    return SegmentSet(drive=segset.drive, start=segset.start, steps=segset.steps,
                      peak_yaw_rate_radps=segset.peak_yaw_rate_radps,
                      distance_m=segset.distance_m, selected=np.ones(len(segset), dtype=bool))


def _cat(parts: list[NDArray[Any]], dtype: type) -> NDArray[Any]:
    return np.concatenate(parts).astype(dtype) if parts else np.zeros(0, dtype=dtype)


def _make_set(drive_idx: list[IntArray], starts: list[IntArray], steps: list[IntArray],
              peaks: list[FloatArray], dists: list[FloatArray], threshold: float) -> SegmentSet:
    peak = _cat(peaks, np.float64)
    return SegmentSet(drive=_cat(drive_idx, np.int64), start=_cat(starts, np.int64),
                      steps=_cat(steps, np.int64), peak_yaw_rate_radps=peak,
                      distance_m=_cat(dists, np.float64), selected=peak > threshold)


class SegmentBatch:
    """Segments of equal length as 2-D arrays, ready for the model.

    inputs : Inputs with arrays of shape (N, K)
    reference : ndarray, shape (N, K+1, 3)
        Measured poses y~; ``reference[:, 0]`` is each segment's initial pose.
    t_s : float

    Made from arrays, it holds them. Made by :func:`gather_lazily`, it holds the drives and where
    the segments lie, and copies a segment's samples out only when asked: :meth:`part` a block
    of segments at a time (what the estimators loop over), ``inputs`` and ``reference`` all at
    once (6.5 times the drive's own samples for overlapping segments: a ten-hour drive's
    selected segments take about 350 MB). Wheel rates given with :meth:`with_wheel_rates`
    replace the drives' either way.
    """

    __slots__ = ("_drives", "_inputs", "_rates", "_reference", "_segments", "t_s")

    def __init__(self, inputs: Inputs, reference: FloatArray, t_s: float) -> None:
        self._inputs: Inputs | None = inputs
        self._reference: FloatArray | None = reference
        self.t_s = float(t_s)
        self._drives: tuple[Drive, ...] = ()
        self._segments: SegmentSet | None = None
        self._rates: tuple[FloatArray, FloatArray] | None = None

    @classmethod
    def _lazy(cls, drives: Sequence[Drive], segments: SegmentSet, t_s: float,
              rates: tuple[FloatArray, FloatArray] | None) -> SegmentBatch:
        batch = cls.__new__(cls)
        batch._inputs = batch._reference = None
        batch.t_s = float(t_s)
        batch._drives, batch._segments, batch._rates = tuple(drives), segments, rates
        return batch

    @property
    def lazy(self) -> bool:
        """Whether the segments are copied out of their drives only when asked."""
        return self._segments is not None

    def __len__(self) -> int:
        if self._segments is not None:
            return len(self._segments)
        assert self._reference is not None
        return int(self._reference.shape[0])

    @property
    def steps(self) -> int:
        if self._segments is not None:
            return int(self._segments.steps[0]) if len(self._segments) else 0
        assert self._reference is not None
        return int(self._reference.shape[1] - 1)

    @property
    def inputs(self) -> Inputs:
        if self._inputs is not None:
            return self._inputs
        return self.part(0, len(self))._inputs  # type: ignore[return-value]

    @property
    def reference(self) -> FloatArray:
        if self._reference is not None:
            return self._reference
        return self.part(0, len(self))._reference  # type: ignore[return-value]

    def part(self, lo: int, hi: int) -> SegmentBatch:
        """Segments ``lo`` to ``hi`` (a view of the arrays, or copied out of the drives)."""
        if self._segments is None:
            return self.take(slice(lo, hi))
        inside = slice(lo, min(hi, len(self)))
        batch = _gather(self._drives, self._segments.subset(inside), self.t_s)
        if self._rates is not None:
            return batch.with_wheel_rates(self._rates[0][inside], self._rates[1][inside])
        return batch

    def input_rows(self, name: str, lo: int, hi: int) -> FloatArray:
        """One input (``n_rl``, ``n_rr``, ``beta`` or ``a_y``) of segments ``lo`` to ``hi``,
        shape (hi - lo, K), without copying the others out."""
        if self._rates is not None and name in ("n_rl", "n_rr"):
            left, right = self._rates
            return (left if name == "n_rl" else right)[lo:hi]
        if self._segments is None:
            return np.asarray(getattr(self.inputs, name)[lo:hi])
        segs = self._segments.subset(slice(lo, min(hi, len(self))))
        out = np.empty((len(segs), self.steps))
        offsets = np.arange(self.steps)
        for i, drive in enumerate(self._drives):
            mask = segs.drive == i
            if mask.any():
                out[mask] = getattr(drive, name)[segs.start[mask][:, None] + offsets]
        return out

    def parts(self, size: int) -> Iterator[SegmentBatch]:
        """The segments a block of ``size`` at a time."""
        for lo in range(0, len(self), max(1, size)):
            yield self.part(lo, lo + size)

    def take(self, index: IntArray | BoolArray | slice) -> SegmentBatch:
        """The segments ``index`` as arrays (copied out of the drives where lazy)."""
        if self._segments is not None:
            return self.subset(index).part(0, len(self._segments.start[index]))
        u = self.inputs
        return SegmentBatch(inputs=Inputs(n_rl=u.n_rl[index], n_rr=u.n_rr[index],
                                          beta=u.beta[index], a_y=u.a_y[index]),
                            reference=self.reference[index], t_s=self.t_s)

    def subset(self, index: IntArray | BoolArray | slice) -> SegmentBatch:
        """The segments ``index``, lazy where this batch is (else as :meth:`take`)."""
        if self._segments is None:
            return self.take(index)
        rates = None if self._rates is None else (self._rates[0][index], self._rates[1][index])
        return SegmentBatch._lazy(self._drives, self._segments.subset(index), self.t_s, rates)

    def with_wheel_rates(self, n_rl: FloatArray, n_rr: FloatArray) -> SegmentBatch:
        if self._segments is not None:
            return SegmentBatch._lazy(self._drives, self._segments, self.t_s, (n_rl, n_rr))
        return SegmentBatch(inputs=self.inputs.with_wheel_rates(n_rl, n_rr),
                            reference=self.reference, t_s=self.t_s)


def gather_lazily(drives: Sequence[Drive], segments: SegmentSet) -> SegmentBatch:
    """The equal-length ``segments`` of ``drives`` as a batch that copies their samples out
    only when asked (:class:`SegmentBatch`)."""
    t_s = common_sampling_time(drives)
    if len(segments) == 0:
        raise DataError("no segments to gather")
    if (segments.steps != segments.steps[0]).any():
        raise DataError("gather needs segments of equal length; use gather_ragged")
    return SegmentBatch._lazy(drives, segments, t_s, None)


def gather(drives: Sequence[Drive], segments: SegmentSet) -> SegmentBatch:
    """Copy equal-length segments out of their drives into a :class:`SegmentBatch`."""
    return _gather(drives, segments, common_sampling_time(drives))


def _gather(drives: Sequence[Drive], segments: SegmentSet, t_s: float) -> SegmentBatch:
    n = len(segments)
    if n == 0:
        raise DataError("no segments to gather")
    k = int(segments.steps[0])
    if (segments.steps != k).any():
        raise DataError("gather needs segments of equal length; use gather_ragged")
    out = {key: np.empty((n, k)) for key in ("n_rl", "n_rr", "beta", "a_y")}
    reference = np.empty((n, k + 1, 3))
    offsets = np.arange(k + 1)
    for i, drive in enumerate(drives):
        mask = segments.drive == i
        if not mask.any():
            continue
        idx = segments.start[mask][:, None] + offsets[None, :]      # (n_i, K+1)
        for key in out:
            out[key][mask] = getattr(drive, key)[idx[:, :-1]]
        reference[mask, :, 0] = drive.x[idx]
        reference[mask, :, 1] = drive.y[idx]
        reference[mask, :, 2] = drive.psi[idx]
    return SegmentBatch(inputs=Inputs(**out), reference=reference, t_s=t_s)


@dataclass(frozen=True)
class RaggedSegments:
    """Segments of different lengths, flattened (for validation).

    inputs : Inputs with arrays of shape (L,), L = sum of steps
    initial : ndarray, shape (S, 3), the measured pose at each segment's start
    reference : ndarray, shape (L, 3)
        Measured poses after each step (the rows ``rollout_ragged`` predicts).
    steps : ndarray of int, shape (S,)
    t_s : float
    """

    inputs: Inputs
    initial: FloatArray
    reference: FloatArray
    steps: IntArray
    t_s: float

    def __len__(self) -> int:
        return int(self.steps.shape[0])

    @property
    def first(self) -> IntArray:
        """Index of each segment's first sample."""
        return np.concatenate([[0], np.cumsum(self.steps)[:-1]]).astype(np.int64)


def gather_ragged(drives: Sequence[Drive], segments: SegmentSet) -> RaggedSegments:
    """Copy segments of any lengths out of their drives, flattened."""
    t_s = common_sampling_time(drives)
    parts: dict[str, list[FloatArray]] = {k: [] for k in ("n_rl", "n_rr", "beta", "a_y")}
    ref_parts: list[FloatArray] = []
    initial: list[FloatArray] = []
    for d, s, k in zip(segments.drive, segments.start, segments.steps, strict=True):
        drive = drives[int(d)]
        for key in parts:
            parts[key].append(getattr(drive, key)[s:s + k])
        pose = np.column_stack([drive.x[s:s + k + 1], drive.y[s:s + k + 1],
                                drive.psi[s:s + k + 1]])
        initial.append(pose[0])
        ref_parts.append(pose[1:])
    if not ref_parts:
        raise DataError("no validation segments: the drives are too short for "
                        "the validation distance")
    inputs = Inputs(**{key: np.concatenate(v) for key, v in parts.items()})
    steps = segments.steps.copy()
    return RaggedSegments(inputs=inputs, initial=np.array(initial),
                          reference=np.concatenate(ref_parts), steps=steps, t_s=t_s)
