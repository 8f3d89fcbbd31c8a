"""The four-wheel car's front axle and steering while driving (``[vehicle] model =
"four_wheel"`` in ``odocal replay`` and :class:`~odocal.online.calibrator.OnlineCalibrator`).

The batch four-wheel calibration fits the front axle on the motion the rear fit settled: the
reference on the wheels' clock (the rear fit's lag), its heading turned by the rear fit's
offset, its departures taken out (:func:`odocal.estimators.front_axle.four_wheel_estimate`).
Live, those are known better the longer the drive: the lag and the offset settle in minutes.
So the samples are kept in blocks of :data:`BLOCK_S` and made into the front fit's windows
(:func:`~odocal.estimators.front_axle.front_windows`, after the front checks'
clean-up, as batch makes them) with the alignment of the moment the estimate is taken; a block's
windows are made again only where the alignment moved (:meth:`Alignment.near`). A block older
than :data:`RAW_S` keeps its windows as last made and lets its samples go, so memory grows
with the windows alone (about 1.6 MB an hour), up to :data:`MEMORY_S` of them; older windows
leave the fit (its uncertainty is then that of the driving kept).

The front fit itself is the batch one on these windows
(:func:`~odocal.estimators.front_axle.car_estimate`): nothing of it is folded, so the live
front estimate *is* the batch fit of the same windows. Its cost grows with them, so the running
updates of a replay fit it again only once the driving kept grew by a tenth
(:data:`REFIT_GROWTH`) and join its last fit with the rear axle of now in between (its stds are
those of the windows it rests on); an ``estimate()`` asked for otherwise fits it on every window
kept.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from odocal.arrays import FloatArray
from odocal.checks.findings import Check, Finding, Severity
from odocal.correlation import correlation_sums, of_sums
from odocal.data.drive import Drive
from odocal.errors import DataError
from odocal.estimators.departures import corrected, excess_doubt
from odocal.estimators.front_axle import (
    FrontWindows,
    front_checks,
    front_windows,
    stated_arm_x,
    steering_pairs,
    steering_peak,
    steering_span,
)
from odocal.online.checking import drive_of
from odocal.online.departures import LiveDepartures
from odocal.online.samples import SAMPLE
from odocal.settings import Settings

#: The samples are made into a drive (and its front windows) every this many seconds.
BLOCK_S = 120.0
#: What a block's front checks find wrong with the steering angle that is the sensor's, for the
#: whole stream (:func:`~odocal.estimators.front_axle.front_checks`): its sign, its unit, its
#: centre or spread far off while driving straight (a constant or stuck angle is the
#: block's own) ...
STREAM_WIDE = ("sign", "unit", "straight")
#: ... once this many whole blocks show it (a slice of a few seconds of a right sensor can
#: turn against the curvature; two stretches of two minutes do not).
STREAM_WIDE_BLOCKS = 2
#: Blocks this recent keep their samples, their windows made again where the alignment moves.
RAW_S = 1800.0
#: The front fit rests on this much of the latest driving at most (s).
MEMORY_S = 24 * 3600.0
#: The alignment moved where the lag moved by more than this share of a sampling step ...
NEAR_STEPS = 0.05
#: ... or the heading offset by more than this (rad: the windows' distance moves by its
#: square, 5e-7 of it) ...
NEAR_RAD = 1e-3
#: ... or a fitted departure by more than this share of its std.
NEAR_STDS = 0.1
#: A running update (``estimate(running=True)``) fits the front axle again once the driving
#: it rests on is this many times that of its last fit.
REFIT_GROWTH = 1.1
#: The model's own inputs, after the rear axle's sample (:data:`~odocal.online.samples.SAMPLE`).
INPUTS = ("n_fl", "n_fr", "steer")
#: The columns of a sample of the four-wheel car.
COLUMNS = (*SAMPLE, *INPUTS)


@dataclass(frozen=True)
class Fitted:
    """The departures the rear fit estimated beside theta (name, value, std; the lag is in
    the delay), and its theta then: what batch takes out of the drives its front axle is
    fitted on (:func:`~odocal.estimators.departures.corrected`: a reference point ahead of
    the axle, a slip, ...)."""

    departures: tuple[tuple[str, float, float], ...] = ()
    theta: tuple[float, ...] = ()

    @staticmethod
    def of(departures: Sequence[tuple[str, float, float]], theta: FloatArray) -> Fitted:
        return Fitted(tuple((n, v, s) for n, v, s in departures if n != "lag"),
                      tuple(float(x) for x in theta))

    def near(self, other: Fitted) -> bool:
        """The same departures, each within :data:`NEAR_STDS` of its std of the other's."""
        return [n for n, _, _ in self.departures] == [n for n, _, _ in other.departures] and all(
            abs(a - b) <= NEAR_STDS * s for (_, a, s), (_, b, _) in zip(
                self.departures, other.departures, strict=True))

    def corrected(self, drive: Drive) -> Drive:
        """``drive`` with these departures taken out."""
        if not self.departures:
            return drive
        values = {n: v for n, v, _ in self.departures}
        return corrected([drive], values, np.asarray(self.theta, dtype=np.float64))[0]


