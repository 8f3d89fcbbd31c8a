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
