"""The one value every estimator hands on, and the one identifiability verdict.

An :class:`Estimate` is theta with its covariance, which parameters were estimated (``free``),
a verdict per parameter (:class:`Identified` or :class:`NotIdentified` with the reason and the
numbers behind it), a :class:`Status` code with a message table (as scipy's ``least_squares``
reports its status), and typed method-specific details. The batch methods (raw Gauss-Newton, the
three-step method, the default errors-in-variables method), the online
calibrator and the fleet's per-drive tasks all produce it; sentences are made from it only in
:mod:`odocal.report` and :mod:`odocal.cli.main`.

The verdict (:func:`judge`) is the same for every method: a parameter the data determine to a
standard deviation no larger than ``identifiable_ratio`` times its datasheet uncertainty
(``[identify] prior_std``) is identified; one held at its datasheet value keeps the reason it was
held (no bends, no information, the wheels carry no differential signal, ...).
"""

from __future__ import annotations

import enum
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from odocal.arrays import BoolArray, FloatArray
from odocal.model.parameters import PARAMETER_DISPLAY, PARAMETER_NAMES, PARAMETERS, Parameters
from odocal.model.vehicle import MODEL
from odocal.settings import IdentifySettings


class Status(enum.IntEnum):
    """How an estimation ended. Positive: an answer; zero or negative: no usable answer."""

    CONVERGED = 1
    SETTLED = 2
    ITERATION_LIMIT = 3
    EXACT = 4
    NO_IMPROVEMENT = 0
    NOTHING_IDENTIFIABLE = -1
    SOLVER_FAILED = -2
    REJECTED = -3

    @property
    def success(self) -> bool:
        return self.value > 0


#: What each status means, in words (the CLI and the report print these).
STATUS_MESSAGES: Mapping[Status, str] = {
    Status.CONVERGED: "converged: the step fell below the tolerance",
    Status.SETTLED: "converged: the cost no longer decreases",
    Status.ITERATION_LIMIT: "stopped at the iteration limit while the cost still decreased "
                            "slightly",
    Status.EXACT: "the data fit the model exactly (noise-free): the parameters are exact to "
                  "numerical precision",
    Status.NO_IMPROVEMENT: "could not improve on the initial parameters",
    Status.NOTHING_IDENTIFIABLE: "no parameter is identifiable from these drives",
    Status.SOLVER_FAILED: "the solver failed (a factorisation broke down)",
    Status.REJECTED: "rejected by the checks of the data and the quality gate (the errors "
                     "above say which)",
}


class ByName(np.ndarray):
    """A value per parameter, read by order or by name: ``est.std[0] == est.std["c_e"]``.

    An ndarray of shape (n,) in the order c_e, c_d, t_r, d; what is computed from it
    (``std * 2``, a slice) is a plain ndarray.
    """

    names: tuple[str, ...] = PARAMETER_NAMES

    def __new__(cls, values: Any, names: tuple[str, ...] = PARAMETER_NAMES) -> ByName:
        out = np.asarray(values, dtype=np.float64).view(cls)
        if out.shape != (len(names),):
            raise ValueError(f"one value per parameter ({', '.join(names)}), not shape "
                             f"{out.shape}")
        out.names = names
        return out

    def __array_wrap__(self, array: Any, context: Any = None,
                       return_scalar: bool = False) -> Any:
        out = np.asarray(array).view(np.ndarray)
        return out[()] if return_scalar else out

    def __getitem__(self, key: Any) -> Any:
        if isinstance(key, str):
            key = _index(key, self.names)
        out = super().__getitem__(key)
        return out.view(np.ndarray) if isinstance(out, np.ndarray) else out

    def as_dict(self) -> dict[str, float]:
        return dict(zip(self.names, np.asarray(self).tolist(), strict=True))

    def __repr__(self) -> str:
        return "ByName(" + ", ".join(f"{n}={v:.6g}" for n, v in self.as_dict().items()) + ")"


