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

from odocal.arrays import BoolArray, FloatArray, IntArray
from odocal.data.segments import SegmentBatch
from odocal.estimators.compensation.problem import (
    STAGE,
    CompensationProblem,
    build_problem,
    build_problems,
)
from odocal.estimators.compensation.reference import solve_osqp
from odocal.estimators.compensation.riccati import solve_riccati, solve_riccati_batch
from odocal.estimators.compensation.structured import solve_structured
from odocal.estimators.parallel import map_chunks
from odocal.model.parameters import Inputs
from odocal.settings import CompensateSettings

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
        return _after_fast_path(p, settings, active)
    return _after_fast_path(p, settings, None)


def _after_fast_path(p: CompensationProblem, settings: CompensateSettings,
                     active: tuple[BoolArray, BoolArray] | None) -> QPSolution:
    """Where the Riccati path did not answer (it left the rate bounds ``active``): the banded
    KKT path from them, then OSQP; with ``active`` None (``solver = "osqp"``), OSQP alone."""
    if active is not None:
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
    status: IntArray
    iterations: IntArray

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


#: The segments step 2 works through, while it does: its workers read their blocks from here
#: (shared by the fork) rather than each block being copied out and sent in advance.
_BATCH: dict[str, SegmentBatch] = {}


def _compensate_block(args: tuple[int, int, FloatArray, CompensateSettings]
                      ) -> tuple[FloatArray, IntArray, IntArray]:
    """Worker: :func:`_compensate_chunk` of the segments ``lo`` to ``hi`` of the batch."""
    lo, hi, thetas, settings = args
    part = _BATCH["segments"].part(lo, hi)
    u = part.inputs
    return _compensate_chunk((u.n_rl, u.n_rr, u.beta, u.a_y, part.reference, thetas, part.t_s,
                              settings))


def _compensate_chunk(args: tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray,
                                  FloatArray, float, CompensateSettings]
                      ) -> tuple[FloatArray, IntArray, IntArray]:
    """Worker: every segment of a chunk with every theta, as :func:`compensate_segment` of each
    segment with the thetas in turn (each warm-started from the last active rate bounds); the
    QPs of one theta are linearised together and solved in one compiled call, and each
    solution is added to the segment's running sum and dropped. Returns the mean of the solved
    rates (N, K, 2; the measured where none solved), the status and iterations (N, S)."""
    n_rl, n_rr, beta, a_y, reference, thetas, t_s, settings = args
    n, k = n_rl.shape
    inputs = Inputs(n_rl=n_rl, n_rr=n_rr, beta=beta, a_y=a_y)
    measured = np.stack([n_rl, n_rr], axis=-1)
    total = np.zeros((n, k, 2))
    count = np.zeros(n, dtype=np.int64)
    status = np.empty((n, thetas.shape[0]), dtype=np.int64)
    iters = np.empty((n, thetas.shape[0]), dtype=np.int64)
    # the warm start each segment carries from theta to theta (none yet: no bound active)
    warm = (np.zeros((n, k, 2), dtype=bool), np.zeros((n, k, 2), dtype=bool))
    for j, theta in enumerate(thetas):
        rates, status[:, j], iters[:, j], warm = _compensate_theta(
            theta, inputs, measured, reference, t_s, settings, warm)
        solved = status[:, j] <= SOLVED_OSQP
        total[solved] += rates[solved]
        count += solved
    mean = np.where((count > 0)[:, None, None], total / np.maximum(count, 1)[:, None, None],
                    measured)
    return mean, status, iters


