"""The live path on the issue's departures from the model (issue 32, "What to build"): a
reference delay, an a_y offset, a wheel-rate offset at standstill, truncated wheel speeds,
one-sided turning. The live path runs the batch default's core on its windows (the lag over a
second either way, the wheel-rate offset with its prior where the rates are encoded, the
identifiability judged jointly) and measures the sensors' departures as batch does, taking out
what it determines (odocal/online/departures.py).

Each test runs several values (none of the issue's) and asserts that no run ends in a confident
wrong number (a parameter reported identified with the truth beyond 3 of its standard
deviations): where the live path cannot be right it must say so (a wider uncertainty, not
identified, or a finding).
"""

from __future__ import annotations

from collections.abc import Callable

from tests.online import departures as dep
from tests.online.test_live_departures import confidently_wrong, pushed


def _wrong(make: Callable[[int], dep.Departed], seeds: range) -> dict[int, list[str]]:
    runs = {seed: pushed(make(seed)) for seed in seeds}
    return {seed: wrong for seed, run in runs.items() if (wrong := confidently_wrong(run))}


def test_a_late_or_early_reference_is_taken_out_or_named() -> None:
    delays = {20: 0.3, 21: -0.2, 22: 0.45, 23: 0.7}
    assert _wrong(lambda s: dep.reference_delay(s, duration_s=420.0, delay_s=delays[s]),
                  range(20, 24)) == {}


def test_an_offset_lateral_acceleration_is_taken_out() -> None:
    offsets = {24: 0.4, 25: -0.7, 26: 0.25}
    assert _wrong(lambda s: dep.lateral_offset(s, duration_s=420.0, offset_mps2=offsets[s]),
                  range(24, 27)) == {}


def test_wheels_turning_at_standstill_are_taken_out() -> None:
    offsets = {27: 0.04, 28: 0.06, 29: 0.025}
    assert _wrong(lambda s: dep.wheel_offset(s, duration_s=420.0, offset_revps=offsets[s]),
                  range(27, 30)) == {}


def test_truncated_wheel_speeds_are_taken_out() -> None:
    steps = {30: (1.0, "rpm"), 31: (0.1, "km/h"), 32: (0.5, "rpm")}
    assert _wrong(lambda s: dep.truncated(s, duration_s=420.0, step=steps[s][0],
                                          unit=steps[s][1]), range(30, 33)) == {}


def test_one_sided_turning_leaves_t_r_and_d_not_identified_together() -> None:
    cases = {33: (9.0, "left"), 34: (13.0, "slalom"), 35: (15.0, "left")}
    assert _wrong(lambda s: dep.one_sided(s, duration_s=420.0, speed_mps=cases[s][0],
                                          pattern=cases[s][1]), range(33, 36)) == {}
