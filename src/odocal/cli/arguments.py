"""The command line's arguments shared by several commands, and their types: every value is
checked by argparse before any command runs (exit 2 with one line naming the argument and what
would be right)."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from typing import Any

from odocal.sim.limits import MAX_DURATION_S, MAX_SEED


def number(lower: float, upper: float, *, unit: str = "", open_lower: bool = False
           ) -> Callable[[str], float]:
    """A finite number in ``[lower, upper]`` (``(lower, upper]`` with ``open_lower``)."""
    span = f"{'above' if open_lower else 'from'} {lower:g} {'and' if open_lower else 'to'} " \
           f"{'at most ' if open_lower else ''}{upper:g}{' ' + unit if unit else ''}"

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError as err:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number ({span})") from err
        inside = lower < value if open_lower else lower <= value
        if not (math.isfinite(value) and inside and value <= upper):
            raise argparse.ArgumentTypeError(f"{text} is out of range: {span}")
        return value

    return parse


def integer(lower: int, upper: int) -> Callable[[str], int]:
    """An integer in ``[lower, upper]``."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError as err:
            raise argparse.ArgumentTypeError(f"{text!r} is not an integer (from {lower} to "
                                             f"{upper})") from err
        if not lower <= value <= upper:
            raise argparse.ArgumentTypeError(f"{text} is out of range: an integer from {lower} "
                                             f"to {upper}")
        return value

    return parse


#: A seed of the simulator or of a calibration's random choices.
SEED = integer(0, MAX_SEED)
#: The length of a simulated drive, s (more than a second, at most a day).
DURATION_S = number(1.0, MAX_DURATION_S, unit="s", open_lower=True)
#: Worker processes (0: every core).
WORKERS = integer(0, 1024)


class DatasheetAction(argparse.Action):
    """``--datasheet NAME=VALUE,...``, repeatable: each one's values merged with the earlier
    ones (a name given twice, in one or in two of them, is refused, never replaced), each
    checked against a vehicle's range. An error is a usage error (exit 2) naming the argument."""

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace,
                 values: Any, option_string: str | None = None) -> None:
        from odocal.errors import ConfigError
        from odocal.settings import datasheet_pairs, datasheet_values

        earlier = list((vars(namespace).get(self.dest) or {}).items())
        try:
            pairs = datasheet_pairs(str(values), what="the datasheet")
            merged = datasheet_values(earlier + pairs, source="the datasheet")
        except ConfigError as err:
            raise argparse.ArgumentError(self, str(err).removeprefix("the datasheet: ")) \
                from err
        setattr(namespace, self.dest, merged)


def export_targets(text: str) -> list[str]:
    """``--export autoware,ros2_control``: the targets named, in order, each once."""
    from odocal.output.results import EXPORT_TARGETS

    names = [n.strip() for n in text.split(",")]
    bad = [n for n in names if n not in EXPORT_TARGETS]
    if bad:
        raise argparse.ArgumentTypeError(
            f"unknown target {bad[0]!r} in {text!r}; choose from {', '.join(EXPORT_TARGETS)} "
            "(a comma list, e.g. autoware,ros2_control)")
    return list(dict.fromkeys(names))


def wheel_joints(text: str) -> tuple[str, str]:
    """``--wheel-joints LEFT,RIGHT``: two names."""
    names = [n.strip() for n in text.split(",")]
    if len(names) != 2 or not all(names):
        raise argparse.ArgumentTypeError(f"{text!r}: give the left and the right wheel joint "
                                         "names separated by a comma")
    return names[0], names[1]


def reference_offset(text: str) -> tuple[float, float]:
    """``--reference-offset FORWARD,LEFT``: two lengths in metres within 20 m of the axle."""
    parts = [v.strip() for v in text.split(",")]
    try:
        values = tuple(float(v) for v in parts)
    except ValueError as err:
        raise argparse.ArgumentTypeError(f"{text!r}: give the reference point's offset from "
                                         "the rear axle's midpoint as FORWARD,LEFT in metres, "
                                         "e.g. 1.2,-0.3") from err
    if len(values) != 2 or not all(math.isfinite(v) and abs(v) <= 20.0 for v in values):
        raise argparse.ArgumentTypeError(f"{text!r}: give FORWARD,LEFT in metres, each within "
                                         "20 m of the rear axle's midpoint")
    return values[0], values[1]


def add_quiet(p: argparse.ArgumentParser) -> None:
    """``-q`` and ``-v``, on every command."""
    p.add_argument("-q", "--quiet", action="store_true", help="print only errors")
    p.add_argument("-v", "--verbose", action="count", default=0,
                   help="more log output (-vv for debug); with an error, what led to it")


def add_config(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", metavar="TOML",
                   help="settings file, a path or a URL (docs: settings)")


def add_datasheet(p: argparse.ArgumentParser) -> None:
    p.add_argument("--datasheet", action=DatasheetAction, metavar="NAME=VALUE,...",
                   help="the vehicle's datasheet values, e.g. c_e=1.84,t_r=1.52 (effective "
                        "wheel circumference and rear track width, m; also c_d (m), d; or a "
                        "robot's wheel_radius=0.1,wheel_separation=0.4): the start of the fit, "
                        "the comparison in results and exports, and the centre of the "
                        "plausible ranges; repeatable, each name once")


def add_workers(p: argparse.ArgumentParser) -> None:
    p.add_argument("--workers", type=WORKERS, metavar="N",
                   help="processes for per-segment work (0 = every core; default from "
                        "settings)")


def add_common(p: argparse.ArgumentParser, *, workers: bool = True,
               datasheet: bool = True) -> None:
    """--config, --datasheet, --workers, -q, -v."""
    add_config(p)
    if datasheet:
        add_datasheet(p)
    if workers:
        add_workers(p)
    add_quiet(p)


def add_source(p: argparse.ArgumentParser, *, required: bool, converts: bool = True) -> None:
    """--from, --mapping, --scene; and for commands that convert, --reference and
    --circumference."""
    from odocal.io.registry import FORMATS

    p.add_argument("--from", dest="source_format", choices=FORMATS, required=required,
                   help="raw log format" + ("" if required else
                                            " (default: drive-format files, .csv or .parquet)"))
    p.add_argument("--mapping", metavar="TOML",
                   help="which files/topics and columns/fields hold each stream "
                        "(docs: real logs)")
    p.add_argument("--scene", action="append", metavar="NAME",
                   help="nuScenes scene to use (repeatable; default all; with --from nuscenes)")
    if not converts:
        return
    p.add_argument("--reference", choices=("auto", "fused", "gnss-imu"),
                   help="reference pose: the log's fused pose, or odocal's GNSS/IMU fusion "
                        "(default auto: the fused pose where the log has one)")
    p.add_argument("--circumference", type=number(0.05, 50.0, unit="m"), metavar="M",
                   help="the circumference wheel speeds in m/s or km/h are turned into wheel "
                        "rates with (default: the datasheet c_e); the calibration is then a "
                        "scale factor on the speed signal")
