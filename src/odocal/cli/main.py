"""The ``odocal`` command line: a thin shell around the library.

Exit codes: 0 done; 1 bad input, settings or output (one line on stderr, no traceback);
2 bad command-line usage; 3 the calibration ran but could not identify anything;
4 an internal error (a bug: rerun with -v for the traceback and report it).
"""

from __future__ import annotations

import argparse
import gc
import logging
import math
import os
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from odocal._version import __version__
from odocal.cli import interrupt
from odocal.cli.arguments import DURATION_S, SEED, WORKERS, number
from odocal.cli.progress import Progress
from odocal.errors import ConfigError, OdocalError, OutputError, shown
from odocal.estimators import DEFAULT_METHOD, METHOD_NAMES
from odocal.settings import Settings, load_settings
from odocal.sim.noise import NOISE_PROFILES

if TYPE_CHECKING:
    from odocal.model.parameters import Parameters
    from odocal.pipeline.result import CalibrationResult

# numpy, scipy and numba load only in the commands that compute: --help and --version stay fast.

log = logging.getLogger("odocal")

EXIT_OK, EXIT_ERROR, EXIT_USAGE, EXIT_FAILED, EXIT_BUG = 0, 1, 2, 3, 4


def _settings(args: argparse.Namespace) -> Settings:
    settings = _load_config(getattr(args, "config", None))
    overrides: dict[str, dict[str, Any]] = {}
    if getattr(args, "workers", None) is not None:
        overrides.setdefault("calibrate", {})["workers"] = args.workers
    if getattr(args, "seed", None) is not None and args.command in ("calibrate", "minimum",
                                                                    "reproduce"):
        overrides.setdefault("calibrate", {})["seed"] = args.seed
    if getattr(args, "reference", None):
        overrides.setdefault("convert", {})["reference"] = args.reference
    if getattr(args, "circumference", None) is not None:
        overrides.setdefault("convert", {})["wheel_circumference_m"] = args.circumference
    if getattr(args, "datasheet", None):
        from odocal.output.export import parse_datasheet
        from odocal.pipeline.calibrate import datasheet_theta

        overrides.setdefault("identify", {})["theta0"] = datasheet_theta(
            parse_datasheet(args.datasheet), settings.identify.theta0)
    return settings.replace(**overrides) if overrides else settings


def _load_config(config: str | None) -> Settings:
    """The settings file, a path or a URL (README, "Fleets where the data lives")."""
    from odocal.io.remote import is_remote

    if config and is_remote(config):
        from odocal.io.remote import read_toml, redact
        from odocal.settings import settings_from_dict

        return settings_from_dict(read_toml(config, "settings file"),
                                  source=f"'{redact(config)}'")
    return load_settings(config)


def print_summary(result: CalibrationResult, *, truth: Parameters | None = None,
                  truth_error_m: float | None = None,
                  best_std: Sequence[float] | None = None) -> None:
    """The calibration's summary (:func:`odocal.report.summary.summary_lines`) on stdout."""
    from odocal.report.summary import summary_lines

    for line in summary_lines(result, truth=truth, truth_error_m=truth_error_m,
                              best_std=best_std):
        _print(line)


def _print(text: str = "") -> None:
    sys.stdout.write(text + "\n")


def _compile_note(args: argparse.Namespace, methods: Sequence[str]) -> None:
    """Say once, before a silent wait, that the segment methods' kernels compile now."""
    if args.quiet or not any(m in ("raw", "compensated") for m in methods):
        return
    from odocal.estimators.kernels import compile_note

    note = compile_note(methods)
    if note:
        sys.stderr.write(note + "\n")
        sys.stderr.flush()


def cmd_demo(args: argparse.Namespace) -> int:
    from odocal.pipeline.calibrate import calibrate, validate_theta
    from odocal.sim.simulate import simulate

    settings = _settings(args)
    _check_out_dir(args, _inputs(args))
    if not args.quiet:
        _print(f"simulating a {args.duration / 60:.0f}-minute city drive (noise profile "
               f"'{args.noise}', seed {args.seed}) with known true parameters ...")
    sim = simulate(duration_s=args.duration, seed=args.seed, noise=args.noise)
    _compile_note(args, [args.method or DEFAULT_METHOD] + ([] if args.no_compare
                                                            else list(METHOD_NAMES)))
    progress = Progress(not args.quiet)
    try:
        result = calibrate(sim.drive, settings=settings, method=args.method, progress=progress)
        truth_error = validate_theta(sim.drive, sim.true_parameters,
                                     settings=settings).mean_error_m
        if not args.no_compare:
            result = _compared(result, [sim.drive], settings, sim.true_parameters, args.quiet,
                               progress)
    finally:
        progress.close()
    if not args.quiet:
        bound = sim.cramer_rao_bound()
        best = None if bound is None else [math.sqrt(v) for v in bound.diagonal()]
        print_summary(result, truth=sim.true_parameters, truth_error_m=truth_error,
                      best_std=best)
    if args.out:
        _write_outputs(result, args, inputs=_inputs(args))
    elif not args.quiet:
        _print("(add --out DIR to write calibration.json and the report with its figures)")
    return exit_code(result)


