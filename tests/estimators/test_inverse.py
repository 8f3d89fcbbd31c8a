"""The default method's error model: a wheel stream counted over a window, errors that telescope."""

from __future__ import annotations

import numpy as np
import pytest

import odocal
from odocal.estimators.covariance import (
    NEWEY_WEST,
    added_meat,
    leverage_adjusted_scores,
    long_run_meat,
)
from odocal.estimators.error_model import (
    CHANNELS,
    arma_from_sums,
    correlation_sums,
    coupling_from_sums,
    coupling_gain,
    coupling_moments,
    coupling_sums,
    coupling_sums_at,
    decouple,
)
from odocal.sim.noise import NoiseProfile


@pytest.mark.parametrize(("kind", "m", "phi"), [
    ("white", (0.0, 0.0), (0.0, 0.0)),
    ("rounding", (0.9, 0.95), (0.0, 0.1)),          # e_w - e_(w-1): only the run's ends remain
    ("smooth", (0.9, 0.95), (0.5, 0.8)),            # a differenced AR(1) error, rho 0.67
])
def test_telescoping_errors_are_recognised(kind: str, m: tuple[float, float],
                                           phi: tuple[float, float]) -> None:
    rng = np.random.default_rng(7)
    n = 4000
    e = rng.standard_normal(n + 1)
    if kind == "white":
        u = e[1:]
    elif kind == "rounding":
        u = np.diff(e)
    else:
        level = np.empty(n + 1)
        level[0] = e[0]
        for i in range(1, n + 1):
            level[i] = 0.67 * level[i - 1] + np.sqrt(1 - 0.67**2) * e[i]
        u = np.diff(level)
    follows = np.ones(n, dtype=bool)
    follows[0] = False
    follows[::500] = False                          # runs broken by gaps
    white = np.random.default_rng(1).standard_normal(n)    # a white distance channel
    got = arma_from_sums(correlation_sums(np.column_stack([white, u]), follows))
    assert got[0].tolist() == [0.0, 0.0]            # the white distance channel is left alone
    assert m[0] <= got[1, 0] <= m[1]
    assert phi[0] <= got[1, 1] <= phi[1]


def test_a_wheel_stream_averaged_over_its_counting_window_leaves_c_e_unbiased() -> None:
    """An ABS unit reports the tick count differenced over 4 samples: a lag of 1.5 steps and a
    spread of (4^2 - 1) / 12 steps^2. Treated as a pure lag, the spread biased c_e by 3 to 5 of
    its own standard deviations on every seed."""
    noise = NoiseProfile("averaged", "fine ticks counted over 4 samples", ticks_per_rev=960,
                         tick_window=4)
    sim = odocal.simulate(duration_s=600, seed=0, noise=noise)
    est = odocal.calibrate(sim.drive, method="inverse").estimate
    z = (est.theta.as_array() - sim.true_parameters.as_array()) / est.std
    assert np.all(np.abs(z) < 3.0), z
    assert 0.5 < est.details.smoothing_steps2 < 2.0
    assert est.details.delay_s == pytest.approx(1.5 * sim.drive.t_s, abs=0.2 * sim.drive.t_s)


def test_leverage_scales_each_cluster_score_by_what_leaving_it_out_would_change() -> None:
    info = np.tile(np.eye(2), (8, 1, 1))              # 8 windows, 2 per cluster, equal weight
    scores = np.arange(16, dtype=float).reshape(8, 2)
    clusters = np.repeat(np.array([5, 7, 9, 11]), 2)
    adjusted, labels = leverage_adjusted_scores(info, scores, np.array([True, True]), clusters)
    assert labels.tolist() == [5, 7, 9, 11]
    plain = scores.reshape(4, 2, 2).sum(axis=1)
    np.testing.assert_allclose(adjusted, plain * 4.0 / 3.0)      # H (H - H/4)^-1 = 4/3
    # a cluster that holds most of a parameter's information is scaled up the most
    info[:2, 1, 1] = 30.0
    adjusted, _ = leverage_adjusted_scores(info, scores, np.array([True, True]), clusters)
    assert adjusted[0, 1] / plain[0, 1] > 10.0 > adjusted[1, 1] / plain[1, 1]


def test_the_online_meat_built_cluster_by_cluster_is_the_batch_one() -> None:
    g = np.random.default_rng(3).standard_normal((12, 5))
    meat, recent = np.zeros((5, 5)), np.zeros((0, 5))
    for row in g[:9]:                                  # folded one by one, as driving
        meat += added_meat(recent, row[None])
        recent = np.vstack([recent, row])[-len(NEWEY_WEST):]
    meat += added_meat(recent, g[9:])                 # the clusters still in memory
    np.testing.assert_allclose(meat, long_run_meat(g, NEWEY_WEST), rtol=1e-12, atol=1e-12)


