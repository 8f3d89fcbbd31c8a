"""Writing a calibration's results to a folder (calibration.json and its companions).

Every file is written atomically, and no output may land on one of the inputs.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np

from odocal.calibrate import CalibrationResult
from odocal.errors import OutputError
from odocal.io.atomic import refuse_inputs
from odocal.io.results import write_json

CALIBRATION_FILE = "calibration.json"


def prepare_output_dir(out_dir: str | Path, inputs: Iterable[str | Path]) -> Path:
    """Create ``out_dir`` (if needed), refusing a path that is one of the inputs."""
    out = Path(out_dir)
    inputs = list(inputs)
    refuse_inputs(out, inputs)
    refuse_inputs(out / CALIBRATION_FILE, inputs)
    if out.exists() and not out.is_dir():
        raise OutputError(f"output '{out}' exists and is not a folder")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"cannot create the output folder '{out}': {exc.strerror}") from None
    return out


def write_calibration(result: CalibrationResult, out_dir: str | Path) -> Path:
    """Write ``calibration.json`` into ``out_dir``."""
    return write_json(Path(out_dir) / CALIBRATION_FILE, result.to_dict())


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
