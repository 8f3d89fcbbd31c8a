"""What corrupts a simulated drive: the noise profiles of the simulator and the noise matrix.

A :class:`NoiseProfile` describes the errors real sensors make, each switched off at zero:

* wheel encoders: white noise of a constant level and of a level proportional to the rate;
  coloured (first-order Gauss-Markov) errors; slip, common to both wheels and differential,
  correlated over about a second and growing with acceleration; quantisation of tick counts
  differenced over a window, as an ABS unit reports the rate; a clock delay of the wheel stream;
* the reference pose: errors a GNSS/INS filter or smoother leaves, correlated in time at two scales
  (seconds: the filter's own dynamics; a minute: multipath and GNSS bias drift);
* the IMU's lateral acceleration (white) and the filtered sideslip (relative, correlated).

:data:`NOISE_PROFILES` is the simulator's menu and the rows of the noise-matrix benchmark
(``benchmarks/bench_matrix.py``). This module imports nothing heavy (the command line lists the
profiles without loading numpy).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from types import MappingProxyType
from typing import Any


@dataclass(frozen=True)
class NoiseProfile:
    """What corrupts the simulated measurements (all zero: a noise-free drive).

    wheel_white_revps : white Gaussian noise on each wheel rate, rev/s (std)
    wheel_white_fraction : white Gaussian noise proportional to the rate (std over |rate|)
    wheel_markov_revps : first-order Gauss-Markov error on each wheel rate (std, rev/s), each wheel
        its own, correlation time ``wheel_markov_correlation_s``
    slip_fraction : wheel slip proportional to speed: std of a first-order Gauss-Markov slip ratio
        common to both rear wheels, correlation time ``slip_correlation_s``
    slip_differential : std of the part of the slip ratio that differs between the wheels
        (it turns into a false yaw rate, so it is much smaller than the common part)
    slip_per_accel : common slip ratio per m/s^2 of longitudinal acceleration (positive when
        accelerating, negative when braking)
    ticks_per_rev : encoder quantisation (0: off): the rate is the change of an integer tick count
        over the last ``tick_window`` samples, as an ABS unit reports it. 96 is a 48-tooth tone ring
        counted on both edges
    tick_window : samples the tick count is differenced over
    wheel_delay_s : the wheel stream lags the truth by this (an uncorrected clock offset), s
    reference_position_m, reference_heading_rad : std of the fast part of the reference pose
        error (a good GNSS/INS filter's): first-order Gauss-Markov, correlation
        ``reference_correlation_s``
    reference_slow_position_m, reference_slow_heading_rad : std of the slow part (multipath, GNSS
        bias drift), correlation ``reference_slow_correlation_s``
    lateral_accel_mps2 : white noise on the IMU lateral acceleration (std)
    sideslip_fraction : relative error of the filtered sideslip (std, correlated like slip)
    """

    name: str
    description: str
    wheel_white_revps: float = 0.0
    wheel_white_fraction: float = 0.0
    wheel_markov_revps: float = 0.0
    wheel_markov_correlation_s: float = 0.5
    slip_fraction: float = 0.0
    slip_differential: float = 0.0
    slip_per_accel: float = 0.0
    slip_correlation_s: float = 1.0
    ticks_per_rev: int = 0
    tick_window: int = 4
    wheel_delay_s: float = 0.0
    reference_position_m: float = 0.0
    reference_heading_rad: float = 0.0
    reference_correlation_s: float = 5.0
    reference_slow_position_m: float = 0.0
    reference_slow_heading_rad: float = 0.0
    reference_slow_correlation_s: float = 60.0
    lateral_accel_mps2: float = 0.0
    sideslip_fraction: float = 0.0

    def as_dict(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @property
    def wheels_exact(self) -> bool:
        """Whether the measured wheel rates are the true ones."""
        return not any((self.wheel_white_revps, self.wheel_white_fraction,
                        self.wheel_markov_revps, self.slip_fraction, self.slip_differential,
                        self.slip_per_accel, self.ticks_per_rev, self.wheel_delay_s))


_DEG = math.pi / 180.0
_REALISTIC: dict[str, Any] = {
    "wheel_white_revps": 0.01, "slip_fraction": 0.003, "slip_differential": 0.0003,
    "slip_per_accel": 0.002, "ticks_per_rev": 96, "reference_position_m": 0.05,
    "reference_heading_rad": 0.2 * _DEG, "lateral_accel_mps2": 0.05, "sideslip_fraction": 0.1}
_SLIP: dict[str, Any] = {"slip_fraction": 0.005, "slip_differential": 0.0005,
                         "slip_per_accel": 0.003}

NOISE_PROFILES: MappingProxyType[str, NoiseProfile] = MappingProxyType({p.name: p for p in (
    NoiseProfile("none", "noise-free: the measurements are the truth"),
    NoiseProfile("white", "white wheel-rate noise of 0.02 rev/s per wheel",
                 wheel_white_revps=0.02),
    NoiseProfile("white-2x", "white wheel-rate noise of 0.04 rev/s per wheel",
                 wheel_white_revps=0.04),
    NoiseProfile("white-5x", "white wheel-rate noise of 0.10 rev/s per wheel",
                 wheel_white_revps=0.10),
    NoiseProfile("white-rate", "white wheel-rate noise growing with the rate: 1% of the rate "
                 "plus 0.005 rev/s", wheel_white_revps=0.005, wheel_white_fraction=0.01),
    NoiseProfile("markov", "coloured wheel-rate errors: 0.015 rev/s per wheel, first-order "
                 "Gauss-Markov over 0.5 s", wheel_markov_revps=0.015),
    NoiseProfile("slip", "wheel slip: 0.5% of speed common to both wheels and 0.05% between them, "
                 "correlated over 1 s, plus 0.3% per m/s^2 of acceleration", **_SLIP),
    NoiseProfile("slip-heavy", "slip-dominated: 1% of speed common and 0.1% between the wheels, "
                 "correlated over 1 s, plus 0.6% per m/s^2 of acceleration, and 0.005 rev/s white",
                 slip_fraction=0.01, slip_differential=0.001, slip_per_accel=0.006,
                 wheel_white_revps=0.005),
    NoiseProfile("quantised", "encoder quantisation: 96 ticks per revolution, counted over 100 ms",
                 ticks_per_rev=96),
    NoiseProfile("quantised-coarse", "encoder quantisation: 48 ticks per revolution, counted "
                 "over 50 ms", ticks_per_rev=48, tick_window=2),
    NoiseProfile("delay", "the wheel stream lags the poses by 40 ms (an uncorrected clock "
                 "offset), with 0.005 rev/s white noise", wheel_delay_s=0.04,
                 wheel_white_revps=0.005),
    NoiseProfile("reference", "reference pose error of a good GNSS/INS filter: 5 cm and 0.2 deg, "
                 "correlated over 5 s", reference_position_m=0.05,
                 reference_heading_rad=0.2 * _DEG),
    NoiseProfile("reference-fused", "reference pose error of a GNSS/INS smoother at two time "
                 "scales: 5 cm and 0.1 deg over 2 s, plus 30 cm and 0.3 deg over 60 s",
                 reference_position_m=0.05, reference_heading_rad=0.1 * _DEG,
                 reference_correlation_s=2.0, reference_slow_position_m=0.3,
                 reference_slow_heading_rad=0.3 * _DEG),
    NoiseProfile("heavy", "heavy white noise with slip: 0.05 rev/s white plus the slip profile",
                 wheel_white_revps=0.05, **_SLIP),
    NoiseProfile("realistic", "all of it: white noise, slip, quantisation, reference error, IMU "
                 "and sideslip errors", **_REALISTIC),
    NoiseProfile("everything", "realistic plus coloured wheel errors (0.02 rev/s over 0.5 s), a "
                 "20 ms wheel delay and the two-scale reference error",
                 **{**_REALISTIC, "wheel_markov_revps": 0.02, "wheel_delay_s": 0.02,
                    "reference_heading_rad": 0.1 * _DEG, "reference_correlation_s": 2.0,
                    "reference_slow_position_m": 0.3, "reference_slow_heading_rad": 0.3 * _DEG}),
)})
