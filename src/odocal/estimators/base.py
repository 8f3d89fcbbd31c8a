"""The one interface every method implements, and what it works on.

A method is a module of this package named as users type it (``inverse``, ``raw``,
``compensated``) with a function ``run(prep, settings, progress) -> MethodOutcome``. It is given
the drives already cut into segments (:class:`Prepared`, made once by :func:`prepare`) and hands
back the typed :class:`~odocal.estimators.estimate.Estimate`, with what the bootstrap may
resample (:class:`BootstrapTerms`). The pipeline chooses the method by name.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from odocal.arrays import BoolArray, FloatArray, IntArray
from odocal.checks.findings import Diagnosis
from odocal.data.drive import Drive
from odocal.data.segments import (
    RaggedSegments,
    SegmentBatch,
    SegmentSet,
    gather_lazily,
    identification_segments,
    validation_segments,
)
from odocal.errors import DataError
from odocal.estimators.estimate import Estimate, NotIdentified, Reason
from odocal.estimators.validation import validation_data
from odocal.settings import Settings

#: ``progress(stage, done, total)``: called as long steps advance (the CLI draws bars from it).
ProgressCallback = Callable[[str, int, int], None]

#: Parameters observable only through the yaw equation in bends (METHOD 2).
NEED_BENDS = ("t_r", "d")
#: Parameters that need the two wheels' difference (all but the distance scale).
NEED_DIFFERENTIAL = ("c_d", "t_r", "d")



@dataclass(frozen=True)
class Prepared:
    """The drives cut into segments, ready for any method.

    drives : the drives
    segments : every identification segment (with the selection rule's verdict)
    used : mask over ``segments`` of those to identify from
    held : parameters the selection already knows the data cannot identify (no bends)
    batch : the used segments' data, measured rates
    clusters : cluster label of each used segment (overlapping segments share one)
    validation_segments, validation : the validation segments and their data (None without any)
    warnings : what the user should know about the data
    selection_warnings : what the segment selection says of the data (few segments with
        bends): words of the segment methods only (the default fits every window)
    """

    drives: tuple[Drive, ...]
    segments: SegmentSet
    used: BoolArray
    held: Mapping[str, NotIdentified]
    clusters: IntArray
    validation_segments: SegmentSet
    validation: RaggedSegments | None
    warnings: tuple[str, ...]
    selection_warnings: tuple[str, ...] = ()

    @functools.cached_property
    def batch(self) -> SegmentBatch:
        """The used segments' data (asked for by the segment-based methods only, and copied out
        of the drives a block of segments at a time as they work through it)."""
        return gather_lazily(self.drives, self.segments.subset(self.used))


@dataclass(frozen=True)
class BootstrapTerms:
    """What the bootstrap resamples: per-unit information and scores at the estimate.

    information : ndarray, shape (N, n, n); scores : ndarray, shape (N, n); clusters : (N,)
    refit : theta from a resample of the units (``bootstrap_mode = "full"``), or None
    step1_thetas, step1_sets : the three-step method's step-1 sets (redrawn too)
    """

    information: FloatArray
    scores: FloatArray
    clusters: IntArray
    refit: Callable[[IntArray], FloatArray] | None = None
    step1_thetas: FloatArray | None = None
    step1_sets: int = 0


@dataclass(frozen=True)
class MethodOutcome:
    """What a method returns to the front door."""

    estimate: Estimate
    three_step: Any = None
    """The compensated method's :class:`~odocal.estimators.compensated.ThreeStepOutcome`."""
    warnings: tuple[str, ...] = ()
    bootstrap: BootstrapTerms | None = None
    """What to bootstrap over; None: the method has no bootstrap."""


def segment_clusters(segments: SegmentSet, block: int) -> IntArray:
    """Group label per segment: segments starting in the same ``block`` samples of a drive.

    Segments in one group overlap in time; the robust covariance treats each group as one
    independent observation.
    """
    return (segments.drive * (10**9) + segments.start // max(block, 1)).astype(np.int64)


def select_identification(segments: SegmentSet, settings: Settings
                          ) -> tuple[BoolArray, dict[str, NotIdentified], tuple[str, ...]]:
    """The selection rule, with the weak-data fallback to every segment.

    Returns the mask of segments to identify from, the parameters to keep at their datasheet
    values (without bends, t_r and d are not observable: the load transfer and the track width
    act on the yaw rate only when the vehicle turns), and warnings.
    """
    seg = settings.segments
    if len(segments) == 0:
        raise DataError(
            f"no drive is long enough for one identification segment of K = {seg.length} steps "
            f"({seg.length} samples); shorten [segments] length or give longer logs")
    selected = segments.selected
    if int(selected.sum()) >= seg.min_selected:
        return selected.copy(), {}, ()
    peak = float(segments.peak_yaw_rate_radps.max())
    warning = (f"only {int(selected.sum())} of {len(segments)} segments have a peak yaw rate "
               f"above {seg.yaw_rate_threshold_radps} rad/s; identifying from all of them")
    held = {name: NotIdentified(Reason.NEEDS_BENDS, detail=peak) for name in NEED_BENDS}
    return np.ones(len(segments), dtype=bool), held, (warning,)


def prepare(drives: Sequence[Drive], settings: Settings) -> Prepared:
    """Cut the drives into identification and validation segments (METHOD 2)."""
    _long_enough(drives, settings)
    id_segments = identification_segments(drives, settings.segments)
    used, held, selection_warnings = select_identification(id_segments, settings)
    warnings: tuple[str, ...] = ()
    val_segments = validation_segments(drives, settings.segments)
    val_data = (validation_data(drives, val_segments, settings) if len(val_segments)
                else None)
    if val_data is None:
        shortest = (settings.segments.validation_min_fraction
                    * settings.segments.validation_distance_m)
        warnings += (f"the drives hold no validation segment of {shortest:.0f} m or more; "
                     "E_p is not available",)
    return Prepared(drives=tuple(drives), segments=id_segments, used=used, held=held,
                    clusters=segment_clusters(id_segments.subset(used), settings.segments.length),
                    validation_segments=val_segments, validation=val_data, warnings=warnings,
                    selection_warnings=selection_warnings)





def _long_enough(drives: Sequence[Drive], settings: Settings) -> None:
    """A DataError, in seconds and samples of the drives themselves, where no stretch of them
    holds one identification segment."""
    seg = settings.segments
    stretches = [(b - a, d) for d in drives for a, b in d.pieces]
    if not stretches:
        return
    count, drive = max(stretches, key=lambda s: s[0])
    if count >= seg.length + 1:
        return
    raise DataError(f"the logs are too short to calibrate from: the longest stretch without a "
                    f"gap ('{drive.name}') holds {count} samples ({(count - 1) * drive.t_s:.1f} "
                    f"s), and an identification segment takes {seg.length + 1} samples "
                    f"({seg.length * drive.t_s:.1f} s at {1.0 / drive.t_s:.3g} Hz: [segments] "
                    f"length = {seg.length} steps); give longer logs, or a shorter [segments] "
                    "length")


def held_by_checks(diagnosis: Diagnosis) -> dict[str, NotIdentified]:
    """The parameters the checks already say the data cannot show: without a differential
    signal in the wheels, all but c_e; without a lateral acceleration, d (its datasheet
    uncertainty then widens t_r's, in the default method)."""
    held: dict[str, NotIdentified] = {}
    if diagnosis.no_differential:
        held.update({n: NotIdentified(Reason.NO_DIFFERENTIAL) for n in NEED_DIFFERENTIAL})
    elif diagnosis.lateral_missing:
        held["d"] = NotIdentified(Reason.NO_LATERAL)
    return held
