"""The online calibrator's running estimate: p (theta and the departures the core took in), the
error model and the lag of now, and the evidence folded into sums; solved from a warm start
after every cluster, refitted by the core, and folding the oldest windows."""

from __future__ import annotations

import dataclasses

import numpy as np

from odocal.arrays import BoolArray, FloatArray
from odocal.checks.findings import Diagnosis
from odocal.estimators import core, fitting
from odocal.estimators import departures as fitted
from odocal.estimators.base import held_by_checks
from odocal.estimators.error_model import ErrorModel
from odocal.estimators.inverse import fit_setup
from odocal.estimators.lag import Lag, choose_lag, scan_lag
from odocal.estimators.windows import WindowSet
from odocal.model.vehicle import MODEL
from odocal.online.changes import disturbed, eliminate
from odocal.online.departures import with_offset_prior
from odocal.settings import Settings

#: Running updates after which the estimate is trusted to tell a disturbed window.
SETTLED = 3


class RunningFit:
    """The running estimate from ``start`` (theta), the datasheet values ``datasheet``.

    ``theta`` and the departures fitted beside it (p after theta:
    :mod:`odocal.estimators.departures`), the departures the core last took in (``entered``),
    the error ``model`` and ``lag`` of now, the ``folded`` sums and how many running ``updates``
    it has made. The windows, the reference heading's offset and what the checks found are the
    calibrator's: they are handed in.
    """

    def __init__(self, settings: Settings, datasheet: FloatArray, start: FloatArray) -> None:
        self.settings = settings
        self.datasheet = datasheet
        self.theta = start.copy()
        self.nuisance = np.zeros(fitting.P - MODEL.size)
        self.entered: tuple[str, ...] = ()
        self.model = ErrorModel()
        self.lag = Lag()
        # (the wheel-rate offset's prior from the start where the settings always fit it; for
        # rates on an encoding's grid from the first check that finds the grid)
        self.folded = fitting.Folded.prior(fitting.pack(datasheet),
                                           core.offset_prior_std(settings, 0.0))
        self.updates = 0

    def fade(self, factor: float) -> None:
        """The folded evidence faded by ``factor`` (forgetting)."""
        self.folded = self.folded.decayed(factor)

    def encoded(self, step_revps: float) -> None:
        """The wheel rates lie on a grid of ``step_revps``: the wheel-rate offset gets its
        prior (:func:`~odocal.online.departures.with_offset_prior`)."""
        self.folded = with_offset_prior(self.folded, self.settings, step_revps)

    def restart_wheels(self, step: FloatArray) -> None:
        """After a change of the wheels by ``step`` (c_e, c_d): what the folded evidence says
        about them is taken out (:func:`~odocal.online.changes.eliminate`)."""
        self.folded = eliminate(self.folded, step)

    @property
    def p(self) -> FloatArray:
        """The running estimate as the core's p (theta and the departures fitted)."""
        return np.concatenate([self.theta, self.nuisance])

    def take(self, p: FloatArray) -> None:
        """``p`` becomes the running estimate."""
        self.theta = np.asarray(p[fitting.THETA], dtype=np.float64).copy()
        self.nuisance = np.asarray(p[MODEL.size:], dtype=np.float64).copy()

    def free(self) -> BoolArray:
        """The elements of p the running fit takes: theta, the offset where it has a prior, and
        the departures the core last took in (the wheels' smoothing among them only where it
        held out, as in batch: freed always, it took up what the common slip's coupling is)."""
        return fitting.free_of(np.ones(self.theta.size, dtype=bool),
                               offset=self.folded.offset_free,
                               entered=[n for n in self.entered if n != "lag"])

    def setup(self, windows: WindowSet, diagnosis: Diagnosis) -> core.Setup:
        """What the live fit may take beside theta (:func:`~odocal.estimators.inverse.
        fit_setup`, the live departures: a change it detects itself). A drift of c_e is fitted
        as batch fits it while every window is in memory (the estimate is c_e now); once
        windows are folded their sums hold no drift, and a drift is what the change detector
        and forgetting follow."""
        blocks = fitted.LIVE if self.folded.clusters else (*fitted.LIVE, ("drift",))
        setup = fit_setup(windows, self.settings, held_by_checks(diagnosis), blocks=blocks)
        return dataclasses.replace(setup, coupled=bool(self.model.coupling))

    def kept(self, windows: WindowSet, heading_offset: float,
             p: FloatArray | None = None) -> BoolArray:
        """Which of ``windows`` the fit takes: all but those a disturbance spoils (a wheel
        more than a tenth away from the running estimate, or ``p``: slip, a skid, reversing
        with unsigned wheel speeds; :func:`~odocal.online.changes.disturbed`), once the
        running estimate has settled (:data:`SETTLED` updates)."""
        if self.updates < SETTLED or not windows.size:
            return np.ones(windows.size, dtype=bool)
        return ~disturbed(windows, self.p if p is None else p, self.lag.shift, heading_offset)

    def fitted(self, windows: WindowSet, heading_offset: float, p: FloatArray | None = None,
               keep: BoolArray | None = None) -> WindowSet:
        """The windows the fit takes (:meth:`kept`), each following the one before it only
        where that one is taken too."""
        keep = self.kept(windows, heading_offset, p) if keep is None else keep
        if keep.all():
            return windows
        follows = windows.follows & np.concatenate([[True], keep[:-1]])
        return dataclasses.replace(windows, follows=follows).take(keep)

    def solve(self, windows: WindowSet, heading_offset: float, diagnosis: Diagnosis, *,
              max_iterations: int) -> fitting.Fit:
        """Gauss-Newton over ``windows`` and the folded sums with the error model and lag of
        now, and the datasheet values with their uncertainty (``[identify] prior_std``) as a
        prior: the running estimate (the change detector's reference, where windows are
        folded) stays near them in what the windows do not determine yet (t_r and d before
        the first bends), and the data decide the rest (the estimate published is the core's,
        from the datasheet values, without the prior)."""
        setup = self.setup(windows, diagnosis)
        view = fitting.View.of(windows, self.lag.shift, heading_offset, tau_h=setup.tau_h,
                               across=setup.across, lateral=setup.lateral)
        with np.errstate(divide="ignore", over="ignore"):
            prior = 1.0 / np.square(np.asarray(self.settings.identify.prior_std, dtype=float))
        prior = np.where(np.isfinite(prior), prior, 0.0)
        h, b = self.folded.h.copy(), self.folded.b.copy()
        h[fitting.THETA, fitting.THETA] += np.diag(prior)
        b[fitting.THETA] += prior * self.datasheet
        return fitting.solve(self.p, view, self.free(), self.model,
                             dataclasses.replace(self.folded, h=h, b=b), np.ones(2),
                             max_iterations=max_iterations,
                             tolerance=self.settings.inverse.tolerance)

    def update(self, windows: WindowSet, heading_offset: float, diagnosis: Diagnosis, *,
               smooth: bool, scan_lag_now: bool) -> bool:
        """A running update from a warm start over ``windows`` (those the fit takes): theta,
        the error model, and where ``scan_lag_now`` the lag, so that the change detector and
        the folding work with current ones. Whether it moved (a solve that failed moves
        nothing)."""
        current = self.solve(windows, heading_offset, diagnosis, max_iterations=3)
        if not np.all(np.isfinite(current.p)):
            return False
        self.take(current.p)
        self.updates += 1
        coupling = self.settings.inverse.common_wheel_error == "estimate"
        self.model = core.refit_model(current, windows, self.folded, coupling=coupling,
                                      kept=bool(self.model.coupling))
        if smooth and "lag" in self.entered and scan_lag_now:
            self.lag = choose_lag(scan_lag(windows, self.p, heading_offset, self.model,
                                           self.folded))
        return True

    def refit(self, windows: WindowSet, heading_offset: float,
              diagnosis: Diagnosis) -> core.CoreFit:
        """The core on ``windows`` (those the fit takes) and the folded sums, with what the
        checks hold back, as batch; the running estimate, error model and lag follow it."""
        found = core.fit(windows, self.folded, self.settings, heading_offset=heading_offset,
                         held=held_by_checks(diagnosis),
                         distance_only=diagnosis.no_differential,
                         setup=self.setup(windows, diagnosis))
        if found.free.any():
            p = found.fit.p.copy()
            p[fitting.LAG] = 0.0                      # (the lag is the view's shift)
            self.take(p)
        self.model, self.lag, self.entered = found.model, found.lag, found.entered
        return found

    def fold(self, windows: WindowSet, mask: BoolArray, p: FloatArray, heading_offset: float,
             diagnosis: Diagnosis, *, smooth: bool) -> WindowSet:
        """Fold the windows at ``mask`` (the oldest in memory), cluster by cluster, linearised
        at ``p``; the windows left in memory."""
        if not mask.any():
            return windows
        kept = self.kept(windows, heading_offset, p)
        view = fitting.View.of(self.fitted(windows, heading_offset, p, kept), self.lag.shift,
                               heading_offset)
        total, _ = fitting.evaluate(p, view, self.model, self.folded, np.ones(2),
                                    smooth=smooth).normal_equations(self.folded)
        # (what a disturbance spoiled is not folded: it leaves memory unused)
        folding = mask & kept
        labels = windows.cluster[folding]
        index = np.flatnonzero(folding)
        for group in np.split(index, np.flatnonzero(np.diff(labels)) + 1):
            if not group.size:
                continue
            part = windows.take(group)
            empty = fitting.Folded(origin=self.folded.origin)
            scan = (scan_lag(part, p, heading_offset, self.model, empty)
                    if windows.shifts > 0 else None)
            self.folded = core.fold(self.folded, part, p, self.lag.shift, heading_offset,
                                    self.model, smooth=smooth, total_h=total, scan=scan,
                                    free=self.free(), setup=self.setup(part, diagnosis))
        return windows.take(~mask)