def _compared(result: CalibrationResult, drives: Sequence[Any], settings: Settings,
              truth: Parameters | None, quiet: bool,
              progress: Callable[[str, int, int], None] | None = None) -> CalibrationResult:
    """``result`` with every method scored on held-out blocks (printed unless quiet)."""
    import dataclasses

    from odocal.pipeline.compare import compare, format_table

    comparison = compare(drives, settings=settings, truth=truth, progress=progress)
    if progress is not None and hasattr(progress, "close"):
        progress.close()                        # its bars end before the table is printed
    if not quiet:
        for line in format_table(comparison):
            _print(line)
        _print()
    return dataclasses.replace(result, comparison=comparison)


def _out_file(out: str, default: str) -> Path:
    """The file a one-file command writes: ``--out`` itself, or, when ``--out`` is a folder (an
    existing one, or any path ending in a slash), ``default`` inside it."""
    path = Path(out)
    if path.is_dir() or out.endswith(("/", os.sep)):
        return path / default
    return path


def cmd_simulate(args: argparse.Namespace) -> int:
    from odocal.io import save_drive
    from odocal.io.atomic import check_output_file
    from odocal.io.results import write_json
    from odocal.sim.simulate import simulate

    out = _out_file(args.out, "drive.parquet")
    truth_path = out.with_name(out.stem + ".truth.json")
    check_output_file(out)                 # odocal replaces only files it wrote
    check_output_file(truth_path)
    other = [p for p in (out.with_suffix(".csv"), out.with_suffix(".parquet"))
             if p != out and p.exists()]
    if truth_path.exists() and other:
        raise OutputError(f"'{truth_path}' is the truth of '{other[0]}'; writing '{out}' would "
                          "replace it: choose another name")
    sim = simulate(duration_s=args.duration, seed=args.seed, noise=args.noise)
    save_drive(sim.drive, out, owned=True)
    write_json(truth_path, sim.truth_dict(), owned=True)
    if not args.quiet:
        d = sim.drive
        _print(f"wrote {out} ({d.n_samples} samples, {d.duration_s / 60:.1f} min, "
               f"{d.distance_m / 1000:.2f} km, noise '{args.noise}') and {truth_path}")
    return EXIT_OK


def _renderer(args: argparse.Namespace) -> Any:
    """A report renderer started now (its helper loads matplotlib while we calibrate), or None.

    Started before anything heavy is imported, so the helper forks from a light process. It
    draws with two processes, one per core (the five figures of the default's report draw in
    parallel): on a one-hour drive the report adds 0.67-1.01 s (median 0.81 s) to a run of
    1.08-1.22 s, and the calibration's stages are not slowed.
    """
    if getattr(args, "no_report", False) or not getattr(args, "out", None):
        return None
    from odocal.report.render import Renderer

    return Renderer(2)


def _inputs(args: argparse.Namespace, *sources: Any) -> list[Any]:
    """Everything a command reads: its sources, settings, mapping (and the files the mapping
    names), parameters."""
    from odocal.io.mapping import mapping_files

    mapping = getattr(args, "mapping", None)
    return [*sources, getattr(args, "config", None), mapping, *mapping_files(mapping),
            getattr(args, "params", None)]


def _check_out_dir(args: argparse.Namespace, inputs: Sequence[Any]) -> None:
    """Before any computation: the results folder may replace nothing the run reads."""
    from odocal.io.atomic import check_replaceable, refuse_inputs

    if getattr(args, "out", None):
        refuse_inputs(args.out, inputs, folder=True)
        check_replaceable(Path(args.out))


def _write_outputs(result: CalibrationResult, args: argparse.Namespace,
                   inputs: Sequence[Any],
                   progress: Callable[[str, int, int], None] | None = None,
                   renderer: Any = None) -> None:
    """The results folder, built beside ``--out`` and swapped in whole when complete
    (:func:`odocal.output.results.write_results` decides what goes into it)."""
    from odocal.io.atomic import results_folder
    from odocal.output.results import write_results

    _check_out_dir(args, inputs)
    out = Path(args.out)
    with results_folder(out) as tmp:
        written = write_results(result, tmp, exports=getattr(args, "export", None) or (),
                                report=not getattr(args, "no_report", False),
                                save_inputs=getattr(args, "save_inputs", False),
                                wheel_joints=_wheel_joints(args), progress=progress,
                                renderer=renderer)
    for note in written.notes:
        _print(f"note: {note}")
    if not args.quiet:
        for path in written.paths:
            _print(f"wrote {out / path}")


