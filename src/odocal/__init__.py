"""odocal: calibrate a vehicle's wheel-odometry model from logged drives.

Implements Fazekas, Gáspár and Németh, "Wheel Odometry Model Calibration with Input Compensation
by Optimal Control" (IFAC PapersOnLine 55-24, 2022): Gauss-Newton identification, input
compensation by a QP, and the three-step calibration architecture; plus an
errors-in-variables estimator (the default).

The public API::

    import odocal
    sim = odocal.simulate(duration_s=1800, seed=1)
    result = odocal.calibrate(sim.drive)               # or calibrate(["drive.csv", ...])
    print(result.theta, result.validation.mean_error_m)

The names below are loaded on first use, so that ``import odocal`` (and ``odocal --help``) stays
fast; numpy, scipy and numba are imported by the parts that compute.
"""

from __future__ import annotations

import importlib
import logging as _logging
import sys
import types
from typing import TYPE_CHECKING, Any

from odocal.errors import (
    ConfigError,
    DataError,
    InputFileError,
    MissingDependencyError,
    OdocalError,
    OutputError,
    SolverError,
)

__version__ = "0.1.0"

if TYPE_CHECKING:
    from odocal.calibrate import CalibrationResult, calibrate, minimum
    from odocal.calibrate import validate_theta as validate
    from odocal.convert import convert, inspect
    from odocal.drive import Drive
    from odocal.estimate import Estimate, Identified, NotIdentified, Reason, Status
    from odocal.io import load_drive, save_drive
    from odocal.model import Parameters
    from odocal.noise import NOISE_PROFILES, NoiseProfile
    from odocal.online import OnlineCalibrator
    from odocal.replay import replay
    from odocal.reproduce import reproduce
    from odocal.settings import Settings, load_settings
    from odocal.simulate import TRUE_PARAMETERS, SimulatedDrive, simulate
    from odocal.validate import reachable_minimum

#: public name -> (module, attribute)
_LAZY: dict[str, tuple[str, str]] = {
    "CalibrationResult": ("odocal.calibrate", "CalibrationResult"),
    "calibrate": ("odocal.calibrate", "calibrate"),
    "validate": ("odocal.calibrate", "validate_theta"),
    "convert": ("odocal.convert", "convert"),
    "inspect": ("odocal.convert", "inspect"),
    "Drive": ("odocal.drive", "Drive"),
    "Estimate": ("odocal.estimate", "Estimate"),
    "Identified": ("odocal.estimate", "Identified"),
    "NotIdentified": ("odocal.estimate", "NotIdentified"),
    "Reason": ("odocal.estimate", "Reason"),
    "Status": ("odocal.estimate", "Status"),
    "load_drive": ("odocal.io.drivefile", "load_drive"),
    "calibrate_fleet": ("odocal.fleet.engine", "calibrate_fleet"),
    "simulate_fleet": ("odocal.fleet.simulate", "simulate_fleet"),
    "save_drive": ("odocal.io.drivefile", "save_drive"),
    "Parameters": ("odocal.model", "Parameters"),
    "NOISE_PROFILES": ("odocal.noise", "NOISE_PROFILES"),
    "NoiseProfile": ("odocal.noise", "NoiseProfile"),
    "reproduce": ("odocal.reproduce", "reproduce"),
    "OnlineCalibrator": ("odocal.online", "OnlineCalibrator"),
    "replay": ("odocal.replay", "replay"),
    "Settings": ("odocal.settings", "Settings"),
    "load_settings": ("odocal.settings", "load_settings"),
    "TRUE_PARAMETERS": ("odocal.simulate", "TRUE_PARAMETERS"),
    "SimulatedDrive": ("odocal.simulate", "SimulatedDrive"),
    "simulate": ("odocal.simulate", "simulate"),
    "reachable_minimum": ("odocal.validate", "reachable_minimum"),
    "minimum": ("odocal.calibrate", "minimum"),
}


def __getattr__(name: str) -> Any:
    target = _LAZY.get(name)
    if target is None:
        raise AttributeError(f"module 'odocal' has no attribute {name!r}")
    value = getattr(importlib.import_module(target[0]), target[1])
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted([*globals(), *_LAZY])


class _Package(types.ModuleType):
    """The package module: ``odocal.calibrate`` and its likes name the functions.

    Importing a submodule sets it as an attribute of its package; where a public function has
    its module's name (calibrate, simulate, convert, reproduce, validate), the function keeps the
    name, as it would with eager ``from odocal.calibrate import calibrate`` imports.
    """

    def __setattr__(self, name: str, value: Any) -> None:
        if isinstance(value, types.ModuleType) and name in _LAZY:
            return
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package


# A library stays quiet unless the application configures logging (the CLI does).
_logging.getLogger("odocal").addHandler(_logging.NullHandler())

__all__ = [
    "NOISE_PROFILES",
    "TRUE_PARAMETERS",
    "CalibrationResult",
    "ConfigError",
    "DataError",
    "Drive",
    "Estimate",
    "Identified",
    "InputFileError",
    "MissingDependencyError",
    "NoiseProfile",
    "NotIdentified",
    "OdocalError",
    "OnlineCalibrator",
    "OutputError",
    "Parameters",
    "Reason",
    "Settings",
    "SimulatedDrive",
    "SolverError",
    "Status",
    "__version__",
    "calibrate",
    "calibrate_fleet",
    "convert",
    "inspect",
    "load_drive",
    "load_settings",
    "minimum",
    "reachable_minimum",
    "replay",
    "reproduce",
    "save_drive",
    "simulate",
    "simulate_fleet",
    "validate",
]