def test_the_weighted_long_run_covariance_cannot_come_out_negative() -> None:
    # scores that alternate (the extreme of errors that telescope): at full weight the
    # neighbours' cross products outweigh the clusters' own products
    alternating = np.array([[1.0], [-1.0]] * 20)
    assert long_run_meat(alternating)[0, 0] < 0
    assert long_run_meat(alternating, NEWEY_WEST)[0, 0] >= 0
    rng = np.random.default_rng(5)
    for _ in range(50):
        g = np.diff(rng.standard_normal((40, 3)), axis=0)
        assert np.linalg.eigvalsh(long_run_meat(g, NEWEY_WEST)).min() > -1e-9


def test_a_wheel_slip_around_its_mean_does_not_bias_c_e() -> None:
    # c_e can only be as good as the drive's own mean slip (it looks like a circumference); the
    # estimate should follow that mean, not sit above it (weights taken at the measured counts
    # put it +0.26 mm above on every seed)
    profile = NoiseProfile("slip-only", "common slip of 1%, correlated over 1 s",
                           slip_fraction=0.01)
    offsets = []
    for seed in range(4):
        sim = odocal.simulate(duration_s=1200.0, seed=seed, noise=profile)
        mean_slip = ((sim.drive.n_rl + sim.drive.n_rr).sum()
                     / (sim.true_n_rl + sim.true_n_rr).sum() - 1.0)
        c_e = sim.true_parameters.c_e
        estimate = odocal.calibrate(sim.drive).estimate
        offset = estimate.theta.c_e - c_e / (1.0 + mean_slip)
        assert abs(offset) < 2.0 * estimate.std[0]
        if not estimate.details.departures:
            # (a slip correlated over a second can hold out as a wheel-rate offset on a
            # drive: fitted, it widens c_e as far as it moves it)
            offsets.append(offset)
    assert len(offsets) >= 3 and abs(np.mean(offsets)) < 1e-4          # 0.1 mm


def test_decoupling_takes_the_distance_channels_share_out_of_the_yaw_channel() -> None:
    rng = np.random.default_rng(3)
    measured = np.column_stack([rng.uniform(4, 6, 50), rng.uniform(4, 6, 50)])
    measured[0] = [5.0, -4.0]                       # reversing in one window: no gain there
    residual = rng.standard_normal((50, 2)) * 1e-3
    x = np.concatenate([residual[..., None], rng.standard_normal((50, 2, 3))], axis=2)
    rev = measured - residual @ np.linalg.inv(CHANNELS).T
    rho = (rev[:, 1] - rev[:, 0]) / rev.mean(axis=1)
    gain = coupling_gain(measured, residual, 0.8)
    assert gain is not None
    assert gain[0] == 0.0 and abs(rho[0]) > 10
    np.testing.assert_allclose(gain[1:], 0.8 * rho[1:], rtol=1e-12)
    out = decouple(x, gain)
    np.testing.assert_array_equal(out[:, 0], x[:, 0])
    np.testing.assert_allclose(out[:, 1], x[:, 1] - gain[:, None] * x[:, 0], rtol=1e-12)
    assert coupling_gain(measured, residual, 0.0) is None
    assert decouple(x, None) is x


