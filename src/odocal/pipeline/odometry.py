"""What the calibrated wheels make of the drives: the odometry dead-reckoned from the reference
pose, and its noise against the reference motion. Part of a calibration's result
(:class:`~odocal.pipeline.result.CalibrationResult`); the output layer writes them (TUM files,
the exports' covariances)."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np

from odocal.arrays import FloatArray
from odocal.data.drive import Drive
from odocal.model.kinematics import inverse_revolutions, motion_increments, rollout
from odocal.model.parameters import Inputs, Parameters
from odocal.model.vehicle import MODEL


@dataclass(frozen=True)
class OdometryNoise:
    """How far the calibrated wheel odometry is from the reference motion, averaged over
    ``window_s`` (1 s where measured against the reference by :func:`odometry_noise`)."""

    speed_std_mps: float
    yaw_rate_std_radps: float
    windows: int
    window_s: float = 1.0


def odometry_noise(drives: Sequence[Drive], theta: Parameters,
                   window_s: float = 1.0) -> OdometryNoise | None:
    """Robust standard deviation of the wheel speed and yaw rate against the reference's."""
    speed_err: list[np.ndarray] = []
    yaw_err: list[np.ndarray] = []
    th = theta.as_array()
    to_body, _ = MODEL.body_map(th)            # a window's revolutions to its speed, yaw
    for d in drives:
        k = max(1, round(window_s / d.t_s))
        for start, stop in d.pieces:
            if stop - start <= k + 1:
                continue
            sl = slice(start, stop)
            ds, dpsi = motion_increments(d.x[sl], d.y[sl], d.psi[sl], d.beta[sl])
            revs, _ = inverse_revolutions(th, ds, dpsi, d.a_y[start:stop - 1])
            measured = np.column_stack([getattr(d, c)[start:stop - 1]
                                        for c in MODEL.wheel_inputs]) * d.t_s
            err = measured - revs
            n = (len(err) // k) * k
            body = err[:n].reshape(-1, k, MODEL.wheels).sum(axis=1) @ to_body.T / (k * d.t_s)
            speed_err.append(body[:, 0])
            yaw_err.append(body[:, 1])
    if not speed_err:
        return None
    sv, sy = np.concatenate(speed_err), np.concatenate(yaw_err)
    if sv.size < 10:
        return None
    mad = 1.4826
    return OdometryNoise(speed_std_mps=float(mad * np.median(np.abs(sv - np.median(sv)))),
                         yaw_rate_std_radps=float(mad * np.median(np.abs(sy - np.median(sy)))),
                         windows=int(sv.size))


@dataclass(frozen=True)
class Trajectories:
    """One drive's poses (N, 3) [x, y, psi]: the reference as logged, and the wheels
    dead-reckoned with the calibrated and with the datasheet parameters."""

    drive: Drive
    reference: FloatArray
    calibrated: FloatArray
    datasheet: FloatArray


def trajectories(drives: Sequence[Drive], theta: Parameters, datasheet: Parameters, *,
                 arm: tuple[float, float] = (0.0, 0.0)) -> Iterator[Trajectories]:
    """Every drive's :class:`Trajectories` (:func:`dead_reckoned` from the reference point
    ``arm``), one drive at a time."""
    for drive in drives:
        yield Trajectories(drive, np.column_stack([drive.x, drive.y, drive.psi]),
                           dead_reckoned(drive, theta, arm), dead_reckoned(drive, datasheet, arm))


def dead_reckoned(drive: Drive, theta: Parameters,
                  arm: tuple[float, float] = (0.0, 0.0)) -> FloatArray:
    """The wheel odometry of ``drive`` with ``theta``: (N, 3) poses [x, y, psi], started at the
    reference pose at the start of every piece, of the reference point ``arm`` (forward, left
    of the rear axle, m: where the reference reports; the model rolls the axle out)."""
    poses = np.empty((drive.n_samples, 3))
    th = theta.as_array()
    forward, left = arm
    for start, stop in drive.pieces:
        sl = slice(start, stop - 1)
        u = Inputs(drive.n_rl[sl], drive.n_rr[sl], drive.beta[sl], drive.a_y[sl])
        psi0 = drive.psi[start]
        x0 = np.array([drive.x[start] - forward * np.cos(psi0) + left * np.sin(psi0),
                       drive.y[start] - forward * np.sin(psi0) - left * np.cos(psi0), psi0])
        poses[start:stop] = rollout(th, u, x0, drive.t_s)
    psi = poses[:, 2]
    poses[:, 0] += forward * np.cos(psi) - left * np.sin(psi)
    poses[:, 1] += forward * np.sin(psi) + left * np.cos(psi)
    return poses


#: Two of a four-wheel log's wheel columns that a mapping may exchange, left and right kept
#: (a left-right swap the front checks name without a fit): the words, and the columns in the
#: order front left, front right, rear left, rear right that the log's are read as.
EXCHANGES: tuple[tuple[str, tuple[int, int, int, int]], ...] = (
    ("front and rear axles", (2, 3, 0, 1)),
    ("front left and rear left wheels", (2, 1, 0, 3)),
    ("front right and rear right wheels", (0, 3, 2, 1)),
)


def exchanged(drive: Drive, order: Sequence[int]) -> Drive:
    """``drive`` with its four wheels' columns (front left, front right, rear left, rear right)
    read in ``order`` (an entry of :data:`EXCHANGES`)."""
    import dataclasses

    rates = [drive.inputs["n_fl"], drive.inputs["n_fr"], drive.n_rl, drive.n_rr]
    fl, fr, rl, rr = (rates[k] for k in order)
    return dataclasses.replace(drive, n_rl=rl, n_rr=rr,
                               inputs={**drive.inputs, "n_fl": fl, "n_fr": fr})


def on_four_wheels(drives: Sequence[Drive], theta: Parameters,
                   std: Sequence[float] | FloatArray) -> list[Drive]:
    """The drives with their rear wheels' rates replaced by those that dead-reckon, through
    the rear axle of the four-wheel ``theta``, the speed and yaw rate all four wheels give
    (:meth:`~odocal.model.four_wheel.FourWheelModel.body_rates`, each axle weighted by ``std``,
    an axle whose scale is not known left out): the rear axle's validation then judges the
    four-wheel odometry unchanged. A drive without front wheels is refused in one line."""
    import dataclasses

    from odocal.errors import DataError
    from odocal.model.four_wheel import FOUR_WHEEL_MODEL

    th = theta.as_array()
    rear = FOUR_WHEEL_MODEL.rear_axle(th)
    out = []
    for d in drives:
        if "n_fl" not in d.inputs or "n_fr" not in d.inputs:
            from odocal.estimators.front_axle import require_front_wheels

            require_front_wheels([d])             # a column the reader left out: says why
            raise DataError(f"{d.name!r} has no front wheels' rates (n_fl, n_fr): the "
                            "four_wheel model's odometry needs all four")
        rates = np.column_stack([d.inputs["n_fl"], d.inputs["n_fr"], d.n_rl, d.n_rr])
        v, w = FOUR_WHEEL_MODEL.body_rates(th, rates, d.a_y, std=np.asarray(std, dtype=float))
        virtual = MODEL.wheel_rates(rear, v, w, d.a_y)
        out.append(dataclasses.replace(d, n_rl=virtual[:, 0], n_rr=virtual[:, 1]))
    return out

