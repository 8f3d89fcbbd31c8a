"""The four-wheel car's equations (issue 37, second part): each wheel's revolutions and the
steering-wheel angle a step's motion implies, checked against the geometry itself, the rear
axle's model, and their Jacobians against finite differences."""

from __future__ import annotations

import numpy as np
import pytest

from odocal.model.four_wheel import FOUR_WHEEL, WHEEL_INPUTS, inverse_step, rear_axle, steering
from odocal.model.parameters import Parameters
from odocal.model.vehicle import MODEL

#: A Renault Zoe's size (wheelbase 2.588 m), with tyres a few millimetres apart.
THETA = np.array([1.93, 0.004, 1.46, 0.0008, 1.925, -0.002, 1.51, 2.588, 15.2, 0.013])


def _arc_path(radius: float, offset: tuple[float, float], angle: float) -> float:
    """How far a point at ``offset`` (x forward, y left) of the rear axle's midpoint travels
    while the body turns ``angle`` about a centre ``radius`` to its left: summed over a
    thousand substeps, from the positions alone."""
    phi = np.linspace(0.0, angle, 1001)
    cx, cy = 0.0, radius                                       # the centre, body frame at 0
    ox, oy = offset
    # the body's pose on the arc: position on the circle, heading phi
    px, py = cx + radius * np.sin(phi), cy - radius * np.cos(phi)
    x = px + ox * np.cos(phi) - oy * np.sin(phi)
    y = py + ox * np.sin(phi) + oy * np.cos(phi)
    return float(np.hypot(np.diff(x), np.diff(y)).sum())


@pytest.mark.parametrize("radius", [8.0, 25.0, -12.0, 400.0])
def test_each_wheel_turns_its_contact_point_s_path_on_a_circle(radius: float) -> None:
    """On a circle of ``radius`` every wheel's contact point runs on its own circle: the
    revolutions are that path (measured from the positions) over the wheel's circumference."""
    angle = 0.3 if radius > 0 else -0.3
    ds, dpsi = radius * angle, angle
    revs, _ = inverse_step(THETA, np.array([ds]), np.array([dpsi]), np.array([0.0]))
    c_e, c_d, t_r, _, c_f, c_fd, t_f, wheelbase = THETA[:8]
    places = {"n_fl": (wheelbase, t_f / 2), "n_fr": (wheelbase, -t_f / 2), "n_rl": (0.0, t_r / 2),
              "n_rr": (0.0, -t_r / 2)}
    circumference = {"n_fl": c_f + c_fd / 2, "n_fr": c_f - c_fd / 2, "n_rl": c_e + c_d / 2,
                     "n_rr": c_e - c_d / 2}
    for column, name in enumerate(WHEEL_INPUTS):
        path = _arc_path(abs(radius), (places[name][0], np.sign(radius) * places[name][1]),
                         abs(angle))
        assert revs[0, column] == pytest.approx(path / circumference[name], rel=1e-6), name


def test_the_rear_wheels_are_the_rear_axle_model_s() -> None:
    rng = np.random.default_rng(5)
    ds, dpsi, a_y = rng.uniform(0.0, 0.5, 300), rng.uniform(-0.02, 0.02, 300), \
        rng.uniform(-4, 4, 300)
    revs, jac = inverse_step(THETA, ds, dpsi, a_y)
    rear, rear_jac = MODEL.inverse_step(rear_axle(THETA), ds, dpsi, a_y)
    np.testing.assert_allclose(revs[:, 2:], rear, rtol=1e-14)
    np.testing.assert_allclose(jac[:, 2:, :4], rear_jac, rtol=1e-12, atol=1e-15)
    assert np.all(jac[:, 2:, 4:] == 0.0)
    assert Parameters.from_array(THETA, layout=FOUR_WHEEL).L == 2.588


def test_the_steering_angle_is_the_bicycle_s_on_a_circle() -> None:
    """On a circle of radius R the front axle's road-wheel angle is atan(L / R); the
    steering-wheel angle is ratio times it plus the offset. Straight ahead: the offset."""
    ratio, offset, wheelbase = THETA[8], THETA[9], THETA[7]
    for radius in (6.0, 30.0, -15.0):
        angle, _ = steering(THETA, np.array([radius * 0.1]), np.array([0.1]))
        assert angle[0] == pytest.approx(ratio * np.arctan(wheelbase / radius) + offset,
                                         rel=1e-12)
    angle, _ = steering(THETA, np.array([1.0, 0.0]), np.array([0.0, 0.01]))
    assert angle[0] == offset and np.isnan(angle[1])


def test_the_jacobians_are_the_derivatives() -> None:
    rng = np.random.default_rng(11)
    ds = rng.uniform(-0.1, 0.6, 200)
    dpsi = rng.uniform(-0.03, 0.03, 200)
    a_y = rng.uniform(-5.0, 5.0, 200)
    _, jac = inverse_step(THETA, ds, dpsi, a_y)
    _, jac_s = steering(THETA, ds, dpsi)
    for j in range(FOUR_WHEEL.size):
        h = 1e-6 * max(1.0, abs(THETA[j]))
        up, down = THETA.copy(), THETA.copy()
        up[j] += h
        down[j] -= h
        numeric = (inverse_step(up, ds, dpsi, a_y)[0] - inverse_step(down, ds, dpsi, a_y)[0]) \
            / (2 * h)
        np.testing.assert_allclose(jac[..., j], numeric, rtol=1e-6, atol=1e-9,
                                   err_msg=FOUR_WHEEL.names[j])
        numeric_s = (steering(up, ds, dpsi)[0] - steering(down, ds, dpsi)[0]) / (2 * h)
        np.testing.assert_allclose(jac_s[:, j], numeric_s, rtol=1e-6, atol=1e-9,
                                   err_msg=FOUR_WHEEL.names[j])


def test_backwards_every_wheel_turns_back_the_same_path() -> None:
    """Reversing along a circle turns each wheel back by what it turned forwards (a signed
    encoder's rate is negative)."""
    ds, dpsi = np.array([2.0, -2.0]), np.array([0.15, -0.15])
    revs, _ = inverse_step(THETA, ds, dpsi, np.zeros(2))
    np.testing.assert_allclose(revs[1], -revs[0], rtol=1e-14)
    assert np.all(revs[0] > 0)


def test_the_load_transfer_acts_alike_on_both_axles() -> None:
    """With lateral acceleration the left wheels roll d a_y larger, the right ones d a_y
    smaller, on the front axle as on the rear."""
    a_y, ds = 3.0, 1.0
    revs, _ = inverse_step(THETA, np.array([ds]), np.array([0.0]), np.array([a_y]))
    c_e, c_d, _, d, c_f, c_fd = THETA[:6]
    np.testing.assert_allclose(revs[0], [ds / (c_f + c_fd / 2 + d * a_y),
                                         ds / (c_f - c_fd / 2 - d * a_y),
                                         ds / (c_e + c_d / 2 + d * a_y),
                                         ds / (c_e - c_d / 2 - d * a_y)], rtol=1e-14)
