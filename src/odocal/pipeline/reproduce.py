"""The paper's experiment (section 6) on a simulated drive, where the truth is known.

On a simulated city drive of about 24 km, with the paper's segment settings and batch sizes:

* **Fig. 4**: 50 independent step-1 batches of N = 10 selected segments, identified with batch G-N
  on the measured rates and validated; their sorted validation errors.
* **Examined batch**: the worst of them (the paper's batch 34).
* **Table 1**: pure G-N on one segment of it (the paper's segment 7) and batch G-N on the whole
  batch, each with measured and with compensated rates (compensated with the five step-1 sets).
* **Fig. 7**: pure G-N on every segment of the examined batch, measured and compensated.
* **Step 3 per batch**: the examined segments in batches of N = 5 on compensated rates.
* **Section 6.5**: the validation errors of the datasheet values, of raw batch G-N (the examined
  batch), of the compensated calibration theta_BF and the reachable minimum; and, which the paper
  could not know, every estimate's distance from the true parameters.
* **Whole drive**: the calibration a user gets (all selected segments), raw and compensated.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from odocal.arrays import FloatArray
from odocal.data.drive import Drive
from odocal.data.segments import (
    RaggedSegments,
    SegmentBatch,
    gather,
    gather_ragged,
    identification_segments,
    validation_segments,
)
from odocal.estimators.compensated import Step1Result, step1, three_step
from odocal.estimators.compensation import BatchCompensation, compensate_batch
from odocal.estimators.estimate import Estimate, GaussNewtonDetails
from odocal.estimators.gauss_newton import gauss_newton
from odocal.estimators.parallel import resolve_workers
from odocal.estimators.validation import mean_error, reachable_minimum
from odocal.model.parameters import PARAMETER_DISPLAY, PARAMETER_NAMES
from odocal.settings import Settings
from odocal.sim.simulate import SimulatedDrive, simulate

log = logging.getLogger(__name__)

#: The paper's segment 7 of the examined batch (1-based in the paper).
EXAMINED_SEGMENT = 6


@dataclass(frozen=True)
class Reproduced:
    """One parameter estimate with its validation error and its distance from the truth."""

    label: str
    theta: FloatArray
    validation_m: float
    error: FloatArray
    iterations: int
    message: str

    def to_dict(self) -> dict[str, Any]:
        return {"label": self.label,
                "theta": dict(zip(PARAMETER_NAMES, self.theta.tolist(), strict=True)),
                "E_p_m": self.validation_m,
                "error_vs_truth": dict(zip(PARAMETER_NAMES, self.error.tolist(), strict=True)),
                "iterations": self.iterations, "message": self.message}


@dataclass(frozen=True)
class ReproduceResult:
    """Everything :func:`reproduce` measured (see the module docstring)."""

    seed: int
    noise: str
    distance_km: float
    segments: int
    selected: int
    validation_segments: int
    truth: Reproduced
    nominal: Reproduced
    step1_sorted_m: FloatArray
    examined_batch: int
    table1: tuple[Reproduced, ...]
    per_segment_raw: tuple[Reproduced, ...]
    per_segment_compensated: tuple[Reproduced, ...]
    step3_batches: tuple[Reproduced, ...]
    whole_raw: Reproduced
    whole_compensated: Reproduced
    minimum: Reproduced | None
    mean_relative_change: float

    def to_dict(self) -> dict[str, Any]:
        def many(items: tuple[Reproduced, ...]) -> list[dict[str, Any]]:
            return [e.to_dict() for e in items]

        return {
            "seed": self.seed, "noise": self.noise, "distance_km": self.distance_km,
            "segments": self.segments, "selected": self.selected,
            "validation_segments": self.validation_segments,
            "fig4_step1_sorted_E_p_m": self.step1_sorted_m.tolist(),
            "examined_batch": self.examined_batch,
            "table1": many(self.table1),
            "fig7_pure_gn_measured": many(self.per_segment_raw),
            "fig7_pure_gn_compensated": many(self.per_segment_compensated),
            "step3_batches_of_5": many(self.step3_batches),
            "section_6_5": {
                "true_parameters": self.truth.to_dict(),
                "nominal": self.nominal.to_dict(),
                "raw_batch_gn_examined": self.table1[2].to_dict(),
                "compensated_theta_BF": self.table1[3].to_dict(),
                "reachable_minimum": self.minimum.to_dict() if self.minimum else None,
            },
            "whole_drive": {"raw": self.whole_raw.to_dict(),
                            "compensated": self.whole_compensated.to_dict()},
            "mean_relative_change_of_compensated_rates": self.mean_relative_change,
        }


def truncate_to_distance(drive: Drive, distance_m: float) -> Drive:
    """The first ``distance_m`` of a (single-piece) drive."""
    cum = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(drive.x), np.diff(drive.y)))])
    end = int(np.searchsorted(cum, distance_m)) + 1
    cols = {k: v[:end] for k, v in drive.columns().items()}
    return Drive.from_columns(cols, name=drive.name, metadata=drive.metadata)


def reproduce(*, seed: int = 0, noise: str = "realistic", distance_km: float = 24.0,
              settings: Settings | None = None, minimum: bool = True,
              progress: Callable[[str, int, int], None] | None = None) -> ReproduceResult:
    """Run the paper's experiment on a simulated drive of ``distance_km``."""
    settings = settings or Settings()
    workers = resolve_workers(settings.calibrate.workers)

    def stage(name: str) -> Callable[[int, int], None] | None:
        return (lambda d, t: progress(name, d, t)) if progress else None

    def step(name: str) -> _Step:
        return _Step(progress, name)

    with step(f"simulating a {distance_km:g} km drive"):
        sim: SimulatedDrive = simulate(duration_s=distance_km * 1000 / 6.0, seed=seed,
                                       noise=noise)
        drive = truncate_to_distance(sim.drive, distance_km * 1000)
    truth = sim.true_parameters.as_array()
    drives = [drive]

    with step("segments"):
        id_segs = identification_segments(drives, settings.segments)
        selected = id_segs.subset(id_segs.selected)
        batch = gather(drives, selected)
        val = gather_ragged(drives, validation_segments(drives, settings.segments))

    def estimate(label: str, result: Estimate | FloatArray) -> Reproduced:
        return _reproduced(label, result, validation=val, truth=truth)

    s1 = step1(batch, val, settings, progress=stage("Fig. 4: step-1 batches"))
    examined, exam, comp, exam_comp = _compensated_examined(
        batch, s1, settings, workers=workers,
        progress=stage("Table 1: compensating the examined batch"))

    table1, per_raw, per_comp, step3 = _examined(exam, exam_comp, s1.results[examined],
                                                 settings, estimate,
                                                 stage("Table 1, Fig. 7: G-N fits on the "
                                                       "examined batch"))
    whole_raw, whole_comp = _whole_drive(batch, val, settings, estimate, progress)

    best = None
    if minimum:
        found = reachable_minimum(val, table1[3].theta, settings=settings.minimum, seed=seed,
                                  workers=workers, progress=progress)
        best = estimate("reachable minimum (differential evolution)", found.theta.as_array())

    return ReproduceResult(
        seed=seed, noise=noise, distance_km=drive.distance_m / 1000, segments=len(id_segs),
        selected=len(selected), validation_segments=len(val),
        truth=estimate("true parameters", truth),
        nominal=estimate("datasheet (nominal)", np.asarray(settings.identify.theta0)),
        step1_sorted_m=s1.validation_m[s1.order], examined_batch=examined,
        table1=table1, per_segment_raw=per_raw, per_segment_compensated=per_comp,
        step3_batches=step3, whole_raw=whole_raw, whole_compensated=whole_comp, minimum=best,
        mean_relative_change=_mean_relative_change(exam, comp))


