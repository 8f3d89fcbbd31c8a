"""The same recording given twice: found by its samples, not by its bytes or its clock.

Two logs of one recording would count its evidence twice: every standard deviation shrinks by
the square root of two (a confident number from duplicated evidence). The bytes of a file say
little: the same samples as Parquet and as CSV, or a copy whose clock was shifted, differ in
every byte. So a drive's identity here is its samples:

* :func:`samples_digest`: the SHA-256 of what a drive holds apart from where its clock starts:
  the steps of its time stamps (to the microsecond) and every other column, bit for bit. The
  same samples in any file format, with the clock shifted by any amount, give the same digest.
* :func:`shared_stretch`: a *near* copy, one log holding a stretch of the other's samples
  (cut shorter, starting a sample later, re-saved with rounding or a little noise added). Found
  where the two logs' wheel rates agree, after the best shift, closer than the wheels' own noise
  over a stretch of driving: two recordings of the same motion differ by at least their two
  noises, one recording copied differs by less than one. Parked samples (wheels at rest agree
  in any two logs) are not counted.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from odocal.arrays import FloatArray
from odocal.data.drive import Drive

#: Seconds of driving two logs must share, sample for sample, to be named as copies.
MIN_SHARED_S = 30.0
#: Share of the shorter log's driving the stretch must cover as well.
MIN_SHARED_PART = 0.10
#: The copies' wheel rates agree within this share of the wheels' own noise.
NOISE_SHARE = 0.5
#: A wheel rate below this (rev/s) is a wheel at rest: samples where either log rests are not
#: compared.
MOVING_REVPS = 0.5
#: Block length (s) of the coarse search for the shift between two logs.
BLOCK_S = 1.0
#: Coarse shifts tried per pair (the best correlations), each refined sample by sample.
CANDIDATES = 3
#: A coarse shift is refined only where the block speeds correlate at least this well (a copy's
#: correlate to 0.999 and more: the noise averages out over a block; two drives seldom do).
MIN_BLOCK_CORRELATION = 0.95


def samples_digest(drive: Drive) -> str:
    """The SHA-256 of ``drive``'s samples, whatever the file format and the clock's origin."""
    digest = hashlib.sha256()
    steps = np.round(np.diff(drive.t) * 1e6).astype(np.int64)
    digest.update(steps.tobytes())
    for column in (drive.n_rl, drive.n_rr, drive.a_y, drive.beta, drive.x, drive.y, drive.psi):
        digest.update(np.ascontiguousarray(column, dtype=np.float64).tobytes())
    return digest.hexdigest()


def piece_digests(drive: Drive) -> dict[int, str]:
    """:func:`samples_digest` of each piece of ``drive`` (its stretches without a gap) that
    drives for :data:`MIN_SHARED_S` or more (two parked pieces may well hold the same
    samples), by the piece's index."""
    digests: dict[int, str] = {}
    for k, (a, b) in enumerate(drive.pieces):
        moving = np.abs(0.5 * (drive.n_rl[a:b] + drive.n_rr[a:b])) > MOVING_REVPS
        if moving.sum() * drive.t_s < MIN_SHARED_S:
            continue
        digest = hashlib.sha256()
        digest.update(np.round(np.diff(drive.t[a:b]) * 1e6).astype(np.int64).tobytes())
        for column in (drive.n_rl, drive.n_rr, drive.a_y, drive.beta, drive.x, drive.y,
                       drive.psi):
            digest.update(np.ascontiguousarray(column[a:b], dtype=np.float64).tobytes())
        digests[k] = digest.hexdigest()
    return digests


@dataclass(frozen=True)
class SharedStretch:
    """Two logs that share a stretch of samples.

    first, second : the drives' indices; start_first_s, start_second_s : where the stretch
    starts in each (s from the log's start); shared_s : its driving time; difference_revps :
    the RMS difference of their wheel rates over it; noise_revps : the wheels' own noise
    """

    first: int
    second: int
    start_first_s: float
    start_second_s: float
    shared_s: float
    difference_revps: float
    noise_revps: float


@dataclass(frozen=True)
class _Run:
    """One piece of one drive (a stretch without a gap), as the search compares them."""

    drive: int
    start: int                 # its first sample's index in the drive
    n_rl: FloatArray
    n_rr: FloatArray
    t_s: float

    @property
    def n_samples(self) -> int:
        return int(self.n_rl.size)


