"""Calibrating while the vehicle drives: the default method, recursive and in bounded memory.

The paper closes with this plan (section 7): re-calibrate online from the signals measured while
driving. :class:`OnlineCalibrator` takes samples in any chunks (``push``) and answers at any time
(``estimate``) with the same :class:`~odocal.estimate.Estimate` as the batch methods.

It runs the default method's model (:mod:`odocal.estimators.inverse`): the wheel revolutions the
reference
motion implies, fitted to the measured ones, window by window. A window keeps only what the
model needs to predict it for *any* theta: the measured revolutions and moments of the
reference motion (``sum ds a^j``, ``sum dpsi a^j`` and the same across the heading, j = 0, 1,
2, at every whole-step shift of the reference side; the lateral acceleration
enters the circumferences through ``d a``, and ``1 / (c + d a)`` is a geometric series in
``d a / c`` whose third term is below 1e-7). So the fit is relinearised exactly over the recent
windows; older windows are folded into the normal equations (linearised at the estimate of the
moment: their error is of second order in how far theta has moved since, negligible once it
has converged), together with their clusters' scores for the sandwich covariance and their
residual moments for the noise model. Memory is a fixed ring of samples, a bounded list of
recent windows and a few sums, whatever the drive's length.

With ``forgetting_s`` set, older evidence fades with that time constant (a parameter that
drifts is tracked). Independently, a two-sided CUSUM watches each completed cluster's own
estimate of c_e and c_d against the running estimate: a step (tyre pressure, a tyre change)
raises an alarm with when, where and how much, and the estimate restarts from the new level.

The wheel stream's clock offset is found as in batch: the yaw channel's cost scanned over
shifts of the reference side (each window keeps its moments at every whole-step shift), theta
refitted at the lag found and the scan repeated until the lag settles; the counting window's
spread, the prewhitening of telescoping errors (the filter runs on across folded windows) and
the share of a common wheel error in the yaw channel (from moments that fold and can be had
at any later theta) are the batch method's too. Folded windows keep the weights, lag and
coupling of their time: on a 15-minute slip-dominated drive with 8 minutes of windows in
memory, t_r came out within 0.1 of batch's standard deviation; with 4 minutes, 1.4 of it.
The reference heading's offset against the direction of travel comes from the same one-second
straight stretches as in batch and is applied when windows are used (each keeps its moments
across the heading as well), so it is never stale.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from odocal.errors import DataError
from odocal.estimators.covariance import NEWEY_WEST, leverage_adjusted_scores, long_run_meat
from odocal.estimators.estimate import (
    CovarianceKind,
    Estimate,
    NotIdentified,
    Reason,
    Status,
    few_clusters_inflation,
    held_as_weak,
    judge,
    weak,
)
from odocal.estimators.inverse import (
    CHANNELS,
    arma_from_sums,
    correlation_sums,
    coupling_from_sums,
    coupling_gain,
    coupling_moments,
    coupling_sums,
    coupling_sums_at,
    decouple,
    expected_revolutions,
    noise_from_sums,
    noise_sums,
    prewhiten,
    window_variance,
    window_weights,
)
from odocal.model.parameters import PARAMETER_NAMES, Parameters
from odocal.settings import Settings

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

_P = 5        # theta and the wheel unit's counting-window spread (kappa), as in batch
_SHIFT_ROUNDS = 6       # lag and theta refitted in turn at most this often (as in batch)
_SHIFT_SETTLED = 1e-3   # steps
_COLUMNS = ("t", "n_rl", "n_rr", "a_y", "x", "y", "psi")


@dataclass(frozen=True)
class Alarm:
    """A change within the drive, found by the CUSUM on the clusters' own estimates.

    parameter : ``c_e`` or ``c_d``
    t : time of the first cluster after the change (the CUSUM's last reset), s
    detected_t : when the alarm rose, s
    distance_km, detected_distance_km : the same in driven distance
    relative_change : the step over the estimate before it (c_d: over c_e)
    sigmas : the step in standard deviations of one cluster's estimate
    """

    parameter: str
    t: float
    detected_t: float
    distance_km: float
    detected_distance_km: float
    relative_change: float
    sigmas: float

    def to_dict(self) -> dict[str, Any]:
        return {"parameter": self.parameter, "t": self.t, "detected_t": self.detected_t,
                "distance_km": self.distance_km, "detected_distance_km": self.detected_distance_km,
                "relative_change": self.relative_change, "sigmas": self.sigmas}


@dataclass(frozen=True)
class OnlineDetails:
    """What the online calibrator has seen and done."""

    samples: int
    windows: int
    windows_in_memory: int
    clusters: int
    distance_km: float
    delay_s: float
    heading_offset_rad: float
    noise: tuple[tuple[float, float], tuple[float, float]]
    alarms: tuple[Alarm, ...]
    forgetting_s: float | None
    coupling: float = 0.0
    """The common wheel error's share in the yaw channel (``beta``), as the batch method's."""

    def to_dict(self) -> dict[str, Any]:
        return {"samples": self.samples, "windows": self.windows,
                "windows_in_memory": self.windows_in_memory, "clusters": self.clusters,
                "distance_km": self.distance_km, "delay_s": self.delay_s,
                "heading_offset_rad": self.heading_offset_rad,
                "noise": {"distance": {"s0_rev": self.noise[0][0], "f": self.noise[0][1]},
                          "yaw": {"s0_rev": self.noise[1][0], "f": self.noise[1][1]}},
                "alarms": [a.to_dict() for a in self.alarms],
                "forgetting_s": self.forgetting_s,
                "coupling_beta": self.coupling}


def window_prediction(theta: FloatArray, moments: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Predicted revolutions (W, 2) and their Jacobian (W, 2, 4) from window moments.

    ``moments`` (W, 6): ``sum ds a^j`` (j = 0, 1, 2) then ``sum dpsi a^j``. With
    ``c_rl = C_l + d a``, ``C_l = c_e + c_d/2`` (and ``c_rr = C_r - d a``), (2)-(3) inverted give
    ``n_rl t_s = (ds - t_r dpsi / 2) / c_rl``; summed over the window and expanded to second order
    in ``d a / C``.
    """
    c_e, c_d, t_r, d = theta
    s0, s1, s2, q0, q1, q2 = moments.T
    out = np.empty((moments.shape[0], 2))
    jac = np.empty((moments.shape[0], 2, 4))
    for w, (big, sign) in enumerate(((c_e + 0.5 * c_d, 1.0), (c_e - 0.5 * c_d, -1.0))):
        e = sign * d / big                          # the load transfer, relative
        a0 = s0 - e * s1 + e * e * s2                # sum ds / (1 + e a)
        b0 = q0 - e * q1 + e * e * q2                # sum dpsi / (1 + e a)
        half = -sign * 0.5 * t_r                     # -t_r/2 for the left wheel, +t_r/2 right
        value = (a0 + half * b0) / big
        out[:, w] = value
        # derivatives of a0, b0 with respect to e, and of e with respect to big and d
        da0 = -s1 + 2.0 * e * s2
        db0 = -q1 + 2.0 * e * q2
        de_dbig = -e / big
        de_dd = sign / big
        dvalue_dbig = -value / big + (da0 + half * db0) / big * de_dbig
        dvalue_dd = (da0 + half * db0) / big * de_dd
        jac[:, w, 0] = dvalue_dbig                   # d big / d c_e = 1
        jac[:, w, 1] = sign * 0.5 * dvalue_dbig      # d big / d c_d = +-1/2
        jac[:, w, 2] = -sign * 0.5 * b0 / big
        jac[:, w, 3] = dvalue_dd
    return out, jac


def _added_meat(recent: FloatArray, new: FloatArray) -> FloatArray:
    """What clusters ``new`` add to the long-run covariance of the scores after ``recent`` (the
    latest clusters already counted): their outer products and cross products with each other
    and with ``recent``."""
    return long_run_meat(np.vstack([recent, new]), NEWEY_WEST) - long_run_meat(recent, NEWEY_WEST)


@dataclass
class _Folded:
    """Older windows, folded: normal equations in information form, scores, residual moments."""

    h: FloatArray = field(default_factory=lambda: np.zeros((_P, _P)))
    b: FloatArray = field(default_factory=lambda: np.zeros(_P))       # g0 + H0 p_lin
    meat: FloatArray = field(default_factory=lambda: np.zeros((_P, _P)))
    # the latest folded clusters' scores (as many as the covariance's cross products reach)
    recent: FloatArray = field(default_factory=lambda: np.zeros((0, _P)))
    clusters: int = 0
    # noise-model sums per channel: n, sum rev^2, sum rev^4, sum r^2, sum r^2 rev^2
    noise: FloatArray = field(default_factory=lambda: np.zeros((2, 5)))
    # the yaw channel's regression on the distance channel's residuals, as moments that give
    # its sums at any theta (inverse.coupling_moments)
    coupling: FloatArray = field(default_factory=lambda: np.zeros((2, 1 + _P, 1 + _P)))
    scan: FloatArray | None = None          # the yaw channel's cost at each shift of the scan
    cost: float = 0.0                        # weighted sum of squared residuals
    count: int = 0                           # residuals in it
    # the standardised residuals' correlation sums (prewhitening), per channel
    correlation: FloatArray = field(default_factory=lambda: np.zeros((2, 6)))
    # the last folded window, for the prewhitening to run on: p it was linearised at, its row
    # unfiltered and filtered ((2, 1 + P) each: residual, Jacobian), its start time
    last: tuple[FloatArray, FloatArray, FloatArray, float] | None = None

    def decay(self, factor: float) -> None:
        self.h *= factor
        self.b *= factor
        self.meat *= factor
        self.recent *= math.sqrt(factor)     # their products with newer clusters decay alike
        self.noise *= factor
        self.coupling *= factor
        self.correlation *= factor
        self.cost *= factor
        if self.scan is not None:
            self.scan *= factor


@dataclass
class _Cusum:
    """Two-sided CUSUM on standardised innovations (k: allowance, h: threshold)."""

    k: float
    h: float
    upper: float = 0.0
    lower: float = 0.0
    count: int = 0
    total: float = 0.0
    start_t: float = 0.0
    start_km: float = 0.0

    def update(self, z: float, t: float, km: float) -> bool:
        if self.upper == 0.0 and self.lower == 0.0:
            self.count, self.total, self.start_t, self.start_km = 0, 0.0, t, km
        self.upper = max(0.0, self.upper + z - self.k)
        self.lower = max(0.0, self.lower - z - self.k)
        self.count += 1
        self.total += z
        return self.upper > self.h or self.lower > self.h

    def reset(self) -> None:
        self.upper = self.lower = 0.0


class OnlineCalibrator:
    """Calibrate while driving: ``push`` samples in any chunks, ``estimate`` at any time.

    Parameters
    ----------
    settings : all settings (``[online]`` for the window memory, forgetting and the change
        detector; ``[inverse]`` for the window length and the clock-offset range; ``[identify]``
        for the datasheet values and the identifiability verdict)
    theta0 : the starting estimate (default: the datasheet values ``[identify] theta0``)
    """

    def __init__(self, settings: Settings | None = None,
                 theta0: Parameters | FloatArray | None = None) -> None:
        self.settings = settings or Settings()
        cfg = self.settings.online
        start = (np.asarray(self.settings.identify.theta0, dtype=np.float64) if theta0 is None
                 else (theta0.as_array() if isinstance(theta0, Parameters)
                       else np.asarray(theta0, dtype=np.float64)))
        if start.shape != (4,) or not np.all(np.isfinite(start)) or start[0] <= 0 \
                or start[2] <= 0:
            raise DataError(f"theta0 {start.tolist()} is not a usable starting estimate")
        self.datasheet = np.asarray(self.settings.identify.theta0, dtype=np.float64)
        self.theta = start.copy()
        # the batch method's wheel-stream model: the counting window's spread (fitted when the
        # lag is) and the prewhitening of errors that telescope across windows
        self._smooth = self.settings.inverse.delay == "estimate"
        self._kappa = 0.0
        self._ma = np.zeros((2, 2))
        # the yaw channel's share of the distance channel's errors, and the last fit's sums for it
        self._coupling = 0.0
        self._coupling_sums = np.zeros(2)
        self._origin = np.append(self.datasheet, 0.0)    # where the folded moments are taken
        self._u = np.zeros((0, 2))                       # standardised residuals of the last fit
        # the last fit's prewhitened Jacobian per window and its whole information
        self._white_jac = np.zeros((0, 2, _P))
        self._h_all: FloatArray | None = None
        self._t_s: float | None = None
        self._last: dict[str, float] | None = None     # the previous sample (continuity)
        self._ring = np.zeros((0, 9))                   # steps not yet in a window
        # windows in memory: head rows [t0, distance, cluster, measured rl, measured rr], the
        # motion moments at every whole-step shift of the reference side, and a weight
        self._head = np.zeros((0, 5))
        self._moments = np.zeros((0, 0, 9))
        self._weight = np.zeros(0)
        self._shift_cache: tuple[int, float, float] | None = None
        self._scan_centre: float | None = None          # where the last scan's minimum was
        self._folded = _Folded()
        self._noise = np.array([[1e-3, 1e-3], [1e-3, 1e-3]])
        self._samples = 0
        self._windows_total = 0
        self._distance_m = 0.0
        # heading offset, as validate.heading_offset: sums over one-second straight stretches
        # (lat, lon, samples) and the steps of the stretch under way (dx, dy, dpsi, psi)
        self._straight = np.zeros(3)
        self._stretch = np.zeros((0, 4))
        self._alarms: list[Alarm] = []
        self._clusters_done = 0
        self._fit_cost = (0.0, 0)
        self._peak_yaw = 0.0
        self._cusum = {"c_e": _Cusum(cfg.cusum_k, cfg.cusum_h),
                       "c_d": _Cusum(cfg.cusum_k, cfg.cusum_h)}
        self._cluster_scale: dict[str, list[float]] = {"c_e": [], "c_d": []}
        self._current_cluster = -1

    # ---------------------------------------------------------------- input

    def push(self, chunk: Mapping[str, Any] | Any) -> None:
        """Add samples: a mapping of drive-format column names to arrays, or a pandas DataFrame.

        Columns ``t, n_rl, n_rr, a_y, x, y, psi`` are required, ``beta`` is optional; ``t`` must
        increase. A gap longer than 1.5 sampling steps ends the current piece (windows never
        span a gap).
        """
        cols = {k: np.asarray(chunk[k], dtype=np.float64).ravel() for k in _COLUMNS
                if _has(chunk, k)}
        missing = [k for k in _COLUMNS if k not in cols]
        if missing:
            raise DataError(f"pushed samples lack column{'s' if len(missing) > 1 else ''} "
                            f"{', '.join(missing)}")
        n = cols["t"].size
        if n == 0:
            return
        beta = np.asarray(chunk["beta"], dtype=np.float64).ravel() if _has(chunk, "beta") \
            else np.zeros(n)
        for key, values in (*cols.items(), ("beta", beta)):
            if values.size != n:
                raise DataError(f"pushed column {key} has {values.size} samples, t has {n}")
            if not np.all(np.isfinite(values)):
                raise DataError(f"pushed column {key} holds NaN or infinite values")
        for key in ("n_rl", "n_rr"):
            if np.any(np.abs(cols[key]) > 100.0):
                raise DataError(f"pushed column {key} reaches {np.max(np.abs(cols[key])):.4g}: "
                                "wheel rates must be in rev/s")
        t = cols["t"]
        if np.any(np.diff(t) <= 0) or (self._last is not None and t[0] <= self._last["t"]):
            raise DataError("pushed samples' t must increase strictly (and continue the "
                            "previous chunk)")
        if self._t_s is None:
            steps = np.diff(t) if n > 1 else (np.array([t[0] - self._last["t"]])
                                              if self._last is not None else np.zeros(0))
            if steps.size == 0:                          # one sample so far: wait for more
                self._last = {k: float(v[0]) for k, v in cols.items()} | {"beta": float(beta[0])}
                self._samples += 1
                return
            self._t_s = float(np.median(steps))
        rows = np.column_stack([t, cols["n_rl"], cols["n_rr"], cols["a_y"], beta, cols["x"],
                                cols["y"], cols["psi"]])
        self._samples += n
        if self._last is not None:
            rows = np.vstack([self._last_row(), rows])
        self._last = dict(zip(("t", "n_rl", "n_rr", "a_y", "beta", "x", "y", "psi"),
                              rows[-1].tolist(), strict=True))
        # runs of samples without a gap; a gap ends the piece (no step, no window across it)
        gaps = np.flatnonzero(np.diff(rows[:, 0]) > 1.5 * self._t_s) + 1
        for k, run in enumerate(np.split(rows, gaps)):
            if k > 0:
                self._stretches(self._ring)              # the piece's last steps
                self._ring = np.zeros((0, 9))
                self._stretch = np.zeros((0, 4))
            if run.shape[0] >= 2:
                self._steps(run)

    def _last_row(self) -> FloatArray:
        assert self._last is not None
        return np.array([[self._last[k] for k in ("t", "n_rl", "n_rr", "a_y", "beta", "x", "y",
                                                  "psi")]])

    def _steps(self, run: FloatArray) -> None:
        """The steps between consecutive samples of a run: revolutions and reference motion."""
        assert self._t_s is not None
        t, n_rl, n_rr, a_y, beta, x, y, psi = run.T
        dpsi = np.remainder(np.diff(psi) + np.pi, 2.0 * np.pi) - np.pi
        h = psi[:-1] + 0.5 * dpsi + beta[:-1]
        dx, dy = np.diff(x), np.diff(y)
        ds = dx * np.cos(h) + dy * np.sin(h)
        self._distance_m += float(np.hypot(dx, dy).sum())
        # per step: time, measured revolutions (the rates at its start), motion, a_y, dx, dy, psi
        steps = np.column_stack([t[:-1], n_rl[:-1] * self._t_s, n_rr[:-1] * self._t_s, ds, dpsi,
                                 a_y[:-1], dx, dy, psi[:-1]])
        self._ring = np.vstack([self._ring, steps])
        length = max(round(self.settings.inverse.window_s / self._t_s), 1)
        margin = self._max_lag() + 1                     # one more step for kappa
        while self._ring.shape[0] >= length + 2 * margin + 1:
            self._window(length, margin)

    def _max_lag(self) -> int:
        """Whole steps the reference side may shift either way (``[inverse] max_delay_s``)."""
        assert self._t_s is not None
        return math.ceil(self.settings.inverse.max_delay_s / self._t_s - 1e-6)

    def _window(self, length: int, margin: int) -> None:
        """Close the oldest window of the ring: measured revolutions, and the motion moments
        at every whole-step shift of the reference side (the lag is chosen when estimating)."""
        assert self._t_s is not None
        ring = self._ring[:length + 2 * margin + 1]
        start = margin                                   # the window's wheel steps: [m, m + L)
        measured = ring[start:start + length, 1:3].sum(axis=0)
        # along and across the heading: the heading offset is applied when the windows are
        # used (it is known better the longer the drive)
        ds, lat, dpsi, a = ring[:, 3], _lateral(ring), ring[:, 4], ring[:, 5]
        columns = np.column_stack([ds, ds * a, ds * a * a, dpsi, dpsi * a, dpsi * a * a,
                                   lat, lat * a, lat * a * a])
        cum = np.vstack([np.zeros((1, 9)), np.cumsum(columns, axis=0)])
        shifts = np.arange(-margin, margin + 1)
        moments = cum[start - shifts + length] - cum[start - shifts]       # (S, 9)
        t0 = float(ring[start, 0])
        cluster = math.floor(t0 / (self.settings.segments.length * self._t_s))
        yaw = np.convolve(ring[start:start + length, 4] / self._t_s, np.full(5, 0.2), "valid")
        if yaw.size:
            self._peak_yaw = max(self._peak_yaw, float(np.max(np.abs(yaw))))
        # the straight stretches take the steps as they leave the ring (in step with the
        # windows, whatever the chunks)
        self._stretches(self._ring[:length])
        self._ring = self._ring[length:]
        if not np.any(measured):                        # standing still: no information
            return
        distance = self._distance_m - float(np.hypot(self._ring[:, 6], self._ring[:, 7]).sum())
        self._add_window(np.array([t0, distance, cluster, *measured]), moments)

    def _rows(self, shift: float, keep: NDArray[np.bool_] | None = None) -> FloatArray:
        """Windows in memory at a (fractional) shift: [t0, distance, cluster, measured (2),
        moments (6), weight, the moments' second difference in the shift (6)] per row."""
        head, moments, weight = self._head, self._moments, self._weight
        if keep is not None:
            head, moments, weight = head[keep], moments[keep], weight[keep]
        if head.shape[0] == 0:
            return np.zeros((0, 18))
        moments = self._rotated(moments)
        margin = (moments.shape[1] - 1) // 2
        x = min(max(shift, 1 - margin), margin - 1) + margin
        at = _interpolate(moments, x)
        second = _interpolate(moments, x + 1.0) + _interpolate(moments, x - 1.0) - 2.0 * at
        return np.column_stack([head, at, weight, second])

    def _rotated(self, moments: FloatArray) -> FloatArray:
        """Window moments (W, S, 9) as the model takes them (W, S, 6): the along-track ones
        turned by the heading offset (``ds cos + lateral sin``)."""
        offset = self.heading_offset()
        if offset == 0.0:
            return moments[..., :6]
        along = moments[..., 0:3] * math.cos(offset) + moments[..., 6:9] * math.sin(offset)
        return np.concatenate([along, moments[..., 3:6]], axis=-1)

    def _follows(self, rows: FloatArray) -> BoolArray:
        """Which windows start where the one before them ended (the first: the last folded)."""
        assert self._t_s is not None
        span = max(round(self.settings.inverse.window_s / self._t_s), 1) * self._t_s
        t0 = rows[:, 0]
        out = np.zeros(t0.size, dtype=bool)
        out[1:] = np.abs(np.diff(t0) - span) < 0.5 * self._t_s
        last = self._folded.last
        if last is not None and t0.size:
            out[0] = abs(t0[0] - last[3] - span) < 0.5 * self._t_s
        return out

    def _design(self, p: FloatArray, rows: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Channel residuals (W, 2) and their Jacobian in p (W, 2, P) of windows ``rows``."""
        n = rows.shape[0]
        both, jac = window_prediction(p[:4], np.concatenate([rows[:, 5:11], rows[:, 12:18]]))
        pred, second, jac = both[:n] + p[4] * both[n:], both[n:], jac[:n]
        r = (rows[:, 3:5] - pred) @ CHANNELS.T
        j = np.einsum("ci,wip->wcp", CHANNELS,
                      np.concatenate([jac, second[..., None]], axis=2))
        return r, j

    def _whiten(self, p: FloatArray, r: FloatArray, j: FloatArray, w: FloatArray,
                follows: BoolArray) -> tuple[FloatArray, FloatArray]:
        """Standardised rows ([residual, Jacobian] per channel), unfiltered and prewhitened, the
        filter continuing from the last folded window (moved to ``p`` to first order)."""
        sw = np.sqrt(w)
        stacked = np.concatenate([(r * sw)[..., None], j * sw[..., None]], axis=2)
        last = self._folded.last
        before = None
        if last is not None:
            moved = p - last[0]
            before = tuple(row - np.concatenate([(row[:, 1:] @ moved)[:, None],
                                                 np.zeros_like(row[:, 1:])], axis=1)
                           for row in (last[1], last[2]))
        return stacked, prewhiten(stacked, follows, self._ma, before)

    def _grid(self) -> FloatArray:
        limit = self._max_lag() if self._t_s is not None else 0
        return np.arange(-limit, limit + 0.25, 0.5)

    def _scan_costs(self, keep: NDArray[np.bool_] | None, theta: FloatArray,
                    index: NDArray[np.int64] | None = None) -> FloatArray:
        """The yaw channel's weighted cost at each shift of the grid (or its points ``index``)
        over windows ``keep``."""
        grid = self._grid() if index is None else self._grid()[index]
        head, moments, weight = self._head, self._moments, self._weight
        if keep is not None:
            head, moments, weight = head[keep], moments[keep], weight[keep]
        if head.shape[0] == 0:
            return np.zeros(grid.size)
        moments = self._rotated(moments)
        margin = (moments.shape[1] - 1) // 2
        x = grid + margin
        lo = np.minimum(np.floor(x).astype(np.int64), moments.shape[1] - 1)
        hi = np.minimum(lo + 1, moments.shape[1] - 1)
        frac = (x - lo)[None, :, None]
        at = moments[:, lo] * (1.0 - frac) + moments[:, hi] * frac       # (N, G, 6)
        n, g = at.shape[0], at.shape[1]
        measured = np.repeat(head[:, 3:5], g, axis=0)
        pred, _ = window_prediction(theta, at.reshape(n * g, 6))
        r = (measured - pred) @ CHANNELS.T
        gain = coupling_gain(measured, r, self._coupling)
        w = window_weights(measured, r, self._noise, gain) * np.repeat(weight, g)[:, None]
        return np.asarray((w[:, 1] * decouple(r, gain)[:, 1] ** 2).reshape(n, g).sum(axis=0))

    def shift(self, theta: FloatArray | None = None) -> tuple[float, float]:
        """The reference side's shift (steps) that fits the wheels best, and its std.

        As the batch method: the yaw channel's cost over a half-step grid (windows in memory
        plus folded ones) at ``theta`` (default: the running estimate), the minimum refined by
        a parabola, applied only beyond three standard deviations of zero.
        """
        if self._t_s is None or self.settings.inverse.delay == "off":
            return 0.0, float("nan")
        key = (self._windows_total, self._folded.clusters)
        if theta is None and self._shift_cache is not None \
                and self._shift_cache[0] == hash(key):
            return self._shift_cache[1], self._shift_cache[2]
        grid = self._grid()
        everywhere = np.arange(grid.size)
        # while driving, the scan around the last minimum (two steps either way) is enough;
        # estimate() scans the whole range, as batch does
        index = everywhere
        if theta is None and self._scan_centre is not None:
            index = np.flatnonzero(np.abs(grid - self._scan_centre) <= 2.0)
        for _ in range(2):
            costs = self._scan_costs(None, self.theta if theta is None else theta, index)
            if self._folded.scan is not None and self._folded.scan.size == grid.size:
                costs = costs + self._folded.scan[index]
            i = int(np.argmin(costs))
            if index.size == grid.size or 0 < i < index.size - 1:
                break
            index = everywhere                          # the minimum moved: look everywhere
        best, std = 0.0, float("nan")
        self._scan_centre = float(grid[index[i]])
        if 0 < index[i] < grid.size - 1:
            c0, c1, c2 = costs[i - 1:i + 2]
            curvature = (c0 - 2.0 * c1 + c2) / 0.25
            if curvature > 0:
                std = float(np.sqrt(2.0 / curvature))
                guess = float(grid[index[i]] + 0.25 * (c0 - c2) / (c0 - 2.0 * c1 + c2))
                best = guess if abs(guess) >= 3.0 * std else 0.0
        self._shift_cache = (hash(key), best, std)
        return best, std

    def delay_s(self) -> float:
        """The wheel stream's lag behind the reference that is applied (positive: late), s."""
        return self.shift()[0] * (self._t_s or 0.0)

    def heading_offset(self) -> float:
        """The reference heading's rotation against the direction of travel (rad), as batch
        finds it (:func:`odocal.estimators.validation.heading_offset`, applied from 200 samples of
        straights
        on)."""
        lat, lon, used = self._straight
        if self.settings.inverse.heading_offset != "estimate" or used < 200 or lon <= 0:
            return 0.0
        return float(math.atan2(lat, lon))

    def _stretches(self, steps: FloatArray) -> None:
        """Add the one-second stretches these steps complete to the straight sums (stretches
        start at the piece's first sample, as in batch; each summed whole, so that how the
        samples were chunked does not matter)."""
        assert self._t_s is not None
        size = max(round(1.0 / self._t_s), 1)
        pending = np.vstack([self._stretch, steps[:, [6, 7, 4, 8]]])
        whole = pending.shape[0] // size
        for part in pending[:whole * size].reshape(whole, size, 4):
            dx, dy, turn = part[:, 0].sum(), part[:, 1].sum(), part[:, 2].sum()
            dt = size * self._t_s
            psi = part[0, 3] + 0.5 * turn
            if math.hypot(dx, dy) / dt > 3.0 and abs(turn) / dt < 0.02:
                self._straight += [-dx * math.sin(psi) + dy * math.cos(psi),
                                   dx * math.cos(psi) + dy * math.sin(psi), size]
        self._stretch = pending[whole * size:]

    # ---------------------------------------------------------------- windows and folding

    def _add_window(self, head: FloatArray, moments: FloatArray) -> None:
        cfg = self.settings.online
        self._windows_total += 1
        cluster = int(head[2])
        if self._head.shape[0] and cluster != self._current_cluster \
                and self._current_cluster >= 0:
            self._cluster_done(self._current_cluster)
        self._current_cluster = cluster
        if cfg.forgetting_s:
            factor = math.exp(-self.settings.inverse.window_s / cfg.forgetting_s)
            self._folded.decay(factor)
            self._weight = self._weight * factor
        if self._moments.shape[0] == 0:
            self._moments = np.zeros((0, *moments.shape))
        self._head = np.vstack([self._head, head])
        self._moments = np.concatenate([self._moments, moments[None]])
        self._weight = np.append(self._weight, 1.0)
        if self._head.shape[0] > cfg.max_windows:
            self._fold()

    def _cluster_done(self, cluster: int) -> None:
        """A cluster is complete: the CUSUM compares its own estimate of c_e and c_d with the
        estimate from the clusters before it, which then takes it in."""
        shift = self.shift()[0]
        rows = self._rows(shift, self._head[:, 2] == cluster)
        self._clusters_done += 1
        if rows.shape[0] >= 3 and self._clusters_done > self.settings.online.warmup_clusters:
            self._watch(rows)
        # a running update from a warm start (estimate() solves to convergence), and of the
        # coupling, so that windows are folded with a current one
        self.theta, _, _ = self._solve(self.theta, self._rows(shift), np.ones(4, dtype=bool),
                                       iterations=3)
        self._update_coupling(self.theta)

    def _watch(self, rows: FloatArray) -> None:
        """The CUSUM step for one completed cluster's windows."""
        theta = self.theta
        r, j = self._design(np.append(theta, self._kappa), rows)
        w = 1.0 / window_variance(expected_revolutions(rows[:, 3:5], r), self._noise)
        gain = coupling_gain(rows[:, 3:5], r, self._coupling)
        r, j = decouple(r, gain), decouple(j, gain)
        for p, name in ((0, "c_e"), (1, "c_d")):
            info = float(np.sum(w * j[:, :, p] ** 2))
            if info <= 0:
                continue
            step = float(np.sum(w * j[:, :, p] * r)) / info
            z = step * math.sqrt(info)
            seen = self._cluster_scale[name]
            seen.append(z)
            if len(seen) > 200:
                seen.pop(0)
            scale = max(float(np.sqrt(np.mean(np.square(seen)))), 1.0) if len(seen) >= 10 \
                else 1.0 + 10.0 / len(seen)
            cusum = self._cusum[name]
            if cusum.update(z / scale, float(rows[0, 0]), float(rows[0, 1]) / 1000.0) \
                    and len(seen) >= 10:
                mean_z = cusum.total / max(cusum.count, 1)
                change = mean_z * scale / math.sqrt(info)
                self._alarms.append(Alarm(
                    parameter=name, t=cusum.start_t, detected_t=float(rows[-1, 0]),
                    distance_km=cusum.start_km, detected_distance_km=float(rows[-1, 1]) / 1000,
                    relative_change=change / theta[0], sigmas=mean_z))
                self._restart(p, change, cusum.start_t)
                return

    def _restart(self, index: int, change: float, since_t: float) -> None:
        """After a change: forget the evidence before it, start from the new level."""
        self.theta = self.theta.copy()
        self.theta[index] += change
        keep = self._head[:, 0] >= since_t
        self._head, self._moments, self._weight = (self._head[keep], self._moments[keep],
                                                   self._weight[keep])
        self._folded = _Folded()
        self._coupling_sums = np.zeros(2)                # (the error model itself carries on)
        self._clusters_done = 0                          # a new warm-up before watching again
        for c in self._cusum.values():
            c.reset()

    def _fold(self) -> None:
        """Fold the oldest complete cluster into the running sums (linearised at theta now)."""
        first = self._head[0, 2]
        count = int(np.sum(self._head[:, 2] == first))
        if count == self._head.shape[0]:
            count //= 2                                  # (one huge cluster: fold half)
        keep = np.arange(self._head.shape[0]) >= count
        shift = self.shift()[0]
        folded_scan = self._scan_costs(~keep, self.theta)
        rows = self._rows(shift, ~keep)
        self._head, self._moments, self._weight = (self._head[keep], self._moments[keep],
                                                   self._weight[keep])
        block = rows
        p = np.append(self.theta, self._kappa)
        r, j = self._design(p, block)
        gain = coupling_gain(block[:, 3:5], r, self._coupling)
        w = window_weights(block[:, 3:5], r, self._noise, gain) * block[:, 11:12]
        follows = self._follows(block)
        stacked, white = self._whiten(p, decouple(r, gain), decouple(j, gain), w, follows)
        jj, rr = white[..., 1:], white[..., 0]
        h = np.einsum("wcp,wcq->pq", jj, jj)
        g = np.einsum("wcp,wc->p", jj, rr)
        f = self._folded
        f.h += h
        f.b += g + h @ p
        # the cluster's score scaled up by its leverage in the whole fit so far (as in batch)
        total = self._h_all if self._h_all is not None else f.h
        g = leverage_adjusted_scores(h[None], g[None], np.append(np.ones(4, dtype=bool),
                                                                  self._smooth),
                                     np.zeros(1, dtype=np.int64), total=total)[0][0]
        f.meat += _added_meat(f.recent, g[None])
        f.recent = np.vstack([f.recent, g])[-len(NEWEY_WEST):]
        f.clusters += 1
        f.cost += float(np.sum(rr**2))
        f.count += r.size
        f.scan = folded_scan if f.scan is None or f.scan.size != folded_scan.size \
            else f.scan + folded_scan
        f.correlation += correlation_sums(decouple(r, gain) * np.sqrt(w), follows)
        f.last = (p, stacked[-1].copy(), white[-1].copy(), float(block[-1, 0]))
        f.noise += noise_sums(block[:, 3:5], r, gain)
        f.coupling += coupling_moments(block[:, 3:5], r, j, p - self._origin, w)

    # ---------------------------------------------------------------- output

    def estimate(self) -> Estimate:
        """The estimate now: theta, covariance, verdicts, status (as the batch methods give)."""
        ident = self.settings.identify
        held: dict[str, NotIdentified] = {}
        free = np.ones(4, dtype=bool)
        if self._peak_yaw <= self.settings.segments.yaw_rate_threshold_radps:
            # as in batch: t_r and d act on the yaw rate only in bends
            for name in ("t_r", "d"):
                held[name] = NotIdentified(Reason.NEEDS_BENDS, detail=self._peak_yaw)
                free[PARAMETER_NAMES.index(name)] = False
        if self._head.shape[0] + self._folded.clusters == 0:
            return self._nothing(Reason.NO_INFORMATION)
        shift = self.shift()[0]
        rows = self._rows(shift)
        theta = self.theta.copy()
        theta[~free] = self.datasheet[~free]
        for _ in range(_SHIFT_ROUNDS if rows.shape[0] else 0):
            for _ in range(2):
                # the prewhitening from the residuals (in memory and folded), as in batch
                theta, _, _ = self._solve(theta, rows, free)
                self._ma = arma_from_sums(self._folded.correlation
                                          + correlation_sums(self._u, self._follows(rows)))
                self._update_coupling(theta)
            # the lag again with this theta, until the two agree (as in batch)
            again = self.shift(theta)[0]
            if abs(again - shift) < _SHIFT_SETTLED:
                break
            shift = again
            rows = self._rows(shift)
        for _ in range(len(PARAMETER_NAMES) + 1):
            theta, h, scores = self._solve(theta, rows, free)
            cov, n_clusters = self._covariance(h, scores, rows, free)
            std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
            if n_clusters < 2:
                for j in np.flatnonzero(free):
                    held[PARAMETER_NAMES[j]] = NotIdentified(Reason.ONE_CLUSTER, float(std[j]),
                                                             detail=float(n_clusters))
                free[:] = False
                break
            too_weak = weak(std, free, ident)
            if not too_weak.any():
                break
            held.update(held_as_weak(std, too_weak, ident))
            free = free & ~too_weak
            theta[~free] = self.datasheet[~free]
        if not free.any():
            cov = np.zeros((4, 4))
        theta[~free] = self.datasheet[~free]
        if free.any():
            self.theta = theta.copy()
        std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        details = self._details()
        return Estimate(method="online", theta=Parameters.from_array(theta),
                        datasheet=Parameters.from_array(self.datasheet), covariance=cov,
                        covariance_kind=CovarianceKind.RECURSIVE,
                        free=tuple(bool(f) for f in free),  # type: ignore[arg-type]
                        verdicts=judge(std, free, ident, held=held),
                        status=Status.CONVERGED if free.any() else Status.NOTHING_IDENTIFIABLE,
                        details=details)

    def _update_coupling(self, theta: FloatArray) -> None:
        """The coupling from the folded windows' moments and the last fit's windows in memory
        (as batch, from the residuals at ``theta``)."""
        if self.settings.inverse.common_wheel_error == "estimate":
            self._coupling = coupling_from_sums(
                coupling_sums_at(self._folded.coupling,
                                 np.append(theta, self._kappa) - self._origin)
                + self._coupling_sums)

    def _solve(self, theta: FloatArray, rows: FloatArray, free: BoolArray,
               iterations: int = 8) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Gauss-Newton over the windows in memory and the folded normal equations, on the
        prewhitened residuals; theta (4,), and the information and per-window scores in p
        (theta and kappa, which it updates)."""
        f = self._folded
        p = np.append(theta, self._kappa)
        free_p = np.append(free, self._smooth)
        h = np.zeros((_P, _P))
        scores = np.zeros((0, _P))
        follows = self._follows(rows) if rows.shape[0] else np.zeros(0, dtype=bool)
        for _ in range(iterations):
            if rows.shape[0]:
                r, j = self._design(p, rows)
                gain = coupling_gain(rows[:, 3:5], r, self._coupling)
                self._noise = noise_from_sums(f.noise + noise_sums(rows[:, 3:5], r, gain))
                w = window_weights(rows[:, 3:5], r, self._noise, gain) * rows[:, 11:12]
                _, white = self._whiten(p, decouple(r, gain), decouple(j, gain), w, follows)
                jj, rr = white[..., 1:], white[..., 0]
                h = np.einsum("wcp,wcq->pq", jj, jj) + f.h
                per_window = np.einsum("wcp,wc->wp", jj, rr)
                self._white_jac, self._h_all = jj, h
                g = per_window.sum(axis=0) + f.b - f.h @ p
                scores = per_window
                self._fit_cost = (float(np.sum(rr**2)) + f.cost, r.size + f.count)
                self._u = decouple(r, gain) * np.sqrt(w)
                self._coupling_sums = coupling_sums(rows[:, 3:5], r, w)
            else:
                h, g = f.h.copy(), f.b - f.h @ p
            cols = np.flatnonzero(free_p)
            if cols.size == 0:
                break
            step = np.zeros(_P)
            step[cols] = np.linalg.lstsq(h[np.ix_(cols, cols)], g[cols], rcond=None)[0]
            p = p + step
            if np.max(np.abs(step) / np.maximum(np.abs(p), 1e-3)) < 1e-10:
                break
        if self._smooth:
            self._kappa = float(p[4])
        return p[:4], h, scores

    def _covariance(self, h: FloatArray, scores: FloatArray, rows: FloatArray,
                    free: BoolArray) -> tuple[FloatArray, int]:
        """Sandwich: folded clusters' meat plus the clusters in memory (cross products up to
        three clusters apart, Newey-West weights), as
        :func:`odocal.estimators.covariance.robust_covariance`."""
        f = self._folded
        free = np.append(free, self._smooth)
        cols = np.flatnonzero(free)
        h_inv = np.zeros((_P, _P))
        if cols.size:
            h_inv[np.ix_(cols, cols)] = np.linalg.pinv(h[np.ix_(cols, cols)])
        meat = f.meat.copy()
        n_clusters = f.clusters
        if rows.shape[0]:
            info = np.einsum("wcp,wcq->wpq", self._white_jac, self._white_jac)
            g, labels = leverage_adjusted_scores(info, scores, free, rows[:, 2].astype(np.int64),
                                                 total=h)
            n_clusters += labels.size
            meat += _added_meat(f.recent, g)
        meat[~free, :] = 0.0
        meat[:, ~free] = 0.0
        values, vectors = np.linalg.eigh(meat)
        meat = (vectors * np.clip(values, 0.0, None)) @ vectors.T
        correction = n_clusters / (n_clusters - 1) if n_clusters > 1 else 1.0
        cov = correction * (h_inv @ meat @ h_inv)
        if n_clusters < 10:
            # few clusters, as in batch: the larger of this and the residual-variance formula,
            # widened for the clusters' small number
            cost, count = self._fit_cost
            naive = cost / max(count - int(free.sum()), 1) * h_inv
            s_n = np.sqrt(np.clip(np.diag(naive), 0.0, None))
            s_r = np.sqrt(np.clip(np.diag(cov), 0.0, None))
            with np.errstate(divide="ignore", invalid="ignore"):
                f_ = np.where(s_n > 0, np.maximum(s_n, s_r) / s_n, 1.0)
            cov = naive * np.outer(f_, f_) * few_clusters_inflation(max(n_clusters, 2)) ** 2
        return cov[:4, :4], n_clusters

    def _details(self) -> OnlineDetails:
        return OnlineDetails(
            samples=self._samples, windows=self._windows_total,
            windows_in_memory=int(self._head.shape[0]),
            clusters=self._folded.clusters + int(np.unique(self._head[:, 2]).size),
            distance_km=self._distance_m / 1000.0, delay_s=self.delay_s(),
            heading_offset_rad=self.heading_offset(),
            noise=((float(self._noise[0, 0]), float(self._noise[0, 1])),
                   (float(self._noise[1, 0]), float(self._noise[1, 1]))),
            alarms=tuple(self._alarms), forgetting_s=self.settings.online.forgetting_s,
            coupling=float(self._coupling))

    def _nothing(self, reason: Reason) -> Estimate:
        theta = Parameters.from_array(self.datasheet)
        held = {n: NotIdentified(reason) for n in PARAMETER_NAMES}
        return Estimate(method="online", theta=theta, datasheet=theta,
                        covariance=np.zeros((4, 4)), covariance_kind=CovarianceKind.NONE,
                        free=(False, False, False, False),
                        verdicts=judge(np.zeros(4), np.zeros(4, dtype=bool),
                                       self.settings.identify, held=held),
                        status=Status.NOTHING_IDENTIFIABLE, details=self._details())

    def details_samples(self) -> int:
        """Samples pushed so far."""
        return self._samples

    @property
    def alarms(self) -> tuple[Alarm, ...]:
        return tuple(self._alarms)

    @property
    def distance_km(self) -> float:
        return self._distance_m / 1000.0


def _has(chunk: Any, key: str) -> bool:
    try:
        return key in chunk
    except TypeError:
        return False


def _lateral(ring: FloatArray) -> FloatArray:
    """Each step's displacement across the direction of travel (for a heading offset)."""
    h = ring[:, 8] + 0.5 * ring[:, 4]
    return -ring[:, 6] * np.sin(h) + ring[:, 7] * np.cos(h)


def _interpolate(moments: FloatArray, x: float) -> FloatArray:
    """Window moments (W, S, 6) at a fractional index ``x`` of their shifts."""
    lo = min(math.floor(x), moments.shape[1] - 1)
    frac = x - lo
    if frac == 0:
        return np.asarray(moments[:, lo])
    return np.asarray(moments[:, lo] * (1.0 - frac) + moments[:, lo + 1] * frac)
