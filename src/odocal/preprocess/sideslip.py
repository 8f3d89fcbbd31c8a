"""Sideslip from the course over ground against the heading, in bends (METHOD 7).

In a bend the velocity of the reference point points away from the vehicle's heading by the
sideslip angle: ``beta = course - psi``. On straights (small yaw rate) and at low speed the
difference is dominated by course noise, so beta is set to zero there; inside bends it is
smoothed with a moving average. It needs a course that does not come from the heading itself
(GNSS velocity, or a fused pose's velocity); the caller decides whether the log has one.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import uniform_filter1d

from odocal.arrays import FloatArray
from odocal.settings import SideslipSettings


def estimate_sideslip(course: FloatArray, psi: FloatArray, yaw_rate: FloatArray,
                      speed: FloatArray, *, rate_hz: float,
                      settings: SideslipSettings) -> FloatArray:
    """beta on the grid, rad: the wrapped course-heading difference in bends, zero elsewhere."""
    beta = np.remainder(course - psi + np.pi, 2 * np.pi) - np.pi
    bend = (np.abs(yaw_rate) > settings.bend_yaw_rate_radps) & (speed > settings.min_speed_mps)
    beta = np.where(bend & (np.abs(beta) <= settings.max_abs_rad), beta, 0.0)
    window = max(round(settings.smoothing_s * rate_hz), 1)
    smooth = uniform_filter1d(beta, size=window, mode="nearest")
    weight = uniform_filter1d(bend.astype(np.float64), size=window, mode="nearest")
    return np.where(bend, smooth / np.maximum(weight, 1e-9), 0.0)