@dataclass(frozen=True)
class Alignment:
    """What the front windows are made with: the wheels' lag behind the reference (s), the
    reference heading's offset (rad), the departures taken out of the samples and those the
    rear fit estimated."""

    delay_s: float
    heading_offset: float
    departures: LiveDepartures
    fitted: Fitted = Fitted()
    steering_lag_s: float = 0.0
    """The steering angle's lag behind the reference on the wheels' clock (s; 0: as logged)."""

    def near(self, other: Alignment | None, t_s: float) -> bool:
        """Whether windows made with ``other`` stand for this alignment."""
        return (other is not None and other.departures == self.departures
                and abs(self.delay_s - other.delay_s) <= NEAR_STEPS * t_s
                and abs(self.steering_lag_s - other.steering_lag_s) <= NEAR_STEPS * t_s
                and abs(self.heading_offset - other.heading_offset) <= NEAR_RAD
                and self.fitted.near(other.fitted))


@dataclass
class _Block:
    """Samples on the grid (M, len(COLUMNS)) as they came, and their windows as last made."""

    rows: FloatArray | None
    first_t: float
    last_t: float
    steering: FloatArray | None = None
    """The steering angle's correlation sums with the reference's curvature
    (:func:`~odocal.correlation.correlation_sums`, the reference as logged)."""
    made: Alignment | None = None
    windows: FrontWindows | None = None
    fault: Finding | None = None
    """What its front checks found wrong with the steering angle that is the sensor's
    (:data:`STREAM_WIDE`), as last made."""


