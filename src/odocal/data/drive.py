"""The in-memory drive: one log of one vehicle on a uniform time grid.

A :class:`Drive` holds the signals of METHOD section 1 sample by sample: the measured wheel rates
``n_rl, n_rr`` (rev/s), the lateral acceleration ``a_y`` (m/s^2), the sideslip ``beta`` (rad) and
the reference pose ``x, y, psi`` (m, m, rad). Every constructor checks its input and raises
:class:`~odocal.errors.DataError` with a message naming the source, the column and the problem.

A drive may consist of several *pieces*: runs of samples on one uniform grid separated by gaps
(for example where a logger dropped out). Segments never cross a piece boundary.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import numpy as np

from odocal.arrays import BoolArray, FloatArray, IntArray
from odocal.errors import DataError

#: Columns of the drive format that must be present.
REQUIRED_COLUMNS: tuple[str, ...] = ("t", "n_rl", "n_rr", "a_y", "x", "y", "psi")
#: The further inputs a drive may carry for a vehicle model beyond the rear axle: the front
#: wheels' rates (rev/s) and the steering-wheel angle (rad). Every current log carries them
#: (nuScenes, comma2k19); :mod:`odocal.model.four_wheel` takes them.
MODEL_INPUTS: tuple[str, ...] = ("n_fl", "n_fr", "steer")
#: Columns of the drive format that may be present.
OPTIONAL_COLUMNS: tuple[str, ...] = ("beta", "yaw_rate", "piece", "x_std", "y_std", "psi_std",
                                     *MODEL_INPUTS)

# Plausibility limits used to catch wrong units (not physics limits of any car).
_MAX_WHEEL_SPEED_MPS = 80.0   # 288 km/h: 40 rev/s of a car's 2 m wheel
_CAR_CIRCUMFERENCE_M = 2.0    # the wheel the rates are judged with when none is stated
_MAX_YAW_RATE_RADPS = 3.0
#: The slowest and fastest sampling a drive may have. Below 10 Hz the model's step (the wheel
#: rates held over a sample) misses most of a bend: simulated drives at 2-5 Hz already give
#: parameters several of their standard deviations off.
MIN_RATE_HZ, MAX_RATE_HZ = 10.0, 1000.0
_UNIFORM_TOLERANCE = 0.01  # relative jitter of the time step still called uniform
#: Stamps whose steps all stay within this fraction of the step are a uniform log with
#: jittered stamps (resampled onto the grid); a longer step is a gap, a shorter one irregular.
_JITTER_LIMIT = 0.5


def _as_float_array(values: Any) -> FloatArray:
    return np.ascontiguousarray(values, dtype=np.float64)


@dataclass(frozen=True, eq=False)
class Drive:
    """One drive on a uniform time grid.

    Attributes
    ----------
    t : ndarray, shape (M,)
        Time, s, strictly increasing; uniform with step ``t_s`` inside each piece.
    n_rl, n_rr : ndarray, shape (M,)
        Measured rear-left / rear-right wheel rotation rates, rev/s.
    a_y : ndarray, shape (M,)
        Lateral acceleration, m/s^2, positive to the left.
    beta : ndarray, shape (M,)
        Sideslip angle, rad.
    x, y : ndarray, shape (M,)
        Reference position in a local planar frame, m.
    psi : ndarray, shape (M,)
        Reference heading, rad, counter-clockwise from the x axis, unwrapped inside each piece.
    yaw_rate : ndarray, shape (M,)
        Yaw rate, rad/s (measured, or derived from ``psi``); used to select segments.
    t_s : float
        Sampling time, s.
    pieces : tuple of (start, stop)
        Index ranges ``[start, stop)`` of the contiguous pieces, in order, covering all samples.
    name : str
        Where the drive came from (a file name), used in messages.
    pose_std : ndarray, shape (M, 3), or None
        Standard deviation of the reference pose (m, m, rad) where known (from a fusion).
    inputs : mapping of name to ndarray, shape (M,)
        The further inputs the log carries (:data:`MODEL_INPUTS`: the front wheels' rates
        ``n_fl``, ``n_fr`` in rev/s, the steering-wheel angle ``steer`` in rad).
    metadata : mapping
        Free-form provenance (source format, conversion settings, time offsets found, ...).
    """

    t: FloatArray
    n_rl: FloatArray
    n_rr: FloatArray
    a_y: FloatArray
    beta: FloatArray
    x: FloatArray
    y: FloatArray
    psi: FloatArray
    yaw_rate: FloatArray
    t_s: float
    pieces: tuple[tuple[int, int], ...]
    name: str = "drive"
    pose_std: FloatArray | None = None
    metadata: Mapping[str, Any] = field(default_factory=lambda: MappingProxyType({}))
    inputs: Mapping[str, FloatArray] = field(default_factory=lambda: MappingProxyType({}))

    def __post_init__(self) -> None:
        m = self.t.shape[0]
        inputs = {k: _as_float_array(v) for k, v in self.inputs.items()}
        for key, arr in inputs.items():
            if key not in MODEL_INPUTS:
                raise DataError(f"{self.name}: {key!r} is not an input odocal knows "
                                f"({', '.join(MODEL_INPUTS)})")
            # NaN: a sample not measured (its model's fit leaves it out); never infinite
            if arr.shape != (m,) or np.isinf(arr).any() or (m and np.isnan(arr).all()):
                raise DataError(f"{self.name}: column {key} must hold {m} values, finite or "
                                "NaN (not measured), not all NaN")
            arr.flags.writeable = False
        object.__setattr__(self, "inputs", MappingProxyType(inputs))
        for key in ("n_rl", "n_rr", "a_y", "beta", "x", "y", "psi", "yaw_rate"):
            arr = getattr(self, key)
            if arr.shape != (m,):
                raise DataError(f"{self.name}: column {key} has shape {arr.shape}, expected ({m},)")
        if self.pose_std is not None and self.pose_std.shape != (m, 3):
            raise DataError(f"{self.name}: pose_std has shape {self.pose_std.shape}, "
                            f"expected ({m}, 3)")
        covered = 0
        for start, stop in self.pieces:
            if start != covered or stop <= start:
                raise DataError(f"{self.name}: pieces {self.pieces} do not tile 0..{m}")
            covered = stop
        if covered != m:
            raise DataError(f"{self.name}: pieces {self.pieces} do not tile 0..{m}")
        if not (np.isfinite(self.t_s) and self.t_s > 0):
            raise DataError(f"{self.name}: the sampling time {self.t_s} must be positive")
        for key in ("t", "n_rl", "n_rr", "a_y", "beta", "x", "y", "psi", "yaw_rate"):
            bad = ~np.isfinite(getattr(self, key))
            if bad.any():
                raise DataError(f"{self.name}: column {key} contains {int(bad.sum())} NaN or "
                                "infinite values")
        if m > 1 and (np.diff(self.t) <= 0).any():
            raise DataError(f"{self.name}: column t is not strictly increasing")
        for arr in (self.t, self.n_rl, self.n_rr, self.a_y, self.beta, self.x, self.y, self.psi,
                    self.yaw_rate):
            arr.flags.writeable = False
        if self.pose_std is not None:
            self.pose_std.flags.writeable = False
        if not isinstance(self.metadata, MappingProxyType):
            object.__setattr__(self, "metadata", MappingProxyType(dict(self.metadata)))

    @property
    def n_samples(self) -> int:
        return int(self.t.shape[0])

    @property
    def duration_s(self) -> float:
        return float(sum((stop - start - 1) * self.t_s for start, stop in self.pieces))

    @property
    def distance_m(self) -> float:
        """Travelled distance of the reference inside the pieces, over the steps in which the
        wheels turn: a parked vehicle's pose jitters (2 cm of noise at 40 Hz adds 5 km an
        hour), its wheels do not."""
        total = 0.0
        for start, stop in self.pieces:
            step = np.hypot(np.diff(self.x[start:stop]), np.diff(self.y[start:stop]))
            turning = 0.5 * np.abs(self.n_rl[start:stop - 1] + self.n_rr[start:stop - 1]) \
                > RESTING_REVPS
            total += float(step[turning].sum())
        return total

    def columns(self) -> dict[str, FloatArray]:
        """The drive as drive-format columns (``piece`` only when there are several)."""
        cols: dict[str, FloatArray] = {
            "t": self.t, "n_rl": self.n_rl, "n_rr": self.n_rr, "a_y": self.a_y,
            "beta": self.beta, "x": self.x, "y": self.y, "psi": self.psi,
            "yaw_rate": self.yaw_rate,
        }
        if len(self.pieces) > 1:
            piece = np.empty(self.n_samples)
            for i, (start, stop) in enumerate(self.pieces):
                piece[start:stop] = i
            cols["piece"] = piece
        if self.pose_std is not None:
            cols["x_std"], cols["y_std"], cols["psi_std"] = (self.pose_std[:, 0],
                                                            self.pose_std[:, 1],
                                                            self.pose_std[:, 2])
        cols.update(self.inputs)
        return cols

    def with_wheel_rates(self, n_rl: FloatArray, n_rr: FloatArray) -> Drive:
        """A copy with other wheel rates (for example compensated ones)."""
        return Drive(t=self.t, n_rl=_as_float_array(n_rl), n_rr=_as_float_array(n_rr),
                     a_y=self.a_y, beta=self.beta, x=self.x, y=self.y, psi=self.psi,
                     yaw_rate=self.yaw_rate, t_s=self.t_s, pieces=self.pieces, name=self.name,
                     pose_std=self.pose_std, metadata=self.metadata, inputs=self.inputs)

    def select(self, keep: BoolArray, **columns: FloatArray) -> Drive:
        """The samples where ``keep`` (pieces split where a run of kept samples breaks), with
        ``columns`` (full length, by field name) replacing the drive's own first."""
        keep = np.asarray(keep, dtype=bool)
        values = {k: np.asarray(columns.get(k, getattr(self, k)))[keep]
                  for k in ("t", "n_rl", "n_rr", "a_y", "beta", "x", "y", "psi", "yaw_rate")}
        index = np.flatnonzero(keep)
        if index.size == 0:
            raise DataError(f"{self.name}: no sample left")
        piece_of = np.zeros(self.n_samples, dtype=np.int64)
        for k, (a, b) in enumerate(self.pieces):
            piece_of[a:b] = k
        breaks = np.flatnonzero((np.diff(index) != 1)
                                | (np.diff(piece_of[index]) != 0)) + 1
        edges = [0, *breaks.tolist(), index.size]
        pose_std = None if self.pose_std is None else self.pose_std[keep]
        return Drive(t_s=self.t_s, pieces=tuple(itertools.pairwise(edges)),
                     name=self.name, pose_std=pose_std, metadata=self.metadata,
                     inputs={k: v[keep] for k, v in self.inputs.items()}, **values)

    def since(self, t0: float) -> Drive:
        """The samples from time ``t0`` on (pieces cut there); the drive itself where it starts
        later."""
        start = int(np.searchsorted(self.t, t0, side="left"))
        if start <= 0:
            return self
        if start >= self.n_samples:
            raise DataError(f"{self.name}: no sample from t = {t0:g} s on")
        pieces = tuple((max(a, start) - start, b - start) for a, b in self.pieces if b > start)
        cut = slice(start, None)
        return Drive(t=self.t[cut], n_rl=self.n_rl[cut], n_rr=self.n_rr[cut],
                     a_y=self.a_y[cut], beta=self.beta[cut], x=self.x[cut], y=self.y[cut],
                     psi=self.psi[cut], yaw_rate=self.yaw_rate[cut], t_s=self.t_s,
                     pieces=pieces, name=self.name,
                     pose_std=None if self.pose_std is None else self.pose_std[cut],
                     metadata=self.metadata, inputs={k: v[cut] for k, v in self.inputs.items()})

    @classmethod
    def from_columns(cls, columns: Mapping[str, Any], *, name: str = "drive",
                     metadata: Mapping[str, Any] | None = None,
                     circumference_m: float | None = None) -> Drive:
        """Build a drive from drive-format columns, checking everything a user can get wrong.

        ``columns`` maps the names of the drive format (see :data:`REQUIRED_COLUMNS` and
        :data:`OPTIONAL_COLUMNS`) to 1-D arrays; unknown columns are ignored. Stamps that jitter
        about a uniform step (no step beyond half a step off) are resampled onto it
        (``metadata["resampled"]`` says so). ``circumference_m``: the vehicle's wheel
        circumference (a datasheet's ``c_e``; default the one ``metadata["datasheet"]`` states,
        else a car's 2 m), which the wheel rates' plausibility is judged with.
        """
        arrays, left_out = _columns(columns, name)
        _check_increasing(name, arrays["t"])
        arrays, pieces, t_s, resampled = _on_uniform_steps(name, arrays)
        m = arrays["t"].shape[0]
        t = arrays["t"]
        wheel_m, stated = _circumference(circumference_m, metadata)

        # a unit mistake first (rates in rpm jump by more than a spike's size everywhere),
        # judged on most of the samples, so that a few broken ones do not look like a unit
        _check_wheel_units(name, arrays["n_rl"], arrays["n_rr"], circumference_m=wheel_m,
                           stated=stated, percentile=90.0)
        arrays, repaired = _without_spikes(name, arrays, pieces)
        _check_limits(name, arrays, left_out)
        n_rl, n_rr = arrays["n_rl"], arrays["n_rr"]
        _check_wheel_bursts(name, arrays["t"], n_rl, n_rr, circumference_m=wheel_m)
        _check_held_reference(name, arrays, pieces)
        _check_wheel_units(name, n_rl, n_rr, circumference_m=wheel_m, stated=stated)
        for key in ("n_fl", "n_fr"):           # the front wheels: left out, not refused
            if key not in arrays:
                continue
            known = arrays[key][np.isfinite(arrays[key])]
            try:
                _check_wheel_units(name, known, known, circumference_m=wheel_m,
                                   stated=stated, key=key)
            except DataError as err:
                _refuse_or_leave_out(str(err), key, arrays, left_out)
        psi, yaw_rate = _heading_and_yaw_rate(name, arrays, t_s, pieces)
        x, y = arrays["x"], arrays["y"]
        _check_position_units(name, x, y, n_rl, n_rr, t_s, pieces, circumference_m=wheel_m)
        pose_std = _pose_std(name, arrays)
        return cls(t=t, n_rl=n_rl, n_rr=n_rr, a_y=arrays["a_y"],
                   beta=arrays.get("beta", np.zeros(m)), x=x, y=y, psi=psi,
                   yaw_rate=_as_float_array(yaw_rate), t_s=t_s, pieces=pieces, name=name,
                   pose_std=pose_std, inputs={k: arrays[k] for k in MODEL_INPUTS if k in arrays},
                   metadata=MappingProxyType({**dict(metadata or {}),
                                              **({"left_out": left_out} if left_out else {}),
                                              **({"repaired": repaired} if repaired else {}),
                                              **({"resampled": resampled} if resampled
                                                 else {})}))


