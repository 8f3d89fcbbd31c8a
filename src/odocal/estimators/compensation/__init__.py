"""METHOD 4: input compensation by optimal control.

For a fixed theta, the measured wheel rates of a segment are replaced by the rates that make the
linearised model follow the measured poses best while changing smoothly, within +-5% of the
measurement (the QP of :mod:`.problem`).

Solvers (``[compensate] solver``):

``structured`` (default)
    A primal-dual active-set method around a Riccati recursion (:mod:`.riccati`); when a state
    bound binds, the same method around a banded LU of the full KKT system (:mod:`.structured`);
    should either fail to settle, OSQP.
``osqp``
    The generic sparse formulation solved with OSQP (:mod:`.reference`).

A segment whose QP is infeasible or cannot be solved keeps its measured rates; the result says so.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from odocal.data.segments import SegmentBatch
from odocal.estimators.compensation.problem import STAGE, CompensationProblem, build_problem
from odocal.estimators.compensation.reference import solve_osqp
from odocal.estimators.compensation.riccati import solve_riccati
from odocal.estimators.compensation.structured import solve_structured
from odocal.estimators.parallel import map_chunks
from odocal.model.parameters import Inputs
from odocal.settings import CompensateSettings

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]
log = logging.getLogger(__name__)

#: Status codes of one solve, as stored in results (small integers keep big batches light).
SOLVED_FAST, SOLVED_KKT, SOLVED_OSQP, INFEASIBLE, FAILED = 0, 1, 2, 3, 4
STATUS_NAMES = ("riccati", "banded-kkt", "osqp", "infeasible", "failed")

__all__ = ["STATUS_NAMES", "CompensationProblem", "QPSolution", "build_problem",
           "compensate_batch", "compensate_segment", "solve_qp"]


@dataclass(frozen=True)
class QPSolution:
    """One solved compensation QP.

    z : ndarray, shape (5K,), ``[dn_0, dx_1, dn_1, ...]`` (zeros when not solved)
    status : one of the codes above; SOLVED_* mean an optimal answer
    iterations : active-set iterations (or OSQP iterations when OSQP answered)
    objective : the QP's objective at ``z`` (nan when not solved)
    active_rates : (lower, upper) active rate bounds, for warm starts
    """

    z: FloatArray
    status: int
    iterations: int
    objective: float
    active_rates: tuple[BoolArray, BoolArray] | None

    @property
    def solved(self) -> bool:
        return self.status in (SOLVED_FAST, SOLVED_KKT, SOLVED_OSQP)


def solve_qp(p: CompensationProblem, settings: CompensateSettings, *,
             initial_active: tuple[BoolArray, BoolArray] | None = None) -> QPSolution:
    """Solve one compensation QP with the configured solver and its fallbacks."""
    if settings.solver == "structured":
        fast = solve_riccati(p, max_iterations=settings.max_active_set_iterations,
                             initial_active=initial_active)
        active = (fast.active_lower, fast.active_upper)
        if fast.converged and fast.states_feasible:
            return QPSolution(fast.z, SOLVED_FAST, fast.iterations, p.objective(fast.z), active)
        start_lo = np.zeros((p.steps, STAGE), dtype=bool)
        start_hi = np.zeros((p.steps, STAGE), dtype=bool)
        start_lo[:, :2], start_hi[:, :2] = active
        full = solve_structured(p, max_iterations=settings.max_active_set_iterations,
                                initial_active=(start_lo.ravel(), start_hi.ravel()))
        if full.converged:
            return QPSolution(full.z, SOLVED_KKT, full.iterations, p.objective(full.z), active)
        log.debug("structured solver did not settle (%s); using OSQP", full.message)
    ref = solve_osqp(p)
    if ref.solved:
        return QPSolution(ref.z, SOLVED_OSQP, ref.iterations, p.objective(ref.z), None)
    status = INFEASIBLE if ref.infeasible else FAILED
    return QPSolution(np.zeros(STAGE * p.steps), status, ref.iterations, float("nan"), None)


@dataclass(frozen=True)
class SegmentCompensation:
    """Compensated rates of one segment for one theta.

    rates : ndarray, shape (K, 2), [n_rl, n_rr] (the measured ones when not solved)
    status : status code of the last solve
    iterations : total solver iterations over the linearisations
    active_rates : final active rate bounds (for warm-starting a neighbouring theta)
    """

    rates: FloatArray
    status: int
    iterations: int
    active_rates: tuple[BoolArray, BoolArray] | None

    @property
    def solved(self) -> bool:
        return self.status in (SOLVED_FAST, SOLVED_KKT, SOLVED_OSQP)


def compensate_segment(theta: FloatArray, inputs: Inputs, reference: FloatArray, t_s: float,
                       settings: CompensateSettings, *,
                       initial_active: tuple[BoolArray, BoolArray] | None = None,
                       ) -> SegmentCompensation:
    """Compensated wheel rates of one segment (inputs arrays of shape (K,), reference (K+1, 3)).

    The model is linearised around the measured rates, the QP solved, and, for
    ``settings.linearisations`` > 1, re-linearised around the new rates and solved again.
    """
    measured = np.column_stack([inputs.n_rl, inputs.n_rr])
    nominal = measured
    active = initial_active
    iterations = 0
    status = FAILED
    for _ in range(settings.linearisations):
        problem = build_problem(theta, inputs, reference, t_s, settings, nominal_rates=nominal)
        solution = solve_qp(problem, settings, initial_active=active)
        iterations += solution.iterations
        status = solution.status
        if not solution.solved:
            return SegmentCompensation(measured, status, iterations, None)
        nominal = problem.rates(solution.z)
        active = solution.active_rates
    return SegmentCompensation(nominal, status, iterations, active)


@dataclass(frozen=True)
class BatchCompensation:
    """Compensated rates of many segments, averaged over several parameter sets (step 2).

    n_rl, n_rr : ndarray, shape (N, K), the averages of the solved estimates (measured where none
        solved)
    status : ndarray of int, shape (N, S), status of each segment's solve with each theta
    iterations : ndarray of int, shape (N, S)
    """

    n_rl: FloatArray
    n_rr: FloatArray
    status: NDArray[np.int64]
    iterations: NDArray[np.int64]

    @property
    def solved(self) -> BoolArray:
        return np.asarray(self.status <= SOLVED_OSQP)

    @property
    def fell_back(self) -> BoolArray:
        """Segments that kept their measured rates (no theta gave a solution)."""
        return np.asarray(~self.solved.any(axis=1))

    def status_counts(self) -> dict[str, int]:
        counts = np.bincount(self.status.ravel(), minlength=len(STATUS_NAMES))
        return {name: int(c) for name, c in zip(STATUS_NAMES, counts, strict=True)}


def _compensate_chunk(args: tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray,
                                  FloatArray, float, CompensateSettings]
                      ) -> tuple[FloatArray, NDArray[np.int64], NDArray[np.int64]]:
    """Worker: every segment of a chunk with every theta; rates (n, S, K, 2)."""
    n_rl, n_rr, beta, a_y, reference, thetas, t_s, settings = args
    n, k = n_rl.shape
    s = thetas.shape[0]
    rates = np.empty((n, s, k, 2))
    status = np.empty((n, s), dtype=np.int64)
    iters = np.empty((n, s), dtype=np.int64)
    for i in range(n):
        inputs = Inputs(n_rl=n_rl[i], n_rr=n_rr[i], beta=beta[i], a_y=a_y[i])
        active = None
        for j in range(s):
            seg = compensate_segment(thetas[j], inputs, reference[i], t_s, settings,
                                     initial_active=active)
            rates[i, j], status[i, j], iters[i, j] = seg.rates, seg.status, seg.iterations
            if seg.active_rates is not None:
                active = seg.active_rates
    return rates, status, iters


def compensate_batch(batch: SegmentBatch, thetas: Sequence[FloatArray] | FloatArray,
                     settings: CompensateSettings, *, workers: int = 1,
                     progress: Callable[[int, int], None] | None = None) -> BatchCompensation:
    """Step 2: compensate every segment with every theta and average the solved estimates.

    Segments are spread over ``workers`` processes; the result does not depend on their number
    (each segment is solved alone, with its thetas in the given order).
    """
    theta_arr = np.atleast_2d(np.asarray(thetas, dtype=np.float64))
    u = batch.inputs
    n = len(batch)
    chunk = max(1, min(64, -(-n // max(4 * workers, 1))))
    tasks = [(u.n_rl[lo:lo + chunk], u.n_rr[lo:lo + chunk], u.beta[lo:lo + chunk],
              u.a_y[lo:lo + chunk], batch.reference[lo:lo + chunk], theta_arr, batch.t_s,
              settings) for lo in range(0, n, chunk)]
    sizes = [t[0].shape[0] for t in tasks]
    results = []
    if workers != 1 and len(tasks) > 1:
        # the first chunk here: the solvers' compiled kernels are then loaded in this process,
        # and the workers forked from it share them instead of each loading its own
        results.append(_compensate_chunk(tasks[0]))
        tasks, sizes = tasks[1:], sizes[1:]
    results += map_chunks(_compensate_chunk, tasks, workers=workers, weights=sizes,
                          progress=progress)
    rates = np.concatenate([r[0] for r in results])            # (N, S, K, 2)
    status = np.concatenate([r[1] for r in results])
    iters = np.concatenate([r[2] for r in results])
    solved = (status <= SOLVED_OSQP)[:, :, None, None]
    count = solved.sum(axis=1)                                  # (N, 1, 1)
    mean = np.where(count > 0, (rates * solved).sum(axis=1) / np.maximum(count, 1),
                    np.stack([u.n_rl, u.n_rr], axis=-1))
    out = BatchCompensation(n_rl=mean[..., 0], n_rr=mean[..., 1], status=status,
                            iterations=iters)
    if out.fell_back.any():
        log.warning("input compensation failed for %d of %d segments with every parameter set; "
                    "they keep their measured wheel rates", int(out.fell_back.sum()), n)
    return out
