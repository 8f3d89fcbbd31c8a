"""A drive simulator with known true parameters: odocal's built-in example and test bench.

The route is a city/suburban drive built from randomly drawn elements:

* straights of 40-350 m at 10-15 m/s,
* bends of 10-100 m radius turning 20-120 degrees, entered and left along clothoids (the
  curvature ramps linearly, so the yaw rate has no jumps), at the speed a lateral acceleration of
  2-3.5 m/s^2 allows,
* intersections: a stop of 2-25 s before a tight 90-degree turn (8-15 m radius),
* roundabouts: a right-hand entry, a 90-270 degree left arc of 12-25 m radius, a right-hand exit.

A speed profile with acceleration and braking limits (1.5 and 2.5 m/s^2) runs along it and comes
to rest at each stop. The true yaw rate is ``w = v kappa``, the lateral acceleration
``a_y = v w`` and the sideslip that of a linear single-track model at the centre of gravity. The
true wheel rates are the inverse of the model (METHOD 1) with the true parameters, and the true
poses are the model's rollout of them, so a noise-free drive fits the model exactly.

Noise profiles (:data:`odocal.sim.noise.NOISE_PROFILES`) corrupt the measurements the way real
sensors do; see :class:`odocal.sim.noise.NoiseProfile`. Everything is deterministic for a given
seed.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from odocal.arrays import FloatArray
from odocal.data.drive import Drive
from odocal.errors import ConfigError
from odocal.model._jit import jit
from odocal.model.kinematics import rollout, wheel_rates_for
from odocal.model.parameters import Inputs, Parameters
from odocal.model.vehicle import MODEL
from odocal.settings import vehicle_problem
from odocal.sim.limits import checked_duration, checked_seed
from odocal.sim.noise import NOISE_PROFILES, NoiseProfile

__all__ = ["NOISE_PROFILES", "TRUE_PARAMETERS", "NoiseProfile", "SimulatedDrive", "simulate"]


#: True parameters of the simulated small car (c_e, c_d, t_r, d), close to the paper's Nissan Leaf.
TRUE_PARAMETERS = Parameters(c_e=1.952, c_d=-0.0021, t_r=1.527, d=0.00076)

_DS = 0.1                 # arc-length grid of the route, m
_ACCEL_MPS2 = 1.5         # acceleration limit of the speed profile
_BRAKE_MPS2 = 2.5         # braking limit
_MASS_KG, _L_F, _L_R = 1500.0, 1.1, 1.5   # single-track model for the sideslip
_C_REAR_NPRAD = 90000.0   # rear-axle cornering stiffness


@dataclass(frozen=True)
class SimulatedDrive:
    """A simulated drive and the truth behind it.

    drive : the measurements, as a user's log would give them
    true_parameters : theta used to simulate
    true_n_rl, true_n_rr : noise-free wheel rates, rev/s, shape (M,)
    true_poses : noise-free poses, shape (M, 3)
    profile : the noise profile applied
    seed : the seed
    changed : whether the wheels turn as another theta from some time on (``change``)
    """

    drive: Drive
    true_parameters: Parameters
    true_n_rl: FloatArray
    true_n_rr: FloatArray
    true_poses: FloatArray
    profile: NoiseProfile
    seed: int
    changed: bool = False

    def cramer_rao_bound(self) -> FloatArray | None:
        """The covariance no unbiased calibration of this drive can beat, shape (n, n): the
        wheel errors' Cramér-Rao bound (:mod:`odocal.sim.bound`; the reference pose taken as
        exact), or None where it does not apply (no wheel error it counts, or tick counts)."""
        from odocal.sim.bound import information_bound
        if self.changed:
            raise ConfigError("a drive simulated with a change has no one theta to bound")
        return information_bound(self.true_parameters.as_array(), self.true_n_rl,
                                 self.true_n_rr, self.profile, self.drive.t_s)

    def truth_dict(self) -> dict[str, Any]:
        """The truth as written to ``<drive>.truth.json``."""
        return {"theta": self.true_parameters.as_dict(), "noise_profile": self.profile.as_dict(),
                "seed": self.seed, "t_s": self.drive.t_s,
                "n_rl": self.true_n_rl.tolist(), "n_rr": self.true_n_rr.tolist()}


def simulate(*, duration_s: float = 1800.0, seed: int = 0, noise: str | NoiseProfile = "realistic",
             theta: Parameters | None = None, t_s: float = 0.025,
             name: str | None = None,
             change: tuple[float, Parameters] | None = None,
             noise_seed: int | None = None, route: str = "city") -> SimulatedDrive:
    """Simulate a city drive with known true parameters.

    Parameters
    ----------
    duration_s : length of the drive, s (at most a day: :mod:`odocal.sim.limits`)
    seed : seeds the route, the speed profile and the noise (an integer from 0 to 2**63 - 1)
    noise : a name in :data:`NOISE_PROFILES` or a :class:`NoiseProfile`
    theta : true parameters (default :data:`TRUE_PARAMETERS`)
    t_s : sampling time, s (0.001 to 0.1: the rates a drive may have)
    change : ``(t, new_theta)``: from time t on, the wheels turn as ``new_theta`` makes them
        (a tyre pressure change within the drive); ``true_parameters`` are those before
    noise_seed : draws the noise from its own seed, so one route (``seed``) can be driven with
        many noise draws (a Monte Carlo over the noise alone); by default ``seed`` draws both
    route : one of :data:`ROUTES`: ``city`` (bends both ways, intersections, roundabouts,
        stops, 10-15 m/s), ``left`` (the same bends, every one to the left, at one speed, no
        stops) or ``slalom`` (a sine of curvature at one speed): on the last two the lateral
        acceleration is the speed times the yaw rate at one speed, so t_r and d act alike
    """
    profile, duration_s, seed, noise_seed = _checked(
        noise=noise, route=route, t_s=t_s, duration_s=duration_s, seed=seed,
        noise_seed=noise_seed, theta=theta, change=change)
    true_theta = (theta or TRUE_PARAMETERS).as_array()
    rng = np.random.default_rng(seed)
    m = round(duration_s / t_s) + 1
    v, w, a_y, beta, n_rl, n_rr = _true_signals(rng, true_theta, duration_s=duration_s,
                                                route=route, m=m, t_s=t_s, change=change)
    poses = _true_poses(rng, true_theta, v, w, a_y, beta, t_s)

    if noise_seed is not None:
        rng = np.random.default_rng([seed, noise_seed])
    meas_rl, meas_rr, meas_ay, meas_beta, ref = _corrupt(rng, profile, v, n_rl, n_rr, a_y,
                                                         beta, poses, t_s)
    t = np.arange(m) * t_s
    drive = Drive.from_columns(
        {"t": t, "n_rl": meas_rl, "n_rr": meas_rr, "a_y": meas_ay, "beta": meas_beta,
         "x": ref[:, 0], "y": ref[:, 1], "psi": ref[:, 2]},
        name=name or (f"simulated-{profile.name}-seed{seed}"
                      + ("" if noise_seed is None else f"-noise{noise_seed}")),
        metadata={"source": "odocal.sim.simulate", "seed": seed, "noise_profile": profile.name,
                  **({} if noise_seed is None else {"noise_seed": noise_seed}),
                  "true_theta": (theta or TRUE_PARAMETERS).as_dict()},
        circumference_m=MODEL.layout.value(true_theta, MODEL.layout.scale))
    return SimulatedDrive(drive=drive, true_parameters=Parameters.from_array(true_theta),
                          true_n_rl=n_rl, true_n_rr=n_rr, true_poses=poses, profile=profile,
                          seed=seed, changed=change is not None)


def _checked(*, noise: str | NoiseProfile, route: str, t_s: float, duration_s: float,
             seed: int, noise_seed: int | None, theta: Parameters | None,
             change: tuple[float, Parameters] | None
             ) -> tuple[NoiseProfile, float, int, int | None]:
    """:func:`simulate`'s arguments checked once (a ConfigError names the bad one).

    Returns the noise profile, the duration (s), the seed and the noise seed.
    """
    if isinstance(noise, str):
        if noise not in NOISE_PROFILES:
            raise ConfigError(f"unknown noise profile {noise!r}; choose one of "
                              f"{', '.join(NOISE_PROFILES)}")
        profile = NOISE_PROFILES[noise]
    else:
        profile = noise
    if route not in ROUTES:
        raise ConfigError(f"unknown route {route!r}; choose one of {', '.join(ROUTES)}")
    if isinstance(t_s, bool) or not isinstance(t_s, int | float) or not 0.001 <= t_s <= 0.1:
        raise ConfigError(f"sampling time {t_s!r} s is out of range: 0.001 to 0.1 s "
                          "(1 kHz to 10 Hz)")
    duration_s = checked_duration(duration_s, step_s=t_s, name="duration")
    seed = checked_seed(seed)
    if noise_seed is not None:
        noise_seed = checked_seed(noise_seed, name="noise_seed")
    for label, given in (("theta", theta), ("change", change[1] if change else None)):
        problem = vehicle_problem(given.as_array()) if given is not None else None
        if problem is not None:
            raise ConfigError(f"simulate: {label}: {problem}")
    return profile, duration_s, seed, noise_seed


def _true_signals(rng: np.random.Generator, true_theta: FloatArray, *, duration_s: float,
                  route: str, m: int, t_s: float, change: tuple[float, Parameters] | None
                  ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray,
                             FloatArray]:
    """The true motion along a drawn route and the wheel rates it takes (METHOD 1), the
    rates after ``change``'s time those of its parameters.

    Returns ``(v, w, a_y, beta, n_rl, n_rr)``, each shape (m,): speed (m/s), yaw rate
    (rad/s), lateral acceleration (m/s^2), sideslip (rad) and the wheel rates (rev/s).
    """
    kappa_s, vmax_s, stops = _route(rng, duration_s, route)
    v, kappa = _drive_along(kappa_s, vmax_s, stops, m, t_s)
    w = v * kappa                                      # yaw rate, rad/s
    a_y = v * w                                        # lateral acceleration, m/s^2
    beta = kappa * (_L_R - _MASS_KG * _L_F * v**2 / (_C_REAR_NPRAD * (_L_F + _L_R)))
    n_rl, n_rr = wheel_rates_for(true_theta, v, w, a_y)
    if change is not None:
        if not (np.isfinite(change[0]) and 0 <= change[0]):
            raise ConfigError(f"change time {change[0]} s must be a time within the drive")
        after = np.arange(m) * t_s >= change[0]
        later_rl, later_rr = wheel_rates_for(change[1].as_array(), v, w, a_y)
        n_rl, n_rr = np.where(after, later_rl, n_rl), np.where(after, later_rr, n_rr)
    return v, w, a_y, beta, n_rl, n_rr


def _true_poses(rng: np.random.Generator, true_theta: FloatArray, v: FloatArray,
                w: FloatArray, a_y: FloatArray, beta: FloatArray, t_s: float) -> FloatArray:
    """The true poses, shape (m, 3), from a drawn heading at the origin: the true motion
    (v, w) whatever the wheels, rolled out with the rates of the first theta."""
    x0 = np.array([0.0, 0.0, rng.uniform(-np.pi, np.pi)])
    # the true motion (v, w) whatever the wheels: rolled out with the rates of the first theta
    first_rl, first_rr = wheel_rates_for(true_theta, v, w, a_y)
    return rollout(true_theta, Inputs(first_rl[:-1], first_rr[:-1], beta[:-1], a_y[:-1]), x0,
                   t_s)


#: The routes :func:`simulate` drives.
ROUTES = ("city", "left", "slalom")
#: The one speed of the ``left`` and ``slalom`` routes, m/s.
_STEADY_MPS = 8.0


def _route(rng: np.random.Generator, duration_s: float, route: str = "city"
           ) -> tuple[FloatArray, FloatArray, list[tuple[float, float]]]:
    """Curvature and speed limit on a 0.1 m arc-length grid, and the stops (s, dwell)."""
    if route == "slalom":
        length = 15.0 * duration_s * 1.1 + 500.0
        s = np.arange(int(length / _DS)) * _DS
        period = rng.uniform(60.0, 120.0)                  # m per left-right cycle
        wave = np.minimum(s / 60.0, 1.0) * np.sin(2.0 * np.pi * s / period) / rng.uniform(
            25.0, 40.0)
        return wave, np.full(s.shape, _STEADY_MPS), []
    kappa: list[FloatArray] = []
    vmax: list[FloatArray] = []
    stops: list[tuple[float, float]] = []
    length = 0.0
    # Enough route for the duration even at the top speed, plus margin.
    needed = 15.0 * duration_s * 1.1 + 500.0

    def add(k: FloatArray, v: float | FloatArray) -> None:
        nonlocal length
        kappa.append(k)
        vmax.append(np.broadcast_to(np.asarray(v, dtype=np.float64), k.shape).copy())
        length += k.shape[0] * _DS

    def arc(radius: float, angle: float, speed: float) -> None:
        """A bend turning ``angle`` (rad, sign = direction) with clothoid ends."""
        if route == "left":
            angle, speed = abs(angle), _STEADY_MPS
        curvature = np.sign(angle) / radius
        total = abs(angle) * radius
        ramp = min(max(0.3 * total, 6.0), total, 25.0)    # clothoid length, m
        n_ramp = max(int(ramp / _DS), 1)
        n_body = max(int((total - ramp) / _DS), 0)  # two half-ramps turn as much as one ramp
        up = np.linspace(0.0, curvature, n_ramp, endpoint=False)
        add(np.concatenate([up, np.full(n_body, curvature), up[::-1]]), speed)

    def straight(meters: float, speed: float) -> None:
        add(np.zeros(max(int(meters / _DS), 1)), _STEADY_MPS if route == "left" else speed)

    straight(60.0, 12.0)
    while length < needed:
        kind = rng.choice(["bend", "intersection", "roundabout", "straight"],
                          p=[0.45, 0.2, 0.1, 0.25])
        if kind == "bend":
            radius = rng.uniform(10.0, 100.0)
            angle = np.deg2rad(rng.uniform(20.0, 120.0)) * rng.choice([-1.0, 1.0])
            arc(radius, angle, min(15.0, np.sqrt(rng.uniform(2.0, 3.5) * radius)))
        elif kind == "intersection":
            if rng.random() < 0.7 and route == "city":
                stops.append((length, rng.uniform(2.0, 25.0)))
            radius = rng.uniform(8.0, 15.0)
            arc(radius, np.deg2rad(90.0) * rng.choice([-1.0, 1.0]), np.sqrt(2.5 * radius))
        elif kind == "roundabout":
            radius = rng.uniform(12.0, 25.0)
            speed = np.sqrt(2.5 * radius)
            arc(15.0, -np.deg2rad(30.0), speed)
            arc(radius, np.deg2rad(rng.uniform(90.0, 270.0)) + np.deg2rad(60.0), speed)
            arc(15.0, -np.deg2rad(30.0), speed)
        straight(rng.uniform(40.0, 350.0), rng.uniform(10.0, 15.0))
    return np.concatenate(kappa), np.concatenate(vmax), stops


def _drive_along(kappa_s: FloatArray, vmax_s: FloatArray, stops: list[tuple[float, float]],
                 m: int, t_s: float) -> tuple[FloatArray, FloatArray]:
    """Speed v(t) and curvature kappa(t) on the time grid for a speed profile along the route."""
    n = kappa_s.shape[0]
    v = vmax_s.copy()
    v[0] = 0.0
    stop_idx = [min(int(s / _DS), n - 1) for s, _ in stops]
    v[stop_idx] = 0.0
    two_a, two_b = 2.0 * _ACCEL_MPS2 * _DS, 2.0 * _BRAKE_MPS2 * _DS
    # forward pass (acceleration limit) and backward pass (braking limit), on v^2
    v2 = v**2
    for i in range(1, n):
        v2[i] = min(v2[i], v2[i - 1] + two_a)
    for i in range(n - 2, -1, -1):
        v2[i] = min(v2[i], v2[i + 1] + two_b)
    v = np.sqrt(v2)
    # Between grid points the acceleration is constant: a = (v1^2 - v0^2) / (2 ds), a cell takes
    # 2 ds / (v0 + v1), and s(tau) = s0 + v0 tau + a tau^2 / 2 inside it (exact from rest too).
    accel = (v2[1:] - v2[:-1]) / (2.0 * _DS)
    cell_time = 2.0 * _DS / np.maximum(v[1:] + v[:-1], 1e-9)
    dwell = np.zeros(n)
    for (_, d), i in zip(stops, stop_idx, strict=True):
        dwell[i] += d
    arrive = np.concatenate([[0.0], np.cumsum(cell_time + dwell[:-1])])
    depart = arrive + dwell
    t_out = np.arange(m + 1) * t_s
    if depart[-1] < t_out[-1]:
        raise RuntimeError("the simulated route is too short for the duration")  # pragma: no cover
    j = np.clip(np.searchsorted(arrive, t_out, side="right") - 1, 0, n - 2)
    tau = np.clip(t_out - depart[j], 0.0, cell_time[j])    # negative while dwelling at point j
    s = j * _DS + v[j] * tau + 0.5 * accel[j] * tau**2
    speed = np.diff(s) / t_s                           # exact displacement per step, (m,)
    s_mid = 0.5 * (s[1:] + s[:-1])
    curvature = np.interp(s_mid, np.arange(n) * _DS, kappa_s)
    return speed, curvature


@jit
def _ar1(drive: FloatArray, first: FloatArray, phi: float) -> FloatArray:  # pragma: no cover
    """out[0] = first, out[k] = phi out[k-1] + drive[k] along axis 0."""
    out = np.empty_like(drive)
    out[0] = first
    for k in range(1, drive.shape[0]):
        out[k] = phi * out[k - 1] + drive[k]
    return out


def _gauss_markov(rng: np.random.Generator, shape: tuple[int, ...], std: float, tau_s: float,
                  t_s: float) -> FloatArray:
    """Stationary first-order Gauss-Markov noise along axis 0 with the given std."""
    if std == 0.0:
        return np.zeros(shape)
    phi = float(np.exp(-t_s / tau_s))
    drive = rng.standard_normal(shape) * std * np.sqrt(1.0 - phi**2)
    first = rng.standard_normal(shape[1:]) * std
    return np.asarray(_ar1(drive.reshape(shape[0], -1), first.reshape(-1), phi)).reshape(shape)


def _wheel_errors(rng: np.random.Generator, profile: NoiseProfile, v: FloatArray,
                  rates: FloatArray, t_s: float) -> FloatArray:
    """The measured rates (M, 2) from the true ones: delay, slip, quantisation, noise."""
    m = rates.shape[0]
    true = rates
    if profile.wheel_delay_s:
        t = np.arange(m) * t_s
        rates = np.column_stack([np.interp(t - profile.wheel_delay_s, t, rates[:, i])
                                 for i in range(2)])
    if profile.slip_fraction or profile.slip_differential or profile.slip_per_accel:
        common = _gauss_markov(rng, (m, 1), profile.slip_fraction, profile.slip_correlation_s, t_s)
        own = _gauss_markov(rng, (m, 2), profile.slip_differential / np.sqrt(2),
                            profile.slip_correlation_s, t_s)
        a_x = np.gradient(v, t_s)
        rates = rates * (1.0 + common + own + profile.slip_per_accel * a_x[:, None])
    if profile.ticks_per_rev:
        # integer tick counters read every sample; the rate is the count difference
        turns = np.concatenate([np.zeros((1, 2)), np.cumsum(rates, axis=0) * t_s])
        angle = (rng.uniform(0, 1, (1, 2)) + turns) * profile.ticks_per_rev
        ticks = np.floor(angle)
        w = profile.tick_window
        lagged = np.concatenate([np.repeat(ticks[:1], w - 1, axis=0), ticks])[:-w]
        rates = (ticks[1:] - lagged[:m]) / (profile.ticks_per_rev * w * t_s)
    rates = rates + _gauss_markov(rng, (m, 2), profile.wheel_markov_revps,
                                  profile.wheel_markov_correlation_s, t_s)
    if profile.wheel_white_revps or profile.wheel_white_fraction:
        std = np.hypot(profile.wheel_white_revps, profile.wheel_white_fraction * np.abs(rates))
        rates = rates + rng.standard_normal((m, 2)) * std
    if not profile.wheels_exact:
        rates = np.where(true == 0.0, 0.0, rates)              # encoders read 0 at rest
    return rates


def _corrupt(rng: np.random.Generator, profile: NoiseProfile, v: FloatArray, n_rl: FloatArray,
             n_rr: FloatArray, a_y: FloatArray, beta: FloatArray, poses: FloatArray,
             t_s: float
             ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:
    m = n_rl.shape[0]
    rates = _wheel_errors(rng, profile, v, np.column_stack([n_rl, n_rr]), t_s)
    meas_ay = a_y + rng.standard_normal(m) * profile.lateral_accel_mps2
    meas_beta = beta * (1.0 + _gauss_markov(rng, (m, 1), profile.sideslip_fraction,
                                            profile.slip_correlation_s, t_s)[:, 0])
    ref = poses.copy()
    for pos, head, tau in ((profile.reference_position_m, profile.reference_heading_rad,
                            profile.reference_correlation_s),
                           (profile.reference_slow_position_m, profile.reference_slow_heading_rad,
                            profile.reference_slow_correlation_s)):
        ref[:, :2] += _gauss_markov(rng, (m, 2), pos, tau, t_s)
        ref[:, 2] += _gauss_markov(rng, (m, 1), head, tau, t_s)[:, 0]
    ref[:, 2] = np.remainder(ref[:, 2] + np.pi, 2 * np.pi) - np.pi   # a wrapped heading, as logged
    return rates[:, 0], rates[:, 1], meas_ay, meas_beta, ref
