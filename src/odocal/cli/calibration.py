"""``odocal calibrate``, ``odocal convert`` and ``odocal inspect``: logs of a vehicle, read,
converted and calibrated."""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import Any

from odocal.cli.arguments import (
    SEED,
    add_common,
    add_source,
    export_targets,
    reference_offset,
    wheel_joints,
)
from odocal.cli.common import (
    EXIT_OK,
    check_out_dir,
    check_out_file,
    compared,
    compile_note,
    drives_from,
    exit_code,
    inputs_of,
    print_summary,
    rejection,
    renderer,
    say,
    settings_for,
    write_outputs,
)
from odocal.cli.progress import Progress
from odocal.estimators import DEFAULT_METHOD, METHOD_NAMES


def cmd_calibrate(args: argparse.Namespace) -> int:
    drawer = renderer(args.out, not args.no_report)
    progress = Progress(not args.quiet)
    try:
        from odocal.pipeline.calibrate import calibrate, load_drives

        settings = settings_for(config=args.config, datasheet=args.datasheet,
                                workers=args.workers, seed=args.seed, reference=args.reference,
                                circumference=args.circumference,
                                reference_offset=args.reference_offset)
        inputs = inputs_of(*args.logs, config=args.config, mapping=args.mapping)
        check_out_dir(args.out, inputs)
        from odocal.output.results import refuse_car_targets

        refuse_car_targets(args.export or (), settings.vehicle.model)
        drives = drives_from(args.logs, source_format=args.source_format,
                             mapping=args.mapping, scenes=args.scene, settings=settings,
                             quiet=args.quiet)
        if args.compare:                             # before anything is fitted
            from odocal.pipeline.compare import check_comparable

            drives = load_drives(drives, settings=settings)
            check_comparable(drives, settings)
        compile_note([args.method or DEFAULT_METHOD]
                     + (list(METHOD_NAMES) if args.compare else []), quiet=args.quiet)
        result = calibrate(drives, settings=settings, method=args.method, progress=progress)
        if args.compare:
            result = compared(result, drives, settings, None, quiet=args.quiet,
                              progress=progress)
        if not args.quiet:
            print_summary(result)
        else:
            refused = rejection(result.estimate, result.diagnosis.findings, settings)
            if refused:                              # -q prints errors only, and this one
                say(refused)
        write_outputs(result, args.out, inputs=inputs, quiet=args.quiet,
                      exports=args.export or (), report=not args.no_report,
                      save_inputs=args.save_inputs, wheel_joints=args.wheel_joints,
                      progress=progress, renderer=drawer)
    finally:
        progress.close()
        if drawer is not None:
            drawer.close()
    return exit_code(result)


def cmd_convert(args: argparse.Namespace) -> int:
    from odocal.io import save_drive

    settings = settings_for(config=args.config, datasheet=args.datasheet, workers=args.workers,
                            reference=args.reference, circumference=args.circumference)
    folder = Path(args.out).is_dir() or args.out.endswith(("/", os.sep))
    out = Path(args.out)
    inputs = inputs_of(*args.logs, config=args.config, mapping=args.mapping)
    if folder:
        from odocal.io.atomic import refuse_inputs

        refuse_inputs(out / "drive.parquet", inputs)
    else:
        check_out_file(out, inputs)                 # odocal replaces only files it wrote
    drives = drives_from(args.logs, source_format=args.source_format, mapping=args.mapping,
                         scenes=args.scene, settings=settings, quiet=args.quiet)
    if folder:                                      # one file per log, named after it
        targets = [out / f"{_safe(d.name)}.parquet" for d in drives]
    else:
        targets = [out] if len(drives) == 1 else \
            [out.with_name(f"{out.stem}-{_safe(d.name)}{out.suffix}") for d in drives]
    for target in targets:                          # every one before the first is written
        check_out_file(target, inputs)
    for drive, target in zip(drives, targets, strict=True):
        save_drive(drive, target, owned=True)
        if not args.quiet:
            say(f"wrote {target} ({drive.n_samples} samples at {1 / drive.t_s:.0f} Hz)")
    return EXIT_OK


def _safe(name: str) -> str:
    from odocal.io.atomic import file_name

    return file_name(Path(name).name)


