"""Fleets: catalog, store (the real SQLite file), drift detection, and the Dask engine run on a
real local cluster and on a real ``dask scheduler`` with two ``dask worker`` processes."""

from __future__ import annotations

import datetime as dt
import json
import os
import re
import signal
import socket
import sqlite3
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from odocal.cli.main import main
from odocal.errors import DataError, OdocalError
from odocal.fleet.catalog import read_catalog
from odocal.fleet.drift import analyse
from odocal.fleet.engine import calibrate_fleet, dask_client
from odocal.fleet.simulate import simulate_fleet
from odocal.fleet.store import SCHEMA_VERSION, open_store
from odocal.settings import FleetSettings
from tests.conftest import interrupt

BIN = Path(sys.executable).parent


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Any:
    """4 vehicles x 8 drives of 4 minutes: none (+ a mis-mapped log), pressure, wear, tyres."""
    return simulate_fleet(tmp_path_factory.mktemp("fleet") / "f", vehicles=4, drives=8,
                          duration_s=240.0, seed=3, size=0.004, wear=0.006)


@pytest.fixture(scope="module")
def client() -> Any:
    with dask_client(workers=2) as c:
        yield c


def _rows(db_path: Path) -> dict[str, dict[str, Any]]:
    with open_store(db_path, create=False) as db:
        return {r["task_key"]: r for r in db.drives()}


# ---------------------------------------------------------------- the engine, on real clusters