def _reproduced(label: str, result: Estimate | FloatArray, *, validation: RaggedSegments,
                truth: FloatArray) -> Reproduced:
    """One row of the experiment: the theta of ``result`` (an estimate's, or values given),
    its validation error E_p, its distance from the true parameters, and the estimate's
    iterations and message (0 and empty for values given)."""
    if isinstance(result, Estimate):
        theta, msg = result.theta.as_array(), result.message
        its = result.details.iterations if isinstance(result.details,
                                                       GaussNewtonDetails) else 0
    else:
        theta, its, msg = np.asarray(result), 0, ""
    return Reproduced(label=label, theta=theta, validation_m=mean_error(theta, validation),
                      error=theta - truth, iterations=its, message=msg)


def _compensated_examined(batch: SegmentBatch, s1: Step1Result, settings: Settings, *,
                          workers: int, progress: Callable[[int, int], None] | None
                          ) -> tuple[int, SegmentBatch, BatchCompensation, SegmentBatch]:
    """The examined batch (the step-1 batch of the largest validation error, the paper's
    batch 34) compensated with the five step-1 parameter sets (step 2).

    Returns the examined batch's number, its segments, the compensation, and its segments with
    the compensated wheel rates.
    """
    examined = int(s1.order[-1])
    exam = batch.take(s1.batches[examined])
    sets = s1.thetas[s1.picked]
    comp = compensate_batch(exam, sets, settings.compensate, workers=workers, progress=progress)
    return examined, exam, comp, exam.with_wheel_rates(comp.n_rl, comp.n_rr)