class LiveFront:
    """The front windows of a live stream (see the module docstring): ``add`` the samples as
    they come, ``windows`` at an alignment when the estimate is taken."""

    def __init__(self, settings: Settings, t_s: float, source: str) -> None:
        self.settings = settings
        self.t_s = t_s
        self.source = source
        self._blocks: list[_Block] = []
        self._open: list[FloatArray] = []
        #: Samples with both front wheels' rates measured, so far.
        self.measured = 0

    def add(self, rows: FloatArray) -> bool:
        """Samples on the grid (M, len(COLUMNS)); whether a block full of them closed (then
        :meth:`settle` at the alignment of now). A block holds the samples of :data:`BLOCK_S`
        from its first, however they came in chunks: where it ends does not hang on how the
        samples were pushed (the ROS 2 node pushes other chunks than replay; blocks closed at
        the first chunk past their span put the node's car 0.3-0.9 std from replay's on 20
        minutes)."""
        if not rows.shape[0]:
            return False
        fl, fr = COLUMNS.index("n_fl"), COLUMNS.index("n_fr")
        self.measured += int((np.isfinite(rows[:, fl]) & np.isfinite(rows[:, fr])).sum())
        self._open.append(rows)
        if float(rows[-1, 0]) - float(self._open[0][0, 0]) < BLOCK_S:
            return False
        waiting = np.vstack(self._open)
        while waiting.shape[0] and float(waiting[-1, 0]) - float(waiting[0, 0]) >= BLOCK_S:
            cut = int(np.searchsorted(waiting[:, 0], waiting[0, 0] + BLOCK_S))
            block, waiting = waiting[:cut], waiting[cut:]
            self._blocks.append(_Block(block, float(block[0, 0]), float(block[-1, 0]),
                                       self._steering_sums(block)))
        self._open = [waiting] if waiting.shape[0] else []
        return True

    def settle(self, alignment: Alignment) -> None:
        """Blocks beyond :data:`RAW_S` keep their windows (made now where they stand for
        another alignment) and let their samples go; those beyond :data:`MEMORY_S` leave."""
        newest = self._blocks[-1].last_t
        for block in self._blocks:
            if block.rows is not None and block.last_t < newest - RAW_S:
                if block.made is None:            # (else: as made at the last estimate)
                    self._made(block, self._steered(alignment, ()))
                block.rows = None
        self._blocks = [b for b in self._blocks if b.last_t >= newest - MEMORY_S]

    def windows(self, alignment: Alignment) -> FrontWindows | None:
        """Every block's windows at ``alignment`` (a block that let its samples go: as last
        made) and those of the samples since the last block; None where there are none."""
        last = None
        if self._open:
            rows = np.vstack(self._open)
            last = _Block(rows, float(rows[0, 0]), float(rows[-1, 0]),
                          self._steering_sums(rows))
        alignment = self._steered(alignment, () if last is None else (last,))
        parts = [self._made(block, alignment) for block in self._blocks]
        if last is not None:
            parts.append(self._made(last, alignment))
        windows = FrontWindows.concat([w for w in parts if w is not None])
        if windows is not None and self.steering_fault is not None:
            windows = dataclasses.replace(windows, steer=np.full_like(windows.steer, np.nan))
        return windows

    def _steered(self, alignment: Alignment, more: Sequence[_Block]) -> Alignment:
        """``alignment`` with the steering's lag behind the reference on the wheels' clock:
        found on every block's driving pooled (its latency is the sensor's, one for the whole
        stream; found block by block, its scatter moved the steering's offset by more than a
        batch std), 0 (as logged) where the angle agrees too little with the curvature."""
        sums = [b.steering for b in (*self._blocks, *more) if b.steering is not None]
        found = steering_peak(of_sums(steering_span(self.t_s), np.sum(sums, axis=0)),
                              self.t_s) if sums else None
        lag = 0.0 if found is None else found - alignment.delay_s
        return dataclasses.replace(alignment, steering_lag_s=lag)

    def _steering_sums(self, rows: FloatArray) -> FloatArray | None:
        """The steering's correlation sums of samples as they came (None: no drive, or no
        steering angle)."""
        try:
            pairs = steering_pairs(drive_of(rows, self.t_s, self.source, COLUMNS))
        except DataError:
            return None
        return correlation_sums(pairs, steering_span(self.t_s)) if pairs else None

    def forget_before(self, t: float) -> None:
        """Leave out the driving before ``t`` (the wheels changed then: what the front wheels
        said of their tyres no longer holds)."""
        self._blocks = [b for b in self._blocks if b.first_t >= t]
        self._open = [r for r in self._open if float(r[0, 0]) >= t]

    def _made(self, block: _Block, alignment: Alignment) -> FrontWindows | None:
        """The block's windows at ``alignment`` (as last made where they stand for it, or where
        its samples are gone)."""
        if block.rows is None or alignment.near(block.made, self.t_s):
            return block.windows
        rows = block.rows.copy()
        rows[:, :len(SAMPLE)] = alignment.departures.correct(rows[:, :len(SAMPLE)])
        name = f"{self.source}, t={block.first_t:.6g} to {block.last_t:.6g} s"
        try:
            drive = alignment.fitted.corrected(drive_of(rows, self.t_s, name, COLUMNS))
            checks = front_checks([drive], self.settings)
            block.fault = next((f for f in checks.findings if f.check is Check.STEERING
                                and f.severity is Severity.FALLBACK
                                and f.name.split("|")[0] in STREAM_WIDE), None)
            checked = checks.drives
            windows = front_windows(checked, self.settings, delay_s=alignment.delay_s,
                                    heading_offset=alignment.heading_offset,
                                    steering_lag_s=alignment.steering_lag_s,
                                    curve=excess_doubt(
                                        {n: v for n, v, _ in alignment.fitted.departures},
                                        stated_arm_x(self.settings)))
        except DataError:
            windows = None      # samples that make no drive: the checks name them
        block.made, block.windows = alignment, windows
        return windows

    @property
    def steering_fault(self) -> Finding | None:
        """Why the stream's steering angle is left out of every block's windows: its sign,
        its unit or its centre found wrong on :data:`STREAM_WIDE_BLOCKS` of the whole blocks
        held (one sensor for the whole stream: a block too straight to judge it kept it, and a
        fit with the angle's sign flipped on some windows lost the wheelbase, the ratio and
        the front track), or None."""
        faults = [b.fault for b in self._blocks if b.fault is not None]
        kinds = [f.name.split("|")[0] for f in faults]
        return next((f for f, kind in zip(faults, kinds, strict=True)
                     if kinds.count(kind) >= STREAM_WIDE_BLOCKS), None)

    @property
    def kept_s(self) -> float:
        """The span of driving the front fit rests on (s)."""
        if not self._blocks and not self._open:
            return 0.0
        first = self._blocks[0].first_t if self._blocks else float(self._open[0][0, 0])
        last = float(self._open[-1][-1, 0]) if self._open else self._blocks[-1].last_t
        return last - first if math.isfinite(first) else 0.0
