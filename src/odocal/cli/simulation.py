"""``odocal demo``, ``odocal simulate`` and ``odocal reproduce``: drives with known truth."""

from __future__ import annotations

import argparse
import math
from typing import TYPE_CHECKING, Any

from odocal.cli.arguments import DURATION_S, SEED, add_common, add_quiet, number
from odocal.cli.common import (
    EXIT_OK,
    UsageError,
    check_out_dir,
    check_out_file,
    compared,
    compile_note,
    exit_code,
    inputs_of,
    out_file,
    print_summary,
    say,
    settings_for,
    write_outputs,
)
from odocal.cli.progress import Progress
from odocal.errors import OutputError
from odocal.estimators import DEFAULT_METHOD, METHOD_NAMES
from odocal.model import registry
from odocal.sim.noise import NOISE_PROFILES

if TYPE_CHECKING:
    from odocal.model.parameters import Parameters


def cmd_demo(args: argparse.Namespace) -> int:
    from odocal.pipeline.calibrate import calibrate, validate_theta

    settings = settings_for(config=args.config, datasheet=args.datasheet, workers=args.workers)
    four = settings.vehicle.model != registry.DEFAULT
    if four and args.method not in (None, DEFAULT_METHOD):
        raise UsageError("--method", f"the {settings.vehicle.model} model is calibrated by the "
                                     f"default method ({DEFAULT_METHOD}) only")
    inputs = inputs_of(config=args.config)
    check_out_dir(args.out, inputs)
    if not args.quiet:
        car = " of a four-wheel car with its steering" if four else ""
        say(f"simulating a {args.duration / 60:.0f}-minute city drive{car} (noise profile "
            f"'{args.noise}', seed {args.seed}) with known true parameters ...")
    sim, truth = _simulated(args, settings.vehicle.model)
    compare = not args.no_compare and not four
    if four and not args.no_compare and not args.quiet:
        say("(the methods are compared on the rear_axle model only: --no-compare taken)")
    method = args.method or DEFAULT_METHOD
    compile_note([method] + (list(METHOD_NAMES) if compare else []), quiet=args.quiet)
    progress = Progress(not args.quiet)
    try:
        result = calibrate(sim.drive, settings=settings, method=args.method, progress=progress)
        truth_error = validate_theta(sim.drive, truth, settings=settings).mean_error_m
        if compare:
            result = compared(result, [sim.drive], settings, truth, quiet=args.quiet,
                              progress=progress)
    finally:
        progress.close()
    if not args.quiet:
        bound = sim.cramer_rao_bound()
        best = None if bound is None else [math.sqrt(v) for v in bound.diagonal()]
        print_summary(result, truth=truth, truth_error_m=truth_error, best_std=best)
    if args.out:
        write_outputs(result, args.out, inputs=inputs, quiet=args.quiet)
    elif not args.quiet:
        say("(add --out DIR to write calibration.json and the report with its figures)")
    return exit_code(result)


def _simulated(args: argparse.Namespace, model: str) -> tuple[Any, Parameters]:
    """The simulated drive of ``args`` for vehicle ``model`` and its true parameters (the
    four-wheel car's: the front wheels and the steering added to the rear axle's drive)."""
    from odocal.sim.simulate import simulate

    sim = simulate(duration_s=args.duration, seed=args.seed, noise=args.noise)
    if model == registry.DEFAULT:
        return sim, sim.true_parameters
    from odocal.sim.four_wheel import with_front_axle

    return with_front_axle(sim)


def cmd_simulate(args: argparse.Namespace) -> int:
    from odocal.io import save_drive
    from odocal.io.json_files import write_json

    out = out_file(args.out, "drive.parquet")
    truth_path = out.with_name(out.stem + ".truth.json")
    check_out_file(out, [])                 # odocal replaces only files it wrote
    check_out_file(truth_path, [])
    other = [p for p in (out.with_suffix(".csv"), out.with_suffix(".parquet"))
             if p != out and p.exists()]
    if truth_path.exists() and other:
        raise OutputError(f"'{truth_path}' is the truth of '{other[0]}'; writing '{out}' would "
                          "replace it: choose another name")
    sim, truth = _simulated(args, args.model)
    save_drive(sim.drive, out, owned=True)
    write_json(truth_path, {**sim.truth_dict(), "theta": truth.as_dict(), "model": args.model},
               owned=True)
    if not args.quiet:
        d = sim.drive
        car = ", four wheels and the steering" if args.model != registry.DEFAULT else ""
        say(f"wrote {out} ({d.n_samples} samples, {d.duration_s / 60:.1f} min, "
            f"{d.distance_m / 1000:.2f} km, noise '{args.noise}'{car}) and {truth_path}")
    return EXIT_OK