def _whole_drive(batch: SegmentBatch, val: RaggedSegments, settings: Settings,
                 estimate: Callable[[str, Estimate], Reproduced],
                 progress: Callable[[str, int, int], None] | None
                 ) -> tuple[Reproduced, Reproduced]:
    """The calibration a user gets from the whole drive (all selected segments): batch G-N on
    the measured rates, and the three-step method."""
    with _Step(progress, "whole drive: batch G-N on measured rates"):
        whole_raw = estimate("all selected segments, measured rates",
                             gauss_newton(batch, settings=settings.identify))
    outcome = three_step(batch, val, settings=settings,
                         progress=(lambda name, d, t: progress(f"whole drive, {name}", d, t))
                         if progress else None)
    return whole_raw, estimate("all selected segments, three-step", outcome.final)


def _mean_relative_change(exam: SegmentBatch, comp: BatchCompensation) -> float:
    """The compensation's mean change of the examined batch's wheel rates, relative to the
    measured rates (floored at 0.5 rev/s)."""
    measured = np.stack([exam.inputs.n_rl, exam.inputs.n_rr])
    return float(np.mean(np.abs(np.stack([comp.n_rl, comp.n_rr]) - measured)
                         / np.maximum(np.abs(measured), 0.5)))


class _Step:
    """A stage of one step: ``progress(name, 0, 1)`` on entry, ``(name, 1, 1)`` on exit."""

    def __init__(self, progress: Callable[[str, int, int], None] | None, name: str) -> None:
        self.progress, self.name = progress, name

    def __enter__(self) -> None:
        if self.progress:
            self.progress(self.name, 0, 1)

    def __exit__(self, *exc: object) -> None:
        if self.progress:
            self.progress(self.name, 1, 1)


