"""The parameters and inputs of the wheel-odometry model (METHOD 1), as plain data.

``theta = [c_e, c_d, t_r, d]`` (m, m, m, m per m/s^2) and the inputs ``u_k = [n_rl, n_rr, beta,
a_y]`` (rev/s, rev/s, rad, m/s^2). Light: numpy only, no compiled code.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

#: Names, units and labels of theta, in order.
PARAMETER_NAMES: tuple[str, str, str, str] = ("c_e", "c_d", "t_r", "d")
PARAMETER_UNITS: tuple[str, str, str, str] = ("m", "m", "m", "m/(m/s^2)")
PARAMETER_LABELS: tuple[str, str, str, str] = (
    "effective wheel circumference", "left-right circumference difference", "rear track width",
    "load-transfer coefficient")
#: How each parameter is best displayed: scale and unit (c_d and d read best in mm).
PARAMETER_DISPLAY: dict[str, tuple[float, str]] = {
    "c_e": (1.0, "m"), "c_d": (1e3, "mm"), "t_r": (1.0, "m"), "d": (1e3, "mm/(m/s^2)")}
STATES, WHEELS, PARAMETERS = 3, 2, 4


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
        return np.array([self.c_e, self.c_d, self.t_r, self.d], dtype=np.float64)

    @classmethod
    def from_array(cls, theta: FloatArray | tuple[float, ...] | list[float]) -> Parameters:
        values = np.asarray(theta, dtype=np.float64).reshape(4)
        return cls(*(float(v) for v in values))

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
