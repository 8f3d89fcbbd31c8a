"""Departures from the model's assumptions, as real sensors and set-ups make them.

Each departure turns a simulated drive (known truth) into the drive a user with that sensor or
set-up would log: a reference pose that is late, an IMU tilted by a roll angle, wheel rates with
an offset or truncated by their CAN encoding, a compass heading with a heading-dependent error,
the front wheels' speeds logged as the rear ones. The calibration of such a drive must be right,
or say why it cannot be (a named finding, or an uncertainty that covers its error): never a
confident wrong number. ``benchmarks/bench_departures.py`` runs them over seeds and values; the
tests run others.

Routes and drive lengths that weaken the data (turns to one side only at one speed, a slalom,
a one-minute drive) and a change inside a log are options of :func:`~odocal.sim.simulate` itself
(``route``, ``duration_s``, ``change``); :func:`simulate_departure` names them all alike.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from types import MappingProxyType

import numpy as np

from odocal.arrays import FloatArray
from odocal.data.drive import Drive
from odocal.errors import ConfigError
from odocal.model.parameters import Parameters
from odocal.model.vehicle import MODEL
from odocal.sim.simulate import TRUE_PARAMETERS, SimulatedDrive, simulate

#: Wheelbase and front track of the simulated car (m): where its front wheels are.
WHEELBASE_M, FRONT_TRACK_M = 2.70, 1.54


def _columns(drive: Drive) -> dict[str, FloatArray]:
    cols = dict(drive.columns())
    cols.pop("yaw_rate", None)          # derived from psi again where psi changes
    return cols


def _rebuilt(sim: SimulatedDrive, cols: Mapping[str, FloatArray], what: str) -> SimulatedDrive:
    drive = Drive.from_columns(cols, name=f"{sim.drive.name}-{what}",
                               metadata={**sim.drive.metadata, "departure": what})
    return dataclasses.replace(sim, drive=drive)


def reference_delay(sim: SimulatedDrive, delay_s: float) -> SimulatedDrive:
    """The reference pose ``delay_s`` late against the wheels and the IMU (early if negative):
    a localisation stack's latency, or a clock offset between two loggers."""
    cols = _columns(sim.drive)
    t = cols["t"]
    psi = np.unwrap(cols["psi"])
    for key, values in (("x", cols["x"]), ("y", cols["y"]), ("psi", psi)):
        cols[key] = np.interp(t - delay_s, t, values)
    return _rebuilt(sim, cols, f"reference-{delay_s:+g}s")


def lateral_offset(sim: SimulatedDrive, offset_mps2: float) -> SimulatedDrive:
    """A constant offset on the lateral acceleration: an IMU rolled by ``asin(offset / g)``
    (0.5 m/s^2 is a 2.9 degree tilt), or a road's constant bank."""
    cols = _columns(sim.drive)
    cols["a_y"] = cols["a_y"] + offset_mps2
    return _rebuilt(sim, cols, f"a_y{offset_mps2:+g}")


def wheel_offset(sim: SimulatedDrive, offset_revps: float) -> SimulatedDrive:
    """Both wheel rates read ``offset_revps`` more, standing or moving (a biased speed signal:
    the wheels "turn" while the vehicle stands)."""
    cols = _columns(sim.drive)
    cols["n_rl"] = cols["n_rl"] + offset_revps
    cols["n_rr"] = cols["n_rr"] + offset_revps
    return _rebuilt(sim, cols, f"wheels{offset_revps:+g}revps")


def truncated_rpm(sim: SimulatedDrive, step_rpm: float = 1.0) -> SimulatedDrive:
    """Wheel rates truncated (towards zero) to whole multiples of ``step_rpm``: a CAN signal in
    rpm whose encoder drops the fraction."""
    cols = _columns(sim.drive)
    for key in ("n_rl", "n_rr"):
        rpm = cols[key] * 60.0
        cols[key] = np.trunc(rpm / step_rpm) * step_rpm / 60.0
    return _rebuilt(sim, cols, f"trunc{step_rpm:g}rpm")


