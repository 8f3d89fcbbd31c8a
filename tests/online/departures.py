"""Drives that depart from the model the way real ones do (issue 32), for the live path's tests
and ``benchmarks/bench_departures_live.py``.

Each function takes a simulated drive's columns (or simulates one) and returns the columns a
logger would have written, with the truth the live estimate should end at. Every departure
takes its size, time and duration as arguments: the tests and the benchmark run several values
of each, never one.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

import odocal
from odocal.model.kinematics import rollout, wheel_rates_for
from odocal.model.parameters import Inputs, Parameters

FloatArray = NDArray[np.float64]
Columns = dict[str, FloatArray]
COLUMNS = ("t", "n_rl", "n_rr", "a_y", "beta", "x", "y", "psi")


@dataclass(frozen=True)
class Departed:
    """A departed drive: its columns, the parameters at its end, and where a change is."""

    columns: Columns
    truth: Parameters
    change_t: float | None = None
    """Time of a change of the wheels (c_e or one wheel's circumference), s."""
    change: dict[str, float] = field(default_factory=dict)
    """The change's relative size per parameter (c_d over c_e)."""
    changes: bool = False
    """Whether an alarm is expected (a change of 1% or more)."""


def base(seed: int, duration_s: float, *, noise: str = "realistic",
         change: tuple[float, Parameters] | None = None) -> odocal.SimulatedDrive:
    return odocal.simulate(duration_s=duration_s, seed=seed, noise=noise, change=change)


def columns_of(sim: odocal.SimulatedDrive) -> Columns:
    return {k: np.array(v, dtype=np.float64) for k, v in sim.drive.columns().items()
            if k in COLUMNS}


def _append(cols: Columns, more: Columns) -> Columns:
    return {k: np.concatenate([cols[k], more[k]]) for k in COLUMNS}


def parked(seed: int, *, drive_s: float, park_s: float, jitter_m: float,
           wheel_noise: bool = False) -> Departed:
    """A drive, then ``park_s`` standing with the reference pose jittering by ``jitter_m``
    (white, per axis) and its heading by ``jitter_m`` / 2 m rad; wheels reading 0 (or, with
    ``wheel_noise``, a few hundredths of a rev/s of noise around 0)."""
    sim = base(seed, drive_s)
    cols = columns_of(sim)
    rng = np.random.default_rng(1000 + seed)
    t_s = sim.drive.t_s
    m = round(park_s / t_s)
    t = cols["t"][-1] + t_s * np.arange(1, m + 1)
    wheels = (rng.normal(0.0, 0.01, (m, 2)) if wheel_noise else np.zeros((m, 2)))
    more = {"t": t, "n_rl": wheels[:, 0], "n_rr": wheels[:, 1],
            "a_y": rng.normal(0.0, 0.05, m), "beta": np.zeros(m),
            "x": cols["x"][-1] + rng.normal(0.0, jitter_m, m),
            "y": cols["y"][-1] + rng.normal(0.0, jitter_m, m),
            "psi": cols["psi"][-1] + rng.normal(0.0, jitter_m / 2.0, m)}
    return Departed(_append(cols, more), sim.true_parameters)


def slipping(seed: int, *, duration_s: float, at_s: float, slip_s: float, fraction: float,
             wheels: str = "both") -> Departed:
    """``slip_s`` of wheel slip from ``at_s``: the wheels turn ``fraction`` more than the
    motion (spinning on ice; negative: locked, skidding), ``wheels`` "both", "left" or
    "right"."""
    sim = base(seed, duration_s)
    cols = columns_of(sim)
    inside = (cols["t"] >= at_s) & (cols["t"] < at_s + slip_s)
    for key in {"both": ("n_rl", "n_rr"), "left": ("n_rl",), "right": ("n_rr",)}[wheels]:
        cols[key] = np.where(inside, cols[key] * (1.0 + fraction), cols[key])
    return Departed(cols, sim.true_parameters)


def reversing(seed: int, *, duration_s: float, at_s: float, reverse_s: float,
              speed_scale: float = 0.3) -> Departed:
    """At ``at_s`` the vehicle backs up along the path it came for ``reverse_s`` (at
    ``speed_scale`` of the speed it came at), then drives it forward again and carries on;
    the wheel speeds are unsigned (positive while reversing)."""
    sim = base(seed, duration_s)
    cols = columns_of(sim)
    t_s = sim.drive.t_s
    i = int(np.searchsorted(cols["t"], at_s))
    lo = max(i - round(reverse_s * speed_scale / t_s), 0)
    path = {k: (np.unwrap(v) if k == "psi" else v)[lo:i + 1] for k, v in cols.items()}
    count = path["t"].size
    m = round(reverse_s / t_s)
    u = np.linspace(0.0, count - 1, m)                 # the path over reverse_s
    scale = (count - 1) / max(m - 1, 1)                # the rates slowed to match
    forward = {k: np.interp(u, np.arange(count), path[k]) for k in COLUMNS if k != "t"}
    for key in ("n_rl", "n_rr"):
        forward[key] = np.abs(forward[key]) * scale
    backward = {k: v[::-1].copy() for k, v in forward.items()}   # unsigned: still positive
    out = {k: v[:i + 1] for k, v in cols.items()}
    for part in (backward, forward):
        part["t"] = out["t"][-1] + t_s * np.arange(1, m + 1)
        part["psi"] = np.remainder(part["psi"] + np.pi, 2 * np.pi) - np.pi
        out = _append(out, part)
    tail = {k: v[i + 1:] for k, v in cols.items()}
    tail["t"] = tail["t"] + 2 * m * t_s
    return Departed(_append(out, tail), sim.true_parameters)


def stepped(seed: int, *, duration_s: float, at_s: float, relative: float,
            wheel: str = "both") -> Departed:
    """The wheels' circumference changes by ``relative`` at ``at_s``: both (c_e) or one wheel
    ("left", "right": a tyre losing pressure; c_e moves by half of it, c_d by the whole)."""
    true = odocal.TRUE_PARAMETERS
    c_l, c_r = true.c_e + true.c_d / 2, true.c_e - true.c_d / 2
    if wheel in ("both", "left"):
        c_l *= 1.0 + relative
    if wheel in ("both", "right"):
        c_r *= 1.0 + relative
    after = Parameters((c_l + c_r) / 2, c_l - c_r, true.t_r, true.d)
    sim = base(seed, duration_s, change=(at_s, after))
    change = {"c_e": after.c_e / true.c_e - 1.0, "c_d": (after.c_d - true.c_d) / true.c_e}
    return Departed(columns_of(sim), after, change_t=at_s, change=change,
                    changes=abs(relative) >= 0.01)


def reference_delay(seed: int, *, duration_s: float, delay_s: float) -> Departed:
    """The reference pose ``delay_s`` late against the wheels (negative: early)."""
    sim = base(seed, duration_s)
    cols = columns_of(sim)
    t = cols["t"]
    for key in ("x", "y"):
        cols[key] = np.interp(t - delay_s, t, cols[key])
    cols["psi"] = np.remainder(np.interp(t - delay_s, t, np.unwrap(cols["psi"])) + np.pi,
                               2 * np.pi) - np.pi
    return Departed(cols, sim.true_parameters)


def lateral_offset(seed: int, *, duration_s: float, offset_mps2: float) -> Departed:
    """A constant offset on the lateral acceleration (a roll tilt of the IMU)."""
    sim = base(seed, duration_s)
    cols = columns_of(sim)
    cols["a_y"] = cols["a_y"] + offset_mps2
    return Departed(cols, sim.true_parameters)


def wheel_offset(seed: int, *, duration_s: float, offset_revps: float) -> Departed:
    """Both wheel rates read ``offset_revps`` too high everywhere (turning at standstill)."""
    sim = base(seed, duration_s)
    cols = columns_of(sim)
    for key in ("n_rl", "n_rr"):
        cols[key] = cols[key] + offset_revps
    return Departed(cols, sim.true_parameters)


def truncated(seed: int, *, duration_s: float, step: float, unit: str) -> Departed:
    """Wheel rates truncated (not rounded) to whole ``step`` of ``unit``: "rpm" (the wheel's
    rate) or "km/h" (the wheel's speed at the nominal circumference)."""
    sim = base(seed, duration_s, noise="white")
    cols = columns_of(sim)
    factor = 60.0 if unit == "rpm" else 3.6 * odocal.TRUE_PARAMETERS.c_e
    for key in ("n_rl", "n_rr"):
        cols[key] = np.trunc(cols[key] * factor / step) * step / factor
    return Departed(cols, sim.true_parameters)


def one_sided(seed: int, *, duration_s: float, speed_mps: float, pattern: str,
              t_s: float = 0.025) -> Departed:
    """A drive at constant speed that turns one way only ("left": left bends of varying
    radius and straights) or weaves ("slalom"): the lateral acceleration is ``v`` times the yaw
    rate throughout, so t_r and d act alike."""
    rng = np.random.default_rng(2000 + seed)
    theta = odocal.TRUE_PARAMETERS
    m = round(duration_s / t_s) + 1
    t = np.arange(m) * t_s
    w = np.zeros(m)
    i = 0
    while i < m:
        length = int(rng.uniform(4.0, 12.0) / t_s)
        peak = rng.uniform(0.05, 0.35)
        sign = 1.0 if pattern == "left" else (1.0 if (i // 1) % 2 == 0 else -1.0)
        if pattern == "slalom":
            sign = rng.choice([-1.0, 1.0])
        shape = np.sin(np.linspace(0.0, np.pi, length)) ** 2
        w[i:i + length] = (sign * peak * shape)[:max(min(length, m - i), 0)]
        i += length + int(rng.uniform(0.0, 6.0) / t_s)
    v = np.full(m, speed_mps)
    a_y = v * w
    n_rl, n_rr = wheel_rates_for(theta.as_array(), v, w, a_y)
    poses = rollout(theta, Inputs(n_rl[:-1], n_rr[:-1], np.zeros(m - 1), a_y[:-1]),
                    np.array([0.0, 0.0, 0.0]), t_s)
    cols = {"t": t, "n_rl": n_rl + rng.normal(0.0, 0.02, m),
            "n_rr": n_rr + rng.normal(0.0, 0.02, m), "a_y": a_y + rng.normal(0.0, 0.05, m),
            "beta": np.zeros(m), "x": poses[:, 0] + rng.normal(0.0, 0.01, m),
            "y": poses[:, 1] + rng.normal(0.0, 0.01, m),
            "psi": np.remainder(poses[:, 2] + rng.normal(0.0, 0.001, m) + np.pi, 2 * np.pi)
            - np.pi}
    return Departed(cols, theta)


Maker = Callable[[int], Departed]
