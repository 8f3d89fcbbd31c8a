"""METHOD 5: the three-step calibration architecture with input compensation.

1. **Step 1.** Independent batches of ``N`` selected segments are identified with batch G-N on the
   measured rates; every result is validated; ``S`` parameter sets are picked at equal steps
   through the list sorted by validation error.
2. **Step 2.** Every selected segment is compensated once with each of the ``S`` sets; the
   estimated rates are averaged.
3. **Step 3.** theta is identified with batch G-N on the compensated rates of every selected
   segment: the calibration. (The paper's per-batch variant, with ``N = 5``, is in
   :mod:`odocal.pipeline.reproduce`.)
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from odocal.arrays import BoolArray, FloatArray, IntArray
from odocal.data.segments import RaggedSegments, SegmentBatch
from odocal.estimators.base import MethodOutcome, Prepared, ProgressCallback
from odocal.estimators.compensation import BatchCompensation, compensate_batch
from odocal.estimators.estimate import CovarianceKind, Estimate, NotIdentified, held_as_weak, weak
from odocal.estimators.gauss_newton import Linearisation, bootstrap_terms, gauss_newton
from odocal.estimators.parallel import map_chunks, resolve_workers
from odocal.estimators.validation import mean_errors
from odocal.model.parameters import PARAMETER_NAMES
from odocal.settings import IdentifySettings, Settings

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Step1Result:
    """Step 1: identification of independent batches on measured rates.

    batches : ndarray of int, shape (B, N), indices into the selected segments
    thetas : ndarray, shape (B, n), theta of each batch
    success : ndarray of bool, shape (B,)
    validation_m : ndarray, shape (B,), E_p of each batch's theta (nan without validation data)
    order : ndarray of int, shape (B,), batches sorted by validation error (best first)
    picked : ndarray of int, shape (S,), the batches whose theta is used in step 2
    results : the step-1 estimates, one per batch
    """

    batches: IntArray
    thetas: FloatArray
    success: BoolArray
    validation_m: FloatArray
    order: IntArray
    picked: IntArray
    results: tuple[Estimate, ...] = field(repr=False)

    def to_dict(self) -> dict[str, Any]:
        return {
            "batches": int(self.batches.shape[0]),
            "batch_size": int(self.batches.shape[1]),
            "validation_E_p_m_sorted": [float(self.validation_m[i]) for i in self.order],
            "picked": [
                {"batch": int(b), "rank": int(np.flatnonzero(self.order == b)[0]),
                 "theta": dict(zip(PARAMETER_NAMES, self.thetas[b].tolist(), strict=True)),
                 "E_p_m": float(self.validation_m[b])}
                for b in self.picked],
            "theta_std": dict(zip(PARAMETER_NAMES, self.thetas[self.success].std(axis=0).tolist()
                                  if self.success.any() else [float("nan")] * 4, strict=True)),
        }


@dataclass(frozen=True)
class ThreeStepOutcome:
    """Everything the three steps produced.

    step1 : the step-1 batches and the picked parameter sets
    compensation : the step-2 compensated rates of every selected segment
    final : the step-3 estimate (the calibration); its covariance includes the spread the
        compensated rates inherit from the step-1 sets
    raw : batch G-N on the same segments with the measured rates, for comparison
    warnings : what the user should know
    timings_s : wall time of each step
    mean_relative_change : mean |n^ - n~| / |n~| of the compensated rates (the paper: below 1.2%)
    """

    step1: Step1Result
    compensation: BatchCompensation
    final: Estimate
    raw: Estimate
    warnings: tuple[str, ...]
    timings_s: dict[str, float]
    mean_relative_change: float
    at_final: Linearisation | None = field(default=None, repr=False, compare=False)
    """Step 3's linearisation at the calibration (what the bootstrap resamples)."""

    def to_dict(self) -> dict[str, Any]:
        comp = self.compensation
        return {
            "step1": self.step1.to_dict(),
            "step2": {"segments": int(comp.n_rl.shape[0]),
                      "parameter_sets": int(comp.status.shape[1]),
                      "solves": comp.status_counts(),
                      "segments_kept_measured_rates": int(comp.fell_back.sum()),
                      "mean_abs_relative_change": self.mean_relative_change},
            "step3": {**self.final.details.to_dict(), "message": self.final.message,
                      "covariance_kind": self.final.covariance_kind.value},
            "raw": {"theta": self.raw.theta.as_dict(),
                    "std": dict(zip(PARAMETER_NAMES, self.raw.std.tolist(), strict=True)),
                    "identified": dict(zip(PARAMETER_NAMES, self.raw.identified, strict=True))},
            "timings_s": dict(self.timings_s),
        }


