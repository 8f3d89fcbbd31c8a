"""The Cramér-Rao bound of a simulated drive, and the default method's distance from it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import odocal
from odocal.model.kinematics import circumferences, wheel_rates_for
from odocal.settings import Settings
from odocal.sim.bound import _processes, information_bound, wheel_information
from odocal.sim.noise import NOISE_PROFILES, NoiseProfile
from odocal.sim.simulate import TRUE_PARAMETERS, _wheel_errors


def _dense_information(sim: odocal.SimulatedDrive) -> np.ndarray:
    """J' Sigma^-1 J with Sigma written out whole (each process's covariance phi^|i-j| std^2)."""
    from odocal.sim.bound import _motion, _rate_jacobian

    p, t_s = sim.profile, sim.drive.t_s
    theta = sim.true_parameters.as_array()
    rates = np.column_stack([sim.true_n_rl, sim.true_n_rr])
    m = rates.shape[0]
    jac = _rate_jacobian(theta, *_motion(theta, rates[:, 0], rates[:, 1]))
    lag = np.abs(np.arange(m)[:, None] - np.arange(m)[None, :])

    def ar1(std: float, tau: float) -> np.ndarray:
        return std**2 * np.exp(-t_s / tau) ** lag

    sigma = np.diag(np.concatenate([p.wheel_white_revps**2
                                    + (p.wheel_white_fraction * rates[:, i])**2
                                    for i in range(2)]))
    both = np.concatenate([rates[:, 0], rates[:, 1]])
    if p.wheel_markov_revps:
        block = ar1(p.wheel_markov_revps, p.wheel_markov_correlation_s)
        sigma[:m, :m] += block
        sigma[m:, m:] += block
    if p.slip_fraction:
        sigma += np.tile(ar1(p.slip_fraction, p.slip_correlation_s), (2, 2)) * np.outer(both,
                                                                                       both)
    if p.slip_differential:
        own = ar1(p.slip_differential / np.sqrt(2.0), p.slip_correlation_s)
        sigma[:m, :m] += own * np.outer(rates[:, 0], rates[:, 0])
        sigma[m:, m:] += own * np.outer(rates[:, 1], rates[:, 1])
    seen = both != 0.0
    j = np.concatenate([jac[:, 0, :], jac[:, 1, :]])[seen]
    return j.T @ np.linalg.solve(sigma[np.ix_(seen, seen)], j)


@pytest.mark.parametrize(("profile", "floor"), [
    ("white-rate", 1e-4), ("slip-heavy", 1e-4), ("heavy", 1e-4),
    ("slip", 5e-3),                  # no white noise at all: the floor is all there is
])
def test_banded_elimination_matches_the_whole_covariance(profile: str, floor: float) -> None:
    sim = odocal.simulate(duration_s=40.0, seed=1, noise=profile)
    banded = np.linalg.inv(wheel_information(sim.true_parameters.as_array(), sim.true_n_rl,
                                             sim.true_n_rr, sim.profile, sim.drive.t_s))
    dense = np.linalg.inv(_dense_information(sim))
    scale = np.sqrt(np.outer(np.diag(dense), np.diag(dense)))
    assert np.max(np.abs(banded - dense) / scale) < floor


def test_coloured_noise_without_white_noise_is_bounded_through_the_floor() -> None:
    # no white part: the white floor keeps the bound finite and moves it by less than 1e-3
    sim = odocal.simulate(duration_s=40.0, seed=2, noise="markov")
    banded = sim.cramer_rao_bound()
    assert banded is not None
    dense = np.linalg.inv(_dense_information(sim))
    assert np.allclose(np.sqrt(np.diag(banded)), np.sqrt(np.diag(dense)), rtol=1e-3)


def test_track_width_column_is_the_yaw_rate_over_the_circumference() -> None:
    # white noise: information is J'J / sigma^2, and dn/dt_r = -+ w / (2 c)
    sim = odocal.simulate(duration_s=60.0, seed=0, noise="white")
    from odocal.sim.bound import _motion, _rate_jacobian

    theta = TRUE_PARAMETERS.as_array()
    v, w, a_y = _motion(theta, sim.true_n_rl, sim.true_n_rr)
    c_rl, c_rr = circumferences(theta, a_y)
    jac = _rate_jacobian(theta, v, w, a_y)
    assert np.allclose(jac[:, 0, 2], -0.5 * w / c_rl, atol=1e-9)
    assert np.allclose(jac[:, 1, 2], 0.5 * w / c_rr, atol=1e-9)
    sigma = NOISE_PROFILES["white"].wheel_white_revps
    seen = np.column_stack([sim.true_n_rl, sim.true_n_rr]) != 0.0
    expected = np.einsum("mi,mi->", jac[:, :, 2] ** 2, seen) / sigma**2
    info = wheel_information(theta, sim.true_n_rl, sim.true_n_rr, sim.profile, sim.drive.t_s)
    assert info[2, 2] == pytest.approx(expected, rel=1e-9)


def test_more_noise_never_lowers_the_bound() -> None:
    sim = odocal.simulate(duration_s=120.0, seed=3, noise="white")
    args = (sim.true_parameters.as_array(), sim.true_n_rl, sim.true_n_rr)
    white = NOISE_PROFILES["white"]
    def bound(profile: NoiseProfile) -> np.ndarray:
        out = information_bound(*args, profile, sim.drive.t_s)
        assert out is not None
        return np.diag(out)

    base = bound(white)
    for extra in ({"wheel_markov_revps": 0.01}, {"slip_fraction": 0.005},
                  {"slip_differential": 0.001}, {"wheel_white_fraction": 0.01}):
        more = bound(dataclasses.replace(white, **extra))
        assert np.all(more >= base), extra
        # and by more than the white floor any process brings along (about 1e-6)
        assert np.any(more > 1.01 * base), extra
    assert np.allclose(bound(NOISE_PROFILES["white-2x"]), 4.0 * base, rtol=1e-9)


@pytest.mark.parametrize("profile", ["reference", "quantised", "realistic", "everything"])
def test_no_bound_without_counted_wheel_errors_or_with_tick_counts(profile: str) -> None:
    # tick counts: the noise is added to rates on the tick grid and can be rounded away
    sim = odocal.simulate(duration_s=60.0, seed=0, noise=profile)
    assert sim.cramer_rao_bound() is None
    with pytest.raises(ValueError, match="does not apply"):
        wheel_information(sim.true_parameters.as_array(), sim.true_n_rl, sim.true_n_rr,
                          sim.profile, sim.drive.t_s)


def test_a_drive_without_bends_bounds_only_what_it_carries() -> None:
    # no yaw rate: nothing about t_r and d (infinite), the circumferences still bounded
    n = 4000
    v = np.linspace(5.0, 15.0, n)
    n_rl, n_rr = wheel_rates_for(TRUE_PARAMETERS.as_array(), v, np.zeros(n), np.zeros(n))
    bound = information_bound(TRUE_PARAMETERS.as_array(), n_rl, n_rr, NOISE_PROFILES["white"],
                              0.025)
    assert bound is not None
    assert np.all(np.isinf(np.diag(bound)[2:]))
    assert np.all(np.isfinite(np.diag(bound)[:2])) and np.all(np.diag(bound)[:2] > 0)


def test_a_drive_with_a_change_has_no_bound() -> None:
    after = TRUE_PARAMETERS.replace(c_e=TRUE_PARAMETERS.c_e * 0.99)
    sim = odocal.simulate(duration_s=60.0, seed=0, noise="white", change=(30.0, after))
    with pytest.raises(odocal.ConfigError, match="change"):
        sim.cramer_rao_bound()


def test_the_bounds_error_model_is_what_the_simulator_draws() -> None:
    # constant wheel rates: the simulated errors' variances, the wheels' covariance and the
    # autocovariance at lags of 1 and 40 steps against the processes the bound integrates out
    profile = NoiseProfile("mix", "white, coloured and slip", wheel_white_revps=0.01,
                           wheel_markov_revps=0.015, slip_fraction=0.01,
                           slip_differential=0.002)
    t_s, m, rate = 0.025, 400_000, np.array([5.0, 6.0])
    rng = np.random.default_rng(11)
    errors = _wheel_errors(rng, profile, np.full(m, 10.0), np.tile(rate, (m, 1)), t_s) - rate
    model = np.zeros((3, 2, 2))                             # lag 0, 1, 40: (wheel, wheel)
    for lag_i, lag in enumerate((0, 1, 40)):
        for std, phi, kind, wheel in _processes(profile, t_s):
            scale = rate if kind == "slip" else np.ones(2)
            part = std**2 * phi**lag * np.outer(scale, scale)
            model[lag_i] += part if wheel < 0 else part * np.eye(2)[wheel][:, None] \
                * np.eye(2)[wheel][None, :]
        if lag == 0:
            model[lag_i] += np.eye(2) * profile.wheel_white_revps**2
    for lag_i, lag in enumerate((0, 1, 40)):
        seen = errors[lag:].T @ errors[:m - lag] / (m - lag)
        np.testing.assert_allclose(seen, model[lag_i], rtol=0.05, atol=2e-3 * model[0].max())


def test_noise_seed_drives_one_route_with_other_noise() -> None:
    first = odocal.simulate(duration_s=60.0, seed=4, noise="white")
    again = odocal.simulate(duration_s=60.0, seed=4, noise="white", noise_seed=1)
    other = odocal.simulate(duration_s=60.0, seed=4, noise="white", noise_seed=2)
    assert np.array_equal(first.true_poses, again.true_poses)
    assert np.array_equal(first.true_n_rl, other.true_n_rl)
    assert not np.array_equal(again.drive.n_rl, other.drive.n_rl)
    assert not np.array_equal(first.drive.n_rl, again.drive.n_rl)
    repeat = odocal.simulate(duration_s=60.0, seed=4, noise="white", noise_seed=1)
    assert np.array_equal(again.drive.n_rl, repeat.drive.n_rl)
    assert again.drive.metadata["noise_seed"] == 1


def test_the_default_method_reaches_the_bound_on_white_noise() -> None:
    # one route, 40 draws of the noise: the default's error spread and its reported std both
    # match the Cramér-Rao bound (with 40 draws a std is known to about 11%)
    settings = Settings()
    errors, stds = [], []
    for k in range(40):
        sim = odocal.simulate(duration_s=300.0, seed=5, noise="white-2x", noise_seed=k)
        est = odocal.calibrate(sim.drive, settings=settings).estimate
        assert all(est.identified)
        errors.append(est.theta.as_array() - sim.true_parameters.as_array())
        stds.append(est.std)
    covariance = sim.cramer_rao_bound()
    assert covariance is not None
    bound = np.sqrt(np.diag(covariance))
    spread = np.std(errors, axis=0, ddof=1)
    assert np.all(spread / bound > 0.75) and np.all(spread / bound < 1.35), spread / bound
    reported = np.mean(stds, axis=0)
    # c_e and c_d rest on every window; t_r and d on this five-minute route's few bends (about
    # seven and three clusters' worth): their std is widened for so few (Student's t at
    # Satterthwaite's degrees of freedom, not rounded: up to 2.2 times the bound for d), so it
    # covers the error spread, above the bound by that factor. The bound also takes the wheels'
    # timing as known, where the calibration carries the lag's own uncertainty (c_e: ~1.25)
    ratio = reported / bound
    assert np.all(ratio > 0.85), ratio
    assert np.all(ratio[:2] < 1.3) and ratio[2] < 1.75 and ratio[3] < 2.3, ratio
    assert np.all(reported >= 0.85 * spread), reported / spread