def _export_targets(text: str) -> list[str]:
    """``--export autoware,ros2_control``: the targets named, in order, each once."""
    from odocal.output.results import EXPORT_TARGETS

    names = [n.strip() for n in text.split(",")]
    bad = [n for n in names if n not in EXPORT_TARGETS]
    if bad:
        raise argparse.ArgumentTypeError(
            f"unknown target {bad[0]!r} in {text!r}; choose from {', '.join(EXPORT_TARGETS)} "
            "(a comma list, e.g. autoware,ros2_control)")
    return list(dict.fromkeys(names))


def _wheel_joints(args: argparse.Namespace) -> tuple[str, str] | None:
    text = getattr(args, "wheel_joints", None)
    if not text:
        return None
    names = [n.strip() for n in text.split(",")]
    if len(names) != 2 or not all(names):
        raise ConfigError(f"--wheel-joints {text!r}: give the left and the right wheel joint "
                          "names separated by a comma")
    return names[0], names[1]


def _drives_from(args: argparse.Namespace, settings: Settings) -> list[Any]:
    """Drive files, or raw logs converted in memory with --from."""
    from odocal.pipeline.calibrate import load_drives

    if getattr(args, "scene", None) and getattr(args, "source_format", None) != "nuscenes":
        raise ConfigError("--scene chooses nuScenes scenes: it needs --from nuscenes")
    if getattr(args, "source_format", None):
        from odocal.io.remote import local_inputs
        from odocal.preprocess.convert import convert

        with local_inputs(args.logs, args.mapping) as (logs, mapping):   # URLs: copied here
            drives = convert(args.source_format, logs, mapping=mapping,
                             scenes=args.scene, settings=settings)
        if not args.quiet:
            for d in drives:
                _print(_conversion_line(d))
        return drives
    return load_drives(args.logs, settings=settings)


def _conversion_line(drive: Any) -> str:
    c = drive.metadata.get("conversion", {})
    offset = (c.get("wheel_offset") or {}).get("message", "no wheel offset estimate")
    return (f"converted {drive.name}: {drive.duration_s:.1f} s, {drive.distance_m:.0f} m, "
            f"{len(drive.pieces)} piece(s), reference {c.get('reference')}; {offset}; "
            f"sideslip {c.get('sideslip')}")


def cmd_calibrate(args: argparse.Namespace) -> int:
    renderer = _renderer(args)
    progress = Progress(not args.quiet)
    try:
        from odocal.pipeline.calibrate import calibrate

        settings = _settings(args)
        _wheel_joints(args)                          # checked before anything is computed
        inputs = _inputs(args, *args.logs)
        _check_out_dir(args, inputs)
        drives = _drives_from(args, settings)
        if args.compare:                             # before anything is fitted
            from odocal.pipeline.calibrate import load_drives
            from odocal.pipeline.compare import check_comparable

            drives = load_drives(drives, settings=settings)
            check_comparable(drives, settings)
        _compile_note(args, [args.method or DEFAULT_METHOD]
                      + (list(METHOD_NAMES) if args.compare else []))
        result = calibrate(drives, settings=settings, method=args.method, progress=progress)
        if args.compare:
            result = _compared(result, drives, settings, None, args.quiet, progress)
        if not args.quiet:
            print_summary(result)
        else:
            rejected = _rejection(result.estimate, result.diagnosis.findings, settings)
            if rejected:                             # -q prints errors only, and this one
                _print(rejected)
        _write_outputs(result, args, progress=progress, renderer=renderer, inputs=inputs)
    finally:
        progress.close()
        if renderer is not None:
            renderer.close()
    return exit_code(result)


def exit_code(result: CalibrationResult) -> int:
    """0 for an answer, or for data that are valid but identify nothing; 3 for a failure."""
    from odocal.estimators.estimate import Status

    if result.success or result.estimate.status is Status.NOTHING_IDENTIFIABLE:
        return EXIT_OK
    return EXIT_FAILED


def cmd_convert(args: argparse.Namespace) -> int:
    from odocal.io import save_drive
    from odocal.io.atomic import check_output_file, refuse_inputs

    settings = _settings(args)
    folder = Path(args.out).is_dir() or args.out.endswith(("/", os.sep))
    out = Path(args.out)
    inputs = _inputs(args, *args.logs)
    refuse_inputs(out / "drive.parquet" if folder else out, inputs)
    if not folder:
        check_output_file(out)                      # odocal replaces only files it wrote
    drives = _drives_from(args, settings)
    if folder:                                      # one file per log, named after it
        targets = [out / f"{_safe(d.name)}.parquet" for d in drives]
    else:
        targets = [out] if len(drives) == 1 else \
            [out.with_name(f"{out.stem}-{_safe(d.name)}{out.suffix}") for d in drives]
    for target in targets:                          # every one before the first is written
        refuse_inputs(target, inputs)
        check_output_file(target)
    for drive, target in zip(drives, targets, strict=True):
        save_drive(drive, target, owned=True)
        if not args.quiet:
            _print(f"wrote {target} ({drive.n_samples} samples at "
                   f"{1 / drive.t_s:.0f} Hz)")
    return EXIT_OK


