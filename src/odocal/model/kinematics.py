"""METHOD 1: the wheel-odometry model's rollouts, on numpy, and the model run backwards.

State ``x_k = [p_x, p_y, psi]`` (m, m, rad); inputs ``u_k = [n_rl, n_rr, beta, a_y]``
(rev/s, rev/s, rad, m/s^2); parameters ``theta = [c_e, c_d, t_r, d]`` (m, m, m, m per m/s^2).
The equations are those of :mod:`odocal.model.step`, run here on whole arrays: a rollout is a
cumulative sum (the heading of (2b) summed, then the steps of (1) along it), vectorised over
time and segments. The model run backwards, the wheel revolutions a step's motion implies
(:func:`inverse_revolutions`, with (1) inverted by :func:`motion_increments`), serves the
default errors-in-variables estimator's checks and exports. The segment methods' rollouts
with Jacobians are in :mod:`odocal.model.jacobians`.

The paper prints ``h = psi + w/2 + beta``; the intended midpoint heading is ``psi + w t_s/2 + beta``
(with ``w/2`` a car at 10 m/s turning at 0.5 rad/s would be rotated by a quarter radian per 25 ms
step), and that is what odocal uses.

**What else depends on the sizes.** Changing the vehicle model means changing
:mod:`odocal.model.step`, and: the compensation QP's solvers
(:mod:`odocal.estimators.compensation.riccati`, :mod:`.structured`) are written for 3 states and
2 controlled inputs (the stage layout ``[dn (2), dx (3)]``, fixed loops over 3 and 5);
the layout (:data:`odocal.model.vehicle.MODEL`, :mod:`odocal.model.layout`) sizes every
covariance.
"""

from __future__ import annotations

import numpy as np

from odocal.arrays import FloatArray, IntArray
from odocal.model import step
from odocal.model.layout import REAR_AXLE
from odocal.model.parameters import Inputs, Parameters


def _flat(values: FloatArray | float, shape: tuple[int, ...]) -> FloatArray:
    """A C-contiguous float64 array of ``shape``."""
    return np.ascontiguousarray(np.broadcast_to(np.asarray(values, dtype=np.float64), shape))


def _theta(theta: FloatArray | Parameters) -> FloatArray:
    if isinstance(theta, Parameters):
        return theta.as_array()
    return np.ascontiguousarray(theta, dtype=np.float64).reshape(REAR_AXLE.size)


def circumferences(theta: FloatArray, a_y: FloatArray) -> tuple[FloatArray, FloatArray]:
    """(3a), (3b): the actual rear-left and rear-right circumferences, m."""
    c_rl, c_rr = step.circumferences(_theta(theta), np.asarray(a_y, dtype=np.float64))
    return np.asarray(c_rl), np.asarray(c_rr)


def body_rates(theta: FloatArray, n_rl: FloatArray, n_rr: FloatArray,
               a_y: FloatArray) -> tuple[FloatArray, FloatArray]:
    """(2a), (2b): longitudinal speed v (m/s) and yaw rate w (rad/s)."""
    shape = np.broadcast_shapes(np.shape(n_rl), np.shape(n_rr), np.shape(a_y))
    v, w, _, _ = step.body(_theta(theta), *(_flat(x, shape) for x in (n_rl, n_rr, a_y)))
    return np.asarray(v), np.asarray(w)