def wheel_noise_revps(n: FloatArray) -> float:
    """The wheel rates' own noise (rev/s): from the second differences of moving samples
    (white noise of sigma gives second differences of sigma sqrt(6); the motion, sampled at
    tens of Hz, adds little)."""
    if n.size < 3:
        return 0.0
    second = np.diff(n, 2)
    moving = np.abs(n[1:-1]) > MOVING_REVPS
    second = second[moving] if moving.sum() > 100 else second
    return float(1.4826 * np.median(np.abs(second - np.median(second))) / np.sqrt(6.0))


def _blocks(speed: FloatArray, size: int) -> FloatArray:
    count = speed.size // size
    return speed[:count * size].reshape(count, size).mean(axis=1) if count else speed[:0]


def _coarse_shifts(a: FloatArray, b: FloatArray, count: int, least: int) -> list[int]:
    """Block shifts k (b's block j against a's block j + k) where the block speeds correlate
    best (Pearson's correlation over the blocks the two share, at least ``least`` of them), by
    FFT and running sums."""
    if a.size < 2 or b.size < 2:
        return []
    n = int(2 ** np.ceil(np.log2(a.size + b.size)))
    products = np.fft.irfft(np.fft.rfft(a, n) * np.conj(np.fft.rfft(b, n)), n)
    # corr[k] = sum_j a[j + k] b[j] for k = -(len(b) - 1) .. len(a) - 1
    shifts = np.arange(-(b.size - 1), a.size)
    s_ab = np.concatenate([products[n - (b.size - 1):], products[:a.size]])
    ca = np.concatenate([[0.0], np.cumsum(a)])
    caa = np.concatenate([[0.0], np.cumsum(a * a)])
    cb = np.concatenate([[0.0], np.cumsum(b)])
    cbb = np.concatenate([[0.0], np.cumsum(b * b)])
    lo_b = np.maximum(0, -shifts)
    hi_b = np.minimum(b.size, a.size - shifts)
    count_k = (hi_b - lo_b).astype(np.float64)
    s_a = ca[hi_b + shifts] - ca[lo_b + shifts]
    s_aa = caa[hi_b + shifts] - caa[lo_b + shifts]
    s_b = cb[hi_b] - cb[lo_b]
    s_bb = cbb[hi_b] - cbb[lo_b]
    with np.errstate(divide="ignore", invalid="ignore"):
        cov = s_ab - s_a * s_b / count_k
        var = (s_aa - s_a**2 / count_k) * (s_bb - s_b**2 / count_k)
        r = np.where((count_k >= least) & (var > 0), cov / np.sqrt(np.abs(var)), -np.inf)
    order = np.argsort(r)[::-1][:count]
    return [int(shifts[i]) for i in order if r[i] >= MIN_BLOCK_CORRELATION]


def _compare(a: _Run, b: _Run, shift: int) -> tuple[float, int, int] | None:
    """At sample shift ``shift`` (b's sample j against a's j + shift): the RMS difference of
    the wheel rates where both logs drive, the number of such samples, and the first index in
    a; None without overlap."""
    lo_b = max(0, -shift)
    hi_b = min(b.n_samples, a.n_samples - shift)
    if hi_b - lo_b < 2:
        return None
    ia = slice(lo_b + shift, hi_b + shift)
    ib = slice(lo_b, hi_b)
    moving = ((np.abs(a.n_rl[ia]) > MOVING_REVPS) & (np.abs(b.n_rl[ib]) > MOVING_REVPS)
              & (np.abs(a.n_rr[ia]) > MOVING_REVPS) & (np.abs(b.n_rr[ib]) > MOVING_REVPS))
    count = int(moving.sum())
    if count == 0:
        return None
    d_rl = a.n_rl[ia][moving] - b.n_rl[ib][moving]
    d_rr = a.n_rr[ia][moving] - b.n_rr[ib][moving]
    rms = float(np.sqrt(0.5 * (np.mean(d_rl ** 2) + np.mean(d_rr ** 2))))
    return rms, count, lo_b + shift


