"""Writing a calibration's results to a folder (calibration.json and its companions).

Every file is written atomically, and no output may land on one of the inputs.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from odocal._version import __version__
from odocal.errors import OutputError
from odocal.io.atomic import write_text
from odocal.io.results import write_json
from odocal.model.parameters import PARAMETER_NAMES, PARAMETER_UNITS
from odocal.pipeline.result import CalibrationResult

CALIBRATION_FILE = "calibration.json"


def write_calibration(result: CalibrationResult, out_dir: str | Path, *,
                      report: dict[str, Any] | None = None) -> Path:
    """Write ``calibration.json`` into ``out_dir`` (with the report's numbers when given)."""
    data = result.to_dict()
    if report is not None:
        data["report"] = report
    return write_json(Path(out_dir) / CALIBRATION_FILE, data)


def export_parameters(result: CalibrationResult, out_dir: str | Path, fmt: str) -> Path:
    """The parameters for a localisation stack: ``yaml`` (a ROS 2 parameter file) or ``json``.

    Both carry theta, its covariance (order c_e, c_d, t_r, d; SI units) and which parameters the
    drive identified; the YAML adds the derived wheel radius.
    """
    est = result.estimate
    theta = est.theta.as_dict()
    cov = est.covariance
    if fmt == "json":
        return write_json(Path(out_dir) / "odometry_parameters.json", {
            "theta": theta, "covariance": cov.tolist(),
            "std": dict(zip(PARAMETER_NAMES, est.std.tolist(), strict=True)),
            "identified": dict(zip(PARAMETER_NAMES, est.identified, strict=True)),
            "units": dict(zip(PARAMETER_NAMES, PARAMETER_UNITS, strict=True)),
            "method": result.method, "odocal_version": __version__})
    if fmt != "yaml":
        raise OutputError(f"unknown export format {fmt!r}; use yaml or json")
    identified = ", ".join("true" if ok else "false" for ok in est.identified)
    lines = [
        f"# Wheel-odometry parameters calibrated by odocal {__version__} "
        f"(method {result.method}).",
        "# Parameters a drive did not identify keep their datasheet values (identified: false).",
        "wheel_odometry:",
        "  ros__parameters:",
        f"    effective_wheel_circumference: {theta['c_e']:.9g}   # c_e, m",
        f"    wheel_radius: {theta['c_e'] / (2 * np.pi):.9g}   # c_e / (2 pi), m",
        f"    circumference_difference: {theta['c_d']:.9g}   # c_d, m, left minus right",
        f"    rear_track_width: {theta['t_r']:.9g}   # t_r, m",
        f"    load_transfer_coefficient: {theta['d']:.9g}   # d, m per m/s^2",
        "    parameter_names: [c_e, c_d, t_r, d]",
        f"    identified: [{identified}]",
        "    # row-major 4x4 covariance in the order of parameter_names, SI units",
        "    covariance: [" + ", ".join(f"{v:.9g}" for v in cov.ravel()) + "]",
    ]
    path = Path(out_dir) / "odometry_parameters.yaml"
    write_text(path, "\n".join(lines) + "\n")
    return path


def export_stack(result: CalibrationResult, out_dir: str | Path, target: str, *,
                 wheel_joints: tuple[str, str] | None = None) -> list[Path]:
    """Parameter files for ``target`` (see :mod:`odocal.output.export`) in ``out_dir/target/``;
    ``wheel_joints`` names the left and right wheel joints (ros2_control)."""
    from odocal.output.export import Calibrated, export, odometry_noise

    est = result.estimate
    calibrated = Calibrated(theta=est.theta, datasheet=est.datasheet,
                            std=tuple(est.std.tolist()),
                            identified=est.identified, method=result.method,
                            noise=odometry_noise(result.drive_data, est.theta),
                            source=", ".join(d.name for d in result.drives),
                            wheel_joints=wheel_joints)
    return export(calibrated, out_dir, [target])


def write_compensated_inputs(result: CalibrationResult, out_dir: str | Path) -> Path | None:
    """Write the compensated wheel rates of every selected segment (``--save-inputs``).

    One row per sample of each segment: segment number, its drive and start, the sample's index
    in the drive, and the measured and compensated rates. None when the method compensated
    nothing.
    """
    import pyarrow as pa
    import pyarrow.parquet as pq

    from odocal.io.atomic import atomic_path

    if result.three_step is None or result.batch is None:
        return None
    comp = result.three_step.compensation
    measured = result.batch.inputs
    segments = result.segments.subset(result.used)
    n, k = comp.n_rl.shape
    offsets = np.arange(k)
    table = pa.table({
        "segment": np.repeat(np.arange(n), k),
        "drive": np.repeat([result.drives[int(d)].name for d in segments.drive], k),
        "index": (segments.start[:, None] + offsets[None, :]).ravel(),
        "n_rl_measured": measured.n_rl.ravel(),
        "n_rr_measured": measured.n_rr.ravel(),
        "n_rl": comp.n_rl.ravel(),
        "n_rr": comp.n_rr.ravel(),
    })
    path = Path(out_dir) / "compensated_inputs.parquet"
    with atomic_path(path) as tmp:
        pq.write_table(table, tmp)
    return path