def _safe(name: str) -> str:
    from odocal.io.atomic import file_name

    return file_name(Path(name).name)


def cmd_inspect(args: argparse.Namespace) -> int:
    from odocal.io.remote import local_inputs
    from odocal.preprocess.convert import inspect

    settings = _settings(args)
    with local_inputs(args.logs, args.mapping) as (logs, mapping):     # URLs: copied here
        found_logs = inspect(args.source_format, logs, mapping=mapping, scenes=args.scene,
                             settings=settings)
    for found in found_logs:
        _print(f"{found.log.name} ({found.log.metadata.get('source_format')}):")
        _print(f"  {'role':<8} {'stream':<34} {'samples':>8} {'rate Hz':>8} {'span s':>8} "
               f"{'gaps':>5} {'longest gap s':>13} {'repaired':>9}  units")
        for role, r in found.streams.items():
            repaired = f"{r.out_of_order}o/{r.duplicates}d/{r.missing}m"
            units = ", ".join(f"{k} {v}" for k, v in r.units.items())
            _print(f"  {role:<8} {r.name[:34]:<34} {r.samples:>8} {r.rate_hz:>8.1f} "
                   f"{r.end_s - r.start_s:>8.2f} {r.gaps:>5} {r.longest_gap_s:>13.3f} "
                   f"{repaired:>9}  {units}")
        spans = [(r.start_s, r.end_s) for r in found.streams.values()]
        overlap = min(b for _, b in spans) - max(a for a, _ in spans)
        _print(f"  common span {max(overlap, 0.0):.2f} s "
               "(repaired: out-of-order / duplicate stamps / samples with missing values)")
    return EXIT_OK


def _parameters_from(args: argparse.Namespace, settings: Settings) -> Parameters:
    from odocal.io.results import read_parameters
    from odocal.model.parameters import Parameters

    if args.params:
        return read_parameters(args.params)
    return Parameters.from_array(settings.identify.theta0)


def cmd_validate(args: argparse.Namespace) -> int:
    from odocal.pipeline.calibrate import validate_theta

    settings = _settings(args)
    theta = _parameters_from(args, settings)
    result = validate_theta(_drives_from(args, settings), theta, settings=settings)
    if args.quiet:
        return EXIT_OK
    _print("parameters: " + ", ".join(f"{k} = {v:.6g}" for k, v in theta.as_dict().items()))
    _print(f"validation error E_p = {result.mean_error_m:.3f} m over {len(result.segments)} "
           f"segments ({result.segments.distance_m.sum() / 1000:.2f} km)")
    _print(f"{'segment':>7} {'drive':<30} {'start [s]':>10} {'length [m]':>10} {'E_p [m]':>9} "
           f"{'end error [m]':>13}")
    drives = result.drive_names
    for i, (d, t0, dist, e, f) in enumerate(zip(result.segments.drive, result.start_s,
                                                 result.segments.distance_m,
                                                 result.errors.mean_m, result.errors.final_m,
                                                 strict=True)):
        _print(f"{i:>7} {Path(drives[int(d)]).name[:30]:<30} {t0:>10.1f} {dist:>10.1f} {e:>9.3f} "
               f"{f:>13.3f}")
    return EXIT_OK


def cmd_minimum(args: argparse.Namespace) -> int:
    from odocal.pipeline.calibrate import minimum

    settings = _settings(args)
    if args.out:
        args.out = str(_out_file(args.out, "minimum.json"))
    if args.out:
        from odocal.io.atomic import check_output_file, refuse_inputs

        refuse_inputs(args.out, _inputs(args, *args.logs))
        check_output_file(args.out)                 # odocal replaces only files it wrote
    start = _parameters_from(args, settings)
    if not args.quiet:
        _print("searching the reachable minimum of E_p over the validation segments "
               "(differential evolution) ...")
    progress = Progress(not args.quiet)
    try:
        result = minimum(_drives_from(args, settings), start=start, settings=settings,
                         progress=progress)
    finally:
        progress.close()
    if args.quiet:
        if args.out:
            from odocal.io.results import write_json

            write_json(args.out, result.to_dict(), owned=True)
        return EXIT_OK if result.success else EXIT_FAILED
    _print(f"start   E_p = {result.start_error_m:.3f} m at "
           + ", ".join(f"{k} = {v:.6g}" for k, v in start.as_dict().items()))
    _print(f"minimum E_p = {result.mean_error_m:.3f} m over {result.segments} segments at "
           + ", ".join(f"{k} = {v:.6g}" for k, v in result.theta.as_dict().items()))
    if not args.quiet:
        _print(f"({result.evaluations} evaluations; {result.message})")
    if args.out:
        from odocal.io.results import write_json

        write_json(args.out, result.to_dict(), owned=True)
        if not args.quiet:
            _print(f"wrote {args.out}")
    return EXIT_OK if result.success else EXIT_FAILED


