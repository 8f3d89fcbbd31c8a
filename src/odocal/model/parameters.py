"""The parameters and inputs of the wheel-odometry model (METHOD 1), as plain data.

``theta = [c_e, c_d, t_r, d]`` (m, m, m, m per m/s^2) and the inputs ``u_k = [n_rl, n_rr, beta,
a_y]`` (rev/s, rev/s, rad, m/s^2). Light: numpy only, no compiled code.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from odocal.model.layout import REAR_AXLE

FloatArray = NDArray[np.float64]

#: Names, units and labels of theta, in order, and how each is best displayed (scale and
#: unit: c_d and d read best in mm): the rear-axle model's layout (:mod:`.layout`).
PARAMETER_NAMES: tuple[str, ...] = REAR_AXLE.names
PARAMETER_UNITS: tuple[str, ...] = REAR_AXLE.units
PARAMETER_LABELS: tuple[str, ...] = REAR_AXLE.labels
PARAMETER_DISPLAY: dict[str, tuple[float, str]] = REAR_AXLE.display
STATES, WHEELS, PARAMETERS = 3, 2, REAR_AXLE.size


@dataclass(frozen=True)
class Parameters:
    """The odometry parameters ``theta = [c_e, c_d, t_r, d]``.

    c_e : effective wheel circumference, m
    c_d : left-right circumference difference (left minus right), m
    t_r : rear track width, m
    d   : load-transfer coefficient, m per m/s^2 of lateral acceleration
    """

    c_e: float
    c_d: float
    t_r: float
    d: float

    def as_array(self) -> FloatArray:
        return np.array([getattr(self, n) for n in REAR_AXLE.names], dtype=np.float64)

    @classmethod
    def from_array(cls, theta: FloatArray | tuple[float, ...] | list[float]) -> Parameters:
        values = np.asarray(theta, dtype=np.float64).reshape(REAR_AXLE.size)
        return cls(**REAR_AXLE.named(values.tolist()))

    def as_dict(self) -> dict[str, float]:
        return dict(zip(PARAMETER_NAMES, self.as_array().tolist(), strict=True))


@dataclass(frozen=True)
class Inputs:
    """Model inputs of one or many segments, each array of shape ``(..., K)``.

    n_rl, n_rr : wheel rotation rates, rev/s
    beta : sideslip angle, rad
    a_y : lateral acceleration, m/s^2
    """

    n_rl: FloatArray
    n_rr: FloatArray
    beta: FloatArray
    a_y: FloatArray

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(self.n_rl.shape)

    def with_wheel_rates(self, n_rl: FloatArray, n_rr: FloatArray) -> Inputs:
        return Inputs(n_rl=n_rl, n_rr=n_rr, beta=self.beta, a_y=self.a_y)
