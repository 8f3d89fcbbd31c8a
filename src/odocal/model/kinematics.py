"""METHOD 1: the wheel-odometry model, its rollouts and their derivatives, in one place.

State ``x_k = [p_x, p_y, psi]`` (m, m, rad); inputs ``u_k = [n_rl, n_rr, beta, a_y]``
(rev/s, rev/s, rad, m/s^2); parameters ``theta = [c_e, c_d, t_r, d]`` (m, m, m, m per m/s^2)::

    (3a) c_rl = c_e + c_d/2 + d a_y          (3b) c_rr = c_e - c_d/2 - d a_y
    (2a) v = (n_rl c_rl + n_rr c_rr) / 2     (2b) w = (n_rr c_rr - n_rl c_rl) / t_r
    (1)  p+ = p + v t_s [cos h, sin h],  h = psi + w t_s / 2 + beta;   psi+ = psi + w t_s

The paper prints ``h = psi + w/2 + beta``; the intended midpoint heading is ``psi + w t_s/2 + beta``
(with ``w/2`` a car at 10 m/s turning at 0.5 rad/s would be rotated by a quarter radian per 25 ms
step), and that is what odocal uses.

**One model step.** Equations (1)-(3) are written once, in :func:`_body` and :func:`_increment`,
and their derivatives once, in :func:`_increment_derivatives` (with respect to the wheel rates
and theta, holding the heading fixed; the derivative with respect to the heading is
``d(p+)/d psi = [-dy, dx]``). Every rollout is built from these compiled pieces: the plain rollout
(:func:`rollout`, :func:`rollout_ragged`: validation, simulation, plots), the Gauss-Newton
linearisation (:func:`segment_r_factors`), the QP's step Jacobians (:func:`step_jacobians`). A
Jacobian ``J = d x_k / d p``
propagates as ``J+ = A_k J + B_k`` with ``A_k = I + [0, 0, -dy; 0, 0, dx; 0, 0, 0]``: a cumulative
sum along the rollout, computed in one compiled pass per segment. The model run backwards, the
wheel revolutions a step's motion implies (:func:`_inverse_step`, :func:`inverse_revolutions`,
with (1) inverted by :func:`motion_increments`), serves the default errors-in-variables estimator
(:mod:`odocal.estimators.inverse`) and the online calibrator.

**What else depends on the sizes.** Changing the vehicle model means changing this module, and:
the compensation QP's solvers (:mod:`odocal.estimators.compensation.riccati`, :mod:`.structured`)
are written
for 3 states and 2 controlled inputs (the stage layout ``[dn (2), dx (3)]``, fixed loops over 3
and 5); :data:`PARAMETER_NAMES` (4 parameters) sizes every covariance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import prange
from numpy.typing import NDArray

from odocal.model._jit import jit
from odocal.model.parameters import Inputs, Parameters

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

# --------------------------------------------------------------------------------------------
# The model step: equations (1)-(3) and their derivatives, written once.
# --------------------------------------------------------------------------------------------

@jit(inline=True)
def _circumferences(th: FloatArray, a_y: float) -> tuple[float, float]:  # pragma: no cover
    """(3a), (3b): c_rl, c_rr."""
    return th[0] + 0.5 * th[1] + th[3] * a_y, th[0] - 0.5 * th[1] - th[3] * a_y


@jit(inline=True)
def _body(th: FloatArray, n_rl: float, n_rr: float,
          a_y: float) -> tuple[float, float, float, float]:  # pragma: no cover
    """(2a), (2b): v, w, and the circumferences c_rl, c_rr."""
    c_rl, c_rr = _circumferences(th, a_y)
    s_rl = n_rl * c_rl
    s_rr = n_rr * c_rr
    return 0.5 * (s_rl + s_rr), (s_rr - s_rl) / th[2], c_rl, c_rr


@jit(inline=True)
def _increment(psi: float, v: float, w: float, beta: float,
               t_s: float) -> tuple[float, float, float, float, float]:  # pragma: no cover
    """(1): the pose increment (dx, dy, dpsi) and t_s cos h, t_s sin h."""
    h = psi + 0.5 * w * t_s + beta
    ct = t_s * math.cos(h)
    st = t_s * math.sin(h)
    return v * ct, v * st, w * t_s, ct, st


@jit(inline=True)
def _increment_derivatives(th: FloatArray, n_rl: float, n_rr: float, a_y: float, v: float,
                           w: float, c_rl: float, c_rr: float, dx: float, dy: float, ct: float,
                           st: float, t_s: float, out: FloatArray) -> None:  # pragma: no cover
    """d(dx, dy, dpsi) / d[n_rl, n_rr, c_e, c_d, t_r, d] at a fixed heading, into out (3, 6).

    With dh = t_s/2 dw:  d(dx) = t_s cos h dv - dy dh,  d(dy) = t_s sin h dv + dx dh,
    d(dpsi) = t_s dw, where (from (2), (3))
    dv/d[n_rl, n_rr, c_e, c_d, t_r, d] = [c_rl/2, c_rr/2, (n_rl+n_rr)/2, (n_rl-n_rr)/4, 0,
                                         a_y (n_rl-n_rr)/2],
    dw/d[...] = [-c_rl, c_rr, n_rr-n_rl, -(n_rl+n_rr)/2, -w t_r, -a_y (n_rl+n_rr)] / t_r.
    """
    inv = 1.0 / th[2]
    n_sum = n_rl + n_rr
    n_diff = n_rl - n_rr
    dv = (0.5 * c_rl, 0.5 * c_rr, 0.5 * n_sum, 0.25 * n_diff, 0.0, 0.5 * a_y * n_diff)
    dw = (-c_rl * inv, c_rr * inv, -n_diff * inv, -0.5 * n_sum * inv, -w * inv,
          -a_y * n_sum * inv)
    for p in range(6):
        dh = 0.5 * t_s * dw[p]
        out[0, p] = ct * dv[p] - dy * dh
        out[1, p] = st * dv[p] + dx * dh
        out[2, p] = t_s * dw[p]


@jit(inline=True)
def _wrap(angle: float) -> float:  # pragma: no cover
    """Wrap to (-pi, pi]."""
    r = angle - 2.0 * math.pi * math.floor((angle + math.pi) / (2.0 * math.pi))
    if r <= -math.pi:
        r += 2.0 * math.pi
    return r


# --------------------------------------------------------------------------------------------
# Compiled rollouts built from the step.
# --------------------------------------------------------------------------------------------

@jit(parallel=True)
def _rollout_kernel(th: FloatArray, n_rl: FloatArray, n_rr: FloatArray, beta: FloatArray,
                    a_y: FloatArray, x0: FloatArray, t_s: float,
                    poses: FloatArray) -> None:  # pragma: no cover
    """Rows of (N, K) inputs from x0 (N, 3) into poses (N, K+1, 3)."""
    n, k_steps = n_rl.shape
    for s in prange(n):
        x, y, psi = x0[s, 0], x0[s, 1], x0[s, 2]
        poses[s, 0, 0], poses[s, 0, 1], poses[s, 0, 2] = x, y, psi
        for k in range(k_steps):
            v, w, _, _ = _body(th, n_rl[s, k], n_rr[s, k], a_y[s, k])
            dx, dy, dpsi, _, _ = _increment(psi, v, w, beta[s, k], t_s)
            x += dx
            y += dy
            psi += dpsi
            poses[s, k + 1, 0], poses[s, k + 1, 1], poses[s, k + 1, 2] = x, y, psi


@jit(parallel=True)
def _ragged_kernel(th: FloatArray, n_rl: FloatArray, n_rr: FloatArray, beta: FloatArray,
                   a_y: FloatArray, x0: FloatArray, first: IntArray, steps: IntArray,
                   t_s: float, poses: FloatArray) -> None:  # pragma: no cover
    """Segments stored one after another (flat inputs); poses (L, 3) after each step."""
    for s in prange(steps.shape[0]):
        x, y, psi = x0[s, 0], x0[s, 1], x0[s, 2]
        for j in range(first[s], first[s] + steps[s]):
            v, w, _, _ = _body(th, n_rl[j], n_rr[j], a_y[j])
            dx, dy, dpsi, _, _ = _increment(psi, v, w, beta[j], t_s)
            x += dx
            y += dy
            psi += dpsi
            poses[j, 0], poses[j, 1], poses[j, 2] = x, y, psi


@jit(parallel=True)
def _jacobian_kernel(th: FloatArray, n_rl: FloatArray, n_rr: FloatArray, beta: FloatArray,
                     a_y: FloatArray, x0: FloatArray, t_s: float, poses: FloatArray,
                     jac: FloatArray) -> None:  # pragma: no cover
    """Rollout and d poses / d theta at every step: poses (N, K+1, 3), jac (N, K+1, 3, 4)."""
    n, k_steps = n_rl.shape
    for s in prange(n):
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


@jit(parallel=True)
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
    for s in prange(n):
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


@jit(parallel=True)
def _step_jacobian_kernel(th: FloatArray, n_rl: FloatArray, n_rr: FloatArray, beta: FloatArray,
                          a_y: FloatArray, poses: FloatArray, t_s: float, a_out: FloatArray,
                          b_out: FloatArray) -> None:  # pragma: no cover
    """A_k = df/dx (N, K, 3, 3) and B_k = df/d[n_rl, n_rr] (N, K, 3, 2) around poses (N, K+1, 3)."""
    n, k_steps = n_rl.shape
    for s in prange(n):
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


@jit(inline=True)
def _inverse_step(th: FloatArray, ds: float, dpsi: float, a_y: float,
                  d: FloatArray) -> tuple[float, float]:  # pragma: no cover
    """(1)-(3) inverted: the wheel revolutions (rl, rr) a step of ``ds`` along track and ``dpsi``
    of heading take, and their derivatives d (2, 4) with respect to theta.

    From (2): n_rl c_rl t_s = v t_s - (t_r / 2) w t_s and n_rr c_rr t_s = v t_s + (t_r / 2) w t_s,
    with v t_s = ds and w t_s = dpsi by (1).
    """
    c_rl, c_rr = _circumferences(th, a_y)
    u_rl = (ds - 0.5 * th[2] * dpsi) / c_rl
    u_rr = (ds + 0.5 * th[2] * dpsi) / c_rr
    d[0, 0] = -u_rl / c_rl
    d[0, 1] = -0.5 * u_rl / c_rl
    d[0, 2] = -0.5 * dpsi / c_rl
    d[0, 3] = -a_y * u_rl / c_rl
    d[1, 0] = -u_rr / c_rr
    d[1, 1] = 0.5 * u_rr / c_rr
    d[1, 2] = 0.5 * dpsi / c_rr
    d[1, 3] = a_y * u_rr / c_rr
    return u_rl, u_rr


@jit
def _inverse_kernel(th: FloatArray, ds: FloatArray, dpsi: FloatArray, a_y: FloatArray,
                    revs: FloatArray, jac: FloatArray) -> None:  # pragma: no cover
    d = np.empty((2, 4))
    for k in range(ds.shape[0]):
        revs[k, 0], revs[k, 1] = _inverse_step(th, ds[k], dpsi[k], a_y[k], d)
        jac[k] = d


@jit
def _body_rates_kernel(th: FloatArray, n_rl: FloatArray, n_rr: FloatArray, a_y: FloatArray,
                       v: FloatArray, w: FloatArray, c_rl: FloatArray,
                       c_rr: FloatArray) -> None:  # pragma: no cover
    for i in range(n_rl.shape[0]):
        v[i], w[i], c_rl[i], c_rr[i] = _body(th, n_rl[i], n_rr[i], a_y[i])


# --------------------------------------------------------------------------------------------
# The public, array-shaped interface.
# --------------------------------------------------------------------------------------------

def _flat(values: FloatArray | float, shape: tuple[int, ...]) -> FloatArray:
    """A C-contiguous float64 array of ``shape`` (one compiled signature per kernel)."""
    return np.ascontiguousarray(np.broadcast_to(np.asarray(values, dtype=np.float64), shape))


def _theta(theta: FloatArray | Parameters) -> FloatArray:
    if isinstance(theta, Parameters):
        return theta.as_array()
    return np.ascontiguousarray(theta, dtype=np.float64).reshape(4)


def circumferences(theta: FloatArray, a_y: FloatArray) -> tuple[FloatArray, FloatArray]:
    """(3a), (3b): the actual rear-left and rear-right circumferences, m."""
    _, _, c_rl, c_rr = _rates(theta, np.zeros_like(a_y, dtype=np.float64),
                              np.zeros_like(a_y, dtype=np.float64), a_y)
    return c_rl, c_rr


def _rates(theta: FloatArray, n_rl: FloatArray, n_rr: FloatArray,
           a_y: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    shape = np.broadcast_shapes(np.shape(n_rl), np.shape(n_rr), np.shape(a_y))
    size = int(np.prod(shape))
    out = [np.empty(size) for _ in range(4)]
    _body_rates_kernel(_theta(theta), _flat(n_rl, shape).reshape(size),
                       _flat(n_rr, shape).reshape(size), _flat(a_y, shape).reshape(size), *out)
    v, w, c_rl, c_rr = (o.reshape(shape) for o in out)
    return v, w, c_rl, c_rr


def body_rates(theta: FloatArray, n_rl: FloatArray, n_rr: FloatArray,
               a_y: FloatArray) -> tuple[FloatArray, FloatArray]:
    """(2a), (2b): longitudinal speed v (m/s) and yaw rate w (rad/s)."""
    v, w, _, _ = _rates(theta, n_rl, n_rr, a_y)
    return v, w


def wheel_rates_for(theta: FloatArray, v: FloatArray, w: FloatArray,
                    a_y: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Inverse of :func:`body_rates`: the wheel rates (rev/s) that give speed v and yaw rate w."""
    c_rl, c_rr = circumferences(theta, np.broadcast_to(a_y, np.broadcast_shapes(
        np.shape(v), np.shape(w), np.shape(a_y))))
    half = 0.5 * _theta(theta)[2] * np.asarray(w)
    return (np.asarray(v) - half) / c_rl, (np.asarray(v) + half) / c_rr


