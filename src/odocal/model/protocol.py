"""What a vehicle model is to the rest of odocal: :class:`VehicleModel`.

A model is one value (``odocal.model.registry.model(name)``) that carries its parameters (the
layout, with the roles a model may or may not have), its inputs (the drive's wheel columns),
its equations (the step, the step run backwards, the window prediction with its Jacobian)
and what the exporters need (the wheels' geometry). Code outside :mod:`odocal.model` takes
them from the model it is given, and writes no equation of a vehicle itself.
"""

from __future__ import annotations

import types
from typing import Protocol, runtime_checkable

from odocal.arrays import FloatArray
from odocal.model.layout import Layout


@runtime_checkable
class VehicleModel(Protocol):
    """A vehicle model (the rear axle of METHOD 1 is :class:`odocal.model.vehicle.RearAxleModel`).

    name : the registry's name (``[vehicle] model``, calibration.json's ``"model"``)
    layout : the parameters, in order, with their roles
    step : the model step, its derivatives and the step run backwards, for numpy and numba
    states : the pose's size
    wheels, wheel_inputs : how many wheel rates the model takes, and their drive columns
    """

    name: str
    layout: Layout
    step: types.ModuleType
    states: int
    wheels: int
    wheel_inputs: tuple[str, ...]

    def circumferences(self, theta: FloatArray,
                       a_y: FloatArray | float = 0.0) -> FloatArray:
        """Each wheel's rolling circumference (..., wheels), m."""

    def body_map(self, theta: FloatArray) -> tuple[FloatArray, FloatArray]:
        """``[v, w] = (M0 + a_y M1) @ rates``: the two (2, wheels) matrices."""

    def body_rates(self, theta: FloatArray, rates: FloatArray,
                   a_y: FloatArray | float) -> tuple[FloatArray, FloatArray]:
        """The body's speed (m/s) and yaw rate (rad/s) from the wheel rates (..., wheels)."""

    def wheel_rates(self, theta: FloatArray, v: FloatArray | float, w: FloatArray | float,
                    a_y: FloatArray | float) -> FloatArray:
        """The wheel rates (..., wheels), rev/s, of a speed and a yaw rate."""

    @property
    def channel_map(self) -> FloatArray:
        """The error model's channels of the wheels' revolutions (channels, wheels)."""

    def channel_gains(self, theta: FloatArray) -> FloatArray:
        """The body's travel (m) and yaw (rad) per revolution of each channel (channels,)."""

    def wheel_changes(self, change: FloatArray) -> FloatArray:
        """Each wheel's circumference change (wheels,) of a change of theta."""

    def with_wheel_scaled(self, theta: FloatArray, wheel: int, factor: float) -> FloatArray:
        """theta with one wheel's circumference scaled, the others' unchanged."""

    def geometry(self, theta: FloatArray) -> dict[str, float]:
        """What the exporters need (wheel radii, separation), by name."""

    def inverse_step(self, theta: FloatArray, ds: FloatArray, dpsi: FloatArray,
                     a_y: FloatArray) -> tuple[FloatArray, FloatArray]:
        """The revolutions (M, wheels) a step's motion implies and their Jacobian."""

    def predict(self, theta: FloatArray, moments: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Each window's revolutions (N, wheels) and their Jacobian (N, wheels, n)."""

    def along_gain(self, theta: FloatArray) -> FloatArray:
        """Each wheel's revolutions per metre of the body's own travel (wheels,)."""

    def load_transfer_column(self, theta: FloatArray, moments: FloatArray) -> FloatArray:
        """The windows' revolutions' derivative in the load transfer (N, wheels)."""
