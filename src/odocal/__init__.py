"""odocal: calibrate a vehicle's wheel-odometry model from logged drives.

Implements Fazekas, Gáspár and Németh, "Wheel Odometry Model Calibration with Input Compensation
by Optimal Control" (IFAC PapersOnLine 55-24, 2022): Gauss-Newton identification, input
compensation by a QP, and the three-step calibration architecture; plus a joint
errors-in-variables estimator.

The public API::

    import odocal
    sim = odocal.simulate(duration_s=1800, seed=1)
    result = odocal.calibrate(sim.drive)               # or calibrate(["drive.csv", ...])
    print(result.theta, result.validation.mean_error_m)
"""

__version__ = "0.1.0"

import logging as _logging

from odocal.calibrate import CalibrationResult, calibrate
from odocal.calibrate import validate_theta as validate
from odocal.convert import convert, inspect
from odocal.drive import Drive
from odocal.errors import (
    ConfigError,
    DataError,
    InputFileError,
    MissingDependencyError,
    OdocalError,
    OutputError,
    SolverError,
)
from odocal.io import load_drive, save_drive
from odocal.model import Parameters
from odocal.settings import Settings, load_settings
from odocal.simulate import NOISE_PROFILES, TRUE_PARAMETERS, SimulatedDrive, simulate

# A library stays quiet unless the application configures logging (the CLI does).
_logging.getLogger("odocal").addHandler(_logging.NullHandler())

__all__ = [
    "NOISE_PROFILES",
    "TRUE_PARAMETERS",
    "CalibrationResult",
    "ConfigError",
    "DataError",
    "Drive",
    "InputFileError",
    "MissingDependencyError",
    "OdocalError",
    "OutputError",
    "Parameters",
    "Settings",
    "SimulatedDrive",
    "SolverError",
    "__version__",
    "calibrate",
    "convert",
    "inspect",
    "load_drive",
    "load_settings",
    "save_drive",
    "simulate",
    "validate",
]
