"""The reference solver: the compensation QP as a generic sparse QP, solved with OSQP.

Used to cross-check the structured solver in the tests and benchmarks, and at run time for the
rare problems the active-set method cannot settle (OSQP also certifies infeasibility).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from odocal.arrays import FloatArray
from odocal.estimators.compensation.problem import STAGE, CompensationProblem


@dataclass(frozen=True)
class SparseQP:
    """``min 1/2 z^T P z + q^T z + constant  s.t.  l <= A z <= u`` (A = [E; I])."""

    P: sp.csc_matrix
    q: FloatArray
    A: sp.csc_matrix
    l: FloatArray
    u: FloatArray
    constant: float


def sparse_qp(p: CompensationProblem) -> SparseQP:
    """The compensation QP in OSQP's form, model constraints as equality rows."""
    k = p.steps
    n = STAGE * k
    dn = STAGE * np.arange(k)            # column of dn_j's first component
    dx = dn + 2                          # column of dx_{j+1}'s first component
    two_r, two_q = 2.0 * p.r_diag, 2.0 * p.q_diag
    count = np.full(k, 2.0)
    count[0] -= 1.0
    count[-1] -= 1.0
    count = np.maximum(count, 0.0)
    a2, i3 = np.arange(2), np.arange(3)
    p_rows = np.concatenate([(dn[:, None] + a2).ravel(), (dn[:-1, None] + a2).ravel(),
                             (dx[:, None] + i3).ravel()])
    p_cols = np.concatenate([(dn[:, None] + a2).ravel(), (dn[1:, None] + a2).ravel(),
                             (dx[:, None] + i3).ravel()])
    p_vals = np.concatenate([(count[:, None] * two_r).ravel(),
                             np.broadcast_to(-two_r, (k - 1, 2)).ravel(),
                             np.broadcast_to(two_q, (k, 3)).ravel()])
    P = sp.csc_matrix((p_vals, (p_rows, p_cols)), shape=(n, n))

    c3 = 3 * np.arange(k)                # row of stage j's constraint
    grids = [np.broadcast_arrays(c3[:, None] + i3, dx[:, None] + i3),             # + dx_{j+1}
             np.broadcast_arrays(c3[1:, None, None] + i3[:, None],                 # - A_j dx_j
                                 dx[:-1, None, None] + i3[None, :]),
             np.broadcast_arrays(c3[:, None, None] + i3[:, None],                  # - B_j dn_j
                                 dn[:, None, None] + a2[None, :])]
    e_rows = [g[0].ravel() for g in grids]
    e_cols = [g[1].ravel() for g in grids]
    e_vals = [np.ones(3 * k), (-p.A[1:]).ravel(), (-p.B).ravel()]
    E = sp.csc_matrix((np.concatenate(e_vals), (np.concatenate(e_rows), np.concatenate(e_cols))),
                      shape=(3 * k, n))
    q, constant = p.gradient_terms()
    A = sp.vstack([E, sp.identity(n, format="csc")], format="csc")
    lower = np.concatenate([np.zeros(3 * k), p.lower.ravel()])
    upper = np.concatenate([np.zeros(3 * k), p.upper.ravel()])
    return SparseQP(P=P, q=q.ravel(), A=A, l=lower, u=upper, constant=float(constant))


@dataclass(frozen=True)
class ReferenceSolution:
    """OSQP's answer.

    z : the solution (valid when ``solved``)
    status : OSQP's status of the last attempt
    solved : OSQP solved the problem and its polishing step succeeded (a KKT-exact answer)
    infeasible : OSQP certified the problem primal infeasible
    iterations : ADMM iterations of the last attempt
    eps : the accuracy setting of the last attempt
    """

    z: FloatArray
    status: str
    solved: bool
    infeasible: bool
    iterations: int
    eps: float


#: OSQP settings tried in turn until its polished answer is feasible to ``FEASIBILITY``. Ruiz
#: scaling helps some of these problems and hurts others, so both are tried, with tighter accuracy.
ATTEMPTS: tuple[dict[str, float], ...] = (
    {"scaling": 10, "eps": 1e-5}, {"scaling": 0, "eps": 1e-5}, {"scaling": 10, "eps": 1e-8},
    {"scaling": 0, "eps": 1e-8}, {"scaling": 10, "eps": 1e-10}, {"scaling": 0, "eps": 1e-10},
)
#: Largest violation of the model equalities or the bounds accepted from OSQP.
FEASIBILITY = 1e-9


def solve_osqp(p: CompensationProblem, *,
               attempts: tuple[dict[str, float], ...] = ATTEMPTS,
               max_iter: int = 50_000) -> ReferenceSolution:
    """Solve the compensation QP with OSQP to KKT accuracy.

    OSQP's ADMM reaches ``eps``; its polishing step then solves the KKT system of the active set
    it found, which gives the exact solution when that set is right. Settings are tried along
    ``attempts`` until polishing succeeds with a feasible answer (a polished point can still
    violate the model equalities slightly, and so undercut the true optimum).
    """
    try:
        import osqp  # the reference solver: loaded where it runs
    except ImportError as err:
        from odocal.errors import MissingDependencyError

        raise MissingDependencyError("the reference QP solver ([compensate] solver = \"osqp\") "
                                     "needs osqp, which is not installed: "
                                     "pip install 'odocal[compensated]'") from err

    qp = sparse_qp(p)
    status, iterations, eps = "not run", 0, float("nan")
    for attempt in attempts:
        eps = float(attempt["eps"])
        solver = osqp.OSQP()
        solver.setup(qp.P, qp.q, qp.A, qp.l, qp.u, verbose=False, eps_abs=eps, eps_rel=eps,
                     scaling=int(attempt["scaling"]), polishing=True, polish_refine_iter=10,
                     max_iter=max_iter, eps_prim_inf=1e-7, eps_dual_inf=1e-7)
        result = solver.solve(raise_error=False)
        status = str(result.info.status)
        iterations = int(result.info.iter)
        if "infeasible" in status and "dual" not in status:
            return ReferenceSolution(z=np.zeros(STAGE * p.steps), status=status, solved=False,
                                     infeasible=True, iterations=iterations, eps=eps)
        if status == "solved" and int(result.info.status_polish) == 1 \
                and _violation(qp, result.x) <= FEASIBILITY:
            return ReferenceSolution(z=np.asarray(result.x, dtype=np.float64), status=status,
                                     solved=True, infeasible=False, iterations=iterations,
                                     eps=eps)
    return ReferenceSolution(z=np.zeros(STAGE * p.steps), status=status, solved=False,
                             infeasible=False, iterations=iterations, eps=eps)


def _violation(qp: SparseQP, z: FloatArray) -> float:
    """Largest violation of ``l <= A z <= u``."""
    az = qp.A @ z
    return float(max(np.max(qp.l - az), np.max(az - qp.u), 0.0))
