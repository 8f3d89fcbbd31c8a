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
from numpy.typing import NDArray

from odocal.data.drive import Drive

FloatArray = NDArray[np.float64]

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


def samples_digest(drive: Drive) -> str:
    """The SHA-256 of ``drive``'s samples, whatever the file format and the clock's origin."""
    digest = hashlib.sha256()
    steps = np.round(np.diff(drive.t) * 1e6).astype(np.int64)
    digest.update(steps.tobytes())
    for column in (drive.n_rl, drive.n_rr, drive.a_y, drive.beta, drive.x, drive.y, drive.psi):
        digest.update(np.ascontiguousarray(column, dtype=np.float64).tobytes())
    return digest.hexdigest()


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


def _coarse_shifts(a: FloatArray, b: FloatArray, count: int) -> list[int]:
    """Block shifts k (b's block j against a's block j + k) where the block speeds correlate
    best, by FFT."""
    if a.size < 2 or b.size < 2:
        return []
    a0, b0 = a - a.mean(), b - b.mean()
    n = int(2 ** np.ceil(np.log2(a.size + b.size)))
    corr = np.fft.irfft(np.fft.rfft(a0, n) * np.conj(np.fft.rfft(b0, n)), n)
    # corr[k] = sum_j a0[j + k] b0[j] (k >= 0); negative shifts wrap to the end
    shifts = np.concatenate([np.arange(0, a.size), np.arange(-(b.size - 1), 0)])
    values = np.concatenate([corr[:a.size], corr[n - (b.size - 1):]])
    order = np.argsort(values)[::-1][:count]
    return [int(shifts[i]) for i in order]


def _compare(a: Drive, b: Drive, shift: int) -> tuple[float, int, int] | None:
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


def _refined(a: Drive, b: Drive, coarse: int, block: int) -> tuple[int, float, int, int] | None:
    """The sample shift near ``coarse * block`` with the smallest difference (a strided look
    first, then the best one in full)."""
    best: tuple[float, int] | None = None
    for shift in range(coarse * block - block, coarse * block + block + 1):
        lo_b = max(0, -shift)
        hi_b = min(b.n_samples, a.n_samples - shift)
        if hi_b - lo_b < 2:
            continue
        step = max(1, (hi_b - lo_b) // 4000)
        ia = slice(lo_b + shift, hi_b + shift, step)
        ib = slice(lo_b, hi_b, step)
        rms = float(np.sqrt(np.mean((a.n_rl[ia] - b.n_rl[ib]) ** 2)
                            + np.mean((a.n_rr[ia] - b.n_rr[ib]) ** 2)))
        if best is None or rms < best[0]:
            best = (rms, shift)
    if best is None:
        return None
    found = _compare(a, b, best[1])
    if found is None:
        return None
    rms, count, start_a = found
    return best[1], rms, count, start_a


def shared_stretch(drives: Sequence[Drive]) -> SharedStretch | None:
    """The first pair of ``drives`` (all of one sampling time) of which one holds a stretch of
    the other's samples (see the module docstring), or None."""
    if len(drives) < 2:
        return None
    t_s = drives[0].t_s
    block = max(1, round(BLOCK_S / t_s))
    speeds = [_blocks(0.5 * (d.n_rl + d.n_rr), block) for d in drives]
    noise = [max(wheel_noise_revps(d.n_rl), wheel_noise_revps(d.n_rr)) for d in drives]
    for i in range(len(drives)):
        for j in range(i + 1, len(drives)):
            found = _pair(drives[i], drives[j], speeds[i], speeds[j], block,
                          min(noise[i], noise[j]))
            if found is not None:
                shift, rms, count, start_a = found
                return SharedStretch(first=i, second=j, start_first_s=start_a * t_s,
                                     start_second_s=(start_a - shift) * t_s,
                                     shared_s=count * t_s, difference_revps=rms,
                                     noise_revps=min(noise[i], noise[j]))
    return None


def _pair(a: Drive, b: Drive, speed_a: FloatArray, speed_b: FloatArray, block: int,
          noise: float) -> tuple[int, float, int, int] | None:
    """(shift, RMS difference, shared samples, start in a) where ``b`` copies a stretch of
    ``a``, else None."""
    driving = min(float(np.sum(np.abs(0.5 * (d.n_rl + d.n_rr)) > MOVING_REVPS))
                  for d in (a, b)) * a.t_s
    need_s = max(MIN_SHARED_S, MIN_SHARED_PART * driving)
    scale = float(np.sqrt(np.mean(a.n_rl ** 2))) if a.n_samples else 0.0
    for coarse in _coarse_shifts(speed_a, speed_b, CANDIDATES):
        found = _refined(a, b, coarse, block)
        if found is None:
            continue
        _, rms, count, _ = found
        if count * a.t_s >= need_s and rms <= NOISE_SHARE * noise + 1e-9 * max(scale, 1.0):
            return found
    return None
