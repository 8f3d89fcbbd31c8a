"""The model step, equations (1)-(3), their derivatives, and the step run backwards: written once.

Plain Python on numbers: the same functions run on whole numpy arrays (every rollout of
:mod:`odocal.model.kinematics` and every Jacobian of :mod:`odocal.model.jacobians`, vectorised
over time and segments: nothing of the model is compiled) and, compiled by numba, on single
numbers (:mod:`odocal.model._jit` keys such kernels on this file). Only :func:`wrap` (a branch)
is for single numbers only; :func:`increment_derivatives` writes into an array ``out`` of shape
(3, 6, ...).

    (3a) c_rl = c_e + c_d/2 + d a_y          (3b) c_rr = c_e - c_d/2 - d a_y
    (2a) v = (n_rl c_rl + n_rr c_rr) / 2     (2b) w = (n_rr c_rr - n_rl c_rl) / t_r
    (1)  p+ = p + v t_s [cos h, sin h],  h = psi + w t_s / 2 + beta;   psi+ = psi + w t_s
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

#: A float, or a numpy array of them.
Number = Any


def circumferences(th: Number, a_y: Number) -> tuple[Number, Number]:
    """(3a), (3b): c_rl, c_rr."""
    return th[0] + 0.5 * th[1] + th[3] * a_y, th[0] - 0.5 * th[1] - th[3] * a_y


def body(th: Number, n_rl: Number, n_rr: Number,
         a_y: Number) -> tuple[Number, Number, Number, Number]:
    """(2a), (2b): v, w, and the circumferences c_rl, c_rr."""
    c_rl, c_rr = circumferences(th, a_y)
    s_rl = n_rl * c_rl
    s_rr = n_rr * c_rr
    return 0.5 * (s_rl + s_rr), (s_rr - s_rl) / th[2], c_rl, c_rr


def increment(psi: Number, v: Number, w: Number, beta: Number,
              t_s: Number) -> tuple[Number, Number, Number, Number, Number]:
    """(1): the pose increment (dx, dy, dpsi) and t_s cos h, t_s sin h."""
    h = psi + 0.5 * w * t_s + beta
    ct = t_s * np.cos(h)
    st = t_s * np.sin(h)
    return v * ct, v * st, w * t_s, ct, st


def increment_derivatives(th: Number, n_rl: Number, n_rr: Number, a_y: Number, v: Number,
                          w: Number, c_rl: Number, c_rr: Number, dx: Number, dy: Number,
                          ct: Number, st: Number, t_s: Number, out: Number) -> None:
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


def wrap(angle: Number) -> Number:
    """Wrap to (-pi, pi]."""
    r = angle - 2.0 * math.pi * math.floor((angle + math.pi) / (2.0 * math.pi))
    if r <= -math.pi:
        r += 2.0 * math.pi
    return r


def inverse_step(th: Number, ds: Number, dpsi: Number,
                  a_y: Number) -> tuple[Number, ...]:
    """(1)-(3) inverted: the wheel revolutions (rl, rr) a step of ``ds`` along track and ``dpsi``
    of heading take, and their derivatives with respect to theta (rl's four, then rr's).

    From (2): n_rl c_rl t_s = v t_s - (t_r / 2) w t_s and n_rr c_rr t_s = v t_s + (t_r / 2) w t_s,
    with v t_s = ds and w t_s = dpsi by (1).
    """
    c_rl, c_rr = circumferences(th, a_y)
    u_rl = (ds - 0.5 * th[2] * dpsi) / c_rl
    u_rr = (ds + 0.5 * th[2] * dpsi) / c_rr
    return (u_rl, u_rr, -u_rl / c_rl, -0.5 * u_rl / c_rl, -0.5 * dpsi / c_rl, -a_y * u_rl / c_rl,
            -u_rr / c_rr, 0.5 * u_rr / c_rr, 0.5 * dpsi / c_rr, a_y * u_rr / c_rr)
