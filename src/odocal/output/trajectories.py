"""Trajectories for evo (``--export tum``): the reference pose and the wheels dead-reckoned.

Three files per input log, in the TUM format evo reads (``timestamp tx ty tz qx qy qz qw``,
one pose per line; the timestamp in seconds of the log's own clock, the pose in the drive's
metric frame, z = 0, the quaternion a rotation about z by the heading):

``reference.tum``
    the reference pose the calibration used (localisation or GNSS/IMU);
``odometry.tum``
    the wheel odometry with the calibrated parameters;
``odometry_datasheet.tum``
    the wheel odometry with the datasheet parameters.

The wheel odometry starts at the reference pose and integrates the model from there; across a
gap in the log (a new piece) it starts again at the reference pose. So
``evo_rpe tum reference.tum odometry.tum --delta 100 --delta_unit m`` measures how far the
odometry drifts per 100 m, and the same against ``odometry_datasheet.tum`` is the calibration's
gain. With one log the files lie in ``trajectories/``; with several, in
``trajectories/<log>/``.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np

from odocal.arrays import FloatArray
from odocal.data.drive import Drive
from odocal.io.atomic import file_name, write_text
from odocal.pipeline.odometry import Trajectories

FOLDER = "trajectories"
FILES = ("reference.tum", "odometry.tum", "odometry_datasheet.tum")


def tum_text(t: FloatArray, poses: FloatArray) -> str:
    """``timestamp x y z qx qy qz qw`` lines for planar poses [x, y, psi]."""
    half = 0.5 * poses[:, 2]
    table = np.column_stack([t, poses[:, 0], poses[:, 1], np.zeros(len(t)), np.zeros(len(t)),
                             np.zeros(len(t)), np.sin(half), np.cos(half)])
    lines = [f"{row[0]:.6f} {row[1]:.6f} {row[2]:.6f} {row[3]:.1f} {row[4]:.1f} {row[5]:.1f} "
             f"{row[6]:.9f} {row[7]:.9f}" for row in table.tolist()]
    return "\n".join(lines) + "\n"


def _folder_names(drives: Sequence[Drive]) -> list[str]:
    """A file-system-safe folder name per drive, unique even where names clean to the same."""
    names: list[str] = []
    for d in drives:
        base = file_name(Path(d.name).name or d.name)
        name, k = base, 2
        while name in names:                 # the same log given twice
            name, k = f"{base}-{k}", k + 1
        names.append(name)
    return names


def write_trajectories(drives: Sequence[Drive], trajectories: Iterable[Trajectories],
                       out_dir: str | Path) -> list[Path]:
    """Write the three TUM files of every drive's trajectories (``drives``' in order, one
    drive at a time: :meth:`odocal.pipeline.result.CalibrationResult.trajectories`) under
    ``out_dir/trajectories``."""
    root = Path(out_dir) / FOLDER
    folders = [root] if len(drives) == 1 else [root / n for n in _folder_names(drives)]
    written: list[Path] = []
    for found, folder in zip(trajectories, folders, strict=True):
        folder.mkdir(parents=True, exist_ok=True)
        for name, poses in zip(FILES, (found.reference, found.calibrated, found.datasheet),
                               strict=True):
            path = folder / name
            write_text(path, tum_text(found.drive.t, poses))
            written.append(path)
    return written