def cmd_replay(args: argparse.Namespace) -> int:
    """Stream a log through the online calibrator; write the estimate, its trace and alarms."""
    renderer = _renderer(args)
    try:
        return _replay(args, renderer)
    finally:
        if renderer is not None:
            renderer.close()


def _replay(args: argparse.Namespace, renderer: Any) -> int:
    from odocal.io.atomic import results_folder
    from odocal.model.parameters import PARAMETER_NAMES
    from odocal.online.replay import TraceRow, replay
    from odocal.report.replay import alarm_words, convergence_km
    from odocal.report.summary import parameter_text, std_text

    settings = _settings(args)
    inputs = _inputs(args, args.source)
    out = Path(args.out)
    _check_out_dir(args, inputs)

    def show(row: TraceRow, est: Any) -> None:
        interrupt.checkpoint()       # (called at every update: Ctrl-C stops the replay here)
        if args.quiet:
            return
        parts = [f"{n} {parameter_text(n, v)} {std_text(n, s)}" if ok else f"{n} -"
                 for n, v, s, ok in zip(PARAMETER_NAMES, row.theta, row.std, row.identified,
                                        strict=True)]
        _print(f"{row.t:9.1f} s {row.distance_km:8.2f} km  " + "  ".join(parts)
               + (f"  REJECTED ({row.rejected_by or 'gate'}): not published" if row.rejected
                  else ""))

    result = replay(args.source, fmt=args.source_format, settings=settings,
                    mapping=args.mapping, on_update=show)
    rejected = _rejection(result.estimate, result.estimate.details.findings, settings)
    batch = None
    if not rejected and not args.no_batch and (args.source_format or "drive") == "drive":
        from odocal.pipeline.calibrate import calibrate

        try:
            batch = calibrate(args.source, settings=settings).estimate
        except OdocalError as exc:   # the comparison is an extra: the replay's answer stands
            interrupt.checkpoint()
            _print(f"note: no batch calibration to compare with: {shown(exc, 300)}")
        interrupt.checkpoint()
    start = result.trace[-1].t - result.duration_s if result.trace else 0.0
    for alarm in result.alarms:
        _print(f"change: {alarm_words(alarm)}, since {alarm.t - start:.0f} s from the log's "
               f"start ({alarm.distance_km:.2f} km; detected at "
               f"{alarm.detected_distance_km:.2f} km)")
    written: list[Path] = []
    with results_folder(out) as tmp:
        from odocal.output.results import write_replay_results

        written += write_replay_results(result, tmp, batch=batch, settings=settings,
                                        source_name=_shown_source(args.source),
                                        report=not args.no_report, renderer=renderer)
    if rejected:
        _print(rejected)
        return EXIT_FAILED
    conv = convergence_km(result)
    if not args.quiet:
        _print(f"replayed {result.duration_s / 60:.1f} min, {result.distance_km:.2f} km in "
               f"{result.elapsed_s:.1f} s; c_e to 1 mm after "
               + (f"{conv['c_e']:.2f} km" if conv["c_e"] is not None else "-")
               + ", t_r to 20 mm after "
               + (f"{conv['t_r']:.2f} km" if conv["t_r"] is not None else "-"))
        for path in written:
            _print(f"wrote {out / path.relative_to(tmp)}")
    return EXIT_OK


def cmd_ros2(args: argparse.Namespace) -> int:
    """The online calibrator as a ROS 2 node (README, "ROS 2"), until Ctrl-C or SIGTERM."""
    settings = _settings(args)
    from odocal.ros2.node import run

    return run(list(getattr(args, "ros_args", [])), settings=settings)


def _rejection(estimate: Any, findings: Sequence[Any], settings: Settings) -> str | None:
    """:func:`odocal.report.summary.rejection_line`."""
    from odocal.report.summary import rejection_line

    return rejection_line(estimate, findings, settings)


def _shown_source(source: str) -> str:
    from odocal.io.remote import redact

    return redact(source)


def cmd_reproduce(args: argparse.Namespace) -> int:
    from odocal.io.results import write_json
    from odocal.pipeline.reproduce import format_report, reproduce

    settings = _settings(args)
    if args.out:                                    # checked before the long computation
        from odocal.io.atomic import check_output_file, refuse_inputs

        args.out = str(_out_file(args.out, "reproduce.json"))
        refuse_inputs(args.out, [getattr(args, "config", None)])
        check_output_file(args.out)                 # odocal replaces only files it wrote
    if not args.quiet:
        _print(f"reproducing the paper's experiment on a simulated {args.distance_km:g} km drive "
               f"(seed {args.seed}, noise '{args.noise}') ...")
    progress = Progress(not args.quiet)
    try:
        result = reproduce(seed=args.seed, noise=args.noise, distance_km=args.distance_km,
                           settings=settings, minimum=not args.no_minimum, progress=progress)
    finally:
        progress.close()
    if not args.quiet:
        _print(format_report(result))
    if args.out:
        write_json(args.out, result.to_dict(), owned=True)
        _print(f"wrote {args.out}")
    return EXIT_OK