def _as_batch(u: Inputs) -> tuple[tuple[int, ...], list[FloatArray]]:
    """Inputs of shape (..., K) as four C-contiguous (N, K) arrays, and the leading shape."""
    shape = u.shape
    lead, k = shape[:-1], shape[-1]
    n = int(np.prod(lead)) if lead else 1
    arrays = [_flat(getattr(u, f), shape).reshape(n, k) for f in ("n_rl", "n_rr", "beta", "a_y")]
    return lead, arrays


def rollout(theta: FloatArray | Parameters, u: Inputs, x0: FloatArray, t_s: float) -> FloatArray:
    """Roll the model out from ``x0`` over the inputs.

    Parameters
    ----------
    theta : ndarray, shape (4,)
    u : Inputs with arrays of shape (..., K)
    x0 : ndarray, shape (..., 3)
        Initial pose of every segment.
    t_s : float
        Sampling time, s.

    Returns
    -------
    poses : ndarray, shape (..., K+1, 3)
        ``poses[..., 0, :] == x0``.
    """
    lead, (n_rl, n_rr, beta, a_y) = _as_batch(u)
    n, k = n_rl.shape
    poses = np.empty((n, k + 1, 3))
    _rollout_kernel(_theta(theta), n_rl, n_rr, beta, a_y, _flat(x0, (*lead, 3)).reshape(n, 3),
                    float(t_s), poses)
    return poses.reshape(*lead, k + 1, 3)


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