def truncated_speed(sim: SimulatedDrive, step_kmh: float = 0.1,
                    circumference_m: float | None = None) -> SimulatedDrive:
    """Wheel speeds logged in km/h truncated to ``step_kmh`` and turned back into rates with the
    circumference the unit assumes (default the true c_e): a CAN wheel-speed signal."""
    c = circumference_m or sim.true_parameters.c_e
    cols = _columns(sim.drive)
    for key in ("n_rl", "n_rr"):
        kmh = cols[key] * c * 3.6
        cols[key] = np.trunc(kmh / step_kmh) * step_kmh / (3.6 * c)
    return _rebuilt(sim, cols, f"trunc{step_kmh:g}kmh")


def heading_error(sim: SimulatedDrive, amplitude_rad: float, phase_rad: float = 0.7,
                  harmonic: int = 1) -> SimulatedDrive:
    """A heading error that depends on the heading, ``amplitude sin(harmonic psi + phase)``: a
    magnetometer's hard-iron (first harmonic) or soft-iron (second) error."""
    cols = _columns(sim.drive)
    psi = cols["psi"]
    cols["psi"] = psi + amplitude_rad * np.sin(harmonic * psi + phase_rad)
    return _rebuilt(sim, cols, f"heading{np.rad2deg(amplitude_rad):g}deg-h{harmonic}")


def front_wheels(sim: SimulatedDrive, wheelbase_m: float = WHEELBASE_M,
                 track_m: float = FRONT_TRACK_M) -> SimulatedDrive:
    """The front wheels' rates logged as the rear ones (a mapping mistake, or a car that sends
    only its front wheels): in a bend a front wheel runs on a wider circle than the rear axle's
    point beside it, by the wheelbase times the yaw rate across the direction of travel."""
    cols = _columns(sim.drive)
    poses = sim.true_poses
    t_s = sim.drive.t_s
    theta = sim.true_parameters
    step = np.diff(poses, axis=0)
    v = np.hypot(step[:, 0], step[:, 1]) / t_s
    w = np.diff(poses[:, 2]) / t_s
    v, w = np.append(v, v[-1]), np.append(w, w[-1])
    c_l, c_r = MODEL.circumferences(theta.as_array())
    cols["n_rl"] = np.hypot(v - 0.5 * track_m * w, wheelbase_m * w) / c_l
    cols["n_rr"] = np.hypot(v + 0.5 * track_m * w, wheelbase_m * w) / c_r
    # the measured rates' own noise, as the profile made it on the rear wheels
    cols["n_rl"] = cols["n_rl"] + (sim.drive.n_rl - sim.true_n_rl)
    cols["n_rr"] = cols["n_rr"] + (sim.drive.n_rr - sim.true_n_rr)
    return _rebuilt(sim, cols, "front-wheels")


def one_wheel_offset(sim: SimulatedDrive, offset_revps: float) -> SimulatedDrive:
    """The rear-left wheel's rate reads ``offset_revps`` more, standing or moving (one wheel's
    sensor biased)."""
    cols = _columns(sim.drive)
    cols["n_rl"] = cols["n_rl"] + offset_revps
    return _rebuilt(sim, cols, f"left{offset_revps:+g}revps")


def filtered_rates(sim: SimulatedDrive, tau_s: float) -> SimulatedDrive:
    """Both wheel rates through a first-order low-pass of time constant ``tau_s`` (a CAN
    gateway's filter): each sample moves ``t_s / tau`` of the way to the new value."""
    cols = _columns(sim.drive)
    alpha = min(sim.drive.t_s / tau_s, 1.0)
    for key in ("n_rl", "n_rr"):
        x = cols[key]
        y = np.empty_like(x)
        y[0] = x[0]
        for k in range(1, x.size):
            y[k] = y[k - 1] + alpha * (x[k] - y[k - 1])
        cols[key] = y
    return _rebuilt(sim, cols, f"lowpass{tau_s:g}s")


def lateral_scale(sim: SimulatedDrive, scale: float) -> SimulatedDrive:
    """The lateral acceleration read ``scale`` times too large (an accelerometer's scale
    error, or a body that rolls in bends)."""
    cols = _columns(sim.drive)
    cols["a_y"] = cols["a_y"] * scale
    return _rebuilt(sim, cols, f"a_y-x{scale:g}")


