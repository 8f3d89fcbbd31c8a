"""The default method's error model: a wheel stream counted over a window, errors that telescope."""

from __future__ import annotations

import numpy as np
import pytest

import odocal
from odocal.inverse import arma_from_sums, correlation_sums
from odocal.noise import NoiseProfile
from odocal.online import _added_meat
from odocal.uncertainty import NEWEY_WEST, leverage_adjusted_scores, long_run_meat


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
        meat += _added_meat(recent, row[None])
        recent = np.vstack([recent, row])[-len(NEWEY_WEST):]
    meat += _added_meat(recent, g[9:])                 # the clusters still in memory
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
        offsets.append(estimate.theta.c_e - c_e / (1.0 + mean_slip))
    assert abs(np.mean(offsets)) < 1e-4                  # 0.1 mm
