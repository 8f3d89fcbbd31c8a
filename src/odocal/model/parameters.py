"""The parameters and inputs of the wheel-odometry model (METHOD 1), as plain data.

``theta = [c_e, c_d, t_r, d]`` (m, m, m, m per m/s^2) and the inputs ``u_k = [n_rl, n_rr, beta,
a_y]`` (rev/s, rev/s, rad, m/s^2). Light: numpy only, no compiled code.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from odocal.arrays import FloatArray
from odocal.model.layout import FOUR_WHEEL, REAR_AXLE, Layout

#: Names, units and labels of theta, in order, and how each is best displayed (scale and
#: unit: c_d and d read best in mm): the rear-axle model's layout (:mod:`.layout`).
PARAMETER_NAMES: tuple[str, ...] = REAR_AXLE.names
PARAMETER_UNITS: tuple[str, ...] = REAR_AXLE.units
PARAMETER_LABELS: tuple[str, ...] = REAR_AXLE.labels
PARAMETER_DISPLAY: dict[str, tuple[float, str]] = {**FOUR_WHEEL.display, **REAR_AXLE.display}
STATES, WHEELS, PARAMETERS = 3, 2, REAR_AXLE.size


class Parameters:
    """A vehicle model's parameters, by name and in its layout's order (immutable).

    For the rear axle (the default layout) ``theta = [c_e, c_d, t_r, d]``:

    c_e : effective wheel circumference, m
    c_d : left-right circumference difference (left minus right), m
    t_r : rear track width, m
    d   : load-transfer coefficient, m per m/s^2 of lateral acceleration

    ``Parameters(1.95, 0.0, 1.5, 0.0)`` and ``Parameters(c_e=1.95, c_d=0.0, t_r=1.5, d=0.0)``
    are alike; another model's are built with ``layout=`` and read by its names
    (``theta.c_e``, ``theta.as_dict()``).
    """

    __slots__ = ("_layout", "_values")
    _layout: Layout
    _values: tuple[float, ...]

    def __init__(self, *values: float, layout: Layout = REAR_AXLE, **named: float) -> None:
        names = layout.names
        if len(values) > len(names):
            raise TypeError(f"{len(values)} values where the model has {len(names)} "
                            f"({', '.join(names)})")
        given = dict(zip(names, values, strict=False))
        for name, value in named.items():
            if name not in names:
                raise TypeError(f"{name!r} is not a parameter of this model ({', '.join(names)})")
            if name in given:
                raise TypeError(f"{name!r} given twice")
            given[name] = value
        missing = [n for n in names if n not in given]
        if missing:
            raise TypeError(f"missing {', '.join(missing)} (the model has {', '.join(names)})")
        object.__setattr__(self, "_layout", layout)
        object.__setattr__(self, "_values", tuple(float(given[n]) for n in names))

    @property
    def layout(self) -> Layout:
        """The model's parameter layout these values are in."""
        return self._layout

    def __getattr__(self, name: str) -> float:
        if not name.startswith("_"):
            layout = object.__getattribute__(self, "_layout")
            if name in layout.names:
                values: tuple[float, ...] = object.__getattribute__(self, "_values")
                return values[layout.names.index(name)]
        raise AttributeError(f"{type(self).__name__!r} has no attribute {name!r}")

    def __setattr__(self, name: str, value: object) -> None:
        raise AttributeError(f"Parameters are immutable: cannot set {name!r}")

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Parameters):
            return NotImplemented
        return self._layout == other._layout and self._values == other._values

    def __hash__(self) -> int:
        return hash((self._layout.names, self._values))

    def __repr__(self) -> str:
        named = ", ".join(f"{n}={v!r}" for n, v in zip(self._layout.names, self._values,
                                                        strict=True))
        return f"Parameters({named})"

    def __reduce__(self) -> tuple[object, ...]:
        return (_rebuild, (self._values, self._layout))

    def as_array(self) -> FloatArray:
        return np.array(self._values, dtype=np.float64)

    @classmethod
    def from_array(cls, theta: FloatArray | tuple[float, ...] | list[float], *,
                   layout: Layout = REAR_AXLE) -> Parameters:
        values = np.asarray(theta, dtype=np.float64).reshape(layout.size)
        return cls(*values.tolist(), layout=layout)

    def as_dict(self) -> dict[str, float]:
        return dict(zip(self._layout.names, self._values, strict=True))

    def replace(self, **named: float) -> Parameters:
        """A copy with the ``named`` values changed."""
        return Parameters(layout=self._layout, **{**self.as_dict(), **named})


def _rebuild(values: tuple[float, ...], layout: Layout) -> Parameters:
    return Parameters(*values, layout=layout)


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
