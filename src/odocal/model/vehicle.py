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

from odocal.arrays import FloatArray
from odocal.model import step
from odocal.model.layout import REAR_AXLE, Layout

#: Powers of the lateral acceleration the window prediction keeps (the series' terms).
SERIES = 4


class RearAxleModel:
    """The rear axle of METHOD 1, equations (1)-(3): :class:`~odocal.model.protocol.VehicleModel`
    for two rear wheel rates.

    name : as ``[vehicle] model`` names it (:mod:`odocal.model.registry`)
    layout : the parameters (:data:`~odocal.model.layout.REAR_AXLE`)
    step : the model step, its derivatives and the step run backwards, written once for numpy
        arrays and numba alike (:mod:`odocal.model.step`)
    states, wheels : sizes of the pose ``[p_x, p_y, psi]`` and of the measured inputs
    wheel_inputs : the drive's columns of the wheel rates, in the order of :meth:`body_map`'s
        columns (left first)
    """

    name: str = "rear_axle"
    layout: Layout = REAR_AXLE
    step: types.ModuleType = step
    states: int = 3
    wheels: int = 2
    wheel_inputs: tuple[str, ...] = ("n_rl", "n_rr")

    @property
    def names(self) -> tuple[str, ...]:
        return self.layout.names

    @property
    def size(self) -> int:
        return self.layout.size

    def index(self, name: str) -> int:
        return self.layout.index(name)

    def circumferences(self, theta: FloatArray, a_y: FloatArray | float = 0.0) -> FloatArray:
        """Each wheel's rolling circumference (..., 2), m, (3a)-(3b): ``c_e +- c_d / 2 +- d a_y``
        (at ``a_y = 0``: the tyres' own)."""
        c_rl, c_rr = self.step.circumferences(np.asarray(theta, dtype=np.float64),
                                              np.asarray(a_y, dtype=np.float64))
        return np.stack(np.broadcast_arrays(c_rl, c_rr), axis=-1)

    def body_map(self, theta: FloatArray) -> tuple[FloatArray, FloatArray]:
        """(2a)-(2b) as a linear map: ``[v, w] = (M0 + a_y M1) @ rates`` for the wheel rates
        (rev/s, :attr:`wheel_inputs`' order), the two (2, 2) matrices. For a loop that takes one
        message at a time (the ROS 2 node) without writing the equations out."""
        lay = self.layout
        th = np.asarray(theta, dtype=np.float64)
        c_l, c_r = self.circumferences(th)
        t_r, d = lay.value(th, lay.track), lay.value(th, lay.load)
        m0 = np.array([[0.5 * c_l, 0.5 * c_r], [-c_l / t_r, c_r / t_r]])
        m1 = np.array([[0.5 * d, -0.5 * d], [-d / t_r, -d / t_r]])
        return m0, m1

    def body_rates(self, theta: FloatArray, rates: FloatArray,
                   a_y: FloatArray | float) -> tuple[FloatArray, FloatArray]:
        """(2a), (2b): the speed v (m/s) and yaw rate w (rad/s) of the wheel rates ``rates``
        (..., 2) in rev/s."""
        r = np.asarray(rates, dtype=np.float64)
        shape = np.broadcast_shapes(r.shape[:-1], np.shape(a_y))
        v, w, _, _ = self.step.body(np.asarray(theta, dtype=np.float64),
                                    *(np.ascontiguousarray(np.broadcast_to(x, shape))
                                      for x in (r[..., 0], r[..., 1],
                                                np.asarray(a_y, dtype=np.float64))))
        return np.asarray(v), np.asarray(w)

    def wheel_rates(self, theta: FloatArray, v: FloatArray | float, w: FloatArray | float,
                    a_y: FloatArray | float) -> FloatArray:
        """:meth:`body_rates` inverted: the wheel rates (..., 2), rev/s, of speed ``v`` and yaw
        rate ``w``."""
        th = np.asarray(theta, dtype=np.float64)
        shape = np.broadcast_shapes(np.shape(v), np.shape(w), np.shape(a_y))
        c = self.circumferences(th, np.broadcast_to(np.asarray(a_y, dtype=np.float64), shape))
        half = 0.5 * self.layout.value(th, self.layout.track) * np.asarray(w)
        return np.stack([(np.asarray(v) - half) / c[..., 0], (np.asarray(v) + half) / c[..., 1]],
                        axis=-1)

    @property
    def channel_map(self) -> FloatArray:
        """The error model's channels of the wheels' revolutions (2, 2): their mean (the
        distance) and their difference right minus left (the yaw); ``channels = map @ wheels``."""
        return np.array([[0.5, 0.5], [-1.0, 1.0]])

    def channel_gains(self, theta: FloatArray) -> FloatArray:
        """Metres of travel per revolution of the mean channel and radians of yaw per
        revolution of the difference channel (2,), at a_y = 0: ``[c_e, c_e / t_r]``."""
        m0, _ = self.body_map(theta)
        return np.array([m0[0].sum(), 0.5 * (m0[1, 1] - m0[1, 0])])

    def wheel_changes(self, change: FloatArray) -> FloatArray:
        """Each wheel's circumference change (2,), m, of a change ``change`` of theta (the
        tyres' own, at a_y = 0): which wheels a change of parameters moved."""
        lay = self.layout
        d_e, d_d = lay.value(change, lay.scale), lay.value(change, lay.difference)
        return np.array([d_e + 0.5 * d_d, d_e - 0.5 * d_d])

    def with_wheel_scaled(self, theta: FloatArray, wheel: int, factor: float) -> FloatArray:
        """theta with wheel ``wheel``'s circumference (0 left, 1 right) times ``factor``, the
        other's unchanged (a pressure loss, a new tyre on one side)."""
        lay = self.layout
        out = np.array(theta, dtype=np.float64)
        c = self.circumferences(out)
        c[wheel] *= factor
        out[lay.index(lay.scale)] = 0.5 * (c[0] + c[1])
        out[lay.index(lay.difference)] = c[0] - c[1]
        return out

    def geometry(self, theta: FloatArray) -> dict[str, float]:
        """What a differential-drive exporter needs, from theta: ``wheel_radius`` (the mean
        wheel's, m), ``wheel_separation`` (m), ``left_wheel_radius``, ``right_wheel_radius``
        (each tyre's own, at a_y = 0)."""
        lay = self.layout
        th = np.asarray(theta, dtype=np.float64)
        c_l, c_r = self.circumferences(th)
        two_pi = 2.0 * np.pi
        return {"wheel_radius": lay.value(th, lay.scale) / two_pi,
                "wheel_separation": lay.value(th, lay.track),
                "left_wheel_radius": float(c_l) / two_pi, "right_wheel_radius": float(c_r) / two_pi}

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
