"""Calibrating while the vehicle drives: the default method's core, folded over time.

The paper closes with this plan (section 7): re-calibrate online from the signals measured while
driving. :class:`OnlineCalibrator` takes samples in any chunks (``push``) and answers at any time
(``estimate``) with the same :class:`~odocal.estimators.estimate.Estimate` as the batch methods.

It is the batch default method, run on a window set that grows as the samples arrive: the same
window builder (:class:`~odocal.estimators.windows.WindowBuilder`) makes the same windows, and
the same core (:func:`odocal.estimators.core.fit`) fits them, with the same lag scan, error
model, covariance and identifiability verdict. Memory is bounded by folding: beyond
``[online] max_windows`` windows, the oldest cluster is folded into sums
(:func:`odocal.estimators.core.fold`: normal equations linearised at the estimate of the moment,
the cluster's scores for the sandwich, the error model's sums and the lag scan's costs), whose
error is of second order in how far theta has moved since. With nothing folded the online
estimate *is* the batch one.

With ``forgetting_s`` set, older evidence fades with that time constant (a parameter that
drifts is tracked). Independently, a two-sided CUSUM watches each completed cluster's own
estimate of c_e and c_d against the running estimate (:mod:`odocal.online.changes`): a step
(tyre pressure, a tyre change) raises an alarm with when, where and how much, and the estimate
restarts from the new level.

Before anything is published, the samples go through the checks every path goes through
(:mod:`odocal.checks`); a contradiction between the data and the model (wheels swapped, wheel
rates in another unit, a dead wheel sensor, ...) halts the calibrator with the finding instead
of an estimate.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from odocal.arrays import BoolArray, FloatArray
from odocal.checks.departures import Departures, wheel_lag_s
from odocal.checks.departures import findings as departure_findings
from odocal.checks.departures import measure as measure_departures
from odocal.checks.diagnosis import check_drives
from odocal.checks.findings import Check, Diagnosis, Finding, Severity
from odocal.checks.gate import gate
from odocal.data.drive import Drive
from odocal.errors import ConfigError, DataError
from odocal.estimators import core, fitting
from odocal.estimators import departures as fitted
from odocal.estimators.base import held_by_checks
from odocal.estimators.estimate import (
    CovarianceKind,
    Estimate,
    NotIdentified,
    Reason,
    Status,
    judge,
)
from odocal.estimators.front_axle import (
    FrontDetails,
    FrontFit,
    car_estimate,
    fit_car_front,
    front_ahead,
    front_checks,
    mapping_findings,
)
from odocal.estimators.windows import (
    WindowBuilder,
    WindowSet,
    builder_for,
    empty_windows,
    heading_offset,
)
from odocal.model import registry
from odocal.model.four_wheel import FOUR_WHEEL_MODEL
from odocal.model.parameters import PARAMETER_NAMES, PARAMETERS, Parameters
from odocal.model.vehicle import MODEL
from odocal.online.arrivals import Arrivals
from odocal.online.changes import (
    WHEELS,
    Alarm,
    Change,
    ChangeDetector,
    Drift,
    Suspect,
    describe,
    estimate_change,
)
from odocal.online.checking import CHECK_WINDOW_S, LiveChecks
from odocal.online.departures import (
    LiveDepartures,
    ReferenceAligner,
    recorrected,
)
from odocal.online.front import (
    COLUMNS,
    INPUTS,
    REFIT_GROWTH,
    Alignment,
    Fitted,
    LiveFront,
)
from odocal.online.running import RunningFit
from odocal.online.samples import SAMPLE, Intake, has_column
from odocal.settings import Settings

#: The running update scans the lag every this many completed clusters.
_LAG_EVERY = 4
#: A suspected change is an alarm where the wheels refitted after it moved by this many of their
#: standard deviations.
CONFIRM_SIGMAS = 5.0
#: The samples are kept this long (s) at most, to make the windows again with a correction
#: found after them (a heading error): the first of the drive.
HISTORY_S = 2.0 * CHECK_WINDOW_S


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
    findings: tuple[Finding, ...] = ()
    """The checks' findings on the latest driving (and the quality gate's on the estimate)."""
    halted: bool = False
    """The data contradicted the model: the calibrator stopped updating (see ``findings``)."""
    time_unit: str = "s"
    """How the pushed ``t`` came: ``s``, ``ms``, ``us``, ``ns`` or ``datetime``."""
    sampling_s: float = float("nan")
    """The grid's step (the first samples'; later ones at another rate are put onto it), s."""
    front: FrontDetails | None = None
    """The four-wheel car's front fit (None: the rear axle's model, or nothing fitted)."""
    front_kept_s: float = 0.0
    """The span of driving the front fit rests on (s; :mod:`odocal.online.front`)."""
    departures: tuple[tuple[str, float, float], ...] = ()
    """The departures fitted beside theta (:mod:`odocal.estimators.departures`): name, value
    and standard deviation, as batch's details give them."""

    @property
    def fitted_departures(self) -> dict[str, float]:
        """The departures fitted, by name (the lag: in steps of the grid, within
        :attr:`delay_s`)."""
        return {name: value for name, value, _ in self.departures}

    def to_dict(self) -> dict[str, Any]:
        return {"samples": self.samples, "windows": self.windows,
                "windows_in_memory": self.windows_in_memory, "clusters": self.clusters,
                "distance_km": self.distance_km, "delay_s": self.delay_s,
                "heading_offset_rad": self.heading_offset_rad,
                "noise": {"distance": {"s0_rev": self.noise[0][0], "f": self.noise[0][1]},
                          "yaw": {"s0_rev": self.noise[1][0], "f": self.noise[1][1]}},
                "alarms": [a.to_dict() for a in self.alarms],
                "forgetting_s": self.forgetting_s,
                "coupling_beta": self.coupling,
                "diagnosis": [f.to_dict() for f in self.findings], "halted": self.halted,
                "time_unit": self.time_unit,
                "sampling_s": self.sampling_s if math.isfinite(self.sampling_s) else None,
                "departures": [{"name": n, "value": v, "std": s}
                               for n, v, s in self.departures],
                **({"front_axle": self.front.to_dict(), "front_kept_s": self.front_kept_s}
                   if self.front is not None else {})}


