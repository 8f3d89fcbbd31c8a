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
from typing import TYPE_CHECKING, Any

from odocal._version import __version__
from odocal.errors import (
    ConfigError,
    DataError,
    InputFileError,
    MissingDependencyError,
    OdocalError,
    OutputError,
    SolverError,
)

if TYPE_CHECKING:
    from odocal.data.drive import Drive
    from odocal.estimators.estimate import Estimate, Identified, NotIdentified, Reason, Status
    from odocal.estimators.validation import reachable_minimum
    from odocal.io import load_drive, save_drive
    from odocal.model.parameters import Parameters
    from odocal.online.calibrator import OnlineCalibrator
    from odocal.online.replay import replay
    from odocal.pipeline.calibrate import calibrate, minimum
    from odocal.pipeline.calibrate import validate_theta as validate
    from odocal.pipeline.reproduce import reproduce
    from odocal.pipeline.result import CalibrationResult
    from odocal.preprocess.convert import convert, inspect
    from odocal.settings import Settings, load_settings
    from odocal.sim.noise import NOISE_PROFILES, NoiseProfile
    from odocal.sim.simulate import TRUE_PARAMETERS, SimulatedDrive, simulate

#: public name -> (module, attribute)
_LAZY: dict[str, tuple[str, str]] = {
    "CalibrationResult": ("odocal.pipeline.result", "CalibrationResult"),
    "calibrate": ("odocal.pipeline.calibrate", "calibrate"),
    "validate": ("odocal.pipeline.calibrate", "validate_theta"),
    "convert": ("odocal.preprocess.convert", "convert"),
    "inspect": ("odocal.preprocess.convert", "inspect"),
    "Drive": ("odocal.data.drive", "Drive"),
    "Estimate": ("odocal.estimators.estimate", "Estimate"),
    "Identified": ("odocal.estimators.estimate", "Identified"),
    "NotIdentified": ("odocal.estimators.estimate", "NotIdentified"),
    "Reason": ("odocal.estimators.estimate", "Reason"),
    "Status": ("odocal.estimators.estimate", "Status"),
    "load_drive": ("odocal.io.drivefile", "load_drive"),
    "calibrate_fleet": ("odocal.fleet.engine", "calibrate_fleet"),
    "simulate_fleet": ("odocal.fleet.simulate", "simulate_fleet"),
    "save_drive": ("odocal.io.drivefile", "save_drive"),
    "Parameters": ("odocal.model.parameters", "Parameters"),
    "NOISE_PROFILES": ("odocal.sim.noise", "NOISE_PROFILES"),
    "NoiseProfile": ("odocal.sim.noise", "NoiseProfile"),
    "reproduce": ("odocal.pipeline.reproduce", "reproduce"),
    "OnlineCalibrator": ("odocal.online.calibrator", "OnlineCalibrator"),
    "replay": ("odocal.online.replay", "replay"),
    "Settings": ("odocal.settings", "Settings"),
    "load_settings": ("odocal.settings", "load_settings"),
    "TRUE_PARAMETERS": ("odocal.sim.simulate", "TRUE_PARAMETERS"),
    "SimulatedDrive": ("odocal.sim.simulate", "SimulatedDrive"),
    "simulate": ("odocal.sim.simulate", "simulate"),
    "reachable_minimum": ("odocal.estimators.validation", "reachable_minimum"),
    "minimum": ("odocal.pipeline.calibrate", "minimum"),
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
