"""What the commands share: exit codes, printing, settings from the command line, the inputs
and outputs a run may touch, and writing a results folder.

Every helper takes the values it needs by name (never the parsed arguments): a command reads
its own arguments and hands them on.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from odocal.errors import ConfigError, OdocalError

if TYPE_CHECKING:
    from odocal.model.parameters import Parameters
    from odocal.pipeline.result import CalibrationResult
    from odocal.settings import Settings

#: The one rule for exit codes (docs/command-line.md).
EXIT_OK, EXIT_ERROR, EXIT_USAGE, EXIT_FAILED, EXIT_BUG = 0, 1, 2, 3, 4
EXIT_INTERRUPTED = 130

ProgressCallback = Callable[[str, int, int], None]


class UsageError(OdocalError):
    """A command line that cannot run as typed (options that do not go together, a value
    beyond what its option allows): exit 2, as argparse's own errors. ``argument`` names the
    option."""

    def __init__(self, argument: str, message: str) -> None:
        super().__init__(f"argument {argument}: {message}")
        self.argument = argument


def say(text: str = "") -> None:
    """One line on stdout (what the command found and wrote), with no URL's query or secret in
    it (:func:`odocal.redaction.redact_text`)."""
    from odocal.redaction import redact_text

    sys.stdout.write(redact_text(text) + "\n")


def load_config(config: str | None) -> Settings:
    """The settings file, a path or a URL (docs: fleets where the data lives)."""
    from odocal.io.remote import is_remote
    from odocal.settings import load_settings

    if config and is_remote(config):
        from odocal.io.remote import read_toml, redact
        from odocal.settings import settings_from_dict

        return settings_from_dict(read_toml(config, "settings file"),
                                  source=f"'{redact(config)}'")
    return load_settings(config)


def settings_for(*, config: str | None, datasheet: Mapping[str, float] | None = None,
                 workers: int | None = None, seed: int | None = None,
                 reference: str | None = None,
                 circumference: float | None = None,
                 reference_offset: tuple[float, float] | None = None,
                 command: str | None = None) -> Settings:
    """The settings a command runs with: the file (or the defaults), then what the command
    line states. A datasheet that does not go with the file's (a c_d beside its c_e) is a
    usage error naming --datasheet. ``command``: a command that takes the rear-axle model
    only (a settings file choosing another is a one-line error naming it)."""
    from odocal.model.registry import require_rear_axle
    from odocal.settings import datasheet_theta

    settings = load_config(config)
    if command is not None:
        require_rear_axle(settings.vehicle.model, f"odocal {command}")
    overrides: dict[str, dict[str, Any]] = {}
    if workers is not None:
        overrides.setdefault("calibrate", {})["workers"] = workers
    if seed is not None:
        overrides.setdefault("calibrate", {})["seed"] = seed
    if reference:
        overrides.setdefault("convert", {})["reference"] = reference
    if circumference is not None:
        overrides.setdefault("convert", {})["wheel_circumference_m"] = circumference
    if reference_offset is not None:
        overrides.setdefault("reference", {})["offset_m"] = list(reference_offset)
    if datasheet:
        try:
            theta0 = datasheet_theta(datasheet, settings.identify.theta0, layout=settings.layout,
                                     source="the datasheet")
        except ConfigError as err:
            raise UsageError("--datasheet", str(err).removeprefix("the datasheet: ")) from err
        overrides.setdefault("identify", {})["theta0"] = theta0
    return settings.replace(**overrides) if overrides else settings


def out_file(out: str, default: str) -> Path:
    """The file a one-file command writes: ``--out`` itself, or, when ``--out`` is a folder (an
    existing one, or any path ending in a slash), ``default`` inside it."""
    path = Path(out)
    if path.is_dir() or out.endswith(("/", os.sep)):
        return path / default
    return path


def inputs_of(*sources: Any, config: str | None = None, mapping: str | None = None,
              params: str | None = None) -> list[Any]:
    """Everything a command reads: its sources, settings, mapping (and the files the mapping
    names), parameters."""
    from odocal.io.mapping import mapping_files

    return [*sources, config, mapping, *mapping_files(mapping), params]


def check_out_dir(out: str | None, inputs: Sequence[Any]) -> None:
    """Before any computation: the results folder may replace nothing the run reads, nor a
    folder odocal did not write."""
    from odocal.io.atomic import check_replaceable, refuse_inputs

    if out:
        refuse_inputs(out, inputs, folder=True)
        check_replaceable(Path(out))


def check_out_file(out: Path, inputs: Sequence[Any]) -> None:
    """Before any computation: a one-file output replaces only a file odocal wrote, and no
    input."""
    from odocal.io.atomic import check_output_file, refuse_inputs

    refuse_inputs(out, inputs)
    check_output_file(out)


def renderer(out: str | None, report: bool) -> Any:
    """A report renderer started now (its helper loads matplotlib while we calibrate), or None.

    Started before anything heavy is imported, so the helper forks from a light process. It
    draws with two processes, one per core (the five figures of the default's report draw in
    parallel): on a one-hour drive the report adds 0.67-1.01 s (median 0.81 s) to a run of
    1.08-1.22 s, and the calibration's stages are not slowed.
    """
    if not report or not out:
        return None
    from odocal.report.render import Renderer

    return Renderer(2)


def write_outputs(result: CalibrationResult, out: str, *, inputs: Sequence[Any],
                  quiet: bool, exports: Sequence[str] = (), report: bool = True,
                  save_inputs: bool = False, wheel_joints: tuple[str, str] | None = None,
                  progress: ProgressCallback | None = None, renderer: Any = None) -> None:
    """The results folder (:meth:`odocal.CalibrationResult.save`), and a line for each file
    in it, named where it is once the run has ended."""
    written = result.save(out, exports=exports, report=report, save_inputs=save_inputs,
                          wheel_joints=wheel_joints, inputs=inputs, progress=progress,
                          renderer=renderer)
    for note in written.notes:
        say(f"note: {note}")
    if not quiet:
        for path in written.paths:
            say(f"wrote {Path(out) / path}")


def exit_code(result: CalibrationResult) -> int:
    """0 for an answer, or for data that are valid but identify nothing; 3 for a failure."""
    from odocal.estimators.estimate import Status

    if result.success or result.estimate.status is Status.NOTHING_IDENTIFIABLE:
        return EXIT_OK
    return EXIT_FAILED


def print_summary(result: CalibrationResult, *, truth: Parameters | None = None,
                  truth_error_m: float | None = None,
                  best_std: Sequence[float] | None = None) -> None:
    """The calibration's summary (:func:`odocal.report.summary.summary_lines`) on stdout."""
    from odocal.report.summary import summary_lines

    for line in summary_lines(result, truth=truth, truth_error_m=truth_error_m,
                              best_std=best_std):
        say(line)