class Flags(tuple[bool, ...]):
    """A yes or no per parameter, read by order or by name: ``est.identified["t_r"]``."""

    names: tuple[str, ...] = PARAMETER_NAMES

    def __new__(cls, values: Any, names: tuple[str, ...] = PARAMETER_NAMES) -> Flags:
        out = super().__new__(cls, (bool(v) for v in values))
        if len(out) != len(names):
            raise ValueError(f"one flag per parameter ({', '.join(names)}), not {len(out)}")
        out.names = names
        return out

    def __getitem__(self, key: Any) -> Any:
        return super().__getitem__(_index(key, self.names) if isinstance(key, str) else key)

    def as_dict(self) -> dict[str, bool]:
        return dict(zip(self.names, self, strict=True))

    def __repr__(self) -> str:
        return "Flags(" + ", ".join(f"{n}={v}" for n, v in self.as_dict().items()) + ")"


def _index(name: str, names: tuple[str, ...] = PARAMETER_NAMES) -> int:
    try:
        return names.index(name)
    except ValueError:
        raise KeyError(f"{name!r} is not a parameter; the parameters are "
                       f"{', '.join(names)}") from None


def parameter_text(name: str, value: float) -> str:
    """A parameter's value in the unit it reads best in (c_d, d in mm), signed where a sign
    means something."""
    scale, unit = PARAMETER_DISPLAY[name]
    return f"{value * scale:+.3f} {unit}" if scale != 1.0 else f"{value:.5f} {unit}"


def std_text(name: str, std: float) -> str:
    """A standard deviation in the parameter's display unit, as ``+-value``."""
    scale, _ = PARAMETER_DISPLAY[name]
    return f"+-{std * scale:.3f}" if scale != 1.0 else f"+-{std:.5f}"


class Reason(enum.Enum):
    """Why a parameter is not identified."""

    NEEDS_BENDS = "needs-bends"
    """t_r and d act on the yaw rate only in bends, and the drives hold too few."""
    NO_INFORMATION = "no-information"
    """The segments carry no information on it (rank-deficient normal equations)."""
    WEAK = "weak"
    """The data determine it, but not better than the identifiability limit."""
    NO_DIFFERENTIAL = "no-differential"
    """The two wheel signals carry no differential information (locked axle, one speed signal,
    a copied column): only the distance scale c_e can be calibrated."""
    NO_LATERAL = "no-lateral"
    """The lateral acceleration column carries none (zero, constant, a sensor unplugged): d
    cannot be seen, and the load transfer it would explain widens t_r's uncertainty."""
    ONE_CLUSTER = "one-cluster"
    """All segments overlap in time: one piece of independent evidence is not enough."""
    HELD = "held"
    """Held at the starting value on request."""
    FAILED = "failed"
    """The estimation failed; nothing was determined."""
    STANDSTILL = "standstill"
    """The vehicle does not move: there is nothing to calibrate."""
    REJECTED = "rejected"
    """The data contradict the model (see the diagnosis): nothing is calibrated."""


@dataclass(frozen=True)
class Identified:
    """The data identify the parameter: its standard deviation is within the limit."""

    std: float
    limit: float


@dataclass(frozen=True)
class NotIdentified:
    """The parameter keeps its datasheet value.

    reason : why
    std : what the data determine it to (nan when they give no number)
    limit : the identifiability limit (``identifiable_ratio * prior_std``)
    detail : a number behind the reason: the largest peak yaw rate (NEEDS_BENDS, rad/s), the
        number of independent segment clusters (ONE_CLUSTER); nan otherwise
    """

    reason: Reason
    std: float = float("nan")
    limit: float = float("nan")
    detail: float = float("nan")


Verdict = Identified | NotIdentified


class CovarianceKind(enum.Enum):
    """Where an estimate's covariance comes from."""

    CLUSTER_ROBUST = "cluster-robust"
    """Sandwich over clusters of overlapping segments (rollout residuals are correlated)."""
    RESIDUAL = "residual"
    """The residual variance with the white-noise formula, inflated for autocorrelation (too
    few clusters for the robust form)."""
    THREE_STEP = "cluster-robust + step-1 spread"
    """Step 3's robust covariance plus the spread the compensated rates inherit from step 1."""
    RECURSIVE = "recursive information"
    """The online calibrator's: the default method's sandwich over the windows in memory and
    the clusters folded into sums before them (their information and the meat of their
    scores), as batch computes it where nothing is folded."""
    NONE = "none"
    """Nothing was estimated."""


