"""How far each published speed and yaw rate may be from the truth: the twist covariance.

The node publishes one odometry message per wheel message: the speed and yaw rate of (2a),
(2b) from that message's two wheel rates and the current calibration. Its error has three
parts, each measured, and the message states their sum (per channel, speed and yaw rate):

* **what one reading adds** (encoder quantisation, white noise): the fit's windows sum the
  readings over ``[inverse] window_s`` and average this away, so it is measured here, on the
  messages themselves: for readings whose errors are independent (or a tick count differenced
  over three samples or more), the second difference ``x[k+1] - 2 x[k] + x[k-1]`` has six
  times a reading's variance, and the motion adds next to nothing to it at a driver's rate.
  Its variance is fitted as ``a + b v^2`` over every message so far (a constant part and one
  growing with the speed, as the error model's);
* **what the fit measured** over its windows (slip, errors that last longer than a reading):
  the error model of the estimate, ``s0^2 + (f rev)^2`` revolutions per window at this speed,
  as the variance of the window's mean speed and yaw rate;
* **the calibration's own uncertainty**: the model's Jacobian of (v, w) in theta at this
  message's rates (:func:`odocal.model.step.increment_derivatives`) with the estimate's
  covariance.

Before an estimate (no measured noise) a message states an unknown variance (1e6).
"""

from __future__ import annotations

import numpy as np

from odocal.estimators.estimate import Estimate
from odocal.model.step import body, increment_derivatives
from odocal.model.vehicle import MODEL

#: The variance stated for what is not measured (before an estimate; what wheels do not see).
UNKNOWN_VARIANCE = 1.0e6
#: Steps between three messages that differ by more than this share are not a second
#: difference at the readings' rate.
_UNEVEN = 0.25
#: The reading noise's fit is solved anew after this many more second differences.
REFIT_EVERY = 64


class ReadingNoise:
    """The variance one wheel reading adds to the speed and the yaw rate, from the second
    differences of what is published: ``a + b v^2`` per channel, least squares over every
    message so far."""

    def __init__(self, max_gap_s: float) -> None:
        self.max_gap_s = max_gap_s
        self._prev: tuple[float, float, float] | None = None
        self._prev2: tuple[float, float, float] | None = None
        # sums of 1, v^2, v^4 and of y, y v^2 per channel (y: the squared second difference / 6)
        self._s = [0.0, 0.0, 0.0]
        self._y = [[0.0, 0.0], [0.0, 0.0]]
        self._fitted: tuple[tuple[float, float], tuple[float, float]] | None = None
        self._fitted_at = 0.0

    def add(self, t: float, v: float, w: float) -> None:
        p1, p2 = self._prev, self._prev2
        self._prev2, self._prev = p1, (t, v, w)
        if p1 is None or p2 is None:
            return
        t1, v1, w1 = p1
        t2, v2, w2 = p2
        step1, step2 = t1 - t2, t - t1
        gap = self.max_gap_s
        if not (0.0 < step1 <= gap and 0.0 < step2 <= gap) or abs(step2 - step1) > _UNEVEN * step1:
            return
        vv = v1 * v1
        s = self._s
        s[0] += 1.0
        s[1] += vv
        s[2] += vv * vv
        y_v, y_w = (v - 2.0 * v1 + v2) ** 2 / 6.0, (w - 2.0 * w1 + w2) ** 2 / 6.0
        speed, yaw = self._y
        speed[0] += y_v
        speed[1] += y_v * vv
        yaw[0] += y_w
        yaw[1] += y_w * vv

    @property
    def count(self) -> int:
        return int(self._s[0])

    def coefficients(self) -> tuple[tuple[float, float], tuple[float, float]] | None:
        """((a, b) for the speed, (a, b) for the yaw rate), each part at least zero; None
        before ten second differences. Solved anew every :data:`REFIT_EVERY` differences."""
        if self._fitted is None or self._s[0] - self._fitted_at >= REFIT_EVERY:
            self._fitted, self._fitted_at = self._solve(), self._s[0]
        return self._fitted

    def _solve(self) -> tuple[tuple[float, float], tuple[float, float]] | None:
        n, s2, s4 = self._s
        if n < 10:
            return None
        det = n * s4 - s2 * s2
        out = []
        for y0, y2 in self._y:
            a = b = -1.0
            if det > 1e-12 * max(n * s4, 1e-300):
                a, b = (s4 * y0 - s2 * y2) / det, (n * y2 - s2 * y0) / det
            if a < 0.0 or b < 0.0:           # one part alone: the one that fits
                b_only = y2 / s4 if s4 > 0 else 0.0
                a_only = y0 / n
                a, b = ((a_only, 0.0) if b < 0.0 or s4 <= 0 else (0.0, b_only))
            out.append((float(a), float(b)))
        return out[0], out[1]

    def reset(self) -> None:
        self.__init__(self.max_gap_s)  # type: ignore[misc]


