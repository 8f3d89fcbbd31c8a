"""Writing a calibration's results to a folder (calibration.json and its companions).

Every file is written atomically, and no output may land on one of the inputs.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from odocal._version import __version__
from odocal.errors import OutputError
from odocal.io.json_files import write_json
from odocal.pipeline.result import CalibrationResult

CALIBRATION_FILE = "calibration.json"
#: What ``--export`` may name: parameter files (yaml, json), the stacks' files, trajectories.
EXPORT_TARGETS = ("yaml", "json", "autoware", "ros2_control", "robot_localization", "ackermann",
                  "tum")


@dataclass(frozen=True)
class Written:
    """What :func:`write_results` wrote (paths relative to the folder) and what it left out,
    in words; ``folder`` is where they are once written (:func:`save_results`)."""

    paths: tuple[Path, ...]
    notes: tuple[str, ...] = ()
    folder: Path | None = None

    @property
    def files(self) -> tuple[Path, ...]:
        """The files written, where they are (``folder / path``)."""
        base = self.folder if self.folder is not None else Path()
        return tuple(base / p for p in self.paths)


def source_files(result: CalibrationResult) -> list[str]:
    """The files a calibration read that exist on this machine (its drives' sources)."""
    sources = [str(d.metadata.get("source", "")) for d in result.drive_data]
    return [s for s in sources if s and Path(s).exists()]


def save_results(result: CalibrationResult, folder: str | Path, *,
                 exports: Sequence[str] = (), report: bool = True, save_inputs: bool = False,
                 wheel_joints: tuple[str, str] | None = None, inputs: Sequence[Any] = (),
                 progress: Callable[[str, int, int], None] | None = None,
                 renderer: Any = None) -> Written:
    """The results folder of ``odocal calibrate --out``, with its rules: built beside
    ``folder`` and swapped in whole when complete (a failure leaves an earlier folder as it
    was); refused, before anything is written, where ``folder`` holds anything odocal did not
    write, or where it is or holds one of the inputs (the result's own drive files and
    ``inputs``). What goes in it: :func:`write_results`."""
    from odocal.io.atomic import check_replaceable, refuse_inputs, results_folder

    out = Path(folder)
    refuse_inputs(out, [*source_files(result), *inputs], folder=True)
    refuse_car_targets(exports, result.model_estimate.model)
    check_replaceable(out)
    with results_folder(out) as tmp:
        written = write_results(result, tmp, exports=exports, report=report,
                                save_inputs=save_inputs, wheel_joints=wheel_joints,
                                progress=progress, renderer=renderer)
    return Written(paths=written.paths, notes=written.notes, folder=out)


def write_results(result: CalibrationResult, out_dir: str | Path, *,
                  exports: Sequence[str] = (), report: bool = True,
                  save_inputs: bool = False, wheel_joints: tuple[str, str] | None = None,
                  progress: Callable[[str, int, int], None] | None = None,
                  renderer: Any = None) -> Written:
    """Everything a calibration writes into ``out_dir`` (a folder that exists; the caller makes
    it atomic): ``report.html`` and its figures (unless ``report`` is False), calibration.json
    (with the report's numbers), the ``exports`` (:data:`EXPORT_TARGETS`: trajectories judge
    any result, even a refused one; parameter files only a calibration that succeeded) and,
    with ``save_inputs``, the compensated wheel rates."""
    out = Path(out_dir)
    written: list[Path] = []
    notes: list[str] = []
    report_numbers = None
    if report:
        from odocal.report import write_report

        page = write_report(result, out, progress=progress, renderer=renderer)
        written += [page.html_path, *page.figure_paths]
        report_numbers = page.data.to_dict()
    written.insert(0, write_calibration(result, out, report=report_numbers))
    targets = list(dict.fromkeys(exports))
    unknown = [t for t in targets if t not in EXPORT_TARGETS]
    if unknown:
        raise OutputError(f"unknown export target {unknown[0]!r}; choose from "
                          f"{', '.join(EXPORT_TARGETS)}")
    refuse_car_targets(targets, result.model_estimate.model)
    if "tum" in targets:
        from odocal.output.trajectories import write_trajectories

        written += write_trajectories(result.drive_data, result.trajectories(), out)
        targets.remove("tum")
    if targets and not result.success:
        notes.append("parameters not exported: the calibration did not succeed")
        targets = []
    for target in targets:
        if target in ("yaml", "json"):
            written.append(export_parameters(result, out, target))
        else:
            written += export_stack(result, out, target, wheel_joints=wheel_joints)
    if save_inputs:
        path = write_compensated_inputs(result, out)
        if path is None:
            notes.append("--save-inputs: this method does not compensate the wheel rates")
        else:
            written.append(path)
    return Written(paths=tuple(p.relative_to(out) if p.is_relative_to(out) else p
                               for p in written), notes=tuple(notes))


def refuse_car_targets(targets: Sequence[str], model: str) -> None:
    """A one-line OutputError, before anything is written, for a car's export (``ackermann``:
    a wheelbase and a steering) asked of a model without them."""
    if "ackermann" in targets and model != "four_wheel":
        raise OutputError(f"--export ackermann needs a car's wheelbase and steering: "
                          f"calibrate with [vehicle] model = \"four_wheel\" (this run is the "
                          f"{model} model's)")


def write_calibration(result: CalibrationResult, out_dir: str | Path, *,
                      report: dict[str, Any] | None = None) -> Path:
    """Write ``calibration.json`` into ``out_dir`` (with the report's numbers when given)."""
    data = result.to_dict()
    if report is not None:
        data["report"] = report
    return write_json(Path(out_dir) / CALIBRATION_FILE, data)


def export_parameters(result: CalibrationResult, out_dir: str | Path, fmt: str) -> Path:
    """The parameters for a localisation stack: ``yaml`` (a ROS 2 parameter file) or ``json``.

    Both carry theta (the chosen model's: ``[vehicle] model``), its covariance (theta's order;
    SI units) and which parameters the drive identified; the YAML adds the derived wheel radius.
    """
    est = result.model_estimate
    theta = est.theta.as_dict()
    cov = est.covariance
    names, units = est.theta.layout.names, est.theta.layout.units
    if fmt == "json":
        return write_json(Path(out_dir) / "odometry_parameters.json", {
            "model": est.model, "theta": theta, "covariance": cov.tolist(),
            "std": dict(zip(names, est.std.tolist(), strict=True)),
            "identified": dict(zip(names, est.identified, strict=True)),
            "datasheet_std": dict(zip(names, (float(v) for v in (
                result.model_settings or result.settings).identify.prior_std), strict=True)),
            "units": dict(zip(names, units, strict=True)),
            "speed_scale": (result.speed_scale.to_dict() if result.speed_scale is not None
                            else None),
            "method": result.method, "odocal_version": __version__})
    if fmt != "yaml":
        raise OutputError(f"unknown export format {fmt!r}; use yaml or json")
    from odocal.output.export import parameters_yaml

    return parameters_yaml(_calibrated(result), Path(out_dir) / "odometry_parameters.yaml")


def export_stack(result: CalibrationResult, out_dir: str | Path, target: str, *,
                 wheel_joints: tuple[str, str] | None = None) -> list[Path]:
    """Parameter files for ``target`` (see :mod:`odocal.output.export`) in ``out_dir/target/``;
    ``wheel_joints`` names the left and right wheel joints (ros2_control)."""
    from odocal.output.export import export

    return export(_calibrated(result, wheel_joints=wheel_joints), out_dir, [target])


def _calibrated(result: CalibrationResult, *,
                wheel_joints: tuple[str, str] | None = None) -> Any:
    """What the exports need from a calibration (:class:`odocal.output.export.Calibrated`)."""
    from odocal.output.export import Calibrated
    from odocal.pipeline.result import speed_signal

    est = result.model_estimate
    # logs whose wheels were speeds (m/s, km/h) were turned into rates with one circumference:
    # the vehicle's reported speed relates to it (the speed scale factor is relative to it)
    signal = speed_signal(result.drive_data)
    circumference = signal[0] if signal is not None else None
    settings = result.model_settings or result.settings
    return Calibrated(theta=est.theta, datasheet=est.datasheet,
                      std=tuple(float(s) for s in est.std),
                      datasheet_std=tuple(float(s) for s in settings.identify.prior_std),
                      identified=est.identified, method=result.method,
                      noise=result.odometry_noise,
                      source=", ".join(d.name for d in result.drives),
                      wheel_joints=wheel_joints,
                      speed_circumference_m=(float(circumference)
                                             if isinstance(circumference, int | float) else None),
                      covariance=tuple(tuple(float(v) for v in row)
                                       for row in est.covariance))


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


def write_replay_results(result: Any, out_dir: str | Path, *, batch: Any, settings: Any,
                         source_name: str, report: bool = True,
                         renderer: Any = None) -> list[Path]:
    """What ``odocal replay`` writes into ``out_dir`` (a folder that exists; the caller makes
    it atomic): calibration.json (the live estimate, its alarms and, where there is one, the
    batch estimate of the same log), trace.csv (the estimate after every update), alarms.json
    and, unless ``report`` is False, report.html with its trace figure. ``result`` is an
    :class:`odocal.online.replay.ReplayResult`, ``batch`` a batch estimate or None."""
    import csv
    import io

    from odocal.io.atomic import write_text
    from odocal.online.replay import TraceRow

    out = Path(out_dir)
    est = result.estimate
    from odocal.report.replay import convergence_km

    data = {"odocal_version": __version__, **est.to_dict(), "method": "online",
            "alarms": [a.to_dict() for a in result.alarms],
            "convergence_km": convergence_km(result), "samples": result.samples,
            "duration_s": result.duration_s, "distance_km": result.distance_km,
            "elapsed_s": result.elapsed_s,
            "details": est.details.to_dict() if est.details is not None else None,
            "batch": batch.to_dict() if batch is not None else None,
            "inputs": [{"name": source_name}], "settings": settings.to_dict()}
    written = [write_json(out / CALIBRATION_FILE, data)]
    text = io.StringIO()
    table = csv.writer(text)
    table.writerow(TraceRow.header(est.names))
    for row in result.trace:
        table.writerow(row.values())
    write_text(out / "trace.csv", text.getvalue())
    written.append(out / "trace.csv")
    written.append(write_json(out / "alarms.json",
                              {"alarms": [a.to_dict() for a in result.alarms]}))
    if report:
        from odocal.report.replay import write_replay_report

        written.append(write_replay_report(result, out, batch=batch, renderer=renderer))
        written.append(out / "figures" / "trace.png")
    return written