@dataclass(frozen=True)
class GaussNewtonDetails:
    """What a (batch) Gauss-Newton identification did.

    iterations : accepted G-N steps
    cost_history : V at the initial guess and after each accepted step
    segments : number of segments identified from
    clusters : number of independent clusters of overlapping segments
    residual_rms : RMS of the p_x, p_y (m) and psi (rad) residuals at the final theta
    covariance_naive : ``sigma^2 (J^T W J)^-1`` inflated for the residuals' autocorrelation
    """

    iterations: int
    cost_history: tuple[float, ...]
    segments: int
    clusters: int
    residual_rms: tuple[float, float, float]
    covariance_naive: FloatArray = field(repr=False)

    def to_dict(self) -> dict[str, Any]:
        return {"iterations": self.iterations, "cost_history": list(self.cost_history),
                "segments": self.segments, "clusters": self.clusters,
                "residual_rms": {"p_x_m": self.residual_rms[0], "p_y_m": self.residual_rms[1],
                                 "psi_rad": self.residual_rms[2]},
                "covariance_naive": self.covariance_naive.tolist()}


@dataclass(frozen=True)
class Estimate:
    """theta, how sure, what is identified and why, and how the estimation ended.

    method : the estimator that produced it
    theta : the estimate (parameters not identified keep their datasheet values)
    datasheet : the datasheet values (the starting point)
    covariance : ndarray, shape (n, n), order c_e, c_d, t_r, d; zero rows and columns for
        parameters that were not estimated
    covariance_kind : where the covariance comes from
    free : which parameters were estimated from the data
    verdicts : per parameter, :class:`Identified` or :class:`NotIdentified`
    status : how the estimation ended (see :data:`STATUS_MESSAGES`)
    details : the method's own record (typed per method)
    widening : ndarray, shape (n,), the factor by which each standard deviation was widened
        beyond the covariance formula (to the bootstrap spread, or for the sensitivity to the
        noise model); 1 where not widened. ``covariance`` already includes it.
    model : the vehicle model theta belongs to (:mod:`odocal.model.registry`'s name)
    """

    method: str
    theta: Parameters
    datasheet: Parameters
    covariance: FloatArray
    covariance_kind: CovarianceKind
    free: tuple[bool, ...]
    verdicts: tuple[Verdict, ...]
    status: Status
    details: Any = field(default=None, repr=False)
    widening: FloatArray = field(default_factory=lambda: np.ones(PARAMETERS))
    model: str = MODEL.name

    @property
    def success(self) -> bool:
        return self.status.success

    @property
    def message(self) -> str:
        return STATUS_MESSAGES[self.status]

    @property
    def std(self) -> ByName:
        """Standard deviations of c_e, c_d, t_r, d (zero where not estimated), by order or by
        name (``std["t_r"]``)."""
        return ByName(np.sqrt(np.clip(np.diag(self.covariance), 0.0, None)), self.names)

    @property
    def identified(self) -> Flags:
        """Whether the data identify each parameter, by order or by name
        (``identified["t_r"]``)."""
        return Flags((isinstance(v, Identified) for v in self.verdicts), self.names)

    def table(self, *, speed_scale: bool = False) -> list[str]:
        """The parameters as the command line prints them: datasheet, calibrated, std (the
        parameters the data do not identify read "not identified"). ``speed_scale``: the
        wheels' own circumference is unknown (wheel speeds in m/s or km/h), so c_e is shown as
        the scale factor it is on the speed signal."""
        return parameter_table(self, speed_scale=speed_scale)

    def __repr__(self) -> str:
        head = (f"Estimate(method={self.method!r}, status={self.status.name.lower()}, "
                f"covariance_kind={self.covariance_kind.value!r})")
        return "\n".join([head, *self.table()])

    @property
    def names(self) -> tuple[str, ...]:
        """The model's parameter names, in theta's order."""
        return self.theta.layout.names

    @property
    def unidentified(self) -> tuple[str, ...]:
        return tuple(n for n, ok in zip(self.names, self.identified, strict=True) if not ok)

    def verdict(self, name: str) -> Verdict:
        return self.verdicts[self.names.index(name)]

    def with_covariance(self, covariance: FloatArray, kind: CovarianceKind, *,
                        widening: FloatArray | None = None) -> Estimate:
        """A copy with another covariance; identified parameters carry its standard deviations.

        Whether they are still within the limit is the caller's to judge (see :func:`weak`).
        """
        std = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
        verdicts = tuple(Identified(float(std[j]), v.limit) if isinstance(v, Identified) else v
                         for j, v in enumerate(self.verdicts))
        return _replace(self, covariance=covariance, covariance_kind=kind, verdicts=verdicts,
                        widening=self.widening if widening is None else widening)

    def to_dict(self) -> dict[str, Any]:
        """The estimate as plain data (the top of calibration.json)."""
        names = self.names
        return {
            "method": self.method,
            "model": self.model,
            "theta": self.theta.as_dict(),
            "std": dict(zip(names, self.std.tolist(), strict=True)),
            "covariance": self.covariance.tolist(),
            "covariance_kind": self.covariance_kind.value,
            "std_widening": dict(zip(names, np.asarray(self.widening).tolist(),
                                     strict=True)),
            "free": dict(zip(names, self.free, strict=True)),
            "identified": dict(zip(names, self.identified, strict=True)),
            "verdicts": {n: verdict_dict(v) for n, v in zip(names, self.verdicts,
                                                            strict=True)},
            "status": {"code": int(self.status), "name": self.status.name.lower(),
                       "success": self.success, "message": self.message},
            "datasheet": self.datasheet.as_dict(),
        }


