"""odocal: calibrate a vehicle's wheel-odometry model from logged drives.

Implements Fazekas, Gáspár and Németh, "Wheel Odometry Model Calibration with Input Compensation
by Optimal Control" (IFAC PapersOnLine 55-24, 2022): Gauss-Newton identification, input
compensation by a QP, and the three-step calibration architecture; plus an
errors-in-variables estimator (the default).

The public API::

    import odocal
    sim = odocal.simulate(duration_s=1800, seed=1)
    result = odocal.calibrate(sim.drive)               # or calibrate(["drive.csv", ...])
    result                                             # the table the command line prints
    result.estimate.std["c_e"], result.estimate.identified["t_r"]
    result.save("results/")                            # calibration.json, report.html, ...

Every name in ``__all__`` is documented in the API reference (docs/api).

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
    from odocal.estimators.estimate import (
        ByName,
        CovarianceKind,
        Estimate,
        Flags,
        Identified,
        NotIdentified,
        Reason,
        Status,
    )
    from odocal.estimators.validation import MinimumResult, ValidationResult, reachable_minimum
    from odocal.fleet.engine import FleetRun, calibrate_fleet
    from odocal.fleet.simulate import SimulatedFleet, simulate_fleet
    from odocal.io import load_drive, save_drive
    from odocal.model.parameters import Parameters
    from odocal.online.calibrator import OnlineCalibrator
    from odocal.online.changes import Alarm
    from odocal.online.replay import ReplayResult, replay
    from odocal.output.results import Written
    from odocal.pipeline.calibrate import calibrate, minimum
    from odocal.pipeline.calibrate import validate_theta as validate
    from odocal.pipeline.reproduce import ReproduceResult, reproduce
    from odocal.pipeline.result import CalibrationResult, Comparison, SpeedScale
    from odocal.preprocess.convert import Inspection, convert, inspect
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
    # what the front doors return
    "ByName": ("odocal.estimators.estimate", "ByName"),
    "Flags": ("odocal.estimators.estimate", "Flags"),
    "CovarianceKind": ("odocal.estimators.estimate", "CovarianceKind"),
    "SpeedScale": ("odocal.pipeline.result", "SpeedScale"),
    "Comparison": ("odocal.pipeline.result", "Comparison"),
    "ValidationResult": ("odocal.estimators.validation", "ValidationResult"),
    "MinimumResult": ("odocal.estimators.validation", "MinimumResult"),
    "ReproduceResult": ("odocal.pipeline.reproduce", "ReproduceResult"),
    "ReplayResult": ("odocal.online.replay", "ReplayResult"),
    "Alarm": ("odocal.online.changes", "Alarm"),
    "Inspection": ("odocal.preprocess.convert", "Inspection"),
    "FleetRun": ("odocal.fleet.engine", "FleetRun"),
    "SimulatedFleet": ("odocal.fleet.simulate", "SimulatedFleet"),
    "Written": ("odocal.output.results", "Written"),
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

#: The public names: the errors, the version, and every name loaded on first use
#: (tests/test_api.py holds it to that).
__all__ = [
    "NOISE_PROFILES",
    "TRUE_PARAMETERS",
    "Alarm",
    "ByName",
    "CalibrationResult",
    "Comparison",
    "ConfigError",
    "CovarianceKind",
    "DataError",
    "Drive",
    "Estimate",
    "Flags",
    "FleetRun",
    "Identified",
    "InputFileError",
    "Inspection",
    "MinimumResult",
    "MissingDependencyError",
    "NoiseProfile",
    "NotIdentified",
    "OdocalError",
    "OnlineCalibrator",
    "OutputError",
    "Parameters",
    "Reason",
    "ReplayResult",
    "ReproduceResult",
    "Settings",
    "SimulatedDrive",
    "SimulatedFleet",
    "SolverError",
    "SpeedScale",
    "Status",
    "ValidationResult",
    "Written",
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
