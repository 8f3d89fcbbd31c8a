"""The Cramér-Rao bound of a simulated drive: how well any unbiased calibration can do on it.

A simulated drive's wheel rates are the true ones plus errors whose law the noise profile gives.
Their Fisher information about theta is ``J' Sigma^-1 J``: ``J`` the derivative of the true wheel
rates (METHOD 1 inverted, at the true motion) with respect to theta, ``Sigma`` the covariance of
the wheel errors. Its inverse bounds the covariance of every unbiased estimator from below: an
error spread the bound already exceeds is out of reach for any unbiased method, not the fault
of one.

The wheel errors counted are those a noise profile draws as Gaussian processes
(:class:`odocal.sim.noise.NoiseProfile`):

* white noise, of a constant level and of a level proportional to the rate;
* first-order Gauss-Markov errors of each wheel (``wheel_markov_*``);
* slip: a Gauss-Markov ratio common to both wheels and one of each wheel's own, times the rate.

They are written as latent first-order processes (banded precision) and integrated out:
``J' W^-1 J - B' A^-1 B`` with ``W`` the white variances, ``A = Q + H' W^-1 H`` banded in time
(``Q`` the processes' precision, ``H`` how they enter the rates) and ``B = H' W^-1 J``. Everything
else a profile does is left out, and each of these left-out parts can only make the true bound
larger:

* the reference pose's errors (the bound takes the true motion as known), the IMU's and the
  sideslip's;
* a clock delay (taken as known).

White noise proportional to the rate is taken at the true rate (the simulator takes it at the
rate after slip and coloured noise; no profile draws both).

A profile that counts ticks (``ticks_per_rev``) has no bound here: the simulator adds its white
and coloured noise *after* the tick count, to rates that sit on a grid of ``1 / (ticks window
t_s)``, and noise much smaller than the grid step can be rounded away (on ``realistic`` every
sample's white noise can), so the counted noise would not bound anything.

Three things go the other way, and raise the computed bound above the true one a little:

* the information in the errors' *level* is left out (the level follows the rate, and so
  theta): where the noise is white and all proportional to the rate (a fraction f of it), the
  level says about ``2 / c_e^2`` per sample of c_e against ``1 / (f c_e)^2`` from the rates'
  mean (1e-4 of c_e's std at f = 1%); for slip, correlated over a second, it is far more:
  leaving it out raises c_e's std by 0.4% (``slip``) and 0.6% (``slip-heavy``);
* slip that follows the acceleration is left out; known, it would scale the signal by
  ``1 + k a_x`` and lower the bound by up to 0.16% (t_r on ``slip-heavy``);
* a white floor of 3% of the smallest process innovation's std keeps ``W`` invertible and the
  elimination well conditioned where a profile draws little or no white noise (a smaller
  floor loses more to rounding in ``J' W^-1 J - B' A^-1 B``); it raises c_d's std by 5e-4 on
  ``slip``, which draws none, and by less where there is white noise.

Samples at rest are read as 0 exactly by the simulated encoders and carry nothing.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.linalg import solveh_banded

from odocal.arrays import FloatArray
from odocal.model.kinematics import body_rates, wheel_rates_for
from odocal.model.parameters import PARAMETERS
from odocal.sim.noise import NoiseProfile

__all__ = ["applies", "information_bound", "wheel_information"]


_FLOOR = 3e-2          # white floor, relative to the smallest process innovation std
_FIXED_POINT = 8       # rounds of a_y = v w when the motion is recovered from the wheel rates


def _motion(theta: FloatArray, n_rl: FloatArray, n_rr: FloatArray
            ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """v, w and a_y = v w that the true wheel rates give (a fixed point in a_y)."""
    a_y = np.zeros_like(n_rl)
    for _ in range(_FIXED_POINT):
        v, w = body_rates(theta, n_rl, n_rr, a_y)
        a_y = v * w
    return v, w, a_y


def _rate_jacobian(theta: FloatArray, v: FloatArray, w: FloatArray, a_y: FloatArray
                   ) -> FloatArray:
    """d(n_rl, n_rr)/d theta at the given motion, shape (M, 2, n) (central differences)."""
    jac = np.empty((v.size, 2, theta.size))
    for j in range(theta.size):
        h = 1e-6 * max(1.0, abs(float(theta[j])))
        up, down = theta.copy(), theta.copy()
        up[j] += h
        down[j] -= h
        hi = np.column_stack(wheel_rates_for(up, v, w, a_y))
        lo = np.column_stack(wheel_rates_for(down, v, w, a_y))
        jac[:, :, j] = (hi - lo) / (2.0 * h)
    return jac


def _processes(profile: NoiseProfile, t_s: float) -> list[tuple[float, float, str, int]]:
    """The latent first-order processes: (std, phi, how it enters, wheel or -1 for both)."""
    out: list[tuple[float, float, str, int]] = []

    def add(std: float, tau: float, kind: str, wheels: tuple[int, ...]) -> None:
        if std > 0.0:
            phi = math.exp(-t_s / tau)
            out.extend((std, phi, kind, w) for w in wheels)

    add(profile.wheel_markov_revps, profile.wheel_markov_correlation_s, "additive", (0, 1))
    add(profile.slip_fraction, profile.slip_correlation_s, "slip", (-1,))
    add(profile.slip_differential / math.sqrt(2.0), profile.slip_correlation_s, "slip", (0, 1))
    return out


def applies(profile: NoiseProfile) -> bool:
    """Whether this bound applies to ``profile``: it draws a wheel error the bound counts, and
    no tick counting that the counted noise is added to."""
    return not profile.ticks_per_rev and bool(
        profile.wheel_white_revps or profile.wheel_white_fraction or profile.wheel_markov_revps
        or profile.slip_fraction or profile.slip_differential)


def wheel_information(theta: FloatArray, n_rl: FloatArray, n_rr: FloatArray,
                      profile: NoiseProfile, t_s: float) -> FloatArray:
    """Fisher information about theta, shape (n, n), in wheel rates with ``profile``'s errors.

    theta : the true parameters (c_e, c_d, t_r, d)
    n_rl, n_rr : the true (noise-free) wheel rates, rev/s, shape (M,)
    profile : the noise profile that corrupts them
    t_s : sampling time, s
    """
    theta = np.asarray(theta, dtype=np.float64)
    rates = np.column_stack([n_rl, n_rr]).astype(np.float64)
    v, w, a_y = _motion(theta, rates[:, 0], rates[:, 1])
    jac = _rate_jacobian(theta, v, w, a_y)
    seen = rates != 0.0                                   # (M, 2): encoders read 0 at rest
    processes = _processes(profile, t_s)

    white = profile.wheel_white_revps**2 + (profile.wheel_white_fraction * rates)**2
    if processes:
        smallest = min(std * math.sqrt(1.0 - phi**2) * (np.abs(rates).max() if kind == "slip"
                                                          else 1.0)
                       for std, phi, kind, _ in processes)
        white = white + (_FLOOR * smallest)**2
    if not applies(profile):
        raise ValueError(f"the bound does not apply to noise profile {profile.name!r} (no "
                         f"wheel error it counts, or tick counts under the noise)")
    inv_w = np.divide(1.0, white, out=np.zeros_like(rates), where=seen)     # (M, 2)

    info = np.einsum("mip,mi,miq->pq", jac, inv_w, jac)
    if not processes:
        return np.asarray(info)

    m, n_proc = rates.shape[0], len(processes)
    # H[k, i, l]: how process l at time k enters wheel i's rate
    h = np.zeros((m, 2, n_proc))
    for col, (_, _, kind, wheel) in enumerate(processes):
        for i in ((0, 1) if wheel < 0 else (wheel,)):
            h[:, i, col] = rates[:, i] if kind == "slip" else 1.0

    # A = Q + H' W^-1 H in upper banded form; unknowns ordered time-major (k * L + l)
    n = m * n_proc
    band = np.zeros((n_proc + 1, n))
    block = np.einsum("kil,ki,kij->klj", h, inv_w, h)     # (M, L, L), measurement part
    for lag in range(n_proc):                             # within a time step
        for low in range(n_proc - lag):
            col = low + lag
            band[n_proc - lag, col::n_proc] += block[:, low, col]
    for col, (std, phi, _, _) in enumerate(processes):    # AR(1) precision along time
        q = std**2 * (1.0 - phi**2)
        diag = np.full(m, (1.0 + phi**2) / q)
        diag[0] = diag[-1] = 1.0 / q
        band[n_proc, col::n_proc] += diag
        band[0, col + n_proc::n_proc] += -phi / q         # A[k L + col, (k+1) L + col]
    b = np.einsum("kil,ki,kip->klp", h, inv_w, jac).reshape(n, theta.size)
    info -= b.T @ solveh_banded(band, b)
    return np.asarray(info)


def information_bound(theta: FloatArray, n_rl: FloatArray, n_rr: FloatArray,
                      profile: NoiseProfile, t_s: float) -> FloatArray | None:
    """The Cramér-Rao bound: the inverse of :func:`wheel_information`, shape (n, n); infinite
    on the diagonal for a parameter the drive carries no information on (no bend: t_r, d).
    None where the bound does not apply (:func:`applies`)."""
    if not applies(profile):
        return None
    info = wheel_information(theta, n_rl, n_rr, profile, t_s)
    diag = np.diag(info)
    some = diag > 1e-12 * max(float(diag.max()), 1e-300)
    out = np.full((PARAMETERS, PARAMETERS), np.nan)
    np.fill_diagonal(out, np.inf)
    try:
        out[np.ix_(some, some)] = np.linalg.inv(info[np.ix_(some, some)])
    except np.linalg.LinAlgError:
        pass                                              # collinear: nothing bounded
    return out
