"""The segment methods' compiled kernels: rollouts with their Jacobians, per segment.

Batch Gauss-Newton (METHOD 3) reduces every segment's ``[sqrt(W) J | sqrt(W) R]`` to an R
factor, and the compensation QP (METHOD 4) linearises every step; both loop over thousands of
steps of hundreds of segments, where numba pays. The kernels are built from the one model step
(:mod:`odocal.model.step`), compiled: :func:`_compiled` binds each step function to the compiled
versions of those it calls. Only the segment methods import this module, so the default method
never loads numba.

A Jacobian ``J = d x_k / d p`` propagates as ``J+ = A_k J + B_k`` with
``A_k = I + [0, 0, -dy; 0, 0, dx; 0, 0, 0]``: a cumulative sum along the rollout, computed in one
compiled pass per segment. The disk cache of each kernel is keyed on the contents of every source
it inlines (this file, :mod:`odocal.model.step`, ...: :mod:`odocal.model._jit`), so an edit to
the model reaches the kernels on their next call.
"""

from __future__ import annotations

import math
import types
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from odocal.model import step
from odocal.model._jit import jit
from odocal.model.kinematics import _as_batch, _flat, _theta
from odocal.model.parameters import Inputs, Parameters

FloatArray = NDArray[np.float64]


def _compiled(function: Callable[..., Any], **callees: Any) -> Any:
    """``function`` compiled to inline, calling the compiled ``callees`` (by name)."""
    env = dict(function.__globals__)
    env.update(callees)
    bound = types.FunctionType(function.__code__, env, function.__name__,
                               function.__defaults__, function.__closure__)
    return jit(inline=True)(bound)


_circumferences = _compiled(step.circumferences)
_body = _compiled(step.body, circumferences=_circumferences)
_increment = _compiled(step.increment)
_increment_derivatives = _compiled(step.increment_derivatives)
_wrap = _compiled(step.wrap)


@jit
def _jacobian_kernel(th: FloatArray, n_rl: FloatArray, n_rr: FloatArray, beta: FloatArray,
                     a_y: FloatArray, x0: FloatArray, t_s: float, poses: FloatArray,
                     jac: FloatArray) -> None:  # pragma: no cover
    """Rollout and d poses / d theta at every step: poses (N, K+1, 3), jac (N, K+1, 3, 4)."""
    n, k_steps = n_rl.shape
    for s in range(n):
        d = np.empty((3, 6))
        x, y, psi = x0[s, 0], x0[s, 1], x0[s, 2]
        poses[s, 0, 0], poses[s, 0, 1], poses[s, 0, 2] = x, y, psi
        jac[s, 0] = 0.0
        for k in range(k_steps):
            v, w, c_rl, c_rr = _body(th, n_rl[s, k], n_rr[s, k], a_y[s, k])
            dx, dy, dpsi, ct, st = _increment(psi, v, w, beta[s, k], t_s)
            _increment_derivatives(th, n_rl[s, k], n_rr[s, k], a_y[s, k], v, w, c_rl, c_rr,
                                   dx, dy, ct, st, t_s, d)
            for j in range(4):
                jpsi = jac[s, k, 2, j]
                jac[s, k + 1, 0, j] = jac[s, k, 0, j] - dy * jpsi + d[0, 2 + j]
                jac[s, k + 1, 1, j] = jac[s, k, 1, j] + dx * jpsi + d[1, 2 + j]
                jac[s, k + 1, 2, j] = jpsi + d[2, 2 + j]
            x += dx
            y += dy
            psi += dpsi
            poses[s, k + 1, 0], poses[s, k + 1, 1], poses[s, k + 1, 2] = x, y, psi


