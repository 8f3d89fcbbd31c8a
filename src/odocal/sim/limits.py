"""What the simulators accept, checked before anything is computed.

Light on purpose (nothing heavy imported): the command line checks its arguments with these
before it loads numpy. A value outside them is a :class:`~odocal.errors.ConfigError` that names
the argument and the range.
"""

from __future__ import annotations

import math
from typing import Any

from odocal.errors import ConfigError

#: The longest drive a simulation makes: 24 hours (``odocal simulate`` peaks at 1.96 GB and
#: 71 s for it on the development machine; memory grows with the length, so a longer one is
#: refused rather than started).
MAX_DURATION_S = 86_400.0
#: Seeds are non-negative integers below 2**63.
MAX_SEED = 2**63 - 1
#: A simulated fleet: at most this many vehicles and drives per vehicle.
MAX_VEHICLES = 1000
MAX_DRIVES = 1000
#: A simulated pressure loss or tread wear takes at most this share of ``c_e`` (5%: a flat
#: tyre on its rim; beyond it the "truth" would be no wheel).
MAX_CIRCUMFERENCE_LOSS = 0.05


def checked_seed(seed: Any, *, name: str = "seed") -> int:
    """``seed`` as an int, or a ConfigError: a seed is an integer from 0 to 2**63 - 1."""
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed <= MAX_SEED:
        raise ConfigError(f"{name} {seed!r} is invalid: a seed is an integer from 0 to "
                          f"{MAX_SEED}")
    return seed


def checked_duration(duration_s: Any, *, step_s: float = 0.025,
                     name: str = "duration") -> float:
    """``duration_s`` as a float, or a ConfigError: more than ten steps, at most a day."""
    value = _number(duration_s, name)
    if not (math.isfinite(value) and 10.0 * step_s < value <= MAX_DURATION_S):
        raise ConfigError(f"{name} {value:g} s is out of range: a simulated drive lasts more "
                          f"than {10.0 * step_s:g} s and at most {MAX_DURATION_S:g} s (24 h)")
    return value


def checked_share(value: Any, *, name: str, upper: float = MAX_CIRCUMFERENCE_LOSS) -> float:
    """A share of the circumference from 0 to ``upper``, or a ConfigError."""
    share = _number(value, name)
    if not (math.isfinite(share) and 0.0 <= share <= upper):
        raise ConfigError(f"{name} {share:g} is out of range: a share of c_e from 0 to "
                          f"{upper:g}")
    return share


def checked_count(value: Any, *, name: str, lower: int, upper: int) -> int:
    """An integer from ``lower`` to ``upper``, or a ConfigError."""
    if isinstance(value, bool) or not isinstance(value, int) or not lower <= value <= upper:
        raise ConfigError(f"{name} {value!r} is out of range: an integer from {lower} to "
                          f"{upper}")
    return value


def _number(value: Any, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ConfigError(f"{name} {value!r} is not a number")
    return float(value)
