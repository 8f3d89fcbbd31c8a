"""The fast path of the structured solver: a Riccati recursion inside a primal-dual active set loop.

For the compensation QP with only the wheel-rate bounds active (the usual case: the +-5 m /
+-0.5 rad state bounds bind only for grossly wrong parameters), the KKT system is solved by
dynamic programming over the stages. The value function is quadratic in the augmented state
``s_j = (dx_j, dn_{j-1})`` (the pose deviation and the previous rate deviation, which the
rate-change penalty R couples to the next decision), so one backward Riccati sweep and one forward
sweep solve the equality-constrained problem for a given active set in O(K) with 5x5 blocks, and
give the multipliers of the active bounds as the gradient of the stage's Q-function.

The active set is updated by the primal-dual active-set rule (see :mod:`.structured`).
The kernels are compiled with numba (cached, keyed on their sources: :mod:`odocal.model._jit`);
they work on plain arrays only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from odocal.arrays import BoolArray, FloatArray, IntArray
from odocal.estimators.compensation.problem import STAGE, CompensationProblem, ProblemBatch
from odocal.model._jit import jit

_STATUS = ("optimal", "the active set cycles", "iteration limit",
           "a stage Hessian is not positive definite")


@jit
def _sweep(A: FloatArray, B: FloatArray, e: FloatArray, c: FloatArray, qd: FloatArray,
           rd: FloatArray, fixed: BoolArray, fixed_val: FloatArray, dn: FloatArray,
           dx: FloatArray, mu: FloatArray) -> bool:  # pragma: no cover - compiled
    """Solve the QP with the rates ``fixed`` held at ``fixed_val``; fill dn, dx, mu.

    Shapes: A (K,3,3), B (K,3,2), e (K,3), c (K-1,2), fixed/fixed_val/dn/mu (K,2), dx (K+1,3).
    Returns False if a stage Hessian is not positive definite.

    Backward: the value function V_{j+1}(dx', n') = 1/2 s'Ps + p's of s = (dx', n') is pulled
    through x' = A dx + B u, n' = u and the rate-change term ||c_j + u - m||_R^2 (m = dn_{j-1})
    to a quadratic in y = (dx, m, u); minimising over the free rates leaves the Schur complement
    in (dx, m) as V_j, to which the tracking term of pose j is added.
    """
    k_steps = A.shape[0]
    gain = np.zeros((k_steps, 2, 5))
    offset = np.zeros((k_steps, 2))
    hu = np.zeros((k_steps, 2, 7))      # rows of the stage Hessian belonging to u
    gu = np.zeros((k_steps, 2))         # and of its gradient
    P = np.zeros((5, 5))
    p = np.zeros(5)
    for i in range(3):
        P[i, i] = 2.0 * qd[i]
        p[i] = -2.0 * qd[i] * e[k_steps - 1, i]
    PA = np.zeros((3, 3))
    W = np.zeros((3, 2))                # Pxx B + Pxn
    H = np.zeros((7, 7))
    h = np.zeros(7)
    for j in range(k_steps - 1, -1, -1):
        # blocks of F'PF with F = [[A, B], [0, I]] over (dx, u)
        for r in range(3):
            for s in range(3):
                PA[r, s] = P[r, 0] * A[j, 0, s] + P[r, 1] * A[j, 1, s] + P[r, 2] * A[j, 2, s]
            for s in range(2):
                W[r, s] = (P[r, 0] * B[j, 0, s] + P[r, 1] * B[j, 1, s] + P[r, 2] * B[j, 2, s]
                           + P[r, 3 + s])
        for r in range(3):
            for s in range(3):
                H[r, s] = A[j, 0, r] * PA[0, s] + A[j, 1, r] * PA[1, s] + A[j, 2, r] * PA[2, s]
            for s in range(2):
                v = A[j, 0, r] * W[0, s] + A[j, 1, r] * W[1, s] + A[j, 2, r] * W[2, s]
                H[r, 5 + s] = v
                H[5 + s, r] = v
            h[r] = A[j, 0, r] * p[0] + A[j, 1, r] * p[1] + A[j, 2, r] * p[2]  # (not theta)
        for r in range(2):
            for s in range(2):
                H[5 + r, 5 + s] = (B[j, 0, r] * W[0, s] + B[j, 1, r] * W[1, s]
                                   + B[j, 2, r] * W[2, s]
                                   + P[3 + r, 0] * B[j, 0, s] + P[3 + r, 1] * B[j, 1, s]
                                   + P[3 + r, 2] * B[j, 2, s] + P[3 + r, 3 + s])
            h[5 + r] = (B[j, 0, r] * p[0] + B[j, 1, r] * p[1] + B[j, 2, r] * p[2]  # (not theta)
                        + p[3 + r])
        for r in range(3):
            for s in range(2):
                H[r, 3 + s] = 0.0
                H[3 + s, r] = 0.0
        for r in range(2):
            h[3 + r] = 0.0
            for s in range(2):
                H[3 + r, 3 + s] = 0.0
                H[3 + r, 5 + s] = 0.0
                H[5 + r, 3 + s] = 0.0
        if j >= 1:
            for r in range(2):
                two_r = 2.0 * rd[r]
                H[3 + r, 3 + r] = two_r
                H[3 + r, 5 + r] = -two_r
                H[5 + r, 3 + r] = -two_r
                H[5 + r, 5 + r] += two_r
                h[5 + r] += two_r * c[j - 1, r]
                h[3 + r] = -two_r * c[j - 1, r]
        for r in range(2):
            gu[j, r] = h[5 + r]
            for s in range(7):
                hu[j, r, s] = H[5 + r, s]
        # fold the fixed rates into the constant terms: y_u = value
        for r in range(2):
            for s in range(5):
                gain[j, r, s] = 0.0
            offset[j, r] = fixed_val[j, r] if fixed[j, r] else 0.0
        for a in range(2):
            if fixed[j, a]:
                val = fixed_val[j, a]
                for s in range(5):
                    h[s] += H[s, 5 + a] * val
                for f in range(2):
                    if not fixed[j, f]:
                        h[5 + f] += H[5 + f, 5 + a] * val
        # V_j over (dx, m): Schur complement of the free rates
        for r in range(5):
            p[r] = h[r]
            for s in range(5):
                P[r, s] = H[r, s]
        free0, free1 = not fixed[j, 0], not fixed[j, 1]
        if free0 and free1:
            a11, a12, a22 = H[5, 5], H[5, 6], H[6, 6]
            det = a11 * a22 - a12 * a12
            if not (a11 > 0.0 and det > 0.0):
                return False
            i00, i01, i11 = a22 / det, -a12 / det, a11 / det
            for s in range(5):
                gain[j, 0, s] = -(i00 * H[5, s] + i01 * H[6, s])
                gain[j, 1, s] = -(i01 * H[5, s] + i11 * H[6, s])
            offset[j, 0] = -(i00 * h[5] + i01 * h[6])
            offset[j, 1] = -(i01 * h[5] + i11 * h[6])
            for r in range(5):
                p[r] += H[r, 5] * offset[j, 0] + H[r, 6] * offset[j, 1]
                for s in range(5):
                    P[r, s] += H[r, 5] * gain[j, 0, s] + H[r, 6] * gain[j, 1, s]
        elif free0 or free1:
            f = 0 if free0 else 1
            hff = H[5 + f, 5 + f]
            if not hff > 0.0:
                return False
            for s in range(5):
                gain[j, f, s] = -H[5 + f, s] / hff
            offset[j, f] = -h[5 + f] / hff
            for r in range(5):
                p[r] += H[r, 5 + f] * offset[j, f]
                for s in range(5):
                    P[r, s] += H[r, 5 + f] * gain[j, f, s]
        if j >= 1:
            for r in range(3):
                P[r, r] += 2.0 * qd[r]
                p[r] -= 2.0 * qd[r] * e[j - 1, r]
    # forward sweep
    y = np.zeros(7)
    for i in range(3):
        dx[0, i] = 0.0
    m0, m1 = 0.0, 0.0
    for j in range(k_steps):
        for i in range(3):
            y[i] = dx[j, i]
        y[3], y[4] = m0, m1
        for r in range(2):
            acc = offset[j, r]
            for s in range(5):
                acc += gain[j, r, s] * y[s]
            y[5 + r] = acc
        for r in range(2):
            dn[j, r] = y[5 + r]
            if fixed[j, r]:
                acc = gu[j, r]
                for s in range(7):
                    acc += hu[j, r, s] * y[s]
                mu[j, r] = -acc
            else:
                mu[j, r] = 0.0
        for i in range(3):
            dx[j + 1, i] = (A[j, i, 0] * dx[j, 0] + A[j, i, 1] * dx[j, 1] + A[j, i, 2] * dx[j, 2]
                            + B[j, i, 0] * y[5] + B[j, i, 1] * y[6])
        m0, m1 = y[5], y[6]
    return True


@jit
def _pdas(A: FloatArray, B: FloatArray, e: FloatArray, c: FloatArray, qd: FloatArray,
          rd: FloatArray, lo: FloatArray, hi: FloatArray, act_lo: BoolArray, act_hi: BoolArray,
          max_iterations: int, dn: FloatArray, dx: FloatArray,
          mu: FloatArray) -> tuple[int, int]:  # pragma: no cover - compiled
    """Primal-dual active-set loop over :func:`_sweep`. Updates act_lo/act_hi in place.

    Returns (status, iterations); status 0 optimal, 1 the active set cycles, 2 iteration limit,
    3 a stage Hessian is not positive definite.
    """
    k_steps = A.shape[0]
    active = np.zeros((k_steps, 2), dtype=np.bool_)
    values = np.zeros((k_steps, 2))
    new_lo = np.zeros((k_steps, 2), dtype=np.bool_)
    new_hi = np.zeros((k_steps, 2), dtype=np.bool_)
    history = np.zeros(max_iterations, dtype=np.uint64)
    for it in range(max_iterations):
        for j in range(k_steps):
            for r in range(2):
                active[j, r] = act_lo[j, r] or act_hi[j, r]
                values[j, r] = lo[j, r] if act_lo[j, r] else hi[j, r]
        if not _sweep(A, B, e, c, qd, rd, active, values, dn, dx, mu):
            return 3, it + 1
        changed = False
        digest = np.uint64(1469598103934665603)
        for j in range(k_steps):
            for r in range(2):
                scale = 4.0 * rd[r]
                tol = scale * 1e-10 * (1.0 + abs(lo[j, r]) + abs(hi[j, r]))
                is_fixed = hi[j, r] - lo[j, r] <= 0.0
                nl = is_fixed or (mu[j, r] + scale * (dn[j, r] - lo[j, r]) < -tol)
                nh = (not is_fixed) and (not nl) \
                    and (mu[j, r] + scale * (dn[j, r] - hi[j, r]) > tol)
                if nl != act_lo[j, r] or nh != act_hi[j, r]:
                    changed = True
                new_lo[j, r] = nl
                new_hi[j, r] = nh
                if nl or nh:
                    code = np.uint64(2 * (2 * j + r) + (1 if nh else 0) + 1)
                    digest = (digest ^ code) * np.uint64(1099511628211)
        if not changed:
            return 0, it + 1
        for prev in range(it):
            if history[prev] == digest:
                return 1, it + 1
        history[it] = digest
        for j in range(k_steps):
            for r in range(2):
                act_lo[j, r] = new_lo[j, r]
                act_hi[j, r] = new_hi[j, r]
    return 2, max_iterations


@jit
def _pdas_batch(A: FloatArray, B: FloatArray, e: FloatArray, c: FloatArray, qd: FloatArray,
                rd: FloatArray, lo: FloatArray, hi: FloatArray, act_lo: BoolArray,
                act_hi: BoolArray, max_iterations: int, dn: FloatArray, dx: FloatArray,
                mu: FloatArray, status: IntArray,
                iterations: IntArray) -> None:  # pragma: no cover - compiled
    """:func:`_pdas` for each of many segments (a leading axis on every per-segment array):
    one call for a chunk of QPs."""
    for s in range(A.shape[0]):
        status[s], iterations[s] = _pdas(A[s], B[s], e[s], c[s], qd, rd, lo[s], hi[s],
                                         act_lo[s], act_hi[s], max_iterations, dn[s], dx[s],
                                         mu[s])


@dataclass(frozen=True)
class RiccatiSolution:
    """Outcome of the fast path.

    z : ndarray, shape (5K,), the primal solution ``[dn_0, dx_1, ...]``
    converged : the active set settled (all rate-bound KKT conditions hold)
    states_feasible : the state bounds hold at the solution (else the general path is needed)
    iterations : Riccati sweeps
    active_lower, active_upper : ndarray of bool, shape (K, 2), the final active rate bounds
    message : why it stopped
    """

    z: FloatArray
    converged: bool
    states_feasible: bool
    iterations: int
    active_lower: BoolArray
    active_upper: BoolArray
    message: str


def solve_riccati(p: CompensationProblem, *, max_iterations: int = 50,
                  initial_active: tuple[BoolArray, BoolArray] | None = None) -> RiccatiSolution:
    """Solve the QP with rate bounds by PDAS around a Riccati recursion; check the state bounds."""
    k = p.steps
    lo, hi = p.lower[:, :2], p.upper[:, :2]
    fixed_by_bounds = hi - lo <= 0.0
    if initial_active is None:
        act_lo, act_hi = fixed_by_bounds.copy(), np.zeros_like(fixed_by_bounds)
    else:
        act_lo = np.ascontiguousarray(initial_active[0] | fixed_by_bounds)
        act_hi = np.ascontiguousarray(initial_active[1] & ~act_lo)
    dn = np.empty((k, 2))
    dx = np.empty((k + 1, 3))
    mu = np.empty((k, 2))
    c = p.rate_change if k > 1 else np.zeros((1, 2))
    status, iterations = _pdas(
        np.ascontiguousarray(p.A), np.ascontiguousarray(p.B),
        np.ascontiguousarray(p.tracking_error), np.ascontiguousarray(c), p.q_diag, p.r_diag,
        np.ascontiguousarray(lo), np.ascontiguousarray(hi), act_lo, act_hi, max_iterations,
        dn, dx, mu)
    converged = status == 0
    message = _STATUS[status]
    z = np.empty((k, STAGE))
    z[:, :2] = dn
    z[:, 2:] = dx[1:]
    margin = 1e-9 * (1.0 + np.abs(p.lower[:, 2:]) + np.abs(p.upper[:, 2:]))
    states_ok = bool(((dx[1:] >= p.lower[:, 2:] - margin)
                      & (dx[1:] <= p.upper[:, 2:] + margin)).all())
    return RiccatiSolution(z=z.ravel(), converged=converged, states_feasible=states_ok,
                           iterations=iterations, active_lower=act_lo, active_upper=act_hi,
                           message=message)


@dataclass(frozen=True)
class RiccatiBatch:
    """Outcome of the fast path for many segments (a leading segment axis on each field of
    :class:`RiccatiSolution`; ``z`` as ``dn`` (N, K, 2) and ``dx`` (N, K, 3))."""

    dn: FloatArray
    dx: FloatArray
    converged: BoolArray
    states_feasible: BoolArray
    iterations: IntArray
    active_lower: BoolArray
    active_upper: BoolArray


def solve_riccati_batch(pb: ProblemBatch, *, max_iterations: int = 50,
                        initial_active: tuple[BoolArray, BoolArray] | None = None
                        ) -> RiccatiBatch:
    """:func:`solve_riccati` of every segment of ``pb`` in one compiled call (the same answers:
    each QP is solved alone). ``initial_active``: (N, K, 2) arrays, or None."""
    n, k = pb.A.shape[:2]
    lo = np.ascontiguousarray(pb.lower[..., :2])
    hi = np.ascontiguousarray(pb.upper[..., :2])
    fixed_by_bounds = hi - lo <= 0.0
    if initial_active is None:
        act_lo, act_hi = fixed_by_bounds.copy(), np.zeros_like(fixed_by_bounds)
    else:
        act_lo = np.ascontiguousarray(initial_active[0] | fixed_by_bounds)
        act_hi = np.ascontiguousarray(initial_active[1] & ~act_lo)
    dn = np.empty((n, k, 2))
    dx = np.empty((n, k + 1, 3))
    mu = np.empty((n, k, 2))
    status = np.empty(n, dtype=np.int64)
    iterations = np.empty(n, dtype=np.int64)
    c = pb.rate_change if k > 1 else np.zeros((n, 1, 2))
    _pdas_batch(np.ascontiguousarray(pb.A), np.ascontiguousarray(pb.B),
                np.ascontiguousarray(pb.tracking_error), np.ascontiguousarray(c), pb.q_diag,
                pb.r_diag, lo, hi, act_lo, act_hi, max_iterations, dn, dx, mu, status,
                iterations)
    states = dx[:, 1:]
    margin = 1e-9 * (1.0 + np.abs(pb.lower[..., 2:]) + np.abs(pb.upper[..., 2:]))
    states_ok = ((states >= pb.lower[..., 2:] - margin)
                 & (states <= pb.upper[..., 2:] + margin)).all(axis=(1, 2))
    return RiccatiBatch(dn=dn, dx=states, converged=status == 0,
                        states_feasible=np.asarray(states_ok, dtype=bool),
                        iterations=iterations, active_lower=act_lo, active_upper=act_hi)
