"""A fleet of four-wheel cars (issue 37): the store holds the car's parameters, drift is watched
for each of them, the report draws them and the exports carry the car's geometry; a store of
the rear axle's parameters is refused in one line."""

from __future__ import annotations

import datetime as dt
import json
import math
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from odocal.errors import DataError
from odocal.fleet.drift import CAUSES, analyse
from odocal.fleet.engine import calibrate_fleet, dask_client
from odocal.fleet.simulate import simulate_fleet
from odocal.fleet.store import open_store
from odocal.model.layout import FOUR_WHEEL
from odocal.settings import FleetSettings, Settings

FOUR = Settings().replace(vehicle={"model": "four_wheel"})
FRONT = ("c_f", "c_fd", "t_f", "L", "ratio", "s_0")
BIN = Path(sys.executable).parent


@pytest.fixture(scope="module")
def four_fleet(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """2 four-wheel cars x 8 drives of 5 minutes, each losing 0.3% of its left rear tyre's
    circumference at a random drive."""
    root = tmp_path_factory.mktemp("four")
    fleet = simulate_fleet(root / "f", vehicles=2, drives=8, duration_s=300.0, seed=5,
                           plan="pressure", size=0.003, model="four_wheel")
    store = root / "fleet.db"
    with dask_client(workers=2) as client:
        run = calibrate_fleet(fleet.catalog, store, settings=FOUR, client=client,
                              out=root / "out", drive_reports=False)
    return {"fleet": fleet, "store": store, "run": run, "out": root / "out",
            "truth": json.loads(fleet.truth.read_text())}


def test_the_store_holds_every_parameter_of_the_car_as_far_as_its_std_says(
        four_fleet: dict[str, Any]) -> None:
    """Each drive's estimate of each parameter against the drive's truth, in its own stds."""
    truth = four_fleet["truth"]
    z: dict[str, list[float]] = {n: [] for n in FOUR_WHEEL.names}
    with open_store(four_fleet["store"], create=False, read_only=True) as db:
        assert db.model == "four_wheel"
        for vehicle, history in truth["vehicles"].items():
            rows = db.drives(vehicle)
            assert len(rows) == 8 and all(r["success"] for r in rows)
            for r, h in zip(rows, history["drives"], strict=True):
                for n in FOUR_WHEEL.names:
                    if r[f"{n}_identified"]:
                        z[n].append((r[n] - h["theta"][n]) / r[f"{n}_std"])
    for n in ("c_f", "c_fd", "t_f", "ratio", "s_0"):          # identified by every drive
        assert len(z[n]) == 16, n
    for n, values in z.items():
        assert max(map(abs, values), default=0.0) < 3.5, (n, values)
    front = np.array([v for n in FRONT for v in z[n]])
    assert 0.4 < float(np.sqrt(np.mean(front**2))) < 1.5


def test_a_rear_tyre_losing_pressure_alarms_on_the_rear_axle_only(
        four_fleet: dict[str, Any]) -> None:
    run, truth = four_fleet["run"], four_fleet["truth"]
    alarmed = {(a.vehicle, a.parameter) for a in run.alarms}
    assert {(v, "c_e") for v in truth["vehicles"]} <= alarmed
    assert not any(p in FRONT for _, p in alarmed), run.alarms
    for a in run.alarms:
        if a.parameter == "c_e":
            event = next(e for e in truth["events"] if e["vehicle"] == a.vehicle)
            assert a.time.isoformat() == event["time"]
            assert a.relative_change == pytest.approx(-0.003, abs=0.001)
    with open_store(four_fleet["store"], create=False, read_only=True) as db:
        watched = {b["parameter"] for b in db.baselines()}
    assert set(FRONT) - {"L"} <= watched                  # L: identified by few 5-min drives


def test_the_report_and_the_exports_carry_the_car(four_fleet: dict[str, Any]) -> None:
    out = four_fleet["out"]
    page = (out / "report.html").read_text()
    with open_store(four_fleet["store"], create=False, read_only=True) as db:
        pooled = {p["vehicle"]: p for p in db.pooled()}
    assert set(pooled) == set(four_fleet["truth"]["vehicles"])
    for vehicle, p in pooled.items():
        assert f"t_f = {p['t_f']:.6g} &plusmn;" in page and f"ratio = {p['ratio']:.6g}" in page
        text = (out / "vehicles" / vehicle / "ackermann" /
                "ackermann_steering_controller.yaml").read_text()
        params = yaml.safe_load(text)["ackermann_steering_controller"]["ros__parameters"]
        assert params["front_wheel_track"] == pytest.approx(p["t_f"], rel=1e-12)
        assert params["rear_wheel_track"] == pytest.approx(p["t_r"], rel=1e-12)
        if p["L_identified"]:
            assert params["wheelbase"] == pytest.approx(p["L"], rel=1e-12)
        else:                            # odocal's placeholder: left for the user to fill in
            assert "wheelbase" not in params and "FILL IN wheelbase" in text
        assert params["front_wheels_radius"] == pytest.approx(p["c_f"] / (2 * math.pi),
                                                              rel=1e-12)
    history = subprocess.run([str(BIN / "odocal"), "fleet", "history", "--store",
                              str(four_fleet["store"]), "--vehicle", "car000"],
                             capture_output=True, text=True, check=True).stdout
    head = history.splitlines()[0]
    assert "L [m]" in head and "s_0 [deg]" in head and "c_fd [mm]" in head


def test_a_store_of_the_rear_axle_is_refused_for_the_car(four_fleet: dict[str, Any],
                                                          tmp_path: Path) -> None:
    """A store holding the rear axle's estimates is refused for the car in one line; one that
    holds none (created, or stopped before its first drive) takes the car's columns."""
    rear = tmp_path / "rear.db"
    with open_store(rear, model="rear_axle") as db:
        db.add_drive({"task_key": "k", "vehicle": "v", "time": "2026-01-01T00:00:00+00:00",
                      "source": "s", "status": "converged", "success": True, "c_e": 1.95})
    with pytest.raises(DataError, match="calibration of the rear_axle model, not of the "
                                        "four_wheel model"):
        calibrate_fleet(four_fleet["fleet"].catalog, rear, settings=FOUR, workers=1)
    empty = tmp_path / "empty.db"
    open_store(empty, model="rear_axle").close()
    with open_store(empty, model="four_wheel") as db:
        assert db.model == "four_wheel"
        db.add_drive({"task_key": "k", "vehicle": "v", "time": "2026-01-01T00:00:00+00:00",
                      "source": "s", "status": "converged", "success": True, "c_e": 1.95,
                      "L": 2.6})
        assert db.drives()[0]["L"] == 2.6


def _rows(parameter: str, values: list[float], std: float) -> list[dict[str, Any]]:
    t0 = dt.datetime(2026, 1, 1, tzinfo=dt.UTC)
    rows = []
    for i, v in enumerate(values):
        row: dict[str, Any] = {"task_key": f"k{i:04d}", "vehicle": "v",
                               "time": (t0 + dt.timedelta(days=i)).isoformat(),
                               "odometer_km": 1000.0 + 20 * i, "distance_km": 20.0,
                               "success": 1, "event": None}
        for n in FOUR_WHEEL.names:
            row[n], row[f"{n}_std"], row[f"{n}_identified"] = (
                (v, std, 1) if n == parameter else (0.0, 0.0, 0))
        rows.append(row)
    return rows


@pytest.mark.parametrize(("parameter", "level", "step", "std", "said"), [
    ("L", 2.62, 0.05, 0.01, "L rose {mm:.1f} mm since 2026-01-18: {cause}"),
    ("s_0", 0.012, -0.01, 0.001, "s_0 fell {deg:.3g} deg since 2026-01-18: {cause}"),
    ("c_fd", 0.0024, -0.004, 0.0002,
     "c_fd fell {mm:.2f} mm ({share:.2f}% of c_f) since 2026-01-18: {cause}"),
])
def test_a_step_of_a_front_parameter_is_named_in_its_words(parameter: str, level: float,
                                                           step: float, std: float,
                                                           said: str) -> None:
    """In the parameter's unit (a difference also as a share of its axle's circumference,
    1.947 m here), with what such a change usually means."""
    rng = np.random.default_rng(1)
    values = [level + rng.normal(0.0, std) + (step if i >= 17 else 0.0) for i in range(30)]
    rows = _rows(parameter, values, std)
    for r in rows:
        r["c_f"] = 1.947
    settings = FleetSettings(excess_floor=(0.0,) * FOUR_WHEEL.size)
    [alarm] = analyse(rows, settings, FOUR_WHEEL).alarms
    assert alarm.parameter == parameter and alarm.kind == "step" and alarm.time.day == 18
    assert abs(alarm.change - step) < 3 * std
    change = abs(alarm.change)
    assert alarm.message == said.format(mm=change * 1000, deg=math.degrees(change),
                                        share=change / 1.947 * 100, cause=CAUSES[parameter])


def test_the_car_on_logs_without_front_wheels_says_why_and_the_store_takes_the_next_model(
        tmp_path: Path) -> None:
    """A four-wheel settings file on a fleet of rear-axle logs (hostile run: exit 0 and no
    word of why 8 of 8 drives failed; the store then refused the rear-axle rerun): the reason
    once with its count, exit 1; the store, holding no estimate, takes the rear axle's run."""
    simulate_fleet(tmp_path / "rear", vehicles=1, drives=3, duration_s=240.0, seed=2)
    config = tmp_path / "car.toml"
    config.write_text('[vehicle]\nmodel = "four_wheel"\n')
    store = tmp_path / "fleet.db"
    argv = [str(BIN / "odocal"), "fleet", "calibrate", str(tmp_path / "rear" / "catalog.csv"),
            "--store", str(store), "--workers", "1"]
    run = subprocess.run([*argv, "--config", str(config)], capture_output=True, text=True)
    assert run.returncode == 1, run.stderr
    assert ("not calibrated (3 drives): DataError: the four_wheel model needs the front "
            "wheels' rates (n_fl, n_fr), and '...' has none") in run.stdout
    errors = [line for line in run.stderr.splitlines() if "error" in line]
    assert len(errors) == 1 and errors[0].startswith(
        "odocal fleet calibrate: error: no drive of the catalog could be calibrated; the "
        "commonest reason: DataError: the four_wheel model needs the front wheels' rates")
    assert "Traceback" not in run.stderr
    rear = subprocess.run(argv, capture_output=True, text=True)
    assert rear.returncode == 0, rear.stderr
    with open_store(store, create=False, read_only=True) as db:
        assert db.model == "rear_axle"
        rows = db.drives()
        assert len(rows) == 3 and all(r["c_e"] is not None for r in rows)
        assert "c_f" not in rows[0]


def test_the_exports_say_how_the_noise_was_measured(four_fleet: dict[str, Any]) -> None:
    """The pooled calibration keeps the odometry's noise, not its window count: the files say
    it was measured against the reference (they said "over 0 windows"), with the variances
    the store holds."""
    with open_store(four_fleet["store"], create=False, read_only=True) as db:
        pooled = {p["vehicle"]: p for p in db.pooled()}
    for vehicle, p in pooled.items():
        text = (four_fleet["out"] / "vehicles" / vehicle / "ackermann" /
                "ackermann_steering_controller.yaml").read_text()
        assert "vx and vyaw variances measured in windows of 1 s against the reference" in text
        assert "0 windows" not in text
        params = yaml.safe_load(text)["ackermann_steering_controller"]["ros__parameters"]
        twist = params["twist_covariance_diagonal"]
        assert twist[0] == pytest.approx(p["speed_std_mps"] ** 2, rel=1e-9)
        assert twist[5] == pytest.approx(p["yaw_rate_std_radps"] ** 2, rel=1e-9)
