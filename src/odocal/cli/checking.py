"""``odocal validate`` and ``odocal minimum``: parameters judged on drives."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING, Any

from odocal.cli.arguments import SEED, add_common, add_source
from odocal.cli.common import (
    EXIT_FAILED,
    EXIT_OK,
    check_out_file,
    drives_from,
    inputs_of,
    out_file,
    say,
    settings_for,
)
from odocal.cli.progress import Progress

if TYPE_CHECKING:
    from odocal.model.parameters import Parameters
    from odocal.settings import Settings


def _parameters(params: str | None, settings: Settings) -> Parameters:
    """The parameters of ``--params``, or the datasheet values."""
    from odocal.io.json_files import read_parameters
    from odocal.model.parameters import Parameters

    if params:
        return read_parameters(params, settings.vehicle.model)
    return Parameters.from_array(settings.identify.theta0, layout=settings.layout)


def cmd_validate(args: argparse.Namespace) -> int:
    from odocal.pipeline.calibrate import validate_theta

    settings = settings_for(config=args.config, datasheet=args.datasheet, workers=args.workers,
                            reference=args.reference, circumference=args.circumference)
    theta = _parameters(args.params, settings)
    std = None
    if args.params and settings.vehicle.model != "rear_axle":
        from odocal.io.json_files import read_uncertainty

        std = read_uncertainty(args.params, settings.vehicle.model)
    drives = drives_from(args.logs, source_format=args.source_format, mapping=args.mapping,
                         scenes=args.scene, settings=settings, quiet=args.quiet)
    if settings.vehicle.model != "rear_axle":
        _front_wheels_checked(drives, settings)
    result = validate_theta(drives, theta, settings=settings, std=std)
    if args.quiet:
        return EXIT_OK
    n = len(result.segments)
    say("parameters: " + ", ".join(f"{k} = {v:.6g}" for k, v in theta.as_dict().items()))
    say(f"validation error E_p = {result.mean_error_m:.3f} m over {n} "
        f"segment{'s' if n != 1 else ''} ({result.segments.distance_m.sum() / 1000:.2f} km)")
    say(f"{'segment':>7} {'drive':<30} {'start [s]':>10} {'length [m]':>10} {'E_p [m]':>9} "
        f"{'end error [m]':>13}")
    names = result.drive_names
    for i, (d, t0, dist, e, f) in enumerate(zip(result.segments.drive, result.start_s,
                                                 result.segments.distance_m,
                                                 result.errors.mean_m, result.errors.final_m,
                                                 strict=True)):
        say(f"{i:>7} {Path(names[int(d)]).name[:30]:<30} {t0:>10.1f} {dist:>10.1f} {e:>9.3f} "
            f"{f:>13.3f}")
    return EXIT_OK


def _front_wheels_checked(drives: Any, settings: Settings) -> None:
    """The front wheels' and steering's checks that need no fit, as calibrate runs them: a
    fatal finding (left and right swapped, a dead wheel, another unit) is a one-line error,
    never an E_p computed on a wrong mapping."""
    from odocal.checks.findings import Severity
    from odocal.errors import DataError
    from odocal.estimators.front_axle import front_checks
    from odocal.report.advice import NOTHING_CALIBRATED, finding_text

    for finding in front_checks(drives, settings).findings:
        if finding.severity is Severity.FATAL:
            raise DataError(finding_text(finding, settings).removesuffix(NOTHING_CALIBRATED))


def cmd_minimum(args: argparse.Namespace) -> int:
    from odocal.io.json_files import write_json
    from odocal.pipeline.calibrate import minimum

    settings = settings_for(command="minimum",
                            config=args.config, datasheet=args.datasheet, workers=args.workers,
                            seed=args.seed, reference=args.reference,
                            circumference=args.circumference)
    out = out_file(args.out, "minimum.json") if args.out else None
    if out is not None:                             # odocal replaces only files it wrote
        check_out_file(out, inputs_of(*args.logs, config=args.config, mapping=args.mapping,
                                      params=args.params))
    start = _parameters(args.params, settings)
    if not args.quiet:
        say("searching the reachable minimum of E_p over the validation segments "
            "(differential evolution) ...")
    progress = Progress(not args.quiet)
    try:
        drives = drives_from(args.logs, source_format=args.source_format, mapping=args.mapping,
                             scenes=args.scene, settings=settings, quiet=args.quiet)
        result = minimum(drives, start=start, settings=settings, progress=progress)
    finally:
        progress.close()
    if not args.quiet:
        say(f"start   E_p = {result.start_error_m:.3f} m at "
            + ", ".join(f"{k} = {v:.6g}" for k, v in start.as_dict().items()))
        say(f"minimum E_p = {result.mean_error_m:.3f} m over {result.segments} segments at "
            + ", ".join(f"{k} = {v:.6g}" for k, v in result.theta.as_dict().items()))
        say(f"({result.evaluations} evaluations; {result.message})")
    if out is not None:
        write_json(out, result.to_dict(), owned=True)
        if not args.quiet:
            say(f"wrote {out}")
    return EXIT_OK if result.success else EXIT_FAILED


def add_parsers(sub: Any) -> None:
    """validate and minimum."""
    p = sub.add_parser("validate", help="validation error E_p of parameters on drive logs")
    p.add_argument("logs", nargs="+", metavar="LOG",
                   help="drive-format files (.csv, .parquet), or raw logs with --from")
    add_source(p, required=False)
    p.add_argument("--params", metavar="JSON",
                   help="calibration.json to validate (default: the datasheet parameters)")
    add_common(p)
    p.set_defaults(func=cmd_validate)

    p = sub.add_parser("minimum", help="the reachable minimum validation error (global search)")
    p.add_argument("logs", nargs="+", metavar="LOG",
                   help="drive-format files (.csv, .parquet), or raw logs with --from")
    add_source(p, required=False)
    p.add_argument("--params", metavar="JSON",
                   help="centre of the search box: a calibration.json (default: the datasheet "
                        "values)")
    p.add_argument("--seed", type=SEED, metavar="N", help="optimiser seed (default from "
                                                          "settings)")
    p.add_argument("--out", metavar="FILE",
                   help="write the result to this JSON file (or minimum.json in this folder)")
    add_common(p)
    p.set_defaults(func=cmd_minimum)