class OnlineCalibrator:
    """Calibrate while driving: ``push`` samples in any chunks, ``estimate`` at any time.

    Parameters
    ----------
    settings : all settings (``[online]`` for the window memory, forgetting and the change
        detector; ``[inverse]`` for the windows and the clock-offset range; ``[identify]`` for
        the datasheet values and the identifiability verdict)
    theta0 : the starting estimate (default: the datasheet values ``[identify] theta0``)
    """

    def __init__(self, settings: Settings | None = None,
                 theta0: Parameters | FloatArray | None = None, *,
                 source: str = "live samples") -> None:
        #: The four-wheel car's settings (None: the rear axle's model); its rear axle is
        #: calibrated with the rear-axle model's (:attr:`settings`), as batch does.
        self.car_settings = _car_settings(settings or Settings())
        self.settings = (settings or Settings()) if self.car_settings is None \
            else self.car_settings.replace(vehicle={"model": registry.DEFAULT})
        #: What the samples are called in the checks' words (``replay``: the log's name).
        self.source = source
        start = (np.asarray(self.settings.identify.theta0, dtype=np.float64) if theta0 is None
                 else (theta0.as_array() if isinstance(theta0, Parameters)
                       else np.asarray(theta0, dtype=np.float64)))
        if self.car_settings is not None and start.shape == (FOUR_WHEEL_MODEL.layout.size,):
            start = start[:MODEL.size]            # (the car's theta0: its rear axle starts)
        lengths = MODEL.layout.indices(MODEL.layout.lengths)
        if start.shape != (MODEL.size,) or not np.all(np.isfinite(start)) \
                or np.any(start[list(lengths)] <= 0):
            raise DataError(f"theta0 {start.tolist()} is not a usable starting estimate")
        self.datasheet = np.asarray(self.settings.identify.theta0, dtype=np.float64)
        # the running estimate, its error model and lag, and the evidence folded
        self._fit = RunningFit(self.settings, self.datasheet, start)
        car = self.car_settings is not None
        self._intake = Intake(INPUTS if car else ())    # the chunks as samples on one grid
        self._front: LiveFront | None = None      # the car's front axle (once the grid is known)
        self._front_fit: FrontFit | None = None   # its last fit (estimate(running=True)),
        self._front_fit_s = 0.0                   # and the driving it rested on (s)
        self._front_seen_ahead = False            # the four wheels showed the front ahead
        self._rear_fitted = Fitted()              # the departures the rear fit estimated
        self._aligner: ReferenceAligner | None = None
        self._builder: WindowBuilder | None = None
        self._windows: WindowSet | None = None
        self._departures = LiveDepartures()       # what is taken out of the samples
        # the samples on the grid as they came, while the windows can still be made again
        self._history: list[FloatArray] | None = (
            None if self.settings.online.forgetting_s else [])
        self._arrivals = Arrivals()               # the cluster under way, kept aside
        self._since_fit = 0                       # windows added since the core last ran
        self._alarms: list[Alarm] = []
        self._clusters_done = 0
        cfg = self.settings.online
        self._changes = ChangeDetector(k=cfg.cusum_k, h=cfg.cusum_h)
        # the checks: the latest samples as they came, what they found, and whether they halted
        self._checks = LiveChecks(COLUMNS if car else SAMPLE)

    # ---------------------------------------------------------------- input

    def push(self, chunk: Mapping[str, Any] | Any) -> None:
        """Add samples: a mapping of drive-format column names to arrays, or a pandas DataFrame.

        Columns ``t, n_rl, n_rr, a_y, x, y, psi`` are required, ``beta`` is optional; ``t`` must
        increase, in s, ms, us or ns (told apart by the sampling step) or as datetimes. Samples
        off the grid of the first ones' step (another rate, jittered time stamps) are
        interpolated onto it (:mod:`odocal.online.samples`). A gap longer than 1.5 sampling
        steps ends the current piece (windows never span a gap). A chunk that cannot be used
        raises a DataError naming why and leaves the calibrator as it was.
        """
        started = self._t_s is not None
        if self.car_settings is not None:
            _require_front_wheels(chunk)
        rows = self._intake.take(chunk)
        if not rows.shape[0]:
            return
        if not started:
            self._start()
        if self._checks.halted:
            return                       # the data contradicted the model: nothing more is used
        try:
            self._update(rows)
        except (np.linalg.LinAlgError, FloatingPointError) as exc:
            self._checks.failed(exc)

    def _start(self) -> None:
        """The grid's step is known (the first two samples): the windows can be made."""
        assert self._t_s is not None
        self._builder = builder_for(self.settings, self._t_s)
        self._windows = empty_windows(length=self._builder.length,
                                      margin=self._builder.margin, t_s=self._t_s)
        self._aligner = ReferenceAligner(self._t_s)
        if self.car_settings is not None:
            self._front = LiveFront(self.car_settings, self._t_s, self.source)

    @property
    def _t_s(self) -> float | None:
        """The grid's step (s), once known."""
        return self._intake.t_s

    def _update(self, rows: FloatArray) -> None:
        """The samples (in seconds) onto the grid, into windows, the estimate updated."""
        assert self._builder is not None
        grid = self._intake.grid(rows)
        if not grid.shape[0]:
            return
        if self._front is not None and self._front.add(grid):
            self._front.settle(self._alignment())
        full, grid = grid, grid[:, :len(SAMPLE)]           # (the rear axle's samples)
        if self._history is not None:
            since = self._history[0][0, 0] if self._history else grid[0, 0]
            if self._fit.folded.clusters or self._alarms or grid[-1, 0] - since > HISTORY_S:
                self._history = None                  # (no window can be made again now)
            else:
                self._history.append(grid)
        # (as they came: the checks measure)
        self._checks.keep(full, driven=bool(self._arrivals.total))
        assert self._aligner is not None
        aligned = self._aligner.add(grid)             # the reference on the wheels' clock
        if aligned.shape[0]:
            self._builder.add(*self._departures.correct(aligned).T)
        self._take(self._builder.windows())
        if self._checks.due:
            self._check()

    def _check(self) -> None:
        """The checks every path goes through, on the latest samples; a contradiction halts
        the calibrator (it publishes the finding instead of an estimate from then on)."""
        latest = self._checks.latest(self._t_s, self.source)
        if latest is None:
            return
        if isinstance(latest, Diagnosis):
            self._checks.found(latest)
            return
        drive, driving_s = latest
        diagnosis = check_drives([drive], self.settings)
        if self.car_settings is not None:         # the front wheels and steering, as batch
            diagnosis = diagnosis.plus(front_checks([drive], self.car_settings).findings)
            # (once the four wheels showed the front ones ahead, the rear fit's excess in
            # bends is the reference's: :meth:`_rear_estimate`)
            self._front_seen_ahead = self._front_seen_ahead or front_ahead(diagnosis.findings)
            # a model input left out whole (a steering angle beyond any car's: its unit), said
            # as batch says it when it reads the log
            diagnosis = diagnosis.plus([
                Finding(Check.INVALID_INPUT, Severity.FALLBACK, name=str(said))
                for said in drive.metadata.get("left_out", ())])
        if not (diagnosis.fatal or diagnosis.standstill):
            # the reference on the wheels' clock, and the sensors' departures, measured as
            # batch measures them (on the samples as they came) and taken out of the samples
            # from now on, and of the windows in memory where that can be done exactly
            # (odocal/online/departures.py)
            self._align(drive)
            self._adopt(measure_departures([drive], self.settings,
                                           lateral=not diagnosis.lateral_missing),
                        driving_s=driving_s)
        self._checks.found(diagnosis.plus(departure_findings(self._departures.as_measured(),
                                                             self.settings)))

    def _align(self, drive: Drive) -> None:
        """The wheel stream's lag behind the reference, measured as batch measures it (beyond
        half the fit's own lag scan, within ``[inverse] max_delay_s``): where it moved by more
        than half the scan, the reference is put on the wheels' clock anew (the windows made
        again where they can be; else from the next sample on, in a new piece)."""
        cfg = self.settings.inverse
        if cfg.delay != "estimate" or self._aligner is None or self._builder is None:
            return
        found = wheel_lag_s([drive], self.datasheet, self.settings)
        if found is None or abs(found) > cfg.max_delay_s:
            return                                  # (not determined now: keep what is)
        shift = found if abs(found) > 0.5 * cfg.lag_scan_s else 0.0
        if abs(shift - self._aligner.shift_s) <= 0.5 * cfg.lag_scan_s:
            return
        self._departures = dataclasses.replace(self._departures, reference_shift_s=shift)
        if self._rebuilt():
            return
        rest = self._aligner.flush()                # what the old shift can still align
        if rest.shape[0]:
            self._builder.add(*self._departures.correct(rest).T)
        self._builder.end_piece()
        self._take(self._builder.windows())
        assert self._t_s is not None
        self._aligner = ReferenceAligner(self._t_s, shift)

    def _adopt(self, found: Departures, *, driving_s: float) -> None:
        """A new measurement of the departures (on ``driving_s`` of driving): the corrections
        it determines replace the earlier ones; the windows in memory are corrected by the
        difference."""
        old, new = self._departures, self._departures.adopt(found, driving_s, self.settings)
        if new == old:
            return
        self._departures = new
        if self._windows is not None:
            self._flush()
        if new.heading_harmonics != old.heading_harmonics and self._rebuilt():
            pass                                   # (the windows made anew, corrected)
        elif self._windows is not None:
            self._windows = recorrected(
                self._windows,
                wheels_revps=(new.wheel_offset_revps[0] - old.wheel_offset_revps[0],
                              new.wheel_offset_revps[1] - old.wheel_offset_revps[1]))
        if self._windows is not None and self._windows.size and self._fit.updates:
            # the running estimate moved to the corrected windows, and the change detector
            # starts again from it: a correction is not a change of the wheels
            current = self._solve(self._fitted(), max_iterations=3)
            if np.all(np.isfinite(current.p)):
                self._fit.take(current.p)
            self._changes.reset()
        if new.wheel_step_revps:
            self._fit.encoded(new.wheel_step_revps)

    def _rebuilt(self) -> bool:
        """The windows in memory made again from the samples as they came, with the
        corrections of now (a heading error cannot be taken out of a window's moments after
        the fact): where nothing has been folded, restarted or faded yet (the first minutes of
        a drive, whose samples are kept for this). Whether they were."""
        if (self._fit.folded.clusters or self._alarms or self.settings.online.forgetting_s
                or self._t_s is None or not self._history):
            return False
        raw = np.vstack(self._history)
        builder = builder_for(self.settings, self._t_s)
        aligner = ReferenceAligner(self._t_s, self._departures.reference_shift_s)
        aligned = aligner.add(raw)
        if aligned.shape[0]:
            builder.add(*self._departures.correct(aligned).T)
        self._aligner = aligner
        windows = builder.windows()
        self._builder = builder
        self._arrivals.restart(windows)
        self._windows = dataclasses.replace(windows, weight=np.ones(windows.size))
        self._since_fit = windows.size
        return True

    def _take(self, new: WindowSet) -> None:
        """Add new windows cluster by cluster: a completed cluster is watched for a change and
        the running estimate updated; the oldest are folded beyond the memory limit."""
        for done, group in self._arrivals.groups(new):
            if done is not None:
                self._cluster_done(done)
            self._append(group)

    def _append(self, new: WindowSet) -> None:
        """New windows of the cluster under way: kept aside until it completes
        (:class:`~odocal.online.arrivals.Arrivals`); with forgetting, into the window set at
        once, the older evidence faded."""
        assert self._windows is not None
        cfg = self.settings.online
        if not cfg.forgetting_s:
            self._arrivals.set_aside(new)
            self._since_fit += new.size
            if self._windows.size + self._arrivals.aside > cfg.max_windows:
                self._flush()
            return
        self._flush()
        windows = self._windows
        if cfg.forgetting_s:
            factor = math.exp(-self.settings.inverse.window_s / cfg.forgetting_s)
            k = new.size
            self._fit.fade(factor**k)
            windows = windows.scaled(factor**k)
            new = dataclasses.replace(new, weight=new.weight * factor ** np.arange(k - 1, -1, -1))
        self._windows = WindowSet.concat([windows, new])
        self._arrivals.counted(new)
        self._since_fit += new.size
        while self._windows.size > cfg.max_windows:
            self._fold()

    def _flush(self) -> None:
        """The windows kept aside into the window set; the oldest folded beyond the memory."""
        assert self._windows is not None
        if self._arrivals.aside:
            self._windows = WindowSet.concat([self._windows, *self._arrivals.take_aside()])
        while self._windows.size > self.settings.online.max_windows:
            self._fold()

    def _cluster_done(self, cluster: int) -> None:
        """A cluster is complete: the change detector compares its own estimate of c_e and c_d
        with the estimate before it (:mod:`odocal.online.changes`), and the running estimate
        takes it in."""
        self._flush()
        assert self._windows is not None
        mine = self._windows.take(self._windows.cluster == cluster)
        self._clusters_done += 1
        offset = self.heading_offset()
        if mine.size >= 3 and self._clusters_done > self.settings.online.warmup_clusters:
            suspect = self._changes.watch(mine, self._fit.p, self._fit.lag.shift, offset,
                                          self._fit.model)
            if suspect is not None and self._changed(suspect, mine):
                return
        # a running update from a warm start (estimate() solves to convergence), so that the
        # change detector and the folding work with current ones (a solve that failed moves
        # nothing; estimate() says)
        self._fit.update(self._fitted(), offset, self._checks.checked, smooth=self._smooth,
                         scan_lag_now=self._clusters_done % _LAG_EVERY == 0)

    def _changed(self, suspect: Suspect, cluster: WindowSet) -> bool:
        """A suspected change: where it began and how large (an alarm), and the estimate
        restarted from it; False where the windows cannot tell yet."""
        assert self._windows is not None and self._t_s is not None
        windows, folded, p, lag = self._windows, self._fit.folded, self._fit.p, self._fit.lag

        def found(drift: bool) -> Change | Drift | None:
            return estimate_change(windows, folded, suspect, p=p, lag=lag,
                                   heading_offset=self.heading_offset(), model=self._fit.model,
                                   smooth=self._smooth, drift=drift,
                                   tolerance=self.settings.inverse.tolerance)

        change = found(drift=not folded.clusters)
        if isinstance(change, Drift):
            # the wheels drift (tyres warming): where the core, choosing its departures
            # afresh on the windows now, takes the drift in (as batch does), no step restarts
            # the estimate from a level the drift leaves; where it does not, a step follows it
            if "drift" in self._refit().entered:
                self._changes.reset()
                return False
            change = found(drift=False)
        if not isinstance(change, Change):
            return False
        alarm = describe(change, suspect, detected_t=float(cluster.t0[-1]),
                         detected_distance_km=float(cluster.distance_m[-1]) / 1000.0)
        if not abs(alarm.sigmas) >= CONFIRM_SIGMAS:
            # the windows after the change point, refitted, do not show it: an excursion of
            # the clusters' estimates, not a change of the wheels
            self._changes.reset()
            return False
        self._alarms.append(alarm)
        if self._front is not None:
            self._front.forget_before(alarm.t)
            self._front_fit = None
        self._restart(change)
        return True

    def _restart(self, change: Change) -> None:
        """After a change of the wheels: the windows before it are folded at the estimate from
        before it, and what the folded evidence says about c_e and c_d is taken out (it keeps
        what it says about t_r, d and the lag); the estimate goes on from the new wheels."""
        assert self._windows is not None
        p = change.before
        before = np.arange(self._windows.size) < change.index
        self._fold_windows(before, p)
        self._fit.restart_wheels(change.step)
        kept = self._windows
        follows = kept.follows.copy()
        follows[:1] = False                          # no filtering across the change
        self._windows = dataclasses.replace(kept, follows=follows)
        after = change.before.copy()
        after[list(WHEELS)] += change.step            # (c_e and c_d)
        after[fitting.DRIFT] = 0.0                    # (folded sums hold no drift)
        self._fit.take(after)
        self._clusters_done = 0                      # a new warm-up before watching again
        self._changes.reset()
        self._since_fit = self._windows.size

    def _fold_windows(self, mask: BoolArray, p: FloatArray) -> None:
        """Fold the windows at ``mask`` (the oldest in memory), cluster by cluster, linearised
        at ``p``; they leave memory."""
        assert self._windows is not None
        self._windows = self._fit.fold(self._windows, mask, p, self.heading_offset(),
                                       self._checks.checked, smooth=self._smooth)

    def _fitted(self) -> WindowSet:
        """The windows in memory the fit takes (:meth:`RunningFit.fitted`)."""
        assert self._windows is not None
        return self._fit.fitted(self._windows, self.heading_offset())

    def _solve(self, windows: WindowSet, *, max_iterations: int) -> fitting.Fit:
        return self._fit.solve(windows, self.heading_offset(), self._checks.checked,
                               max_iterations=max_iterations)

    @property
    def _smooth(self) -> bool:
        return self.settings.inverse.delay == "estimate" and bool(
            self._windows is not None and self._windows.shifts > 0)

    def _fold(self) -> None:
        """Fold the oldest complete cluster into the sums, linearised at the estimate now (the
        core run first where it has not run for a quarter of the memory)."""
        assert self._windows is not None
        if self._since_fit > self.settings.online.max_windows // 4:
            self._refit()
        windows = self._windows
        oldest = windows.cluster == windows.cluster[0]
        if oldest.all():
            oldest = np.arange(windows.size) < windows.size // 2   # (one huge cluster: half)
        self._fold_windows(oldest, self._fit.p)

    def _refit(self, windows: WindowSet | None = None) -> core.CoreFit:
        """The core on everything so far (``windows``: those the fit takes, :meth:`_fitted`;
        with what the checks hold back, as batch); the running estimate, error model and lag
        follow it."""
        assert self._windows is not None
        found = self._fit.refit(self._fitted() if windows is None else windows,
                                self.heading_offset(), self._checks.checked)
        self._since_fit = 0
        return found

    # ---------------------------------------------------------------- output

    def estimate(self, *, running: bool = False) -> Estimate:
        """The estimate now: theta, covariance, verdicts, status (as the batch methods give).

        The latest samples are checked first (as every path checks its data); where they
        contradict the model, or the estimate fails the quality gate, the status is
        ``REJECTED`` and the findings are in ``details.findings``. The four-wheel car's is its
        rear axle's with the front axle and the steering fitted on the front windows kept
        (:mod:`odocal.online.front`) and joined, as batch joins them.

        ``running``: an update of a running trace (``odocal replay``'s): the front axle is
        fitted again only where the driving it rests on grew by
        :data:`~odocal.online.front.REFIT_GROWTH` since its last fit (each fit costs all the
        windows kept: fitted at every update, a replay's time would grow with the square of
        its length); in between, its last fit is joined with the rear axle of now.
        """
        rear = self._rear_estimate(running=running)
        return rear if self.car_settings is None else self._car(rear, running=running)

    def _car(self, rear: Estimate, *, running: bool) -> Estimate:
        """The four-wheel estimate of the rear axle's ``rear``, and what its fit shows of the
        wheels' mapping (fatal: refused, as batch refuses it)."""
        assert self.car_settings is not None
        fit, kept_s = self._front_fit, self._front.kept_s if self._front is not None else 0.0
        if self._front is not None and rear.success and (
                not running or fit is None or kept_s >= REFIT_GROWTH * self._front_fit_s):
            windows = self._front.windows(self._alignment(rear))
            fit = None if windows is None else fit_car_front(rear, windows, self.car_settings)
            self._front_fit, self._front_fit_s = fit, kept_s
        car = car_estimate(rear, None, self.car_settings, front=fit)
        found = mapping_findings(car, self._checks.checked,
                                 max_difference=self.car_settings.gate.max_abs_c_d_fraction)
        if self._front is not None and rear.success and not self._front.measured:
            found = (*found, Finding(
                Check.INVALID_INPUT, Severity.FALLBACK,
                name=f"{self.source} holds no sample with both front wheels' rates measured "
                     "(n_fl, n_fr NaN throughout): the front axle and the steering are not "
                     "calibrated; check the front wheel columns"))
        fault = self._front.steering_fault if self._front is not None else None
        if fault is not None and not any(
                f.check is Check.STEERING and f.name.split("|")[0] == fault.name.split("|")[0]
                for f in rear.details.findings):
            found = (*found, fault)       # (left out of every block, found on an earlier one)
        details = dataclasses.replace(
            rear.details, front=getattr(car.details, "front", None),
            front_kept_s=self._front.kept_s if self._front is not None else 0.0,
            findings=(*rear.details.findings, *found))
        # the wheels' mapping contradicts the model (the car's fit, or steered wheels in the
        # rear axle's columns, which a car's four columns can only be by a wrong mapping):
        # halted, as the checks halt it, never an estimate published before it was seen. The
        # rear fit's judgement of steered wheels halts at a final estimate only (judged there
        # as batch judges it): a running fit, on folded sums and without the windows where a
        # wheel turns far from its estimate, read a simulated reference's second-order motion
        # as wheels 2 m ahead (an hour at 40 Hz, while it still kept departures from earlier
        # estimates; a running estimate that names them is refused, as the rear axle's is)
        mapping = [f for f in details.findings if f.severity is Severity.FATAL and (
            f in found or (f.check is Check.FRONT_WHEELS and not running))]
        fatal = any(f.severity is Severity.FATAL for f in found)
        if mapping:
            self._checks.found(self._checks.checked.plus(mapping))
        return dataclasses.replace(car, details=details,
                                   status=Status.REJECTED if fatal else car.status)

    def _alignment(self, rear: Estimate | None = None) -> Alignment:
        """What the front windows are made with now: the rear fit's lag, heading offset, the
        departures taken out of the samples and those ``rear`` (the rear axle's estimate now;
        None: the last one's) fitted beside theta (the lag is in the delay)."""
        if rear is not None:
            self._rear_fitted = Fitted.of(getattr(rear.details, "departures", ()),
                                          rear.theta.as_array())
        return Alignment(self.delay_s(), self.heading_offset(), self._departures,
                         self._rear_fitted)

    def _rear_estimate(self, *, running: bool = True) -> Estimate:
        """The rear axle's estimate now (:meth:`estimate`)."""
        if self._checks.unchecked:
            self._check()
        if self._checks.halted:
            return self._nothing(Reason.REJECTED, Status.REJECTED)
        if self._windows is not None:
            self._flush()
        if self._checks.checked.standstill and self._fit.folded.clusters == 0 and (
                self._windows is None or self._windows.size == 0):
            return self._nothing(Reason.STANDSTILL)
        if self._windows is None or self._windows.size + self._fit.folded.clusters == 0:
            return self._nothing(Reason.NO_INFORMATION)
        windows = self._fitted()
        try:
            found = self._refit(windows)
        except (np.linalg.LinAlgError, FloatingPointError) as exc:
            self._checks.failed(exc)
            return self._nothing(Reason.REJECTED, Status.REJECTED)
        free = found.free
        theta = found.theta.copy()
        theta[~free] = self.datasheet[~free]
        std = np.sqrt(np.clip(np.diag(found.covariance), 0.0, None))
        status = Status.CONVERGED if free.any() else Status.NOTHING_IDENTIFIABLE
        refused = gate(theta, self.settings, error_m=None, datasheet_error_m=None,
                       segment_m=None)
        if refused:
            status = Status.REJECTED
        total = found.fit.p.copy()
        total[fitting.LAG] = found.lag.shift if "lag" in found.entered else 0.0
        named = fitted.findings(total, found.nuisance_std, found.entered,
                                t_s=self._t_s or 0.0,
                                reference_shift_s=self._departures.reference_shift_s,
                                heading_own=self._fit.setup(windows, self._checks.checked).across,
                                rivals=found.rivals)
        if not running:
            named = self._front_wheels_afresh(named)
        if self._front_seen_ahead:
            named = fitted.as_excess(named)
        if any(f.severity is Severity.FATAL for f in named):
            status = Status.REJECTED
        departed = tuple((name, float(total[fitted.at(name)]),
                          float(found.nuisance_std[fitted.at(name)])) for name in found.entered)
        return Estimate(method="online", theta=Parameters.from_array(theta),
                        datasheet=Parameters.from_array(self.datasheet),
                        covariance=found.covariance, covariance_kind=CovarianceKind.RECURSIVE,
                        free=tuple(bool(f) for f in free),
                        verdicts=judge(std, free, self.settings.identify, held=found.held),
                        status=status,
                        details=dataclasses.replace(
                            self._details(found.clusters, [*named, *refused]),
                            departures=departed),
                        widening=found.uncertainty.widening)

    def _front_wheels_afresh(self, named: Sequence[Finding]) -> list[Finding]:
        """``named`` (the running fit's findings) with front wheels mapped as the rear ones
        judged as batch judges them: on every window in memory (the running fit leaves out
        windows where a wheel turns far from its estimate: the tight bends left out blur the
        wheels' excess in bends that names front wheels). That judgement replaces the running
        fit's; where something is folded already (the windows are not all in memory), the
        running fit's stands."""
        windows = self._windows
        if windows is None or not windows.size or self._fit.folded.clusters:
            return list(named)
        checked = self._checks.checked
        setup = self._fit.setup(windows, checked)
        try:
            found = core.fit(windows, self._fit.folded, self.settings,
                             heading_offset=self.heading_offset(), held=held_by_checks(checked),
                             distance_only=checked.no_differential, setup=setup)
        except (np.linalg.LinAlgError, FloatingPointError):
            return list(named)
        total = found.fit.p.copy()
        total[fitting.LAG] = found.lag.shift if "lag" in found.entered else 0.0
        steered = [f for f in fitted.findings(
                       total, found.nuisance_std, found.entered, t_s=self._t_s or 0.0,
                       reference_shift_s=self._departures.reference_shift_s,
                       heading_own=setup.across, rivals=found.rivals)
                   if f.check is Check.FRONT_WHEELS and f.severity is Severity.FATAL]
        return [f for f in named if not (f.check is Check.FRONT_WHEELS
                                         and f.severity is Severity.FATAL)] + steered

    @property
    def theta(self) -> FloatArray:
        """The running estimate of theta."""
        return self._fit.theta

    @property
    def diagnosis(self) -> Diagnosis:
        """What the checks found on the latest samples (and why the numbers could not be
        fitted, where they could not)."""
        return self._checks.diagnosis

    @property
    def halted(self) -> bool:
        """Whether the data contradicted the model and the calibrator stopped updating."""
        return self._checks.halted

    def delay_s(self) -> float:
        """The wheel stream's lag behind the reference that is applied (positive: late), s:
        the reference's alignment and the fit's fine lag together."""
        return self._fit.lag.shift * (self._t_s or 0.0) + self._departures.reference_shift_s

    def heading_offset(self) -> float:
        """The reference heading's rotation against the direction of travel (rad), found on the
        straight stretches as batch finds it."""
        if self._builder is None or self.settings.inverse.heading_offset != "estimate":
            return 0.0
        return heading_offset(self._builder.straight_so_far())

    def _details(self, clusters: int, more: Sequence[Finding] = ()) -> OnlineDetails:
        noise = self._fit.model.noise
        return OnlineDetails(
            samples=self._intake.samples, windows=self._arrivals.total,
            windows_in_memory=(0 if self._windows is None
                               else self._windows.size + self._arrivals.aside),
            clusters=clusters, distance_km=self.distance_km, delay_s=self.delay_s(),
            heading_offset_rad=self.heading_offset(),
            noise=((float(noise[0, 0]), float(noise[0, 1])),
                   (float(noise[1, 0]), float(noise[1, 1]))),
            alarms=tuple(self._alarms), forgetting_s=self.settings.online.forgetting_s,
            coupling=float(self._fit.model.coupling),
            findings=(*self.diagnosis.findings, *more),
            halted=self._checks.halted,
            time_unit=self._intake.unit or "s",
            sampling_s=self._t_s if self._t_s is not None else float("nan"))

    def _nothing(self, reason: Reason,
                 status: Status = Status.NOTHING_IDENTIFIABLE) -> Estimate:
        theta = Parameters.from_array(self.datasheet)
        held = {n: NotIdentified(reason) for n in PARAMETER_NAMES}
        return Estimate(method="online", theta=theta, datasheet=theta,
                        covariance=np.zeros((PARAMETERS, PARAMETERS)),
                        covariance_kind=CovarianceKind.NONE, free=(False,) * PARAMETERS,
                        verdicts=judge(np.zeros(PARAMETERS), np.zeros(PARAMETERS, dtype=bool),
                                       self.settings.identify, held=held),
                        status=status, details=self._details(0))

    def details_samples(self) -> int:
        """Samples pushed so far."""
        return self._intake.samples

    @property
    def span_s(self) -> tuple[float, float] | None:
        """The first and the latest sample's time on the log's clock, in seconds (whatever the
        unit ``t`` is pushed in), or None before the unit is known."""
        if self._intake.first_t is None or self._intake.last_t is None:
            return None
        return self._intake.first_t, self._intake.last_t

    @property
    def alarms(self) -> tuple[Alarm, ...]:
        return tuple(self._alarms)

    @property
    def distance_km(self) -> float:
        return 0.0 if self._builder is None else self._builder.distance_m / 1000.0



    def __repr__(self) -> str:
        """What it has taken in, and the running parameters beside the datasheet values (the
        table a replay prints; :meth:`estimate` gives their uncertainty and verdicts)."""
        from odocal.estimators.estimate import parameter_text

        windows = 0 if self._windows is None else self._windows.size
        state = ("halted: the data contradict the model (estimate().details.findings)"
                 if self._checks.halted else f"{len(self._alarms)} alarm(s)")
        lines = [f"OnlineCalibrator({self._intake.samples} samples, {self.distance_km:.2f} km, "
                 f"{windows} windows in memory, {self._fit.folded.clusters} clusters folded, "
                 f"{state})",
                 f"{'parameter':<10} {'datasheet':>16} {'running':>16}"]
        for name, sheet, now in zip(PARAMETER_NAMES, self.datasheet, self._fit.theta, strict=True):
            lines.append(f"{name:<10} {parameter_text(name, float(sheet)):>16} "
                         f"{parameter_text(name, float(now)):>16}")
        return "\n".join(lines)