def drift(sim: SimulatedDrive, fraction: float) -> SimulatedDrive:
    """c_e grows by ``fraction`` of itself from the start of the drive to its end, evenly
    (tyres warming): the wheels turn ``1 / (1 + fraction t / T)`` as often for the same
    travel. The truth at the end is c_e times ``1 + fraction``."""
    cols = _columns(sim.drive)
    t = cols["t"]
    grow = 1.0 + fraction * (t - t[0]) / (t[-1] - t[0])
    cols["n_rl"] = cols["n_rl"] / grow
    cols["n_rr"] = cols["n_rr"] / grow
    return _rebuilt(sim, cols, f"drift{fraction:+g}")


def lever_arm(sim: SimulatedDrive, forward_m: float, left_m: float) -> SimulatedDrive:
    """The reference pose of a point ``forward_m`` ahead of and ``left_m`` left of the rear
    axle's midpoint (a GNSS antenna on the roof, an INS at its IMU)."""
    cols = _columns(sim.drive)
    psi = cols["psi"]
    cols["x"] = cols["x"] + forward_m * np.cos(psi) - left_m * np.sin(psi)
    cols["y"] = cols["y"] + forward_m * np.sin(psi) + left_m * np.cos(psi)
    return _rebuilt(sim, cols, f"arm{forward_m:+g},{left_m:+g}m")


def parked(sim: SimulatedDrive, minutes: float, jitter_m: float = 0.02) -> SimulatedDrive:
    """The drive, then ``minutes`` parked where it ended: the wheels at zero, the reference
    pose jittering by ``jitter_m`` (a GNSS fix at rest)."""
    cols = _columns(sim.drive)
    t_s = sim.drive.t_s
    count = round(minutes * 60.0 / t_s)
    rng = np.random.default_rng(sim.seed + 7)
    more = {"t": cols["t"][-1] + t_s * np.arange(1, count + 1)}
    for key in cols:
        if key == "t":
            continue
        more[key] = np.full(count, cols[key][-1] if key in ("x", "y", "psi") else 0.0)
    more["x"] = more["x"] + rng.normal(0.0, jitter_m, count)
    more["y"] = more["y"] + rng.normal(0.0, jitter_m, count)
    more["psi"] = more["psi"] + rng.normal(0.0, 0.002, count)
    joined = {k: np.concatenate([cols[k], more[k]]) for k in cols}
    return _rebuilt(sim, joined, f"parked{minutes:g}min")


@dataclass(frozen=True)
class Departure:
    """A kind of departure and the values it is run at.

    expect : what an honest calibration does with it: ``modelled`` (estimated and taken out:
        the parameters come out right), ``named`` (a finding names it) or ``uncertain`` (the
        uncertainty covers the error; parameters the data cannot tell apart are not identified)
    """

    name: str
    description: str
    values: tuple[float, ...]
    expect: str
    make: Callable[[int, float, str, float], SimulatedDrive]


def _plain(seed: int, duration_s: float, noise: str) -> SimulatedDrive:
    return simulate(duration_s=duration_s, seed=seed, noise=noise)


def _change(seed: int, value: float, noise: str, duration_s: float) -> SimulatedDrive:
    new = TRUE_PARAMETERS.replace(c_e=TRUE_PARAMETERS.c_e * (1.0 + value))
    return simulate(duration_s=duration_s, seed=seed, noise=noise,
                    change=(0.5 * duration_s, new))


def _pressure(seed: int, value: float, noise: str, duration_s: float) -> SimulatedDrive:
    """One rear wheel's circumference ``value`` smaller from half-way (a pressure loss)."""
    new = Parameters.from_array(MODEL.with_wheel_scaled(TRUE_PARAMETERS.as_array(), 0,
                                                        1.0 - value))
    return simulate(duration_s=duration_s, seed=seed, noise=noise,
                    change=(0.5 * duration_s, new))


