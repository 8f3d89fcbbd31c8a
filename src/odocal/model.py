"""METHOD 1: the wheel-odometry model, its rollout and its Jacobians.

State ``x_k = [p_x, p_y, psi]`` (m, m, rad); inputs ``u_k = [n_rl, n_rr, beta, a_y]``
(rev/s, rev/s, rad, m/s^2); parameters ``theta = [c_e, c_d, t_r, d]`` (m, m, m, m per m/s^2)::

    (3a) c_rl = c_e + c_d/2 + d a_y          (3b) c_rr = c_e - c_d/2 - d a_y
    (2a) v = (n_rl c_rl + n_rr c_rr) / 2     (2b) w = (n_rr c_rr - n_rl c_rl) / t_r
    (1)  p+ = p + v t_s [cos h, sin h],  h = psi + w t_s / 2 + beta;   psi+ = psi + w t_s

A rollout is a cumulative sum over time, so every function here works on arrays of any leading
shape ``(..., K)`` (one segment, or a batch of segments of equal length) without a Python loop.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

#: Names and units of theta, in order.
PARAMETER_NAMES: tuple[str, str, str, str] = ("c_e", "c_d", "t_r", "d")
PARAMETER_UNITS: tuple[str, str, str, str] = ("m", "m", "m", "m/(m/s^2)")
PARAMETER_LABELS: tuple[str, str, str, str] = (
    "effective wheel circumference", "left-right circumference difference", "rear track width",
    "load-transfer coefficient")


@dataclass(frozen=True)
class Parameters:
    """The odometry parameters ``theta = [c_e, c_d, t_r, d]``.

    c_e : effective wheel circumference, m
    c_d : left-right circumference difference (left minus right), m
    t_r : rear track width, m
    d   : load-transfer coefficient, m per m/s^2 of lateral acceleration
    """

    c_e: float
    c_d: float
    t_r: float
    d: float

    def as_array(self) -> FloatArray:
        return np.array([self.c_e, self.c_d, self.t_r, self.d], dtype=np.float64)

    @classmethod
    def from_array(cls, theta: FloatArray | tuple[float, ...] | list[float]) -> Parameters:
        values = np.asarray(theta, dtype=np.float64).reshape(4)
        return cls(*(float(v) for v in values))

    def as_dict(self) -> dict[str, float]:
        return dict(zip(PARAMETER_NAMES, self.as_array().tolist(), strict=True))


@dataclass(frozen=True)
class Inputs:
    """Model inputs of one or many segments, each array of shape ``(..., K)``.

    n_rl, n_rr : wheel rotation rates, rev/s
    beta : sideslip angle, rad
    a_y : lateral acceleration, m/s^2
    """

    n_rl: FloatArray
    n_rr: FloatArray
    beta: FloatArray
    a_y: FloatArray

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(self.n_rl.shape)

    def with_wheel_rates(self, n_rl: FloatArray, n_rr: FloatArray) -> Inputs:
        return Inputs(n_rl=n_rl, n_rr=n_rr, beta=self.beta, a_y=self.a_y)


def circumferences(theta: FloatArray, a_y: FloatArray) -> tuple[FloatArray, FloatArray]:
    """(3a), (3b): the actual rear-left and rear-right circumferences, m."""
    c_e, c_d, _, d = theta
    c_rl = c_e + 0.5 * c_d + d * a_y
    c_rr = c_e - 0.5 * c_d - d * a_y
    return c_rl, c_rr


def body_rates(theta: FloatArray, n_rl: FloatArray, n_rr: FloatArray,
               a_y: FloatArray) -> tuple[FloatArray, FloatArray]:
    """(2a), (2b): longitudinal speed v (m/s) and yaw rate w (rad/s)."""
    c_rl, c_rr = circumferences(theta, a_y)
    s_rl, s_rr = n_rl * c_rl, n_rr * c_rr
    return 0.5 * (s_rl + s_rr), (s_rr - s_rl) / theta[2]


def wheel_rates_for(theta: FloatArray, v: FloatArray, w: FloatArray,
                    a_y: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Inverse of :func:`body_rates`: the wheel rates (rev/s) that give speed v and yaw rate w."""
    c_rl, c_rr = circumferences(theta, a_y)
    half = 0.5 * theta[2] * w
    return (v - half) / c_rl, (v + half) / c_rr


