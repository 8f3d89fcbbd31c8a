"""Changes within a drive: a CUSUM on each completed cluster's own estimate of the wheels.

A cluster of windows (one segment length of driving) gives its own estimate of c_e and c_d
(jointly, the others held) against a *reference*: the running estimate when the detector was
last quiet, frozen while evidence of a change accumulates (a running estimate that takes the
changed clusters in would chase the change and shrink it). Each estimate, standardised by its
information and by the clusters' own robust spread (from the median of their successive
differences: mis-weighted errors do not pass for changes, and a change, which moves the level,
does not widen the scale), feeds a two-sided CUSUM (allowance ``k``, threshold ``h``:
``[online] cusum_k, cusum_h``).

What is not a tyre is kept out:

* windows where the vehicle hardly moves (parked, with the reference pose jittering): below
  :data:`MIN_RATE_REVPS` there is no circumference to see;
* windows whose wheels disagree with the reference by more than :data:`GROSS` (a tenth): slip
  on ice, a locked wheel, reversing with unsigned wheel speeds. No tyre changes by that much;
* a cluster adds at most :data:`CAP` standard deviations, and a change must show in the last
  :data:`PERSIST` informative clusters, each by more than ``k``, the same way: a disturbance of
  up to half a minute touches at most three clusters (of about 16 s), so it cannot raise an
  alarm however large it is.

When the CUSUM rises, :func:`estimate_change` finds where the change began (the likelihood
change point over the windows) and how much (the wheels refitted on the windows after it,
against an estimate from the windows before it): an :class:`Alarm`. While nothing is folded,
a suspicion that a steady drift of c_e explains rather than a step (:func:`drifting`) is a
:class:`Drift`: no alarm where the core takes the drift in (the calibrator asks it).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from odocal.arrays import BoolArray, FloatArray
from odocal.estimators import departures as fitted_departures
from odocal.estimators import fitting
from odocal.estimators.error_model import (
    CHANNELS,
    ErrorModel,
    coupling_gain,
    decouple,
    expected_revolutions,
    window_variance,
)
from odocal.estimators.lag import Lag
from odocal.estimators.windows import WindowSet
from odocal.model.vehicle import MODEL

#: Standardised cluster estimates kept for their robust spread.
_SCALE_MEMORY = 200
#: Cluster estimates before the spread is trusted (until then the scale is generous).
_SCALE_WARMUP = 10
#: Wheels turning slower than this (rev/s, about 1 m/s) say nothing about a circumference.
MIN_RATE_REVPS = 0.5
#: A window whose wheel turns more than this share away from the reference is not a tyre.
GROSS = 0.1
#: The most one cluster adds to the CUSUM, in (scaled) standard deviations.
CAP = 3.0
#: Informative clusters in a row that must each show the change.
PERSIST = 4
#: Usable windows a cluster needs to be informative.
_MIN_WINDOWS = 3
#: The change's parameters (indices into theta).
_LAYOUT = MODEL.layout
#: The wheels' parameters a tyre moves: the distance scale (both wheels alike) and the wheels'
#: difference (one against the other), by name and position in theta.
NAMES = (_LAYOUT.scale, _LAYOUT.difference)
WHEELS = _LAYOUT.indices(NAMES)


@dataclass(frozen=True)
class Alarm:
    """A change within the drive.

    parameter : ``c_e`` (both wheels changed alike) or ``c_d`` (one wheel, or the two unlike)
    t : when the change began (the likelihood change point), s on the log's clock
    detected_t : when the alarm rose, s
    distance_km, detected_distance_km : the same in driven distance
    relative_change : the step of ``parameter`` over c_e before it
    sigmas : the step in its own standard deviations
    change_m : the steps of c_e and c_d, m
    std_m : their standard deviations, m
    wheel : ``both``, ``left`` or ``right``: whose circumference changed
    """

    parameter: str
    t: float
    detected_t: float
    distance_km: float
    detected_distance_km: float
    relative_change: float
    sigmas: float
    change_m: tuple[float, float] = (0.0, 0.0)
    std_m: tuple[float, float] = (math.nan, math.nan)
    wheel: str = "both"

    def to_dict(self) -> dict[str, Any]:
        return {"parameter": self.parameter, "t": self.t, "detected_t": self.detected_t,
                "distance_km": self.distance_km, "detected_distance_km": self.detected_distance_km,
                "relative_change": self.relative_change, "sigmas": self.sigmas,
                "c_e_change_m": self.change_m[0], "c_d_change_m": self.change_m[1],
                "c_e_change_std_m": _finite(self.std_m[0]),
                "c_d_change_std_m": _finite(self.std_m[1]), "wheel": self.wheel}


def _finite(value: float) -> float | None:
    return value if math.isfinite(value) else None


@dataclass
class Cusum:
    """Two-sided CUSUM on standardised steps (k: allowance; the threshold is the detector's)."""

    k: float
    upper: float = 0.0
    lower: float = 0.0

    def update(self, z: float) -> None:
        self.upper = max(0.0, self.upper + z - self.k)
        self.lower = max(0.0, self.lower - z - self.k)

    @property
    def quiet(self) -> bool:
        return self.upper == 0.0 and self.lower == 0.0

    def reset(self) -> None:
        self.upper = self.lower = 0.0


@dataclass(frozen=True)
class Steps:
    """Each window's evidence on (c_e, c_d) against a reference: the gradient ``g`` (W, 2) and
    information ``h`` (W, 2, 2) of the weighted squared residuals (the step is ``h^-1 g``), and
    whether the window is usable (moving, and not grossly off)."""

    g: FloatArray
    h: FloatArray
    usable: BoolArray


def _predicted(windows: WindowSet, p: FloatArray, shift: float,
               heading_offset: float, end_t: float | None = None
               ) -> tuple[FloatArray, FloatArray]:
    """Each window's revolutions (W, 2) at the core's ``p`` (theta and the departures fitted;
    a spread of the wheels' timing left out: it moves a window by a tiny share) and their
    Jacobian in theta (W, 2, n). ``end_t``: the end of the windows ``p`` was fitted on, where
    its c_e is theirs at the end of a drift (the drift then runs on from it)."""
    tau = None
    if end_t is not None and p[fitting.DRIFT]:
        tau = (windows.t0 + 0.5 * windows.length * windows.t_s - end_t) / 3600.0
    pred, jac = fitting.wheels(np.asarray(p, dtype=np.float64),
                               fitting.View.of(windows, shift, heading_offset, tau_h=tau),
                               smooth=False)
    return pred, jac[..., fitting.THETA]


def disturbed(windows: WindowSet, p: FloatArray, shift: float,
              heading_offset: float) -> BoolArray:
    """(W,): windows a disturbance spoils: a wheel turning more than :data:`GROSS` away from
    what the reference motion and the core's ``p`` make it turn (slip on ice, a locked wheel,
    reversing with unsigned wheel speeds, a spike), where the wheels turn at all (a parked
    vehicle's windows are never called disturbed). No tyre changes by a tenth; the fit and the
    change detector leave such windows out."""
    pred, _ = _predicted(windows, p, shift, heading_offset)
    span = windows.length * windows.t_s
    moving = np.abs(pred) >= MIN_RATE_REVPS * span
    return np.asarray(np.any(moving & (np.abs(windows.measured - pred) > GROSS * np.abs(pred)),
                             axis=1))


def window_steps(windows: WindowSet, reference: FloatArray, shift: float, heading_offset: float,
                 model: ErrorModel, end_t: float | None = None) -> Steps:
    """The windows' evidence on a change of c_e and c_d from ``reference`` (the core's p; see
    :class:`Steps`)."""
    pred, jac = _predicted(windows, reference, shift, heading_offset, end_t)
    wheels = windows.measured - pred                                  # per wheel
    r = wheels @ CHANNELS.T
    j = np.einsum("ci,wip->wcp", CHANNELS, jac[:, :, list(WHEELS)])
    w = 1.0 / window_variance(expected_revolutions(windows.measured, r), model.noise)
    gain = coupling_gain(windows.measured, r, model.coupling)
    r, j = decouple(r, gain), decouple(j, gain)
    span = windows.length * windows.t_s
    moving = np.all(np.abs(pred) >= MIN_RATE_REVPS * span, axis=1)
    usable = moving & ~np.any(np.abs(wheels) > GROSS * np.abs(pred), axis=1)
    g = np.einsum("wc,wcp,wc->wp", w, j, r)
    h = np.einsum("wc,wcp,wcq->wpq", w, j, j)
    return Steps(g=np.where(usable[:, None], g, 0.0),
                 h=np.where(usable[:, None, None], h, 0.0), usable=usable)


def _solve2(h: FloatArray, g: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The step ``h^-1 g`` and its standard deviations (nan where a direction is not seen)."""
    scale = np.sqrt(np.maximum(np.diag(h), 1e-300))
    hs = h / np.outer(scale, scale)
    if np.linalg.cond(hs) > 1e8:
        out = np.full(2, np.nan)
        std = np.full(2, np.nan)
        if h[0, 0] > 0:                                 # c_e alone (no differential signal)
            out[0], std[0] = g[0] / h[0, 0], 1.0 / math.sqrt(h[0, 0])
        return out, std
    inv = np.linalg.inv(hs) / np.outer(scale, scale)
    return inv @ g, np.sqrt(np.maximum(np.diag(inv), 0.0))


@dataclass(frozen=True)
class Suspect:
    """The detector's verdict on a cluster: a change of ``parameter`` (an index into theta)
    against ``reference`` (the core's p), begun between ``since_t`` (the start of the first
    cluster since the detector was last quiet) and ``until_t`` (the start of the latest
    cluster); ``reference_t``: the end of the windows the reference was fitted on."""

    parameter: int
    since_t: float
    until_t: float
    reference: FloatArray
    sigmas: float
    reference_t: float | None = None


@dataclass
class _Record:
    t0: float
    z: FloatArray          # (2,) scaled, uncapped


@dataclass
class ChangeDetector:
    """The CUSUMs of c_e and c_d over completed clusters, against a frozen reference."""

    k: float
    h: float
    cusum: tuple[Cusum, Cusum] = field(init=False)
    reference: FloatArray | None = None
    reference_t: float | None = None         # the end of the windows it was fitted on
    since_t: float | None = None
    seen: list[list[float]] = field(default_factory=lambda: [[], []])
    recent: list[_Record] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.cusum = (Cusum(self.k), Cusum(self.k))

    def reset(self) -> None:
        """After a change: quiet, with no reference (the next running estimate becomes it)."""
        for c in self.cusum:
            c.reset()
        self.reference = None
        self.since_t = None
        self.recent.clear()

    def watch(self, cluster: WindowSet, p: FloatArray, shift: float, heading_offset: float,
              model: ErrorModel) -> Suspect | None:
        """One completed cluster; ``p`` the running estimate (the core's p: the reference while
        quiet). A :class:`Suspect` when a change has persisted long enough, else None."""
        quiet = all(c.quiet for c in self.cusum)
        if self.reference is None or quiet:
            self.reference = np.asarray(p, dtype=np.float64).copy()
            self.reference_t = float(cluster.t0[0])         # (p is of the windows before it)
        steps = window_steps(cluster, self.reference, shift, heading_offset, model,
                             self.reference_t)
        if int(steps.usable.sum()) < _MIN_WINDOWS:
            return None                                  # parked, or all disturbed: no verdict
        step, std = _solve2(steps.h.sum(axis=0), steps.g.sum(axis=0))
        z = np.zeros(2)
        for i in range(2):
            if not (math.isfinite(step[i]) and std[i] > 0):
                continue
            raw = step[i] / std[i]
            seen = self.seen[i]
            seen.append(raw)
            del seen[:-_SCALE_MEMORY]
            z[i] = raw / self._scale(i)
        t0 = float(cluster.t0[0])
        self.recent.append(_Record(t0, z))
        del self.recent[:-PERSIST]
        for i, cusum in enumerate(self.cusum):
            cusum.update(float(np.clip(z[i], -CAP, CAP)))
        if all(c.quiet for c in self.cusum):
            self.since_t = None
        elif quiet or self.since_t is None:
            self.since_t = t0                          # evidence begins to gather here
        found: Suspect | None = None
        for i, cusum in enumerate(self.cusum):
            side = 1.0 if cusum.upper > self.h else (-1.0 if cusum.lower > self.h else 0.0)
            if side == 0.0 or len(self.seen[i]) < _SCALE_WARMUP or len(self.recent) < PERSIST:
                continue
            if all(side * r.z[i] > self.k for r in self.recent):
                sigmas = abs(float(np.mean([r.z[i] for r in self.recent])))
                if found is None or sigmas > found.sigmas:
                    found = Suspect(parameter=WHEELS[i],
                                    since_t=min(self.since_t or t0, self.recent[0].t0),
                                    until_t=t0, reference=self.reference.copy(),
                                    sigmas=sigmas, reference_t=self.reference_t)
        return found

    def _scale(self, i: int) -> float:
        """The spread of the clusters' standardised estimates (1 where the weights are right):
        from their successive differences (a change moves the level, not the differences),
        their median absolute value, never below 1; generous while few are seen."""
        seen = self.seen[i]
        if len(seen) < 3:
            return 1.0 + 10.0 / max(len(seen), 1)
        spread = 1.4826 * float(np.median(np.abs(np.diff(seen)))) / math.sqrt(2.0)
        return max(spread, 1.0 + 10.0 / len(seen) if len(seen) < _SCALE_WARMUP else 1.0)


def change_point(steps: Steps, t0: FloatArray, *, earliest: float, latest: float) -> int:
    """The index of the first window after the change: the likelihood change point of a step in
    (c_e, c_d) from the reference, among windows starting in [earliest, latest]; the windows
    (``steps``, ``t0``) in time order, ending with those that show the change."""
    g = np.cumsum(steps.g[::-1], axis=0)[::-1]            # sums from each window to the end
    h = np.cumsum(steps.h[::-1], axis=0)[::-1]
    best, at = -math.inf, 0
    for s in np.flatnonzero((t0 >= earliest) & (t0 <= latest) & steps.usable):
        try:
            gain = float(g[s] @ np.linalg.solve(h[s] + 1e-12 * np.eye(2) * np.trace(h[s]), g[s]))
        except np.linalg.LinAlgError:
            continue
        if gain > best:
            best, at = gain, int(s)
    return at


@dataclass(frozen=True)
class Drift:
    """A suspected change that a steady drift of c_e explains (:func:`drifting`): the gains
    over the reference of the drift, of the step, and of a step on top of the drift; the
    drift's rate (relative, per hour)."""

    drift_gain: float
    step_gain: float
    both_gain: float
    per_hour: float


#: The fastest drift the running fit can take in (relative per hour: the ``drift``
#: departure's bound); a faster one is followed by steps.
DRIFT_BOUND = fitted_departures.NUISANCES[fitted_departures.NAMES.index("drift")].bound


def _gain(steps: Steps, columns: list[FloatArray]) -> tuple[float, FloatArray]:
    """The gain in the weighted squared residuals over the reference of the model whose
    parameters move each window's (c_e, c_d) by ``columns`` (each (W, 2)), and its solution."""
    x = np.stack(columns, axis=1)                                      # (W, K, 2)
    g = np.einsum("wkp,wp->k", x, steps.g)
    h = np.einsum("wkp,wpq,wlq->kl", x, steps.h, x)
    scale = np.sqrt(np.maximum(np.diag(h), 1e-300))
    solved = np.linalg.lstsq(h / np.outer(scale, scale), g / scale, rcond=1e-10)[0]
    return float((g / scale) @ solved), solved / scale


def drifting(steps: Steps, t0: FloatArray, index: int, latest: float,
             c_e: float) -> Drift | None:
    """Whether a steady drift of c_e (a level in c_e and c_d, a slope in c_e: the fit's
    ``drift``) explains ``steps`` rather than the step at ``index`` (a level and a step in
    both). All three must hold:

    * the drift explains them as well as the step, the step's place (searched among the
      usable windows starting up to ``latest``) counted against the step (Schwarz's ``log``
      of their number, as batch counts a change's time);
    * a step on top of the drift adds no more than a step's own penalty (``2 log`` of the
      windows and the ``log`` of the places): warming and then a tyre changed is a step;
    * the drift is one the running fit can take in (:data:`DRIFT_BOUND`).

    One tyre drifting (c_d) is a step here: the fit's drift is c_e's. Each gain is in the
    weighted squared residuals over the reference; on simulated drives the step's gain led
    the drift's by 10.6 to 74 for steps of 0.3-1% of c_e, and by -1.7 to 1.8 for a drift of
    0.3% over 20 minutes (the place's penalty at most 6.3)."""
    span = max(float(t0[-1] - t0[0]), 1e-9)
    zero, one = np.zeros(t0.size), np.ones(t0.size)
    slope = (t0 - t0.mean()) / span
    after = (np.arange(t0.size) >= index).astype(float)
    level = [np.stack([one, zero], axis=1), np.stack([zero, one], axis=1)]
    ramp = [np.stack([slope, zero], axis=1)]
    step = [np.stack([after, zero], axis=1), np.stack([zero, after], axis=1)]
    drift_gain, solved = _gain(steps, level + ramp)
    step_gain, _ = _gain(steps, level + step)
    both_gain, _ = _gain(steps, level + ramp + step)
    windows = max(int(steps.usable.sum()), 3)
    places = math.log(max(int((steps.usable & (t0 <= latest)).sum()), 1))
    per_hour = float(solved[2]) / c_e * 3600.0 / span
    if drift_gain >= step_gain - places \
            and both_gain - drift_gain <= 2.0 * math.log(windows) + places \
            and abs(per_hour) <= DRIFT_BOUND:
        return Drift(drift_gain, step_gain, both_gain, per_hour)
    return None


@dataclass(frozen=True)
class Change:
    """The change found: where it began, the estimate before it (the core's p) and the steps
    of c_e and c_d with their standard deviations."""

    index: int
    t: float
    distance_m: float
    before: FloatArray
    step: FloatArray
    std: FloatArray


def estimate_change(windows: WindowSet, folded: fitting.Folded, suspect: Suspect, *,
                    p: FloatArray, lag: Lag, heading_offset: float, model: ErrorModel,
                    smooth: bool, tolerance: float, drift: bool = False
                    ) -> Change | Drift | None:
    """Where a suspected change began and how large it is; with ``drift`` (the running fit
    can take a drift of c_e in), a :class:`Drift` where one explains the windows rather than a
    step (:func:`drifting`). The change point is searched among the windows in memory up to
    the suspect's latest cluster (a small change lets the CUSUM fall back to zero now and then
    after it: where its evidence last began is no bound); the wheels before it come from the
    windows before it (and the folded sums) fitted anew, all parameters free; after it, c_e
    and c_d alone from the windows after it, the others held at the fit before. ``p``: the
    running estimate (the core's p). None where the windows after it cannot carry the step."""
    steps = window_steps(windows, suspect.reference, lag.shift, heading_offset, model,
                         suspect.reference_t)
    index = change_point(steps, windows.t0, earliest=-math.inf, latest=suspect.until_t)
    after = np.arange(windows.size) >= index
    if int((steps.usable & after).sum()) < _MIN_WINDOWS:
        return None
    found = drifting(steps, windows.t0, index, suspect.until_t,
                     _LAYOUT.value(suspect.reference, _LAYOUT.scale)) if drift else None
    if found is not None:
        return found
    theta_size = int(np.asarray(p[fitting.THETA]).size)
    free = fitting.free_of(np.ones(theta_size, dtype=bool), kappa=smooth,
                           offset=folded.offset_free)
    channels = np.ones(2)
    before_fit: FloatArray = np.asarray(suspect.reference, dtype=np.float64).copy()
    if index > 0 or folded.clusters:
        view = fitting.View.of(windows.take(~after), lag.shift, heading_offset)
        fit = fitting.solve(np.asarray(p, dtype=np.float64), view, free, model, folded, channels,
                            max_iterations=5, tolerance=tolerance)
        if np.all(np.isfinite(fit.p)):
            before_fit = np.asarray(fit.p, dtype=np.float64).copy()
    # after: the wheels alone, from the reference moved by the windows' own step (a good start
    # for the robust weights), the rest held at the fit before
    mine = windows.take(after & steps.usable)
    first, _ = _solve2(steps.h[after].sum(axis=0), steps.g[after].sum(axis=0))
    wheels = list(WHEELS)
    start = before_fit.copy()
    if np.all(np.isfinite(first)):
        start[wheels] = suspect.reference[wheels] + first
    view = fitting.View.of(mine, lag.shift, heading_offset)
    wheels_free = np.zeros(fitting.P, dtype=bool)
    wheels_free[wheels] = True
    empty = fitting.Folded(origin=folded.origin)
    fit = fitting.solve(start, view, wheels_free, model, empty, channels, max_iterations=8,
                        tolerance=tolerance)
    if not np.all(np.isfinite(fit.p)):
        return None
    h, _ = fit.normal_equations(empty)
    try:
        cov = np.linalg.inv(h[np.ix_(wheels, wheels)])
    except np.linalg.LinAlgError:
        return None
    step = np.asarray(fit.p[wheels]) - before_fit[wheels]
    std = np.sqrt(np.maximum(np.diag(cov), 0.0))
    return Change(index=index, t=float(windows.t0[index]),
                  distance_m=float(windows.distance_m[index]), before=before_fit, step=step,
                  std=std)


def describe(change: Change, suspect: Suspect, *, detected_t: float,
             detected_distance_km: float) -> Alarm:
    """The alarm for a change: which wheels (c_e: both alike; c_d: one, or the two unlike)."""
    c_e = _LAYOUT.value(change.before, _LAYOUT.scale)
    d_e, d_d = (float(v) for v in change.step)
    whole = np.zeros(_LAYOUT.size)
    whole[list(WHEELS)] = change.step
    left, right = (float(v) for v in MODEL.wheel_changes(whole))    # each tyre's own change
    if abs(left) < abs(right) / 3.0:
        wheel = "right"
    elif abs(right) < abs(left) / 3.0:
        wheel = "left"
    else:
        wheel = "both" if left * right > 0 else "unlike"
    parameter = 0 if wheel == "both" else 1
    if wheel == "unlike":                 # (the two wheels moved apart: named by the larger)
        z = np.abs(change.step) / np.where(change.std > 0, change.std, np.inf)
        parameter = int(np.argmax(z))
        wheel = "both" if parameter == 0 else ("left" if abs(left) > abs(right) else "right")
    std = float(change.std[parameter])
    step = float(change.step[parameter])
    return Alarm(parameter=NAMES[parameter], t=change.t, detected_t=detected_t,
                 distance_km=change.distance_m / 1000.0,
                 detected_distance_km=detected_distance_km,
                 relative_change=step / c_e, sigmas=step / std if std > 0 else math.inf,
                 change_m=(d_e, d_d), std_m=(float(change.std[0]), float(change.std[1])),
                 wheel=wheel)


def eliminate(folded: fitting.Folded, step: FloatArray) -> fitting.Folded:
    """The folded sums with what they say about c_e and c_d taken out (profiled: they keep
    what they say about t_r, d and the lag's spread, whatever the wheels were), and their
    residual moments moved by the wheels' ``step``: the evidence from before a change of the
    wheels, for the estimate after it."""
    import dataclasses

    wheels = list(WHEELS)
    rest = [i for i in range(fitting.P) if i not in wheels]
    h = folded.h
    h_cc = h[np.ix_(wheels, wheels)]
    if not np.any(h_cc):
        return dataclasses.replace(folded, last=None)
    project = np.eye(fitting.P)                        # scores -> profiled scores
    gain = h[np.ix_(rest, wheels)] @ np.linalg.pinv(h_cc)
    project[np.ix_(rest, wheels)] = -gain
    project[wheels, :] = 0.0
    new_h = project @ h @ project.T
    new_b = project @ folded.b
    meat = project @ folded.meat @ project.T
    recent = folded.recent @ project.T
    # the coupling's residual moments, about origin: the windows' residuals at p are now those
    # they had at p - step (v = (1, p - origin) -> (1, p - step - origin))
    move = np.eye(1 + fitting.P)
    for i, s in zip(wheels, step, strict=True):
        move[1 + i, 0] = -float(s)
    coupling = np.einsum("ai,kab,bj->kij", move, folded.coupling, move)
    return dataclasses.replace(folded, h=new_h, b=new_b, meat=meat, recent=recent,
                               coupling=coupling, last=None)