@jit
def _r_factor_kernel(th: FloatArray, n_rl: FloatArray, n_rr: FloatArray, beta: FloatArray,
                     a_y: FloatArray, ref: FloatArray, t_s: float, sqrt_w: FloatArray,
                     r_out: FloatArray, stats: FloatArray) -> None:  # pragma: no cover
    """Per segment: the R factor of ``[sqrt(W) J | sqrt(W) R]`` (3K x 5) by Householder QR.

    ref (N, K+1, 3) are the measured poses (each rollout starts at ref[s, 0]); r_out (N, 5, 5);
    stats (N, 5): weighted cost, unweighted sums of squares of the p_x, p_y, psi residuals, and
    the sum of lag-1 products of the centred weighted residuals along the segment.
    """
    n, k_steps = n_rl.shape
    m = 3 * k_steps
    for s in range(n):
        mat = np.empty((m, 5))
        d = np.empty((3, 6))
        jac = np.zeros((3, 4))
        x, y, psi = ref[s, 0, 0], ref[s, 0, 1], ref[s, 0, 2]
        for k in range(k_steps):
            v, w, c_rl, c_rr = _body(th, n_rl[s, k], n_rr[s, k], a_y[s, k])
            dx, dy, dpsi, ct, st = _increment(psi, v, w, beta[s, k], t_s)
            _increment_derivatives(th, n_rl[s, k], n_rr[s, k], a_y[s, k], v, w, c_rl, c_rr,
                                   dx, dy, ct, st, t_s, d)
            for j in range(4):
                jpsi = jac[2, j]
                jac[0, j] += -dy * jpsi + d[0, 2 + j]
                jac[1, j] += dx * jpsi + d[1, 2 + j]
                jac[2, j] = jpsi + d[2, 2 + j]
            x += dx
            y += dy
            psi += dpsi
            row = 3 * k
            res0 = ref[s, k + 1, 0] - x
            res1 = ref[s, k + 1, 1] - y
            res2 = _wrap(ref[s, k + 1, 2] - psi)
            for i in range(3):
                for j in range(4):
                    mat[row + i, j] = sqrt_w[i] * jac[i, j]
            mat[row, 4] = sqrt_w[0] * res0
            mat[row + 1, 4] = sqrt_w[1] * res1
            mat[row + 2, 4] = sqrt_w[2] * res2
        # residual statistics, before the factorisation overwrites the last column
        cost = 0.0
        ss0 = ss1 = ss2 = 0.0
        mean0 = mean1 = mean2 = 0.0
        for k in range(k_steps):
            a0, a1, a2 = mat[3 * k, 4], mat[3 * k + 1, 4], mat[3 * k + 2, 4]
            cost += a0 * a0 + a1 * a1 + a2 * a2
            mean0 += a0
            mean1 += a1
            mean2 += a2
            ss0 += (a0 / sqrt_w[0]) ** 2
            ss1 += (a1 / sqrt_w[1]) ** 2
            ss2 += (a2 / sqrt_w[2]) ** 2
        mean0 /= k_steps
        mean1 /= k_steps
        mean2 /= k_steps
        lagged = 0.0
        for k in range(1, k_steps):
            lagged += ((mat[3 * k, 4] - mean0) * (mat[3 * k - 3, 4] - mean0)
                       + (mat[3 * k + 1, 4] - mean1) * (mat[3 * k - 2, 4] - mean1)
                       + (mat[3 * k + 2, 4] - mean2) * (mat[3 * k - 1, 4] - mean2))
        stats[s, 0], stats[s, 1], stats[s, 2], stats[s, 3], stats[s, 4] = (cost, ss0, ss1, ss2,
                                                                           lagged)
        _householder_r(mat, r_out[s])


@jit(inline=True)
def _householder_r(mat: FloatArray, r: FloatArray) -> None:  # pragma: no cover
    """Upper-triangular R (n x n) of the QR factorisation of mat (m x n), overwriting mat."""
    m, ncol = mat.shape
    for j in range(ncol):
        norm2 = 0.0
        for i in range(j, m):
            norm2 += mat[i, j] * mat[i, j]
        norm = math.sqrt(norm2)
        if norm == 0.0:
            continue
        alpha = -norm if mat[j, j] >= 0.0 else norm
        mat[j, j] -= alpha                         # v = x - alpha e1, stored in place
        vnorm2 = norm2 - 2.0 * alpha * (mat[j, j] + alpha) + alpha * alpha
        if vnorm2 > 0.0:
            for c in range(j + 1, ncol):
                dot = 0.0
                for i in range(j, m):
                    dot += mat[i, j] * mat[i, c]
                f = 2.0 * dot / vnorm2
                for i in range(j, m):
                    mat[i, c] -= f * mat[i, j]
        mat[j, j] = alpha
    for i in range(ncol):
        for j in range(ncol):
            r[i, j] = mat[i, j] if j >= i and i < m else 0.0