def _refined(a: _Run, b: _Run, coarse: int, block: int) -> tuple[int, float, int, int] | None:
    """The sample shift near ``coarse * block`` with the smallest difference (every shift
    looked at on a strided subset at once, then the best one in full)."""
    shifts = np.arange(coarse * block - block, coarse * block + block + 1)
    lo_b = np.maximum(0, -shifts)
    hi_b = np.minimum(b.n_samples, a.n_samples - shifts)
    keep = hi_b - lo_b >= 2
    if not keep.any():
        return None
    shifts, lo_b, hi_b = shifts[keep], lo_b[keep], hi_b[keep]
    # the same 1000 (or fewer) places of b for every shift, within their common overlap
    lo, hi = int(lo_b.max()), int(hi_b.min())
    if hi - lo < 2:
        lo, hi = int(lo_b.min()), int(hi_b.max())
    j = np.unique(np.linspace(lo, hi - 1, min(1000, hi - lo)).astype(np.int64))
    ia = np.clip(j[None, :] + shifts[:, None], 0, a.n_samples - 1)
    rms = np.sqrt(np.mean((a.n_rl[ia] - b.n_rl[j]) ** 2 + (a.n_rr[ia] - b.n_rr[j]) ** 2,
                          axis=1))
    best = int(shifts[int(np.argmin(rms))])
    found = _compare(a, b, best)
    if found is None:
        return None
    rms_best, count, start_a = found
    return best, rms_best, count, start_a


def shared_stretch(drives: Sequence[Drive]) -> SharedStretch | None:
    """The first pair of pieces of two of ``drives`` (all of one sampling time) of which one
    holds a stretch of the other's samples (see the module docstring), or None. (The pieces of
    one drive are compared by their digests alone, :func:`piece_digests`: a log cut into
    pieces, by gaps or by ``--compare``'s time blocks, holds many.)"""
    if not drives:
        return None
    t_s = drives[0].t_s
    least = round(MIN_SHARED_S / t_s)
    runs = [_Run(i, a, d.n_rl[a:b], d.n_rr[a:b], d.t_s)
            for i, d in enumerate(drives) for a, b in d.pieces
            if b - a >= least]
    if len(runs) < 2:
        return None
    block = max(1, round(BLOCK_S / t_s))
    speeds = [_blocks(0.5 * (r.n_rl + r.n_rr), block) for r in runs]
    noise = [max(wheel_noise_revps(r.n_rl), wheel_noise_revps(r.n_rr)) for r in runs]
    for i in range(len(runs)):
        for j in range(i + 1, len(runs)):
            if runs[i].drive == runs[j].drive:
                continue              # (one drive's pieces: by their digests, piece_digests)
            found = _pair(runs[i], runs[j], speeds[i], speeds[j], block,
                          min(noise[i], noise[j]))
            if found is not None:
                shift, rms, count, start_a = found
                a, b = runs[i], runs[j]
                t_a, t_b = drives[a.drive].t, drives[b.drive].t
                return SharedStretch(
                    first=a.drive, second=b.drive,
                    start_first_s=float(t_a[a.start + start_a] - t_a[0]),
                    start_second_s=float(t_b[b.start + start_a - shift] - t_b[0]),
                    shared_s=count * t_s, difference_revps=rms,
                    noise_revps=min(noise[i], noise[j]))
    return None


def _pair(a: _Run, b: _Run, speed_a: FloatArray, speed_b: FloatArray, block: int,
          noise: float) -> tuple[int, float, int, int] | None:
    """(shift, RMS difference, shared samples, start in a) where ``b`` copies a stretch of
    ``a``, else None."""
    driving = min(float(np.sum(np.abs(0.5 * (d.n_rl + d.n_rr)) > MOVING_REVPS))
                  for d in (a, b)) * a.t_s
    need_s = max(MIN_SHARED_S, MIN_SHARED_PART * driving)
    scale = float(np.sqrt(np.mean(a.n_rl ** 2))) if a.n_samples else 0.0
    least = max(2, int(need_s / (block * a.t_s)))
    for coarse in _coarse_shifts(speed_a, speed_b, CANDIDATES, least):
        found = _refined(a, b, coarse, block)
        if found is None:
            continue
        _, rms, count, _ = found
        if count * a.t_s >= need_s and rms <= NOISE_SHARE * noise + 1e-9 * max(scale, 1.0):
            return found
    return None