def _check_increasing(name: str, t: FloatArray) -> None:
    """A DataError where ``t`` does not strictly increase (naming stamps that repeat because
    they lost their precision first: :func:`check_time_precision`)."""
    dt = np.diff(t)
    if (dt <= 0).any():
        first = int(np.argmax(dt <= 0))
        check_time_precision(name, t)
        raise DataError(f"'{name}' column t is not strictly increasing: t={t[first + 1]:.6g} "
                        f"follows t={t[first]:.6g} at row {first + 2}; sort the log or drop "
                        "duplicate stamps")


def _on_uniform_steps(name: str, arrays: dict[str, FloatArray]
                      ) -> tuple[dict[str, FloatArray], tuple[tuple[int, int], ...], float,
                                 dict[str, float]]:
    """The columns on a uniform step within each piece: as given where the stamps are
    uniform, else resampled onto the step their jitter lies about (:func:`_resampled`).

    Returns the columns, the pieces, the step (s) and what the resampling did (``step_s``,
    ``max_jitter_s``; empty where nothing was resampled).
    """
    pieces = _pieces(name, arrays["t"], arrays.get("piece"))
    t_s, jitter_s = _sampling_time(name, arrays["t"], pieces)
    resampled: dict[str, float] = {}
    if jitter_s is not None:
        arrays, pieces = _resampled(arrays, pieces, t_s)
        resampled = {"step_s": t_s, "max_jitter_s": jitter_s}
    return arrays, pieces, t_s, resampled


