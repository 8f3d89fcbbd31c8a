"""The segment methods' rollouts with their Jacobians, vectorised over time and segments.

Batch Gauss-Newton (METHOD 3) reduces every segment's ``[sqrt(W) J | sqrt(W) R]`` to an R
factor, and the compensation QP (METHOD 4) linearises every step. Both run the one model step
(:mod:`odocal.model.step`) on whole ``(segments, steps)`` arrays: nothing here is compiled, so
an edit to the model reaches them at once and a first run costs what every run costs.

A Jacobian ``J = d x_k / d theta`` propagates as ``J+ = A_k J + B_k`` with
``A_k = I + [0, 0, -dy; 0, 0, dx; 0, 0, 0]``: a cumulative sum along the rollout. The heading's
row is the sum of the steps' ``d(dpsi)/d theta``; the position rows add, step by step, each
step's own derivative and the heading's so far turned by the step (``-dy``, ``dx``).
Segments are taken a chunk at a time (:data:`CHUNK_STEPS` steps), so the work arrays stay in
the caches and a ten-hour drive's segments never sit in memory as Jacobians all at once.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from odocal.arrays import FloatArray
from odocal.model import step
from odocal.model.kinematics import _as_batch, _flat, _theta, wrap_angle
from odocal.model.parameters import PARAMETERS, STATES, WHEELS, Inputs, Parameters

#: Segment steps handled per pass (a chunk of segments of about this many steps in all).
CHUNK_STEPS = 1 << 15


def _chunks(n: int, k: int) -> range:
    """Start indices of chunks of segments of ``k`` steps each, about CHUNK_STEPS steps a chunk."""
    return range(0, n, max(1, CHUNK_STEPS // max(k, 1)))


def _linearised(th: FloatArray, n_rl: FloatArray, n_rr: FloatArray, beta: FloatArray,
                a_y: FloatArray, psi: FloatArray, t_s: float
                ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Each step's increment (dx, dy, dpsi) from the headings ``psi`` (N, K) before it, and its
    derivatives ``d`` (N, 3, wheels + n, K) in ``[n_rl, n_rr, theta]`` at the fixed heading
    (time along the last axis, where the cumulative sums run)."""
    v, w, c_rl, c_rr = step.body(th, n_rl, n_rr, a_y)
    dx, dy, dpsi, ct, st = step.increment(psi, v, w, beta, t_s)
    n, k = n_rl.shape
    d = np.empty((n, STATES, WHEELS + PARAMETERS, k))
    step.increment_derivatives(th, n_rl, n_rr, a_y, v, w, c_rl, c_rr, dx, dy, ct, st, t_s,
                               d.transpose(1, 2, 0, 3))
    return dx, dy, dpsi, d


def _headings(th: FloatArray, n_rl: FloatArray, n_rr: FloatArray, a_y: FloatArray,
              psi0: FloatArray, t_s: float) -> FloatArray:
    """The heading before each step of each rollout (N, K): psi0 plus the turns so far."""
    _, w, _, _ = step.body(th, n_rl, n_rr, a_y)
    turn = w * t_s
    psi = np.empty_like(turn)
    psi[:, 0] = psi0
    np.cumsum(turn[:, :-1], axis=1, out=psi[:, 1:])
    psi[:, 1:] += psi0[:, None]
    return psi


def _propagate(dx: FloatArray, dy: FloatArray, d: FloatArray, out: FloatArray) -> None:
    """d pose_k / d theta after every step into ``out[:, :n]`` (N, n, 3, K): ``J+ = A_k J +
    B_k`` summed along the rollout."""
    d_theta = d[:, :, WHEELS:]                            # (N, 3, n, K)
    n = d_theta.shape[2]
    heading = np.cumsum(d_theta[:, 2], axis=-1, out=out[:, :n, 2])  # after each step
    before = heading - d_theta[:, 2]                      # and before it
    np.cumsum(d_theta[:, 0] - dy[:, None] * before, axis=-1, out=out[:, :n, 0])
    np.cumsum(d_theta[:, 1] + dx[:, None] * before, axis=-1, out=out[:, :n, 1])


