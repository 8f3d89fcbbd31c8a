"""Every method on the user's own drive, judged on data it did not see (``--compare``).

The drives are cut into time blocks (``block_s``, five minutes by default) that alternate
between two folds. Each method calibrates on one fold and is validated (E_p, METHOD 6) on the
other, and the other way round; its score is the mean of the two held-out E_p. Blocks are
pieces of their own, so no segment spans two blocks or crosses from one fold into the other. On
a simulated drive the error against the true parameters is given too.

The held-out E_p says which method the data favour; it is noisy on short drives (it rests on
half the validation segments each way), so methods within a few percent of each other are
called equal.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence

import numpy as np

from odocal.data.drive import Drive
from odocal.errors import DataError, OdocalError
from odocal.estimators import METHOD_NAMES
from odocal.model.parameters import PARAMETER_NAMES, Parameters
from odocal.pipeline.result import TIE, Comparison, MethodScore
from odocal.settings import Settings


def folds(drives: Sequence[Drive], block_s: float) -> tuple[list[Drive], list[Drive]]:
    """The drives' alternate time blocks, as two lists of drives (blocks are pieces)."""
    out: tuple[list[Drive], list[Drive]] = ([], [])
    for d in drives:
        cols = d.columns()
        piece = cols.get("piece", np.zeros(d.n_samples))
        block = np.floor((d.t - d.t[0]) / block_s)
        key = piece * 1e6 + block
        for k in (0, 1):
            keep = (block % 2) == k
            if keep.sum() < 10:
                continue
            sub = {name: np.asarray(v)[keep] for name, v in cols.items()}
            sub["piece"] = key[keep]
            try:
                out[k].append(Drive.from_columns(sub, name=f"{d.name} (fold {k + 1})"))
            except DataError:
                continue
    return out


def check_comparable(drives: Sequence[Drive], settings: Settings | None = None,
                     block_s: float = 300.0) -> tuple[list[Drive], list[Drive]]:
    """The two held-out halves, or a DataError (before anything is fitted) when either holds no
    validation segment to score a method on."""
    from odocal.data.segments import validation_segments
    from odocal.model.registry import require_rear_axle

    settings = settings or Settings()
    require_rear_axle(settings.vehicle.model, "--compare (every method on held-out data)")
    duration = sum(d.duration_s for d in drives)
    block = min(block_s, max(duration / 6.0, 30.0))
    halves = folds(drives, block)
    need = settings.segments.validation_distance_m
    for half in halves:
        if not half or len(validation_segments(half, settings.segments)) == 0:
            km = sum(d.distance_m for d in drives) / 1000
            raise DataError(f"--compare holds out alternate {block:.0f} s blocks and scores "
                            f"each method on {need:.0f} m validation segments in them; these "
                            f"drives ({km:.2f} km, {duration / 60:.1f} min) are too short for "
                            "that: calibrate without --compare, or with a shorter [segments] "
                            "validation_distance_m")
    return halves


def compare(drives: Sequence[Drive], *, settings: Settings | None = None,
            truth: Parameters | None = None, methods: Sequence[str] = METHOD_NAMES,
            block_s: float = 300.0,
            progress: Callable[[str, int, int], None] | None = None) -> Comparison:
    """Score every method by held-out E_p (see the module docstring).

    ``progress(stage, done, total)`` counts each method's three fits (two halves, the whole).
    """
    from odocal.pipeline.calibrate import validate_theta

    settings = settings or Settings()
    halves = check_comparable(drives, settings, block_s)
    block = min(block_s, max(sum(d.duration_s for d in drives) / 6.0, 30.0))

    def held_out(theta: Parameters, k: int) -> float | None:
        try:
            return validate_theta(halves[1 - k], theta, settings=settings).mean_error_m
        except OdocalError:
            return None

    scores = [_method_score(method, drives, halves, settings=settings, truth=truth,
                            held_out=held_out, progress=progress) for method in methods]
    datasheet = [held_out(Parameters(*settings.identify.theta0), k) for k in (0, 1)]
    data_ok = [v for v in datasheet if v is not None]
    held = sorted((s.held_out_e_p_m, s.method) for s in scores if s.held_out_e_p_m is not None)
    favoured = tuple(m for e_p, m in held if e_p <= held[0][0] * (1.0 + TIE))
    return Comparison(scores=tuple(scores), block_s=block, favoured=favoured,
                      datasheet_e_p_m=float(np.mean(data_ok)) if len(data_ok) == 2 else None)