def _without_spikes(name: str, arrays: Mapping[str, FloatArray],
                    pieces: tuple[tuple[int, int], ...]
                    ) -> tuple[dict[str, FloatArray], dict[str, int]]:
    """The columns with isolated spikes repaired (:func:`_repair_spikes`, the columns of
    :data:`_SPIKE_SCALE`), and how many were repaired in each column that had any."""
    arrays = dict(arrays)
    repaired: dict[str, int] = {}
    for key, scale in _SPIKE_SCALE.items():
        if key in arrays:
            arrays[key], count = _repair_spikes(name, key, arrays[key], scale, pieces)
            if count:
                repaired[key] = count
    return arrays, repaired


def _heading_and_yaw_rate(name: str, arrays: Mapping[str, FloatArray], t_s: float,
                          pieces: tuple[tuple[int, int], ...]) -> tuple[FloatArray, FloatArray]:
    """The heading unwrapped within each piece, and the yaw rate (the column, else the
    heading's derivative); a DataError where either turns faster than any vehicle (degrees,
    deg/s, or a heading that is noisy or jumps)."""
    psi = _unwrap_pieces(arrays["psi"], pieces)
    yaw_from_psi = derivative_pieces(psi, t_s, pieces)
    if np.percentile(np.abs(yaw_from_psi), 99) > _MAX_YAW_RATE_RADPS:
        _psi_too_fast(name, psi, yaw_from_psi, t_s)
    yaw_rate = arrays.get("yaw_rate", yaw_from_psi)
    if np.percentile(np.abs(yaw_rate), 99) > _MAX_YAW_RATE_RADPS:
        raise DataError(f"'{name}' column yaw_rate reaches {np.max(np.abs(yaw_rate)):.3g}: "
                        "yaw_rate must be in rad/s (is it in deg/s?)")
    return psi, yaw_rate


