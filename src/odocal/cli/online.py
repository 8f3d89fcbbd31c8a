"""``odocal replay`` and ``odocal ros2``: the online calibrator, on a log or on live topics."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import TYPE_CHECKING, Any

from odocal.cli import interrupt
from odocal.cli.arguments import add_common
from odocal.cli.common import (
    EXIT_FAILED,
    EXIT_OK,
    check_out_dir,
    inputs_of,
    rejection,
    renderer,
    say,
    settings_for,
    shown_source,
)
from odocal.errors import OdocalError, shown

if TYPE_CHECKING:
    from odocal.estimators.estimate import Estimate
    from odocal.online.replay import TraceRow
    from odocal.settings import Settings


def cmd_replay(args: argparse.Namespace) -> int:
    """Stream a log through the online calibrator; write the estimate, its trace and alarms."""
    drawer = renderer(args.out, not args.no_report)
    try:
        return _replay(args, drawer)
    finally:
        if drawer is not None:
            drawer.close()


def _replay(args: argparse.Namespace, drawer: Any) -> int:
    from odocal.io.atomic import results_folder
    from odocal.online.replay import replay
    from odocal.report.replay import alarm_words, convergence_km

    settings = settings_for(config=args.config, datasheet=args.datasheet, workers=args.workers)
    inputs = inputs_of(args.source, config=args.config, mapping=args.mapping)
    out = Path(args.out)
    check_out_dir(args.out, inputs)

    def show(row: TraceRow, est: Any) -> None:
        interrupt.checkpoint()       # (called at every update: Ctrl-C stops the replay here)
        if args.quiet:
            return
        say(_update_line(row))

    result = replay(args.source, fmt=args.source_format, settings=settings,
                    mapping=args.mapping, on_update=show)
    refused = rejection(result.estimate, result.estimate.details.findings, settings)
    batch = None
    if not refused and not args.no_batch and (args.source_format or "drive") == "drive":
        batch = _batch_estimate(args.source, settings)
    start = result.trace[-1].t - result.duration_s if result.trace else 0.0
    for alarm in result.alarms:
        say(f"change: {alarm_words(alarm)}, since {alarm.t - start:.0f} s from the log's "
            f"start ({alarm.distance_km:.2f} km; detected at "
            f"{alarm.detected_distance_km:.2f} km)")
    with results_folder(out) as tmp:
        from odocal.output.results import write_replay_results

        written = [p.relative_to(tmp) for p in write_replay_results(
            result, tmp, batch=batch, settings=settings,
            source_name=shown_source(args.source), report=not args.no_report,
            renderer=drawer)]
    if refused:
        say(refused)
        return EXIT_FAILED
    for line in _said(result, settings):
        say(line)
    conv = convergence_km(result)
    if not args.quiet:
        say(f"replayed {result.duration_s / 60:.1f} min, {result.distance_km:.2f} km in "
            f"{result.elapsed_s:.1f} s; c_e to 1 mm after "
            + (f"{conv['c_e']:.2f} km" if conv["c_e"] is not None else "-")
            + ", t_r to 20 mm after "
            + (f"{conv['t_r']:.2f} km" if conv["t_r"] is not None else "-"))
        for path in written:
            say(f"wrote {out / path}")
    return EXIT_OK


def _said(result: Any, settings: Settings) -> list[str]:
    """What the replay's answer holds back, in the report's words: a final estimate refused
    (the published one is the last that was not), the warnings the checks raised (an input
    left out, a steering angle that cannot be the car's), and for the four-wheel car what the
    drive did not identify of its front axle and steering."""
    from odocal.checks.findings import Severity
    from odocal.report.advice import finding_text, front_advice
    from odocal.report.summary import SEVERITY_WORDS

    lines = []
    if result.published_km is not None and result.final is not None:
        why = rejection(result.final, result.final.details.findings, settings)
        lines.append(f"note: the final estimate was refused ({(why or '').removeprefix('error: ')}"
                     f"); published: the last estimate that was not, from "
                     f"{result.published_km:.2f} km")
    seen = set()
    for finding in result.estimate.details.findings:
        text = finding_text(finding, settings)
        if finding.severity is Severity.FALLBACK and text not in seen:
            seen.add(text)
            lines.append(f"{SEVERITY_WORDS[int(finding.severity)]}: {text}")
    if result.estimate.model != "rear_axle":
        lines += [f"note: {a.text}" for a in front_advice(result.estimate) if not a.identified]
    return lines


def _update_line(row: TraceRow) -> str:
    """One update of the replay as the terminal shows it: each parameter with its standard
    deviation (- where not identified), and whether the gate refused it."""
    from odocal.report.summary import parameter_text, std_text

    parts = [f"{n} {parameter_text(n, v)} {std_text(n, s)}" if ok else f"{n} -"
             for n, v, s, ok in zip(row.names, row.theta, row.std, row.identified,
                                    strict=True)]
    return (f"{row.t:9.1f} s {row.distance_km:8.2f} km  " + "  ".join(parts)
            + (f"  REJECTED ({row.rejected_by or 'gate'}): not published" if row.rejected
               else ""))


def _batch_estimate(source: str, settings: Settings) -> Estimate | None:
    """The batch calibration of the whole log, to compare the replay's estimate with; None,
    said in a note, where there is none."""
    from odocal.pipeline.calibrate import calibrate

    batch = None
    try:
        batch = calibrate(source, settings=settings).model_estimate
    except OdocalError as exc:   # the comparison is an extra: the replay's answer stands
        interrupt.checkpoint()
        say(f"note: no batch calibration to compare with: {shown(exc, 300)}")
    interrupt.checkpoint()
    return batch


def cmd_ros2(args: argparse.Namespace) -> int:
    """The online calibrator as a ROS 2 node (docs: ROS 2), until Ctrl-C or SIGTERM."""
    settings = settings_for(config=args.config, datasheet=args.datasheet)
    from odocal.ros2.node import run

    return run(list(args.ros_args), settings=settings)


def add_parsers(sub: Any) -> None:
    """replay and ros2."""
    p = sub.add_parser("replay", help="stream a log through the online calibrator")
    p.add_argument("source", metavar="SOURCE",
                   help="a drive file (.parquet, .csv), or a bag with --from rosbag")
    p.add_argument("--from", dest="source_format", choices=("drive", "rosbag"),
                   help="source format (default: a drive file)")
    p.add_argument("--mapping", metavar="TOML",
                   help="topics and fields of a bag (docs: real logs)")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="folder for calibration.json, trace.csv, alarms.json, report.html")
    p.add_argument("--no-batch", action="store_true",
                   help="skip the batch calibration of the whole log shown for comparison")
    p.add_argument("--no-report", action="store_true", help="skip report.html")
    add_common(p)
    p.set_defaults(func=cmd_replay)

    p = sub.add_parser("ros2", help="run the online calibrator as a ROS 2 node (the ros2 extra)",
                       description="The online calibrator on live ROS 2 topics; node parameters "
                                   "after --ros-args (docs: ROS 2), e.g. odocal ros2 "
                                   "--datasheet c_e=1.95,t_r=1.51 --ros-args -p "
                                   "pose_topic:=/odometry/filtered")
    p.add_argument("--ros-args", dest="ros_args_help", action="store_true",
                   help="everything after it goes to ROS 2: parameters (-p NAME:=VALUE), "
                        "remappings, --params-file")
    add_common(p, workers=False)
    p.set_defaults(func=cmd_ros2)