def _add_source(p: argparse.ArgumentParser, *, required: bool, converts: bool = True) -> None:
    from odocal.io.registry import FORMATS

    p.add_argument("--from", dest="source_format", choices=FORMATS, required=required,
                   help="raw log format")
    p.add_argument("--mapping", metavar="TOML",
                   help="which files/topics and columns/fields hold each stream (see README)")
    p.add_argument("--scene", action="append", metavar="NAME",
                   help="nuScenes scene to use (repeatable; default all)")
    if not converts:
        return
    p.add_argument("--reference", choices=("auto", "fused", "gnss-imu"),
                   help="reference pose: the log's fused pose, or odocal's GNSS/IMU fusion")
    p.add_argument("--circumference", type=number(0.05, 50.0, unit="m"), metavar="M",
                   help="nominal wheel circumference for wheel speeds in m/s or km/h")


def _add_common(p: argparse.ArgumentParser, *, workers: bool = True,
                datasheet: bool = True) -> None:
    p.add_argument("--config", metavar="TOML", help="settings file (see README, 'Settings')")
    if datasheet:
        p.add_argument("--datasheet", metavar="NAME=VALUE,...",
                       help="the vehicle's datasheet values, e.g. c_e=1.84,t_r=1.52 (effective "
                            "wheel circumference and rear track width, m; also c_d, d; or a "
                            "robot's wheel_radius=0.1,wheel_separation=0.4): the "
                            "start of the fit, the comparison in results and exports, and the "
                            "centre of the plausible ranges")
    if workers:
        p.add_argument("--workers", type=WORKERS, metavar="N",
                       help="processes for per-segment work (0 = every core; default from "
                            "settings)")
    p.add_argument("-q", "--quiet", action="store_true", help="print only errors")
    p.add_argument("-v", "--verbose", action="count", default=0,
                   help="more log output (-vv for debug)")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="odocal", description="Calibrate a vehicle's wheel-odometry model from logged drives.")
    parser.add_argument("--version", action="version", version=f"odocal {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    _add_simulation_commands(sub)
    _add_calibration_commands(sub)
    _add_checking_commands(sub)

    from odocal.cli.fleet import add_parsers

    add_parsers(sub)
    return parser


def _configure_logging(verbose: int, quiet: bool) -> None:
    level = logging.ERROR if quiet else (logging.WARNING if verbose == 0 else
                                         logging.INFO if verbose == 1 else logging.DEBUG)
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s",
                        stream=sys.stderr)
    if verbose == 0:
        # warnings are printed in the summary; keep the log for -v
        logging.getLogger("odocal").setLevel(logging.ERROR)


def _causes(exc: BaseException) -> list[BaseException]:
    """What led to an error, outermost first (``raise ... from err`` and errors raised while
    handling another), without repeats."""
    out: list[BaseException] = []
    cause = exc.__cause__ or (None if exc.__suppress_context__ else exc.__context__)
    while cause is not None and cause not in out and len(out) < 10:
        out.append(cause)
        cause = cause.__cause__ or (None if cause.__suppress_context__ else cause.__context__)
    return out


def main(argv: Sequence[str] | None = None) -> int:
    if argv is None:
        interrupt.install()           # the program itself: Ctrl-C remembered (cli/interrupt.py)
    try:
        parser = build_parser()
        words = list(sys.argv[1:] if argv is None else argv)
        ros_args: list[str] = []
        if words[:1] == ["ros2"] and "--ros-args" in words:  # ROS 2's own arguments, as they are
            ros_args, words = words[words.index("--ros-args"):], words[:words.index("--ros-args")]
        args = parser.parse_args(words)
    except KeyboardInterrupt:
        return _interrupted("odocal", argv)
    if args.command == "ros2":
        args.ros_args = ros_args
    _configure_logging(args.verbose, args.quiet)
    func: Callable[[argparse.Namespace], int] = args.func
    try:
        code = func(args)
        if _swallowed(args):          # an interrupt some library swallowed on the way
            return _interrupted(f"odocal {args.command}", argv)
        return code
    except OdocalError as exc:
        if _swallowed(args):
            return _interrupted(f"odocal {args.command}", argv)
        sys.stderr.write(f"odocal {args.command}: error: {shown(exc, 2000)}\n")
        if args.verbose:
            for cause in _causes(exc):
                sys.stderr.write(f"  caused by {type(cause).__name__}: {shown(cause, 2000)}\n")
        return EXIT_ERROR
    except KeyboardInterrupt:
        return _interrupted(f"odocal {args.command}", argv)
    except BrokenPipeError:  # the reader went away (| head): stop quietly
        sys.stderr.close()
        return EXIT_OK
    except OSError as exc:   # the machine said no (a name too long, no space, no permission)
        if _swallowed(args):
            return _interrupted(f"odocal {args.command}", argv)
        if args.verbose:
            raise
        where = f" '{shown(exc.filename)}'" if exc.filename else ""
        sys.stderr.write(f"odocal {args.command}: error: cannot use{where}: "
                         f"{shown(exc.strerror or exc)}\n")
        return EXIT_ERROR
    except MemoryError:
        sys.stderr.write(f"odocal {args.command}: error: out of memory: the settings ask for "
                         "more than this machine has (see README, 'Input limits')\n")
        return EXIT_ERROR
    except Exception as exc:  # a bug: say so in one line, with the traceback on request
        if _swallowed(args):          # (or what an interrupt left behind: a half-done import)
            return _interrupted(f"odocal {args.command}", argv)
        if args.verbose:
            raise
        sys.stderr.write(f"odocal {args.command}: internal error: {type(exc).__name__}: "
                         f"{shown(exc, 300)} (rerun with -v for the traceback)\n")
        return EXIT_BUG
    finally:
        if argv is None:
            # the program ends here: what it made needs no collecting on the way out (the
            # interpreter's last collection took 0.2 s after a one-hour calibration)
            gc.freeze()


