"""The checks every path goes through, on a live stream: the latest driving kept, made into a
drive when the checks are due, what they found, and whether the calibrator halted."""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from odocal.arrays import FloatArray
from odocal.checks.findings import Check, Diagnosis, Finding, Severity
from odocal.data.drive import Drive
from odocal.errors import DataError
from odocal.online.samples import SAMPLE

#: The checks look at this much of the latest driving (s) ...
CHECK_WINDOW_S = 600.0
#: ... every time this much more has arrived (s), and before every estimate.
CHECK_EVERY_S = 60.0
#: Samples with the wheels at 0 and the reference pose within this (m) are a parked vehicle's.
PARKED_M = 0.5


class LiveChecks:
    """The latest :data:`CHECK_WINDOW_S` of samples on the grid (as they came), when they were
    last checked, what the checks found (:attr:`diagnosis`) and whether the data halted the
    calibrator (:attr:`halted`): a contradiction of the model, or numbers that could not be
    fitted (:meth:`failed`)."""

    def __init__(self, columns: Sequence[str] = SAMPLE) -> None:
        #: The samples' columns (:data:`~odocal.online.samples.SAMPLE` and a model's inputs).
        self.columns = tuple(columns)
        self._recent: list[FloatArray] = []
        self._checked_t = -math.inf
        self._recent_t = -math.inf                # the newest sample kept
        self._found = Diagnosis(())
        self._failure: Finding | None = None      # the numbers could not be fitted
        self.halted = False

    def keep(self, rows: FloatArray, *, driven: bool) -> None:
        """Keep the latest samples of driving: once the vehicle has ``driven``, samples of it
        parked (the wheels at 0, the reference pose within :data:`PARKED_M`) are not kept, so
        that the checks never judge a drive by the minutes parked after it (one that never
        drives is still recognised)."""
        span = np.ptp(rows[:, 5:7], axis=0) if rows.shape[0] > 1 else np.zeros(2)
        if not rows[:, 1:3].any() and float(np.hypot(*span)) <= PARKED_M and driven:
            return
        self._recent.append(rows)
        newest = float(rows[-1, 0])
        self._recent_t = newest
        while len(self._recent) > 1 and float(self._recent[1][0, 0]) <= newest - CHECK_WINDOW_S:
            self._recent.pop(0)

    @property
    def due(self) -> bool:
        """Whether :data:`CHECK_EVERY_S` more has arrived since the last check."""
        return self._recent_t - self._checked_t >= CHECK_EVERY_S

    @property
    def unchecked(self) -> bool:
        """Whether samples arrived since the last check."""
        return self._recent_t > self._checked_t

    def latest(self, t_s: float | None, source: str) -> tuple[Drive, float] | Diagnosis | None:
        """The latest :data:`CHECK_WINDOW_S` kept as a drive named by ``source`` and its span,
        and the driving it holds (s); a finding where the samples make no drive; None where
        fewer than three samples are kept. The samples count as checked."""
        samples = np.vstack(self._recent) if self._recent else np.zeros((0, len(self.columns)))
        samples = samples[samples[:, 0] > samples[-1, 0] - CHECK_WINDOW_S] if samples.size \
            else samples
        self._checked_t = float(samples[-1, 0]) if samples.size else self._checked_t
        if samples.shape[0] < 3:
            return None
        step = t_s or float(np.median(np.diff(samples[:, 0])))
        # named by the source and the stretch (s) the checks judged
        name = f"{source}, t={samples[0, 0]:.6g} to {samples[-1, 0]:.6g} s"
        try:
            drive = drive_of(samples, step, name, self.columns)
        except DataError as exc:
            return Diagnosis((Finding(Check.INVALID_INPUT, Severity.FATAL, name=str(exc)),))
        return drive, samples.shape[0] * step

    def found(self, diagnosis: Diagnosis) -> None:
        """What the checks found; a contradiction halts the calibrator."""
        self._found = diagnosis
        if diagnosis.fatal:
            self.halted = True

    def failed(self, exc: Exception) -> None:
        """The numbers could not be fitted (a solver that did not converge on degenerate
        samples): the calibrator halts with that finding rather than publish anything."""
        text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        self._failure = Finding(Check.INVALID_INPUT, Severity.FATAL,
                                name=f"the live samples cannot be fitted ({text}): they are "
                                     "degenerate or out of any vehicle's range")
        self.halted = True

    @property
    def checked(self) -> Diagnosis:
        """What the checks found on the latest samples."""
        return self._found

    @property
    def diagnosis(self) -> Diagnosis:
        """What the checks found, and why the numbers could not be fitted where they could
        not."""
        if self._failure is not None:
            return Diagnosis((*self._found.findings, self._failure))
        return self._found


def drive_of(rows: FloatArray, t_s: float, name: str, columns: Sequence[str] = SAMPLE
             ) -> Drive:
    """Samples on the grid (in ``columns``) as a drive named ``name`` (a gap beyond 1.5 steps
    ends a piece; a model input never measured is left out); a DataError where they make
    none."""
    piece = np.cumsum(np.concatenate([[0], np.diff(rows[:, 0]) > 1.5 * t_s]))
    data = {k: rows[:, i] for i, k in enumerate(columns)
            if k in SAMPLE or np.isfinite(rows[:, i]).any()}
    return Drive.from_columns(data | {"piece": piece}, name=name)