@jit
def _step_jacobian_kernel(th: FloatArray, n_rl: FloatArray, n_rr: FloatArray, beta: FloatArray,
                          a_y: FloatArray, poses: FloatArray, t_s: float, a_out: FloatArray,
                          b_out: FloatArray) -> None:  # pragma: no cover
    """A_k = df/dx (N, K, 3, 3) and B_k = df/d[n_rl, n_rr] (N, K, 3, 2) around poses (N, K+1, 3)."""
    n, k_steps = n_rl.shape
    for s in range(n):
        d = np.empty((3, 6))
        for k in range(k_steps):
            v, w, c_rl, c_rr = _body(th, n_rl[s, k], n_rr[s, k], a_y[s, k])
            dx, dy, _, ct, st = _increment(poses[s, k, 2], v, w, beta[s, k], t_s)
            _increment_derivatives(th, n_rl[s, k], n_rr[s, k], a_y[s, k], v, w, c_rl, c_rr,
                                   dx, dy, ct, st, t_s, d)
            for i in range(3):
                for j in range(3):
                    a_out[s, k, i, j] = 1.0 if i == j else 0.0
                b_out[s, k, i, 0] = d[i, 0]
                b_out[s, k, i, 1] = d[i, 1]
            a_out[s, k, 0, 2] = -dy
            a_out[s, k, 1, 2] = dx


def rollout_with_jacobian(theta: FloatArray | Parameters, u: Inputs, x0: FloatArray,
                          t_s: float) -> tuple[FloatArray, FloatArray]:
    """Rollout and its Jacobian with respect to theta, propagated along the rollout.

    Returns
    -------
    poses : ndarray, shape (..., K+1, 3)
    jac : ndarray, shape (..., K+1, 3, 4)
        ``jac[..., k, i, j] = d poses[..., k, i] / d theta[j]``; zero at k = 0 (x0 is measured).
    """
    lead, (n_rl, n_rr, beta, a_y) = _as_batch(u)
    n, k = n_rl.shape
    poses = np.empty((n, k + 1, 3))
    jac = np.empty((n, k + 1, 3, 4))
    _jacobian_kernel(_theta(theta), n_rl, n_rr, beta, a_y, _flat(x0, (*lead, 3)).reshape(n, 3),
                     float(t_s), poses, jac)
    return poses.reshape(*lead, k + 1, 3), jac.reshape(*lead, k + 1, 3, 4)


def segment_r_factors(theta: FloatArray | Parameters, u: Inputs, reference: FloatArray,
                      t_s: float, weights: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The Gauss-Newton least-squares problem of each segment, reduced to a 5x5 R factor.

    Parameters
    ----------
    u : Inputs with arrays of shape (N, K)
    reference : ndarray, shape (N, K+1, 3), the measured poses; each rollout starts at the first
    weights : ndarray, shape (3,), W per sample (METHOD 3)

    Returns
    -------
    r : ndarray, shape (N, 5, 5)
        Upper-triangular R of ``[sqrt(W) J_s | sqrt(W) R_s] = Q R`` for each segment s, with
        J_s = d y^ / d theta and R_s = y~ - y^ (heading residuals wrapped) over its K samples.
    stats : ndarray, shape (N, 5)
        Weighted cost, unweighted sums of squares of the p_x, p_y, psi residuals, and the sum of
        lag-1 products of the centred weighted residuals.
    """
    _, (n_rl, n_rr, beta, a_y) = _as_batch(u)
    n = n_rl.shape[0]
    r = np.empty((n, 5, 5))
    stats = np.empty((n, 5))
    _r_factor_kernel(_theta(theta), n_rl, n_rr, beta, a_y,
                     np.ascontiguousarray(reference, dtype=np.float64), float(t_s),
                     np.sqrt(np.asarray(weights, dtype=np.float64)), r, stats)
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
    a = np.empty((n, k, 3, 3))
    b = np.empty((n, k, 3, 2))
    _step_jacobian_kernel(_theta(theta), n_rl, n_rr, beta, a_y,
                          _flat(poses, (*lead, k + 1, 3)).reshape(n, k + 1, 3), float(t_s), a, b)
    return StepJacobians(A=a.reshape(*lead, k, 3, 3), B=b.reshape(*lead, k, 3, 2))