def rate_derivatives(theta: FloatArray, u: Inputs) -> tuple[FloatArray, FloatArray,
                                                             FloatArray, FloatArray]:
    """v, w and their derivatives with respect to theta, shapes (..., K) and (..., K, 4)."""
    v, w = body_rates(theta, u.n_rl, u.n_rr, u.a_y)
    t_r = theta[2]
    n_sum, n_diff = u.n_rl + u.n_rr, u.n_rl - u.n_rr
    dv = np.stack([0.5 * n_sum,                # dv/dc_e
                   0.25 * n_diff,              # dv/dc_d
                   np.zeros_like(v),           # dv/dt_r
                   0.5 * u.a_y * n_diff],      # dv/dd
                  axis=-1)
    dw = np.stack([-n_diff / t_r,              # dw/dc_e = (n_rr - n_rl)/t_r
                   -0.5 * n_sum / t_r,         # dw/dc_d
                   -w / t_r,                   # dw/dt_r
                   -u.a_y * n_sum / t_r],      # dw/dd
                  axis=-1)
    return v, w, dv, dw


def _exclusive_cumsum(values: FloatArray, axis: int) -> FloatArray:
    """out[k] = sum of values[:k] along ``axis``, with one more entry than the input."""
    out_shape = list(values.shape)
    out_shape[axis] += 1
    out = np.zeros(out_shape, dtype=np.float64)
    index: list[slice] = [slice(None)] * values.ndim
    index[axis] = slice(1, None)
    np.cumsum(values, axis=axis, out=out[tuple(index)])
    return out


def rollout(theta: FloatArray, u: Inputs, x0: FloatArray, t_s: float) -> FloatArray:
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
    v, w = body_rates(theta, u.n_rl, u.n_rr, u.a_y)
    return _integrate(v, w, u.beta, x0, t_s)


def _integrate(v: FloatArray, w: FloatArray, beta: FloatArray, x0: FloatArray,
               t_s: float) -> FloatArray:
    psi = x0[..., 2:3] + t_s * _exclusive_cumsum(w, axis=-1)           # (..., K+1)
    heading = psi[..., :-1] + 0.5 * t_s * w + beta                      # (1): psi + w t_s/2 + beta
    step = v * t_s
    poses = np.empty((*v.shape[:-1], v.shape[-1] + 1, 3))
    poses[..., 0] = x0[..., 0:1] + _exclusive_cumsum(step * np.cos(heading), axis=-1)
    poses[..., 1] = x0[..., 1:2] + _exclusive_cumsum(step * np.sin(heading), axis=-1)
    poses[..., 2] = psi
    return poses


def rollout_with_jacobian(theta: FloatArray, u: Inputs, x0: FloatArray,
                          t_s: float) -> tuple[FloatArray, FloatArray]:
    """Rollout and its Jacobian with respect to theta, propagated along the rollout.

    Returns
    -------
    poses : ndarray, shape (..., K+1, 3)
    jac : ndarray, shape (..., K+1, 3, 4)
        ``jac[..., k, i, j] = d poses[..., k, i] / d theta[j]``; zero at k = 0 (x0 is measured).
    """
    v, w, dv, dw = rate_derivatives(theta, u)
    poses = _integrate(v, w, u.beta, x0, t_s)
    heading = poses[..., :-1, 2] + 0.5 * t_s * w + u.beta
    cos_h, sin_h = np.cos(heading), np.sin(heading)
    jac = np.empty((*poses.shape, 4))
    dpsi = t_s * _exclusive_cumsum(dw, axis=-2)                           # (..., K+1, 4)
    dheading = dpsi[..., :-1, :] + 0.5 * t_s * dw                         # (..., K, 4)
    # d(v t_s cos h) = t_s (dv cos h - v sin h dh), and likewise for sin.
    vt = (v * t_s)[..., None]
    jac[..., 0, :] = _exclusive_cumsum(t_s * dv * cos_h[..., None] - vt * sin_h[..., None]
                                       * dheading, axis=-2)
    jac[..., 1, :] = _exclusive_cumsum(t_s * dv * sin_h[..., None] + vt * cos_h[..., None]
                                       * dheading, axis=-2)
    jac[..., 2, :] = dpsi
    return poses, jac


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