def _method_score(method: str, drives: Sequence[Drive],
                  halves: tuple[list[Drive], list[Drive]], *,
                  settings: Settings, truth: Parameters | None,
                  held_out: Callable[[Parameters, int], float | None],
                  progress: Callable[[str, int, int], None] | None) -> MethodScore:
    """One method's score: fitted on each half and validated on the other (``held_out(theta,
    k)``: E_p on the half fit ``k`` did not see), and fitted on the whole; a method that fails
    is scored as an error."""
    from odocal.pipeline.calibrate import calibrate

    started = time.perf_counter()
    per_fold: list[float | None] = []
    error = None
    stage = f"comparing the methods: {method}, 3 fits"
    try:
        for k in (0, 1):
            if progress:
                progress(stage, k, 3)
            fit = calibrate(halves[k], settings=settings, method=method)
            per_fold.append(held_out(fit.theta, k) if fit.success else None)
        if progress:
            progress(stage, 2, 3)
        whole = calibrate(list(drives), settings=settings, method=method)
        if progress:
            progress(stage, 3, 3)
    except OdocalError as exc:
        if progress:
            progress(stage, 3, 3)
        error = str(exc)
        return MethodScore(method, Parameters(*settings.identify.theta0),
                           (0.0,) * 4, (False,) * 4, "error", None, tuple(per_fold),
                           None, time.perf_counter() - started, error)
    est = whole.estimate
    ok = [v for v in per_fold if v is not None]
    truth_error = None
    if truth is not None:
        diff = est.theta.as_array() - truth.as_array()
        truth_error = dict(zip(PARAMETER_NAMES, diff.tolist(), strict=True))
    return MethodScore(
        method=method, theta=est.theta, std=tuple(est.std.tolist()),
        identified=est.identified, status=est.status.name.lower(),
        held_out_e_p_m=float(np.mean(ok)) if len(ok) == 2 else None,
        folds_e_p_m=tuple(per_fold), truth_error=truth_error,
        elapsed_s=time.perf_counter() - started)


def format_table(comparison: Comparison) -> list[str]:
    """The comparison as text lines (the CLI's)."""
    from odocal.model.parameters import PARAMETER_DISPLAY

    truth = any(s.truth_error is not None for s in comparison.scores)
    head = f"{'method':<12} {'held-out E_p':>12}"
    if truth:
        head += "".join(f" {'err ' + n + ' [' + PARAMETER_DISPLAY[n][1] + ']':>20}"
                        for n in PARAMETER_NAMES)
    head += f" {'time s':>7}"
    lines = [f"comparing the methods on held-out time blocks of {comparison.block_s:.0f} s:",
             head]
    for s in comparison.scores:
        e_p = f"{s.held_out_e_p_m:.3f} m" if s.held_out_e_p_m is not None else "-"
        row = f"{s.method:<12} {e_p:>12}"
        if truth:
            row += "".join(f" {s.truth_error[n] * PARAMETER_DISPLAY[n][0]:>20.4g}"
                           if s.truth_error else f" {'-':>20}" for n in PARAMETER_NAMES)
        row += f" {s.elapsed_s:>7.1f}"
        if s.error:
            row += f"  ({s.error})"
        lines.append(row)
    if comparison.datasheet_e_p_m is not None:
        lines.append(f"{'datasheet':<12} {comparison.datasheet_e_p_m:>10.3f} m")
    lines.append(comparison.verdict)
    return lines
