"""The structured QP solver: a primal-dual active-set method on the banded KKT system.

The QP of :mod:`odocal.estimators.compensation.problem` is an LQ tracking problem with box bounds.
Ordering the
unknowns stage by stage, ``[dn_{k-1} (2), lambda_k (3), dx_k (3)]`` for k = 1..K, puts its KKT
matrix (Hessian, model constraints and their multipliers) in a band of half-width 9, so one solve
is a banded LU (LAPACK ``dgbsv``) costing O(K).

This is the general path, used when a state bound binds (the fast path in :mod:`.riccati` handles
the rate bounds alone). Bounds are handled exactly by an active-set method: each iteration fixes
the working set at its bounds and solves the equality-constrained KKT system; bounds with a
multiplier of the wrong sign leave, violated ones enter. A full primal-dual active-set update
(Hintermüller, Ito and Kunisch 2003) is unstable with state bounds (the set overshoots to
hundreds of bounds and the KKT system turns singular), so changes are made a few at a time. If
the working set cycles, the KKT system is singular or the iteration limit is reached, the caller
hands the problem to OSQP.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
from scipy.linalg import lapack

from odocal.arrays import BoolArray, FloatArray, IntArray
from odocal.estimators.compensation.problem import STAGE, CompensationProblem

_WIDTH = 8            # KKT unknowns per stage
_KL = _KU = 9         # half-bandwidths of the stage-ordered KKT matrix


@dataclass(frozen=True)
class StructuredSolution:
    """Outcome of the active-set solver.

    z : ndarray, shape (5K,), the primal solution ``[dn_0, dx_1, ...]`` (valid if converged)
    converged : whether the active set settled with all KKT conditions met
    iterations : active-set iterations (banded solves)
    active : number of variables at a bound
    message : why it stopped
    """

    z: FloatArray
    converged: bool
    iterations: int
    active: int
    message: str


@functools.lru_cache(maxsize=16)
def _pattern(k: int) -> tuple[IntArray, IntArray, IntArray, IntArray]:
    """Row/column indices of the KKT nonzeros for K stages, and where each z-variable lives.

    Returns (rows, cols, band_rows, z_index): ``band_rows`` is the row of each entry in LAPACK
    band storage; ``z_index`` maps the 5K z-variables to KKT unknowns.
    """
    base = _WIDTH * np.arange(k)
    rows: list[IntArray] = []
    cols: list[IntArray] = []

    def add(r: IntArray, c: IntArray) -> None:
        rr, cc = np.broadcast_arrays(r, c)
        rows.append(rr.astype(np.int64).ravel())
        cols.append(cc.astype(np.int64).ravel())

    # index grids: stage j on axis 0, then the component axes in the order the values use
    a2 = np.arange(2)
    i3 = np.arange(3)
    b_all, b_now, b_prev = base[:, None, None], base[1:, None, None], base[:-1, None, None]
    # 1. stationarity of dn_j: R-chain diagonal, neighbours, -B_j^T lambda_{j+1}   (j, a, i)
    add(base[:, None] + a2, base[:, None] + a2)
    add(base[1:, None] + a2, base[:-1, None] + a2)
    add(base[:-1, None] + a2, base[1:, None] + a2)
    add(b_all + a2[:, None], b_all + 2 + i3[None, :])
    # 2. model constraint lambda_{j+1}: dx_{j+1} - A_j dx_j - B_j dn_j = 0
    add(base[:, None] + 2 + i3, base[:, None] + 5 + i3)
    add(b_now + 2 + i3[:, None], b_prev + 5 + i3[None, :])              # (j, i, m)
    add(b_all + 2 + i3[:, None], b_all + a2[None, :])                   # (j, i, a)
    # 3. stationarity of dx_{j+1}: 2Q, + lambda_{j+1}, - A_{j+1}^T lambda_{j+2}   (j, i, m)
    add(base[:, None] + 5 + i3, base[:, None] + 5 + i3)
    add(base[:, None] + 5 + i3, base[:, None] + 2 + i3)
    add(b_prev + 5 + i3[:, None], b_now + 2 + i3[None, :])
    r = np.concatenate(rows)
    c = np.concatenate(cols)
    band_rows = _KL + _KU + r - c
    z_index = (base[:, None] + np.array([0, 1, 5, 6, 7])).ravel()
    return r, c, band_rows, z_index


def _values(p: CompensationProblem) -> FloatArray:
    """KKT nonzero values in the order of :func:`_pattern`."""
    k = p.steps
    two_r = 2.0 * p.r_diag
    count = np.full(k, 2.0)
    count[0] -= 1.0
    count[-1] -= 1.0
    count = np.maximum(count, 0.0)
    a_mat, b_mat = p.A, p.B
    parts = [
        (count[:, None] * two_r).ravel(),                        # dn diagonal
        np.broadcast_to(-two_r, (k - 1, 2)).ravel(),             # dn_j with dn_{j-1}
        np.broadcast_to(-two_r, (k - 1, 2)).ravel(),             # dn_j with dn_{j+1}
        (-np.swapaxes(b_mat, 1, 2)).ravel(),                     # -B_j^T (a, i)
        np.ones(3 * k),                                          # dx_{j+1} in its constraint
        (-a_mat[1:]).ravel(),                                    # -A_j (i, m) on dx_j
        (-b_mat).ravel(),                                        # -B_j (i, a) on dn_j
        np.broadcast_to(2.0 * p.q_diag, (k, 3)).ravel(),         # 2Q
        np.ones(3 * k),                                          # lambda_{j+1}
        (-np.swapaxes(a_mat[1:], 1, 2)).ravel(),                 # -A_{j+1}^T
    ]
    return np.concatenate(parts)


def _runs(mask: BoolArray, k: int) -> list[IntArray]:
    """Indices of ``mask`` (shape (5K,)) grouped into runs consecutive in time per component."""
    grid = mask.reshape(k, STAGE)
    runs: list[IntArray] = []
    for comp in range(STAGE):
        idx = np.flatnonzero(grid[:, comp])
        if idx.size == 0:
            continue
        for part in np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1):
            runs.append(part * STAGE + comp)
    return runs


def _kkt_solve(base: FloatArray, rhs_base: FloatArray, z_index: IntArray,
               act_lo: BoolArray, act_hi: BoolArray, lower: FloatArray,
               upper: FloatArray) -> tuple[FloatArray, int]:
    """The banded KKT system with the working set's variables fixed at their bounds (their
    rows replaced by ``z_i = bound``), solved by banded LU; the solution and LAPACK's info."""
    n = base.shape[1]
    active = act_lo | act_hi
    ab = base.copy()
    rhs = rhs_base.copy()
    if active.any():
        kkt_rows = z_index[active]
        band_cols = kkt_rows[:, None] + np.arange(-_KL, _KU + 1)[None, :]
        ok = (band_cols >= 0) & (band_cols < n)
        rr = np.broadcast_to(kkt_rows[:, None], band_cols.shape)[ok]
        cc = band_cols[ok]
        ab[_KL + _KU + rr - cc, cc] = 0.0
        ab[_KL + _KU, kkt_rows] = 1.0
        rhs[kkt_rows] = np.where(act_lo[active], lower[active], upper[active])
    _, _, x, info = lapack.dgbsv(_KL, _KU, ab, rhs, overwrite_ab=True, overwrite_b=True)
    return np.asarray(x), int(info)


