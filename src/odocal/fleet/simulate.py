"""A simulated fleet with known truth: vehicles, daily drives, and the events a fleet sees.

Each vehicle gets its own parameters (the simulated car's, spread as tyres and builds spread),
a little drive-to-drive scatter (load, temperature) and, by the plan, one event:

``pressure``  the left rear tyre loses pressure at a random drive: c_e falls by ``size``
              (relative) and c_d by twice that share of c_e (only one tyre shrinks); undeclared,
              to be detected
``wear``      tread wear: c_e falls linearly by ``wear`` (relative) over the vehicle's history
``tyres``     a declared tyre change (``event = tyre change`` in the catalog): new tyres, new
              parameters; the baseline restarts, no alarm is expected
``mismapped`` one log with the left and right wheel columns swapped: the checks must reject it,
              and it must raise no alarm

The ``mixed`` plan cycles none, pressure, wear, tyres, with a mis-mapped log on every
event-free vehicle; ``pressure`` and ``none`` give every vehicle that plan (for detection and
false-alarm rates). Written: one drive file per drive (``VEHICLE/DATE_dNN.parquet``),
``catalog.csv`` and ``truth.json`` (every drive's true parameters and every event).

With ``model="four_wheel"`` every drive also carries the front wheels and the steering-wheel
angle (:func:`odocal.sim.four_wheel.with_front_axle`) of a front axle and steering drawn per
vehicle around :data:`~odocal.sim.four_wheel.TRUE_FOUR_WHEEL`'s (from a random stream of their
own: the rear axle's drives are those of the rear-axle fleet of the same seed), drawn anew at a
tyre change; the events stay the rear axle's.
"""

from __future__ import annotations

import dataclasses
import datetime as dt
import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from odocal.data.drive import Drive
from odocal.errors import ConfigError, OutputError
from odocal.io.atomic import write_text
from odocal.io.drivefile import save_drive
from odocal.model import registry
from odocal.model.layout import REAR_AXLE
from odocal.model.parameters import Parameters
from odocal.sim.limits import (
    MAX_DRIVES,
    MAX_VEHICLES,
    checked_count,
    checked_duration,
    checked_seed,
    checked_share,
)
from odocal.sim.simulate import TRUE_PARAMETERS, simulate

PLANS = ("mixed", "pressure", "wear", "tyres", "none")
_MIXED = ("none", "pressure", "wear", "tyres")
START = dt.datetime(2026, 3, 2, 8, 0, tzinfo=dt.UTC)


@dataclass(frozen=True)
class FleetEvent:
    vehicle: str
    drive: int             # index of the first drive after the event
    time: str
    kind: str
    size: float            # relative change of c_e
    declared: bool


@dataclass(frozen=True)
class SimulatedFleet:
    catalog: Path
    truth: Path
    drives: int
    events: tuple[FleetEvent, ...]


def _front_theta(rng: np.random.Generator) -> np.ndarray:
    """A vehicle's front axle and steering (c_f, c_fd, t_f, L, ratio, s_0), spread around the
    simulated car's as tyres, builds and steering racks spread."""
    from odocal.sim.four_wheel import TRUE_FOUR_WHEEL

    base = TRUE_FOUR_WHEEL.as_array()[REAR_AXLE.size:].copy()
    base[0] *= 1.0 + rng.normal(0.0, 0.003)
    base[1] += rng.normal(0.0, 0.0005)
    base[2] += rng.normal(0.0, 0.01)
    base[3] += rng.normal(0.0, 0.03)
    base[4] *= 1.0 + rng.normal(0.0, 0.03)
    base[5] += rng.normal(0.0, 0.005)
    return base


def _vehicle_theta(rng: np.random.Generator) -> np.ndarray:
    base = TRUE_PARAMETERS.as_array().copy()
    base[0] *= 1.0 + rng.normal(0.0, 0.003)
    base[1] += rng.normal(0.0, 0.0005)
    base[2] += rng.normal(0.0, 0.01)
    base[3] *= 1.0 + rng.normal(0.0, 0.1)
    return base


def simulate_fleet(out: str | Path, *, vehicles: int = 4, drives: int = 12,
                   duration_s: float = 600.0, seed: int = 0, noise: str = "realistic",
                   plan: str = "mixed", size: float = 0.002, wear: float = 0.003,
                   model: str = registry.DEFAULT,
                   progress: Callable[[str, int, int], None] | None = None) -> SimulatedFleet:
    """Write a simulated fleet of the vehicle ``model``'s drives into the folder ``out`` (see
    the module docstring)."""
    registry.entry(model)
    if plan not in PLANS:
        raise ConfigError(f"unknown fleet plan {plan!r}; choose one of {', '.join(PLANS)}")
    checked_count(vehicles, name="vehicles", lower=1, upper=MAX_VEHICLES)
    checked_count(drives, name="drives per vehicle", lower=2, upper=MAX_DRIVES)
    checked_duration(duration_s, name="drive duration")
    checked_seed(seed)
    checked_share(size, name="pressure loss size")
    checked_share(wear, name="wear")
    target = Path(out)
    if target.exists() and (not target.is_dir() or any(target.iterdir())):
        raise OutputError(f"'{target}' exists and is not an empty folder; simulate-fleet writes a "
                          "new fleet into a new folder")
    from odocal.io.atomic import new_folder

    # written beside it and moved into place when complete: an interrupted run leaves no
    # half a fleet
    with new_folder(target) as root:
        events = _write_fleet(root, vehicles=vehicles, drives=drives, duration_s=duration_s,
                              seed=seed, noise=noise, plan=plan, size=size, wear=wear,
                              four=model != registry.DEFAULT, progress=progress)
    return SimulatedFleet(catalog=target / "catalog.csv", truth=target / "truth.json",
                          drives=vehicles * drives, events=tuple(events))