#: Commands whose normal end is Ctrl-C (a node that spins until stopped): they catch it
#: themselves and say how they ended.
_ENDED_BY_CTRL_C = frozenset({"ros2"})


def _swallowed(args: argparse.Namespace) -> bool:
    """Whether Ctrl-C was pressed during a command that does not end on it."""
    return interrupt.interrupted() and args.command not in _ENDED_BY_CTRL_C


def _interrupted(command: str, argv: Sequence[str] | None) -> int:
    """Ctrl-C: one line, exit 130. The program itself (not a caller's ``main([...])``) has
    stopped and cleaned up its work (pools terminated, temporary results removed) and leaves
    now rather than wait in exit handlers for the threads of a broken pool."""
    if argv is None:
        interrupt.leave(command)
    sys.stderr.write(f"{command}: interrupted\n")
    sys.stderr.flush()
    sys.stdout.flush()
    return 130


def _add_simulation_commands(sub: Any) -> None:
    """demo and simulate."""
    p = sub.add_parser("demo", help="simulate a drive with known parameters and calibrate it")
    p.add_argument("--duration", type=DURATION_S, default=1200.0, metavar="S",
                   help="simulated drive length in seconds (default 1200, at most 86400)")
    p.add_argument("--seed", type=SEED, default=0, help="simulation seed (default 0)")
    p.add_argument("--noise", choices=sorted(NOISE_PROFILES), default="realistic",
                   help="noise profile (default realistic)")
    p.add_argument("--method", choices=METHOD_NAMES,
                   help=f"calibration method (default {DEFAULT_METHOD})")
    p.add_argument("--out", metavar="DIR",
                   help="also write the results (calibration.json, report.html) to this folder")
    p.add_argument("--no-compare", action="store_true",
                   help="skip comparing every method on held-out parts of the drive")
    _add_common(p)
    p.set_defaults(func=cmd_demo)

    p = sub.add_parser("simulate", help="write a simulated drive and its truth")
    p.add_argument("--out", required=True, metavar="FILE",
                   help="drive file to write (.csv or .parquet; or drive.parquet in this "
                        "folder); the truth goes to FILE.truth.json beside it")
    p.add_argument("--seed", type=SEED, default=0)
    p.add_argument("--duration", type=DURATION_S, default=1800.0, metavar="S",
                   help="drive length in seconds (default 1800, at most 86400)")
    p.add_argument("--noise", choices=sorted(NOISE_PROFILES), default="realistic",
                   metavar="PROFILE", help=f"one of {', '.join(NOISE_PROFILES)}")
    p.add_argument("-q", "--quiet", action="store_true")
    p.add_argument("-v", "--verbose", action="count", default=0)
    p.set_defaults(func=cmd_simulate)


