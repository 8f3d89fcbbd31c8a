"""A drive's identity is its content and its vehicle: one row per drive, replaced on a rerun,
never moved to another vehicle; times are instants; a fault that gets drives rejected is itself
evidence of a change; two vehicles under one name are named; a full disk is one line."""

from __future__ import annotations

import contextlib
import datetime as dt
import json
import os
import shutil
import subprocess
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import odocal
from odocal.fleet.drift import analyse
from odocal.fleet.engine import calibrate_fleet, dask_client
from odocal.fleet.simulate import simulate_fleet
from odocal.fleet.store import open_store
from odocal.model.parameters import Parameters
from odocal.settings import FleetSettings, Settings
from odocal.sim.simulate import TRUE_PARAMETERS
from tests.conftest import run


@pytest.fixture(scope="module")
def client() -> Iterator[Any]:
    with dask_client(workers=2) as c:
        yield c


@pytest.fixture(scope="module")
def drives(tmp_path_factory: pytest.TempPathFactory) -> list[Path]:
    """Three short drives of one car."""
    root = tmp_path_factory.mktemp("drives")
    out = []
    for i in range(3):
        path = root / f"d{i}.parquet"
        odocal.save_drive(odocal.simulate(duration_s=150.0, seed=40 + i).drive, path)
        out.append(path)
    return out


def _catalog(path: Path, rows: list[tuple[str, Path, str]]) -> Path:
    path.write_text("vehicle,path,time\n" + "".join(f"{v},{p},{t}\n" for v, p, t in rows))
    return path


def _rows(store: Path) -> list[dict[str, Any]]:
    with open_store(store, create=False) as db:
        return db.drives()


def test_times_with_offsets_are_ordered_as_instants_and_reruns_replace_rows(
        drives: list[Path], client: Any, tmp_path: Path) -> None:
    # 07:00Z, 08:00Z and 09:00Z, written with three offsets (as text: the reverse order)
    catalog = _catalog(tmp_path / "c.csv", [
        ("car", drives[0], "2026-03-02T12:00:00+05:00"),
        ("car", drives[1], "2026-03-02T08:00:00Z"),
        ("car", drives[2], "2026-03-02T01:00:00-08:00")])
    store = tmp_path / "f.db"
    calibrate_fleet(catalog, store, client=client)
    rows = _rows(store)
    assert [r["source"] for r in rows] == [str(p) for p in drives]
    assert [r["time"] for r in rows] == [f"2026-03-02T{h:02d}:00:00+00:00" for h in (7, 8, 9)]
    first = {r["drive_id"]: r["task_key"] for r in rows}
    # other settings: every drive calibrated again, each row replaced (not a second one)
    settings = Settings().replace(segments={"length": 600})
    again = calibrate_fleet(catalog, store, client=client, settings=settings)
    assert again.calibrated == 3
    rows = _rows(store)
    assert len(rows) == 3 and {r["drive_id"] for r in rows} == set(first)
    assert all(first[r["drive_id"]] != r["task_key"] for r in rows)


def test_a_drive_is_never_moved_to_another_vehicle(drives: list[Path], client: Any,
                                                   tmp_path: Path) -> None:
    store = tmp_path / "f.db"
    calibrate_fleet(_catalog(tmp_path / "a.csv", [("car000", drives[0], "2026-03-02"),
                                                  ("car001", drives[1], "2026-03-02")]),
                    store, client=client)
    told: list[str] = []
    run_ = calibrate_fleet(_catalog(tmp_path / "b.csv", [("car001", drives[0], "2026-03-03"),
                                                         ("car001", drives[2], "2026-03-04")]),
                           store, client=client, refuse=told.append)
    assert told == list(run_.refused) and len(told) == 1
    assert told[0].startswith("catalog row 1 (car001): drive '") and \
        "is stored under vehicle car000" in told[0]
    rows = _rows(store)
    assert sorted((r["vehicle"], Path(r["source"]).name) for r in rows) == [
        ("car000", "d0.parquet"), ("car001", "d1.parquet"), ("car001", "d2.parquet")]


def test_a_changed_file_replaces_its_drive_row(drives: list[Path], client: Any,
                                               tmp_path: Path) -> None:
    log = tmp_path / "latest.parquet"
    shutil.copyfile(drives[0], log)
    catalog = _catalog(tmp_path / "c.csv", [("car", log, "2026-03-02")])
    store = tmp_path / "f.db"
    calibrate_fleet(catalog, store, client=client)
    [before] = _rows(store)
    shutil.copyfile(drives[1], log)                 # re-converted: other content, same place
    calibrate_fleet(catalog, store, client=client)
    [after] = _rows(store)
    assert after["content"] != before["content"] and after["c_e"] != before["c_e"]