#: Every departure :mod:`benchmarks.bench_departures` runs, by name.
DEPARTURES: Mapping[str, Departure] = MappingProxyType({d.name: d for d in (
    Departure("reference-late", "the reference pose late (s; negative: early)",
              (0.25, 0.35, 0.5, -0.25, 0.8), "modelled",
              lambda seed, v, noise, dur: reference_delay(_plain(seed, dur, noise), v)),
    Departure("a_y-offset", "a constant lateral-acceleration offset (m/s^2; IMU roll tilt)",
              (0.5, -0.3, 1.0), "modelled",
              lambda seed, v, noise, dur: lateral_offset(_plain(seed, dur, noise), v)),
    Departure("wheel-offset", "both wheel rates offset, standing or moving (rev/s)",
              (0.05, 0.02, -0.03), "modelled",
              lambda seed, v, noise, dur: wheel_offset(_plain(seed, dur, noise), v)),
    Departure("truncated-rpm", "wheel rates truncated to a step of rpm",
              (1.0, 2.0), "modelled",
              lambda seed, v, noise, dur: truncated_rpm(_plain(seed, dur, noise), v)),
    Departure("truncated-kmh", "wheel speeds truncated to a step of km/h",
              (0.1, 0.05), "modelled",
              lambda seed, v, noise, dur: truncated_speed(_plain(seed, dur, noise), v)),
    Departure("heading-error", "a heading error of this amplitude varying with the heading "
              "(degrees; magnetometer)", (5.0, 3.0), "named",
              lambda seed, v, noise, dur: heading_error(_plain(seed, dur, noise),
                                                        np.deg2rad(v))),
    Departure("left-only", "every bend to the left, at one speed (value: minutes)", (20.0,),
              "uncertain",
              lambda seed, v, noise, dur: simulate(duration_s=60.0 * v, seed=seed, noise=noise,
                                                   route="left")),
    Departure("slalom", "a slalom at one speed (value: minutes)", (20.0,), "uncertain",
              lambda seed, v, noise, dur: simulate(duration_s=60.0 * v, seed=seed, noise=noise,
                                                   route="slalom")),
    Departure("short", "a short city drive (value: seconds)", (60.0, 90.0, 150.0), "uncertain",
              lambda seed, v, noise, dur: simulate(duration_s=v, seed=seed, noise=noise)),
    Departure("c_e-change", "c_e changes by this fraction half-way through the log",
              (0.02, -0.01, 0.015), "named", lambda seed, v, noise, dur: _change(seed, v, noise,
                                                                              dur)),
    Departure("pressure-change", "one rear wheel's circumference shrinks by this fraction "
              "half-way through the log", (0.01, 0.02), "named",
              lambda seed, v, noise, dur: _pressure(seed, v, noise, dur)),
    Departure("front-wheels", "the front wheels' rates mapped as the rear ones "
              "(value: wheelbase, m)", (2.7, 2.5), "named",
              lambda seed, v, noise, dur: front_wheels(_plain(seed, dur, noise), v)),
    Departure("one-wheel-offset", "the left wheel's rate offset, standing or moving (rev/s)",
              (0.01, 0.03, 0.05), "modelled",
              lambda seed, v, noise, dur: one_wheel_offset(_plain(seed, dur, noise), v)),
    Departure("filtered-rates", "the wheel rates low-pass filtered (time constant, s)",
              (0.3, 0.5), "modelled",
              lambda seed, v, noise, dur: filtered_rates(_plain(seed, dur, noise), v)),
    Departure("a_y-scale", "a_y read this many times too large", (1.3, 0.8), "modelled",
              lambda seed, v, noise, dur: lateral_scale(_plain(seed, dur, noise), v)),
    Departure("drift", "c_e grows by this fraction over the drive (tyres warming)",
              (0.003, -0.003), "modelled",
              lambda seed, v, noise, dur: drift(_plain(seed, dur, noise), v)),
    Departure("arm-ahead", "the reference point this far ahead of the rear axle (m)",
              (2.0, -0.8), "modelled",
              lambda seed, v, noise, dur: lever_arm(_plain(seed, dur, noise), v, 0.0)),
    Departure("arm-left", "the reference point this far left of the rear axle (m)",
              (0.5, -2.0), "modelled",
              lambda seed, v, noise, dur: lever_arm(_plain(seed, dur, noise), 0.0, v)),
    Departure("parked", "the drive followed by this many minutes parked", (10.0,),
              "uncertain",
              lambda seed, v, noise, dur: parked(_plain(seed, dur, noise), v)),
)})


def simulate_departure(name: str, value: float, *, seed: int, noise: str = "realistic",
                       duration_s: float = 1200.0) -> SimulatedDrive:
    """A simulated drive with the departure ``name`` at ``value`` (see :data:`DEPARTURES`)."""
    if name not in DEPARTURES:
        raise ConfigError(f"unknown departure {name!r}; choose one of {', '.join(DEPARTURES)}")
    return DEPARTURES[name].make(seed, value, noise, duration_s)
