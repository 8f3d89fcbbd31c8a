"""The twist variances the node states in each odometry message (``odocal.ros2.twist``), pinned
to values worked out by hand from the module's formula for a known speed and known noise (issue
38: the variance with the error model read in rev/s, where it is revolutions per window,
passed the node's tests). No ROS 2 is needed: the node publishes what these return."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from odocal.estimators.estimate import CovarianceKind, Estimate, Identified, Status
from odocal.model.parameters import Parameters
from odocal.ros2.twist import UNKNOWN_VARIANCE, TwistVariance

THETA = (1.9, 0.002, 1.55, 0.0005)           # c_e, c_d, t_r (m), d (m per m/s^2)
WINDOW_S = 2.0                               # [inverse] window_s
# the error model per channel (speed, yaw): s0 in revolutions per window, f per revolution
NOISE = np.array([[0.004, 0.01], [0.003, 0.008]])


def _estimate(covariance: np.ndarray) -> Estimate:
    theta = Parameters(*THETA)
    return Estimate(method="online", theta=theta, datasheet=theta, covariance=covariance,
                    covariance_kind=CovarianceKind.CLUSTER_ROBUST, free=(True,) * 4,
                    verdicts=(Identified(0.0, 1.0),) * 4, status=Status.CONVERGED,
                    details=SimpleNamespace(noise=NOISE))


def _twist(covariance: np.ndarray) -> TwistVariance:
    twist = TwistVariance(window_s=WINDOW_S, max_gap_s=0.1)
    assert twist.variances(2.0, 1.0, 1.0, 0.0) == (UNKNOWN_VARIANCE, UNKNOWN_VARIANCE)
    for k in range(20):                      # steady readings: no reading noise measured
        twist.readings.add(0.01 * k, 2.0, 0.1)
    twist.calibrate(_estimate(covariance))
    return twist


def test_the_twist_variance_at_a_known_speed_is_the_error_models_in_revolutions_per_window(
        ) -> None:
    var_v, var_w = _twist(np.zeros((4, 4))).variances(2.0, 1.0, 1.1, 0.5)
    # speed: (c_e s0 / W)^2 + (f v)^2 = (1.9 * 0.004 / 2)^2 + (0.01 * 2)^2
    assert var_v == pytest.approx(0.0038 ** 2 + 0.02 ** 2, rel=1e-12)        # 4.1444e-4
    # yaw rate: the same over t_r: (1.9 * 0.003 / (1.55 * 2))^2 + (0.008 * 2 / 1.55)^2
    assert var_w == pytest.approx((0.0057 / 3.1) ** 2 + (0.016 / 1.55) ** 2, rel=1e-12)
    assert var_w == pytest.approx(1.099365e-4, rel=1e-6)


def test_the_calibrations_own_uncertainty_adds_through_the_models_jacobian() -> None:
    covariance = np.zeros((4, 4))
    covariance[0, 0] = 1e-6                  # c_e known to 1 mm, the rest exactly
    n_rl, n_rr = 1.0, 1.1
    var_v, var_w = _twist(covariance).variances(2.0, n_rl, n_rr, 0.5)
    alone_v, alone_w = _twist(np.zeros((4, 4))).variances(2.0, n_rl, n_rr, 0.5)
    # v = (n_rl c_rl + n_rr c_rr) / 2, w = (n_rr c_rr - n_rl c_rl) / t_r, c_rl, c_rr = c_e +- ...
    assert var_v - alone_v == pytest.approx(1e-6 * ((n_rl + n_rr) / 2) ** 2, rel=1e-9)
    assert var_w - alone_w == pytest.approx(1e-6 * ((n_rr - n_rl) / 1.55) ** 2, rel=1e-9)
