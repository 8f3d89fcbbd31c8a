"""The quality gate's plausible ranges (issue 25: they follow the datasheet)."""

from __future__ import annotations

import numpy as np
import pytest

from odocal.checks.findings import Check
from odocal.checks.gate import gate, plausible_range
from odocal.settings import Settings


def test_ranges_follow_the_datasheet_unless_fixed_per_parameter() -> None:
    robot = Settings().replace(identify={"theta0": (0.44, 0.0, 0.30, 0.0)})
    assert plausible_range(robot, "c_e") == pytest.approx((0.22, 0.88))
    assert plausible_range(robot, "t_r") == pytest.approx((0.15, 0.60))
    fixed_t_r = robot.replace(gate={"t_r_m": (0.2, 0.4)})
    assert plausible_range(fixed_t_r, "t_r") == (0.2, 0.4)
    assert plausible_range(fixed_t_r, "c_e") == pytest.approx((0.22, 0.88))   # untouched
    fixed_c_e = robot.replace(gate={"c_e_m": (0.4, 0.5), "range_factor": 3.0})
    assert plausible_range(fixed_c_e, "c_e") == (0.4, 0.5)
    assert plausible_range(fixed_c_e, "t_r") == pytest.approx((0.10, 0.90))


@pytest.mark.parametrize(("c_e", "t_r", "name", "bound"), [
    (0.30, 0.30, "c_e", 0.5), (6.0, 0.30, "c_e", 5.0), (0.6, 0.05, "t_r", 0.15),
    (0.6, 0.9, "t_r", 0.6)])
def test_a_value_outside_its_range_names_the_bound_it_crossed(c_e: float, t_r: float, name: str,
                                                             bound: float) -> None:
    settings = Settings().replace(identify={"theta0": (0.44, 0.0, 0.30, 0.0)},
                                  gate={"c_e_m": (0.5, 5.0)})
    found = gate(np.array([c_e, 0.0, t_r, 0.0]), settings, error_m=None,
                 datasheet_error_m=None, segment_m=None)
    [finding] = [f for f in found if f.check is Check.PARAMETER_RANGE]
    assert finding.name == name and finding.reference == pytest.approx(bound)


def test_a_load_transfer_or_wheel_difference_out_of_range_is_named_with_its_limit() -> None:
    """|d| beyond [gate] max_abs_d and |c_d| beyond its share of c_e: each a parameter-range
    finding naming the parameter, its value and the limit it crossed."""
    settings = Settings()
    lim = settings.gate
    d = 2.0 * lim.max_abs_d
    c_d = -2.0 * lim.max_abs_c_d_fraction * 1.95
    found = gate(np.array([1.95, c_d, 1.53, d]), settings, error_m=None,
                 datasheet_error_m=None, segment_m=None)
    named = {f.name: f for f in found}
    assert set(named) == {"c_d", "d"}
    assert all(f.check is Check.PARAMETER_RANGE for f in found)
    assert named["d"].value == d and named["d"].reference == lim.max_abs_d
    assert named["c_d"].value == c_d
    assert named["c_d"].reference == pytest.approx(lim.max_abs_c_d_fraction * 1.95)