def rollout_with_jacobian(theta: FloatArray | Parameters, u: Inputs, x0: FloatArray,
                          t_s: float) -> tuple[FloatArray, FloatArray]:
    """Rollout and its Jacobian with respect to theta, propagated along the rollout.

    Returns
    -------
    poses : ndarray, shape (..., K+1, 3)
    jac : ndarray, shape (..., K+1, 3, n)
        ``jac[..., k, i, j] = d poses[..., k, i] / d theta[j]``; zero at k = 0 (x0 is measured).
    """
    lead, (n_rl, n_rr, beta, a_y) = _as_batch(u)
    n, k = n_rl.shape
    th = _theta(theta)
    start = _flat(x0, (*lead, STATES)).reshape(n, STATES)
    poses = np.empty((n, k + 1, STATES))
    jac = np.empty((n, k + 1, STATES, PARAMETERS))
    jac[:, 0] = 0.0
    poses[:, 0] = start
    psi = _headings(th, n_rl, n_rr, a_y, start[:, 2], t_s)
    dx, dy, dpsi, d = _linearised(th, n_rl, n_rr, beta, a_y, psi, float(t_s))
    poses[:, 1:, 0] = start[:, :1] + np.cumsum(dx, axis=1)
    poses[:, 1:, 1] = start[:, 1:2] + np.cumsum(dy, axis=1)
    poses[:, 1:, 2] = psi + dpsi
    work = np.empty((n, PARAMETERS, STATES, k))
    _propagate(dx, dy, d, work)
    jac[:, 1:] = work.transpose(0, 3, 2, 1)
    return (poses.reshape(*lead, k + 1, STATES),
            jac.reshape(*lead, k + 1, STATES, PARAMETERS))