def step_jacobians(theta: FloatArray, u: Inputs, poses: FloatArray, t_s: float) -> StepJacobians:
    """(10a): A_k = df/dx and B_k = df/dn around ``poses`` (the trajectory of the inputs ``u``).

    ``poses`` has shape (..., K+1, 3) and ``u`` arrays (..., K); step k maps poses[k] to
    poses[k+1] with u[k].
    """
    v, w = body_rates(theta, u.n_rl, u.n_rr, u.a_y)
    c_rl, c_rr = circumferences(theta, u.a_y)
    heading = poses[..., :-1, 2] + 0.5 * t_s * w + u.beta
    cos_h, sin_h = np.cos(heading), np.sin(heading)
    shape = v.shape
    A = np.zeros((*shape, 3, 3))
    A[..., 0, 0] = A[..., 1, 1] = A[..., 2, 2] = 1.0
    A[..., 0, 2] = -v * t_s * sin_h
    A[..., 1, 2] = v * t_s * cos_h
    # dv/dn = [c_rl/2, c_rr/2]; dw/dn = [-c_rl/t_r, c_rr/t_r]
    dv = np.stack([0.5 * c_rl, 0.5 * c_rr], axis=-1)
    dw = np.stack([-c_rl / theta[2], c_rr / theta[2]], axis=-1)
    half = 0.5 * t_s * v
    B = np.empty((*shape, 3, 2))
    B[..., 0, :] = t_s * (dv * cos_h[..., None] - half[..., None] * sin_h[..., None] * dw)
    B[..., 1, :] = t_s * (dv * sin_h[..., None] + half[..., None] * cos_h[..., None] * dw)
    B[..., 2, :] = t_s * dw
    return StepJacobians(A=A, B=B)


def wrap_angle(angle: FloatArray) -> FloatArray:
    """Wrap to (-pi, pi]."""
    wrapped = np.remainder(angle + np.pi, 2.0 * np.pi) - np.pi
    return np.where(wrapped == -np.pi, np.pi, wrapped)


def pose_residuals(reference: FloatArray, predicted: FloatArray) -> FloatArray:
    """``reference - predicted`` with the heading residual wrapped to (-pi, pi]."""
    r = reference - predicted
    r[..., 2] = wrap_angle(r[..., 2])
    return r


def rollout_ragged(theta: FloatArray, u: Inputs, x0: FloatArray, steps: NDArray[np.int64],
                   t_s: float, *, segment: NDArray[np.int64] | None = None) -> FloatArray:
    """Roll out many segments of different lengths stored one after another.

    Parameters
    ----------
    u : Inputs with arrays of shape (L,), ``L = steps.sum()``; segment after segment.
    x0 : ndarray, shape (S, 3), the initial pose of each segment
    steps : ndarray of int, shape (S,)
    segment : ndarray of int, shape (L,), optional
        Segment number of each input sample (``np.repeat(np.arange(S), steps)``); pass it when
        rolling out the same segments many times.

    Returns
    -------
    poses : ndarray, shape (L, 3)
        The pose after each step: row j is the pose that input sample j leads to.
    """
    if segment is None:
        segment = np.repeat(np.arange(steps.shape[0]), steps)
    first = np.concatenate([[0], np.cumsum(steps)[:-1]]).astype(np.int64)
    v, w = body_rates(theta, u.n_rl, u.n_rr, u.a_y)
    turn = w * t_s
    before = np.cumsum(turn) - turn                       # heading change before each step
    psi = x0[segment, 2] + before - before[first][segment]
    heading = psi + 0.5 * turn + u.beta                   # (1): psi + w t_s / 2 + beta
    length = v * t_s
    poses = np.empty((v.shape[0], 3))
    for axis, trig in ((0, np.cos), (1, np.sin)):
        step = length * trig(heading)
        travelled = np.cumsum(step)
        travelled -= (travelled[first] - step[first])[segment]
        poses[:, axis] = x0[segment, axis] + travelled
    poses[:, 2] = psi + turn
    return poses