def compared(result: CalibrationResult, drives: Sequence[Any], settings: Settings,
             truth: Parameters | None, *, quiet: bool,
             progress: ProgressCallback | None = None) -> CalibrationResult:
    """``result`` with every method scored on held-out blocks (printed unless quiet)."""
    import dataclasses

    from odocal.cli.progress import Progress
    from odocal.pipeline.compare import compare, format_table

    comparison = compare(drives, settings=settings, truth=truth, progress=progress)
    if isinstance(progress, Progress):
        progress.close()                        # its bars end before the table is printed
    if not quiet:
        for line in format_table(comparison):
            say(line)
        say()
    return dataclasses.replace(result, comparison=comparison)


def rejection(estimate: Any, findings: Sequence[Any], settings: Settings) -> str | None:
    """:func:`odocal.report.summary.rejection_line`."""
    from odocal.report.summary import rejection_line

    return rejection_line(estimate, findings, settings)


def compile_note(methods: Sequence[str], *, quiet: bool) -> None:
    """Say once, before a silent wait, that the segment methods' kernels compile now."""
    if quiet or not any(m == "compensated" for m in methods):
        return
    from odocal.estimators.kernels import compile_note as note_of

    note = note_of(methods)
    if note:
        sys.stderr.write(note + "\n")
        sys.stderr.flush()


def drives_from(logs: Sequence[str], *, source_format: str | None, mapping: str | None,
                scenes: Sequence[str] | None, settings: Settings, quiet: bool) -> list[Any]:
    """Drive files, or raw logs converted in memory with --from (a line for each unless
    quiet)."""
    from odocal.pipeline.calibrate import load_drives

    if scenes and source_format != "nuscenes":
        raise UsageError("--scene", "--scene chooses nuScenes scenes: it needs --from nuscenes")
    if not source_format:
        return load_drives(list(logs), settings=settings)
    from odocal.io.remote import local_inputs
    from odocal.preprocess.convert import convert

    with local_inputs(list(logs), mapping) as (local, local_mapping):    # URLs: copied here
        drives = convert(source_format, local, mapping=local_mapping, scenes=scenes,
                         settings=settings)
    if not quiet:
        for d in drives:
            say(conversion_line(d))
    return drives


def conversion_line(drive: Any) -> str:
    c = drive.metadata.get("conversion", {})
    offset = (c.get("wheel_offset") or {}).get("message", "no wheel offset estimate")
    return (f"converted {drive.name}: {drive.duration_s:.1f} s, {drive.distance_m:.0f} m, "
            f"{len(drive.pieces)} piece(s), reference {c.get('reference')}; {offset}; "
            f"sideslip {c.get('sideslip')}")


def shown_source(source: str) -> str:
    from odocal.io.remote import redact

    return redact(source)