def _kkt_system(p: CompensationProblem
                ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
    """The KKT matrix in LAPACK band storage and its right-hand side, no bound fixed; the KKT
    nonzero values (in the order of :func:`_pattern`), q (5K,), and the curvature of each
    z-variable (its diagonal entry), to compare multipliers by."""
    k = p.steps
    n = _WIDTH * k
    rows, cols, band_rows, z_index = _pattern(k)
    vals = _values(p)
    q, _ = p.gradient_terms()
    q = q.ravel()

    base = np.zeros((2 * _KL + _KU + 1, n))
    base[band_rows, cols] = vals
    rhs_base = np.zeros(n)
    rhs_base[z_index] = -q

    diag = np.zeros(n)
    on_diag = rows == cols
    diag[rows[on_diag]] = vals[on_diag]
    scale = np.maximum(diag[z_index], 1e-8)       # curvature per variable, to compare multipliers
    return base, rhs_base, vals, q, scale


def _initial_set(fixed: BoolArray, initial_active: tuple[BoolArray, BoolArray] | None
                 ) -> tuple[BoolArray, BoolArray]:
    """The starting working set (at the lower bound, at the upper): ``initial_active`` where
    given, and every fixed variable at its lower bound."""
    if initial_active is None:
        return fixed.copy(), np.zeros_like(fixed)
    act_lo = initial_active[0] | fixed
    act_hi = initial_active[1] & ~act_lo
    return act_lo, act_hi


def solve_structured(p: CompensationProblem, *, max_iterations: int = 50,
                     initial_active: tuple[BoolArray, BoolArray] | None = None,
                     ) -> StructuredSolution:
    """Solve the compensation QP with an active-set method on the banded KKT system.

    Each iteration fixes the working set at its bounds and solves the KKT system by banded LU.
    If a working bound has a multiplier of the wrong sign, the worst one is released; otherwise,
    if bounds are violated, the most violated bound of each run of violations (consecutive in
    time) is added. When neither happens the KKT conditions hold. Starting from a good working
    set (the fast path's rate bounds), few iterations are needed.
    """
    k = p.steps
    n = _WIDTH * k
    rows, cols, _, z_index = _pattern(k)
    base, rhs_base, vals, q, scale = _kkt_system(p)
    lower, upper = p.lower.ravel(), p.upper.ravel()
    width = np.maximum(upper - lower, 1e-12)
    fixed = upper - lower <= 0.0
    tol_z = 1e-10 * (1.0 + np.abs(lower) + np.abs(upper))
    act_lo, act_hi = _initial_set(fixed, initial_active)
    seen: set[bytes] = set()
    z = np.zeros(STAGE * k)
    message = "iteration limit"
    iteration = 0
    for iteration in range(1, max_iterations + 1):
        active = act_lo | act_hi
        key = np.packbits(np.concatenate([act_lo, act_hi])).tobytes()
        if key in seen:
            message = "the working set cycles"
            break
        seen.add(key)
        x, info = _kkt_solve(base, rhs_base, z_index, act_lo, act_hi, lower, upper)
        if info != 0:
            return StructuredSolution(z=z, converged=False, iterations=iteration,
                                      active=int(active.sum()),
                                      message=f"singular KKT system (LAPACK info {info})")
        z = x[z_index]
        # bound multipliers mu = -(P z + q + E^T lambda) from the unmodified stationarity rows
        stationarity = np.bincount(rows, weights=vals * x[cols], minlength=n)[z_index] + q
        mu = -stationarity
        wrong = ~fixed & ((act_hi & (mu < -1e-9 * scale)) | (act_lo & (mu > 1e-9 * scale)))
        if wrong.any():
            worst = int(np.argmax(np.where(wrong, np.abs(mu) / scale, -1.0)))
            act_lo[worst] = act_hi[worst] = False
            continue
        below = ~active & (z < lower - tol_z)
        above = ~active & (z > upper + tol_z)
        if not (below.any() or above.any()):
            return StructuredSolution(z=z, converged=True, iterations=iteration,
                                      active=int(active.sum()), message="optimal")
        violation = np.where(below, lower - z, np.where(above, z - upper, 0.0)) / width
        for run in _runs(below | above, k):
            i = int(run[np.argmax(violation[run])])
            act_lo[i], act_hi[i] = bool(below[i]), bool(above[i])
    return StructuredSolution(z=z, converged=False, iterations=iteration,
                              active=int((act_lo | act_hi).sum()), message=message)