def _pose_std(name: str, arrays: Mapping[str, FloatArray]) -> FloatArray | None:
    """The reference pose's standard deviations, shape (M, 3) (x_std, y_std, psi_std), or None
    where the drive has none; a DataError for some of them only, or a negative one."""
    std_cols = [c for c in ("x_std", "y_std", "psi_std") if c in arrays]
    if not std_cols:
        return None
    if len(std_cols) != 3:
        raise DataError(f"'{name}' has {', '.join(std_cols)} but not all of x_std, y_std, "
                        "psi_std")
    pose_std = np.column_stack([arrays["x_std"], arrays["y_std"], arrays["psi_std"]])
    if (pose_std < 0).any():
        raise DataError(f"'{name}' has negative pose standard deviations")
    return pose_std


def _columns(columns: Mapping[str, Any], name: str
             ) -> tuple[dict[str, FloatArray], list[str]]:
    """The drive format's columns as float arrays, each checked: present, numeric, one row per
    sample, finite."""
    missing = [c for c in REQUIRED_COLUMNS if c not in columns]
    if missing:
        known = {*REQUIRED_COLUMNS, *OPTIONAL_COLUMNS}
        other = [str(c) for c in columns if c not in known]
        hint = (f"; it has other columns ({', '.join(other[:6])}{', ...' if len(other) > 6 else ''}"
                "): a log of other columns is read with a mapping that names each stream's "
                "columns and units, --from table --mapping MAP.toml" if other else "")
        raise DataError(f"'{name}' lacks column{'s' if len(missing) > 1 else ''} "
                        f"{', '.join(missing)} (the drive format needs "
                        f"{', '.join(REQUIRED_COLUMNS)}){hint}")
    arrays: dict[str, FloatArray] = {}
    for key in (*REQUIRED_COLUMNS, *OPTIONAL_COLUMNS):
        if key not in columns:
            continue
        try:
            arr = _as_float_array(columns[key])
        except (TypeError, ValueError) as err:
            raise DataError(f"'{name}' column {key} is not numeric") from err
        if arr.ndim != 1:
            raise DataError(f"'{name}' column {key} must be one-dimensional")
        arrays[key] = arr
    m = arrays["t"].shape[0]
    if m == 0:
        raise DataError(f"'{name}' has no rows")
    if m < 3:
        raise DataError(f"'{name}' has only {m} rows; a drive needs many samples")
    t = arrays["t"]
    left_out: list[str] = []
    for key, arr in list(arrays.items()):
        if arr.shape[0] != m:
            raise DataError(f"'{name}' column {key} has {arr.shape[0]} rows, t has {m}")
        bad = ~np.isfinite(arr)
        if bad.any():
            first = int(np.argmax(bad))
            where = f"t={t[first]:.3f} s" if key != "t" and np.isfinite(t[first]) \
                else f"row {first + 1}"
            said = (f"'{name}' column {key} contains {int(bad.sum())} NaN or infinite values "
                    f"(first at {where})")
            if key in MODEL_INPUTS and not bad.all():
                # a further input's samples not measured (dropped CAN frames): those samples
                # are left out of its model's fit, the rest of the column is read
                arrays[key] = np.where(bad, np.nan, arr)
                left_out.append(f"{said}: those samples are left out (an input only the "
                                "four_wheel model reads)")
                continue
            _refuse_or_leave_out(said, key, arrays, left_out)
    return arrays, left_out