def _car_settings(settings: Settings) -> Settings | None:
    """The four-wheel car's settings where they choose it (None: the rear axle's model); a
    one-line ConfigError for a model the live path does not take, or a car whose evidence
    would fade (``[online] forgetting_s``: the front fit keeps its windows, it does not fade
    them)."""
    model = settings.vehicle.model
    if model == registry.DEFAULT:
        return None
    if model != FOUR_WHEEL_MODEL.name:
        registry.require_rear_axle(model, "the live calibration")
    if settings.online.forgetting_s:
        raise ConfigError(f"the live calibration of the {model} model does not fade its "
                          "evidence: set [online] forgetting_s = 0 (or calibrate the rear "
                          "axle: [vehicle] model = \"rear_axle\")")
    return settings


def _require_front_wheels(chunk: Any) -> None:
    """A one-line DataError where pushed samples of the four-wheel car lack the front wheels'
    rates."""
    missing = [k for k in ("n_fl", "n_fr") if not has_column(chunk, k)]
    if missing:
        raise DataError(f"the four_wheel model needs the front wheels' rates (n_fl, n_fr), and "
                        f"the pushed samples lack {', '.join(missing)}: map them ([wheels] "
                        "front_left/front_right, or the table's columns), or calibrate the "
                        "rear axle ([vehicle] model = \"rear_axle\")")


class Updates:
    """When the running estimate is taken (one rule for ``odocal replay`` and the ROS 2
    node): every ``update_s`` of data on the log's clock, the first ``update_s`` after the
    first sample."""

    def __init__(self, update_s: float) -> None:
        self._every = update_s
        self._next: float | None = None

    def due(self, span: tuple[float, float] | None) -> bool:
        """Whether an estimate is due now that the samples pushed span ``span`` (the
        calibrator's :attr:`~OnlineCalibrator.span_s`); if so, the next is ``update_s`` on."""
        if span is None:
            return False
        first, last = span
        if self._next is None:
            self._next = first + self._every
        if last < self._next:
            return False
        self._next = last + self._every
        return True
