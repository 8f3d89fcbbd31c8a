"""The four-wheel car's front axle and steering (issue 37), fitted on the motion the rear
axle's default fit settled.

The wheels of the two axles share no parameter but the load transfer ``d``
(:mod:`odocal.model.four_wheel`): given the reference motion, the front wheels' revolutions
and the steering-wheel angle depend on ``c_f, c_fd, t_f, L, ratio, s_0`` and ``d`` alone. So
the four-wheel calibration is the default method's rear-axle fit (its lag, departures, error
model and sandwich, unchanged) and this fit of the front axle and the steering on the same
motion: the reference on the wheels' clock (the lag the rear fit found), with the departures
it fitted taken out, turned by its heading offset.

``d`` is fitted here too, with the rear fit's estimate as its prior (its value and std): the
front wheels' own evidence on it joins the rear axle's, and the rear axle's other parameters
follow by their covariance with it (:func:`joined`: the two fits' Gaussian summaries joined,
which is the joint fit where the axles' errors are independent). It matters: in bends the
front wheels' difference moves with ``t_f``, ``d`` and ``L`` alike, and holding ``d`` at the
rear's value would leave its whole uncertainty in ``L`` and ``t_f``. Where the rear fit does
not identify ``d`` it stays held, its datasheet uncertainty carried into the front parameters
(``-H^-1 H_d`` times it), as is that of every front parameter the drives do not identify: a
free parameter that cannot be told from a held one carries its uncertainty.

The channels of a window (``window_s``, as the default's): the front wheels' mean and
difference revolutions (the rear axle's channels, on the front axle) and the mean
steering-wheel angle over its moving steps. Each channel is weighted by its robust residual
scale, refitted; windows beyond :data:`OUTLIER` scales in a channel are left out of the final
fit. The covariance is the default's: the sandwich over clusters of windows (errors that last
seconds stay in one), widened by Student's t for the clusters each parameter rests on, never
below the residual-variance formula.

The wheelbase is estimated by the front wheels alone (their path around a bend is ``hypot(ds
- t_f dpsi / 2, L dpsi)``): at small angles the steering says ``ratio L`` only, and the little
it says of L by itself is what an unmodelled steering (understeer, a ratio that varies with
the angle) moves first. The steering's equations estimate the ratio and the offset; the
sandwich carries L's uncertainty into the ratio.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from odocal.arrays import BoolArray, FloatArray, IntArray
from odocal.checks.departures import shifted_reference
from odocal.checks.findings import Check, Diagnosis, Finding, Severity
from odocal.correlation import Correlations, correlations
from odocal.data.drive import Drive, derivative_pieces
from odocal.errors import DataError
from odocal.estimators.covariance import widened
from odocal.estimators.departures import FRONT_MIN_M, curve_excess, excess_doubt
from odocal.estimators.estimate import Estimate, Identified, NotIdentified, Reason, Verdict
from odocal.estimators.windows import MOVING_MPS, cluster_steps_for
from odocal.model.four_wheel import FOUR_WHEEL_MODEL
from odocal.model.kinematics import midpoint_heading
from odocal.model.parameters import Parameters
from odocal.settings import MAX_DIFFERENCE_SHARE, Settings

LAYOUT = FOUR_WHEEL_MODEL.layout
#: The parameters this fit estimates, and where theta holds them.
FRONT: tuple[str, ...] = FOUR_WHEEL_MODEL.front_names
_FRONT = np.array(LAYOUT.indices(FRONT))
_LOAD = LAYOUT.index(LAYOUT.load)
#: The traction slip's place in the working vector ``p = [theta, traction]``: the front
#: wheels' revolutions times ``1 + traction a_x`` (a driven axle slips as it pulls, a braked
#: one as it brakes: 1/(m/s^2)), fitted beside the parameters, not one of them.
_K = LAYOUT.size
#: What the fit solves for: the front parameters, then d (with its prior), the traction.
_FIT = np.concatenate([_FRONT, [_LOAD, _K]])
_D = len(FRONT)
_RATIO = FRONT.index("ratio")
#: The traction's prior: none expected, a percent per m/s^2 allowed.
TRACTION_STD = 0.01
#: The channels: the front wheels' mean and difference (right minus left) revolutions, the
#: mean steering-wheel angle.
CHANNELS = ("front mean", "front difference", "steering")
#: A window beyond this many robust scales in any channel is left out of the final fit ...
OUTLIER = 5.0
#: ... unless more than this share of the channel's windows are.
MAX_OUTLIER_SHARE = 0.05
#: Rounds of judging, fitting and rescaling the channels.
ROUNDS = 4
#: The least residual scale of each channel (rev, rev, rad): a measurement is never taken as
#: exact (a channel that fits to the last bit, a constant column, would weigh without bound).
SCALE_FLOOR = (1e-5, 1e-5, 2e-5)
#: The model runs on sub-steps of about this long (s): :func:`_substep`.
SUBSTEP_S = 0.1
#: Gauss-Newton steps per round at most, and the relative step that ends them.
MAX_STEPS, STEP_TOLERANCE = 50, 1e-10


@dataclass(frozen=True)
class FrontWindows:
    """Windows of steps: the reference motion per step and what was measured per window.

    ds, dpsi, a_y : (N, q) each sub-step's motion along track (m), in heading (rad) and its
        mean lateral acceleration (a window of k steps in q sub-steps: :func:`_substep`)
    a_x : (N, q) each sub-step's mean acceleration along track (m/s^2, the reference's)
    revolutions : (N, 2) the front left and right wheels' revolutions over the window
    steer : (N, q) each sub-step's mean steering-wheel angle (rad; NaN where not measured or
        a step of it barely moves)
    cluster : (N,) the windows' clusters (neighbouring windows share their errors)
    """

    ds: FloatArray
    dpsi: FloatArray
    a_y: FloatArray
    a_x: FloatArray
    revolutions: FloatArray
    steer: FloatArray
    cluster: IntArray
    steering_lag_s: tuple[float, ...] = ()
    """Each drive's steering lag behind the reference that was found and taken out."""
    heading_noise: FloatArray | None = None
    """(N,) the reference heading's sample-to-sample noise (rad) of each window's piece
    (:func:`heading_noise`); None: not known."""
    excess: FloatArray | None = None
    """(N,) the wheels' excess travel in bends over the reference's point (m) that the rear
    fit found (its ``curve`` departure: the front wheels were read without it) or that its
    lever arm gives (:func:`~odocal.estimators.departures.excess_doubt`); None: none (the fit
    carries how far it would move with it as a systematic error)."""

    @property
    def size(self) -> int:
        return int(self.ds.shape[0])

    @staticmethod
    def concat(parts: Sequence[FrontWindows]) -> FrontWindows | None:
        """The windows of ``parts`` (made alike: one window length and grid) in one set, each
        part's clusters its own; None where no part holds a window."""
        held = [w for w in parts if w.size]
        if not held:
            return None
        own = [w.cluster - w.cluster.min() for w in held]
        base = np.cumsum([0, *(int(c.max()) + 1 for c in own[:-1])])
        noise = [w.heading_noise if w.heading_noise is not None else np.full(w.size, np.nan)
                 for w in held]
        excess = ([w.excess if w.excess is not None else np.zeros(w.size) for w in held]
                  if any(w.excess is not None for w in held) else None)
        def joined(key: str) -> FloatArray:
            return np.concatenate([getattr(w, key) for w in held])

        return FrontWindows(joined("ds"), joined("dpsi"), joined("a_y"), joined("a_x"),
                            joined("revolutions"), joined("steer"),
                            cluster=np.concatenate([c + b for c, b in zip(own, base,
                                                                          strict=True)]),
                            steering_lag_s=tuple(x for w in held for x in w.steering_lag_s),
                            heading_noise=np.concatenate(noise),
                            excess=None if excess is None else np.concatenate(excess))

    def measured(self) -> FloatArray:
        """(N, 3): the channels' measurements (:data:`CHANNELS`; the steering's NaN where a
        window has no moving step with an angle)."""
        fl, fr = self.revolutions[:, 0], self.revolutions[:, 1]
        known = np.isfinite(self.steer)
        count = known.sum(axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            angle = np.where(known, self.steer, 0.0).sum(axis=1) / count
        return np.column_stack([0.5 * (fl + fr), fr - fl, np.where(count > 0, angle, np.nan)])


def front_windows(drives: Sequence[Drive], settings: Settings, *, delay_s: float = 0.0,
                  heading_offset: float = 0.0, steering_lag_s: float | None = None,
                  curve: float = 0.0) -> FrontWindows:
    """The drives' windows of ``[inverse] window_s`` (the default method's), piece by piece:
    the reference delayed by ``delay_s`` (the wheels' lag behind it) and its heading turned by
    ``heading_offset`` onto the course, as the default fit found them. Windows that do not
    move (a mean speed below :data:`~odocal.estimators.windows.MOVING_MPS`) say nothing and
    are left out, as are drives without front wheels (:func:`require_front_wheels` names a
    set with none). The steering angle is put on the reference's clock by its own lag
    (:func:`steering_lag`): a steering sensor's latency is not the wheels'. ``steering_lag_s``:
    that lag as found already (on more driving than a drive: the live path's), for every
    drive. ``curve``: the excess in bends the front fit doubts (m^2,
    :func:`~odocal.estimators.departures.excess_doubt`: the rear fit's ``curve`` departure,
    which :func:`~odocal.estimators.departures.corrected` took out of the front wheels, or its
    lever arm's): each window's share of it is kept (:attr:`FrontWindows.excess`)."""
    require_front_wheels(drives)
    parts: dict[str, list[FloatArray]] = {k: [] for k in ("ds", "dpsi", "a_y", "a_x", "revs",
                                                          "steer", "cluster", "noise",
                                                          "excess")}
    lags = []
    for index, drive in enumerate(drives):
        if "n_fl" not in drive.inputs or "n_fr" not in drive.inputs:
            continue
        if delay_s:
            drive = shifted_reference(drive, delay_s)
        if steering_lag_s is None:
            steer, lag = steering_lag(drive)
        else:
            lag = steering_lag_s if "steer" in drive.inputs else None
            steer = steering_at(drive, steering_lag_s) if lag is not None else None
        if lag is not None:
            lags.append(lag)
        # clustered drive by drive, as the rear fit's windows are: a drive added changes
        # nothing of the others' clusters, and a short scene is several clusters, not a share
        # of one pooled over every drive
        cluster_s = cluster_steps_for([drive], settings) * drive.t_s
        _add_windows(parts, drive, steer, settings.inverse.window_s, heading_offset,
                     index * 10**9, cluster_s, curve)
    if not parts["ds"]:
        empty = np.zeros((0, 1))
        return FrontWindows(empty, empty, empty, empty, np.zeros((0, 2)), empty,
                            np.zeros(0, dtype=np.int64), tuple(lags), np.zeros(0))
    cat = {k: np.concatenate(v) for k, v in parts.items()}
    return FrontWindows(cat["ds"], cat["dpsi"], cat["a_y"], cat["a_x"], cat["revs"],
                        cat["steer"], cat["cluster"].astype(np.int64), tuple(lags),
                        cat["noise"], excess=cat["excess"] if curve else None)


def require_front_wheels(drives: Sequence[Drive]) -> None:
    """A one-line DataError where no drive carries both front wheels' rates (the four-wheel
    model fits its front axle on those that do)."""
    if not any("n_fl" in d.inputs and "n_fr" in d.inputs for d in drives):
        name = repr(drives[0].name) if len(drives) == 1 else f"none of the {len(drives)} drives"
        why = [str(said) for d in drives for said in d.metadata.get("left_out", ())
               if "column n_f" in str(said)]
        if why:                              # the reader left them out: say why
            raise DataError(f"the four_wheel model needs the front wheels' rates, and "
                            f"{why[0].split(': left out')[0]}: they were left out")
        raise DataError(f"the four_wheel model needs the front wheels' rates (n_fl, n_fr), "
                        f"and {name} has none: map them ([wheels] front_left/front_right, "
                        "or the table's columns), or calibrate the rear axle ([vehicle] "
                        "model = \"rear_axle\")")


#: The steering angle's lag is searched within this many seconds either way ...
STEERING_LAG_S = 1.0
#: ... and taken where the steering and the reference's curvature agree at least this well.
STEERING_MIN_CORRELATION = 0.5


def steering_lag(drive: Drive) -> tuple[FloatArray | None, float | None]:
    """The drive's steering angle on the reference's clock, and its lag behind it (s): the lag
    at which the angle agrees best with the reference's curvature (its yaw rate over a speed
    of at least 2 m/s), refined between samples, within :data:`STEERING_LAG_S`. None for the
    lag where the drive has no steering, or it agrees too little (straight driving): the angle
    then stays as logged."""
    steer = drive.inputs.get("steer")
    if steer is None:
        return None, None
    pairs = steering_pairs(drive)
    span = steering_span(drive.t_s)
    lag = steering_peak(correlations(pairs, span), drive.t_s) if pairs else None
    if lag is None:
        return np.asarray(steer, dtype=np.float64), None
    return steering_at(drive, lag), lag


def steering_span(t_s: float) -> int:
    """The steps the steering's lag is searched within, either way."""
    return max(1, round(STEERING_LAG_S / t_s))


def steering_pairs(drive: Drive) -> list[tuple[FloatArray, FloatArray]]:
    """The reference's curvature and the steering angle of each piece long enough to search
    the steering's lag on (none without a steering angle)."""
    steer = drive.inputs.get("steer")
    if steer is None:
        return []
    t_s = drive.t_s
    pairs = []
    for a, b in drive.pieces:
        if b - a <= 4 * STEERING_LAG_S / t_s:
            continue
        psi = np.unwrap(np.asarray(drive.psi[a:b], dtype=np.float64))
        speed = np.hypot(np.gradient(drive.x[a:b], t_s), np.gradient(drive.y[a:b], t_s))
        curvature = np.gradient(psi, t_s) / np.maximum(speed, 2.0) * _direction(drive)[a:b]
        pairs.append((curvature, filled(steer[a:b])))
    return pairs


def steering_peak(found: Correlations, t_s: float) -> float | None:
    """The steering's lag (s) where the angle agrees with the curvature well enough
    (:data:`STEERING_MIN_CORRELATION`, not at the search's edge); None where it does not."""
    peak = found.peak()
    if peak is None or peak.at_edge or abs(peak.correlation) < STEERING_MIN_CORRELATION:
        return None
    # a steering angle with the wrong sign agrees best at a negative correlation: the lag is
    # that of the agreement either way (the fit names the sign)
    if peak.correlation < 0:
        negated = Correlations(found.lags, -found.values, found.overlap).peak()
        peak = negated if negated is not None else peak
    return float(peak.steps * t_s)


def steering_at(drive: Drive, lag: float) -> FloatArray:
    """The drive's steering angle at ``lag`` (s) after each sample (on the reference's clock
    where ``lag`` is its lag behind it)."""
    steer = drive.inputs["steer"]
    aligned = np.array(steer, dtype=np.float64)
    for a, b in drive.pieces:
        aligned[a:b] = _shifted(drive.t[a:b], np.asarray(steer[a:b], dtype=np.float64), lag,
                                drive.t_s)
    return aligned


def _shifted(t: FloatArray, values: FloatArray, lag: float, t_s: float) -> FloatArray:
    """``values`` at ``t + lag``, interpolated between their measured samples (NaN: not
    measured); NaN where no measured sample lies within two steps of the time asked."""
    known = np.isfinite(values)
    if not known.any():
        return np.full(t.size, np.nan)
    at, tk = t + lag, t[known]
    out = np.interp(at, tk, values[known])
    j = np.clip(np.searchsorted(tk, at), 1, max(tk.size - 1, 1))
    near = np.minimum(np.abs(at - tk[j - 1]), np.abs(tk[np.minimum(j, tk.size - 1)] - at))
    return np.where(near <= 2.0 * t_s, out, np.nan)


def _add_windows(parts: dict[str, list[FloatArray]], drive: Drive, steer_in: FloatArray | None,
                 window_s: float, heading_offset: float, label: int, cluster_s: float,
                 curve: float) -> None:
    """One drive's windows, piece by piece, into ``parts`` (``steer_in``: its steering angle
    on the reference's clock, None without one; ``curve``: see :func:`front_windows`)."""
    t_s = drive.t_s
    k = max(round(window_s / t_s), 1)
    for a, b in drive.pieces:
        n = (b - a - 1) // k
        if n < 1:
            continue
        cut = n * k
        psi = np.asarray(drive.psi[a:b], dtype=np.float64)
        dpsi = np.remainder(np.diff(psi) + np.pi, 2.0 * np.pi) - np.pi
        h = midpoint_heading(psi[:-1], dpsi, np.asarray(drive.beta[a:b - 1]) + heading_offset)
        ds = np.diff(drive.x[a:b]) * np.cos(h) + np.diff(drive.y[a:b]) * np.sin(h)
        a_x = np.gradient(ds / t_s, t_s) if ds.size > 1 else np.zeros_like(ds)
        ds, dpsi = ds[:cut].reshape(n, k), dpsi[:cut].reshape(n, k)
        moving = np.abs(ds).sum(axis=1) > MOVING_MPS * k * t_s
        revs = _measured_revolutions(np.column_stack([drive.inputs["n_fl"][a:b - 1],
                                                       drive.inputs["n_fr"][a:b - 1]])[:cut],
                                     n, k, t_s)
        if steer_in is None:
            steer = np.full((n, k), np.nan)
        else:
            steer = np.array(steer_in[a:b - 1][:cut], dtype=np.float64).reshape(n, k)
        crawl = np.abs(ds) <= MOVING_MPS * t_s                  # the reference's noise there
        keep = moving & np.isfinite(revs).all(axis=1)
        t0 = drive.t[a:b - 1][:cut:k]
        cluster = label + np.floor((t0 - drive.t[0]) / cluster_s)
        m = _substep(k, t_s)
        a_y = np.asarray(drive.a_y[a:b - 1][:cut], dtype=np.float64).reshape(n, k)
        parts["ds"].append(_summed(ds[keep], m))
        parts["dpsi"].append(_summed(dpsi[keep], m))
        parts["a_y"].append(_summed(a_y[keep], m) / m)
        parts["a_x"].append(_summed(a_x[:cut].reshape(n, k)[keep], m) / m)
        parts["revs"].append(revs[keep])
        parts["steer"].append(_substep_angle(steer[keep], crawl[keep], m))
        parts["cluster"].append(cluster[keep])
        parts["noise"].append(np.full(int(keep.sum()), heading_noise(psi)))
        excess = (curve_excess(drive.t[a:b], drive.x[a:b], drive.y[a:b], psi, curve)[:-1]
                  if curve else np.zeros(b - a - 1))
        parts["excess"].append((excess[:cut].reshape(n, k).sum(axis=1) * t_s)[keep])


#: A window's revolutions are told from its measured samples where at least this share of them
#: is measured (a signal on half the grid: a 50 Hz wheel speed beside a 100 Hz one).
MIN_MEASURED = 0.5


def _measured_revolutions(rates: FloatArray, n: int, k: int, t_s: float) -> FloatArray:
    """(n, 2) each window's revolutions of the wheels' rates (n k, 2): the mean rate of its
    measured samples over the window's time, NaN where fewer than :data:`MIN_MEASURED` of them
    are measured (a wheel's rate is smooth over a window's samples: a sample not measured is
    its neighbours')."""
    mean, count = _measured_mean(rates.reshape(n, k, 2), axis=1)
    return np.where(count >= MIN_MEASURED * k, mean * k * t_s, np.nan)


def _measured_mean(values: FloatArray, axis: int) -> tuple[FloatArray, IntArray]:
    """The mean of ``values``' measured (finite) entries along ``axis`` (NaN where none is),
    and how many there are."""
    known = np.isfinite(values)
    count = known.sum(axis=axis)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(known, values, 0.0).sum(axis=axis) / count, count


def _substep_angle(steer: FloatArray, crawl: BoolArray, m: int) -> FloatArray:
    """(N, k / m) each sub-step's mean steering angle over its measured samples, NaN where a
    step of it crawls (the reference's curvature there is its noise) or none is measured."""
    n, k = steer.shape
    mean, count = _measured_mean(steer.reshape(n, k // m, m), axis=2)
    crawling = crawl.reshape(n, k // m, m).any(axis=2)
    return np.where((count > 0) & ~crawling, mean, np.nan)


def heading_noise(psi: FloatArray) -> float:
    """The white noise (rad) of a heading sampled at a fixed rate: a robust spread of its
    second differences over sqrt(6) (a car's true heading bends too slowly to show in them at
    a wheel-speed rate; a pose that jitters sample to sample shows whole)."""
    d2 = np.diff(np.unwrap(np.asarray(psi, dtype=np.float64)), 2)
    if d2.size < 3:
        return 0.0
    mad = float(np.median(np.abs(d2 - np.median(d2))))
    return 1.4826 * mad / math.sqrt(6.0)


def steering_attenuation(windows: FrontWindows, theta: FloatArray) -> float | None:
    """How much of the spread of the road-wheel angle the reference's motion implies (the
    steering's regressor, ``atan(L curvature)`` averaged over a window) is turning, not the
    reference heading's noise: ``1 - mean(noise variance) / variance`` over the windows with
    a steering angle. The fitted ratio comes out that share of the true one (errors in the
    regressor dilute its slope); None where it cannot be told (fewer than three windows, no
    noise known, no spread)."""
    if windows.heading_noise is None:
        return None
    known = np.isfinite(windows.steer)
    has = known.any(axis=1)
    if has.sum() < 3:
        return None
    wheelbase = float(np.asarray(theta, dtype=np.float64)[LAYOUT.index("L")])
    moving = windows.ds != 0.0
    curvature = np.where(moving, windows.dpsi / np.where(moving, windows.ds, 1.0), 0.0)
    delta = np.where(known & moving, np.arctan(wheelbase * curvature), 0.0)
    x = delta.sum(axis=1)[has] / np.maximum((known & moving).sum(axis=1)[has], 1)
    distance = np.abs(windows.ds).sum(axis=1)[has]
    noise = 2.0 * (wheelbase * windows.heading_noise[has] / np.maximum(distance, 1e-9)) ** 2
    spread = float(np.var(x))
    if not spread > 0.0:
        return None
    return 1.0 - float(np.mean(noise)) / spread


def _substep(k: int, t_s: float) -> int:
    """Steps per sub-step: the divisor of the window's ``k`` steps nearest
    :data:`SUBSTEP_S`. Over a sub-step that short the curvature barely changes, and a wheel's
    path over steps of one curvature is its path over their sum (each step moves the contact
    point by the same vector in the body's frame), so the model runs on sub-steps: the
    front wheels' revolutions to the second order of the curvature's change within one."""
    divisors = [m for m in range(1, k + 1) if k % m == 0]
    return min(divisors, key=lambda m: abs(m * t_s - SUBSTEP_S))


def _summed(steps: FloatArray, m: int) -> FloatArray:
    """(N, k) steps summed over sub-steps of ``m``: (N, k / m)."""
    return np.asarray(steps.reshape(steps.shape[0], steps.shape[1] // m, m).sum(axis=2))


class HeldFar(NamedTuple):
    """A front parameter the datasheet states and the fit held, that a fit from odocal's
    placeholder identifies far from the statement (:func:`_held_far`)."""

    name: str
    drives: float       # the value a fit from odocal's placeholder puts it at
    std: float
    datasheet: float


@dataclass(frozen=True)
class FrontDetails:
    """What the front axle's fit did.

    windows, clusters : the windows fitted (of ``window_s``) and their clusters
    steering_windows : those with a steering angle
    scales : each channel's residual scale, the RMS over the windows (rev, rev, rad)
    left_out : windows beyond :data:`OUTLIER` scales, left out of the final fit
    iterations : Gauss-Newton steps of the final round
    load_prior : d's value and std from the rear fit (the prior), and whether it was fitted
        here (False: the rear fit holds it, or the front wheels disagree with it, so it stays
        held)
    load_joined : whether the front wheels' evidence on d joined the rear's (else d, fitted
        here with its prior, was a nuisance of the front fit only: the rear's d stands)
    traction : the front wheels' slip per m/s^2 of acceleration fitted beside (1/(m/s^2)),
        and its std
    """

    windows: int
    window_s: float
    clusters: int
    steering_windows: int
    scales: tuple[float, float, float]
    left_out: int
    iterations: int
    load_prior: tuple[float, float, bool]
    load_joined: bool = False
    traction: tuple[float, float] = (0.0, 0.0)
    steering_out_of_range: float | None = None
    """The steering ratio the drives said where it lies beyond any steering's (the ratio and
    offset were then held: the steering is named, not calibrated); None otherwise."""
    steering_attenuation: float | None = None
    """The share of the steering regressor's spread that is turning, not the reference
    heading's noise (:func:`steering_attenuation`); below :data:`MIN_ATTENUATION` the ratio
    is held. None where not told."""
    held_far: tuple[HeldFar, ...] = ()
    """Front parameters the datasheet states and the fit held (judged at the stated value, the
    drives could not tell them) that a fit from odocal's placeholder identifies far from the
    statement (:func:`_held_far`)."""
    change: tuple[float, float] | None = None
    """The front wheels' circumference changed within the windows (:func:`front_change`): the
    later half's relative step against the earlier half's, and its size in standard
    deviations; None where no change shows."""

    def to_dict(self) -> dict[str, Any]:
        return {"windows": self.windows, "window_s": self.window_s, "clusters": self.clusters,
                "steering_windows": self.steering_windows,
                "scales": dict(zip(("front_mean_rev", "front_difference_rev", "steering_rad"),
                                   self.scales, strict=True)),
                "left_out": self.left_out, "iterations": self.iterations,
                "load_prior": {"value": self.load_prior[0], "std": self.load_prior[1],
                               "fitted": self.load_prior[2], "joined": self.load_joined},
                "traction_per_mps2": {"value": self.traction[0], "std": self.traction[1]},
                "steering_out_of_range": self.steering_out_of_range,
                "steering_attenuation": self.steering_attenuation,
                "held_far": [far._asdict() for far in self.held_far],
                "change": (None if self.change is None
                           else {"relative": self.change[0], "sigmas": self.change[1]})}


@dataclass(frozen=True)
class FrontFit:
    """The front axle's and the steering's estimate, with d.

    theta : the four-wheel theta (the rear axle's values as given but d, fitted here where the
        rear fit identifies it; the front ones fitted or kept at the datasheet's)
    covariance : (10, 10) of the front parameters and d (the rest zero: the rear fit's own)
    verdicts : per parameter of :data:`FRONT`
    """

    theta: FloatArray
    covariance: FloatArray
    verdicts: tuple[Verdict, ...]
    details: FrontDetails

    @property
    def free(self) -> tuple[bool, ...]:
        return tuple(isinstance(v, Identified) for v in self.verdicts)


def _predict(p: FloatArray, w: FrontWindows) -> tuple[FloatArray, FloatArray]:
    """Each window's channels (N, 3) and their Jacobian in ``p = [theta, traction]``
    (N, 3, 11)."""
    theta = p[:_K]
    revs, jac = FOUR_WHEEL_MODEL.inverse_step(theta, w.ds, w.dpsi, w.a_y, front_only=True)
    slip = w.a_x[..., None]                                     # (N, k, 1)
    jac = np.concatenate([jac * (1.0 + p[_K] * slip)[..., None],
                          (revs * slip)[..., None]], axis=-1)
    revs = revs * (1.0 + p[_K] * slip)
    angle, jac_s = FOUR_WHEEL_MODEL.steering(theta, w.ds, w.dpsi)
    jac_s = np.concatenate([jac_s, np.zeros((*jac_s.shape[:-1], 1))], axis=-1)
    known = np.isfinite(w.steer)
    count = np.maximum(known.sum(axis=1), 1)
    mean_angle = np.where(known, angle, 0.0).sum(axis=1) / count
    mean_jac = np.where(known[..., None], jac_s, 0.0).sum(axis=1) / count[:, None]
    fl, fr = revs[..., 0].sum(axis=1), revs[..., 1].sum(axis=1)
    j_fl, j_fr = jac[..., 0, :].sum(axis=1), jac[..., 1, :].sum(axis=1)
    pred = np.column_stack([0.5 * (fl + fr), fr - fl, mean_angle])
    return pred, np.stack([0.5 * (j_fl + j_fr), j_fr - j_fl, mean_jac], axis=1)


#: Which channel's equations estimate which parameter (1) or only carry it (0), in
#: :data:`_FIT`'s order: the steering's leave L to the wheels.
_TOLD = np.ones((3, _FIT.size))
_TOLD[2, FRONT.index("L")] = 0.0


@dataclass(frozen=True)
class _Prior:
    """d's prior: its value and std (0: held); the traction's is :data:`TRACTION_STD` about
    none."""

    value: float
    std: float

    def information(self) -> FloatArray:
        out = np.zeros((_FIT.size, _FIT.size))
        if self.std > 0:
            out[_D, _D] = self.std ** -2
        out[-1, -1] = TRACTION_STD ** -2
        return out

    def pull(self, p: FloatArray) -> FloatArray:
        """The prior's gradient at ``p`` (in :data:`_FIT`'s order)."""
        out = np.zeros(_FIT.size)
        if self.std > 0:
            out[_D] = (self.value - float(p[_LOAD])) / self.std ** 2
        out[-1] = -float(p[_K]) / TRACTION_STD ** 2
        return out


@dataclass(frozen=True)
class _Normal:
    """The weighted estimating equations at a theta, in :data:`_FIT`'s order (d's prior
    included in ``a`` and ``g``, not in ``scores`` and ``told_info``: the data's own)."""

    a: FloatArray          # (told J)^T J + prior
    g: FloatArray          # (told J)^T r + prior's pull
    scores: FloatArray     # (N, 8) per window
    told_info: FloatArray  # (told J)^T (told J): what each parameter's own equations say
    residual: FloatArray   # (N, 3), unweighted
    white: FloatArray      # (N, 3) weighted residuals


def _normal(p: FloatArray, w: FrontWindows, measured: FloatArray, weight: FloatArray,
            scale: FloatArray, prior: _Prior) -> _Normal:
    pred, jac = _predict(p, w)
    residual = measured - pred
    root = np.sqrt(weight) / scale                         # (N, 3)
    white = np.where(weight > 0, residual, 0.0) * root
    j = (jac * root[..., None])[..., _FIT]
    told = _TOLD * j
    info = prior.information()
    return _Normal(a=np.einsum("ncp,ncq->pq", told, j) + info,
                   g=np.einsum("ncp,nc->p", told, white) + prior.pull(p),
                   scores=np.einsum("ncp,nc->np", told, white),
                   told_info=np.einsum("ncp,ncq->pq", told, told) + info, residual=residual,
                   white=white)


def std_from_information(information: FloatArray) -> FloatArray:
    """Each parameter's standard deviation from an information matrix; infinite for those a
    direction the data do not see moves (a pseudo-inverse would call them exact)."""
    diag = np.sqrt(np.clip(np.diag(information), 0.0, None))
    out = np.full(diag.size, np.inf)
    seen = diag > 0
    if not seen.any():
        return out
    normed = information[np.ix_(seen, seen)] / np.outer(diag[seen], diag[seen])
    values, vectors = np.linalg.eigh(0.5 * (normed + normed.T))
    blind = values <= 1e-10 * max(float(values.max()), 0.0)
    var = (vectors[:, ~blind] ** 2 / values[~blind]).sum(axis=1)
    var[(vectors[:, blind] ** 2 > 1e-12).any(axis=1)] = np.inf
    out[seen] = np.sqrt(var) / diag[seen]
    return out


def _judged(told_info: FloatArray, limit: FloatArray, usable: BoolArray) -> BoolArray:
    """Which parameters (of :data:`_FIT`) the drives identify: the weakest front one held in
    turn until every one left has a std (from its own equations' information) within its
    limit, as the default does (d, with its prior, is judged by the rear fit)."""
    free = usable.copy()
    while free[:_D].any():
        std = np.full(free.size, np.inf)
        std[free] = std_from_information(told_info[np.ix_(free, free)])
        worst = int(np.argmax(np.where(free[:_D], std[:_D] / limit, -np.inf)))
        if std[worst] <= limit[worst]:
            break
        free[worst] = False
    return free


def fit_front(windows: FrontWindows, theta0: FloatArray, settings: Settings, *,
              load_std: float, fit_load: bool = True) -> FrontFit:
    """Gauss-Newton for the front axle and the steering over ``windows``, from the four-wheel
    ``theta0`` (its rear axle: the rear fit's estimate), judged by the identifiability rule of
    ``[identify]`` (a std within ``identifiable_ratio`` of the datasheet's). ``load_std``: the
    rear fit's std of d (0 where the rear fit holds d), its prior here where ``fit_load``;
    else d stays held and that std (or d's datasheet uncertainty) is carried into the front
    parameters."""
    theta0 = np.array(theta0, dtype=np.float64)
    stds = np.asarray(settings.identify.prior_std, dtype=np.float64)
    prior = stds[_FRONT]
    limit = settings.identify.identifiable_ratio * prior
    load = _Prior(float(theta0[_LOAD]), float(load_std) if fit_load else 0.0)
    measured = windows.measured()
    has_angle = np.isfinite(measured[:, 2])
    clusters = int(np.unique(windows.cluster).size)
    details = FrontDetails(windows=windows.size, window_s=settings.inverse.window_s,
                           clusters=clusters, steering_windows=int(has_angle.sum()),
                           scales=(math.nan,) * 3, left_out=0, iterations=0,
                           load_prior=(load.value, float(load_std), load.std > 0))
    if windows.size < 3 or clusters < 2:
        reason = Reason.ONE_CLUSTER if windows.size >= 3 else Reason.NO_INFORMATION
        return FrontFit(theta=theta0, covariance=np.zeros((LAYOUT.size, LAYOUT.size)),
                        verdicts=tuple(NotIdentified(reason, limit=float(x)) for x in limit),
                        details=details)
    measured = np.where(np.isfinite(measured), measured, 0.0)
    weight, scale, usable = _start(measured, has_angle, load)
    held = np.zeros(_FIT.size, dtype=bool)
    attenuation = steering_attenuation(windows, theta0) if usable[_RATIO] else None
    if attenuation is not None and attenuation < MIN_ATTENUATION:
        held[_RATIO] = True          # the reference's noise dilutes the ratio: not judged
    steering_range: float | None = None
    nuisance = np.append(prior, [0.0 if load.std > 0 else (load_std or stds[_LOAD]), 0.0])
    p0 = np.append(theta0, 0.0)                 # no traction slip to start from
    while True:
        p, free, weight_f, scale_f, steps = _rounds(
            p0, windows, measured, (weight, scale), usable & ~held, limit, load)
        eq = _normal(p, windows, measured, weight_f, scale_f, load)
        cov = _covariance(eq, windows, free, nuisance, clusters, load)
        cov = cov + _excess_term(eq, p, windows, measured, (weight_f, scale_f), free, load)
        std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        hold, out_of_range = _to_hold(p, free, std, limit)
        if not hold:
            break
        held[hold] = True
        steering_range = out_of_range if out_of_range is not None else steering_range
    covariance = np.zeros((LAYOUT.size, LAYOUT.size))
    covariance[np.ix_(_FIT[:-1], _FIT[:-1])] = cov[:-1, :-1]     # the traction profiled out
    details = dataclasses.replace(
        details, scales=(_rms(scale_f[:, 0]), _rms(scale_f[:, 1]), _rms(scale_f[:, 2])),
        left_out=int((weight_f[:, :2] == 0).any(axis=1).sum()), iterations=steps,
        traction=(float(p[_K]), float(std[-1])), steering_out_of_range=steering_range,
        steering_attenuation=attenuation)
    return FrontFit(theta=p[:_K], covariance=covariance,
                    verdicts=_verdicts(free[:_D], usable[:_D], std[:_D], limit),
                    details=details)


def _start(measured: FloatArray, has_angle: BoolArray, load: _Prior
           ) -> tuple[FloatArray, FloatArray, BoolArray]:
    """The first weights (the steering's only where a window has an angle), the first channel
    scales (the measurements' spread, floored) and which of :data:`_FIT` may be fitted (d only
    with its prior, the ratio and offset only with a steering angle)."""
    weight = np.column_stack([np.ones(has_angle.size), np.ones(has_angle.size), has_angle])
    usable = np.ones(_FIT.size, dtype=bool)
    usable[_D] = load.std > 0
    if not has_angle.any():             # no steering angle: the ratio and offset say nothing
        usable[[FRONT.index("ratio"), FRONT.index("s_0")]] = False
    scale = np.broadcast_to(np.maximum(np.array(
        [float(np.std(measured[weight[:, c] > 0, c])) if (weight[:, c] > 0).any() else 1.0
         for c in range(3)]), SCALE_FLOOR), measured.shape)
    return weight, scale, usable


def _to_hold(p: FloatArray, free: BoolArray, std: FloatArray, limit: FloatArray
             ) -> tuple[list[int], float | None]:
    """What the fit must hold next (positions in :data:`_FIT`; none: the fit stands), and the
    ratio that made it hold the steering. A ratio no steering has (a stuck or noisy sensor on
    a straight drive, a flipped one the pre-check could not judge) holds the ratio and offset:
    it is the steering's failure, not a value. Else the front parameter furthest beyond its
    limit (the widened std of each must be within it)."""
    ratio = FRONT.index("ratio")
    low, high = LAYOUT.parameters[LAYOUT.index("ratio")].vehicle_range
    if free[ratio] and not low <= p[_FRONT[ratio]] <= high:
        return [ratio, FRONT.index("s_0")], float(p[_FRONT[ratio]])
    over = free[:_D] & ~(std[:_D] <= limit)
    if not over.any():
        return [], None
    return [int(np.argmax(np.where(over, std[:_D] / limit, -np.inf)))], None


def _rounds(theta0: FloatArray, windows: FrontWindows, measured: FloatArray,
            start: tuple[FloatArray, FloatArray], usable: BoolArray, limit: FloatArray,
            load: _Prior) -> tuple[FloatArray, BoolArray, FloatArray, FloatArray, int]:
    """:data:`ROUNDS` of judging (from the datasheet), fitting the identified and rescaling
    the channels, each window beyond :data:`OUTLIER` scales left out of its channel: theta,
    the parameters fitted, the weights, the scales and the last round's steps."""
    weight, scale = start
    has_angle = weight[:, 2] > 0
    theta = np.array(theta0, dtype=np.float64)
    free, steps = usable.copy(), 0
    for round_ in range(ROUNDS + 1):
        first = np.array(theta0, dtype=np.float64)
        if round_:                        # the first round fits every usable one, for scales
            free = _judged(_normal(first, windows, measured, weight, scale, load).told_info,
                           limit, usable)
        theta, steps = _solve(first, windows, measured, weight, scale, free, load)
        residual = _normal(theta, windows, measured, weight, scale, load).residual
        scale = _scales(residual, weight, scale, np.abs(measured[:, 0]))
        weight = _outliers_out(residual, scale, has_angle)
    return theta, free, weight, scale, steps


def _rms(values: FloatArray) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


def _outliers_out(residual: FloatArray, scale: FloatArray, has_angle: BoolArray) -> FloatArray:
    """The channels' weights (N, 3): a window beyond :data:`OUTLIER` robust scales from its
    channel's median residual is left out of that channel; where more than
    :data:`MAX_OUTLIER_SHARE` of a channel's windows are, they are the model's departure,
    not outliers, and every window stays."""
    base = np.column_stack([np.ones(has_angle.size), np.ones(has_angle.size), has_angle])
    out = base.copy()
    for c in range(3):
        counted = base[:, c] > 0
        if not counted.any():
            continue
        r = residual[:, c]
        far = counted & (np.abs(r - np.median(r[counted])) > OUTLIER * scale[:, c])
        if far.sum() <= MAX_OUTLIER_SHARE * counted.sum():
            out[far, c] = 0.0
    return out


def _solve(theta: FloatArray, windows: FrontWindows, measured: FloatArray, weight: FloatArray,
           scale: FloatArray, free: BoolArray, load: _Prior) -> tuple[FloatArray, int]:
    """Gauss-Newton on the free parameters of :data:`_FIT` (the others as given)."""
    index = _FIT[free]
    if not index.size:
        return theta, 0
    for steps in range(1, MAX_STEPS + 1):
        eq = _normal(theta, windows, measured, weight, scale, load)
        step = np.linalg.lstsq(eq.a[np.ix_(free, free)], eq.g[free], rcond=None)[0]
        theta[index] += step
        if np.all(np.abs(step) <= STEP_TOLERANCE * np.maximum(1.0, np.abs(theta[index]))):
            return theta, steps
    return theta, MAX_STEPS


def _scales(residual: FloatArray, weight: FloatArray, before: FloatArray,
            revolutions: FloatArray) -> FloatArray:
    """Each window's scale per channel (N, 3): the wheels' channels ``sqrt(s0^2 + f^2 n^2)``
    with ``n`` the window's revolutions (wheel noise grows with the speed, as the default's
    error model has it), ``s0^2`` and ``f^2`` regressed from the squared residuals of the
    windows that count (a robust core: those within :data:`OUTLIER` scales); the steering's
    one scale, its residuals' standard deviation over that core. The scale before where a
    channel has fewer than three windows."""
    out = np.array(before, dtype=np.float64, copy=True)
    n2 = revolutions ** 2
    for c in range(3):
        core = (weight[:, c] > 0) & (np.abs(residual[:, c]) <= OUTLIER * out[:, c])
        r2 = residual[core, c] ** 2
        if r2.size < 3:
            continue
        if c == 2:
            out[:, c] = max(float(np.sqrt(r2.mean())), SCALE_FLOOR[c])
            continue
        design = np.column_stack([np.ones(r2.size), n2[core]])
        s0, f = np.linalg.lstsq(design, r2, rcond=None)[0]
        if s0 <= 0.0 or f < 0.0:            # no growth with the speed the data show
            s0, f = float(r2.mean()), 0.0
        out[:, c] = np.sqrt(np.maximum(s0 + f * n2, SCALE_FLOOR[c] ** 2))
    return out


def _covariance(eq: _Normal, windows: FrontWindows, free: BoolArray, nuisance: FloatArray,
                clusters: int, load: _Prior) -> FloatArray:
    """The covariance (8, 8) of :data:`_FIT`: the data's sandwich over clusters, widened as
    the default's (:func:`~odocal.estimators.covariance.widened`), d's prior's own, plus the
    spread that each held parameter's datasheet uncertainty (``nuisance``) gives the free
    ones."""
    n = _FIT.size
    cols = np.flatnonzero(free)
    if not cols.size:
        return np.zeros((n, n))
    bread = np.zeros((n, n))
    bread[np.ix_(cols, cols)] = np.linalg.pinv(eq.a[np.ix_(cols, cols)])
    labels, index = np.unique(windows.cluster, return_inverse=True)
    sums = np.zeros((labels.size, n))
    np.add.at(sums, index, eq.scores)
    sums[:, ~free] = 0.0
    correction = clusters / (clusters - 1) if clusters > 1 else 1.0
    sandwich = correction * bread @ (sums.T @ sums) @ bread.T
    # the model-based form: the residual variance over the rows that count
    rows = int(np.count_nonzero(eq.white))
    sigma2 = float((eq.white ** 2).sum()) / max(rows - int(free.sum()), 1)
    data_info = eq.told_info - load.information()
    naive = sigma2 * bread @ data_info @ bread.T
    effective = _effective(eq, bread, labels.size, index)
    cov = widened(sandwich, naive, effective, clusters, few=True)
    cov = cov + bread @ load.information() @ bread.T
    for j in np.flatnonzero(~free & (nuisance > 0)):
        shift = -bread @ eq.a[:, j]                 # d p_free / d p_j (held)
        cov = cov + nuisance[j] ** 2 * np.outer(shift, shift)
    return np.asarray(0.5 * (cov + cov.T))          # symmetric to the last bit


def _excess_term(eq: _Normal, p: FloatArray, windows: FrontWindows, measured: FloatArray,
                 weights: tuple[FloatArray, FloatArray], free: BoolArray, load: _Prior
                 ) -> FloatArray:
    """The systematic covariance (8, 8) of the wheels' excess in bends
    (:attr:`FrontWindows.excess`): ``s s^T``, with ``s`` how far one Gauss-Newton step moves
    the fit were the front wheels read with it (without it, where the rear fit left it out:
    the same to first order). The rear fit's constant excess describes the reference's motion
    in bends to the first order only, and the wheelbase lives in the second; zeros without an
    excess."""
    n = _FIT.size
    if windows.excess is None or not np.any(windows.excess) or not free.any():
        return np.zeros((n, n))
    other = np.array(measured, dtype=np.float64, copy=True)
    other[:, 0] += windows.excess / float(p[LAYOUT.index("c_f")])      # (m -> revolutions)
    alt = _normal(p, windows, other, weights[0], weights[1], load)
    cols = np.flatnonzero(free)
    shift = np.zeros(n)
    shift[cols] = np.linalg.lstsq(eq.a[np.ix_(cols, cols)], (alt.g - eq.g)[cols],
                                  rcond=None)[0]
    return np.outer(shift, shift)


def _effective(eq: _Normal, bread: FloatArray, count: int, index: IntArray) -> FloatArray:
    """Per parameter, the effective number of clusters its variance rests on: ``(sum_k
    e_k)^2 / sum_k e_k^2`` with ``e_k`` cluster k's share (its scores through the bread)."""
    shares = np.zeros((count, bread.shape[0]))
    np.add.at(shares, index, (eq.scores @ bread.T) ** 2)
    total, squares = shares.sum(axis=0), (shares ** 2).sum(axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(squares > 0, total ** 2 / squares, 0.0)


def _verdicts(free: BoolArray, usable: BoolArray, std: FloatArray,
              limit: FloatArray) -> tuple[Verdict, ...]:
    """Per front parameter: identified with its std, or why not (no steering angle; bends
    the drives lack; too weak)."""
    out: list[Verdict] = []
    for j, name in enumerate(FRONT):
        if free[j]:
            out.append(Identified(float(std[j]), float(limit[j])))
        elif not usable[j]:
            out.append(NotIdentified(Reason.NO_INFORMATION, limit=float(limit[j])))
        else:
            reason = Reason.NEEDS_BENDS if name in LAYOUT.bends else Reason.WEAK
            out.append(NotIdentified(reason, limit=float(limit[j])))
    return tuple(out)


def joined(rear_theta: FloatArray, rear_cov: FloatArray, front: FrontFit
           ) -> tuple[FloatArray, FloatArray]:
    """The four-wheel theta (10,) and covariance (10, 10) of the rear fit's estimate
    (``rear_theta``, ``rear_cov``: the rear axle's four and their covariance) joined with the
    front fit's: where the front fit moved d (its prior: the rear's), the rear axle's other
    parameters follow by their regression on d (``Sigma_rd / sigma_d^2``), and their
    covariance is conditioned alike; the front parameters' covariance with the rear's is
    theirs with d times that regression."""
    r = np.array(LAYOUT.indices(FOUR_WHEEL_MODEL.rear.layout.names))
    theta = np.array(front.theta, dtype=np.float64)
    cov = np.array(front.covariance, dtype=np.float64)
    rear_theta = np.asarray(rear_theta, dtype=np.float64)
    rear_cov = np.asarray(rear_cov, dtype=np.float64)
    d = FOUR_WHEEL_MODEL.rear.layout.index(LAYOUT.load)
    prior_var = float(rear_cov[d, d])
    if not front.details.load_joined or prior_var <= 0:
        theta[r] = rear_theta
        cov[np.ix_(r, r)] = rear_cov
        return theta, cov
    k = rear_cov[:, d] / prior_var                       # the rear axle's regression on d
    moved = float(theta[_LOAD]) - float(rear_theta[d])
    theta[r] = rear_theta + k * moved
    post_var = float(cov[_LOAD, _LOAD])
    cov[np.ix_(r, r)] = rear_cov + np.outer(k, k) * (post_var - prior_var)
    cross = np.outer(cov[_FRONT, _LOAD], k)              # (front, rear)
    cov[np.ix_(_FRONT, r)] = cross
    cov[np.ix_(r, _FRONT)] = cross.T
    return theta, cov


@dataclass(frozen=True)
class FourWheelDetails:
    """What the four-wheel calibration did: the rear axle's default fit and the front fit."""

    rear: Any
    front: FrontDetails | None

    def to_dict(self) -> dict[str, Any]:
        rear = self.rear.to_dict() if hasattr(self.rear, "to_dict") else None
        return {"rear_axle": rear,
                "front_axle": self.front.to_dict() if self.front is not None else None}


def rear_axle_of(est: Estimate) -> Estimate:
    """The rear axle within a four-wheel estimate (its four as joined with the front's: values,
    covariance, verdicts, and the rear fit's details) as the rear-axle model's estimate: what
    odometry from the rear wheels alone runs on. A rear-axle estimate is returned as it is."""
    if est.model != FOUR_WHEEL_MODEL.name:
        return est
    rear = FOUR_WHEEL_MODEL.rear
    r = np.array(LAYOUT.indices(rear.layout.names))
    details = est.details.rear if isinstance(est.details, FourWheelDetails) else est.details
    return Estimate(method=est.method,
                    theta=Parameters.from_array(est.theta.as_array()[r], layout=rear.layout),
                    datasheet=Parameters.from_array(est.datasheet.as_array()[r],
                                                    layout=rear.layout),
                    covariance=np.asarray(est.covariance)[np.ix_(r, r)],
                    covariance_kind=est.covariance_kind,
                    free=tuple(est.free[i] for i in r), verdicts=tuple(est.verdicts[i] for i in r),
                    status=est.status, details=details, widening=np.asarray(est.widening)[r],
                    model=rear.name)


def four_wheel_estimate(rear: Estimate, drives: Sequence[Drive], settings: Settings
                        ) -> Estimate:
    """The four-wheel model's estimate from the rear axle's (the default method's, on
    ``drives`` as it fitted them: its departures taken out): the front axle and the steering
    fitted on the motion it settled (its lag and heading offset) and joined with it
    (:func:`joined`). ``settings``: the four-wheel model's. Where the rear fit ended without an
    estimate, nothing of the front is fitted either (its verdicts say why)."""
    details = rear.details
    if not rear.success or not hasattr(details, "delay_s"):
        return car_estimate(rear, None, settings)
    # the wheels' whole lag is the rear fit's delay; a lag it fitted as a departure is part
    # of it, and the drives (as fitted) are already shifted by that part
    taken = float(dict(getattr(details, "fitted_departures", {}) or {}).get("lag", 0.0))
    shift = float(details.delay_s) - taken * (drives[0].t_s if drives else 0.0)
    windows = front_windows(drives, settings, delay_s=shift,
                            heading_offset=float(details.heading_offset_rad),
                            curve=excess_doubt(dict(getattr(details, "fitted_departures", {})
                                                    or {}), stated_arm_x(settings)))
    return car_estimate(rear, windows, settings)


def stated_arm_x(settings: Settings) -> float | None:
    """The lever arm ahead of the rear axle the settings state (``[reference] offset_m``; the
    fit holds it, so it is not among the departures fitted), or None."""
    arm = settings.reference.offset_m
    return None if arm is None else float(arm[0])


def car_estimate(rear: Estimate, windows: FrontWindows | None, settings: Settings, *,
                 front: FrontFit | None = None) -> Estimate:
    """The four-wheel estimate of the rear axle's (``rear``) and the front ``windows`` made on
    the motion it settled (:func:`front_windows`; the live calibrator keeps its own): the
    front axle and the steering fitted on them (:func:`fit_car_front`; ``front``: as fitted
    already, on windows the caller kept) and joined with the rear's. None for both, or a rear
    fit that ended without an estimate: the front at the datasheet's, not calibrated for the
    rear's reason."""
    datasheet = _front_datasheet(rear, settings)
    limit = settings.identify.identifiable_ratio * np.asarray(settings.identify.prior_std)
    details = rear.details
    if not rear.success or (front is None and windows is None):
        return _without_front(rear, datasheet, limit)
    if front is None:
        assert windows is not None
        front = fit_car_front(rear, windows, settings)
    d = FOUR_WHEEL_MODEL.rear.layout.index(LAYOUT.load)
    theta, cov = joined(rear.theta.as_array(), rear.covariance, front)
    front = _widened_for_change(front, theta, cov)
    verdicts: list[Verdict] = list(rear.verdicts)
    if front.details.load_joined:
        # d joined with the front wheels' evidence, and the rear axle's others following it
        # by their covariance with d: their verdicts state the joined std, as the estimate
        for j, verdict in enumerate(rear.verdicts):
            if isinstance(verdict, Identified) or j == d:
                verdicts[j] = Identified(float(np.sqrt(max(cov[j, j], 0.0))),
                                         float(limit[j]))
    return Estimate(method=rear.method, theta=Parameters.from_array(theta, layout=LAYOUT),
                    datasheet=datasheet, covariance=cov, covariance_kind=rear.covariance_kind,
                    free=(*rear.free, *front.free), verdicts=(*verdicts, *front.verdicts),
                    status=rear.status, details=FourWheelDetails(details, front.details),
                    widening=np.append(rear.widening, np.ones(len(FRONT))),
                    model=FOUR_WHEEL_MODEL.name)


def _widened_for_change(front: FrontFit, theta: FloatArray, cov: FloatArray) -> FrontFit:
    """Where the front wheels changed within the windows (:func:`front_change`), c_f is the
    mix of the two: its variance (in ``cov``, in place) widened by half the step squared, so
    that its std covers either; its verdict with it."""
    if front.details.change is None:
        return front
    j = LAYOUT.index("c_f")
    cov[j, j] += (0.5 * front.details.change[0] * float(theta[j])) ** 2
    verdicts = list(front.verdicts)
    k = FRONT.index("c_f")
    if isinstance(verdicts[k], Identified):
        verdicts[k] = Identified(float(np.sqrt(cov[j, j])), verdicts[k].limit)
    return dataclasses.replace(front, verdicts=tuple(verdicts))


def fit_car_front(rear: Estimate, windows: FrontWindows, settings: Settings) -> FrontFit:
    """The front axle and the steering fitted on ``windows`` from the rear axle's estimate
    (``rear``: its d the prior of the front's, where it identifies it), with what the
    datasheet states far from what the windows identify (:func:`_held_far`)."""
    theta0 = _front_datasheet(rear, settings).as_array().copy()
    theta0[:_REAR_SIZE] = rear.theta.as_array()
    d = FOUR_WHEEL_MODEL.rear.layout.index(LAYOUT.load)
    load_std = float(rear.std[d]) if rear.identified[d] else 0.0
    # an exact rear fit (noise-free data) states d's std at rounding's size: as a prior its
    # information would swamp the front's equations (their steps vanish): d is held there
    fit_load = load_std > LOAD_STD_FLOOR
    front = fit_front(windows, theta0, settings, load_std=load_std, fit_load=fit_load)
    if fit_load:
        front = _with_load(front, windows, theta0, settings, float(rear.theta.as_array()[d]),
                           load_std)
    far = _held_far(front, windows, theta0, settings, load_std=load_std, fit_load=fit_load)
    return dataclasses.replace(front, details=dataclasses.replace(
        front.details, held_far=far, change=front_change(windows, front)))


#: The front wheels' circumference changed within the windows where their later half reads
#: beyond this many standard deviations ...
CHANGE_SIGMAS = 5.0
#: ... and beyond this share of it from the earlier half (a tyre changed, or its pressure).
CHANGE_SHARE = 0.002
#: Each half holds at least this many clusters.
CHANGE_MIN_CLUSTERS = 5


def front_change(windows: FrontWindows, front: FrontFit) -> tuple[float, float] | None:
    """A change of the front wheels' circumference within ``windows`` (a front tyre changed,
    or its pressure: the rear axle's change detector does not see it): the front wheels' mean
    revolutions against those the fit predicts, as a share, averaged per cluster (in time),
    the later half of the clusters against the earlier half (Welch's difference over the
    clusters' means). Returns the relative step and its size in standard deviations where
    beyond :data:`CHANGE_SIGMAS` and :data:`CHANGE_SHARE`; None otherwise. Over 27 simulated
    drives of 9 noise profiles without a change the largest was 1.67 standard deviations, on
    the shared real logs 1.42; a 2% change of both front tyres halfway through read 29.9."""
    if not windows.size or not np.all(np.isfinite(front.theta)):
        return None
    pred, _ = _predict(np.append(front.theta, front.details.traction[0]), windows)
    measured = windows.measured()[:, 0]
    ok = np.isfinite(measured) & (np.abs(pred[:, 0]) > 1.0)
    if not ok.any():
        return None
    ids, inverse = np.unique(windows.cluster[ok], return_inverse=True)
    means = np.bincount(inverse, measured[ok] / pred[ok, 0] - 1.0) / np.bincount(inverse)
    half = ids.size // 2
    early, late = means[:half], means[half:]
    if min(early.size, late.size) < CHANGE_MIN_CLUSTERS:
        return None
    step = float(late.mean() - early.mean())
    std = float(np.sqrt(early.var(ddof=1) / early.size + late.var(ddof=1) / late.size))
    if std <= 0 or abs(step) <= CHANGE_SHARE or abs(step) <= CHANGE_SIGMAS * std:
        return None
    return step, step / std


_REAR_SIZE = FOUR_WHEEL_MODEL.rear.layout.size


def _front_datasheet(rear: Estimate, settings: Settings) -> Parameters:
    """The four-wheel datasheet: the rear axle's as the rear fit took it; the front axle's
    circumference and track as the rear's where the settings leave them at their placeholders
    (a car's tyres and tracks are alike front and rear, and their datasheet uncertainty covers
    the difference); the rest as the settings state."""
    values = np.array(settings.identify.theta0, dtype=np.float64)
    values[:_REAR_SIZE] = rear.datasheet.as_array()
    for own, rear_name in (("c_f", LAYOUT.scale), ("t_f", LAYOUT.track)):
        k = LAYOUT.index(own)
        if values[k] == LAYOUT.placeholder[k]:
            values[k] = values[LAYOUT.index(rear_name)]
    return Parameters.from_array(values, layout=LAYOUT)


def _without_front(rear: Estimate, datasheet: Parameters, limit: FloatArray) -> Estimate:
    """The four-wheel estimate where the rear fit gave none: the rear axle's as it ended, the
    front at the datasheet's, each front parameter not calibrated for the rear's reason."""
    reason = Reason.FAILED if not rear.success else Reason.NO_INFORMATION
    first = rear.verdicts[0]
    if isinstance(first, NotIdentified) and first.reason in (Reason.REJECTED,
                                                             Reason.STANDSTILL):
        reason = first.reason
    theta = datasheet.as_array().copy()
    theta[:_REAR_SIZE] = rear.theta.as_array()
    cov = np.zeros((LAYOUT.size, LAYOUT.size))
    cov[:_REAR_SIZE, :_REAR_SIZE] = rear.covariance
    verdicts = (*rear.verdicts, *(NotIdentified(reason, limit=float(limit[j])) for j in _FRONT))
    return Estimate(method=rear.method, theta=Parameters.from_array(theta, layout=LAYOUT),
                    datasheet=datasheet, covariance=cov, covariance_kind=rear.covariance_kind,
                    free=(*rear.free, *(False,) * len(FRONT)), verdicts=verdicts,
                    status=rear.status, details=FourWheelDetails(rear.details, None),
                    widening=np.append(rear.widening, np.ones(len(FRONT))),
                    model=FOUR_WHEEL_MODEL.name)


def _held_far(front: FrontFit, windows: FrontWindows, theta0: FloatArray, settings: Settings,
              *, load_std: float, fit_load: bool) -> tuple[HeldFar, ...]:
    """Front parameters the datasheet states (not odocal's placeholder) and the fit held, that
    the drives identify far from the statement. Judged at a stated value, a parameter whose
    signal grows with it (the wheelbase: the front wheels' longer path and the steering
    angle's reach both scale with L) can look untold where the value is wrong: a typo (1.5 m
    for 2.5 m) would be held silently. So the drives are fitted once more from odocal's
    placeholder for those parameters; where that fit identifies one beyond
    :data:`DATASHEET_FAR` of its stds and 5% of the statement, it is returned (the estimate
    keeps the datasheet's value: the note says the drives' one)."""
    sheet = np.asarray(theta0, dtype=np.float64)
    stated = [name for name, free in zip(FRONT, front.free, strict=True)
              if not free and sheet[LAYOUT.index(name)] != LAYOUT.placeholder[LAYOUT.index(name)]]
    if not stated:
        return ()
    start = sheet.copy()
    for name in stated:
        start[LAYOUT.index(name)] = LAYOUT.placeholder[LAYOUT.index(name)]
    probe = fit_front(windows, start, settings, load_std=load_std, fit_load=fit_load)
    told = dict(zip(FRONT, probe.free, strict=True))
    far = []
    for name in stated:
        j = LAYOUT.index(name)
        value, std = float(probe.theta[j]), float(np.sqrt(max(probe.covariance[j, j], 0.0)))
        gap = abs(value - sheet[j])
        if told[name] and std > 0 and gap > DATASHEET_FAR * std \
                and gap > 0.05 * max(abs(float(sheet[j])), 1e-9):
            far.append(HeldFar(name, value, std, float(sheet[j])))
    return tuple(far)


#: Below this share of the steering regressor's spread being turning (the rest the reference
#: heading's noise, :func:`steering_attenuation`) the ratio is held: the fit would find it
#: low by at least the rest (errors in the regressor dilute a slope).
MIN_ATTENUATION = 0.95

#: The front parameters whose evidence on d is its own only where the fit identifies them:
#: in bends the front wheels' difference moves with t_f, d and L alike.
_WITH_LOAD = ("t_f", "L")


def _with_load(front: FrontFit, windows: FrontWindows, theta0: FloatArray, settings: Settings,
               prior_value: float, prior_std: float) -> FrontFit:
    """The front fit as d's evidence allows, from the fit with d under its prior (the rear's).
    Where the front wheels agree with the rear's d (within three of the prior's std), the
    front parameters stand as fitted with d beside them (d's uncertainty is in theirs), and the
    front's d joins the rear's where it is the front's own evidence (:func:`_joins`); else
    it is the front fit's nuisance only and the rear's d stands. Where they disagree, the
    axles' load transfer differ (a departure from the model): the front is fitted again with
    d held at the rear's, its uncertainty carried."""
    moved = abs(float(front.theta[_LOAD]) - prior_value)
    if moved > 3.0 * prior_std:
        return fit_front(windows, theta0, settings, load_std=prior_std, fit_load=False)
    joins = _joins(front, prior_std)
    theta = np.array(front.theta, dtype=np.float64)
    covariance = np.array(front.covariance, dtype=np.float64)
    if not joins:                            # the rear's d stands, uncorrelated with the front
        theta[_LOAD] = prior_value
        covariance[_LOAD, :] = 0.0
        covariance[:, _LOAD] = 0.0
    return dataclasses.replace(front, theta=theta, covariance=covariance,
                               details=dataclasses.replace(front.details, load_joined=joins))


def _joins(front: FrontFit, prior_std: float) -> bool:
    """Whether the front fit's d (agreeing with the rear's) may join the rear's: the front
    identifies t_f and L (held at the datasheet's, they would pull d) and adds information (a
    std below the prior's)."""
    identified = dict(zip(FRONT, front.free, strict=True))
    std = float(np.sqrt(max(front.covariance[_LOAD, _LOAD], 0.0)))
    return all(identified[n] for n in _WITH_LOAD) and 0.0 < std < prior_std


def _changed(vehicle: Estimate) -> list[Finding]:
    """A change of the front tyres within the drives (:func:`front_change`), as a warning:
    c_f is their mix, its std widened."""
    change = getattr(getattr(vehicle.details, "front", None), "change", None)
    if change is None:
        return []
    return [Finding(Check.FRONT_AXLE, Severity.FALLBACK, change[0], change[1], "change")]


def _slid(vehicle: Estimate) -> list[Finding]:
    """Where the rear fit described the reference's motion in bends by the rear axle's slip
    or the wheels' excess in bends (departures it fitted: a sideslip the log lacks) while the
    front fit identifies the wheelbase or the ratio, a warning: the front wheels' path in
    bends, which tells them, follows from that description to first order only, and their
    stds carry none of its error (value: the slip, rad per m/s^2; reference: the excess)."""
    details = getattr(vehicle.details, "rear", vehicle.details)     # (batch's; the live one)
    fitted = dict(getattr(details, "fitted_departures", {}) or {})
    told = any(vehicle.identified[LAYOUT.index(n)] for n in ("L", "ratio"))
    if not told or not (fitted.get("slip") or fitted.get("curve")):
        return []
    return [Finding(Check.FRONT_AXLE, Severity.FALLBACK, float(fitted.get("slip", 0.0)),
                    float(fitted.get("curve", 0.0)), "slid")]


def mapping_findings(vehicle: Estimate, diagnosis: Diagnosis, *,
                     max_difference: float = MAX_DIFFERENCE_SHARE) -> tuple[Finding, ...]:
    """What the four-wheel fit shows of the wheels' mapping and units, fatal each: front
    wheels whose difference runs against the turning (a negative front track: left and right
    swapped); rear wheels without a difference in bends beside front ones (two wheels of one
    side taken as an axle); a front axle whose wheels imply a circumference far from the rear
    one's (another unit, a wheel that reads a share of its turns), or two front wheels apart
    by more than ``max_difference`` of it (the rear wheels' gate, ``[gate]
    max_abs_c_d_fraction``: one of them scaled, another tooth count), or a wheelbase no car
    has. A front axle whose circumference differs from the rear's by more than
    :data:`FRONT_SCALE_NOTE` is a note (staggered tyres differ by a few per cent). A
    front and rear axle swapped, or a front wheel in a rear column, the rear fit names itself
    (:data:`~odocal.checks.findings.Check.FRONT_WHEELS`). A change of the front tyres within
    the drives is a warning (:func:`_changed`), as a wheelbase or ratio told on a
    reference's motion the rear fit had to describe by a slip (:func:`_slid`)."""
    found = _changed(vehicle) + _slid(vehicle)
    th, ok = vehicle.theta.as_dict(), vehicle.identified
    t_f = LAYOUT.index("t_f")
    if ok[t_f] and th["t_f"] < 0.0:
        found.append(Finding(Check.WHEEL_MAPPING, Severity.FATAL, th["t_f"],
                             float(vehicle.std[t_f]), "front-sides"))
    if diagnosis.no_differential:
        found.append(Finding(Check.WHEEL_MAPPING, Severity.FATAL, name="sides"))
    if ok["c_f"] and th["c_e"] > 0:
        ratio = th["c_f"] / th["c_e"]
        if not FRONT_SCALE[0] <= ratio <= FRONT_SCALE[1]:
            found.append(Finding(Check.FRONT_AXLE, Severity.FATAL, ratio, th["c_f"], "scale"))
        elif abs(ratio - 1.0) > FRONT_SCALE_NOTE:
            found.append(Finding(Check.FRONT_AXLE, Severity.NOTE, ratio, th["c_f"],
                                 "scale-note"))
    if ok["c_fd"] and abs(th["c_fd"]) > max_difference * abs(th["c_f"]):
        found.append(Finding(Check.FRONT_AXLE, Severity.FATAL, th["c_fd"], th["c_f"],
                             "difference"))
    elif ok["c_fd"] and abs(th["c_fd"]) > FRONT_DIFFERENCE_NOTE * abs(th["c_f"]):
        found.append(Finding(Check.FRONT_AXLE, Severity.NOTE, th["c_fd"], th["c_f"],
                             "difference-note"))
    front = getattr(vehicle.details, "front", None)
    said = getattr(front, "steering_out_of_range", None)
    if said is not None:
        found.append(Finding(Check.STEERING, Severity.FALLBACK, said, 0.0, "range"))
    attenuation = getattr(front, "steering_attenuation", None)
    if attenuation is not None and attenuation < MIN_ATTENUATION:
        found.append(Finding(Check.STEERING, Severity.NOTE, attenuation, MIN_ATTENUATION,
                             "diluted"))
    sheet = vehicle.datasheet.as_array()
    for name in FRONT:                  # a datasheet stated far from what the drives say
        j = LAYOUT.index(name)
        std = float(vehicle.std[j])
        if ok[name] and sheet[j] != LAYOUT.placeholder[j] and std > 0 \
                and abs(th[name] - sheet[j]) > DATASHEET_FAR * std \
                and abs(th[name] - sheet[j]) > 0.05 * max(abs(sheet[j]), 1e-9):
            found.append(Finding(Check.FRONT_AXLE, Severity.NOTE, th[name], float(sheet[j]),
                                 f"datasheet-far|{name}"))
    for far in getattr(front, "held_far", ()):
        found.append(Finding(Check.FRONT_AXLE, Severity.NOTE, far.drives, far.datasheet,
                             f"datasheet-held|{far.name}"))
    low, high = LAYOUT.parameters[LAYOUT.index("L")].vehicle_range
    if ok["L"] and not low <= th["L"] <= high:
        found.append(Finding(Check.FRONT_AXLE, Severity.FATAL, th["L"], high, "wheelbase"))
    return tuple(found)


#: The front wheels' circumference over the rear ones' that a car's tyres span (staggered
#: sizes differ by a tenth or two); beyond, the front rates are in another unit or scaled.
FRONT_SCALE = (0.67, 1.5)
#: Below this std (m per m/s^2) the rear fit's d is exact (a noise-free fit's) and held in the
#: front fit rather than its prior: a micrometre, below any drive's (tens of micrometres on
#: twenty minutes of driving).
LOAD_STD_FLOOR = 1e-6
#: An identified front parameter this many of its stds (and 5%) from a datasheet value stated
#: (not odocal's placeholder) is said in a note: a typo in the datasheet, or another car.
DATASHEET_FAR = 5.0
#: The front wheels' circumference off the rear ones' by more than this share is said in a
#: note: staggered tyres differ by a few per cent; more is a front speed signal converted
#: with another circumference, or rings of another tooth count, unless the car is built so.
FRONT_SCALE_NOTE = 0.05
#: Two front wheels apart per turn by more than this share of the circumference (below the
#: rear wheels' gate) is said in a note: two tyres of one axle differ by a few millimetres
#: (a tenth of a per cent); a per cent is a tyre of another size or wear, or a scaled signal.
FRONT_DIFFERENCE_NOTE = 0.01
#: A front wheel reading nothing on more than this share of the moving samples, while the
#: other turns, is dead.
DEAD_SHARE = 0.9
#: A front wheel that follows none of the other's changes for longer than this (s, of changes)
#: has stopped updating (the shared logs' longest such run is a fraction of a second).
FROZEN_S = 5.0
#: The steering angle's span (rad) below which it carries nothing (a constant column).
STEERING_MIN_SPAN = 1e-6
#: A steering angle holding one value for longer than this (s) through a bend is stuck there
#: (a car's steering wheel moves in every bend) ...
STUCK_S = 5.0
#: ... a bend: the reference's curvature (1/m, a second's mean) spanning this (a 50 m radius).
STUCK_TURN = 0.02
#: Driving straight: the reference's curvature (1/m, averaged over a second) below this (a
#: radius beyond 500 m, where a car's steering wheel stands within a few degrees of centre).
STRAIGHT_CURVATURE = 0.002
#: The seconds of straight driving a steering angle's centre and spread are judged on.
STRAIGHT_MIN_S = 10.0
#: A steering-wheel angle off centre by more than this (rad, 20 degrees) while driving
#: straight, its median or the 95th percentile of its spread, is no car's: degrees given as
#: radians (a degree of offset reads as 57), or another zero.
STRAIGHT_MAX_RAD = 0.35
#: The agreement of the steering (or the front wheels' difference) with the reference's
#: turning beyond which its sign and scale are judged.
TURNING_CORRELATION = 0.5


@dataclass(frozen=True)
class FrontChecks:
    """The front axle's inputs checked before its fit: the drives to fit (a steering angle
    that cannot be the car's taken out of its drive) and what was found."""

    drives: tuple[Drive, ...]
    findings: tuple[Finding, ...]


def front_checks(drives: Sequence[Drive], settings: Settings) -> FrontChecks:
    """Each drive's front wheels and steering against the reference's motion, before they are
    fitted. Fatal: a dead front wheel; front wheels whose difference turns against the yaw
    (left and right swapped, seen without the front track being identified); front wheels
    turning at a rate no car's tyres give beside the rear ones' (another unit). Left out of
    the fit and named (the ratio and offset then not identified): a steering angle that is
    constant, turns against the curvature (its sign) or says a ratio no steering has with
    the datasheet's wheelbase (its unit: degrees as radians)."""
    found: list[Finding] = []
    out: list[Drive] = []
    wheelbase = float(settings.identify.theta0[LAYOUT.index("L")])
    low, high = LAYOUT.parameters[LAYOUT.index("ratio")].vehicle_range
    fronts = ["n_fl" in d.inputs and "n_fr" in d.inputs for d in drives]
    steers = ["steer" in d.inputs for d in drives]
    for d, front, steer in zip(drives, fronts, steers, strict=True):
        if not front and any(fronts):            # the others carry the front axle: say so
            found.append(Finding(Check.FRONT_AXLE, Severity.NOTE, name=f"no-front|{d.name}"))
        elif front and not steer and any(steers):
            found.append(Finding(Check.STEERING, Severity.NOTE, name=f"no-steering|{d.name}"))
        if not front:
            out.append(d)
            continue
        # (within each piece: a gap's jump in position and heading is no motion)
        speed = np.hypot(derivative_pieces(d.x, d.t_s, d.pieces),
                         derivative_pieces(d.y, d.t_s, d.pieces))
        yaw = derivative_pieces(np.unwrap(np.asarray(d.psi, dtype=np.float64)), d.t_s,
                                d.pieces)
        moving = speed > 1.0
        curvature = yaw / np.maximum(speed, 2.0) * _direction(d)
        d, unsigned_s = _without_unsigned_backing(d)
        if unsigned_s > 0.0:
            found.append(Finding(Check.FRONT_AXLE, Severity.NOTE, unsigned_s, 0.0,
                                 f"unsigned|{d.name}"))
        if steer:
            d, stuck_s = _without_stuck_steering(d, moving, curvature)
            if stuck_s > 0.0:
                found.append(Finding(Check.STEERING, Severity.NOTE, stuck_s, STUCK_S,
                                     f"stuck|{d.name}"))
        # judged on the inputs with their samples not measured (NaN) bridged: a few dropped
        # frames change no verdict (the fit leaves those samples out)
        # (only where measured: a gap bridged by a held value is no frozen sensor)
        judged = dataclasses.replace(d, inputs={k: filled(v) for k, v in d.inputs.items()})
        wheels = moving & np.isfinite(d.inputs["n_fl"]) & np.isfinite(d.inputs["n_fr"])
        found += _front_wheel_findings(judged, wheels, yaw)
        found += _ahead_findings(judged, wheels, yaw)
        found += _axle_findings(judged, wheels, yaw)
        angle = moving & np.isfinite(d.inputs["steer"]) if "steer" in d.inputs else moving
        problem = _steering_problem(judged, angle, curvature, wheelbase, (low, high))
        if problem is None:
            out.append(d)
            continue
        found.append(problem)
        out.append(dataclasses.replace(d, inputs={k: v for k, v in d.inputs.items()
                                                  if k != "steer"}))
    return FrontChecks(tuple(out), tuple(found))


def _direction(drive: Drive) -> FloatArray:
    """+1 where the rear wheels turn forwards (or stand), -1 where they turn backwards: a car
    backing up turns against its steering's side (its path's curvature flips sign)."""
    rear = 0.5 * (np.asarray(drive.n_rl) + np.asarray(drive.n_rr))
    return np.where(rear < -0.25, -1.0, 1.0)


def _without_unsigned_backing(drive: Drive) -> tuple[Drive, float]:
    """The drive with its front wheels' rates left out (NaN) where the rear wheels turn
    backwards and a front wheel reads forwards: front speeds without a sign (the rear ones
    carry it) on a vehicle backing up. And the seconds left out. A front wheel turning against
    the rear ones nearly throughout is a flipped sign, named by the front checks instead."""
    rear = 0.5 * (np.asarray(drive.n_rl) + np.asarray(drive.n_rr))
    backing = _direction(drive) < 0.0
    fl, fr = (np.asarray(drive.inputs[k], dtype=np.float64) for k in ("n_fl", "n_fr"))
    against = backing & ((fl > 0.0) | (fr > 0.0))
    rolling = np.abs(rear) > 0.25
    if not against.any() or against.sum() > DEAD_SHARE * max(int(rolling.sum()), 1):
        return drive, 0.0
    inputs = {**drive.inputs, "n_fl": np.where(against, np.nan, fl),
              "n_fr": np.where(against, np.nan, fr)}
    return dataclasses.replace(drive, inputs=inputs), float(against.sum()) * drive.t_s


def _without_stuck_steering(drive: Drive, moving: BoolArray, curvature: FloatArray
                            ) -> tuple[Drive, float]:
    """The drive with its steering angle left out (NaN) where it holds one value for longer
    than :data:`STUCK_S` while the reference turns through a bend (its curvature, averaged
    over a second, spanning :data:`STUCK_TURN` or more): a sensor that stopped updating, or
    a column zeroed from some time on. And the seconds left out."""
    steer = np.asarray(drive.inputs["steer"], dtype=np.float64)
    bend = _second_mean(curvature, moving, drive.t_s)
    same = np.concatenate([[False], np.diff(steer) == 0.0])
    edges = np.flatnonzero(np.diff(np.concatenate([[0], same.astype(np.int8), [0]])))
    out = steer.copy()
    for start, stop in zip(edges[::2], edges[1::2], strict=True):
        first = max(start - 1, 0)                   # the run's first sample holds it too
        if (stop - first) * drive.t_s > STUCK_S and moving[first:stop].any() \
                and float(np.ptp(bend[first:stop])) >= STUCK_TURN:
            out[first:stop] = np.nan
    gone = float(np.count_nonzero(np.isnan(out) & ~np.isnan(steer))) * drive.t_s
    if gone == 0.0 or np.isnan(out).all():
        return drive, 0.0
    return dataclasses.replace(drive, inputs={**drive.inputs, "steer": out}), gone


def filled(values: FloatArray) -> FloatArray:
    """``values`` with its NaN (samples not measured) bridged linearly between the measured
    ones (held at the ends)."""
    x = np.asarray(values, dtype=np.float64)
    known = np.isfinite(x)
    if known.all() or not known.any():
        return x
    index = np.arange(x.size)
    return np.interp(index, index[known], x[known])


def _front_wheel_findings(d: Drive, moving: BoolArray, yaw: FloatArray) -> list[Finding]:
    """One drive's front wheels, each on its own (dead or frozen while the other turns; turning
    against the rear ones, or at a rate no car's tyres give beside them), and their difference
    against the reference's yaw over seconds (left and right swapped)."""
    found: list[Finding] = []
    fl, fr = np.asarray(d.inputs["n_fl"]), np.asarray(d.inputs["n_fr"])
    if moving.sum() > 10 and np.array_equal(fl[moving], fr[moving]):
        # one signal in both columns: no difference to swap or to fit
        return [Finding(Check.WHEEL_MAPPING, Severity.FATAL, name=f"front-copy|{d.name}")]
    dead = False
    for side, own, other in (("left", fl, fr), ("right", fr, fl)):
        turning = moving & (np.abs(other) > 0.1)
        if turning.sum() > 10 and np.mean(np.abs(own[turning]) < 1e-9) > DEAD_SHARE:
            dead = True
            found.append(Finding(Check.FRONT_AXLE, Severity.FATAL,
                                 float(np.mean(np.abs(own[turning]) < 1e-9)), DEAD_SHARE,
                                 f"dead-{side}|{d.name}"))
            continue
        longest = _frozen_s(own, other, turning, d.t_s)
        if longest > FROZEN_S:
            dead = True
            found.append(Finding(Check.FRONT_AXLE, Severity.FATAL, longest, FROZEN_S,
                                 f"frozen-{side}|{d.name}"))
    rear = 0.5 * (np.asarray(d.n_rl) + np.asarray(d.n_rr))
    rolling = moving & (np.abs(rear) > 0.25)
    if rolling.sum() > 10 and not dead:
        for side, own in (("left", fl), ("right", fr)):
            against = float(np.mean(own[rolling] * rear[rolling] < 0))
            if against > DEAD_SHARE:
                found.append(Finding(Check.FRONT_AXLE, Severity.FATAL, against, DEAD_SHARE,
                                     f"backwards-{side}|{d.name}"))
                continue
            # the rates go as the inverse circumferences: a car's tyres span FRONT_SCALE
            ratio = float(np.median(np.abs(own[rolling]) / np.abs(rear[rolling])))
            if not 1.0 / FRONT_SCALE[1] <= ratio <= 1.0 / FRONT_SCALE[0]:
                found.append(Finding(Check.FRONT_AXLE, Severity.FATAL, ratio, 1.0,
                                     f"rates-{side}|{d.name}"))
    # the front wheels' difference against the yaw, over seconds (a second's sums: the
    # wheels' noise of one sample would hide a short drive's few bends)
    size = max(1, round(1.0 / d.t_s))
    whole = (d.n_samples // size) * size
    diff = ((fr - fl) * moving)[:whole].reshape(-1, size).sum(axis=1)
    turn = (yaw * moving)[:whole].reshape(-1, size).sum(axis=1)
    bends = np.abs(turn) > 0.05 * size
    if bends.sum() >= 5:
        r = _correlation(diff[bends], turn[bends])
        if r < -TURNING_CORRELATION:
            found.append(Finding(Check.WHEEL_MAPPING, Severity.FATAL, r, 1.0,
                                 f"front-sides-yaw|{d.name}"))
    return found


#: A side's front wheel travels further than its rear one in bends, by about (L kappa)^2 / 2
#: of the path: regressed on a second's sums, the coefficient of kappa^2 / 2 (m^2) is L^2 where
#: the columns are mapped right and -L^2 where a side's front and rear are exchanged. Judged
#: beyond this many standard deviations and beyond a short car's wheelbase squared ...
AHEAD_SIGMAS = 5.0
#: ... on at least this many moving seconds, some as tight as this curvature (1/m).
AHEAD_MIN_SECONDS, AHEAD_MIN_CURVATURE = 20, 0.05


def _ahead_findings(d: Drive, moving: BoolArray, yaw: FloatArray) -> list[Finding]:
    """Each side's front wheel against its rear one in bends, on the wheels alone (the
    reference's curvature only says where the bends are): a front wheel that travels further
    by a wheelbase's share is a note (value: the coefficient, m^2; reference: its std), one
    that travels less is a rear wheel in a front column (fatal)."""
    size = max(1, round(1.0 / d.t_s))
    whole = (d.n_samples // size) * size
    if whole < AHEAD_MIN_SECONDS * size:
        return []

    def seconds(values: FloatArray) -> FloatArray:
        return np.asarray(np.where(moving, values, 0.0)[:whole].reshape(-1, size).sum(axis=1))

    speed = np.hypot(derivative_pieces(d.x, d.t_s, d.pieces),
                     derivative_pieces(d.y, d.t_s, d.pieces))
    kappa = seconds(yaw) / np.maximum(seconds(speed), 1e-9)
    counted = seconds(np.ones(d.n_samples)) == size
    found: list[Finding] = []
    behind: list[Finding] = []
    for side, front, rear in (("left", d.inputs["n_fl"], d.n_rl),
                              ("right", d.inputs["n_fr"], d.n_rr)):
        f, r = seconds(np.asarray(front)), seconds(np.asarray(rear))
        use = counted & np.isfinite(f) & np.isfinite(r) & (np.abs(r) > 0.5 * size) \
            & (f * r > 0)
        if use.sum() < AHEAD_MIN_SECONDS or not np.any(np.abs(kappa[use]) > AHEAD_MIN_CURVATURE):
            continue
        k = kappa[use]
        design = np.column_stack([np.ones(k.size), k, 0.5 * k * k])
        coef, *_ = np.linalg.lstsq(design, f[use] / r[use], rcond=None)
        residual = f[use] / r[use] - design @ coef
        sigma2 = float(residual @ residual) / max(k.size - 3, 1)
        std = float(np.sqrt(sigma2 * np.linalg.pinv(design.T @ design)[2, 2])) / abs(coef[0])
        l2 = float(coef[2] / coef[0])
        short = FRONT_MIN_M ** 2
        if l2 < -short and l2 + AHEAD_SIGMAS * std < 0.0:
            behind.append(Finding(Check.WHEEL_MAPPING, Severity.FATAL, l2, std,
                                  f"front-behind-{side}|{d.name}"))
        elif l2 > short and l2 - AHEAD_SIGMAS * std > 0.0:
            found.append(Finding(Check.FRONT_AXLE, Severity.NOTE, l2, std,
                                 f"ahead-{side}|{d.name}"))
    if len(behind) == 2:                    # both sides: the axles exchanged, said once
        behind = [dataclasses.replace(behind[0], name=f"front-behind-axles|{d.name}")]
    return found + behind


#: An axle's wheels' difference follows the reference's turning second by second (a
#: correlation of 0.995 or more on simulated and real drives): below this, on at least
#: :data:`AXLE_MIN_BENDS` seconds of bends, its columns hold no axle (two wheels of one side,
#: a front and a rear wheel: 0.2-0.5 on simulated drives) ...
AXLE_CORRELATION = 0.8
AXLE_MIN_BENDS = 10


def _axle_findings(d: Drive, moving: BoolArray, yaw: FloatArray) -> list[Finding]:
    """Each axle's wheels' difference against the reference's yaw over seconds of bends: a
    pair that does not follow it (nor turns against it: left and right swapped, named
    elsewhere) is not an axle's (fatal)."""
    size = max(1, round(1.0 / d.t_s))
    whole = (d.n_samples // size) * size

    def seconds(values: FloatArray) -> FloatArray:
        return np.asarray(np.where(moving, values, 0.0)[:whole].reshape(-1, size).sum(axis=1))

    turn = seconds(yaw)
    bends = np.abs(turn) > 0.05 * size
    if bends.sum() < AXLE_MIN_BENDS:
        return []
    found = []
    for axle, left, right in (("front", d.inputs["n_fl"], d.inputs["n_fr"]),
                              ("rear", d.n_rl, d.n_rr)):
        diff = seconds(np.asarray(right) - np.asarray(left))[bends]
        if not np.ptp(diff):
            continue                            # one signal in both columns: named elsewhere
        # with the axle's travel taken out (two wheels of it apart in scale: named elsewhere)
        travel = np.column_stack([np.ones(diff.size),
                                  seconds(np.asarray(right) + np.asarray(left))[bends]])
        r = _correlation(*(v - travel @ np.linalg.lstsq(travel, v, rcond=None)[0]
                           for v in (diff, turn[bends])))
        if -TURNING_CORRELATION <= r < AXLE_CORRELATION:
            found.append(Finding(Check.WHEEL_MAPPING, Severity.FATAL, r, AXLE_CORRELATION,
                                 f"axle-sides-{axle}|{d.name}"))
    return found


def front_ahead(findings: Sequence[Finding]) -> bool:
    """Whether ``findings`` (:func:`front_checks`') show both sides' front wheels travelling
    further than their rear ones in bends, and none less: the rear columns hold no front
    wheel, whatever the rear fit makes of the wheels' excess in bends."""
    names = [f.name.partition("|")[0] for f in findings]
    return ("ahead-left" in names and "ahead-right" in names
            and not any(n.startswith("front-behind") for n in names))


def _frozen_s(own: FloatArray, other: FloatArray, turning: BoolArray, t_s: float) -> float:
    """The longest time (s, of the other wheel's changes) ``own`` holds one value while
    ``other`` changes and its speed moves by more than a tenth: a sensor that stopped updating.
    An encoder at a steady speed holds its count too, while the other wheel's count flickers
    by a tick: that the tenth leaves out."""
    changing = np.flatnonzero(turning[1:] & (np.diff(other) != 0)) + 1
    if changing.size < 2:
        return 0.0
    stuck = (own[changing] == own[changing - 1]).astype(np.int64)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], stuck, [0]])))
    longest = 0.0
    for start, stop in zip(edges[::2], edges[1::2], strict=True):
        span = other[changing[start]:changing[stop - 1] + 1]
        if np.ptp(span) > 0.1 * max(float(np.mean(np.abs(span))), 1e-9):
            longest = max(longest, float(stop - start) * t_s)
    return longest


def _correlation(a: FloatArray, b: FloatArray) -> float:
    a, b = a - a.mean(), b - b.mean()
    den = float(np.sqrt((a * a).sum() * (b * b).sum()))
    return float((a * b).sum() / den) if den > 0 else 0.0


def _straight(curvature: FloatArray, moving: BoolArray, t_s: float) -> BoolArray:
    """The samples of straight driving: moving, with the reference's curvature, averaged over
    a second (its noise sample to sample is a jittery pose's), below :data:`STRAIGHT_CURVATURE`."""
    return moving & (np.abs(_second_mean(curvature, moving, t_s)) < STRAIGHT_CURVATURE)


def _second_mean(curvature: FloatArray, moving: BoolArray, t_s: float) -> FloatArray:
    """The curvature while moving (0 standing), averaged over a second about each sample (over
    all of them where they span less)."""
    n = min(max(round(1.0 / t_s), 1), max(curvature.size, 1))
    return np.convolve(np.where(moving, curvature, 0.0), np.ones(n) / n, mode="same")


def _steering_problem(drive: Drive, moving: BoolArray, curvature: FloatArray,
                      wheelbase: float, ratio_range: tuple[float, float]) -> Finding | None:
    """Why the drive's steering angle cannot be the car's (a FALLBACK finding: it is left
    out), or None: constant while moving; where it agrees too little with the curvature to
    judge its sign and scale, far off centre while driving straight (its median or spread
    beyond :data:`STRAIGHT_MAX_RAD`); else against the curvature, or a ratio beyond
    ``ratio_range`` with ``wheelbase`` (the slope of the angle on the curvature is ``ratio
    L`` at small angles)."""
    steer = drive.inputs.get("steer")
    if steer is None or not moving.any():
        return None
    s = np.asarray(steer, dtype=np.float64)[moving]
    if float(np.ptp(s)) < STEERING_MIN_SPAN:
        return Finding(Check.STEERING, Severity.FALLBACK, float(s[0]), 0.0,
                       f"constant|{drive.name}")
    k = curvature[moving]
    r = _correlation(s, k)
    if abs(r) < TURNING_CORRELATION:         # too straight to judge the sign or the scale:
        straight = _straight(curvature, moving, drive.t_s)[moving]      # its centre then
        if straight.sum() < STRAIGHT_MIN_S / drive.t_s:
            return None
        centre = float(np.median(s[straight]))
        spread = float(np.percentile(np.abs(s[straight] - centre), 95))
        if max(abs(centre), spread) > STRAIGHT_MAX_RAD:
            return Finding(Check.STEERING, Severity.FALLBACK, centre, spread,
                           f"straight|{drive.name}")
        return None
    slope = float(((s - s.mean()) * (k - k.mean())).sum() / ((k - k.mean()) ** 2).sum())
    ratio = slope / wheelbase
    if ratio < 0:
        return Finding(Check.STEERING, Severity.FALLBACK, ratio, r, f"sign|{drive.name}")
    if not ratio_range[0] <= ratio <= ratio_range[1]:
        return Finding(Check.STEERING, Severity.FALLBACK, ratio, wheelbase,
                       f"unit|{drive.name}")
    return None
