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
from numpy.typing import NDArray

from odocal.checks.diagnosis import check_drives
from odocal.checks.findings import Check, Diagnosis, Finding, Severity
from odocal.checks.gate import gate
from odocal.data.drive import Drive
from odocal.errors import DataError
from odocal.estimators import core
from odocal.estimators.base import held_by_checks
from odocal.estimators.error_model import ErrorModel
from odocal.estimators.estimate import (
    CovarianceKind,
    Estimate,
    NotIdentified,
    Reason,
    Status,
    judge,
)
from odocal.estimators.windows import (
    WindowBuilder,
    WindowSet,
    builder_for,
    empty_windows,
    heading_offset,
)
from odocal.model.parameters import PARAMETER_NAMES, PARAMETERS, Parameters
from odocal.online.changes import Alarm, ChangeDetector
from odocal.settings import Settings

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

_COLUMNS = ("t", "n_rl", "n_rr", "a_y", "x", "y", "psi")
_SAMPLE = ("t", "n_rl", "n_rr", "a_y", "beta", "x", "y", "psi")
#: Wheel rates beyond this (rev/s) in a pushed chunk are in another unit, whatever else.
_MAX_PUSHED_RATE_REVPS = 100.0
#: The checks look at this much of the latest driving (s) ...
CHECK_WINDOW_S = 600.0
#: ... every time this much more has arrived (s), and before every estimate.
CHECK_EVERY_S = 60.0
#: The running update scans the lag every this many completed clusters.
_LAG_EVERY = 4


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
                "diagnosis": [f.to_dict() for f in self.findings], "halted": self.halted}


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
                 theta0: Parameters | FloatArray | None = None) -> None:
        self.settings = settings or Settings()
        start = (np.asarray(self.settings.identify.theta0, dtype=np.float64) if theta0 is None
                 else (theta0.as_array() if isinstance(theta0, Parameters)
                       else np.asarray(theta0, dtype=np.float64)))
        if start.shape != (4,) or not np.all(np.isfinite(start)) or start[0] <= 0 \
                or start[2] <= 0:
            raise DataError(f"theta0 {start.tolist()} is not a usable starting estimate")
        self.datasheet = np.asarray(self.settings.identify.theta0, dtype=np.float64)
        self.theta = start.copy()
        self._kappa = 0.0
        self._model = ErrorModel()
        self._lag = core.Lag()
        self._t_s: float | None = None
        self._pending: dict[str, float] | None = None  # a lone first sample, until t_s is known
        self._last_t: float | None = None
        self._builder: WindowBuilder | None = None
        self._windows: WindowSet | None = None
        self._folded = core.Folded(origin=core.pack(self.datasheet))
        self._samples = 0
        self._windows_total = 0
        self._since_fit = 0                       # windows added since the core last ran
        self._alarms: list[Alarm] = []
        self._clusters_done = 0
        self._current_cluster: int | None = None
        cfg = self.settings.online
        self._changes = ChangeDetector(k=cfg.cusum_k, h=cfg.cusum_h)
        # the checks: the latest samples as they came, what they found, and whether they halted
        self._recent: list[FloatArray] = []
        self._checked_t = -math.inf
        self._diagnosis = Diagnosis(())
        self._halted = False

    # ---------------------------------------------------------------- input

    def push(self, chunk: Mapping[str, Any] | Any) -> None:
        """Add samples: a mapping of drive-format column names to arrays, or a pandas DataFrame.

        Columns ``t, n_rl, n_rr, a_y, x, y, psi`` are required, ``beta`` is optional; ``t`` must
        increase. A gap longer than 1.5 sampling steps ends the current piece (windows never
        span a gap).
        """
        cols = _columns(chunk)
        t = cols["t"]
        if t.size == 0:
            return
        if np.any(np.diff(t) <= 0) or (self._last_t is not None and t[0] <= self._last_t):
            raise DataError("pushed samples' t must increase strictly (and continue the "
                            "previous chunk)")
        self._samples += t.size
        self._keep_recent(cols)
        if self._halted:
            return                       # the data contradicted the model: nothing more is used
        if self._t_s is None:
            if self._pending is not None:
                cols = {k: np.concatenate([[self._pending[k]], v]) for k, v in cols.items()}
            if cols["t"].size < 2:                       # one sample so far: wait for more
                self._pending = {k: float(v[0]) for k, v in cols.items()}
                self._last_t = float(cols["t"][-1])
                return
            self._pending = None
            self._t_s = float(np.median(np.diff(cols["t"])))
            self._builder = builder_for(self.settings, self._t_s)
            self._windows = empty_windows(length=self._builder.length,
                                          margin=self._builder.margin, t_s=self._t_s)
        assert self._builder is not None
        self._last_t = float(cols["t"][-1])
        self._builder.add(cols["t"], cols["n_rl"], cols["n_rr"], cols["a_y"], cols["beta"],
                          cols["x"], cols["y"], cols["psi"])
        self._take(self._builder.windows())
        if self._last_t - self._checked_t >= CHECK_EVERY_S:
            self._check()

    def _keep_recent(self, cols: Mapping[str, FloatArray]) -> None:
        """The latest samples, as pushed, for the checks (the last CHECK_WINDOW_S)."""
        self._recent.append(np.column_stack([cols[k] for k in _SAMPLE]))
        newest = float(self._recent[-1][-1, 0])
        while len(self._recent) > 1 and float(self._recent[1][0, 0]) <= newest - CHECK_WINDOW_S:
            self._recent.pop(0)

    def _check(self) -> Diagnosis:
        """The checks every path goes through, on the latest samples; a contradiction halts
        the calibrator (it publishes the finding instead of an estimate from then on)."""
        samples = np.vstack(self._recent) if self._recent else np.zeros((0, len(_SAMPLE)))
        samples = samples[samples[:, 0] > samples[-1, 0] - CHECK_WINDOW_S] if samples.size \
            else samples
        self._checked_t = float(samples[-1, 0]) if samples.size else self._checked_t
        if samples.shape[0] < 3:
            return self._diagnosis
        step = self._t_s or float(np.median(np.diff(samples[:, 0])))
        piece = np.cumsum(np.concatenate([[0], np.diff(samples[:, 0]) > 1.5 * step]))
        columns = {k: samples[:, i] for i, k in enumerate(_SAMPLE)} | {"piece": piece}
        try:
            drive = Drive.from_columns(columns, name="live samples")
        except DataError as exc:
            diagnosis = Diagnosis((Finding(Check.INVALID_INPUT, Severity.FATAL,
                                           name=str(exc)),))
        else:
            diagnosis = check_drives([drive], self.settings)
        self._diagnosis = diagnosis
        if diagnosis.fatal:
            self._halted = True
        return diagnosis

    def _take(self, new: WindowSet) -> None:
        """Add new windows cluster by cluster: a completed cluster is watched for a change and
        the running estimate updated; the oldest are folded beyond the memory limit."""
        if not new.size:
            return
        labels = new.cluster
        bounds = np.flatnonzero(np.diff(labels)) + 1
        for group in np.split(np.arange(new.size), bounds):
            cluster = int(labels[group[0]])
            if self._current_cluster is not None and cluster != self._current_cluster:
                self._cluster_done(self._current_cluster)
            self._current_cluster = cluster
            self._append(new.take(group))

    def _append(self, new: WindowSet) -> None:
        assert self._windows is not None
        cfg = self.settings.online
        windows = self._windows
        if cfg.forgetting_s:
            factor = math.exp(-self.settings.inverse.window_s / cfg.forgetting_s)
            k = new.size
            self._folded = self._folded.decayed(factor**k)
            windows = windows.scaled(factor**k)
            new = dataclasses.replace(new, weight=new.weight * factor ** np.arange(k - 1, -1, -1))
        self._windows = WindowSet.concat([windows, new])
        self._windows_total += new.size
        self._since_fit += new.size
        while self._windows.size > cfg.max_windows:
            self._fold()

    def _cluster_done(self, cluster: int) -> None:
        """A cluster is complete: the CUSUM compares its own estimate of c_e and c_d with the
        estimate from the clusters before it, which then takes it in."""
        assert self._windows is not None
        mine = self._windows.take(self._windows.cluster == cluster)
        self._clusters_done += 1
        offset = self.heading_offset()
        if mine.size >= 3 and self._clusters_done > self.settings.online.warmup_clusters:
            found = self._changes.watch(mine, self.theta, self._lag.shift, offset, self._model)
            if found is not None:
                alarm, index, change = found
                self._alarms.append(alarm)
                self._restart(index, change, alarm.t)
                return
        # a running update from a warm start (estimate() solves to convergence): theta, the
        # error model, and every few clusters the lag, so that the change detector and the
        # folding work with current ones
        current = self._solve(max_iterations=3)
        self.theta, self._kappa = current.p[core.THETA].copy(), float(current.p[core.KAPPA])
        coupling = self.settings.inverse.common_wheel_error == "estimate"
        self._model = core.refit_model(current, self._windows, self._folded, coupling=coupling)
        if self._smooth and self._clusters_done % _LAG_EVERY == 0:
            self._lag = core.choose_lag(core.scan_lag(self._windows, self.theta, offset,
                                                      self._model, self._folded))

    def _restart(self, index: int, change: float, since_t: float) -> None:
        """After a change: forget the evidence before it, start from the new level."""
        assert self._windows is not None
        self.theta = self.theta.copy()
        self.theta[index] += change
        kept = self._windows.take(self._windows.t0 >= since_t)
        follows = kept.follows.copy()
        follows[:1] = False                              # nothing folded before it any more
        self._windows = dataclasses.replace(kept, follows=follows)
        self._folded = core.Folded(origin=self._folded.origin)
        self._clusters_done = 0                          # a new warm-up before watching again
        self._changes.reset()

    def _solve(self, *, max_iterations: int) -> core.Fit:
        """Gauss-Newton over the windows in memory and the folded sums with the error model and
        lag of now."""
        assert self._windows is not None
        view = core.View.of(self._windows, self._lag.shift, self.heading_offset())
        free = core.free_of(np.ones(self.theta.size, dtype=bool), kappa=self._smooth)
        return core.solve(core.pack(self.theta, self._kappa), view, free, self._model,
                          self._folded, np.ones(2), max_iterations=max_iterations,
                          tolerance=self.settings.inverse.tolerance)

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
        offset = self.heading_offset()
        p = core.pack(self.theta, self._kappa)
        total, _ = core.evaluate(p, core.View.of(windows, self._lag.shift, offset), self._model,
                                 self._folded, np.ones(2),
                                 smooth=self._smooth).normal_equations(self._folded)
        part = windows.take(oldest)
        empty = core.Folded(origin=self._folded.origin)
        scan = (core.scan_lag(part, self.theta, offset, self._model, empty)
                if windows.shifts > 0 else None)
        self._folded = core.fold(self._folded, part, p, self._lag.shift, offset, self._model,
                                 smooth=self._smooth, total_h=total, scan=scan)
        self._windows = windows.take(~oldest)

    def _refit(self) -> core.CoreFit:
        """The core on everything so far (with what the checks hold back, as batch); the
        running estimate, error model and lag follow it."""
        assert self._windows is not None
        found = core.fit(self._windows, self._folded, self.settings,
                         heading_offset=self.heading_offset(),
                         held=held_by_checks(self._diagnosis),
                         distance_only=self._diagnosis.no_differential)
        if found.free.any():
            self.theta = found.theta.copy()
            self._kappa = float(found.fit.p[core.KAPPA])
        self._model, self._lag = found.model, found.lag
        self._since_fit = 0
        return found

    # ---------------------------------------------------------------- output

    def estimate(self) -> Estimate:
        """The estimate now: theta, covariance, verdicts, status (as the batch methods give).

        The latest samples are checked first (as every path checks its data); where they
        contradict the model, or the estimate fails the quality gate, the status is
        ``REJECTED`` and the findings are in ``details.findings``.
        """
        if self._last_t is not None and self._last_t > self._checked_t:
            self._check()
        if self._halted:
            return self._nothing(Reason.REJECTED, Status.REJECTED)
        if self._diagnosis.standstill and self._folded.clusters == 0:
            return self._nothing(Reason.STANDSTILL)
        if self._windows is None or self._windows.size + self._folded.clusters == 0:
            return self._nothing(Reason.NO_INFORMATION)
        found = self._refit()
        free = found.free
        theta = found.theta.copy()
        theta[~free] = self.datasheet[~free]
        std = np.sqrt(np.clip(np.diag(found.covariance), 0.0, None))
        status = Status.CONVERGED if free.any() else Status.NOTHING_IDENTIFIABLE
        refused = gate(theta, self.settings, error_m=None, datasheet_error_m=None,
                       segment_m=None)
        if refused:
            status = Status.REJECTED
        return Estimate(method="online", theta=Parameters.from_array(theta),
                        datasheet=Parameters.from_array(self.datasheet),
                        covariance=found.covariance, covariance_kind=CovarianceKind.RECURSIVE,
                        free=tuple(bool(f) for f in free),
                        verdicts=judge(std, free, self.settings.identify, held=found.held),
                        status=status, details=self._details(found.clusters, refused),
                        widening=found.uncertainty.widening)

    @property
    def diagnosis(self) -> Diagnosis:
        """What the checks found on the latest samples."""
        return self._diagnosis

    @property
    def halted(self) -> bool:
        """Whether the data contradicted the model and the calibrator stopped updating."""
        return self._halted

    def delay_s(self) -> float:
        """The wheel stream's lag behind the reference that is applied (positive: late), s."""
        return self._lag.shift * (self._t_s or 0.0)

    def heading_offset(self) -> float:
        """The reference heading's rotation against the direction of travel (rad), found on the
        straight stretches as batch finds it."""
        if self._builder is None or self.settings.inverse.heading_offset != "estimate":
            return 0.0
        return heading_offset(self._builder.straight_so_far())

    def _details(self, clusters: int, more: Sequence[Finding] = ()) -> OnlineDetails:
        noise = self._model.noise
        return OnlineDetails(
            samples=self._samples, windows=self._windows_total,
            windows_in_memory=0 if self._windows is None else self._windows.size,
            clusters=clusters, distance_km=self.distance_km, delay_s=self.delay_s(),
            heading_offset_rad=self.heading_offset(),
            noise=((float(noise[0, 0]), float(noise[0, 1])),
                   (float(noise[1, 0]), float(noise[1, 1]))),
            alarms=tuple(self._alarms), forgetting_s=self.settings.online.forgetting_s,
            coupling=float(self._model.coupling),
            findings=(*self._diagnosis.findings, *more), halted=self._halted)

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
        return self._samples

    @property
    def alarms(self) -> tuple[Alarm, ...]:
        return tuple(self._alarms)

    @property
    def distance_km(self) -> float:
        return 0.0 if self._builder is None else self._builder.distance_m / 1000.0


