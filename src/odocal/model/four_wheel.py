"""The four-wheel car with a steering angle (issue 37): its parameters and its equations run
backwards, the wheel revolutions and the steering-wheel angle a step's motion implies.

Geometry (the rear axle's midpoint is the origin, x forward): the rear wheels at
``(0, +-t_r / 2)``, the front wheels a wheelbase ``L`` ahead at ``(L, +-t_f / 2)``. Over a step
of ``ds`` along track and ``dpsi`` of heading (the body's motion at the rear axle, as (1) of
the rear axle inverts it), a wheel's contact point moves by the body's motion plus the turn
about its place; a rear wheel rolls along the body, a steered front wheel along its own
heading, so its revolutions are the contact point's path over its circumference (negative
where the wheel rolls backwards)::

    n_rl t_s = (ds - t_r dpsi / 2) / c_rl                       (as the rear axle's (2)-(3))
    n_fl t_s = hypot(ds - t_f dpsi / 2, L dpsi) / c_fl,         n_fr: t_f -> -t_f

with ``c_rl = c_e + c_d / 2 + d a_y`` (``c_rr = c_e - c_d / 2 - d a_y``) and ``c_fl = c_f +
c_fd / 2 + d a_y`` (``c_fr = c_f - c_fd / 2 - d a_y``): per axle a mean circumference and a
left-minus-right difference. That choice, not four circumferences, because a drive's distance
fixes each axle's mean and its bends the difference, so the two come out nearly uncorrelated
(four circumferences would share the distance scale's whole uncertainty). The load transfer
``d`` acts alike on both axles.

The steering-wheel angle (rad) follows from the road-wheel angle of the front axle's midpoint,
``delta = atan(L dpsi / ds)`` (the kinematic bicycle), through a ratio and an offset::

    s = ratio delta + s_0

At small angles only ``ratio L`` shows in ``s`` (``ratio`` and ``L`` are told apart by the
front wheels' ``hypot``, which needs bends: ``L dpsi`` against ``ds``). An estimator should
take L from the wheels alone and the ratio and offset from the steering: the little the
steering says of L by itself (the arctangent's bend) is what an unmodelled steering
(understeer, a ratio that varies with the angle) moves first. On the shared nuScenes scenes
(113 moving seconds) ``benchmarks/bench_four_wheel.py`` fits L = 2.507 +- 0.186 m from the
front wheels (the Zoe's datasheet: 2.588 m) and 3.046 +- 0.138 m (z = +3.3) where the
steering also tells L; by odocal's rule (a std below half the datasheet's 0.2 m) these
seconds do not identify L, and the fit keeps the datasheet's.

This module holds the equations and their Jacobians, and :data:`FOUR_WHEEL_MODEL`, the model
``[vehicle] model = "four_wheel"`` chooses (:mod:`odocal.model.registry`). Its rear axle is the
rear-axle model's (the same parameters, the same equations), so the default estimator fits the
rear axle as it does for two wheels, and :mod:`odocal.estimators.front_axle` the front axle and
the steering on the same motion.
"""

from __future__ import annotations

import numpy as np

from odocal.arrays import FloatArray
from odocal.model.layout import FOUR_WHEEL
from odocal.model.vehicle import MODEL, RearAxleModel

#: The wheels in the order of :func:`inverse_step`'s columns, as a drive's columns name them.
WHEEL_INPUTS = ("n_fl", "n_fr", "n_rl", "n_rr")
#: Where theta holds each parameter.
_E, _D, _T, _A, _F, _FD, _TF, _L, _RATIO, _S0 = range(FOUR_WHEEL.size)


