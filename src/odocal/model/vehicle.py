"""The vehicle model as one object: its parameters, its step, the step run backwards, and the
window prediction the default method fits, with their Jacobians.

:data:`MODEL` is the rear axle of METHOD 1. Estimators, checks, the gate, exports and the
report take the parameter layout from it (``MODEL.layout``: names, units, order, roles) and
the equations (``MODEL.step`` is :mod:`odocal.model.step`, run on whole arrays by the segment
methods' Jacobians; ``MODEL.predict`` the window prediction of the default method).

The window prediction
---------------------
A window sums the reference's motion over ``window_s``. The model run backwards (1)-(3) gives
the revolutions each rear wheel turns over a step of ``ds`` along track and ``dpsi`` of
heading::

    n_rl t_s = (ds - t_r dpsi / 2) / c_rl,      n_rr t_s = (ds + t_r dpsi / 2) / c_rr

with ``c_rl = C_l + d a``, ``C_l = c_e + c_d / 2`` (``c_rr = C_r - d a``, ``C_r = c_e - c_d / 2``).
``1 / (C + d a)`` is a geometric series in ``d a / C`` (below 1e-2 for any car), so a window's
revolutions follow from the moments ``sum ds a^j`` and ``sum dpsi a^j`` (``j < SERIES``) for
any theta, to a relative ``(d a / C)^SERIES``: :meth:`RearAxleModel.predict`. It is
:meth:`inverse_step` summed over the window's steps, as ``tests/model`` checks.
"""

from __future__ import annotations

import types

import numpy as np
from numpy.typing import NDArray

from odocal.model import step
from odocal.model.layout import REAR_AXLE, Layout

FloatArray = NDArray[np.float64]

#: Powers of the lateral acceleration the window prediction keeps (the series' terms).
SERIES = 4


class RearAxleModel:
    """The rear axle of METHOD 1, equations (1)-(3).

    layout : the parameters (:data:`~odocal.model.layout.REAR_AXLE`)
    step : the model step, its derivatives and the step run backwards, written once for numpy
        arrays and numba alike (:mod:`odocal.model.step`)
    states, wheels : sizes of the pose ``[p_x, p_y, psi]`` and of the measured inputs
        ``[n_rl, n_rr]``
    """

    layout: Layout = REAR_AXLE
    step: types.ModuleType = step
    states: int = 3
    wheels: int = 2

    @property
    def names(self) -> tuple[str, ...]:
        return self.layout.names

    @property
    def size(self) -> int:
        return self.layout.size

    def index(self, name: str) -> int:
        return self.layout.index(name)

    def inverse_step(self, theta: FloatArray, ds: FloatArray, dpsi: FloatArray,
                     a_y: FloatArray) -> tuple[FloatArray, FloatArray]:
        """The revolutions (M, 2) each step's motion implies and their Jacobian (M, 2, n)."""
        out = self.step.inverse_step(np.asarray(theta, dtype=np.float64),
                                     *(np.asarray(x, dtype=np.float64) for x in (ds, dpsi, a_y)))
        n = self.size
        revs = np.stack([np.asarray(out[0]), np.asarray(out[1])], axis=-1)
        jac = np.stack([np.stack([np.asarray(v) for v in out[2:2 + n]], axis=-1),
                        np.stack([np.asarray(v) for v in out[2 + n:2 + 2 * n]], axis=-1)],
                       axis=-2)
        return revs, jac

    def predict(self, theta: FloatArray, moments: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Each window's revolutions (N, 2) and their Jacobian in theta (N, 2, n), from the
        motion moments ``[along_j, dpsi_j, ...]`` (N, >= 2 SERIES; ``along_j = sum ds a^j``).

        For a wheel with ``C`` (``c_e +- c_d / 2``), ``s`` (+1 left, -1 right) and
        ``e = s d / C``: ``revs = sum_j (-e)^j (A_j - s t_r Q_j / 2) / C``, the series of
        (2)-(3) inverted.
        """
        lay = self.layout
        c_e, c_d = lay.value(theta, lay.scale), lay.value(theta, lay.difference)
        t_r, d = lay.value(theta, lay.track), lay.value(theta, lay.load)
        i_e, i_d, i_t, i_l = (lay.index(n) for n in (lay.scale, lay.difference, lay.track,
                                                     lay.load))
        along, turn = moments[:, :SERIES], moments[:, SERIES:2 * SERIES]
        out = np.empty((moments.shape[0], 2))
        jac = np.zeros((moments.shape[0], 2, lay.size))
        powers = np.arange(SERIES)
        for w, sign in enumerate((1.0, -1.0)):
            big = c_e + 0.5 * sign * c_d
            e = sign * d / big
            coef = (-e) ** powers                               # (-e)^j
            dcoef = -powers * (-e) ** np.maximum(powers - 1, 0)  # d(-e)^j / de
            half = -0.5 * sign * t_r
            combined = along + half * turn                      # M_j = A_j + h Q_j
            series = combined @ coef
            value = series / big
            dseries_de = combined @ dcoef
            out[:, w] = value
            dvalue_dbig = -value / big - dseries_de * e / (big * big)     # de/dC = -e / C
            jac[:, w, i_e] = dvalue_dbig
            jac[:, w, i_d] = 0.5 * sign * dvalue_dbig
            jac[:, w, i_t] = -0.5 * sign * (turn @ coef) / big
            jac[:, w, i_l] = dseries_de * sign / (big * big)              # de/dd = s / C
        return out, jac

    def along_gain(self, theta: FloatArray) -> FloatArray:
        """Each wheel's revolutions per metre of the axle's own travel (2,): ``1 / C`` with
        ``C = c_e +- c_d / 2`` (the first term of :meth:`predict`'s series). A departure that
        moves the axle's distance (a reference point off the axle, wheels ahead of it) acts
        through it."""
        lay = self.layout
        c_e, c_d = lay.value(theta, lay.scale), lay.value(theta, lay.difference)
        return np.array([1.0 / (c_e + 0.5 * c_d), 1.0 / (c_e - 0.5 * c_d)])

    def load_transfer_column(self, theta: FloatArray, moments: FloatArray) -> FloatArray:
        """The windows' revolutions' derivative in the load transfer (N, 2) as if their lateral
        acceleration were the reference's own, ``v w`` (at d = 0: ``-s (A' - s t_r Q' / 2) /
        C^2`` with ``A', Q'`` the moments ``[2 SERIES]``, ``[2 SERIES + 1]``, times ``v w``):
        how a load transfer the a_y column does not show would move them."""
        lay = self.layout
        c_e, c_d = lay.value(theta, lay.scale), lay.value(theta, lay.difference)
        t_r = lay.value(theta, lay.track)
        along, turn = moments[:, 2 * SERIES], moments[:, 2 * SERIES + 1]
        out = np.empty((moments.shape[0], 2))
        for w, sign in enumerate((1.0, -1.0)):
            big = c_e + 0.5 * sign * c_d
            out[:, w] = -sign * (along - 0.5 * sign * t_r * turn) / (big * big)
        return out


#: The vehicle model odocal calibrates.
MODEL = RearAxleModel()