def wheel_rates_for(theta: FloatArray, v: FloatArray, w: FloatArray,
                    a_y: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Inverse of :func:`body_rates`: the wheel rates (rev/s) that give speed v and yaw rate w."""
    c_rl, c_rr = circumferences(theta, np.broadcast_to(a_y, np.broadcast_shapes(
        np.shape(v), np.shape(w), np.shape(a_y))))
    half = 0.5 * REAR_AXLE.value(_theta(theta), REAR_AXLE.track) * np.asarray(w)
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
    start = _flat(x0, (*lead, 3)).reshape(n, 3)
    v, w, _, _ = step.body(_theta(theta), n_rl, n_rr, a_y)
    # the heading before each step: a cumulative sum of (1)'s w t_s from the initial heading
    turn = np.cumsum(w * t_s, axis=1)
    psi = start[:, 2:3] + turn
    dx, dy, _, _, _ = step.increment(psi - w * t_s, v, w, beta, float(t_s))
    poses = np.empty((n, k + 1, 3))
    poses[:, 0] = start
    poses[:, 1:, 0] = start[:, 0:1] + np.cumsum(dx, axis=1)
    poses[:, 1:, 1] = start[:, 1:2] + np.cumsum(dy, axis=1)
    poses[:, 1:, 2] = psi
    return poses.reshape(*lead, k + 1, 3)


def midpoint_heading(psi: FloatArray, dpsi: FloatArray,
                     beta: FloatArray | float = 0.0) -> FloatArray:
    """(1): the direction a step (or a stretch) of turn ``dpsi`` from heading ``psi`` moves
    along, ``h = psi + dpsi / 2 + beta``."""
    return np.asarray(psi) + 0.5 * np.asarray(dpsi) + beta


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
    h = midpoint_heading(psi[:-1], dpsi, beta[:-1])
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
    out = step.inverse_step(_theta(theta), *(_flat(x, (m,)) for x in (ds, dpsi, a_y)))
    n = REAR_AXLE.size
    revs = np.column_stack(out[:2])
    jac = np.stack([np.column_stack(out[2:2 + n]), np.column_stack(out[2 + n:2 + 2 * n])],
                   axis=1)
    return revs, jac


def wrap_angle(angle: FloatArray) -> FloatArray:
    """Wrap to (-pi, pi]."""
    wrapped = np.remainder(angle + np.pi, 2.0 * np.pi) - np.pi
    return np.where(wrapped == -np.pi, np.pi, wrapped)


def rollout_ragged(theta: FloatArray | Parameters, u: Inputs, x0: FloatArray,
                   steps: IntArray, t_s: float) -> FloatArray:
    """Roll out many segments of different lengths stored one after another.

    Parameters
    ----------
    theta : ndarray, shape (4,), or (P, 4) for P parameter sets at once
    u : Inputs with arrays of shape (L,), ``L = steps.sum()``; segment after segment.
    x0 : ndarray, shape (S, 3), the initial pose of each segment
    steps : ndarray of int, shape (S,)

    Returns
    -------
    poses : ndarray, shape (L, 3), or (P, L, 3)
        The pose after each step: row j is the pose that input sample j leads to.
    """
    steps = np.ascontiguousarray(steps, dtype=np.int64)
    size = int(steps.sum())
    first = np.concatenate([[0], np.cumsum(steps)[:-1]]).astype(np.int64)
    start = _flat(x0, (steps.shape[0], 3))
    n_rl, n_rr, beta, a_y = (_flat(getattr(u, f), (size,)) for f in ("n_rl", "n_rr", "beta",
                                                                      "a_y"))
    thetas = theta.as_array() if isinstance(theta, Parameters) else np.asarray(theta, float)
    # parameter sets along a leading axis: each of theta's four entries a (P, 1) column
    n = REAR_AXLE.size
    th = thetas.reshape(n) if thetas.ndim == 1 else thetas.reshape(-1, n).T[:, :, None]
    v, w, _, _ = step.body(th, n_rl, n_rr, a_y)

    def running(x: FloatArray, x0: FloatArray) -> FloatArray:
        """``x0`` of each segment plus the cumulative sum of ``x`` (along the last axis),
        restarting at every segment's first step."""
        total = np.cumsum(x, axis=-1)
        total -= np.repeat(total[..., first] - x[..., first] - x0, steps, axis=-1)
        return total

    dpsi = w * t_s
    psi = running(dpsi, start[:, 2])
    dx, dy, _, _, _ = step.increment(psi - dpsi, v, w, beta, float(t_s))
    return np.stack([running(dx, start[:, 0]), running(dy, start[:, 1]), psi], axis=-1)