def parameter_table(est: Estimate, *, truth: Parameters | None = None,
                    best_std: Any = None, speed_scale: bool = False) -> list[str]:
    """The parameter table of the command line's summary (and of ``repr(estimate)``):
    ``truth`` (a simulated drive's) adds the true values and the errors, ``best_std`` (its
    Cramér-Rao bound) the least std possible; ``speed_scale`` shows c_e as the factor it is
    on a speed signal of unknown circumference (the datasheet column: the circumference the
    speeds were turned into wheel rates with)."""
    import math

    header = f"{'parameter':<10} {'datasheet':>16} {'calibrated':>16} {'std':>10}"
    if best_std is not None:
        header += f" {'best std':>10}"
    if truth is not None:
        header += f" {'true':>16} {'error':>10}"
    lines = [header]
    theta0, theta = est.datasheet.as_dict(), est.theta.as_dict()
    true = truth.as_dict() if truth is not None else None
    std = est.std
    exact = est.status is Status.EXACT
    for j, (name, ok) in enumerate(zip(est.names, est.identified, strict=True)):
        if ok:
            cal = parameter_text(name, theta[name])
            # exact: a noise-free fit's, to rounding (a part with noise of its own, such as
            # the four-wheel car's steering sensor, shows its std)
            tiny = float(std[j]) <= 1e-9 * max(abs(theta[name]), 1.0)
            sd = "exact" if exact and tiny else std_text(name, float(std[j]))
        else:
            cal, sd = "not identified", ""
        line = f"{name:<10} {parameter_text(name, theta0[name]):>16} {cal:>16} {sd:>10}"
        if best_std is not None:
            best = float(best_std[j])
            line += f" {std_text(name, best) if math.isfinite(best) else '-':>10}"
        if true is not None:
            err = std_text(name, abs(theta[name] - true[name])).replace("+-", "") if ok else ""
            line += f" {parameter_text(name, true[name]):>16} {err:>10}"
        lines.append(line)
    if speed_scale and est.identified[0] and theta0[PARAMETER_NAMES[0]] > 0:
        factor = theta[PARAMETER_NAMES[0]] / theta0[PARAMETER_NAMES[0]]
        lines.append(f"{'scale':<10} {'1':>16} {factor:>16.5f} "
                     f"{'+-' + format(float(std[0]) / theta0[PARAMETER_NAMES[0]], '.5f'):>10}")
    return lines