def cmd_inspect(args: argparse.Namespace) -> int:
    from odocal.io.remote import local_inputs
    from odocal.preprocess.convert import inspect

    settings = settings_for(config=args.config)
    with local_inputs(args.logs, args.mapping) as (logs, mapping):     # URLs: copied here
        found_logs = inspect(args.source_format, logs, mapping=mapping, scenes=args.scene,
                             settings=settings)
    for found in found_logs:
        say(f"{found.log.name} ({found.log.metadata.get('source_format')}):")
        say(f"  {'role':<8} {'stream':<34} {'samples':>8} {'rate Hz':>8} {'span s':>8} "
            f"{'gaps':>5} {'longest gap s':>13} {'repaired':>9}  units")
        for role, r in found.streams.items():
            repaired = f"{r.out_of_order}o/{r.duplicates}d/{r.missing}m"
            units = ", ".join(f"{k} {v}" for k, v in r.units.items())
            say(f"  {role:<8} {r.name[:34]:<34} {r.samples:>8} {r.rate_hz:>8.1f} "
                f"{r.end_s - r.start_s:>8.2f} {r.gaps:>5} {r.longest_gap_s:>13.3f} "
                f"{repaired:>9}  {units}")
        spans = [(r.start_s, r.end_s) for r in found.streams.values()]
        overlap = min(b for _, b in spans) - max(a for a, _ in spans)
        say(f"  common span {max(overlap, 0.0):.2f} s "
            "(repaired: out-of-order / duplicate stamps / samples with missing values)")
    return EXIT_OK


def add_parsers(sub: Any) -> None:
    """calibrate, convert and inspect."""
    p = sub.add_parser("calibrate", help="calibrate from drive logs of one vehicle",
                       description="Calibrate the wheel-odometry model of one vehicle from "
                                   "its logs: calibration.json, report.html and its figures "
                                   "in the folder --out.")
    p.add_argument("logs", nargs="+", metavar="LOG",
                   help="drive-format files (.csv, .parquet), or raw logs with --from; paths "
                        "or URLs")
    add_source(p, required=False)
    p.add_argument("--out", required=True, metavar="DIR",
                   help="folder for calibration.json, report.html and figures/ (replaced "
                        "whole; odocal refuses a folder it did not write)")
    p.add_argument("--method", choices=METHOD_NAMES,
                   help=f"calibration method (default {DEFAULT_METHOD}; docs: methods)")
    p.add_argument("--seed", type=SEED, metavar="N",
                   help="seed of the segment methods' step-1 batch draw (default from "
                        "settings)")
    p.add_argument("--save-inputs", action="store_true",
                   help="also write the compensated wheel rates (compensated_inputs.parquet; "
                        "--method compensated)")
    p.add_argument("--export", action="extend", type=export_targets, metavar="TARGET,...",
                   help="also write the parameters for a localisation stack: yaml (a ROS 2 "
                        "parameter file) or json, with their covariance, or the parameter files "
                        "of autoware, ros2_control, robot_localization, ackermann (the "
                        "four_wheel model's ackermann_steering_controller); or tum: the reference "
                        "and the wheel odometry (calibrated and datasheet) as trajectories for "
                        "evo (a comma list, or repeated)")
    p.add_argument("--wheel-joints", type=wheel_joints, metavar="LEFT,RIGHT",
                   help="wheel joint names for --export ros2_control")
    p.add_argument("--reference-offset", type=reference_offset, metavar="FORWARD,LEFT",
                   help="where the reference pose is on the vehicle: its offset from the rear "
                        "axle's midpoint, forward and left, m (a GNSS antenna, an INS, a "
                        "camera); unset, odocal estimates it where the bends show it (docs: "
                        "checks)")
    p.add_argument("--no-report", action="store_true", help="skip report.html and the figures")
    p.add_argument("--compare", action="store_true",
                   help="also score every method on held-out parts of the drives (slower)")
    add_common(p)
    p.set_defaults(func=cmd_calibrate)

    p = sub.add_parser("convert", help="turn raw logs into the drive format")
    p.add_argument("logs", nargs="+", metavar="SOURCE",
                   help="nuScenes folders, comma2k19 segment folders, bags or table files")
    add_source(p, required=True)
    p.add_argument("--out", required=True, metavar="FILE",
                   help="drive file (.csv or .parquet); with several logs, one file each named "
                        "FILE-<log>; or a folder (existing, or ending in /): <log>.parquet "
                        "in it")
    add_common(p)
    p.set_defaults(func=cmd_convert)

    p = sub.add_parser("inspect", help="list the streams in raw logs before converting them")
    p.add_argument("logs", nargs="+", metavar="SOURCE",
                   help="raw logs of the format --from names: nuScenes folders, comma2k19 "
                        "segment folders, bags, table files (paths or URLs)")
    add_source(p, required=True, converts=False)
    add_common(p, workers=False, datasheet=False)
    p.set_defaults(func=cmd_inspect)