def test_the_cli_exits_1_when_a_catalog_row_is_refused(drives: list[Path], tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    catalog = _catalog(tmp_path / "c.csv", [("car", drives[0], "2026-03-02")])
    store = tmp_path / "f.db"
    assert run(capsys, "fleet", "calibrate", str(catalog), "--store", str(store), "-q",
               "--workers", "1")[0] == 0
    other = _catalog(tmp_path / "o.csv", [("bus", drives[0], "2026-03-02")])
    code, out, err = run(capsys, "fleet", "calibrate", str(other), "--store", str(store), "-q",
                         "--workers", "1")
    assert code == 1 and out == ""
    assert err.splitlines()[0].startswith("odocal fleet calibrate: error: catalog row 1 (bus)")


# ---------------------------------------------------------------- drift: rejected drives, blends

def _history(values: list[float], *, rejected_from: int | None = None, std: float = 4e-4,
             name: str = "c_e") -> list[dict[str, Any]]:
    start = dt.datetime(2026, 3, 1, tzinfo=dt.UTC)
    rows = []
    for i, v in enumerate(values):
        rejected = rejected_from is not None and i >= rejected_from
        theta = {"c_e": 1.95, "c_d": -0.002, "t_r": 1.53, "d": 0.001, name: v}
        rows.append({"vehicle": "car", "task_key": f"k{i}",
                     "time": (start + dt.timedelta(days=i)).isoformat(), "event": None,
                     "success": not rejected, "status": "rejected" if rejected else "converged",
                     "out_of_range": json.dumps(["c_d"]) if rejected else None,
                     "distance_km": 3.0, "odometer_km": None,
                     **{k: theta[k] for k in theta},
                     **{f"{k}_std": (std if k == name else 1e-3) for k in theta},
                     **{f"{k}_identified": 1 for k in theta}})
    return rows


@pytest.mark.parametrize("size", [0.01, 0.02, 0.05])
def test_drives_rejected_for_a_range_are_evidence_of_a_change(size: float) -> None:
    rng = np.random.default_rng(int(size * 1000))
    c_d = list(-0.002 + rng.normal(0, 1e-4, 6)) + list(-0.002 - 2 * size * 1.95
                                                      + rng.normal(0, 1e-4, 4))
    rows = _history(c_d, rejected_from=6, std=1e-4, name="c_d")
    [alarm] = [a for a in analyse(rows, FleetSettings()).alarms if a.parameter == "c_d"]
    assert alarm.time == dt.datetime(2026, 3, 7, tzinfo=dt.UTC) and alarm.kind == "step"
    assert "drives since were rejected for an implausible parameter" in alarm.message
    # the same history with the rejected drives left out (as before) says nothing
    kept = [r for r in rows if r["success"]]
    assert not analyse(kept, FleetSettings()).alarms


@pytest.mark.parametrize("apart", [0.005, 0.007, 0.015])
def test_two_cars_under_one_name_are_named_not_blended(apart: float) -> None:
    rng = np.random.default_rng(int(apart * 1e4))
    pattern = [0, 1, 1, 0, 1, 0, 0, 1, 0, 1, 1, 0]
    values = [1.95 * (1 + apart * p) + rng.normal(0, 3e-4) for p in pattern]
    alarms = analyse(_history(values), FleetSettings()).alarms
    [mixed] = [a for a in alarms if a.kind == "mixed"]
    assert mixed.parameter == "c_e" and mixed.relative_change == pytest.approx(apart, rel=0.1)
    assert "two levels" in mixed.message and "6 drives at" in mixed.message


@pytest.mark.parametrize("history", ["one car", "a step", "a step and back"])
def test_one_car_a_step_or_a_step_and_back_are_not_a_blend(history: str) -> None:
    rng = np.random.default_rng(3)
    levels = {"one car": [0] * 12, "a step": [0] * 6 + [1] * 6,
              "a step and back": [0] * 4 + [1] * 4 + [0] * 4}[history]
    values = [1.95 * (1 - 0.007 * p) + rng.normal(0, 3e-4) for p in levels]
    assert not [a for a in analyse(_history(values), FleetSettings()).alarms
                if a.kind == "mixed"]


def test_a_flat_tyre_raises_alarms_on_every_vehicle(client: Any, tmp_path: Path) -> None:
    """``simulate-fleet --plan pressure --size 0.02`` with 300 s drives: every drive after the
    loss is rejected (c_d out of range), and every vehicle alarms."""
    made = simulate_fleet(tmp_path / "f", vehicles=2, drives=9, duration_s=300.0, seed=0,
                          plan="pressure", size=0.02)
    result = calibrate_fleet(made.catalog, tmp_path / "f.db", client=client)
    truth = json.loads(made.truth.read_text())
    for event in truth["events"]:
        alarms = [a for a in result.alarms if a.vehicle == event["vehicle"]]
        assert {a.parameter for a in alarms} >= {"c_e", "c_d"}, event
        c_e = next(a for a in alarms if a.parameter == "c_e")
        assert c_e.time.isoformat() == event["time"]
        assert c_e.relative_change == pytest.approx(-0.02, abs=0.004)


def test_two_simulated_cars_under_one_name_give_a_finding(client: Any, tmp_path: Path) -> None:
    base = TRUE_PARAMETERS.as_array()
    rows = []
    for i, car in enumerate([0, 1, 1, 0, 1, 0, 0, 1]):
        theta = base.copy()
        theta[0] *= 1.0 + 0.007 * car
        path = tmp_path / f"d{i}.parquet"
        odocal.save_drive(odocal.simulate(duration_s=200.0, seed=70 + i,
                                          theta=Parameters(*theta)).drive, path)
        rows.append(("car", path, f"2026-03-{i + 1:02d}"))
    result = calibrate_fleet(_catalog(tmp_path / "c.csv", rows), tmp_path / "f.db",
                             client=client)
    [mixed] = [a for a in result.alarms if a.kind == "mixed" and a.parameter == "c_e"]
    assert mixed.relative_change == pytest.approx(0.007, abs=0.0015)


# ---------------------------------------------------------------- a full disk

@contextlib.contextmanager
def _small_disk(path: Path, size_kb: int) -> Iterator[Path]:
    """A real file system of ``size_kb`` (tmpfs), or a skip where this process may not mount."""
    path.mkdir()
    if os.geteuid() != 0 or shutil.which("mount") is None:
        pytest.skip("mounting a small file system needs root")
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size_kb}k", "tmpfs",
                           str(path)], capture_output=True, check=False)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.decode().strip()}")
    try:
        yield path
    finally:
        subprocess.run(["umount", "-l", str(path)], check=False)