def segment_r_factors(theta: FloatArray | Parameters, u: Inputs, reference: FloatArray,
                      t_s: float, weights: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The Gauss-Newton least-squares problem of each segment, reduced to an R factor.

    Parameters
    ----------
    u : Inputs with arrays of shape (N, K)
    reference : ndarray, shape (N, K+1, 3), the measured poses; each rollout starts at the first
    weights : ndarray, shape (3,), W per sample (METHOD 3)

    Returns
    -------
    r : ndarray, shape (N, n+1, n+1)
        Upper-triangular R of ``[sqrt(W) J_s | sqrt(W) R_s] = Q R`` (Householder, LAPACK) for
        each segment s, with J_s = d y^ / d theta and R_s = y~ - y^ (heading residuals wrapped)
        over its K samples. Its rows' signs are LAPACK's: only ``R^T R`` and least-squares
        solves with it are meant.
    stats : ndarray, shape (N, 5)
        Weighted cost, unweighted sums of squares of the p_x, p_y, psi residuals, and the sum of
        lag-1 products of the centred weighted residuals.
    """
    _, (n_rl, n_rr, beta, a_y) = _as_batch(u)
    n, k = n_rl.shape
    th = _theta(theta)
    ref = np.asarray(reference, dtype=np.float64).reshape(n, k + 1, STATES)
    sqrt_w = np.sqrt(np.asarray(weights, dtype=np.float64))
    cols = PARAMETERS + 1
    r = np.empty((n, cols, cols))
    stats = np.empty((n, 5))
    for lo in _chunks(n, k):
        hi = min(n, lo + max(1, CHUNK_STEPS // max(k, 1)))
        part = slice(lo, hi)
        x0 = ref[part, 0]
        psi = _headings(th, n_rl[part], n_rr[part], a_y[part], x0[:, 2], t_s)
        dx, dy, dpsi, d = _linearised(th, n_rl[part], n_rr[part], beta[part], a_y[part], psi,
                                      float(t_s))
        # [sqrt(W) J | sqrt(W) R] stored column by column ((c, n+1, 3, K): time last, where
        # the sums run; the rows' order does not change R^T R), so LAPACK reads it as it is
        mat = np.empty((hi - lo, cols, STATES, k))
        _propagate(dx, dy, d, mat)
        res = mat[:, PARAMETERS]                                   # (c, 3, K), a view
        np.subtract(ref[part, 1:, 0], x0[:, :1] + np.cumsum(dx, axis=1), out=res[:, 0])
        np.subtract(ref[part, 1:, 1], x0[:, 1:2] + np.cumsum(dy, axis=1), out=res[:, 1])
        res[:, 2] = wrap_angle(ref[part, 1:, 2] - (psi + dpsi))
        ss = np.einsum("cik,cik->ci", res, res)
        mat *= sqrt_w[:, None]
        centred = res - res.mean(axis=2, keepdims=True)
        stats[part, 0] = ss @ sqrt_w ** 2
        stats[part, 1:4] = ss
        stats[part, 4] = np.einsum("cik,cik->c", centred[..., 1:], centred[..., :-1])
        columns = mat.reshape(hi - lo, cols, STATES * k).transpose(0, 2, 1)
        r[part] = np.linalg.qr(columns, mode="r")
    return r, stats


@dataclass(frozen=True)
class StepJacobians:
    """Linearisation of one step ``x_k = f(x_{k-1}, u_{k-1})`` around a trajectory.

    A : ndarray, shape (..., K, 3, 3)
        df/dx at each step.
    B : ndarray, shape (..., K, 3, 2)
        df/d[n_rl, n_rr] at each step.
    """

    A: FloatArray
    B: FloatArray


def step_jacobians(theta: FloatArray | Parameters, u: Inputs, poses: FloatArray,
                   t_s: float) -> StepJacobians:
    """(10a): A_k = df/dx and B_k = df/dn around ``poses`` (the trajectory of the inputs ``u``).

    ``poses`` has shape (..., K+1, 3) and ``u`` arrays (..., K); step k maps poses[k] to
    poses[k+1] with u[k].
    """
    lead, (n_rl, n_rr, beta, a_y) = _as_batch(u)
    n, k = n_rl.shape
    psi = _flat(poses, (*lead, k + 1, STATES)).reshape(n, k + 1, STATES)[:, :-1, 2]
    dx, dy, _, d = _linearised(_theta(theta), n_rl, n_rr, beta, a_y, psi, float(t_s))
    a = np.zeros((n, k, STATES, STATES))
    a[..., 0, 0] = a[..., 1, 1] = a[..., 2, 2] = 1.0
    a[..., 0, 2] = -dy
    a[..., 1, 2] = dx
    b = d[:, :, :WHEELS].transpose(0, 3, 1, 2)
    return StepJacobians(A=a.reshape(*lead, k, STATES, STATES),
                         B=np.ascontiguousarray(b).reshape(*lead, k, STATES, WHEELS))


def linearised_rollout(theta: FloatArray | Parameters, u: Inputs, x0: FloatArray,
                       t_s: float) -> tuple[FloatArray, StepJacobians]:
    """:func:`odocal.model.kinematics.rollout` from ``x0`` and :func:`step_jacobians` around
    it, the steps' increments computed once for both (the compensation QP's linearisation)."""
    lead, (n_rl, n_rr, beta, a_y) = _as_batch(u)
    n, k = n_rl.shape
    th = _theta(theta)
    start = _flat(x0, (*lead, STATES)).reshape(n, STATES)
    psi = _headings(th, n_rl, n_rr, a_y, start[:, 2], t_s)
    dx, dy, dpsi, d = _linearised(th, n_rl, n_rr, beta, a_y, psi, float(t_s))
    poses = np.empty((n, k + 1, STATES))
    poses[:, 0] = start
    poses[:, 1:, 0] = start[:, :1] + np.cumsum(dx, axis=1)
    poses[:, 1:, 1] = start[:, 1:2] + np.cumsum(dy, axis=1)
    poses[:, 1:, 2] = psi + dpsi
    a = np.zeros((n, k, STATES, STATES))
    a[..., 0, 0] = a[..., 1, 1] = a[..., 2, 2] = 1.0
    a[..., 0, 2] = -dy
    a[..., 1, 2] = dx
    b = np.ascontiguousarray(d[:, :, :WHEELS].transpose(0, 3, 1, 2))
    return (poses.reshape(*lead, k + 1, STATES),
            StepJacobians(A=a.reshape(*lead, k, STATES, STATES),
                          B=b.reshape(*lead, k, STATES, WHEELS)))
