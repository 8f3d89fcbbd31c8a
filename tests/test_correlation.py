"""odocal.correlation: the one lag search of the checks and the preprocessing."""

from __future__ import annotations

import numpy as np
import pytest

from odocal.correlation import correlations


def _pearson_by_hand(pairs: list[tuple[np.ndarray, np.ndarray]],
                     k: int) -> tuple[list[float], list[float]]:
    a_all: list[float] = []
    b_all: list[float] = []
    for a, b in pairs:
        for i in range(a.size):
            if 0 <= i + k < a.size:
                a_all.append(a[i])
                b_all.append(b[i + k])
    return a_all, b_all


def test_every_lag_is_pearsons_correlation_of_the_samples_both_pairs_hold() -> None:
    rng = np.random.default_rng(0)
    pairs = [(rng.normal(size=50) + 3.0, rng.normal(size=50)),
             (rng.normal(size=30), rng.normal(size=30) + 1.0)]
    found = correlations(pairs, 35)
    assert found.lags.tolist() == list(range(-35, 36))
    for k, value, overlap in zip(found.lags, found.values, found.overlap, strict=True):
        a, b = _pearson_by_hand(pairs, int(k))
        assert overlap == len(a)
        if len(a) > 1:
            assert value == pytest.approx(np.corrcoef(a, b)[0, 1], abs=1e-10)
        else:
            assert np.isnan(value)


def test_a_delayed_copy_is_found_between_steps() -> None:
    t = np.arange(4000) * 0.01
    a = np.sin(0.7 * t) + 0.5 * np.sin(2.3 * t)
    late = 0.0437                                   # 4.37 steps
    b = np.sin(0.7 * (t - late)) + 0.5 * np.sin(2.3 * (t - late))
    peak = correlations([(a, b)], 20).peak()
    assert peak is not None and not peak.at_edge
    assert peak.steps == pytest.approx(4.37, abs=0.02)
    assert peak.correlation > 0.999


def test_no_pair_of_samples_spans_two_series() -> None:
    # each series alone is its own shift of the other; joined, a lag across the join would
    # compare the end of one with the start of the next
    rng = np.random.default_rng(1)
    x = np.cumsum(rng.normal(size=600))
    pairs = [(x[:300], np.roll(x, 5)[:300]), (x[300:], np.roll(x, 5)[300:])]
    peak = correlations(pairs, 10).peak()
    assert peak is not None and round(peak.steps) == 5


def test_a_lag_beyond_the_search_is_at_the_edge_and_a_flat_signal_has_none() -> None:
    rng = np.random.default_rng(2)
    x = np.cumsum(rng.normal(size=1000))
    peak = correlations([(x[50:-50], x[80:-20])], 10).peak()   # b is 30 steps ahead
    assert peak is not None and peak.at_edge and peak.steps == -10
    assert correlations([(np.ones(100), x[:100])], 5).peak() is None
    assert correlations([], 3).peak() is None


def test_unusable_lags_are_passed_over() -> None:
    rng = np.random.default_rng(3)
    x = np.cumsum(rng.normal(size=500))
    found = correlations([(x, x)], 5)
    assert found.peak().steps == pytest.approx(0.0, abs=1e-9)
    peak = found.peak(found.lags != 0)
    assert peak is not None and abs(peak.steps) == 1.0


def test_where_b_reaches_beyond_a_every_lag_compares_all_of_a() -> None:
    rng = np.random.default_rng(4)
    a = rng.normal(size=80)
    b = rng.normal(size=80 + 2 * 6)
    found = correlations([(a, b)], 6)
    assert (found.overlap == 80).all()
    for k, value in zip(found.lags, found.values, strict=True):
        window = b[6 + k:6 + k + 80]
        assert value == pytest.approx(np.corrcoef(a, window)[0, 1], abs=1e-10)
    with pytest.raises(ValueError, match="as many"):
        correlations([(a, b[:-1])], 6)


def test_the_tapered_estimate_divides_the_products_by_the_whole_series_energies() -> None:
    rng = np.random.default_rng(5)
    pairs = [(rng.normal(size=40) + 1.0, rng.normal(size=40)),
             (rng.normal(size=25), rng.normal(size=25) - 2.0)]
    found = correlations(pairs, 10, estimate="tapered")
    centred = [(a - a.mean(), b - b.mean()) for a, b in pairs]
    energy = np.sqrt(sum(a @ a for a, _ in centred) * sum(b @ b for _, b in centred))
    for k, value in zip(found.lags, found.values, strict=True):
        a, b = _pearson_by_hand(centred, int(k))
        assert value == pytest.approx(np.dot(a, b) / energy, abs=1e-12)
    # it shrinks with the lag: a copy's correlation falls off linearly with the samples lost
    x = np.cumsum(rng.normal(size=200))
    same = correlations([(x, x)], 20, estimate="tapered")
    assert same.values[20] == pytest.approx(1.0)
    assert np.all(same.values < 1.0 + 1e-12)


def test_sums_of_series_one_after_another_pool_into_their_correlation(
        rng: np.random.Generator) -> None:
    """The live path keeps each block's sums and pools them: the same correlation at every
    lag as the pairs taken together, whatever the centre the sums were taken about."""
    from odocal.correlation import correlation_sums, of_sums

    pairs = []
    for size in (300, 450, 120):
        a = rng.normal(0.1, 1.0, size)
        pairs.append((a, np.roll(a, 3) + rng.normal(0.2, 0.5, size)))
    whole = correlations(pairs, 10)
    pooled = of_sums(10, correlation_sums(pairs[:2], 10) + correlation_sums(pairs[2:], 10))
    np.testing.assert_allclose(pooled.values, whole.values, rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(pooled.overlap, whole.overlap)
    assert pooled.peak() is not None and pooled.peak().steps == pytest.approx(3.0, abs=0.2)
    centred = of_sums(10, correlation_sums(pairs, 10, centre=(0.1, 0.3)))
    np.testing.assert_allclose(centred.values, whole.values, rtol=1e-9, atol=1e-12)
