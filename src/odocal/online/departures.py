"""The sensors' departures from the model on the live path: measured as batch measures them,
taken out of the samples as they arrive.

Batch measures the departures of :mod:`odocal.checks.departures` on the whole log and corrects
it before the fit. The online calibrator measures them on the latest ten minutes of driving
(with every check) and takes out what is determined (:class:`LiveDepartures`):

* **the wheel stream's lag behind the reference** (beyond half the fit's own lag scan, up to
  ``[inverse] max_delay_s``): the reference is shifted onto the wheels' clock as the samples
  arrive (:class:`ReferenceAligner`; an early wheel stream holds the samples back by as much),
  and the fit scans ``[inverse] lag_scan_s`` around it, as batch does;
* **wheels that read an offset at standstill**: out of every sample from then on, and out of
  the windows already in memory exactly (a wheel's revolutions over a window less the offset
  times its time);
* **a heading error that varies with the heading**: out of every sample from then on (a
  window's moments cannot be turned by a heading error after the fact, nor shifted in time: the
  first minutes' windows are made again where the lag or the heading error is found after
  them, before anything is folded), measured on no less
  than :data:`HEADING_MIN_S` of driving (on two minutes a fit of its harmonics can pass its
  test at a hundred degrees), and replaced by every later measurement, zero included;
* **the rates' encoding step**: the wheel-rate offset fitted from then on, with a prior of half
  the step (truncation towards zero reads half a step low), as batch does.

For the offsets a later measurement replaces an earlier one only where it determines them (a
stretch without enough driving, or without standing still, changes nothing). What was folded
keeps the corrections of its time. a_y's clock against the reference is named by the checks,
not taken out (that would hold the stream back by up to two seconds).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from odocal.arrays import FloatArray
from odocal.checks.departures import Departures, heading_correction, pose_at
from odocal.estimators import core, fitting
from odocal.estimators.windows import WindowSet
from odocal.settings import Settings

#: The heading error is measured on no less driving than this (s).
HEADING_MIN_S = 300.0
#: Columns of a sample (as :data:`odocal.online.samples.SAMPLE`).
_NRL, _NRR, _PSI = 1, 2, 7


@dataclass(frozen=True)
class LiveDepartures:
    """What the live path takes out of the samples: each wheel's offset at standstill (rev/s),
    the heading error's harmonics (rad), and whether the wheel rates are encoded on a grid of
    ``wheel_step_revps`` (rev/s; 0: not). (a_y's offset and scale are the fit's own:
    :mod:`odocal.estimators.departures`.)"""

    reference_shift_s: float = 0.0
    """The wheel stream's lag behind the reference taken out by shifting the reference (s)."""
    wheel_offset_revps: tuple[float, float] = (0.0, 0.0)
    heading_harmonics: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0)   # a1, b1, a2, b2 (not theta)
    heading_amplitude_rad: float = 0.0
    wheel_step_revps: float = 0.0

    def as_measured(self) -> Departures:
        """The same as :class:`~odocal.checks.departures.Departures` (for its findings)."""
        return Departures(reference_shift_s=self.reference_shift_s,
                          heading_harmonics=self.heading_harmonics,
                          heading_amplitude_rad=self.heading_amplitude_rad,
                          standstill_offset_revps=self.wheel_offset_revps,
                          wheel_step_revps=self.wheel_step_revps)

    def adopt(self, found: Departures, driving_s: float, settings: Settings) -> LiveDepartures:
        """These corrections updated by a new measurement (on ``driving_s`` of driving) where
        it determines them."""
        out = self
        if any(found.standstill_offset_revps):
            out = dataclasses.replace(out, wheel_offset_revps=found.standstill_offset_revps)
        if driving_s >= HEADING_MIN_S and _apart(found.heading_harmonics,
                                                 out.heading_harmonics,
                                                 settings.checks.heading_harmonic_min_rad):
            out = dataclasses.replace(out, heading_harmonics=found.heading_harmonics,
                                      heading_amplitude_rad=found.heading_amplitude_rad)
        if found.wheel_step_revps and not out.wheel_step_revps:
            out = dataclasses.replace(out, wheel_step_revps=found.wheel_step_revps)
        return out

    def correct(self, rows: FloatArray) -> FloatArray:
        """Samples (M, 8) with the corrections taken out."""
        if not (any(self.wheel_offset_revps) or self.heading_amplitude_rad):
            return rows
        out = rows.copy()
        out[:, _NRL] -= self.wheel_offset_revps[0]
        out[:, _NRR] -= self.wheel_offset_revps[1]
        if self.heading_amplitude_rad:
            out[:, _PSI] += heading_correction(out[:, _PSI], self.heading_harmonics)
        return out


def _apart(new: tuple[float, ...], old: tuple[float, ...], smallest_rad: float) -> bool:
    """Whether two heading-error fits differ by more than half the smallest one applied."""
    return float(np.max(np.abs(np.subtract(new, old)))) > 0.5 * smallest_rad


