"""Types of the command line's numeric arguments: each a range, checked by argparse before any
command runs (exit 2 with one line naming the argument and the range)."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable

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