def _replace(estimate: Estimate, **changes: Any) -> Estimate:
    import dataclasses

    return dataclasses.replace(estimate, **changes)


def verdict_dict(v: Verdict) -> dict[str, Any]:
    if isinstance(v, Identified):
        return {"identified": True, "std": v.std, "limit": v.limit}
    return {"identified": False, "reason": v.reason.value, "std": v.std, "limit": v.limit,
            "detail": v.detail}


def identifiability_limits(settings: IdentifySettings) -> FloatArray:
    """The largest standard deviation at which each parameter counts as identified."""
    return settings.identifiable_ratio * np.asarray(settings.prior_std, dtype=np.float64)


def weak(std: FloatArray, free: BoolArray | tuple[bool, ...],
         settings: IdentifySettings) -> BoolArray:
    """Free parameters whose standard deviation exceeds the identifiability limit."""
    if not settings.judge_identifiability:
        return np.zeros(PARAMETERS, dtype=bool)
    std = np.asarray(std, dtype=np.float64)
    return np.asarray(free, dtype=bool) & ~(std <= identifiability_limits(settings))


def judge(std: FloatArray, free: BoolArray | tuple[bool, ...], settings: IdentifySettings, *,
          held: Mapping[str, NotIdentified] | None = None,
          ) -> tuple[Verdict, ...]:
    """The verdict per parameter: held ones keep their reason, free ones are judged by std."""
    held = held or {}
    limits = identifiability_limits(settings)
    too_weak = weak(std, free, settings)
    out: list[Verdict] = []
    for j, name in enumerate(PARAMETER_NAMES):
        if name in held:
            h = held[name]
            out.append(NotIdentified(h.reason, h.std, float(limits[j]), h.detail))
        elif not free[j]:
            out.append(NotIdentified(Reason.HELD, float("nan"), float(limits[j])))
        elif too_weak[j]:
            out.append(NotIdentified(Reason.WEAK, float(std[j]), float(limits[j])))
        else:
            out.append(Identified(float(std[j]), float(limits[j])))
    return tuple(out)


def hold_unidentified(free: BoolArray, held: Mapping[str, NotIdentified],
                      settings: IdentifySettings, *,
                      covariance_of: Callable[[BoolArray], tuple[FloatArray, int]],
                      refit: Callable[[BoolArray], None],
                      ) -> tuple[BoolArray, dict[str, NotIdentified]]:
    """The identifiability verdict, the same for every method: parameters the data do not
    determine within the limit (:func:`weak`) keep their datasheet values and are named, one
    at a time (the weakest against its limit first), and the rest is refitted
    (``refit(free)``), until every free one passes. Where the evidence is
    one cluster of overlapping data only, nothing is identified (no spread to judge by).

    ``covariance_of(free)`` gives the (n, n) covariance of the latest fit and the number of
    independent clusters it rests on. Returns the free parameters and why the others are held.
    """
    free = np.asarray(free, dtype=bool).copy()
    held = dict(held)
    for _ in range(len(PARAMETER_NAMES) + 1):
        cov, clusters = covariance_of(free)
        std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        if clusters < 2 and free.any() and settings.judge_identifiability:
            for j in np.flatnonzero(free):
                held[PARAMETER_NAMES[j]] = NotIdentified(Reason.ONE_CLUSTER, float(std[j]),
                                                         detail=float(clusters))
            free[:] = False
        else:
            too_weak = weak(std, free, settings)
            if not too_weak.any():
                break
            # the weakest first: holding it can make another one well determined (a circle's
            # d held, its c_e no longer bends to d's yaw), or take another one's support away
            ratio = np.where(too_weak, std / identifiability_limits(settings), -np.inf)
            worst = np.zeros_like(too_weak)
            worst[int(np.argmax(ratio))] = True
            held.update(held_as_weak(std, worst, settings))
            free = free & ~worst
        refit(free)
        if not free.any():
            break
    return free, held