def _fill(disk: Path, leave_kb: int) -> None:
    free = shutil.disk_usage(disk).free
    (disk / "filler").write_bytes(b"\0" * max(free - leave_kb * 1024, 0))


@pytest.mark.parametrize("where", ["store", "outputs"])
def test_a_full_disk_is_one_line_and_exit_1(drives: list[Path], tmp_path: Path, where: str,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    catalog = _catalog(tmp_path / "c.csv", [("car", drives[0], "2026-03-02"),
                                            ("car", drives[1], "2026-03-03")])
    with _small_disk(tmp_path / "disk", 2048) as disk:
        store = (disk if where == "store" else tmp_path) / "f.db"
        out = (disk if where == "outputs" else tmp_path) / "out"
        if where == "store":                   # the store starts, then the disk fills
            assert run(capsys, "fleet", "calibrate", str(_catalog(
                tmp_path / "one.csv", [("car", drives[2], "2026-03-01")])), "--store",
                str(store), "-q", "--workers", "1")[0] == 0
        _fill(disk, 8)
        args = ["fleet", "calibrate", str(catalog), "--store", str(store), "-q", "--workers",
                "1"] + (["--out", str(out)] if where == "outputs" else [])
        code, _, err = run(capsys, *args)
    assert code == 1, err
    assert err.count("\n") == 1 and "internal error" not in err
    assert ("cannot write the fleet store" in err and "no space left on the device" in err
            if where == "store" else "cannot write the report of catalog row 1 (car)" in err
            and "No space left on device" in err), err


def test_a_version_2_store_becomes_one_row_per_drive_in_utc(tmp_path: Path) -> None:
    """Version 2 added a second row for a drive recalibrated with other settings and kept
    times with their offsets; opening it migrates to one row per drive, times in UTC."""
    import sqlite3

    path = tmp_path / "old.db"
    with sqlite3.connect(path) as db:
        db.execute("CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL)")
        db.execute("INSERT INTO meta VALUES ('schema_version', '2')")
        db.execute("CREATE TABLE drives (task_key TEXT PRIMARY KEY, vehicle TEXT NOT NULL, "
                   "time TEXT NOT NULL, source TEXT NOT NULL, status TEXT NOT NULL, "
                   "success INTEGER NOT NULL, c_e REAL, input_hashes TEXT, "
                   "stored_at TEXT NOT NULL)")
        rows = [("k1", "car", "2026-03-02T12:00:00+05:00", "a.parquet", 1.90, "aaa", "t1"),
                ("k2", "car", "2026-03-02T12:00:00+05:00", "a.parquet", 1.95, "aaa", "t2"),
                ("k3", "car", "2026-03-02T08:00:00+00:00", "b.parquet", 1.96, "bbb", "t1")]
        db.executemany("INSERT INTO drives VALUES (?, ?, ?, ?, 'converged', 1, ?, ?, ?)",
                       [(k, v, t, s, c, json.dumps({"source": h}), at)
                        for k, v, t, s, c, h, at in rows])
    with open_store(path) as store:
        got = [(r["task_key"], r["time"], r["c_e"], r["content"]) for r in store.drives()]
    assert got == [("k2", "2026-03-02T07:00:00+00:00", 1.95, "aaa"),
                   ("k3", "2026-03-02T08:00:00+00:00", 1.96, "bbb")]