def inverse_step(theta: FloatArray, ds: FloatArray, dpsi: FloatArray,
                 a_y: FloatArray, *, front_only: bool = False) -> tuple[FloatArray, FloatArray]:
    """The revolutions each wheel turns over each step (M, 4: fl, fr, rl, rr) and their
    Jacobian in theta (M, 4, n); ``front_only``: the front wheels' alone (M, 2), (M, 2, n)
    (what the front axle's fit takes: half the work and memory)."""
    th = np.asarray(theta, dtype=np.float64)
    ds, dpsi, a_y = (np.asarray(x, dtype=np.float64) for x in np.broadcast_arrays(ds, dpsi, a_y))
    wheels = 2 if front_only else 4
    revs = np.empty((*ds.shape, wheels))
    jac = np.zeros((*ds.shape, wheels, FOUR_WHEEL.size))
    load = th[_A] * a_y

    def rolling(column: int, sign: float, mean: int, difference: int,
                path: FloatArray) -> FloatArray:
        """Wheel ``column``'s revolutions, ``path`` over its circumference (an axle's mean
        ``mean`` +- half its difference ``difference`` and the load transfer), with their
        derivatives in those three; returns the circumference."""
        c = th[mean] + sign * (0.5 * th[difference] + load)
        u = path / c
        revs[..., column] = u
        dc = -u / c
        jac[..., column, mean] = dc
        jac[..., column, difference] = sign * 0.5 * dc
        jac[..., column, _A] = sign * a_y * dc
        return c

    for column, sign in () if front_only else ((2, 1.0), (3, -1.0)):   # rl (+), rr (-)
        c = rolling(column, sign, _E, _D, ds - sign * 0.5 * th[_T] * dpsi)
        jac[..., column, _T] = -sign * 0.5 * dpsi / c
    for column, sign in ((0, 1.0), (1, -1.0)):                   # fl (+), fr (-)
        along = ds - sign * 0.5 * th[_TF] * dpsi
        across = th[_L] * dpsi
        rolls = np.where(along < 0.0, -1.0, 1.0)          # backwards where the axle reverses
        path = rolls * np.hypot(along, across)
        c = rolling(column, sign, _F, _FD, path)
        moved = path != 0.0
        safe = np.where(moved, path, 1.0)                  # d|p| / dx = x / |p|, signed alike
        jac[..., column, _TF] = np.where(moved, -sign * 0.5 * dpsi * along / safe, 0.0) / c
        jac[..., column, _L] = np.where(moved, dpsi * across / safe, 0.0) / c
    return revs, jac