def test_the_coupling_is_found_where_it_stands_out_and_only_there() -> None:
    rng = np.random.default_rng(5)
    n = 3000
    measured = np.column_stack([rng.uniform(3, 7, n), rng.uniform(3, 7, n)])
    e_s = rng.standard_normal(n) * 1e-3                 # revolutions per window
    independent = np.column_stack([e_s, rng.standard_normal(n) * 1e-3])
    weight = np.full((n, 2), 1e6)                          # standardised
    assert coupling_from_sums(coupling_sums(measured, independent, weight)) == 0.0
    # a common error: the yaw channel carries rho times the distance channel's
    rev = measured - independent @ np.linalg.inv(CHANNELS).T
    rho = (rev[:, 1] - rev[:, 0]) / rev.mean(axis=1)
    coupled = np.column_stack([e_s, rho * e_s + 5e-5 * rng.standard_normal(n)])
    strong = weight.copy()
    strong[:, 1] /= 0.05**2                                # the yaw channel's remaining error
    assert coupling_from_sums(coupling_sums(measured, coupled, strong)) == pytest.approx(
        1.0, abs=0.05)
    # a share no common slip gives (what telescoping rounding can fake) is refused
    faked = np.column_stack([e_s, 3.0 * rho * e_s + 5e-5 * rng.standard_normal(n)])
    assert coupling_from_sums(coupling_sums(measured, faked, strong)) == 0.0
    # a spike in one wheel, or a window that reverses, does not carry the regression
    spiked, turned = coupled.copy(), measured.copy()
    spiked[7] = [0.5, -1.0]                                   # +1 rev on the left wheel
    turned[8] = [2.0, -1.5]
    base = coupling_sums(measured, coupled, strong)
    np.testing.assert_allclose(coupling_sums(measured, spiked, strong),
                               base - coupling_sums(measured[7:8], coupled[7:8], strong[7:8]))
    np.testing.assert_allclose(coupling_sums(turned, coupled, strong),
                               base - coupling_sums(measured[8:9], coupled[8:9], strong[8:9]))
    # sums of parts add up to the whole (the online calibrator folds them)
    halves = coupling_sums(measured[:n // 2], coupled[:n // 2], weight[:n // 2]) \
        + coupling_sums(measured[n // 2:], coupled[n // 2:], weight[n // 2:])
    np.testing.assert_allclose(halves, coupling_sums(measured, coupled, weight), rtol=1e-12)


def _no_coupling() -> odocal.Settings:
    return odocal.Settings().replace(inverse={"common_wheel_error": "off"})


def test_a_slip_common_to_both_wheels_is_taken_out_of_the_yaw_channel() -> None:
    # a common slip is a yaw error in bends: the fit regresses it out (beta near 1) and t_r
    # comes out closer over the same four noise draws than with the coupling held off
    profile = NoiseProfile("common-slip", "common slip of 1%, correlated over 1 s, and white",
                           slip_fraction=0.01, wheel_white_revps=0.005)
    with_it, without = [], []
    for k in range(4):
        sim = odocal.simulate(duration_s=1200.0, seed=1, noise=profile, noise_seed=k)
        est = odocal.calibrate(sim.drive).estimate
        assert est.details.coupling == pytest.approx(1.0, abs=0.25)
        with_it.append(est.theta.t_r - sim.true_parameters.t_r)
        off = odocal.calibrate(sim.drive, settings=_no_coupling()).estimate
        without.append(off.theta.t_r - sim.true_parameters.t_r)
    assert np.sqrt(np.mean(np.square(with_it))) < 0.7 * np.sqrt(np.mean(np.square(without)))
    white = odocal.simulate(duration_s=600.0, seed=1, noise="white").drive
    assert odocal.calibrate(white).estimate.details.coupling == 0.0


def test_no_coupling_from_rounding_or_a_wheel_spike() -> None:
    # rounded tick counts telescope, and a regression on them with a constant beside rho passed
    # the Wald test on this route (beta 7.5); so did three-sample wheel glitches
    quantised = odocal.simulate(duration_s=1200.0, seed=12, noise="quantised").drive
    assert odocal.calibrate(quantised).estimate.details.coupling == 0.0
    sim = odocal.simulate(duration_s=1200.0, seed=0, noise="white")
    n_rl = sim.drive.n_rl.copy()
    moving = np.flatnonzero(n_rl > 3.0)
    n_rl[moving[5000]:moving[5000] + 2] += 40.0
    spiked = sim.drive.with_wheel_rates(n_rl, sim.drive.n_rr)
    assert odocal.calibrate(spiked).estimate.details.coupling == 0.0


def test_coupling_moments_give_the_sums_at_a_later_theta() -> None:
    # the online calibrator folds windows as moments linearised where theta was then; at a
    # later theta they must give what the windows' residuals there give
    rng = np.random.default_rng(9)
    n = 400
    measured = np.column_stack([rng.uniform(3, 7, n), rng.uniform(3, 7, n)])
    residual = rng.standard_normal((n, 2)) * 1e-3
    jac = rng.standard_normal((n, 2, 5))
    weight = rng.uniform(0.5, 2.0, (n, 2)) * 1e5          # (no window an outlier)
    p = np.array([1.95, -0.002, 1.5, 0.0008, 0.1])
    q = p + rng.standard_normal(5) * 1e-5
    moved = residual - jac @ (q - p)
    origin = np.array([2.0, 0.0, 1.6, 0.0, 0.0])          # the datasheet's
    halves = coupling_moments(measured[:200], residual[:200], jac[:200], p - origin,
                              weight[:200]) \
        + coupling_moments(measured[200:], residual[200:], jac[200:], p - origin, weight[200:])
    np.testing.assert_allclose(coupling_sums_at(halves, p - origin),
                               coupling_sums(measured, residual, weight), rtol=1e-7)
    # (the windows' wheel ratio is kept from the linearisation point: it moves by ~1e-5)
    np.testing.assert_allclose(coupling_sums_at(halves, q - origin),
                               coupling_sums(measured, moved, weight), rtol=1e-3)
