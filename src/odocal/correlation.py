"""The lag at which two signals agree best: their correlation at every lag, and its peak.

One definition for every clock the checks and the preprocessing search: the wheels' yaw rate
against the IMU's or the reference's, a_y against the reference's ``v w``, the reference's speed
against the wheels'. At lag ``k`` (``b`` behind ``a`` by ``k`` steps) ``a[i]`` is compared with
``b[i + k]`` over the samples both series hold, within each pair of series (a drive's pieces: no
pair of samples spans a gap), and the correlation is Pearson's over all the pairs' samples
pooled. Where ``b`` reaches ``span`` samples beyond ``a`` at both ends (``b[span + i]`` is
``a[i]``'s time), every lag compares the whole of ``a``. The numerators come from one FFT per
pair, the overlaps' sums from cumulative sums, so a search over thousands of lags costs a few
FFTs.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np

from odocal.arrays import BoolArray, FloatArray, IntArray


@dataclass(frozen=True)
class Correlations:
    """Pearson's correlation of ``a[i]`` with ``b[i + k]`` at every lag ``k`` of ``lags``
    (nan where the samples compared do not vary), and how many samples each compares."""

    lags: IntArray
    values: FloatArray
    overlap: IntArray

    def peak(self, usable: BoolArray | None = None) -> Peak | None:
        """The best lag among the ``usable`` ones (default: all), refined between steps by a
        parabola through its neighbours; None where no usable lag has a correlation."""
        values = np.where(np.isfinite(self.values), self.values, -np.inf)
        if usable is not None:
            values = np.where(usable, values, -np.inf)
        best = int(np.argmax(values))
        if not np.isfinite(values[best]):
            return None
        shift = 0.0
        if 0 < best < values.size - 1 and np.all(np.isfinite(values[best - 1:best + 2])):
            c0, c1, c2 = values[best - 1:best + 2]
            curvature = c0 - 2.0 * c1 + c2
            if curvature < 0:
                shift = 0.5 * (c0 - c2) / curvature
        return Peak(steps=float(self.lags[best] + shift), correlation=float(values[best]),
                    at_edge=best in (0, values.size - 1))


@dataclass(frozen=True)
class Peak:
    """The lag of ``b`` behind ``a`` (steps, refined), the correlation at the best whole step,
    and whether that step is the first or last searched (the true lag may lie beyond)."""

    steps: float
    correlation: float
    at_edge: bool


def correlations(pairs: Sequence[tuple[FloatArray, FloatArray]], span: int, *,
                 estimate: Literal["pearson", "tapered"] = "pearson") -> Correlations:
    """The correlation of each pair's ``a`` and ``b`` at every lag from ``-span`` to ``span``
    steps, pooled over the pairs (see the module docstring). ``b`` is as long as ``a``, or
    ``2 span`` longer (reaching ``span`` beyond it at both ends).

    ``estimate``: ``pearson`` is Pearson's over the samples compared at each lag; ``tapered``
    is the classical estimate (Box and Jenkins'): each pair centred on its own mean, the
    products of the samples compared summed and divided by the whole series' energies. It
    shrinks as the lag takes samples out, so it favours small lags: what a search of a few
    seconds over long pieces (a clock offset) is after; a search over half a series (a
    reference out of step by minutes) needs Pearson's.
    """
    lags = np.arange(-span, span + 1)
    if not pairs:
        return Correlations(lags, np.full(lags.size, np.nan), np.zeros(lags.size, np.int64))
    if estimate == "tapered":
        return _tapered(pairs, lags)
    # centred on the means of all samples (the pooled correlation does not change; the sums
    # keep their precision)
    mean_a = float(np.mean(np.concatenate([np.asarray(a, float) for a, _ in pairs])))
    mean_b = float(np.mean(np.concatenate([np.asarray(b, float) for _, b in pairs])))
    return of_sums(span, correlation_sums(pairs, span, centre=(mean_a, mean_b)))


def correlation_sums(pairs: Sequence[tuple[FloatArray, FloatArray]], span: int, *,
                     centre: tuple[float, float] = (0.0, 0.0)) -> FloatArray:
    """(6, 2 span + 1): per lag the count, sums, sums of squares and sum of products of the
    samples :func:`correlations` compares, ``centre`` taken from ``a`` and ``b``. Sums of
    series taken one after another add up (with one ``centre``): :func:`of_sums` makes their
    pooled correlation."""
    lags = np.arange(-span, span + 1)
    sums = np.zeros((6, lags.size))                   # n, sa, sb, saa, sbb, sab
    for a_in, b_in in pairs:
        a = np.asarray(a_in, dtype=np.float64) - centre[0]
        b = np.asarray(b_in, dtype=np.float64) - centre[1]
        if b.size == a.size + 2 * span:
            sums += _whole_sums(a, b, lags, span)
        elif b.size == a.size:
            sums += _overlap_sums(a, b, lags)
        else:
            raise ValueError(f"b holds {b.size} samples for a's {a.size}: as many, or "
                             f"{2 * span} more")
    return sums


def of_sums(span: int, sums: FloatArray) -> Correlations:
    """Pearson's correlation at every lag from ``-span`` to ``span`` of
    :func:`correlation_sums`' sums."""
    n, sa, sb, saa, sbb, sab = sums
    with np.errstate(divide="ignore", invalid="ignore"):
        cov = sab - sa * sb / n
        var = (saa - sa * sa / n) * (sbb - sb * sb / n)
        values = np.where((n > 1) & (var > 0), cov / np.sqrt(var), np.nan)
    return Correlations(np.arange(-span, span + 1), values, n.astype(np.int64))


def _tapered(pairs: Sequence[tuple[FloatArray, FloatArray]], lags: IntArray) -> Correlations:
    """:func:`correlations`' ``tapered`` estimate (pairs of equal lengths)."""
    products = np.zeros(lags.size)
    overlap = np.zeros(lags.size, dtype=np.int64)
    energy_a = energy_b = 0.0
    for a_in, b_in in pairs:
        a = np.asarray(a_in, dtype=np.float64)
        b = np.asarray(b_in, dtype=np.float64)
        if a.size != b.size:
            raise ValueError(f"b holds {b.size} samples for a's {a.size}: the tapered "
                             "estimate takes as many")
        a, b = a - a.mean(), b - b.mean()
        sums = _overlap_sums(a, b, lags)
        products += sums[5]
        overlap += sums[0].astype(np.int64)
        energy_a, energy_b = energy_a + float(a @ a), energy_b + float(b @ b)
    if energy_a <= 0 or energy_b <= 0:
        return Correlations(lags, np.full(lags.size, np.nan), overlap)
    return Correlations(lags, products / math.sqrt(energy_a * energy_b), overlap)


def _overlap_sums(a: FloatArray, b: FloatArray, lags: IntArray) -> FloatArray:
    """(6, lags): per lag the count, sums and sums of squares of ``a[i]`` and ``b[i + k]`` over
    the samples both hold, and the sum of their products."""
    size = a.size
    out = np.zeros((6, lags.size))
    inside = np.abs(lags) < size
    k = lags[inside]
    start_a, end_a = np.maximum(0, -k), size - np.maximum(0, k)
    start_b, end_b = np.maximum(0, k), size - np.maximum(0, -k)
    ca = np.concatenate([[0.0], np.cumsum(a)])
    cb = np.concatenate([[0.0], np.cumsum(b)])
    caa = np.concatenate([[0.0], np.cumsum(a * a)])
    cbb = np.concatenate([[0.0], np.cumsum(b * b)])
    fft_size = 1 << math.ceil(math.log2(max(2 * size, 2)))
    # sum_i a[i] b[i + k] at every lag by one FFT (zero-padded: no wrap-around)
    full = np.fft.irfft(np.conj(np.fft.rfft(a, fft_size)) * np.fft.rfft(b, fft_size), fft_size)
    out[0, inside] = end_a - start_a
    out[1, inside] = ca[end_a] - ca[start_a]
    out[2, inside] = cb[end_b] - cb[start_b]
    out[3, inside] = caa[end_a] - caa[start_a]
    out[4, inside] = cbb[end_b] - cbb[start_b]
    out[5, inside] = full[k % fft_size]
    return out


def _whole_sums(a: FloatArray, b: FloatArray, lags: IntArray, span: int) -> FloatArray:
    """:func:`_overlap_sums` where ``b`` reaches ``span`` beyond ``a`` at both ends: every lag
    compares all of ``a`` with ``b[span + k:][:a.size]``."""
    size = a.size
    out = np.zeros((6, lags.size))
    start = span + lags
    cb = np.concatenate([[0.0], np.cumsum(b)])
    cbb = np.concatenate([[0.0], np.cumsum(b * b)])
    fft_size = 1 << math.ceil(math.log2(max(a.size + b.size, 2)))
    full = np.fft.irfft(np.conj(np.fft.rfft(a, fft_size)) * np.fft.rfft(b, fft_size), fft_size)
    out[0] = size
    out[1] = a.sum()
    out[2] = cb[start + size] - cb[start]
    out[3] = float(a @ a)
    out[4] = cbb[start + size] - cbb[start]
    out[5] = full[start]
    return out