def _pieces(name: str, t: FloatArray, piece: FloatArray | None) -> tuple[tuple[int, int], ...]:
    """Index ranges of the pieces: from a ``piece`` column, or one piece."""
    m = t.shape[0]
    if piece is None:
        return ((0, m),)
    if (piece != np.round(piece)).any():
        raise DataError(f"'{name}' column piece must hold integers")
    change = np.flatnonzero(np.diff(piece) != 0) + 1
    if (np.diff(piece) < 0).any():
        raise DataError(f"'{name}' column piece must not decrease")
    bounds = [0, *change.tolist(), m]
    return tuple((bounds[i], bounds[i + 1]) for i in range(len(bounds) - 1))


def _sampling_time(name: str, t: FloatArray, pieces: tuple[tuple[int, int], ...]
                   ) -> tuple[float, float | None]:
    """The uniform step inside the pieces, and how far the stamps jitter about it (None: they
    are uniform within 1%), or a DataError naming the first irregularity (a gap, a step of
    another unit, a rate no drive log has)."""
    inside = np.concatenate([np.diff(t[a:b]) for a, b in pieces])
    if inside.size == 0:
        raise DataError(f"'{name}': every piece holds a single sample")
    t_s = float(np.median(inside))
    _check_rate(name, t_s)
    off = np.abs(inside - t_s) > _UNIFORM_TOLERANCE * t_s
    # the mean step: stamps on an epoch clock (1.7e9 s) are rounded to 2.4e-7 s, which moves
    # their median step by parts in a million (and c_e, which scales with it, as much)
    counts = sum(b - a - 1 for a, b in pieces)
    step = float(sum(t[b - 1] - t[a] for a, b in pieces)) / counts
    if not off.any():
        return step, None
    offsets = np.concatenate([np.arange(a, b - 1) for a, b in pieces])
    broken = np.abs(inside - t_s) >= _JITTER_LIMIT * t_s
    if broken.any():
        _check_rate_change(name, t, inside, offsets, t_s)
        # the time where the first step beyond jitter starts
        first = int(offsets[np.argmax(broken)])
        step = float(t[first + 1] - t[first])
        kind = "a gap" if step > t_s else "an irregular step"
        raise DataError(f"'{name}' column t has {kind} of {step:.4g} s at t={t[first]:.3f} s "
                        f"(the step is {t_s:.4g} s); resample to a uniform grid, or mark the "
                        "separate runs with a 'piece' column")
    # jittered stamps of a uniform log: the grid's step is their mean step
    jitter = max(float(np.max(np.abs(_deviation(t[a:b], step)))) for a, b in pieces)
    if jitter >= _JITTER_LIMIT * step:
        raise DataError(f"'{name}' column t drifts {jitter:.4g} s from a uniform step of "
                        f"{step:.4g} s within a piece: resample to a uniform grid, or mark the "
                        "separate runs with a 'piece' column")
    return step, jitter


#: Consecutive steps of one other length that make a stretch logged at another rate.
_RATE_RUN = 10


def _check_rate_change(name: str, t: FloatArray, inside: FloatArray, offsets: IntArray,
                       t_s: float) -> None:
    """A DataError naming a stretch logged at another rate (a logger reconfigured: 10 Hz,
    then 40 Hz), not its first step as a gap."""
    off = np.abs(inside - t_s) >= _JITTER_LIMIT * t_s
    first = int(np.argmax(off))
    other = float(inside[first])
    same = np.abs(inside - other) <= _UNIFORM_TOLERANCE * other
    run = first
    while run < inside.size and same[run]:
        run += 1
    if run - first < _RATE_RUN:
        return
    start, stop = int(offsets[first]), int(offsets[run - 1]) + 1
    raise DataError(f"'{name}' column t steps {other:.4g} s ({1.0 / other:.3g} Hz) from "
                    f"t={t[start]:.3f} s to t={t[stop]:.3f} s ({run - first} steps) and "
                    f"{t_s:.4g} s ({1.0 / t_s:.3g} Hz) elsewhere: the log changes its rate; "
                    "resample it to one rate")


_TIME_UNITS = (("milliseconds", 1e-3, "1000"), ("microseconds", 1e-6, "1e6"),
               ("nanoseconds", 1e-9, "1e9"))


def _deviation(t: FloatArray, step: float) -> FloatArray:
    """How far the stamps ``t`` (one piece) lie from the uniform grid of ``step`` that fits
    them best."""
    grid = step * np.arange(t.size)
    return t - grid - float(np.mean(t - grid))