def motion_increments(x: FloatArray, y: FloatArray, psi: FloatArray,
                      beta: FloatArray) -> tuple[FloatArray, FloatArray]:
    """(1) inverted: what each step of a pose sequence moved, along track and in heading.

    Parameters
    ----------
    x, y, psi : ndarray, shape (M,), poses (psi unwrapped)
    beta : ndarray, shape (M,), sideslip

    Returns
    -------
    ds : ndarray, shape (M-1,)
        The step's displacement along the direction of travel ``h = psi + dpsi/2 + beta``
        (``v t_s`` in (1)).
    dpsi : ndarray, shape (M-1,)
        The heading increment (``w t_s``).
    """
    dpsi = np.diff(psi)
    h = psi[:-1] + 0.5 * dpsi + beta[:-1]
    return np.diff(x) * np.cos(h) + np.diff(y) * np.sin(h), dpsi


def inverse_revolutions(theta: FloatArray | Parameters, ds: FloatArray, dpsi: FloatArray,
                        a_y: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The wheel revolutions each step's motion implies, and their Jacobian in theta.

    Parameters
    ----------
    ds, dpsi : ndarray, shape (M,), from :func:`motion_increments`
    a_y : ndarray, shape (M,), lateral acceleration of each step

    Returns
    -------
    revs : ndarray, shape (M, 2), revolutions of the rear-left and rear-right wheel
        (``n_rl t_s``, ``n_rr t_s``)
    jac : ndarray, shape (M, 2, 4), d revs / d theta
    """
    m = int(np.shape(ds)[0])
    revs = np.empty((m, 2))
    jac = np.empty((m, 2, 4))
    _inverse_kernel(_theta(theta), _flat(ds, (m,)), _flat(dpsi, (m,)), _flat(a_y, (m,)), revs, jac)
    return revs, jac


def wrap_angle(angle: FloatArray) -> FloatArray:
    """Wrap to (-pi, pi]."""
    wrapped = np.remainder(angle + np.pi, 2.0 * np.pi) - np.pi
    return np.where(wrapped == -np.pi, np.pi, wrapped)


def pose_residuals(reference: FloatArray, predicted: FloatArray) -> FloatArray:
    """``reference - predicted`` with the heading residual wrapped to (-pi, pi]."""
    r = reference - predicted
    r[..., 2] = wrap_angle(r[..., 2])
    return r


def rollout_ragged(theta: FloatArray | Parameters, u: Inputs, x0: FloatArray,
                   steps: NDArray[np.int64], t_s: float, *,
                   segment: NDArray[np.int64] | None = None) -> FloatArray:
    """Roll out many segments of different lengths stored one after another.

    Parameters
    ----------
    u : Inputs with arrays of shape (L,), ``L = steps.sum()``; segment after segment.
    x0 : ndarray, shape (S, 3), the initial pose of each segment
    steps : ndarray of int, shape (S,)
    segment : unused; kept for callers that pass the sample-to-segment map

    Returns
    -------
    poses : ndarray, shape (L, 3)
        The pose after each step: row j is the pose that input sample j leads to.
    """
    del segment
    steps = np.ascontiguousarray(steps, dtype=np.int64)
    first = np.zeros(steps.shape[0], dtype=np.int64)
    if steps.shape[0] > 1:
        first[1:] = np.cumsum(steps)[:-1]
    size = int(steps.sum())
    poses = np.empty((size, 3))
    _ragged_kernel(_theta(theta), *(_flat(getattr(u, f), (size,))
                                    for f in ("n_rl", "n_rr", "beta", "a_y")),
                   _flat(x0, (steps.shape[0], 3)), first, steps, float(t_s), poses)
    return poses