def test_fleet_on_local_cluster_detects_the_events(fleet: Any, client: Any,
                                                    tmp_path: Path) -> None:
    store = tmp_path / "fleet.db"
    run = calibrate_fleet(fleet.catalog, store, client=client, out=tmp_path / "out",
                          drive_reports=False)
    assert run.drives == 32 and run.calibrated == 32 and run.stored_before == 0
    rows = list(_rows(store).values())
    mismapped = [r for r in rows if r["vehicle"] == "car000" and not r["success"]]
    assert len(mismapped) == 1 and mismapped[0]["status"] == "rejected"
    # why, in the row itself (it said "the errors above say which", with nothing above it)
    assert mismapped[0]["message"].startswith("rejected: the yaw rate the wheels imply turns "
                                              "against the reference's in bends")
    assert "the left and right wheel columns are swapped" in mismapped[0]["message"]
    by_vehicle = {(a.vehicle, a.parameter) for a in run.alarms}
    assert ("car001", "c_e") in by_vehicle               # the pressure loss
    assert ("car002", "c_e") in by_vehicle               # the wear
    assert not any(v in ("car000", "car003") for v, _ in by_vehicle)   # none; declared tyres
    truth = json.loads(fleet.truth.read_text())
    pressure = next(e for e in truth["events"] if e["kind"] == "pressure")
    alarm = next(a for a in run.alarms if (a.vehicle, a.parameter) == ("car001", "c_e"))
    assert alarm.time.isoformat() == pressure["time"]
    assert alarm.relative_change == pytest.approx(-0.004, abs=0.001)
    assert alarm.kind == "step" and alarm.confidence > 0.99 and alarm.drives_to_detect <= 3
    wear = next(a for a in run.alarms if (a.vehicle, a.parameter) == ("car002", "c_e"))
    assert wear.kind == "trend"
    # every vehicle has a pooled calibration; the pressure car's uses the drives after the loss
    with open_store(store) as db:
        pooled = {p["vehicle"]: p for p in db.pooled()}
        assert set(pooled) == {"car000", "car001", "car002", "car003"}
        assert pooled["car001"]["c_e"] == pytest.approx(
            truth["vehicles"]["car001"]["drives"][-1]["theta"]["c_e"], abs=2e-3)
        assert len(json.loads(pooled["car001"]["drives"])) == 8 - pressure["drive"]
    html = (tmp_path / "out" / "report.html").read_text()
    assert "Vehicles to recalibrate" in html and "car001" in html and "data:image/png" in html
    # idempotent: the rerun calibrates nothing and changes nothing
    before = _rows(store)
    again = calibrate_fleet(fleet.catalog, store, client=client)
    assert again.calibrated == 0 and again.stored_before == 32 and again.pooled == 0
    assert {k: r["c_e"] for k, r in _rows(store).items()} == {k: r["c_e"]
                                                              for k, r in before.items()}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_fleet_on_a_running_dask_scheduler(fleet: Any, client: Any, tmp_path: Path) -> None:
    """A real `dask scheduler` and two `dask worker` processes on the loopback address; the
    answers are the local cluster's, to the last digit."""
    port = _free_port()
    address = f"tcp://127.0.0.1:{port}"
    env = {**os.environ, "NUMBA_NUM_THREADS": "1"}
    procs = [subprocess.Popen([str(BIN / "dask"), "scheduler", "--host", "127.0.0.1", "--port",
                               str(port), "--no-dashboard"], env=env,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    try:
        for _ in range(2):
            procs.append(subprocess.Popen(
                [str(BIN / "dask"), "worker", address, "--nthreads", "1", "--host", "127.0.0.1",
                 "--no-dashboard"], env=env, stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL))
        from distributed import Client

        with Client(address, timeout="60s") as probe:
            probe.wait_for_workers(2, timeout=60)
            assert len(probe.scheduler_info()["workers"]) == 2
        remote = tmp_path / "remote.db"
        run = calibrate_fleet(fleet.catalog, remote, scheduler=address)
        assert run.calibrated == 32
        local = tmp_path / "local.db"
        calibrate_fleet(fleet.catalog, local, client=client)
        a, b = _rows(remote), _rows(local)
        assert a.keys() == b.keys()
        for key in a:
            for col in ("c_e", "c_d", "t_r", "d", "c_e_std", "status"):
                assert a[key][col] == b[key][col], (key, col)
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in procs:
            p.wait(timeout=30)


def test_unreachable_scheduler_is_one_clear_error(fleet: Any, tmp_path: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["fleet", "calibrate", str(fleet.catalog), "--store", str(tmp_path / "x.db"),
                 "--scheduler", f"tcp://127.0.0.1:{_free_port()}", "-q"])
    err = capsys.readouterr().err
    assert code == 1 and "cannot reach the Dask scheduler" in err and len(err.splitlines()) == 1


def _wait_for_drives(store: Path, count: int, limit_s: float = 240.0) -> int:
    """Poll a store another process writes until it holds ``count`` drives (or time runs out)."""
    deadline = time.monotonic() + limit_s
    stored = 0
    while time.monotonic() < deadline and stored < count:
        time.sleep(0.2)
        if store.exists():
            with sqlite3.connect(store, timeout=30) as db:
                try:
                    stored = db.execute("SELECT count(*) FROM drives").fetchone()[0]
                except sqlite3.OperationalError:
                    stored = 0
    return int(stored)


def test_sigkill_loses_nothing_stored_and_the_rerun_finishes(fleet: Any, tmp_path: Path) -> None:
    store = tmp_path / "killed.db"
    cmd = [str(BIN / "odocal"), "fleet", "calibrate", str(fleet.catalog), "--store", str(store),
           "--workers", "1", "-q"]
    proc = subprocess.Popen(cmd, start_new_session=True, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    try:
        stored = _wait_for_drives(store, 4)
        assert stored >= 4, "the run stored nothing in time"
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    with sqlite3.connect(store) as db:
        assert db.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
        kept = db.execute("SELECT count(*) FROM drives").fetchone()[0]
    assert 4 <= kept < 32
    rerun = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert rerun.returncode == 0, rerun.stderr
    with open_store(store, create=False) as db:
        assert len(db.drives()) == 32
    assert _rows(store).keys() >= set()


def test_one_unreadable_drive_is_named_by_its_row_and_the_rest_calibrate(
        fleet: Any, client: Any, tmp_path: Path) -> None:
    bad = tmp_path / "broken.parquet"
    bad.write_bytes(b"PAR1 this is not parquet")
    good = sorted((fleet.catalog.parent / "car003").glob("*.parquet"))[0]
    catalog = tmp_path / "catalog.csv"
    catalog.write_text(f"vehicle,path,time\nx,{bad},2026-01-01\nx,{good},2026-01-02\n")
    told: list[str] = []
    run = calibrate_fleet(catalog, tmp_path / "s.db", client=client, refuse=told.append)
    assert run.calibrated == 1 and run.failed == 0
    assert told == list(run.refused) and len(told) == 1
    assert told[0].startswith("catalog row 1 (x): ") and "cannot be read" in told[0]
    assert "\n" not in told[0]
    [row] = _rows(tmp_path / "s.db").values()          # nothing stored for the broken one
    assert row["success"] == 1 and row["source"] == str(good)


# ---------------------------------------------------------------- catalog

def test_catalog_errors_are_one_line(tmp_path: Path) -> None:
    drive = tmp_path / "d.parquet"
    drive.write_bytes(b"x")
    cases = {
        "vehicle,path\nv,d.parquet\n": "lacks column time",
        "vehicle,path,time\nv,d.parquet,yesterday\n": "not an ISO 8601",
        "vehicle,path,time\nv,nope.parquet,2026-01-01\n": "does not exist",
        "vehicle,path,time,format\nv,d.parquet,2026-01-01,tar\n": "unknown format",
        "vehicle,path,time,odometer_km\nv,d.parquet,2026-01-01,-5\n": "not a plausible",
        "vehicle,path,time\n,d.parquet,2026-01-01\n": "the vehicle is empty",
    }
    for text, message in cases.items():
        catalog = tmp_path / "c.csv"
        catalog.write_text(text)
        with pytest.raises(OdocalError, match=message):
            read_catalog(catalog)


def test_the_same_drive_twice_is_refused(fleet: Any, tmp_path: Path) -> None:
    good = sorted((fleet.catalog.parent / "car000").glob("*.parquet"))[0]
    copy = tmp_path / "copy.parquet"
    copy.write_bytes(good.read_bytes())
    catalog = tmp_path / "c.csv"
    catalog.write_text(f"vehicle,path,time\na,{good},2026-01-01\nb,{copy},2026-01-02\n")
    with pytest.raises(DataError, match="same drive"):
        calibrate_fleet(catalog, tmp_path / "s.db", workers=1)


def test_folder_layout_is_a_catalog(fleet: Any) -> None:
    entries = read_catalog(fleet.catalog.parent)
    assert len(entries) == 32 and {e.vehicle for e in entries} == {f"car00{i}" for i in range(4)}
    times = [e.time for e in entries if e.vehicle == "car001"]
    assert times == sorted(times)


def test_store_refuses_inputs_and_other_databases(fleet: Any, tmp_path: Path) -> None:
    with pytest.raises(OdocalError, match="input"):
        calibrate_fleet(fleet.catalog, fleet.catalog, workers=1)
    other = tmp_path / "other.db"
    with sqlite3.connect(other) as db:
        db.execute("CREATE TABLE t (x)")
    with pytest.raises(DataError, match="not an odocal fleet store"):
        open_store(other)
    with pytest.raises(DataError, match="does not exist"):
        open_store(tmp_path / "missing.db", create=False)


# ---------------------------------------------------------------- store

def test_store_migrates_a_version_1_file(tmp_path: Path) -> None:
    path = tmp_path / "v1.db"
    cols = ", ".join(f"{n} REAL, {n}_std REAL, {n}_identified INTEGER"
                     for n in ("c_e", "c_d", "t_r", "d"))
    with sqlite3.connect(path) as db:
        db.execute("CREATE TABLE meta (key TEXT PRIMARY KEY, value TEXT NOT NULL)")
        db.execute("INSERT INTO meta VALUES ('schema_version', '1')")
        db.execute(f"""CREATE TABLE drives (task_key TEXT PRIMARY KEY, vehicle TEXT NOT NULL,
            time TEXT NOT NULL, odometer_km REAL, source TEXT NOT NULL, format TEXT, event TEXT,
            method TEXT, status TEXT NOT NULL, success INTEGER NOT NULL, message TEXT, {cols},
            covariance TEXT, e_p_m REAL, datasheet_e_p_m REAL, distance_km REAL,
            duration_s REAL, error TEXT, input_hashes TEXT, settings_hash TEXT,
            odocal_version TEXT, stored_at TEXT NOT NULL)""")
        db.execute("INSERT INTO drives (task_key, vehicle, time, source, status, success, c_e, "
                   "stored_at) VALUES ('k', 'v', '2026-01-01T00:00:00+00:00', 'x', "
                   "'converged', 1, 1.95, 'then')")
    with open_store(path) as store:
        row = store.drives()[0]
        assert row["c_e"] == 1.95 and row["findings"] is None and row["report"] is None
        assert store.pooled() == []
        version = store.db.execute("SELECT value FROM meta WHERE key='schema_version'")
        assert int(version.fetchone()[0]) == SCHEMA_VERSION
    with sqlite3.connect(path) as db:
        db.execute("UPDATE meta SET value = '99' WHERE key = 'schema_version'")
    with pytest.raises(DataError, match="newer than this"):
        open_store(path)


def test_a_failed_transaction_stores_nothing(tmp_path: Path) -> None:
    with open_store(tmp_path / "s.db") as store:
        with pytest.raises(ZeroDivisionError), store.transaction() as db:
            db.execute("INSERT INTO baselines VALUES ('v', 'c_e', 't', 1, 1, 0, 4)")
            raise ZeroDivisionError
        assert store.baselines() == []


# ---------------------------------------------------------------- drift detection

def _history(values: list[float], std: float, *, events: dict[int, str] | None = None,
             odometer: bool = True, km0: float = 1000.0) -> list[dict[str, Any]]:
    t0 = dt.datetime(2026, 1, 1, tzinfo=dt.UTC)
    rows = []
    for i, v in enumerate(values):
        row: dict[str, Any] = {"task_key": f"k{i:04d}", "vehicle": "v",
                               "time": (t0 + dt.timedelta(days=i)).isoformat(),
                               "odometer_km": km0 + 20 * i if odometer else None,
                               "distance_km": 20.0, "success": 1,
                               "event": (events or {}).get(i)}
        for n in ("c_e", "c_d", "t_r", "d"):
            row[n], row[f"{n}_std"], row[f"{n}_identified"] = (v, std, 1) if n == "c_e" \
                else (0.0, 0.0, 0)
        rows.append(row)
    return rows


def test_a_step_is_found_where_it_happened() -> None:
    rng = np.random.default_rng(0)
    values = list(1.95 + rng.normal(0, 4e-4, 30))
    for i in range(17, 30):
        values[i] -= 0.002 * 1.95
    alarms = analyse(_history(values, 4e-4), FleetSettings()).alarms
    assert len(alarms) == 1
    a = alarms[0]
    assert a.parameter == "c_e" and a.kind == "step" and a.time.day == 18    # drive 17
    assert a.relative_change == pytest.approx(-0.002, abs=4e-4)
    assert "c_e fell 0." in a.message and "since 2026-01-18" in a.message


def test_no_alarm_without_a_change_over_many_drives() -> None:
    """5,000 event-free drives whose scatter is a quarter larger than their stated std: fewer
    than 4 alarms per 1,000 drives (the target is 5)."""
    rng = np.random.default_rng(1)
    alarms = 0
    for _ in range(100):
        values = list(1.95 + rng.normal(0, 5e-4, 50))
        alarms += len(analyse(_history(values, 4e-4), FleetSettings()).alarms)
    assert alarms < 20


def test_one_wild_drive_never_alarms_and_events_reset() -> None:
    values = [1.95] * 6 + [1.90] + [1.95] * 6
    assert analyse(_history(values, 4e-4), FleetSettings()).alarms == ()
    # a declared tyre change: the new level is the new baseline, not an alarm
    values = [1.95] * 8 + [1.96] * 8
    result = analyse(_history(values, 4e-4, events={8: "tyre change"}), FleetSettings())
    assert result.alarms == ()
    assert [b.value for b in result.baselines] == pytest.approx([1.95, 1.96])


@pytest.mark.parametrize("km0", [1000.0, 19000.0, 150000.0])
def test_wear_is_a_trend_at_its_rate(km0: float) -> None:
    """0.4% over 29 drives of 20 km: 0.69% per 1000 km whatever the odometer reads (the
    hostile run: a car at 19,000 km was said to wear 3.83% per 1000 km where it wore 13.8%,
    the rate taken as a share of the line's value at 0 km)."""
    values = [1.95 * (1 - 0.004 * i / 29) for i in range(30)]
    alarms = analyse(_history(values, 3e-4, km0=km0), FleetSettings()).alarms
    assert alarms and alarms[0].kind == "trend"
    assert alarms[0].relative_change < 0
    rate = re.search(r"gradually \(([0-9.]+)% per 1000 km\)", alarms[0].message)
    assert rate is not None, alarms[0].message
    assert float(rate[1]) == pytest.approx(0.4 / 580 * 1000, abs=0.02)


# ---------------------------------------------------------------- the command line

def test_cli_alarms_history_and_simulate_fleet(fleet: Any, client: Any, tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    store = tmp_path / "s.db"
    calibrate_fleet(fleet.catalog, store, client=client)
    assert main(["fleet", "alarms", "--store", str(store), "--json"]) == 0
    alarms = json.loads(capsys.readouterr().out)
    assert alarms and all({"vehicle", "parameter", "time", "relative_change", "confidence"}
                          <= set(a) for a in alarms)
    assert {a["parameter"] for a in alarms} <= {"c_e", "c_d", "t_r", "d"}
    assert main(["fleet", "history", "--store", str(store), "--vehicle", "car001", "--json"]) == 0
    history = json.loads(capsys.readouterr().out)
    assert len(history) == 8 and all(len(r["covariance"]) == 4 for r in history if r["success"])
    assert main(["fleet", "history", "--store", str(store), "--vehicle", "car001"]) == 0
    assert "c_e [m]" in capsys.readouterr().out
    assert main(["fleet", "history", "--store", str(store), "--vehicle", "nope"]) == 1
    assert "no drive of vehicle 'nope'" in capsys.readouterr().err
    assert main(["simulate-fleet", "--out", str(fleet.catalog.parent), "-q"]) == 1
    assert "not an empty folder" in capsys.readouterr().err


def test_ctrl_c_stops_the_fleet_at_once_and_keeps_what_is_stored(fleet: Any,
                                                                   tmp_path: Path) -> None:
    store = tmp_path / "interrupted.db"
    proc = subprocess.Popen([str(BIN / "odocal"), "fleet", "calibrate", str(fleet.catalog),
                             "--store", str(store), "--workers", "1"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    stored = _wait_for_drives(store, 2)
    err = interrupt(proc, 30, "the fleet run")
    assert proc.returncode == 130 and "interrupted" in err and "Traceback" not in err
    with sqlite3.connect(store) as db:
        assert db.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
        assert db.execute("SELECT count(*) FROM drives").fetchone()[0] >= stored


def test_the_same_samples_in_two_files_are_stored_once(fleet: Any, client: Any,
                                                      tmp_path: Path) -> None:
    """A catalog that lists a drive as Parquet, as CSV and with its clock shifted: one row
    stored, the two others named by their row (on main: three drives of one recording in the
    vehicle's history); a rerun that lists the CSV alone names it against the stored drive."""
    from odocal.io import load_drive, save_drive

    good = sorted((fleet.catalog.parent / "car000").glob("*.parquet"))[0]
    drive = load_drive(good)
    csv = tmp_path / "same.csv"
    save_drive(drive, csv)
    columns = dict(drive.columns())
    columns["t"] = np.asarray(columns["t"]) + 5000.0
    shifted = tmp_path / "shifted.parquet"
    save_drive(type(drive).from_columns(columns, name="shifted"), shifted)
    catalog = tmp_path / "c.csv"
    catalog.write_text(f"vehicle,path,time\ncar000,{good},2026-01-01\n"
                       f"car000,{csv},2026-01-02\ncar000,{shifted},2026-01-03\n")
    run = calibrate_fleet(catalog, tmp_path / "s.db", client=client)
    assert run.calibrated == 1 and len(run.refused) == 2, run.refused
    assert all("holds the same samples as catalog row" in r for r in run.refused)
    # (the one stored is the first whose result came back: the workers decide the order)
    assert len({r.split(":")[0] for r in run.refused}) == 2
    again = tmp_path / "again.csv"
    stored = _rows(tmp_path / "s.db")
    kept = next(iter(stored.values()))["source"]
    other = next(p for p in (good, csv, shifted) if str(p) != kept)
    again.write_text(f"vehicle,path,time\ncar000,{other},2026-01-02\n")
    rerun = calibrate_fleet(again, tmp_path / "s.db", client=client)
    assert rerun.calibrated == 0 and "the stored drive" in rerun.refused[0]
    assert len(_rows(tmp_path / "s.db")) == 1