def cmd_reproduce(args: argparse.Namespace) -> int:
    from odocal.io.json_files import write_json
    from odocal.pipeline.reproduce import format_report, reproduce

    settings = settings_for(command="reproduce",
                            config=args.config, datasheet=args.datasheet, workers=args.workers,
                            seed=args.seed)
    out = out_file(args.out, "reproduce.json") if args.out else None
    if out is not None:                             # checked before the long computation
        check_out_file(out, inputs_of(config=args.config))
    if not args.quiet:
        say(f"reproducing the paper's experiment on a simulated {args.distance_km:g} km drive "
            f"(seed {args.seed}, noise '{args.noise}') ...")
    progress = Progress(not args.quiet)
    try:
        result = reproduce(seed=args.seed, noise=args.noise, distance_km=args.distance_km,
                           settings=settings, minimum=not args.no_minimum, progress=progress)
    finally:
        progress.close()
    if not args.quiet:
        say(format_report(result))
    if out is not None:
        write_json(out, result.to_dict(), owned=True)
        if not args.quiet:
            say(f"wrote {out}")
    return EXIT_OK


def _noise(p: argparse.ArgumentParser) -> None:
    p.add_argument("--noise", choices=sorted(NOISE_PROFILES), default="realistic",
                   metavar="PROFILE",
                   help=f"noise profile (default realistic): {', '.join(NOISE_PROFILES)}")


def add_parsers(sub: Any) -> None:
    """demo, simulate and reproduce."""
    p = sub.add_parser("demo", help="simulate a drive with known parameters and calibrate it",
                       description="Simulate a city drive with known true parameters, "
                                   "calibrate it and compare the result with the truth.")
    p.add_argument("--duration", type=DURATION_S, default=1200.0, metavar="S",
                   help="simulated drive length in seconds (default 1200, at most 86400)")
    p.add_argument("--seed", type=SEED, default=0, metavar="N",
                   help="simulation seed (default 0)")
    _noise(p)
    p.add_argument("--method", choices=METHOD_NAMES,
                   help=f"calibration method (default {DEFAULT_METHOD})")
    p.add_argument("--out", metavar="DIR",
                   help="also write the results (calibration.json, report.html) to this folder")
    p.add_argument("--no-compare", action="store_true",
                   help="skip comparing every method on held-out parts of the drive")
    add_common(p)
    p.set_defaults(func=cmd_demo)

    p = sub.add_parser("simulate", help="write a simulated drive and its truth",
                       description="Write a simulated drive in the drive format and its truth "
                                   "(the true parameters and the noise-free wheel rates) "
                                   "beside it: drive.parquet and drive.truth.json.")
    p.add_argument("--out", required=True, metavar="DRIVE",
                   help="drive file to write (.csv or .parquet; or drive.parquet in this "
                        "folder); the truth goes beside it as NAME.truth.json (drive.csv: "
                        "drive.truth.json)")
    p.add_argument("--seed", type=SEED, default=0, metavar="N",
                   help="simulation seed (default 0)")
    p.add_argument("--duration", type=DURATION_S, default=1800.0, metavar="S",
                   help="drive length in seconds (default 1800, at most 86400)")
    _noise(p)
    p.add_argument("--model", choices=registry.names(), default=registry.DEFAULT,
                   help="the vehicle model simulated (default rear_axle: the two rear wheels); "
                        "four_wheel adds the front wheels (n_fl, n_fr) and the steering-wheel "
                        "angle (steer), with the four-wheel truth")
    add_quiet(p)
    p.set_defaults(func=cmd_simulate)

    p = sub.add_parser("reproduce", help="the paper's experiment on a simulated ~24 km drive")
    p.add_argument("--seed", type=SEED, default=0, metavar="N",
                   help="simulation and batch seed (default 0)")
    _noise(p)
    p.add_argument("--distance-km", type=number(0.5, 500.0, unit="km"), default=24.0,
                   metavar="KM", help="drive length (default 24, from 0.5 to 500)")
    p.add_argument("--no-minimum", action="store_true",
                   help="skip the global search for the reachable minimum")
    p.add_argument("--out", metavar="FILE",
                   help="write the numbers to this JSON file (or reproduce.json in this folder)")
    add_common(p)
    p.set_defaults(func=cmd_reproduce)
