"""METHOD 1: the model, its rollout and its Jacobians."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from odocal.model.jacobians import rollout_with_jacobian, step_jacobians
from odocal.model.kinematics import (
    body_rates,
    rollout,
    rollout_ragged,
    wheel_rates_for,
    wrap_angle,
)
from odocal.model.parameters import Inputs, Parameters

THETA = np.array([1.95, -0.002, 1.53, 0.0008])
T_S = 0.025


def random_inputs(rng: np.random.Generator, shape: tuple[int, ...]) -> Inputs:
    base = rng.uniform(2.0, 7.0, (*shape[:-1], 1))
    return Inputs(n_rl=base + 0.3 * rng.standard_normal(shape),
                  n_rr=base + 0.3 * rng.standard_normal(shape),
                  beta=0.02 * rng.standard_normal(shape),
                  a_y=rng.uniform(-3.0, 3.0, shape))


def test_theta_jacobian_matches_finite_differences(rng: np.random.Generator) -> None:
    u = random_inputs(rng, (3, 120))
    x0 = rng.standard_normal((3, 3))
    _, jac = rollout_with_jacobian(THETA, u, x0, T_S)
    for j in range(4):
        h = 1e-6 * max(abs(THETA[j]), 1.0)
        plus, minus = THETA.copy(), THETA.copy()
        plus[j] += h
        minus[j] -= h
        fd = (rollout(plus, u, x0, T_S) - rollout(minus, u, x0, T_S)) / (2 * h)
        np.testing.assert_allclose(jac[..., j], fd, rtol=1e-6, atol=1e-7)
    assert np.all(jac[:, 0] == 0.0)


def test_step_jacobians_match_finite_differences(rng: np.random.Generator) -> None:
    u = random_inputs(rng, (40,))
    x0 = np.array([1.0, -2.0, 0.4])
    poses = rollout(THETA, u, x0, T_S)
    lin = step_jacobians(THETA, u, poses, T_S)
    k = 17
    one = Inputs(*(np.array([getattr(u, f)[k]]) for f in ("n_rl", "n_rr", "beta", "a_y")))

    def step(x: np.ndarray, n: np.ndarray) -> np.ndarray:
        return rollout(THETA, one.with_wheel_rates(n[:1], n[1:]), x, T_S)[1]

    x, n = poses[k], np.array([u.n_rl[k], u.n_rr[k]])
    for i in range(3):
        e = np.zeros(3)
        e[i] = 1e-6
        np.testing.assert_allclose(lin.A[k][:, i], (step(x + e, n) - step(x - e, n)) / 2e-6,
                                   rtol=1e-7, atol=1e-9)
    for i in range(2):
        e = np.zeros(2)
        e[i] = 1e-6
        np.testing.assert_allclose(lin.B[k][:, i], (step(x, n + e) - step(x, n - e)) / 2e-6,
                                   rtol=1e-7, atol=1e-9)


def test_straight_line_by_hand() -> None:
    theta = np.array([2.0, 0.0, 1.6, 0.0])
    k = 400
    u = Inputs(n_rl=np.full(k, 5.0), n_rr=np.full(k, 5.0), beta=np.zeros(k), a_y=np.zeros(k))
    poses = rollout(theta, u, np.array([1.0, 2.0, np.pi / 6]), T_S)
    # v = 5 rev/s * 2 m = 10 m/s along 30 degrees for 10 s
    np.testing.assert_allclose(poses[-1], [1.0 + 100 * np.cos(np.pi / 6),
                                           2.0 + 100 * np.sin(np.pi / 6), np.pi / 6], rtol=1e-12)


def test_constant_radius_circle_by_hand() -> None:
    theta = np.array([2.0, 0.0, 1.6, 0.0])
    v, radius = 8.0, 40.0
    w = v / radius
    n_rl, n_rr = wheel_rates_for(theta, np.array([v]), np.array([w]), np.zeros(1))
    steps = round(2 * np.pi / (w * T_S))
    w = 2 * np.pi / (steps * T_S)                       # exactly one turn in ``steps``
    n_rl, n_rr = wheel_rates_for(theta, np.array([v]), np.array([w]), np.zeros(1))
    u = Inputs(n_rl=np.full(steps, n_rl[0]), n_rr=np.full(steps, n_rr[0]), beta=np.zeros(steps),
               a_y=np.zeros(steps))
    poses = rollout(theta, u, np.zeros(3), T_S)
    # the midpoint rule puts every pose on a circle of radius v t_s / (2 sin(w t_s / 2))
    r_discrete = v * T_S / (2 * np.sin(w * T_S / 2))
    centre = np.array([0.0, r_discrete])
    np.testing.assert_allclose(np.hypot(*(poses[:, :2] - centre).T), r_discrete, rtol=1e-10)
    np.testing.assert_allclose(poses[-1, :2], [0.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(poses[-1, 2], 2 * np.pi, rtol=1e-12)
    assert abs(r_discrete - v / w) < 1e-3


def test_load_transfer_moves_circumference_between_wheels() -> None:
    theta = np.array([2.0, 0.0, 1.6, 0.01])
    v, w = body_rates(theta, np.array([5.0]), np.array([5.0]), np.array([2.0]))
    # c_rl = 2.02, c_rr = 1.98: the left wheel covers more ground, so the car turns right
    assert v[0] == 10.0 and w[0] < 0


def test_ragged_rollout_equals_separate_rollouts(rng: np.random.Generator) -> None:
    steps = np.array([5, 30, 1, 17])
    u = random_inputs(rng, (int(steps.sum()),))
    x0 = rng.standard_normal((4, 3))
    poses = rollout_ragged(THETA, u, x0, steps, T_S)
    col = 0
    for s, k in enumerate(steps):
        part = Inputs(*(getattr(u, f)[col:col + k] for f in ("n_rl", "n_rr", "beta", "a_y")))
        np.testing.assert_allclose(poses[col:col + k], rollout(THETA, part, x0[s], T_S)[1:],
                                   rtol=1e-12, atol=1e-12)
        col += k


@settings(max_examples=50, deadline=None)
@given(v=st.floats(-20, 20), w=st.floats(-1.5, 1.5), a_y=st.floats(-5, 5),
       c_e=st.floats(1.5, 2.5), c_d=st.floats(-0.01, 0.01), t_r=st.floats(1.2, 1.8),
       d=st.floats(-0.01, 0.01))
def test_wheel_rates_for_inverts_body_rates(v: float, w: float, a_y: float, c_e: float,
                                            c_d: float, t_r: float, d: float) -> None:
    theta = np.array([c_e, c_d, t_r, d])
    n_rl, n_rr = wheel_rates_for(theta, np.array([v]), np.array([w]), np.array([a_y]))
    v2, w2 = body_rates(theta, n_rl, n_rr, np.array([a_y]))
    np.testing.assert_allclose([v2[0], w2[0]], [v, w], atol=1e-9)


@settings(max_examples=50, deadline=None)
@given(heading=st.floats(-np.pi, np.pi), x=st.floats(-1e3, 1e3), y=st.floats(-1e3, 1e3))
def test_rollout_is_equivariant_under_rotation_of_the_frame(heading: float, x: float,
                                                            y: float) -> None:
    rng = np.random.default_rng(0)
    u = random_inputs(rng, (50,))
    base = rollout(THETA, u, np.zeros(3), T_S)
    moved = rollout(THETA, u, np.array([x, y, heading]), T_S)
    c, s = np.cos(heading), np.sin(heading)
    expected = np.column_stack([x + c * base[:, 0] - s * base[:, 1],
                                y + s * base[:, 0] + c * base[:, 1], base[:, 2] + heading])
    np.testing.assert_allclose(moved, expected, atol=1e-9)


@settings(max_examples=100, deadline=None)
@given(angle=st.floats(-1e4, 1e4))
def test_wrap_angle_range_and_equivalence(angle: float) -> None:
    wrapped = wrap_angle(np.array([angle]))[0]
    assert -np.pi < wrapped <= np.pi
    assert abs(np.sin(wrapped) - np.sin(angle)) < 1e-6
    assert abs(np.cos(wrapped) - np.cos(angle)) < 1e-6


def test_parameters_round_trip() -> None:
    p = Parameters(1.9, -0.001, 1.5, 0.002)
    assert Parameters.from_array(p.as_array()) == p
    assert p.as_dict() == {"c_e": 1.9, "c_d": -0.001, "t_r": 1.5, "d": 0.002}


def test_the_unseen_load_transfer_column_is_the_models_d_derivative_with_v_w_as_a_y(
        rng: np.random.Generator) -> None:
    """Where a_y is missing, d's column is taken with the reference's own v w: it must be the
    model's own derivative in d (at d = 0) of windows whose a_y were v w, for both wheels (an
    unequal c_d, so a wheel's circumference taken for the other's is seen)."""
    from odocal.model.vehicle import MODEL, SERIES

    theta = np.array([1.95, -0.03, 1.53, 0.0])
    windows = 40
    moments = rng.normal(0.0, 1.0, (windows, 3 * SERIES + 1))
    moments[:, 0] = rng.uniform(5.0, 30.0, windows)             # sum ds: moving
    along_vw, turn_vw = moments[:, 2 * SERIES], moments[:, 2 * SERIES + 1]
    as_a_y = moments.copy()
    as_a_y[:, 1], as_a_y[:, SERIES + 1] = along_vw, turn_vw      # sum ds a, sum dpsi a := v w's
    _, jac = MODEL.predict(theta, as_a_y)
    d = MODEL.layout.index(MODEL.layout.load)
    np.testing.assert_allclose(MODEL.load_transfer_column(theta, moments), jac[:, :, d],
                               rtol=1e-12, atol=1e-15)


def test_wrapped_angles_lie_in_the_half_open_interval_of_the_step() -> None:
    """(-pi, pi]: a heading residual of half a turn is +pi whichever way it came, as the
    compiled step's own wrap gives it."""
    from odocal.model.step import wrap

    angles = np.array([-3 * np.pi, -np.pi, np.pi, 3 * np.pi, 0.5, -0.5 - 4 * np.pi])
    wrapped = wrap_angle(angles)
    np.testing.assert_allclose(wrapped, [np.pi, np.pi, np.pi, np.pi, 0.5, -0.5], atol=1e-12)
    np.testing.assert_allclose(wrapped, [wrap(float(a)) for a in angles], atol=1e-12)