def held_as_weak(std: FloatArray, mask: BoolArray,
                 settings: IdentifySettings) -> dict[str, NotIdentified]:
    """NotIdentified(WEAK) for the parameters in ``mask``, with the std the data gave."""
    limits = identifiability_limits(settings)
    return {PARAMETER_NAMES[j]: NotIdentified(Reason.WEAK, float(std[j]), float(limits[j]))
            for j in np.flatnonzero(mask)}


def refused_estimate(method: str, settings: IdentifySettings, status: Status, reason: Reason,
                     *, details: Any = None) -> Estimate:
    """The datasheet values, nothing estimated, every parameter not identified for ``reason``."""
    theta0 = Parameters.from_array(settings.theta0)
    limits = identifiability_limits(settings)
    return Estimate(method=method, theta=theta0, datasheet=theta0,
                    covariance=np.zeros((PARAMETERS, PARAMETERS)),
                    covariance_kind=CovarianceKind.NONE, free=(False,) * PARAMETERS,
                    verdicts=tuple(NotIdentified(reason, limit=float(v))
                                   for v in limits),
                    status=status, details=details)


#: The one-standard-deviation quantile (0.8413) of Student's t with 1..8 degrees of freedom
#: (``scipy.special.stdtrit(dof, 0.8413447)``): how much wider a standard deviation estimated
#: from only 2..9 independent clusters must be to cover as often as one from many.
_T_ONE_SIGMA = (1.8373, 1.3213, 1.1969, 1.1416, 1.1105, 1.0906, 1.0767, 1.0665)


def few_clusters_inflation(clusters: int) -> float:
    """Factor for standard deviations estimated from ``clusters`` independent clusters."""
    if clusters < 2:
        return float("inf")
    return _T_ONE_SIGMA[clusters - 2] if clusters - 2 < len(_T_ONE_SIGMA) else 1.0


#: The tail at which a standard deviation from few clusters is made to cover: two sigmas (a
#: normal error beyond it 4.6% of the time).
_TAIL_SIGMAS = 2.0


def tail_inflation(clusters: float) -> float:
    """Factor for a standard deviation estimated from ``clusters`` independent clusters so
    that an error beyond two of them is as rare as a normal error's (4.6%): Student's t with
    ``clusters - 1`` degrees of freedom (Satterthwaite's: not a whole number where the
    clusters share the information unevenly), at that quantile, over 2. 2.26 for 3 clusters,
    1.99 for 3.3, 1.16 for 10 (a one-minute drive), 1.04 for 30: a short drive's uncertainty
    must cover its errors, whose spread is itself estimated from few pieces."""
    if clusters < 2:
        return float("inf")
    # scipy.special's distribution functions (scipy.stats would take half a second to import,
    # on every calibration)
    from scipy.special import ndtr, stdtrit

    quantile = float(ndtr(_TAIL_SIGMAS))
    return float(stdtrit(clusters - 1.0, quantile) / _TAIL_SIGMAS)


#: Relative singular value of the scaled information's root below which it is rank deficient.
_RANK_RCOND = 1e-7


def numerically_free(information: FloatArray, prior_std: tuple[float, ...] | FloatArray,
                     free: BoolArray) -> BoolArray:
    """``free`` less the parameters the information (n, n) cannot tell apart from the others:
    dropped one by one (the one that carries the null direction most, in units of its datasheet
    uncertainty) until the rest has full rank."""
    prior = np.asarray(prior_std, dtype=np.float64)
    free = np.asarray(free, dtype=bool).copy()
    while free.any():
        cols = np.flatnonzero(free)
        scaled = information[np.ix_(cols, cols)] * np.outer(prior[cols], prior[cols])
        values, vectors = np.linalg.eigh(scaled)
        top = float(values[-1])
        if top > 0 and values[0] > (_RANK_RCOND**2) * top:
            break
        free[cols[int(np.argmax(np.abs(vectors[:, 0])))] if top > 0 else cols] = False
    return free