def _add_calibration_commands(sub: Any) -> None:
    """calibrate and convert."""
    p = sub.add_parser("calibrate", help="calibrate from drive logs of one vehicle")
    p.add_argument("logs", nargs="+", metavar="LOG",
                   help="drive-format files (.csv, .parquet), or raw logs with --from")
    _add_source(p, required=False)
    p.add_argument("--out", required=True, metavar="DIR", help="folder for calibration.json")
    p.add_argument("--method", choices=METHOD_NAMES,
                   help=f"calibration method (default {DEFAULT_METHOD}; README, 'Methods')")
    p.add_argument("--seed", type=SEED, help="seed of the step-1 batch draw")
    p.add_argument("--save-inputs", action="store_true",
                   help="also write the compensated wheel rates (compensated_inputs.parquet)")
    p.add_argument("--export", action="extend", type=_export_targets, metavar="TARGET,...",
                   help="also write the parameters for a localisation stack: yaml (a ROS 2 "
                        "parameter file) or json, with their covariance, or the parameter files "
                        "of autoware, ros2_control, robot_localization; or tum: the reference "
                        "and the wheel odometry (calibrated and datasheet) as trajectories for "
                        "evo (a comma list, or repeated)")
    p.add_argument("--wheel-joints", metavar="LEFT,RIGHT",
                   help="wheel joint names for --export ros2_control")
    p.add_argument("--no-report", action="store_true", help="skip report.html and the figures")
    p.add_argument("--compare", action="store_true",
                   help="also score every method on held-out parts of the drives (slower)")
    _add_common(p)
    p.set_defaults(func=cmd_calibrate)

    p = sub.add_parser("convert", help="turn raw logs into the drive format")
    p.add_argument("logs", nargs="+", metavar="SOURCE",
                   help="nuScenes folders, comma2k19 segment folders, bags or table files")
    _add_source(p, required=True)
    p.add_argument("--out", required=True, metavar="FILE",
                   help="drive file (.csv or .parquet); with several logs, one file each named "
                        "FILE-<log>; or a folder (existing, or ending in /): <log>.parquet "
                        "in it")
    _add_common(p)
    p.set_defaults(func=cmd_convert)


def _add_checking_commands(sub: Any) -> None:
    """inspect, validate, reproduce, replay and minimum."""
    p = sub.add_parser("inspect", help="list the streams in raw logs before converting them")
    p.add_argument("logs", nargs="+", metavar="SOURCE")
    _add_source(p, required=True, converts=False)
    _add_common(p, workers=False, datasheet=False)
    p.set_defaults(func=cmd_inspect)

    p = sub.add_parser("validate", help="validation error E_p of parameters on drive logs")
    p.add_argument("logs", nargs="+", metavar="LOG",
                   help="drive-format files (.csv, .parquet), or raw logs with --from")
    _add_source(p, required=False)
    p.add_argument("--params", metavar="JSON",
                   help="calibration.json to validate (default: the datasheet parameters)")
    _add_common(p)
    p.set_defaults(func=cmd_validate)

    p = sub.add_parser("reproduce", help="the paper's experiment on a simulated ~24 km drive")
    p.add_argument("--seed", type=SEED, default=0, help="simulation and batch seed (default 0)")
    p.add_argument("--noise", choices=sorted(NOISE_PROFILES), default="realistic")
    p.add_argument("--distance-km", type=number(0.5, 500.0, unit="km"), default=24.0,
                   help="drive length (default 24, from 0.5 to 500)")
    p.add_argument("--no-minimum", action="store_true",
                   help="skip the global search for the reachable minimum")
    p.add_argument("--out", metavar="FILE",
                   help="write the numbers to this JSON file (or reproduce.json in this folder)")
    _add_common(p)
    p.set_defaults(func=cmd_reproduce)

    p = sub.add_parser("replay", help="stream a log through the online calibrator")
    p.add_argument("source", metavar="SOURCE",
                   help="a drive file (.parquet, .csv), or a bag with --from rosbag")
    p.add_argument("--from", dest="source_format", choices=("drive", "rosbag"),
                   help="source format (default: a drive file)")
    p.add_argument("--mapping", metavar="TOML", help="topics and fields of a bag (see README)")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="folder for calibration.json, trace.csv, alarms.json, report.html")
    p.add_argument("--no-batch", action="store_true",
                   help="skip the batch calibration of the whole log shown for comparison")
    p.add_argument("--no-report", action="store_true", help="skip report.html")
    _add_common(p)
    p.set_defaults(func=cmd_replay)

    p = sub.add_parser("ros2", help="run the online calibrator as a ROS 2 node (the ros2 extra)",
                       description="The online calibrator on live ROS 2 topics; node parameters "
                                   "after --ros-args (README, 'ROS 2'), e.g. odocal ros2 "
                                   "--datasheet c_e=1.95,t_r=1.51 --ros-args -p "
                                   "pose_topic:=/odometry/filtered")
    p.add_argument("--ros-args", dest="ros_args_help", action="store_true",
                   help="everything after it goes to ROS 2: parameters (-p NAME:=VALUE), "
                        "remappings, --params-file")
    _add_common(p, workers=False)
    p.set_defaults(func=cmd_ros2)

    p = sub.add_parser("minimum", help="the reachable minimum validation error (global search)")
    p.add_argument("logs", nargs="+", metavar="LOG",
                   help="drive-format files (.csv, .parquet), or raw logs with --from")
    _add_source(p, required=False)
    p.add_argument("--params", metavar="JSON", help="centre of the search box (default datasheet)")
    p.add_argument("--seed", type=SEED, help="optimiser seed")
    p.add_argument("--out", metavar="FILE",
                   help="write the result to this JSON file (or minimum.json in this folder)")
    _add_common(p)
    p.set_defaults(func=cmd_minimum)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
