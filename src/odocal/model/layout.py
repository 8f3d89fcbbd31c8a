"""The vehicle model's parameters: their names, units, order and roles, in one place.

Pure Python (no numpy): the settings and the command line read it without loading the
numerical stack. Every layer takes the parameter layout from here (through
:data:`odocal.model.MODEL`): which position holds which parameter, what each is for (the
distance scale, the track width, the wheels' difference, the load transfer), which act only
through the wheels' difference and which only in bends. A second vehicle model (a front axle
with steering, four wheels, a skid-steer robot) is a second :class:`Layout` with its step.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class ParameterSpec:
    """One parameter of the model.

    name : as users type it (``--datasheet c_e=...``) and as calibration.json keys it
    unit : SI unit
    label : in words
    display_scale, display_unit : how it reads best (c_d in mm: scale 1e3, unit "mm")
    placeholder : odocal's value where the user states no datasheet (a small car)
    prior_std : the datasheet value's uncertainty (``[identify] prior_std``'s default)
    vehicle_range : what a wheeled vehicle's value can be (generous: robots and trucks alike)
    prior_std_max : the largest datasheet uncertainty that still describes a vehicle
    """

    name: str
    unit: str
    label: str
    display_scale: float
    display_unit: str
    placeholder: float
    prior_std: float
    vehicle_range: tuple[float, float] = (float("-inf"), float("inf"))
    prior_std_max: float = float("inf")


@dataclass(frozen=True)
class Layout:
    """The parameters of a vehicle model, in order, with the roles the checks, the gate, the
    estimators and the report need to find them by.

    scale : the distance scale (the wheels' mean: what a speed signal's scale error moves)
    track : the track width (the yaw from the wheels' difference)
    difference : the wheels' own difference (one tyre against the other)
    load : the load transfer with lateral acceleration
    differential : those that act through the wheels' difference only (a drive whose wheels
        carry no differential signal identifies none of them)
    bends : those that act on the yaw rate only in bends (a straight drive identifies none)
    lengths : positive lengths that size the vehicle (their plausible range is the datasheet's,
        times and over a factor)
    """

    parameters: tuple[ParameterSpec, ...]
    scale: str
    track: str
    difference: str
    load: str
    differential: tuple[str, ...]
    bends: tuple[str, ...]
    lengths: tuple[str, ...]

    def __post_init__(self) -> None:
        names = self.names
        for role in (self.scale, self.track, self.difference, self.load, *self.differential,
                     *self.bends, *self.lengths):
            if role not in names:
                raise ValueError(f"layout names {role!r}, which is not one of {names}")

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.parameters)

    @property
    def units(self) -> tuple[str, ...]:
        return tuple(p.unit for p in self.parameters)

    @property
    def labels(self) -> tuple[str, ...]:
        return tuple(p.label for p in self.parameters)

    @property
    def size(self) -> int:
        return len(self.parameters)

    @property
    def display(self) -> dict[str, tuple[float, str]]:
        """Each parameter's display scale and unit, by name."""
        return {p.name: (p.display_scale, p.display_unit) for p in self.parameters}

    @property
    def placeholder(self) -> tuple[float, ...]:
        return tuple(p.placeholder for p in self.parameters)

    @property
    def prior_std(self) -> tuple[float, ...]:
        return tuple(p.prior_std for p in self.parameters)

    def index(self, name: str) -> int:
        """The position of ``name`` in theta."""
        try:
            return self.names.index(name)
        except ValueError as err:
            raise KeyError(f"{name!r} is not a parameter of this model "
                           f"({', '.join(self.names)})") from err

    def indices(self, names: Iterable[str]) -> tuple[int, ...]:
        return tuple(self.index(n) for n in names)

    def mask(self, names: Iterable[str]) -> list[bool]:
        """Which positions of theta hold ``names`` (a list of bools, for numpy to take)."""
        wanted = set(names)
        return [n in wanted for n in self.names]

    def value(self, theta: Sequence[float] | Any, name: str) -> float:
        """``theta``'s value of ``name``."""
        return float(theta[self.index(name)])

    def named(self, theta: Sequence[float]) -> dict[str, float]:
        """``theta`` by name."""
        if len(theta) != self.size:
            raise ValueError(f"theta has {len(theta)} values, the model {self.size} "
                             f"({', '.join(self.names)})")
        return {n: float(v) for n, v in zip(self.names, theta, strict=True)}

    def ordered(self, values: dict[str, float], base: Sequence[float]) -> tuple[float, ...]:
        """theta from named ``values``, the others from ``base``."""
        theta = list(base)
        for name, value in values.items():
            theta[self.index(name)] = float(value)
        return tuple(theta)


#: The rear axle of METHOD 1: ``theta = [c_e, c_d, t_r, d]`` (m, m, m, m per m/s^2), with the
#: rear wheels' rates, the lateral acceleration and the sideslip as inputs.
REAR_AXLE = Layout(
    parameters=(
        ParameterSpec("c_e", "m", "effective wheel circumference", 1.0, "m", 2.0, 0.05,
                      (0.05, 50.0), 50.0),
        ParameterSpec("c_d", "m", "left-right circumference difference", 1e3, "mm", 0.0,
                      0.01, (-50.0, 50.0), 50.0),
        ParameterSpec("t_r", "m", "rear track width", 1.0, "m", 1.6, 0.10, (0.05, 30.0), 30.0),
        ParameterSpec("d", "m/(m/s^2)", "load-transfer coefficient", 1e3, "mm/(m/s^2)", 0.0,
                      0.005, (-1.0, 1.0), 1.0),
    ),
    scale="c_e", track="t_r", difference="c_d", load="d",
    differential=("c_d", "t_r", "d"), bends=("t_r", "d"), lengths=("c_e", "t_r"))

#: ``theta = [c_e, c_d, t_r, d, c_f, c_fd, t_f, L, ratio, s_0]``: the rear axle's four, then
#: the front axle's mean circumference, difference and track, the wheelbase, and the steering's
#: ratio and offset.
FOUR_WHEEL = Layout(
    parameters=(
        *REAR_AXLE.parameters,
        ParameterSpec("c_f", "m", "front effective wheel circumference", 1.0, "m", 2.0, 0.05,
                      (0.05, 50.0), 50.0),
        ParameterSpec("c_fd", "m", "front left-right circumference difference", 1e3, "mm",
                      0.0, 0.01, (-50.0, 50.0), 50.0),
        ParameterSpec("t_f", "m", "front track width", 1.0, "m", 1.6, 0.10, (0.05, 30.0),
                      30.0),
        ParameterSpec("L", "m", "wheelbase", 1.0, "m", 2.7, 0.2, (0.1, 30.0), 30.0),
        ParameterSpec("ratio", "1", "steering ratio (steering-wheel over road-wheel angle)",
                      1.0, "", 15.0, 3.0, (0.5, 40.0), 40.0),
        ParameterSpec("s_0", "rad", "steering-wheel angle offset", 57.29577951308232, "deg",
                      0.0, 0.05, (-1.0, 1.0), 1.0),
    ),
    scale="c_e", track="t_r", difference="c_d", load="d",
    differential=("c_d", "t_r", "d", "c_fd", "t_f"), bends=("t_r", "d", "t_f", "L", "ratio"),
    lengths=("c_e", "t_r", "c_f", "t_f", "L"))