def test_a_ragged_rollout_of_many_parameter_sets_is_each_sets_own(
        rng: np.random.Generator) -> None:
    """Validation rolls several parameter sets (the bootstrap's) through segments of different
    lengths at once: each set's poses are those of its rollout alone, segment by segment."""
    steps = np.array([30, 55, 12])
    u = random_inputs(rng, (int(steps.sum()),))
    x0 = rng.standard_normal((3, 3))
    thetas = THETA + np.array([[0.0, 0.0, 0.0, 0.0], [0.02, 0.001, -0.03, 0.0002],
                               [-0.05, -0.004, 0.1, -0.0005]])
    together = rollout_ragged(thetas, u, x0, steps, T_S)
    assert together.shape == (3, int(steps.sum()), 3)
    first = np.concatenate([[0], np.cumsum(steps)[:-1]])
    for p, theta in enumerate(thetas):
        np.testing.assert_allclose(together[p], rollout_ragged(theta, u, x0, steps, T_S),
                                   rtol=1e-12, atol=1e-12)
        for s, (a, n) in enumerate(zip(first, steps, strict=True)):
            part = Inputs(*(np.asarray(getattr(u, f))[a:a + n]
                            for f in ("n_rl", "n_rr", "beta", "a_y")))
            alone = rollout(theta, part, x0[s], T_S)
            np.testing.assert_allclose(together[p, a:a + n], alone[1:], rtol=1e-12,
                                       atol=1e-12)
