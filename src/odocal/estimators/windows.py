"""The window set: what the default method fits, in batch and live alike.

A window is ``window_s`` of wheel revolutions (the measurement) beside the reference motion over
the same time (the model's input), summed. The model predicts a window's revolutions for *any*
theta from moments of the motion (:meth:`odocal.model.vehicle.RearAxleModel.predict`), so a
window keeps only those: ``sum ds a^j``, ``sum dpsi a^j`` and ``sum lat a^j`` (the displacement
across the heading) for ``j < SERIES``. The moments are kept at every whole-step shift
of the reference side within ``margin`` steps (the wheel stream's clock offset is chosen when
fitting, by linear interpolation between them), and those across the heading let a constant
heading offset of the reference be applied when the windows are used.

Every quantity is a sum: windows of different drives, chunks or times concatenate, and the
online calibrator folds the oldest into normal equations (:mod:`odocal.estimators.core`).
:class:`WindowBuilder` makes windows from samples in any chunks, piece by piece;
:func:`windows_from_drives` is the same builder fed whole drives.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from odocal.arrays import BoolArray, FloatArray, IntArray
from odocal.data.drive import Drive
from odocal.model.kinematics import midpoint_heading
from odocal.model.vehicle import SERIES
from odocal.settings import Settings

#: Moment columns: ``ds a^j``, ``dpsi a^j``, ``lat a^j`` for j < SERIES, then the same three
#: times the reference's own lateral acceleration ``v w`` (where a_y is missing, the load
#: transfer d it cannot show is still felt: :func:`load_transfer_column`), then the time the
#: reference moves (signed by the direction of travel: what a wheel-rate offset, or rates
#: truncated towards zero, add to the revolutions), then what the departures of
#: :mod:`odocal.estimators.departures` act through: ``2 sin(dpsi / 2) sin(beta)`` and ``...
#: cos(beta)`` (the chord a point off the axle turns through, across and along the axle's
#: direction of travel), ``dpsi^2 / ds`` on moving steps (the curvature squared: wheels ahead
#: of the axle, or a reference whose heading is its course), ``a t_s`` and ``v w t_s`` (the
#: lateral acceleration against the reference's own).
COLUMNS = 3 * SERIES + 11
#: The index of the moving time among the moment columns ...
MOVING = 3 * SERIES + 3
#: ... of the chord's two parts, ``dpsi^2 / ds``, ``a t_s``, ``v w t_s``, ``w^2 t_s`` (what a
#: point beside the axle adds to ``v w``) and ``w^2 ds`` (a reference smoothed in time cuts a
#: bend short by ``(w sigma)^2 / 2`` of it).
BETA_TURN, CURVE, ACCEL, AREF, COS_TURN, TURN2, CUT = (MOVING + k for k in range(1, 8))
#: The largest curvature a moving step counts in ``dpsi^2 / ds`` (1/m: a 2 m radius; beyond it a
#: reference's jitter at a crawl, not a bend).
MAX_CURVATURE = 0.5
#: ... and among the columns the model takes (:meth:`WindowSet.at`), with those of the
#: departures: ``beta dpsi``, ``dpsi^2 / ds``, ``a t_s``, ``v w t_s`` and the step across the
#: turned heading (the reference's sideways motion).
AT_MOVING = 2 * SERIES + 2
AT_BETA_TURN, AT_CURVE, AT_ACCEL, AT_AREF, AT_COS_TURN, AT_TURN2, AT_CUT, AT_LAT = (
    AT_MOVING + k for k in range(1, 9))
AT_WIDTH = AT_LAT + 1
#: A step moves when the reference goes faster than this (m/s).
MOVING_MPS = 0.5
#: Straight stretches for the heading offset: one second long, faster than this (m/s) ...
STRAIGHT_SPEED_MPS = 3.0
#: ... and turning slower than this (rad/s).
STRAIGHT_YAW_RADPS = 0.02
#: Samples of straight stretches below which no heading offset is applied (five seconds).
STRAIGHT_MIN_SAMPLES = 200
#: Steps either way the moments are differenced over for their derivatives in the shift.
SPAN = 16
#: Steps of a window that set its peak yaw rate by their moving average (noise is not a bend).
_YAW_SMOOTHING = 5
#: Per-step columns the builder keeps: t, revolutions rl, rr, ds, dpsi, lat, a, dx, dy, psi,
#: beta.
_T, _RL, _RR, _DS, _DPSI, _LAT, _A, _DX, _DY, _PSI, _BETA = range(11)
_STEP_COLUMNS = 11


@dataclass(frozen=True)
class WindowSet:
    """Windows of wheel revolutions and reference-motion moments.

    t0 : (W,) time of each window's first wheel step, s
    distance_m : (W,) reference distance travelled before the window (since the first sample)
    cluster : (W,) label of the group of neighbouring windows (one segment length of a drive)
    measured : (W, 2) measured revolutions of the rear-left and rear-right wheel
    moments : (W, S, COLUMNS) motion moments at the reference side's shifts ``-margin..margin``
    follows : (W,) the window starts where the one before it in the set ended (same piece)
    weight : (W,) the window's weight (1; less where forgetting fades older evidence)
    peak_yaw_radps : (W,) the largest smoothed reference yaw rate within the window
    length, margin : steps per window, and the most the reference side shifts either way
    t_s : sampling time, s
    """

    t0: FloatArray
    distance_m: FloatArray
    cluster: IntArray
    measured: FloatArray
    moments: FloatArray
    follows: BoolArray
    weight: FloatArray
    peak_yaw_radps: FloatArray
    length: int
    margin: int
    t_s: float

    @property
    def size(self) -> int:
        return int(self.t0.shape[0])

    @property
    def shifts(self) -> int:
        """Whole steps the reference side can be shifted either way with the second difference
        of the moments still at hand (the lag scan's limit)."""
        return max(self.margin - 1, 0)

    def take(self, index: BoolArray | IntArray) -> WindowSet:
        """The windows at ``index``, each with its ``follows`` as it was (whether it continues
        the window before it in time, kept or folded elsewhere)."""
        return replace(self, t0=self.t0[index], distance_m=self.distance_m[index],
                       cluster=self.cluster[index], measured=self.measured[index],
                       moments=self.moments[index], follows=self.follows[index],
                       weight=self.weight[index], peak_yaw_radps=self.peak_yaw_radps[index])

    def scaled(self, factor: float) -> WindowSet:
        """The same windows with their weights times ``factor`` (forgetting)."""
        return replace(self, weight=self.weight * factor)

    def rotated(self, heading_offset: float) -> FloatArray:
        """The moments the model takes at every whole-step shift (W, S, AT_WIDTH)."""
        return _rotated(self.moments, heading_offset)

    def at(self, shift: float, heading_offset: float) -> tuple[FloatArray, FloatArray]:
        """The moments the model takes, ``[along_j, dpsi_j, along v w, dpsi v w, moving, ...]``
        (W, AT_WIDTH), at a (fractional) shift of the reference side (steps; linear between
        whole steps, kept within :attr:`shifts`), the along-track ones turned by the heading
        offset; and their second difference in the shift (the counting window's spread; zero
        without a margin)."""
        at, _, second = self.around(shift, heading_offset)
        return at, second

    def around(self, shift: float, heading_offset: float
               ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """:meth:`at`'s moments, and their first and second derivative in the shift (per step,
        per step squared): how they move with the reference side's lag, and a spread of the
        wheels' timing. The derivatives are differences :data:`SPAN` steps either way (fewer
        near the margin's end): a difference of neighbouring shifts is the reference's
        position noise differenced twice, which would drown the signal. The second derivative
        leaves the moments at the shift itself out (those at half the span and the span either
        way: ``(m(+s) + m(-s) - m(+s/2) - m(-s/2)) / (3 s^2 / 4)``): the residual holds the
        reference's noise at the shift, and a derivative holding it too would fit a spread of
        about a third of the span squared to noise alone."""
        moments = self.moments
        if moments.shape[1] < 3:
            m = _rotated(moments[:, 0], heading_offset)
            return m, np.zeros_like(m), np.zeros_like(m)
        limit = self.shifts
        x = min(max(shift, -limit), limit) + self.margin
        span = float(max(1, min(SPAN, math.floor(min(x, moments.shape[1] - 1 - x)))))
        at = _interpolate(moments, x)
        ahead, behind = _interpolate(moments, x + span), _interpolate(moments, x - span)
        if span >= 4.0:
            inner = _interpolate(moments, x + span / 2) + _interpolate(moments, x - span / 2)
            second = (ahead + behind - inner) / (0.75 * span ** 2)
        else:
            second = (ahead + behind - 2.0 * at) / span ** 2
        return (_rotated(at, heading_offset),
                _rotated(0.5 * (ahead - behind) / span, heading_offset),
                _rotated(second, heading_offset))

    def third(self, shift: float, heading_offset: float) -> FloatArray:
        """The moments' third derivative in the shift (per step cubed), from the moments at
        half the span and the span either way (:meth:`around`'s):
        ``(m(+s) - 2 m(+s/2) + 2 m(-s/2) - m(-s)) / (s^3 / 4)``; zero where the margin is too
        narrow for it."""
        moments = self.moments
        limit = self.shifts
        x = min(max(shift, -limit), limit) + self.margin
        span = float(min(SPAN, math.floor(min(x, moments.shape[1] - 1 - x))))
        if moments.shape[1] < 3 or span < 4.0:
            return np.zeros_like(_rotated(moments[:, 0], heading_offset))
        outer = _interpolate(moments, x + span) - _interpolate(moments, x - span)
        inner = _interpolate(moments, x + span / 2) - _interpolate(moments, x - span / 2)
        return _rotated((outer - 2.0 * inner) / (0.25 * span ** 3), heading_offset)

    @staticmethod
    def concat(sets: Sequence[WindowSet]) -> WindowSet:
        """Windows of several sets, in order (each window's ``follows`` as its set says: a
        builder's windows know whether they continue its previous ones)."""
        sets = [s for s in sets if s.size] or list(sets[:1])
        first = sets[0]

        def cat(name: str) -> FloatArray:
            return np.concatenate([getattr(s, name) for s in sets])

        return replace(first, t0=cat("t0"), distance_m=cat("distance_m"),
                       cluster=cat("cluster").astype(np.int64), measured=cat("measured"),
                       moments=cat("moments"), follows=cat("follows").astype(bool),
                       weight=cat("weight"), peak_yaw_radps=cat("peak_yaw_radps"))


def empty_windows(*, length: int, margin: int, t_s: float) -> WindowSet:
    """A window set with no windows."""
    return WindowSet(t0=np.zeros(0), distance_m=np.zeros(0), cluster=np.zeros(0, dtype=np.int64),
                     measured=np.zeros((0, 2)),
                     moments=np.zeros((0, 2 * margin + 1, COLUMNS)),
                     follows=np.zeros(0, dtype=bool), weight=np.zeros(0),
                     peak_yaw_radps=np.zeros(0), length=length, margin=margin, t_s=t_s)


def _interpolate(moments: FloatArray, x: float) -> FloatArray:
    """Moments (W, S, C) at a fractional index ``x`` of their shifts."""
    lo = min(math.floor(x), moments.shape[1] - 1)
    frac = x - lo
    if frac == 0.0:
        return np.asarray(moments[:, lo])
    return np.asarray(moments[:, lo] * (1.0 - frac) + moments[:, lo + 1] * frac)


def _rotated(moments: FloatArray, offset: float) -> FloatArray:
    """``[along_j, dpsi_j, along a_ref, dpsi a_ref, moving, beta dpsi, dpsi^2 / ds, a t_s,
    v w t_s, across]`` from the stored columns (..., COLUMNS): the step along the direction of
    travel when the reference heading is ``offset`` short of it (``ds cos + lat sin``: (1)
    projected on the turned heading, exactly), and across it (``lat cos - ds sin``)."""
    ds, dpsi, lat = (moments[..., k * SERIES:(k + 1) * SERIES] for k in range(3))
    rds, rdpsi, rlat = (moments[..., 3 * SERIES + k, None] for k in range(3))
    across = lat[..., :1]
    if offset != 0.0:
        c, s = math.cos(offset), math.sin(offset)
        across = lat[..., :1] * c - ds[..., :1] * s
        ds, rds = ds * c + lat * s, rds * c + rlat * s
    return np.concatenate([ds, dpsi, rds, rdpsi, moments[..., MOVING:MOVING + 8], across],
                          axis=-1)


class WindowBuilder:
    """Windows from samples as they arrive, piece by piece (batch: whole drives; live: chunks).

    Parameters
    ----------
    t_s : the sampling time, s
    length : steps per window
    margin : steps kept on either side of a window for the reference side's shift
    cluster_steps : steps per cluster of neighbouring windows (a segment's length)
    drive : index of the drive (batch), part of each cluster's label
    """

    def __init__(self, *, t_s: float, length: int, margin: int, cluster_steps: int,
                 drive: int = 0) -> None:
        self.t_s, self.length, self.margin = t_s, length, margin
        self.cluster_span_s = max(cluster_steps, 1) * t_s
        self.drive = drive
        self.origin: float | None = None
        self.straight = np.zeros(3)            # heading offset: sums lat, lon, samples
        self.distance_m = 0.0                   # reference distance of every step added
        self._left_m = 0.0                      # ... of the steps that have left the ring
        self._ring = np.zeros((0, _STEP_COLUMNS))   # steps of the piece not yet windowed
        self._last: FloatArray | None = None    # the piece's last sample (t, n_rl, ..., psi)
        # dx, dy, dpsi, psi of the straight stretch under way
        self._stretch = np.zeros((0, 4))        # (not theta)
        self._follows = False                   # the next window follows the last one made
        self._done: list[WindowSet] = []

    def add(self, t: FloatArray, n_rl: FloatArray, n_rr: FloatArray, a_y: FloatArray,
            beta: FloatArray, x: FloatArray, y: FloatArray, psi: FloatArray) -> None:
        """Samples (M,) each, continuing the current piece; a gap of more than 1.5 steps in
        ``t`` (from the last sample added) ends the piece there."""
        samples = np.column_stack([t, n_rl, n_rr, a_y, beta, x, y, psi]).astype(np.float64)
        if samples.shape[0] == 0:
            return
        if self.origin is None:
            self.origin = float(samples[0, 0])
        if self._last is not None:
            samples = np.vstack([self._last, samples])
        gaps = np.flatnonzero(np.diff(samples[:, 0]) > 1.5 * self.t_s) + 1
        for k, run in enumerate(np.split(samples, gaps)):
            if k > 0:
                self.end_piece()
            if run.shape[0] >= 2:
                self._steps(run)
            self._last = run[-1].copy()

    def end_piece(self) -> None:
        """The piece ends: no step and no window across this point."""
        self._to_stretches(self._ring)
        self._left_m += float(np.hypot(self._ring[:, _DX], self._ring[:, _DY]).sum())
        self._ring = np.zeros((0, _STEP_COLUMNS))
        self._stretch = np.zeros((0, 4))        # (not theta)
        self._last = None
        self._follows = False

    def straight_so_far(self) -> FloatArray:
        """The straight-stretch sums of every step added so far (those not yet in a window
        included), as :func:`windows_from_drives` gives them for a whole drive."""
        pending = np.vstack([self._stretch, self._ring[:, [_DX, _DY, _DPSI, _PSI]]])
        size = max(round(1.0 / self.t_s), 1)
        whole = pending.shape[0] // size
        return self.straight + straight_sums(pending[:whole * size], size, self.t_s)

    def windows(self) -> WindowSet:
        """The windows completed since the last call."""
        done = self._done
        self._done = []
        if not done:
            return empty_windows(length=self.length, margin=self.margin, t_s=self.t_s)
        return WindowSet.concat(done)

    def _steps(self, run: FloatArray) -> None:
        """The steps between consecutive samples of a run: revolutions and reference motion."""
        t, n_rl, n_rr, a_y, beta, x, y, psi = run.T
        dpsi = np.remainder(np.diff(psi) + np.pi, 2.0 * np.pi) - np.pi
        h = midpoint_heading(psi[:-1], dpsi, beta[:-1])
        dx, dy = np.diff(x), np.diff(y)
        cos, sin = np.cos(h), np.sin(h)
        steps = np.column_stack([t[:-1], n_rl[:-1] * self.t_s, n_rr[:-1] * self.t_s,
                                 dx * cos + dy * sin, dpsi, -dx * sin + dy * cos, a_y[:-1],
                                 dx, dy, psi[:-1], beta[:-1]])
        self.distance_m += float(np.hypot(dx, dy).sum())
        self._ring = np.vstack([self._ring, steps])
        self._close()

    def _close(self) -> None:
        """Close every window the ring holds with its margins: measured revolutions and the
        motion moments at every whole-step shift of the reference side."""
        length, margin = self.length, self.margin
        count = (self._ring.shape[0] - 2 * margin - length) // length + 1
        if count <= 0:
            return
        ring = self._ring[:2 * margin + count * length]
        start = margin + length * np.arange(count)
        a = ring[:, _A]
        power = a[:, None] ** np.arange(SERIES)[None, :]
        a_ref = (ring[:, _DS] * ring[:, _DPSI] / self.t_s**2)[:, None]      # v w
        ds, dpsi = ring[:, _DS], ring[:, _DPSI]
        fast = np.abs(ds) > MOVING_MPS * self.t_s
        moving = np.where(fast, np.sign(ds) * self.t_s, 0.0)[:, None]
        with np.errstate(divide="ignore", invalid="ignore"):
            kappa = np.where(fast, dpsi / ds, 0.0)
        kappa = np.clip(kappa, -MAX_CURVATURE, MAX_CURVATURE)
        chord = 2.0 * np.sin(0.5 * dpsi)
        extra = np.column_stack([chord * np.sin(ring[:, _BETA]), kappa * kappa * np.abs(ds),
                                 a * self.t_s, a_ref[:, 0] * self.t_s,
                                 chord * np.cos(ring[:, _BETA]), dpsi * dpsi / self.t_s,
                                 np.abs(ds) * (dpsi / self.t_s) ** 2])
        columns = np.concatenate([ds[:, None] * power, dpsi[:, None] * power,
                                  ring[:, _LAT, None] * power,
                                  ring[:, [_DS, _DPSI, _LAT]] * a_ref, moving, extra], axis=1)
        # each window's sums from its own steps (a running sum over the whole ring would leave
        # rounding of its size in every difference, and depend on how the samples came)
        span = length + 2 * margin
        local = columns[start[:, None] - margin + np.arange(span)[None, :]]   # (count, span, C)
        cum = np.concatenate([np.zeros((count, 1, COLUMNS)), np.cumsum(local, axis=1)], axis=1)
        lo = margin - np.arange(-margin, margin + 1)                            # (S,)
        moments = cum[:, lo + length] - cum[:, lo]                             # (count, S, C)
        measured = ring[start[:, None] + np.arange(length)[None, :], _RL:_RR + 1].sum(axis=1)
        yaw = ring[:, _DPSI] / self.t_s
        smooth = np.convolve(yaw, np.full(_YAW_SMOOTHING, 1.0 / _YAW_SMOOTHING), "same")
        peak = np.abs(smooth[start[:, None] + np.arange(length)[None, :]]).max(axis=1)
        step_m = np.hypot(ring[:, _DX], ring[:, _DY])
        before = np.concatenate([[0.0], np.cumsum(step_m)])
        t0 = ring[start, _T]
        assert self.origin is not None
        cluster = (self.drive * 10**9
                   + np.floor((t0 - self.origin) / self.cluster_span_s)).astype(np.int64)
        # standing still says nothing: the wheels do not turn, or the reference stays put
        # (where wheels that read an offset would be all residual)
        moving = (np.abs(measured).sum(axis=1) > 0) & (moments[:, margin, MOVING] != 0)
        follows = np.ones(count, dtype=bool)
        follows[0] = self._follows
        follows[1:] &= moving[:-1]
        self._follows = bool(moving[-1])
        keep = moving
        self._done.append(WindowSet(
            t0=t0[keep], distance_m=(self._left_m + before[start])[keep], cluster=cluster[keep],
            measured=measured[keep], moments=moments[keep], follows=follows[keep],
            weight=np.ones(int(keep.sum())), peak_yaw_radps=peak[keep], length=length,
            margin=margin, t_s=self.t_s))
        leaving = count * length
        self._to_stretches(self._ring[:leaving])
        self._left_m += float(step_m[:leaving].sum())
        self._ring = self._ring[leaving:]

    def _to_stretches(self, steps: FloatArray) -> None:
        """Add the one-second straight stretches these steps complete (stretches start at the
        piece's first step; whatever the chunks, each is summed whole)."""
        pending = np.vstack([self._stretch, steps[:, [_DX, _DY, _DPSI, _PSI]]])
        size = max(round(1.0 / self.t_s), 1)
        whole = pending.shape[0] // size
        self.straight += straight_sums(pending[:whole * size], size, self.t_s)
        self._stretch = pending[whole * size:]


def straight_sums(steps: FloatArray, size: int, t_s: float) -> FloatArray:
    """Sums over whole stretches of ``size`` steps that are straight and fast: the displacement
    across and along the heading at the stretch's middle, and the samples. ``steps`` (N, 4):
    dx, dy, dpsi, psi at each step's start; N a multiple of ``size``."""
    parts = steps.reshape(-1, size, 4)
    dx, dy, turn = parts[:, :, 0].sum(axis=1), parts[:, :, 1].sum(axis=1), parts[:, :, 2].sum(1)
    dt = size * t_s
    psi = midpoint_heading(parts[:, 0, 3], turn)
    ok = (np.hypot(dx, dy) / dt > STRAIGHT_SPEED_MPS) & (np.abs(turn) / dt < STRAIGHT_YAW_RADPS)
    return np.array([float(np.sum((-dx * np.sin(psi) + dy * np.cos(psi))[ok])),
                     float(np.sum((dx * np.cos(psi) + dy * np.sin(psi))[ok])),
                     float(ok.sum() * size)])


def heading_offset(straight: FloatArray) -> float:
    """The reference heading's constant rotation against the direction of travel (rad; added to
    the heading it gives the course), from :func:`straight_sums`; 0 on less than five seconds of
    straight driving."""
    lat, lon, used = (float(v) for v in straight)
    if used < STRAIGHT_MIN_SAMPLES or lon <= 0:
        return 0.0
    return math.atan2(lat, lon)


def builder_for(settings: Settings, t_s: float, *, drive: int = 0,
                cluster_steps: int | None = None, reach_s: float | None = None
                ) -> WindowBuilder:
    """A builder with the default method's window length and margin (``[inverse]``); clusters
    of a segment's length unless ``cluster_steps`` says otherwise. ``reach_s``: how far the lag
    scan reaches either way (default ``lag_scan_s``: the clocks are aligned before, to within
    it; at most ``max_delay_s``). Every piece loses the margin at either end."""
    cfg = settings.inverse
    length = max(round(cfg.window_s / t_s), 1)
    reach = cfg.lag_scan_s if reach_s is None else min(reach_s, cfg.max_delay_s)
    # room for the lag scan (a step beyond the range, so a lag at its end is not at the
    # grid's edge) and one step either way for the counting window's spread
    margin = math.ceil(reach / t_s - 1e-6) + 2 if cfg.delay == "estimate" else 0
    return WindowBuilder(t_s=t_s, length=length, margin=margin,
                         cluster_steps=cluster_steps or settings.segments.length, drive=drive)


#: Short drives are clustered finer so that they give at least this many clusters ...
MIN_CLUSTERS = 10
#: ... of at least this many windows each.
MIN_CLUSTER_WINDOWS = 2


def cluster_steps_for(drives: Sequence[Drive], settings: Settings, *,
                      reach_s: float | None = None) -> int:
    """Steps per cluster of windows of a drive: a segment's length (``[segments] length``), or
    less where the drive is too short for :data:`MIN_CLUSTERS` of them, down to two windows.
    A 20 s scene is then five clusters of 4 s, not one: its evidence is judged (with the
    few-clusters widening) rather than refused as a single piece. Each drive is clustered by
    its own length (:func:`windows_from_drives` asks drive by drive), so that a drive added to
    a calibration changes nothing of the others' clusters."""
    if not drives:
        return settings.segments.length
    margin = builder_for(settings, drives[0].t_s, reach_s=reach_s).margin   # lost at each end
    steps = sum(max(b - a - 1 - 2 * margin, 0) for d in drives for a, b in d.pieces)
    window = max(round(settings.inverse.window_s / drives[0].t_s), 1)
    return int(min(settings.segments.length,
                   max(MIN_CLUSTER_WINDOWS * window, steps // MIN_CLUSTERS)))


def windows_from_drives(drives: Sequence[Drive], settings: Settings, *,
                        chunk: int = 65536, reach_s: float | None = None
                        ) -> tuple[WindowSet, FloatArray]:
    """Every window of every piece of the drives, and their straight-stretch sums (the builder
    fed each piece in chunks: memory stays bounded however long the drive); ``reach_s`` as
    :func:`builder_for` takes it."""
    sets, straight = [], np.zeros(3)
    for k, d in enumerate(drives):
        builder = builder_for(settings, d.t_s, drive=k,
                              cluster_steps=cluster_steps_for([d], settings, reach_s=reach_s),
                              reach_s=reach_s)
        for a, b in d.pieces:
            for lo in range(a, b, chunk):
                hi = min(lo + chunk, b)
                builder.add(d.t[lo:hi], d.n_rl[lo:hi], d.n_rr[lo:hi], d.a_y[lo:hi],
                            d.beta[lo:hi], d.x[lo:hi], d.y[lo:hi], d.psi[lo:hi])
            builder.end_piece()
            sets.append(builder.windows())
        straight += builder.straight
    return WindowSet.concat(sets), straight


def drives_heading_offset(drives: Sequence[Drive]) -> tuple[float, int]:
    """The reference heading's offset against the direction of travel on the drives' straight
    stretches (rad), and the samples it rests on (as the window builder finds it)."""
    straight = np.zeros(3)
    for d in drives:
        size = max(round(1.0 / d.t_s), 1)
        for a, b in d.pieces:
            dpsi = np.diff(d.psi[a:b])
            steps = np.column_stack([np.diff(d.x[a:b]), np.diff(d.y[a:b]), dpsi, d.psi[a:b - 1]])
            whole = steps.shape[0] // size
            straight += straight_sums(steps[:whole * size], size, d.t_s)
    return heading_offset(straight), int(straight[2])