def relative_change(measured: SegmentBatch, comp: BatchCompensation) -> float:
    """Mean absolute relative change of the rates by compensation, where the wheels turn
    (summed a block of segments at a time: no copy of every segment's rates)."""
    total, count = 0.0, 0
    n = len(measured)
    block = max(1, (1 << 16) // max(measured.steps, 1))
    for lo in range(0, n, block):
        part = slice(lo, lo + block)
        for meas, new in ((measured.input_rows("n_rl", lo, lo + block), comp.n_rl[part]),
                          (measured.input_rows("n_rr", lo, lo + block), comp.n_rr[part])):
            moving = np.abs(meas) > 0.5
            change = np.abs(new - meas)
            np.divide(change, np.abs(meas), out=change, where=moving)
            total += float(change.sum(where=moving))
            count += int(moving.sum())
    return total / count if count else 0.0


def draw_batches(n_segments: int, n_batches: int, batch_size: int, seed: int) -> IntArray:
    """Independent (disjoint) batches of segment indices, seeded.

    Uses as many batches as the segments allow, up to ``n_batches``; with fewer segments than one
    batch needs, one batch of all of them.
    """
    if n_segments == 0:
        return np.zeros((0, batch_size), dtype=np.int64)
    size = min(batch_size, n_segments)
    count = max(1, min(n_batches, n_segments // size))
    perm = np.random.default_rng(seed).permutation(n_segments)
    return np.sort(perm[:count * size].reshape(count, size), axis=1).astype(np.int64)


def pick_at_equal_steps(order: IntArray, count: int) -> IntArray:
    """``count`` entries at equal steps through ``order`` (first and last included)."""
    if count >= order.shape[0]:
        return order.copy()
    positions = np.round(np.linspace(0, order.shape[0] - 1, count)).astype(np.int64)
    return order[positions]


def _identify_batches(args: tuple[SegmentBatch, IntArray, IdentifySettings,
                                  dict[str, NotIdentified]]
                      ) -> tuple[list[Estimate], FloatArray | None]:
    """Worker: step-1 batches identified, and their thetas validated (E_p) where there are
    validation segments (shared by the fork in _VALIDATION, not sent)."""
    batch, batches, settings, held = args
    results = [gauss_newton(batch.take(idx), settings=settings, held=held, method="step 1")
               for idx in batches]
    validation = _VALIDATION.get("data")
    if validation is None:
        return results, None
    return results, mean_errors(np.array([r.theta.as_array() for r in results]), validation)


#: The validation segments while step 1's workers run (read through the fork).
_VALIDATION: dict[str, RaggedSegments] = {}


def step1(batch: SegmentBatch, validation: RaggedSegments | None, settings: Settings, *,
          held: Mapping[str, NotIdentified] | None = None,
          progress: Callable[[int, int], None] | None = None,
          workers: int = 1) -> Step1Result:
    """Identify independent batches on measured rates, validate, sort and pick.

    The batches are spread over ``workers`` processes (each is identified alone: the result
    does not depend on their number).
    """
    cal = settings.calibrate
    batches = draw_batches(len(batch), cal.step1_batches, cal.step1_batch_size, cal.seed)
    # Step 1 estimates every parameter the batch's equations determine, as the paper does: its
    # sets only feed the compensation and are ranked by validation; the verdict on what the drive
    # identifies belongs to the final step.
    identify = dataclasses.replace(settings.identify, judge_identifiability=False)
    per_task = max(1, -(-batches.shape[0] // 10))
    tasks = [(batch.take(np.unique(batches[lo:lo + per_task])), _reindex(batches[lo:lo + per_task]),
              identify, dict(held or {})) for lo in range(0, batches.shape[0], per_task)]
    if validation is not None:
        _VALIDATION["data"] = validation
    try:
        chunks = map_chunks(_identify_batches, tasks, workers=workers,
                            weights=[t[1].shape[0] for t in tasks], progress=progress)
    finally:
        _VALIDATION.clear()
    results = tuple(r for chunk, _ in chunks for r in chunk)
    thetas = np.array([r.theta.as_array() for r in results])
    success = np.array([r.success for r in results])
    if validation is not None:
        errors = np.concatenate([np.zeros(0)] + [e for _, e in chunks if e is not None])
    else:  # no validation segments: rank by the identification cost per segment instead
        errors = np.array([r.details.cost_history[-1] / max(r.details.segments, 1)
                           for r in results])
    ranking = np.where(success, errors, np.inf)
    order = np.argsort(ranking, kind="stable").astype(np.int64)
    usable = order[np.isfinite(ranking[order])]
    picked = pick_at_equal_steps(usable if usable.size else order, cal.step1_sets)
    return Step1Result(batches=batches, thetas=thetas, success=success,
                       validation_m=errors if validation is not None else np.full(len(results),
                                                                                   np.nan),
                       order=order, picked=picked, results=results)


def _reindex(batches: IntArray) -> IntArray:
    """Batch indices into the compacted batch made of ``np.unique(batches)``."""
    return np.searchsorted(np.unique(batches), batches).astype(np.int64)


def three_step(batch: SegmentBatch, validation: RaggedSegments | None, *, settings: Settings,
               clusters: IntArray | None = None, held: Mapping[str, NotIdentified] | None = None,
               progress: Callable[[str, int, int], None] | None = None) -> ThreeStepOutcome:
    """Run the three steps on the selected segments ``batch``; step 3 uses all of them."""
    workers = resolve_workers(settings.calibrate.workers)
    warnings: list[str] = []
    timings: dict[str, float] = {}

    def stage(name: str) -> Callable[[int, int], None] | None:
        if progress is None:
            return None
        return lambda done, total: progress(name, done, total)

    started = time.perf_counter()
    s1 = step1(batch, validation, settings, held=held,
               progress=stage("step 1: batches"), workers=workers)
    timings["step1"] = time.perf_counter() - started
    if not s1.success.any():
        warnings.append("no step-1 batch could be identified; compensating with the datasheet "
                        "parameters")
    sets = s1.thetas[s1.picked]
    if s1.batches.shape[0] < settings.calibrate.step1_sets:
        warnings.append(f"only {s1.batches.shape[0]} step-1 batch(es) of "
                        f"{s1.batches.shape[1]} segments fit in {len(batch)} selected segments "
                        f"(the method asks for {settings.calibrate.step1_batches}); step 2 uses "
                        f"{sets.shape[0]} parameter set(s)")

    started = time.perf_counter()
    comp = compensate_batch(batch, sets, settings.compensate, workers=workers,
                            progress=stage("step 2: compensation"))
    timings["step2"] = time.perf_counter() - started
    if comp.fell_back.any():
        warnings.append(f"input compensation failed for {int(comp.fell_back.sum())} of "
                        f"{len(batch)} segments; they keep their measured wheel rates")

    started = time.perf_counter()
    if progress:
        progress("step 3: identification", 0, 1)
    final, raw, at_final = _step3_fits(batch, comp, s1, sets, settings=settings,
                                       clusters=clusters, held=held, workers=workers)
    if progress:
        progress("step 3: identification", 1, 1)
    timings["step3"] = time.perf_counter() - started
    return ThreeStepOutcome(step1=s1, compensation=comp, final=final, raw=raw,
                            warnings=tuple(warnings), timings_s=timings,
                            mean_relative_change=relative_change(batch, comp),
                            at_final=at_final)


def _step3_fits(batch: SegmentBatch, comp: BatchCompensation, s1: Step1Result,
                sets: FloatArray, *, settings: Settings, clusters: IntArray | None,
                held: Mapping[str, NotIdentified] | None,
                workers: int) -> tuple[Estimate, Estimate, Linearisation]:
    """Step 3: the calibration on the compensated rates (with its linearisation at the end)
    and the comparison on the measured rates, from the step-1 ``sets``."""
    # Start from the step-1 sets' mean: the same minimum as from the datasheet, in fewer steps.
    start = sets.mean(axis=0) if s1.success.any() else None
    compensated = batch.with_wheel_rates(comp.n_rl, comp.n_rr)
    held = dict(held or {})
    task = _Step3(settings=settings, start=start, clusters=clusters, held=held,
                  step1_thetas=s1.thetas[s1.success], sets=sets.shape[0])
    # the calibration and the comparison on the measured rates, side by side (forked workers
    # read the segments from _SHARED instead of receiving them); the comparison holds what
    # the calibration holds, so where the calibration held more it is fitted again
    _SHARED.update(compensated=compensated, measured=batch)
    try:
        (final, held_final, at_final), raw = map_chunks(
            _step3, [("final", task), ("raw", task)], workers=workers)
    finally:
        _SHARED.clear()
    if held_final != held:
        raw = gauss_newton(batch, settings=settings.identify, start=start, clusters=clusters,
                           held=held_final)
    return final, raw, at_final


#: What the workers of step 3 read (set only while they run): the compensated and the measured
#: segments, shared by the fork rather than sent to each worker.
_SHARED: dict[str, SegmentBatch] = {}


@dataclass(frozen=True)
class _Step3:
    """What both fits of step 3 start from."""

    settings: Settings
    start: FloatArray | None
    clusters: IntArray | None
    held: dict[str, NotIdentified]
    step1_thetas: FloatArray
    sets: int


def _step3(job: tuple[str, _Step3]) -> Any:
    """Step 3's calibration (with the held parameters it ends with) or its comparison fit."""
    which, t = job
    if which == "raw":
        return gauss_newton(_SHARED["measured"], settings=t.settings.identify, start=t.start,
                            clusters=t.clusters, held=t.held)
    held = dict(t.held)
    kept: list[Linearisation] = []
    for _ in range(len(PARAMETER_NAMES)):
        final = gauss_newton(_SHARED["compensated"], settings=t.settings.identify,
                             start=t.start, clusters=t.clusters, held=held,
                             method="compensated", keep=kept)
        final = _with_inheritance(final, t.step1_thetas, t.sets)
        too_weak = weak(final.std, final.free, t.settings.identify)
        if not too_weak.any():
            break
        # the inherited spread pushed a parameter over the limit: hold it and identify again
        held.update(held_as_weak(final.std, too_weak, t.settings.identify))
    return final, held, kept[-1]


def _with_inheritance(final: Estimate, step1_thetas: FloatArray, sets: int) -> Estimate:
    """Add the spread the compensated rates inherit from the step-1 sets to the covariance.

    The compensated rates make the model fit with whatever parameters they were computed with,
    so step 3 returns about the mean of the step-1 sets (on simulated drives, the three-step
    error correlates with the step-1 sets' mean error at +0.95 to +1.00 over seeds). That mean
    varies like the step-1 batches' covariance divided by the number of sets, which step 3's own
    covariance does not see (it is 15 to 80 times too small without this term).
    """
    if step1_thetas.shape[0] < 2 or not any(final.free):
        return final
    free = np.array(final.free)
    inherit = np.cov(step1_thetas.T) / max(sets, 1) * np.outer(free, free)
    return final.with_covariance(final.covariance + inherit, CovarianceKind.THREE_STEP)


def run(prep: Prepared, settings: Settings,
        progress: ProgressCallback | None = None) -> MethodOutcome:
    """The three-step calibration of the selected segments (``--method compensated``)."""
    outcome = three_step(prep.batch, prep.validation, settings=settings, clusters=prep.clusters,
                         held=prep.held, progress=progress)
    s1 = outcome.step1
    rates = prep.batch.with_wheel_rates(outcome.compensation.n_rl, outcome.compensation.n_rr)
    return MethodOutcome(estimate=outcome.final, three_step=outcome, warnings=outcome.warnings,
                         bootstrap=bootstrap_terms(rates, outcome.final, prep.clusters, settings,
                                                   at_estimate=outcome.at_final,
                                                   step1_thetas=s1.thetas[s1.success],
                                                   step1_sets=int(s1.picked.size)))