def _has(chunk: Any, key: str) -> bool:
    try:
        return key in chunk
    except TypeError:
        return False


def _columns(chunk: Any) -> dict[str, FloatArray]:
    """A pushed chunk's columns as float arrays (``beta`` 0 where absent), or a DataError
    naming what is wrong with it."""
    if not hasattr(chunk, "__getitem__") or isinstance(chunk, str | bytes):
        raise DataError(f"pushed samples must be a mapping of column names to arrays (or a "
                        f"DataFrame), not {type(chunk).__name__}")
    missing = [k for k in _COLUMNS if not _has(chunk, k)]
    if missing:
        raise DataError(f"pushed samples lack column{'s' if len(missing) > 1 else ''} "
                        f"{', '.join(missing)}")
    cols: dict[str, FloatArray] = {}
    for key in (*_COLUMNS, "beta"):
        if key == "beta" and not _has(chunk, key):
            continue
        try:
            cols[key] = np.asarray(chunk[key], dtype=np.float64).ravel()
        except (TypeError, ValueError):
            raise DataError(f"pushed column {key} is not numeric") from None
    n = cols["t"].size
    cols.setdefault("beta", np.zeros(n))
    for key, values in cols.items():
        if values.size != n:
            raise DataError(f"pushed column {key} has {values.size} samples, t has {n}")
        if not np.all(np.isfinite(values)):
            raise DataError(f"pushed column {key} holds NaN or infinite values")
    for key in ("n_rl", "n_rr"):
        if np.any(np.abs(cols[key]) > _MAX_PUSHED_RATE_REVPS):
            raise DataError(f"pushed column {key} reaches {np.max(np.abs(cols[key])):.4g}: "
                            "wheel rates must be in rev/s")
    return cols