def _check_rate(name: str, t_s: float) -> None:
    """A DataError unless a step of ``t_s`` seconds is that of a drive log (10 Hz - 1 kHz): it
    names the unit the step looks like, or the rate that is too low."""
    if t_s < 1.0 / MAX_RATE_HZ:
        raise DataError(f"'{name}' column t has a step of {t_s:.3g} s: t must be in seconds "
                        f"(a rate above {MAX_RATE_HZ:g} Hz is not a drive log)")
    if t_s <= (1.0 + _UNIFORM_TOLERANCE) / MIN_RATE_HZ:
        return
    if t_s <= 1.0:
        raise DataError(f"'{name}' is sampled at {1.0 / t_s:.3g} Hz (column t steps "
                        f"{t_s:.3g} s): the model holds the wheel rates over each step and "
                        f"needs {MIN_RATE_HZ:g} Hz or more; log or resample the sensors faster")
    looks = [f"{unit} at {1.0 / (t_s * factor):.4g} Hz: divide t by {divisor}"
             for unit, factor, divisor in _TIME_UNITS
             if MIN_RATE_HZ <= 1.0 / (t_s * factor) <= MAX_RATE_HZ]
    unit = (f"it looks like {' or '.join(looks)}" if looks else
            f"in no unit is that the step of a drive log at {MIN_RATE_HZ:g} Hz - "
            f"{MAX_RATE_HZ:g} Hz")
    raise DataError(f"'{name}' column t has a step of {t_s:.6g}: t must be in seconds ({unit}; "
                    f"in seconds the log would be sampled at {1.0 / t_s:.3g} Hz, and the model "
                    f"needs {MIN_RATE_HZ:g} Hz or more)")


def _resampled(arrays: dict[str, FloatArray], pieces: tuple[tuple[int, int], ...],
               t_s: float) -> tuple[dict[str, FloatArray], tuple[tuple[int, int], ...]]:
    """Every column linearly interpolated onto a uniform grid of step ``t_s`` over each piece
    (headings unwrapped first), and the pieces on it."""
    t = arrays["t"]
    grids = []
    for a, b in pieces:                      # the fitted grid, inside the piece's stamps
        origin = t[a] - _deviation(t[a:b], t_s)[0]
        first = int(np.ceil((t[a] - origin) / t_s - 1e-9))
        last = int(np.floor((t[b - 1] - origin) / t_s + 1e-9))
        grids.append(origin + t_s * np.arange(first, last + 1))
    out: dict[str, FloatArray] = {}
    for key, values in arrays.items():
        parts = []
        for (a, b), grid in zip(pieces, grids, strict=True):
            v = np.unwrap(values[a:b]) if key == "psi" else values[a:b]
            parts.append(np.interp(grid, t[a:b], v))
        out[key] = np.concatenate(parts)
    bounds = np.concatenate([[0], np.cumsum([g.size for g in grids])])
    return out, tuple((int(bounds[i]), int(bounds[i + 1])) for i in range(len(grids)))


def _circumference(circumference_m: float | None,
                   metadata: Mapping[str, Any] | None) -> tuple[float, bool]:
    """The wheel circumference the rates are judged with, and whether it was stated (else a
    car's)."""
    if circumference_m is None:
        datasheet = (metadata or {}).get("datasheet")
        if isinstance(datasheet, Mapping):
            circumference_m = datasheet.get("c_e")
    if isinstance(circumference_m, int | float) and not isinstance(circumference_m, bool) \
            and np.isfinite(circumference_m) and circumference_m > 0:
        return float(circumference_m), True
    return _CAR_CIRCUMFERENCE_M, False


def _unwrap_pieces(psi: FloatArray, pieces: tuple[tuple[int, int], ...]) -> FloatArray:
    out = np.empty_like(psi)
    for a, b in pieces:
        out[a:b] = np.unwrap(psi[a:b])
    return out


def derivative_pieces(values: FloatArray, t_s: float,
                      pieces: tuple[tuple[int, int], ...]) -> FloatArray:
    """The derivative of ``values`` within each piece (never across a gap; 0 in a piece of
    one sample)."""
    out = np.zeros_like(values)
    for a, b in pieces:
        if b - a >= 2:
            out[a:b] = np.gradient(values[a:b], t_s)
    return out


#: Isolated spikes: a sample this far from both neighbours, whose neighbours agree within a
#: tenth of it, is no physical motion (wheel rates in rev/s, a_y in m/s^2).
_SPIKE_SCALE = {"n_rl": 5.0, "n_rr": 5.0, "a_y": 20.0}
#: Share of a column's samples that may be repaired; beyond it the column is broken.
_MAX_REPAIRED = 0.01
#: Largest magnitudes a car's log can hold (docs/command-line.md, "Input limits").
LIMITS = {"a_y": (30.0, "m/s^2"), "beta": (0.8, "rad"), "x": (1e7, "m"), "y": (1e7, "m"),
          "steer": (15.0, "rad")}    # lock to lock is under 3 turns (in degrees: 860)