class TwistVariance:
    """The twist variances stated in each published odometry message (see the module)."""

    def __init__(self, *, window_s: float, max_gap_s: float) -> None:
        self.window_s = window_s
        self.readings = ReadingNoise(max_gap_s)
        self._fit: tuple[tuple[float, float], tuple[float, float]] | None = None
        self._quadratic: tuple[tuple[float, ...], tuple[float, ...]] | None = None

    def calibrate(self, est: Estimate | None) -> None:
        """Take the error model and covariance of ``est`` (None: nothing is known)."""
        if est is None or est.details is None:
            self._fit, self._quadratic = None, None
            return
        noise = np.asarray(getattr(est.details, "noise", np.full((2, 2), np.nan)), dtype=float)
        th = est.theta.as_array()
        if not np.all(np.isfinite(noise)):
            self._fit, self._quadratic = None, None
            return
        gain_v, gain_w = MODEL.channel_gains(th)     # [c_e, c_e / t_r] for the rear axle
        window = self.window_s
        # (window mean) speed: (g_v / W)^2 (s0^2 + (f rev)^2), rev = |v| W / g_v; yaw: g_w's
        self._fit = ((float((gain_v * noise[0, 0] / window) ** 2), float(noise[0, 1] ** 2)),
                     (float((gain_w * noise[1, 0] / window) ** 2),
                      float((gain_w / gain_v * noise[1, 1]) ** 2)))
        self._quadratic = _parameter_terms(th, np.asarray(est.covariance, dtype=float))

    def variances(self, v: float, n_rl: float, n_rr: float, a_y: float) -> tuple[float, float]:
        """The speed's and the yaw rate's variance for a message (``v`` its speed, m/s)."""
        fit, readings = self._fit, self.readings.coefficients()
        if fit is None or readings is None:
            return UNKNOWN_VARIANCE, UNKNOWN_VARIANCE
        v2 = v * v
        var_v = readings[0][0] + readings[0][1] * v2 + fit[0][0] + fit[0][1] * v2
        var_w = readings[1][0] + readings[1][1] * v2 + fit[1][0] + fit[1][1] * v2
        q = self._quadratic
        if q is not None:
            z0, z1, z2, z3 = n_rl, n_rr, a_y * n_rl, a_y * n_rr
            for channel, c in enumerate(q):    # z' Q z, the upper triangle in row order
                part = (z0 * (c[0] * z0 + c[1] * z1 + c[2] * z2 + c[3] * z3)
                        + z1 * (c[4] * z1 + c[5] * z2 + c[6] * z3)
                        + z2 * (c[7] * z2 + c[8] * z3) + c[9] * z3 * z3)
                if channel == 0:
                    var_v += part
                else:
                    var_w += part
        return var_v, var_w


def _parameter_terms(th: np.ndarray, covariance: np.ndarray
                     ) -> tuple[tuple[float, ...], tuple[float, ...]] | None:
    """The calibration's share of the variances as quadratic forms in
    ``z = (n_rl, n_rr, a_y n_rl, a_y n_rr)``: (2a) and (2b) and their Jacobian in theta are
    linear in z, so ``J = G z`` with G found from the model's Jacobian at four points, and the
    variance is ``z' G' Sigma G z``. Returned per channel (speed, yaw rate) as the coefficients
    of ``z_i z_j`` for ``i <= j`` in row order (None: no covariance)."""
    sigma = np.where(np.isfinite(covariance), covariance, 0.0)
    if not sigma.any():
        return None
    out = np.zeros((3, 6))
    columns = []
    for n_rl, n_rr, a_y in ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (1.0, 0.0, 1.0),
                            (0.0, 1.0, 1.0)):
        v, w, c_rl, c_rr = body(th, n_rl, n_rr, a_y)
        increment_derivatives(th, n_rl, n_rr, a_y, v, w, c_rl, c_rr, v, 0.0, 1.0, 0.0, 1.0,
                              out)
        columns.append(out[[0, 2], 2:].copy())       # d(v, w) / d theta at this point
    g = np.stack([columns[0], columns[1], columns[2] - columns[0], columns[3] - columns[1]],
                 axis=-1)                             # (2, theta, z)
    forms = []
    for channel in range(2):
        q = g[channel].T @ sigma @ g[channel]
        n = q.shape[0]
        forms.append(tuple(float(q[i, j] * (1.0 if i == j else 2.0))
                           for i in range(n) for j in range(i, n)))
    return forms[0], forms[1]
