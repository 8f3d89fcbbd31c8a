"""METHOD 6: validation error E_p and the reachable minimum.

For a parameter set, every validation segment is rolled out with the *measured* wheel rates from its
measured initial pose, and the per-sample position error ``sqrt(dx^2 + dy^2)`` is averaged over the
segment's samples (k = 1..K). ``E_p`` is the mean over segments (the paper's overline E_p,
section 6.1). Departure from the printed paper: it writes the per-segment error as a sum over k
but reports metres; odocal takes the mean over k, which is what a length in metres means.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from odocal import cancel
from odocal.arrays import FloatArray
from odocal.data.drive import Drive
from odocal.data.segments import RaggedSegments, SegmentSet, gather_ragged
from odocal.estimators.parallel import process_map
from odocal.estimators.windows import drives_heading_offset
from odocal.model.kinematics import body_rates, rollout_ragged
from odocal.model.parameters import Inputs, Parameters
from odocal.settings import MinimumSettings, Settings

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SegmentErrors:
    """Per-segment validation errors of one parameter set.

    mean_m : ndarray, shape (S,)
        Mean position error over each segment's samples, m.
    final_m : ndarray, shape (S,)
        Position error at each segment's last sample, m.
    distance_m : ndarray, shape (S,)
        Absolute error of the distance travelled along the segment (the wheels' against the
        reference's), m: the error that remains when the heading comes from elsewhere.
    """

    mean_m: FloatArray
    final_m: FloatArray
    distance_m: FloatArray


#: Samples of validation segments rolled out per pass (whole segments: at least one).
BLOCK_SAMPLES = 1 << 17


def _blocks(data: RaggedSegments) -> list[RaggedSegments]:
    """``data`` cut into runs of whole segments of about BLOCK_SAMPLES samples (views): every
    segment is rolled out alone, so the errors are those of one pass, in less memory."""
    ends = np.cumsum(data.steps)
    if ends.size == 0 or ends[-1] <= BLOCK_SAMPLES:
        return [data]
    out = []
    a = 0
    while a < data.steps.shape[0]:
        first = int(ends[a - 1]) if a else 0
        b = max(a + 1, int(np.searchsorted(ends, first + BLOCK_SAMPLES, side="right")))
        last = int(ends[b - 1])
        u = data.inputs
        out.append(RaggedSegments(
            inputs=Inputs(n_rl=u.n_rl[first:last], n_rr=u.n_rr[first:last],
                          beta=u.beta[first:last], a_y=u.a_y[first:last]),
            initial=data.initial[a:b], reference=data.reference[first:last],
            steps=data.steps[a:b], t_s=data.t_s))
        a = b
    return out


def segment_errors(theta: FloatArray, data: RaggedSegments) -> SegmentErrors:
    """Validation errors of ``theta`` on every segment of ``data``."""
    parts = [_segment_errors(theta, block) for block in _blocks(data)]
    return SegmentErrors(*(np.concatenate([getattr(p, f.name) for p in parts])
                           for f in dataclasses.fields(SegmentErrors)))


def _segment_errors(theta: FloatArray, data: RaggedSegments) -> SegmentErrors:
    theta = np.asarray(theta, dtype=np.float64)
    poses = rollout_ragged(theta, data.inputs, data.initial, data.steps, data.t_s)
    err = np.hypot(poses[:, 0] - data.reference[:, 0], poses[:, 1] - data.reference[:, 1])
    first = data.first
    last = first + data.steps - 1
    # distance along track: the wheels' (2a) against the reference's ((1) inverted)
    before = np.empty_like(data.reference)
    before[1:] = data.reference[:-1]
    before[first] = data.initial
    u = data.inputs
    v, _ = body_rates(theta, u.n_rl, u.n_rr, u.a_y)
    psi = np.unwrap(np.concatenate([before[:, 2:3], data.reference[:, 2:3]], axis=1), axis=1)
    heading = 0.5 * (psi[:, 0] + psi[:, 1]) + u.beta
    ds = ((data.reference[:, 0] - before[:, 0]) * np.cos(heading)
          + (data.reference[:, 1] - before[:, 1]) * np.sin(heading))
    distance = np.abs(np.add.reduceat(v * data.t_s - ds, first))
    return SegmentErrors(mean_m=np.add.reduceat(err, first) / data.steps, final_m=err[last],
                         distance_m=distance)


def mean_error(theta: FloatArray, data: RaggedSegments) -> float:
    """E_p: the mean over segments of the mean position error, m."""
    return float(mean_errors(np.asarray(theta, dtype=np.float64)[None], data)[0])


def mean_errors(thetas: FloatArray, data: RaggedSegments, *, chunk: int = 1) -> FloatArray:
    """E_p of many parameter sets (P, n), shape (P,): the rollouts and the position errors only
    (what a search over parameter sets needs), ``chunk`` sets per pass (one is fastest where a
    rollout's arrays outgrow the caches)."""
    thetas = np.atleast_2d(np.asarray(thetas, dtype=np.float64))
    per_segment = np.empty((thetas.shape[0], len(data)))
    done = 0
    for block in _blocks(data):
        cols = slice(done, done + len(block))
        done += len(block)
        for lo in range(0, thetas.shape[0], chunk):
            poses = rollout_ragged(thetas[lo:lo + chunk], block.inputs, block.initial,
                                   block.steps, block.t_s)
            err = np.hypot(poses[..., 0] - block.reference[:, 0],
                           poses[..., 1] - block.reference[:, 1])
            per_segment[lo:lo + chunk, cols] = (np.add.reduceat(err, block.first, axis=-1)
                                                / block.steps)
    return per_segment.mean(axis=-1)


@dataclass(frozen=True)
class ValidationResult:
    """Validation of one parameter set.

    theta : the parameters validated
    mean_error_m : E_p, m
    errors : per-segment errors
    segments : where the validation segments lie
    drive_names : names of the drives, indexed by ``segments.drive``
    start_s : ndarray, shape (S,), time of each segment's first sample in its drive, s
    """

    theta: Parameters
    mean_error_m: float
    errors: SegmentErrors
    segments: SegmentSet
    drive_names: tuple[str, ...]
    start_s: FloatArray

    @property
    def mean_distance_error_m(self) -> float:
        """Mean over segments of the absolute along-track distance error, m."""
        return float(self.errors.distance_m.mean())

    def to_dict(self) -> dict[str, object]:
        return {
            "E_p_m": self.mean_error_m,
            "distance_error_m": self.mean_distance_error_m,
            "segments": len(self.segments),
            "distance_m": float(self.segments.distance_m.sum()),
            "per_segment": [
                {"drive": self.drive_names[int(d)], "start": int(s), "start_s": float(t0),
                 "steps": int(k), "distance_m": float(dist), "E_p_m": float(e),
                 "final_error_m": float(f)}
                for d, s, t0, k, dist, e, f in zip(self.segments.drive, self.segments.start,
                                                   self.start_s, self.segments.steps,
                                                   self.segments.distance_m, self.errors.mean_m,
                                                   self.errors.final_m, strict=True)
            ],
        }


@dataclass(frozen=True)
class MinimumResult:
    """The reachable minimum of E_p found by a global optimiser.

    theta : the minimising parameters
    mean_error_m : the minimum E_p, m
    start : the centre of the search box; ``start_error_m`` its E_p
    converged, message : the optimiser's status (it may stop at its generation limit)
    evaluations : how many times E_p was evaluated
    bounds : the search box, shape (4, 2)
    segments : validation segments searched over
    """

    theta: Parameters
    mean_error_m: float
    start: Parameters
    start_error_m: float
    converged: bool
    message: str
    evaluations: int
    bounds: FloatArray
    segments: int

    @property
    def success(self) -> bool:
        """Whether the search improved on its starting point."""
        return self.mean_error_m < self.start_error_m or self.converged

    def to_dict(self) -> dict[str, object]:
        return {"theta": self.theta.as_dict(), "E_p_m": self.mean_error_m,
                "start": {"theta": self.start.as_dict(), "E_p_m": self.start_error_m},
                "converged": self.converged, "success": self.success, "message": self.message,
                "evaluations": self.evaluations, "segments": self.segments,
                "bounds": np.asarray(self.bounds).tolist()}


def _mean_error_or_stop(theta: FloatArray, data: RaggedSegments) -> float:
    """:func:`mean_error`, after a look at whether the run was asked to stop (in this process;
    a worker's flag is never set)."""
    cancel.check()
    return mean_error(theta, data)


def reachable_minimum(data: RaggedSegments, start: FloatArray, *, settings: MinimumSettings,
                      seed: int = 0, workers: int = 1,
                      progress: Callable[[str, int, int], None] | None = None) -> MinimumResult:
    """Minimise E_p over theta with differential evolution in a box around ``start``.

    Bounded, seeded, and polished with L-BFGS-B, so the same inputs give the same answer.
    ``workers`` > 1 evaluates the population in parallel processes (same result).
    ``progress(stage, generation, max_generations)`` is called after every generation.
    """
    from scipy.optimize import differential_evolution

    start = np.asarray(start, dtype=np.float64)
    half = np.asarray(settings.half_width)
    bounds = np.column_stack([start - half, start + half])
    bounds[0, 0] = max(bounds[0, 0], 1e-3)
    bounds[2, 0] = max(bounds[2, 0], 1e-3)
    stage = "reachable minimum: differential evolution, generation"
    generations = [0]

    def generation(xk: FloatArray, convergence: float = 0.0) -> bool:
        cancel.check()
        generations[0] += 1
        if progress:
            progress(stage, min(generations[0], settings.max_generations),
                     settings.max_generations)
        return False

    if progress:
        progress(stage, 0, settings.max_generations)
    # the population is evaluated by odocal's own workers (scipy's pool would let each worker
    # take Ctrl-C: tracebacks, leaked semaphores, a worker left running); a stop asked for is
    # looked at every generation and while the workers compute
    with process_map(workers) as evaluate:
        result = differential_evolution(
            _mean_error_or_stop, bounds=[tuple(b) for b in bounds], args=(data,),
            callback=generation, seed=seed, maxiter=settings.max_generations,
            popsize=settings.population,
            tol=settings.tolerance, polish=True, x0=np.clip(start, bounds[:, 0], bounds[:, 1]),
            workers=evaluate if workers != 1 else 1,
            updating="deferred" if workers != 1 else "immediate")
    if progress:                                  # converged before the last generation
        progress(stage, settings.max_generations, settings.max_generations)
    on_edge = np.isclose(result.x, bounds[:, 0]) | np.isclose(result.x, bounds[:, 1])
    message = str(result.message)
    if on_edge.any():
        message += "; the minimum lies on the edge of the search box (widen [minimum] half_width)"
        log.warning("reachable minimum on the edge of the search box")
    return MinimumResult(theta=Parameters.from_array(result.x), mean_error_m=float(result.fun),
                         start=Parameters.from_array(start),
                         start_error_m=mean_error(start, data),
                         converged=bool(result.success), message=message,
                         evaluations=int(result.nfev), bounds=bounds, segments=len(data))


def validation_data(drives: Sequence[Drive], segments: SegmentSet,
                    settings: Settings) -> RaggedSegments:
    """The validation segments' data, with the reference heading's constant offset removed.

    A reference whose heading is rotated against the direction of travel (a camera's or an
    antenna's mounting yaw in a fused pose) would start every validation rollout pointing off
    by that much, and E_p would favour parameters that curve the rollout back (a biased c_d)
    over the right ones. Where ``[inverse] heading_offset = "estimate"`` and at least five
    seconds of straight driving show it (as the default method finds it), every validation, of every
    method and of the datasheet values alike, starts from the corrected heading. Departure from
    the paper, which starts from the measured pose as it is.
    """
    data = gather_ragged(drives, segments)
    if settings.inverse.heading_offset != "estimate":
        return data
    offset, _ = drives_heading_offset(drives)
    if offset == 0.0:
        return data
    initial = data.initial.copy()
    reference = data.reference.copy()
    initial[:, 2] += offset
    reference[:, 2] += offset
    return dataclasses.replace(data, initial=initial, reference=reference)