def recorrected(windows: WindowSet, *, wheels_revps: tuple[float, float]) -> WindowSet:
    """Windows whose samples had each wheel ``wheels_revps`` more taken out: the revolutions
    less the offset times the window's time."""
    if not windows.size or not any(wheels_revps):
        return windows
    span = windows.length * windows.t_s
    measured = windows.measured - np.asarray(wheels_revps, dtype=np.float64)[None, :] * span
    return dataclasses.replace(windows, measured=measured)


def with_offset_prior(folded: fitting.Folded, settings: Settings,
                      step_revps: float) -> fitting.Folded:
    """The folded sums with the wheel-rate offset's prior for rates encoded on a grid of
    ``step_revps`` (as :meth:`odocal.estimators.fitting.Folded.prior` gives batch); as they are
    where it is already fitted or the settings do not fit it."""
    return with_offset_std(folded, core.offset_prior_std(settings, step_revps))


def with_offset_std(folded: fitting.Folded, std: float) -> fitting.Folded:
    """The folded sums with a wheel-rate offset prior of ``std`` (rev/s); as they are where the
    offset is already fitted or ``std`` is 0."""
    if folded.offset_free or std <= 0:
        return folded
    precision = std ** -2.0
    h, meat = folded.h.copy(), folded.meat.copy()
    h[fitting.OFFSET, fitting.OFFSET] += precision
    meat[fitting.OFFSET, fitting.OFFSET] += precision
    return dataclasses.replace(folded, h=h, meat=meat, offset_std=std)


#: Columns of a sample that are the reference pose (x, y, psi).
_POSE = [5, 6, 7]


class ReferenceAligner:
    """The reference pose put on the wheels' clock as the samples arrive (batch:
    :func:`odocal.checks.departures.shifted_reference`): with the wheel stream ``shift_s`` late,
    each sample's reference becomes the one ``shift_s`` earlier (interpolated within the piece;
    the heading along its shorter way round). An early wheel stream (a negative shift) needs the
    reference ahead: samples are held back by as much. Samples whose shifted time falls outside
    their piece are left out, as batch leaves them out.

    ``add`` takes samples on the grid (M, 8) and gives those it can align; a gap (a step over
    1.5 grid steps) ends a piece.
    """

    def __init__(self, t_s: float, shift_s: float = 0.0) -> None:
        self.t_s = t_s
        self.shift_s = shift_s
        self._piece = np.zeros((0, 8))      # the current piece's samples still needed
        self._sent_t = -math.inf            # the latest sample given out

    def add(self, rows: FloatArray) -> FloatArray:
        if not rows.shape[0] or self.shift_s == 0.0:
            return rows                             # (on the wheels' clock already)
        out: list[FloatArray] = []
        breaks = np.flatnonzero(np.diff(rows[:, 0]) > 1.5 * self.t_s) + 1
        first = True
        for run in np.split(rows, breaks):
            if self._piece.shape[0] and (not first or
                                         run[0, 0] - self._piece[-1, 0] > 1.5 * self.t_s):
                out.append(self._ready())     # the piece ended: what can still go out
                self._piece = np.zeros((0, 8))
            first = False
            self._piece = np.vstack([self._piece, run])
            out.append(self._ready())
        return np.vstack(out) if out else np.zeros((0, 8))

    def _ready(self) -> FloatArray:
        """The samples of the current piece whose shifted reference is within reach, shifted;
        the piece's older samples no longer needed are let go. (A sample held back for a
        reference ahead of it goes out only once that reference has come: at the piece's end,
        those still held back are the ones whose shifted time falls beyond it, which batch
        leaves out too.)"""
        piece = self._piece
        if not piece.shape[0]:
            return piece
        t = piece[:, 0]
        newest = t[-1]
        # a sample goes out once its shifted time is covered (ahead: it is held back)
        latest = newest + min(self.shift_s, 0.0)
        ready = (t > self._sent_t) & (t <= latest + 1e-9 * self.t_s)
        if not ready.any():
            return np.zeros((0, 8))
        rows = piece[ready].copy()
        rows[:, _POSE], inside = pose_at(t, piece[:, _POSE], rows[:, 0] - self.shift_s,
                                         self.t_s)
        self._sent_t = float(rows[-1, 0])
        # keep what later samples' shifted times still reach back to
        keep_from = self._sent_t - max(self.shift_s, 0.0) - 2.0 * self.t_s
        self._piece = piece[t >= keep_from]
        return rows[inside]

    def flush(self) -> FloatArray:
        """What is held back, aligned as far as the samples reach (the stream ends here)."""
        if self.shift_s == 0.0:
            return np.zeros((0, 8))
        out = self._ready()
        self._piece = np.zeros((0, 8))
        return out