def steering(theta: FloatArray, ds: FloatArray, dpsi: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The steering-wheel angle (rad) a step's motion implies (M,) and its Jacobian in theta
    (M, n): ``ratio atan(L dpsi / ds) + s_0``. Where the step does not move (``ds`` = 0) the
    angle is not defined: NaN, with a zero Jacobian; where it barely moves, the curvature is
    the reference's noise over a small ds, and an estimator leaves such steps out."""
    th = np.asarray(theta, dtype=np.float64)
    ds, dpsi = (np.asarray(x, dtype=np.float64) for x in np.broadcast_arrays(ds, dpsi))
    moving = ds != 0.0
    curvature = np.where(moving, dpsi / np.where(moving, ds, 1.0), 0.0)
    delta = np.arctan(th[_L] * curvature)
    angle = np.where(moving, th[_RATIO] * delta + th[_S0], np.nan)
    jac = np.zeros((*ds.shape, FOUR_WHEEL.size))
    jac[..., _RATIO] = np.where(moving, delta, 0.0)
    jac[..., _S0] = np.where(moving, 1.0, 0.0)
    jac[..., _L] = np.where(moving, th[_RATIO] * curvature / (1.0 + (th[_L] * curvature) ** 2),
                            0.0)
    return angle, jac


def rear_axle(theta: FloatArray) -> FloatArray:
    """The rear axle's parameters of a four-wheel theta (the rear-axle model's theta)."""
    return np.asarray(theta, dtype=np.float64)[[_E, _D, _T, _A]]


class FourWheelModel:
    """The four-wheel car with a steering angle: the rear axle of METHOD 1 (:attr:`rear`, its
    parameters first in theta) with a steered front axle a wheelbase ahead.

    name : as ``[vehicle] model`` names it (:mod:`odocal.model.registry`)
    layout : the parameters (:data:`~odocal.model.layout.FOUR_WHEEL`)
    rear : the rear-axle model whose parameters lead theta
    wheels, wheel_inputs : four wheel rates, as the drive's columns name them (front first)
    steering_input : the drive's column of the steering-wheel angle (rad)
    """

    name: str = "four_wheel"
    layout = FOUR_WHEEL
    rear: RearAxleModel = MODEL
    states: int = 3
    wheels: int = 4
    wheel_inputs: tuple[str, ...] = WHEEL_INPUTS
    steering_input: str = "steer"

    @property
    def front_names(self) -> tuple[str, ...]:
        """The parameters the rear axle does not have (the front axle's and the steering's)."""
        return self.layout.names[self.rear.size:]

    def rear_axle(self, theta: FloatArray) -> FloatArray:
        """The rear axle's parameters of a four-wheel theta (the rear-axle model's theta)."""
        return rear_axle(theta)

    def inverse_step(self, theta: FloatArray, ds: FloatArray, dpsi: FloatArray,
                     a_y: FloatArray, *, front_only: bool = False
                     ) -> tuple[FloatArray, FloatArray]:
        """Each wheel's revolutions over each step (..., 4: fl, fr, rl, rr; ``front_only``:
        fl, fr) and their Jacobian in theta: :func:`inverse_step`."""
        return inverse_step(theta, ds, dpsi, a_y, front_only=front_only)

    def steering(self, theta: FloatArray, ds: FloatArray,
                 dpsi: FloatArray) -> tuple[FloatArray, FloatArray]:
        """The steering-wheel angle a step's motion implies and its Jacobian: :func:`steering`."""
        return steering(theta, ds, dpsi)

    def circumferences(self, theta: FloatArray, a_y: FloatArray | float = 0.0) -> FloatArray:
        """Each wheel's rolling circumference (..., 4: fl, fr, rl, rr), m (at ``a_y = 0``: the
        tyres' own)."""
        th = np.asarray(theta, dtype=np.float64)
        load = th[_A] * np.asarray(a_y, dtype=np.float64)
        return np.stack(np.broadcast_arrays(th[_F] + 0.5 * th[_FD] + load,
                                            th[_F] - 0.5 * th[_FD] - load,
                                            th[_E] + 0.5 * th[_D] + load,
                                            th[_E] - 0.5 * th[_D] - load), axis=-1)

    def front_body_rates(self, theta: FloatArray, rates: FloatArray,
                         a_y: FloatArray | float) -> tuple[FloatArray, FloatArray]:
        """The body's speed (m/s) and yaw rate (rad/s) at the rear axle from the front wheels'
        rates alone (..., 2: fl, fr; rev/s), the front half of :func:`inverse_step` solved
        exactly: with the contact points' speeds ``s_l, s_r`` (rates times circumferences),
        ``s_r^2 - s_l^2 = 2 t_f v w`` and ``(s_l^2 + s_r^2) / 2 = v^2 + (t_f^2 / 4 + L^2) w^2``,
        so ``v^2`` is the larger root of ``v^4 - Q v^2 + a P^2 = 0`` and ``w = P / v`` (no
        steering angle needed). Signed by the wheels' direction; where noise leaves no real
        root, ``v^2 = Q / 2``."""
        th = np.asarray(theta, dtype=np.float64)
        r = np.asarray(rates, dtype=np.float64)
        c = self.circumferences(th, a_y)
        s_l, s_r = r[..., 0] * c[..., 0], r[..., 1] * c[..., 1]
        sign = np.where(s_l + s_r < 0.0, -1.0, 1.0)
        p = (s_r * np.abs(s_r) - s_l * np.abs(s_l)) / (2.0 * th[_TF]) * sign
        q = 0.5 * (s_l * s_l + s_r * s_r)
        a = 0.25 * th[_TF] ** 2 + th[_L] ** 2
        v2 = 0.5 * (q + np.sqrt(np.clip(q * q - 4.0 * a * p * p, 0.0, None)))
        v = sign * np.sqrt(v2)
        with np.errstate(divide="ignore", invalid="ignore"):
            w = np.where(v2 > 0.0, p / v, 0.0)
        return v, w

    def body_rates(self, theta: FloatArray, rates: FloatArray, a_y: FloatArray | float, *,
                   std: FloatArray | None = None) -> tuple[FloatArray, FloatArray]:
        """The body's speed and yaw rate from all four wheels (..., 4: fl, fr, rl, rr): the
        rear axle's (2a)-(2b) and the front axle's :meth:`front_body_rates`, two measurements
        of one motion, averaged. ``std`` (theta's standard deviations; a parameter the drives
        did not identify at its datasheet uncertainty) weights them by how well each axle's
        scale is known: the speeds by the inverse of their circumference's relative variance
        (``c_e``, ``c_f``). The yaw rate is the rear axle's where its track is known, the
        front's only where the rear's is not. The front's yaw carries what the model leaves
        out of the steered wheels (their contact points also move with the steering: the
        scrub radius), and on the shared Singapore logs it was off the reference's by -3.5%
        to +1.2% scene by scene in 50-100 degree turns while the rear's was within 0.3%.
        Mixed in by the tracks' variances it made the held-out odometry 22% worse there; by
        the share that fitted the calibration drives' yaw best (5-20%), still 4% worse, as
        a scene's own departure is not the others'. An infinite std
        (a parameter the drives did not identify) leaves that axle's part out (the rear's
        where neither is known: the rear-axle model's odometry), so that an axle whose
        geometry the calibration did not tell adds nothing it would spoil; so does a front
        sample not measured (NaN). Without ``std``, the plain mean."""
        r = np.asarray(rates, dtype=np.float64)
        v_f, w_f = self.front_body_rates(theta, r[..., :2], a_y)
        v_r, w_r = self.rear.body_rates(self.rear_axle(theta), r[..., 2:], a_y)
        if std is None:
            return 0.5 * (v_f + v_r), 0.5 * (w_f + w_r)
        th, sd = np.asarray(theta, dtype=np.float64), np.asarray(std, dtype=np.float64)

        def share(front: int, rear: int) -> float:
            """The front axle's weight: its relative variance against the rear's."""
            var_f, var_r = (sd[front] / th[front]) ** 2, (sd[rear] / th[rear]) ** 2
            if not np.isfinite(var_f):
                return 0.0
            if not np.isfinite(var_r):
                return 1.0
            return float(var_r / (var_f + var_r)) if var_f + var_r > 0 else 0.5

        k_v = share(_F, _E)
        k_w = 0.0 if np.isfinite(sd[_T]) else share(_TF, _T)
        # a front sample not measured (NaN): the rear axle's alone there
        front = np.isfinite(v_f) & np.isfinite(w_f)
        v = np.where(front, k_v * np.where(front, v_f, 0.0) + (1.0 - k_v) * v_r, v_r)
        w = np.where(front, k_w * np.where(front, w_f, 0.0) + (1.0 - k_w) * w_r, w_r)
        return v, w

    def geometry(self, theta: FloatArray) -> dict[str, float]:
        """What a car-like exporter needs (ros2_controllers' steering controllers, Autoware's
        vehicle_info), from theta: ``wheelbase``, ``front_wheel_track``, ``rear_wheel_track``,
        ``front_wheels_radius``, ``rear_wheels_radius`` (each axle's mean wheel), and the
        steering's ``steering_ratio`` and ``steering_offset_rad``."""
        th = np.asarray(theta, dtype=np.float64)
        two_pi = 2.0 * np.pi
        return {"wheelbase": float(th[_L]), "front_wheel_track": float(th[_TF]),
                "rear_wheel_track": float(th[_T]), "front_wheels_radius": float(th[_F]) / two_pi,
                "rear_wheels_radius": float(th[_E]) / two_pi,
                "steering_ratio": float(th[_RATIO]), "steering_offset_rad": float(th[_S0])}


#: The four-wheel car (``[vehicle] model = "four_wheel"``).
FOUR_WHEEL_MODEL = FourWheelModel()