def _write_fleet(root: Path, *, vehicles: int, drives: int, duration_s: float, seed: int,
                 noise: str, plan: str, size: float, wear: float, four: bool,
                 progress: Callable[[str, int, int], None] | None) -> list[FleetEvent]:
    """The fleet's drives, catalog and truth (of four-wheel cars with ``four``), written into
    ``root``; its events."""
    rows: list[dict[str, Any]] = []
    truth: dict[str, Any] = {"plan": plan, "size": size, "wear": wear, "noise": noise,
                             "duration_s": duration_s, "seed": seed, "vehicles": {}}
    events: list[FleetEvent] = []
    total = vehicles * drives
    for v in range(vehicles):
        name = f"car{v:03d}"
        rng = np.random.default_rng([seed, v])
        kind = _MIXED[v % len(_MIXED)] if plan == "mixed" else plan
        theta = _vehicle_theta(rng)
        front_rng = np.random.default_rng([seed, v, 4])     # (the rear's stream unchanged)
        front = _front_theta(front_rng) if four else None
        at = int(rng.integers(6, max(7, drives - 4))) if kind in ("pressure", "tyres") else -1
        mismapped = (int(rng.integers(2, drives)) if plan == "mixed" and kind == "none"
                     and drives > 2 else -1)
        odometer = float(rng.uniform(5000.0, 50000.0))
        history: list[dict[str, Any]] = []
        (root / name).mkdir()
        for i in range(drives):
            when = START + dt.timedelta(days=i, hours=float(rng.uniform(0, 10)))
            event = ""
            if kind == "tyres" and i == at:
                event = "tyre change"
                theta = _vehicle_theta(rng)
                front = _front_theta(front_rng) if four else None
            current = _drive_theta(theta, rng, kind=kind, i=i, at=at, drives=drives, size=size,
                                   wear=wear)
            drive, true = _drive(current, front, duration_s=duration_s,
                                 seed=int(rng.integers(2**31)), noise=noise,
                                 name=f"{name}-{i:02d}", mismapped=i == mismapped)
            path = root / name / f"{when.strftime('%Y-%m-%dT%H-%M')}_d{i:02d}.parquet"
            save_drive(drive, path)
            rows.append({"vehicle": name, "path": f"{name}/{path.name}",
                         "time": when.isoformat(timespec="seconds"),
                         "odometer_km": f"{odometer:.1f}", "event": event})
            history.append({"drive": i, "time": when.isoformat(timespec="seconds"),
                            "theta": true,
                            "mismapped": i == mismapped})
            odometer += drive.distance_m / 1000.0
            if event or (kind == "pressure" and i == at) or i == mismapped:
                events.append(FleetEvent(name, i, when.isoformat(timespec="seconds"),
                                         "mismapped" if i == mismapped else kind,
                                         0.0 if i == mismapped else
                                         (-size if kind == "pressure" else 0.0),
                                         declared=bool(event)))
            if progress:
                progress("simulate", v * drives + i + 1, total)
        if kind == "wear":
            events.append(FleetEvent(name, 0, str(history[0]["time"]), "wear", -wear, False))
        truth["vehicles"][name] = {"plan": kind, "drives": history}
    truth["events"] = [dataclasses.asdict(e) for e in events]
    _write_catalog(root, rows, truth)
    return events


def _drive(current: np.ndarray, front: np.ndarray | None, *, duration_s: float, seed: int,
           noise: str, name: str, mismapped: bool) -> tuple[Drive, dict[str, float]]:
    """One drive of the rear axle ``current`` (and the front axle and steering ``front``), its
    rear wheel columns swapped where ``mismapped``, and its true parameters by name."""
    sim = simulate(duration_s=duration_s, seed=seed, noise=noise, theta=Parameters(*current),
                   name=name)
    truth = Parameters(*current)
    if front is not None:
        from odocal.model.four_wheel import FOUR_WHEEL
        from odocal.sim.four_wheel import with_front_axle

        sim, truth = with_front_axle(sim, theta=Parameters(*current, *front, layout=FOUR_WHEEL))
    drive = sim.drive
    if mismapped:
        drive = dataclasses.replace(drive, n_rl=drive.n_rr, n_rr=drive.n_rl)
    return drive, truth.as_dict()


def _drive_theta(theta: np.ndarray, rng: np.random.Generator, *, kind: str, i: int, at: int,
                 drives: int, size: float, wear: float) -> np.ndarray:
    """The parameters on drive ``i`` of a vehicle whose own are ``theta`` (new ones after a
    tyre change), under its plan ``kind`` (a pressure loss from drive ``at`` on, wear over its
    ``drives``), scattered a little by load and temperature."""
    current = theta.copy()
    if kind == "pressure" and i >= at:
        current[1] -= 2.0 * size * current[0]
        current[0] *= 1.0 - size
    elif kind == "wear":
        current[0] *= 1.0 - wear * i / (drives - 1)
    current[0] *= 1.0 + rng.normal(0.0, 0.0001)     # load, temperature
    current[1] += rng.normal(0.0, 0.0001)
    return current


def _write_catalog(root: Path, rows: list[dict[str, Any]], truth: dict[str, Any]) -> None:
    """``catalog.csv`` (one row per drive) and ``truth.json``, written into ``root``."""
    header = ["vehicle", "path", "time", "odometer_km", "event"]
    lines = [",".join(header)] + [",".join(str(r[h]) for h in header) for r in rows]
    catalog = root / "catalog.csv"
    write_text(catalog, "\n".join(lines) + "\n")
    truth_path = root / "truth.json"
    write_text(truth_path, json.dumps(truth, indent=1) + "\n")