def _repair_spikes(name: str, key: str, arr: FloatArray, scale: float,
                   pieces: tuple[tuple[int, int], ...]) -> tuple[FloatArray, int]:
    """Isolated one-sample spikes replaced by the mean of their neighbours (counted)."""
    prev, nxt = np.roll(arr, 1), np.roll(arr, -1)
    spike = ((np.abs(arr - prev) > scale) & (np.abs(arr - nxt) > scale)
             & (np.abs(prev - nxt) < 0.1 * np.minimum(np.abs(arr - prev), np.abs(arr - nxt))))
    for start, stop in pieces:               # piece ends have one neighbour: left as they are
        spike[start] = spike[stop - 1] = False
    count = int(spike.sum())
    if count == 0:
        return arr, 0
    if count > _MAX_REPAIRED * arr.size:
        raise DataError(f"'{name}' column {key} jumps by more than {scale:g} and back in "
                        f"{count} samples ({count / arr.size:.1%}); the log is corrupt or in "
                        "another unit")
    fixed = arr.copy()
    fixed[spike] = 0.5 * (prev[spike] + nxt[spike])
    return fixed, count


#: A wheel turning slower than this (rev/s) is at rest (0.2 m/s on a car's 2 m wheel): its
#: pose's steps are noise, not distance.
RESTING_REVPS = 0.1


def check_time_precision(name: str, t: FloatArray) -> None:
    """A DataError where stamps repeat because they lost their precision: times of the epoch
    (1.7e9 s) kept as 32-bit floats step by 128 s, so most stamps of a log share a value."""
    finite = t[np.isfinite(t)]
    if finite.size < 2:
        return
    peak = float(np.max(np.abs(finite)))
    as32 = finite.astype(np.float32)
    spacing = float(np.spacing(np.float32(peak)))
    if np.array_equal(as32.astype(np.float64), finite) and spacing >= 1e-3:
        distinct = int(np.unique(finite).size)
        raise DataError(f"'{name}' column t holds times near {peak:.4g} with 32-bit precision, "
                        f"which steps by {spacing:.4g} s there: {finite.size} stamps take only "
                        f"{distinct} value{'s' if distinct != 1 else ''}. Store t as 64-bit "
                        "floats (or as seconds from the log's start)")


def _check_wheel_bursts(name: str, t: FloatArray, n_rl: FloatArray, n_rr: FloatArray, *,
                        circumference_m: float) -> None:
    """A DataError where a wheel rate, after isolated spikes were repaired, reaches beyond
    2.5 times the fastest plausible (a stretch too short to move the percentiles the unit
    check reads): no wheel turns that fast, whatever the unit of the rest."""
    limit = 2.5 * _MAX_WHEEL_SPEED_MPS / circumference_m
    for key, n in (("n_rl", n_rl), ("n_rr", n_rr)):
        beyond = np.abs(n) > limit
        if beyond.any():
            k = int(np.argmax(beyond))
            kmh = 2.5 * _MAX_WHEEL_SPEED_MPS * 3.6
            raise DataError(f"'{name}' column {key} reaches {float(np.max(np.abs(n))):.4g} "
                            f"rev/s (first at t={t[k]:.3f} s, row {k + 1}; {int(beyond.sum())} "
                            f"samples beyond {limit:.3g} rev/s, {kmh:.0f} km/h on a "
                            f"{circumference_m:g} m wheel): a corrupt stretch of the log, or "
                            "wheel rates in another unit than rev/s")


#: A reference whose position stays the same on this share of the steps in which the wheels
#: turn is held between updates of a slower source.
_HELD_SHARE = 0.5


def _check_held_reference(name: str, arrays: Mapping[str, FloatArray],
                          pieces: tuple[tuple[int, int], ...]) -> None:
    """A DataError where the reference position repeats while the wheels turn: a slower
    source (a 1 Hz GNSS) held between its updates, whose steps then look like jumps."""
    x, y, t = arrays["x"], arrays["y"], arrays["t"]
    turning = held = changed = 0
    updates: list[float] = []
    for a, b in pieces:
        moving = 0.5 * np.abs(arrays["n_rl"][a:b - 1] + arrays["n_rr"][a:b - 1]) \
            > 5 * RESTING_REVPS
        same = (np.diff(x[a:b]) == 0.0) & (np.diff(y[a:b]) == 0.0)
        turning += int(moving.sum())
        held += int((same & moving).sum())
        changes = np.flatnonzero(~same & moving)
        changed += int(changes.size)
        if changes.size > 1:
            updates.append(float(np.median(np.diff(t[a:b][changes]))))
    if turning < 100 or held < _HELD_SHARE * turning or changed < 10:
        return                       # (a reference that never moves is not held: it is dead)
    period = float(np.median(updates)) if updates else float("nan")
    rate = f" (it changes every {period:.3g} s, {1.0 / period:.3g} Hz)" if period > 0 else ""
    raise DataError(f"'{name}' columns x, y stay the same on {held / turning:.0%} of the steps "
                    f"in which the wheels turn{rate}: the reference is held between the updates "
                    "of a slower source, and its steps would look like jumps. Interpolate it "
                    "between its updates (odocal convert does, from the raw streams)")


