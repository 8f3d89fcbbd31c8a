"""Numbers the estimators' uncertainty rests on, pinned to the value worked out by hand (issue
38: each one-line mutation of them lived through every other test)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from odocal.estimators import core, fitting
from odocal.estimators.estimate import tail_inflation
from odocal.settings import Settings


@pytest.mark.parametrize(("clusters", "factor"), [
    (3.0, 2.2633),            # Student's t, 2 dof, at Phi(2) = 0.97725: 4.5265, over 2
    (10.0, 1.1599),           # 9 dof: 2.3198 / 2 (the docstring's "1.16 for 10")
    (30.0, 1.0450),           # 29 dof: 2.0900 / 2
])
def test_the_tail_inflation_is_students_t_with_one_dof_fewer_than_clusters(
        clusters: float, factor: float) -> None:
    # with ``clusters`` degrees of freedom (one more) it would be 1.1418 at 10 clusters
    assert tail_inflation(clusters) == pytest.approx(factor, abs=1e-4)
    assert tail_inflation(1.5) == float("inf")


def _settings(mode: str) -> Settings:
    s = Settings()
    return dataclasses.replace(s, inverse=dataclasses.replace(s.inverse, wheel_offset=mode))


def test_the_moving_wheel_rate_offsets_prior_is_half_an_encoding_step() -> None:
    # a truncating encoder reads up to a step low: the offset's prior std is half a step
    assert core.offset_prior_std(_settings("encoded"), 0.08) == pytest.approx(0.04, rel=1e-12)
    assert core.offset_prior_std(_settings("encoded"), 0.0) == 0.0   # no grid: not fitted
    # asked for always: [inverse] wheel_offset_prior_revps, 0.02 rev/s unless set
    assert core.offset_prior_std(_settings("always"), 0.08) == 0.02
    assert core.offset_prior_std(_settings("off"), 0.08) == 0.0
    # the prior enters the folded information as 1 / std^2, in h and in the meat alike
    folded = fitting.Folded.prior(np.zeros(4), 0.04)
    expected = np.zeros((fitting.P, fitting.P))
    expected[fitting.OFFSET, fitting.OFFSET] = 1.0 / 0.04 ** 2                  # 625 (rev/s)^-2
    np.testing.assert_allclose(folded.h, expected, rtol=1e-12)
    np.testing.assert_allclose(folded.meat, expected, rtol=1e-12)
    assert folded.offset_std == 0.04 and folded.offset_free


def test_the_prewhitening_is_fitted_from_twenty_pairs_of_windows_and_not_fewer() -> None:
    """The ARMA filter of the telescoping errors needs 20 lag-one and 20 lag-two pairs (a
    correlation from fewer is chance): at 20 it is fitted, at 19 of either it is not."""
    from odocal.estimators.error_model import arma_from_sums

    def sums(n1: int, n2: int) -> np.ndarray:
        # per channel: sum of squares, count, lag-one products and pairs, lag-two ditto; a
        # lag-one correlation of -0.8, beyond what 20 pairs of white errors show (-3/sqrt(20)),
        # lag-two 0
        n = 40.0
        return np.array([[n, n, -0.8 * n1, float(n1), 0.0, float(n2)]] * 2)

    fitted = arma_from_sums(sums(20, 20))
    assert np.all(fitted[:, 0] != 0.0)
    for n1, n2 in ((19, 20), (20, 19)):
        np.testing.assert_array_equal(arma_from_sums(sums(n1, n2)), np.zeros((2, 2)))