def _compensate_theta(theta: FloatArray, inputs: Inputs, measured: FloatArray,
                      reference: FloatArray, t_s: float, settings: CompensateSettings,
                      warm: tuple[BoolArray, BoolArray]
                      ) -> tuple[FloatArray, IntArray, IntArray,
                                 tuple[BoolArray, BoolArray]]:
    """:func:`compensate_segment` of every segment with one theta: the rates (N, K, 2),
    status, iterations, and the warm start for the next theta (each segment's final active
    rate bounds where its last solve gave them, else the ones it came with)."""
    n, k = measured.shape[:2]
    nominal = measured.copy()
    active = (warm[0].copy(), warm[1].copy())
    iterations = np.zeros(n, dtype=np.int64)
    status = np.full(n, FAILED, dtype=np.int64)
    alive = np.ones(n, dtype=bool)               # solved at every linearisation so far
    gave_active = np.ones(n, dtype=bool)         # the last solve named its active bounds
    for _ in range(settings.linearisations):
        pb = build_problems(theta, inputs, reference, t_s, settings, nominal_rates=nominal)
        dn = np.zeros((n, k, 2))
        step_status = np.full(n, FAILED, dtype=np.int64)
        step_iters = np.zeros(n, dtype=np.int64)
        new_active = (np.zeros((n, k, 2), dtype=bool), np.zeros((n, k, 2), dtype=bool))
        got = np.zeros(n, dtype=bool)
        slow = alive.copy()
        fast_active: tuple[BoolArray, BoolArray] | None = None
        if settings.solver == "structured":
            fast = solve_riccati_batch(pb, max_iterations=settings.max_active_set_iterations,
                                       initial_active=active)
            ok = alive & fast.converged & fast.states_feasible
            dn[ok] = fast.dn[ok]
            step_status[ok] = SOLVED_FAST
            step_iters[ok] = fast.iterations[ok]
            new_active[0][ok], new_active[1][ok] = fast.active_lower[ok], fast.active_upper[ok]
            got[ok] = True
            slow &= ~ok
            fast_active = (fast.active_lower, fast.active_upper)
        for i in np.flatnonzero(slow):
            start = None if fast_active is None else (fast_active[0][i], fast_active[1][i])
            sol = _after_fast_path(pb.problem(int(i)), settings, start)
            step_status[i], step_iters[i] = sol.status, sol.iterations
            if sol.solved:
                dn[i] = sol.z.reshape(k, STAGE)[:, :2]
            if sol.active_rates is not None:
                new_active[0][i], new_active[1][i] = sol.active_rates
                got[i] = True
        iterations[alive] += step_iters[alive]
        status[alive] = step_status[alive]
        solved = alive & (step_status <= SOLVED_OSQP)
        alive = solved
        nominal[alive] = pb.nominal_rates[alive] + dn[alive]
        # the next linearisation starts from this one's active bounds (none after OSQP)
        active = (np.where(got[:, None, None], new_active[0], False),
                  np.where(got[:, None, None], new_active[1], False))
        gave_active = got
    rates = np.where(alive[:, None, None], nominal, measured)
    keep = alive & gave_active
    next_warm = (np.where(keep[:, None, None], active[0], warm[0]),
                 np.where(keep[:, None, None], active[1], warm[1]))
    return rates, status, iterations, next_warm


def compensate_batch(batch: SegmentBatch, thetas: Sequence[FloatArray] | FloatArray,
                     settings: CompensateSettings, *, workers: int = 1,
                     progress: Callable[[int, int], None] | None = None) -> BatchCompensation:
    """Step 2: compensate every segment with every theta and average the solved estimates.

    Segments are spread over ``workers`` processes; the result does not depend on their number
    (each segment is solved alone, with its thetas in the given order).
    """
    theta_arr = np.atleast_2d(np.asarray(thetas, dtype=np.float64))
    n = len(batch)
    chunk = max(1, min(64, -(-n // max(4 * workers, 1))))
    tasks = [(lo, min(n, lo + chunk), theta_arr, settings) for lo in range(0, n, chunk)]
    sizes = [hi - lo for lo, hi, _, _ in tasks]
    results = []
    _BATCH["segments"] = batch
    try:
        if workers != 1 and len(tasks) > 1:
            # the first block here: the solvers' compiled kernels are then loaded in this
            # process, and the workers forked from it share them instead of each loading its own
            results.append(_compensate_block(tasks[0]))
            tasks, sizes = tasks[1:], sizes[1:]
        results += map_chunks(_compensate_block, tasks, workers=workers, weights=sizes,
                              progress=progress)
    finally:
        _BATCH.clear()
    status = np.concatenate([r[1] for r in results])
    iters = np.concatenate([r[2] for r in results])
    # each block's rates moved into place and let go (no second copy of every segment's)
    mean = np.empty((n, batch.steps, 2))
    at = 0
    for i, (rates, _, _) in enumerate(results):
        mean[at:at + rates.shape[0]] = rates
        at += rates.shape[0]
        results[i] = (np.empty((0, batch.steps, 2)), results[i][1], results[i][2])
    out = BatchCompensation(n_rl=mean[..., 0], n_rr=mean[..., 1], status=status,
                            iterations=iters)
    if out.fell_back.any():
        log.warning("input compensation failed for %d of %d segments with every parameter set; "
                    "they keep their measured wheel rates", int(out.fell_back.sum()), n)
    return out