def _psi_too_fast(name: str, psi: FloatArray, yaw: FloatArray, t_s: float) -> None:
    """The DataError for a heading (unwrapped) that turns faster than any vehicle: degrees
    where it also turns that fast over whole seconds (a scale), else a heading in radians that
    is noisy or jumps (fast from sample to sample, not over a second)."""
    per_sample = float(np.percentile(np.abs(yaw), 99)) * t_s
    step = max(round(1.0 / t_s), 1)
    if psi.size > 2 * step:
        per_second = float(np.percentile(np.abs(psi[step:] - psi[:-step]), 99))
    else:                                   # (under two seconds: end to end)
        per_second = abs(float(psi[-1] - psi[0])) / max((psi.size - 1) * t_s, t_s)
    if per_second > _MAX_YAW_RATE_RADPS:
        raise DataError(f"'{name}' column psi changes by up to {per_sample:.3g} per sample and "
                        f"{per_second:.3g} per second: psi must be in radians (is it in "
                        "degrees?)")
    raise DataError(f"'{name}' column psi changes by up to {per_sample:.3g} rad per sample "
                    f"({per_sample / t_s:.3g} rad/s at the 99th percentile, though only "
                    f"{per_second:.3g} rad over a second: radians, not degrees; no vehicle turns "
                    f"faster than {_MAX_YAW_RATE_RADPS:g} rad/s): the heading is noisy or "
                    "jumps; smooth it, or check which column it is")


def _refuse_or_leave_out(said: str, key: str, arrays: dict[str, FloatArray],
                         left_out: list[str]) -> None:
    """A column that cannot be used: a DataError saying why, or, for a further input (a front
    wheel, the steering) only a model beyond the rear axle reads, left out whole with the same
    words in ``left_out`` (as a bag's: that model then says what it lacks)."""
    if key not in MODEL_INPUTS:
        raise DataError(said)
    left_out.append(f"{said}: left out (an input only the four_wheel model reads)")
    del arrays[key]


def _check_limits(name: str, arrays: dict[str, FloatArray], left_out: list[str]) -> None:
    """A column beyond any car's values is an error; a further input (the steering) is left out
    instead (``left_out`` says so; only a model beyond the rear axle reads it)."""
    for key, (limit, unit) in LIMITS.items():
        if key not in arrays:
            continue
        peak = float(np.nanmax(np.abs(arrays[key])))
        if peak > limit:
            _refuse_or_leave_out(f"'{name}' column {key} reaches {peak:.4g} {unit}, beyond "
                                 f"any car (limit {limit:g} {unit}); check its unit and the "
                                 "log", key, arrays, left_out)


def _check_wheel_units(name: str, n_rl: FloatArray, n_rr: FloatArray, *,
                       circumference_m: float = _CAR_CIRCUMFERENCE_M, stated: bool = False,
                       percentile: float = 99.0, key: str | None = None) -> None:
    """Wheel rates no wheel of ``circumference_m`` reaches below 288 km/h are another unit
    (``key``: one other wheel's column, given as both)."""
    limit = _MAX_WHEEL_SPEED_MPS / circumference_m
    columns = (("n_rl", n_rl), ("n_rr", n_rr)) if key is None else ((key, n_rl),)
    for key, n in columns:
        finite = np.abs(n[np.isfinite(n)])
        if finite.size == 0:
            continue
        peak = float(np.percentile(finite, percentile))
        if peak > limit:
            speed = ("; or wheel speeds in km/h (or m/s, mph), not rates: a mapping's "
                     "unit = \"km/h\" turns them into rates")
            if peak <= 2 * np.pi * limit:
                hint = f" (it looks like rad/s: divide by 2 pi{speed}; or rpm: divide by 60)"
            elif peak < 60 * limit:
                hint = " (it looks like rpm: divide by 60)"
            else:
                hint = ""
            wheel = (f"a wheel of {circumference_m:g} m (the stated c_e) turns at most "
                     f"{limit:.3g} rev/s" if stated else
                     f"a car's wheel turns at most {limit:.3g} rev/s; a smaller wheel: state "
                     "its circumference, --datasheet c_e=..")
            raise DataError(f"'{name}' column {key} reaches {peak:.4g}: wheel rates must be in "
                            f"rev/s{hint}; {wheel}")


def _check_position_units(name: str, x: FloatArray, y: FloatArray, n_rl: FloatArray,
                          n_rr: FloatArray, t_s: float, pieces: tuple[tuple[int, int], ...], *,
                          circumference_m: float = _CAR_CIRCUMFERENCE_M) -> None:
    """Positions must move roughly as far as the wheels say (within a factor of ten of a wheel
    of ``circumference_m``)."""
    ref_dist = 0.0
    wheel_rev = 0.0
    for a, b in pieces:
        ref_dist += float(np.hypot(np.diff(x[a:b]), np.diff(y[a:b])).sum())
        wheel_rev += float((0.5 * np.abs(n_rl[a:b - 1] + n_rr[a:b - 1])).sum() * t_s)
    if wheel_rev < 20.0:  # too little motion to judge (a stand-still log)
        return
    metres_per_rev = ref_dist / wheel_rev
    if not 0.1 * circumference_m <= metres_per_rev <= 10.0 * circumference_m:
        raise DataError(f"'{name}' columns x, y move {ref_dist:.4g} while the wheels turn "
                        f"{wheel_rev:.4g} revolutions ({metres_per_rev:.3g} per revolution): "
                        "x and y must be metres in a local planar frame (not degrees or km)")