def _examined(exam: SegmentBatch, exam_comp: SegmentBatch, step1_result: Estimate,
              settings: Settings, estimate: Callable[[str, Estimate], Reproduced],
              progress: Callable[[int, int], None] | None = None,
              ) -> tuple[tuple[Reproduced, ...], ...]:
    """The examined batch, as the paper's Table 1 and Fig. 7 show it: one segment and the
    batch with measured and compensated rates, every segment alone (pure G-N shows the raw
    per-segment estimates, however loose), and step 3's batches.

    ``progress(done, total)`` counts the G-N fits."""
    loose = dataclasses.replace(settings.identify, judge_identifiability=False)
    seg = min(EXAMINED_SEGMENT, len(exam) - 1)
    one = slice(seg, seg + 1)
    n3 = settings.calibrate.step3_batch_size
    total = 3 + 2 * len(exam) + -(-len(exam) // n3)
    done = [0]

    def fit(batch: SegmentBatch, identify: Any) -> Estimate:
        result = gauss_newton(batch, settings=identify)
        done[0] += 1
        if progress:
            progress(done[0], total)
        return result

    if progress:
        progress(0, total)
    table1 = (
        estimate(f"segment {seg + 1} with measured rates", fit(exam.take(one), loose)),
        estimate(f"segment {seg + 1} with compensated rates", fit(exam_comp.take(one), loose)),
        estimate("batch with measured rates", step1_result),
        estimate("batch with compensated rates (theta_BF)", fit(exam_comp, settings.identify)),
    )
    per_raw = tuple(estimate(f"segment {i + 1}", fit(exam.take(slice(i, i + 1)), loose))
                    for i in range(len(exam)))
    per_comp = tuple(estimate(f"segment {i + 1}", fit(exam_comp.take(slice(i, i + 1)), loose))
                     for i in range(len(exam)))
    step3 = tuple(estimate(f"segments {lo + 1}-{min(lo + n3, len(exam))}",
                           fit(exam_comp.take(slice(lo, lo + n3)), settings.identify))
                  for lo in range(0, len(exam), n3))
    return table1, per_raw, per_comp, step3


def _mm(value: float) -> str:
    return f"{value * 1000:+7.2f}"


def _heads(prefix: str) -> str:
    """The parameters' column heads, each 7 wide."""
    return " ".join(f"{prefix + name:>7}" for name in PARAMETER_NAMES)


def _values(theta: Sequence[float] | FloatArray, digits: int, *, signed: bool = False) -> str:
    """theta in columns 7 wide: lengths in m with ``digits`` decimals, the parameters that
    read best in mm (c_d, d) in mm."""
    out = []
    for name, value in zip(PARAMETER_NAMES, theta, strict=True):
        scale, _ = PARAMETER_DISPLAY[name]
        out.append(_mm(value) if scale != 1.0 else
                   (f"{value:+7.{digits}f}" if signed else f"{value:7.{digits}f}"))
    return " ".join(out)


def format_report(r: ReproduceResult) -> str:
    """The counterparts of the paper's results as text tables."""
    lines = [
        f"simulated drive: {r.distance_km:.1f} km, {r.segments} segments of 650 samples, "
        f"{r.selected} selected (paper: 24 km, 1025 segments, 504 selected); "
        f"{r.validation_segments} validation segments of ~300 m",
        "",
        "Fig. 4 - validation error of the 50 step-1 batches (batch G-N, measured rates), sorted:",
        "  " + " ".join(f"{e:.2f}" for e in r.step1_sorted_m),
        f"  best third mean {np.mean(r.step1_sorted_m[:len(r.step1_sorted_m) // 3]):.2f} m, "
        f"worst third mean {np.mean(r.step1_sorted_m[-(len(r.step1_sorted_m) // 3):]):.2f} m "
        f"(paper: best third below 2.5 m, worst third 3.25 m)",
        f"  examined batch: {r.examined_batch} (the worst)",
        "",
        "Table 1 - identified parameters (c_e, t_r in m; c_d, d in mm) and E_p; error vs truth",
        f"  {'case':<44} {_heads('')} {'E_p':>7}   {_heads('d')}",
    ]

    def row(e: Reproduced) -> str:
        return (f"  {e.label:<44} {_values(e.theta, 4)} {e.validation_m:7.2f}   "
                f"{_values(e.error, 4, signed=True)}")

    lines += [row(e) for e in (*r.table1, r.truth)]
    lines += ["", "Fig. 7 - pure G-N on each segment of the examined batch "
              "(measured | compensated):",
              f"  {'':<10} {_heads('')} {'E_p':>7}  | {_heads('')} {'E_p':>7}"]
    for a, b in zip(r.per_segment_raw, r.per_segment_compensated, strict=True):
        lines.append(f"  {a.label:<10} {_values(a.theta, 3)} {a.validation_m:7.2f}  | "
                     f"{_values(b.theta, 3)} {b.validation_m:7.2f}")
    lines += ["", "Step 3 in batches of N = 5 (compensated rates):"]
    lines += [row(e) for e in r.step3_batches]
    lines += ["", "Section 6.5 - validation error E_p (paper: nominal 11.09, raw 3.86, "
              "compensated 2.48, minimum 2.40 m):"]
    entries = [r.nominal, r.table1[2], r.table1[3]]
    if r.minimum is not None:
        entries.append(r.minimum)
    entries.append(r.truth)
    lines += [row(e) for e in entries]
    lines += ["", "The calibration from the whole drive (all selected segments):"]
    lines += [row(r.whole_raw), row(r.whole_compensated)]
    lines += ["", f"compensated rates differ from the measured ones by "
              f"{r.mean_relative_change * 100:.2f}% on average (paper: below 1.2%)"]
    return "\n".join(lines)
