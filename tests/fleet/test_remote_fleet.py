"""Fleets whose drives and catalog lie in an object store (a real S3 API: moto's server, with
IAM authentication) or behind a plain HTTP server, calibrated on a real local Dask cluster whose
workers read the objects themselves."""

from __future__ import annotations

import sqlite3
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from odocal.fleet.engine import calibrate_fleet, dask_client
from odocal.fleet.simulate import simulate_fleet
from odocal.fleet.store import open_store
from tests.conftest import run
from tests.servers import S3Server, free_port, http_server, s3_server

PARAMS = ("c_e", "c_d", "t_r", "d", "c_e_std", "c_d_std", "t_r_std", "d_std", "e_p_m")


@pytest.fixture(scope="module")
def s3() -> Iterator[S3Server]:
    """The S3 API, its credentials and endpoint in the environment of this process and of the
    worker processes started after it (as a user's shell would have them)."""
    with s3_server() as server, pytest.MonkeyPatch.context() as mp:
        for key, value in server.env().items():
            mp.setenv(key, value)
        mp.delenv("AWS_PROFILE", raising=False)
        yield server


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory, s3: S3Server) -> Any:
    """2 vehicles x 3 drives of 200 s on disk, and the same folder uploaded to the bucket."""
    made = simulate_fleet(tmp_path_factory.mktemp("remote") / "f", vehicles=2, drives=3,
                          duration_s=200.0, seed=7, plan="none")
    s3.upload_tree("fleet", "v1", made.catalog.parent)
    return made


@pytest.fixture(scope="module")
def client(s3: S3Server) -> Iterator[Any]:
    with dask_client(workers=2) as c:
        yield c


def _by_drive(store: Path) -> dict[tuple[str, str], dict[str, Any]]:
    with open_store(store, create=False) as db:
        return {(r["vehicle"], r["time"]): r for r in db.drives()}


def test_a_fleet_in_a_bucket_gives_the_estimates_of_the_same_drives_on_disk(
        fleet: Any, client: Any, tmp_path: Path) -> None:
    local = calibrate_fleet(fleet.catalog, tmp_path / "local.db", client=client)
    remote = calibrate_fleet("s3://fleet/v1/catalog.csv", tmp_path / "remote.db", client=client)
    assert local.calibrated == remote.calibrated == 6 and not remote.refused
    on_disk, in_bucket = _by_drive(tmp_path / "local.db"), _by_drive(tmp_path / "remote.db")
    assert on_disk.keys() == in_bucket.keys()
    for key, row in on_disk.items():
        other = in_bucket[key]
        assert [row[p] for p in PARAMS] == [other[p] for p in PARAMS]    # to the last digit
        assert row["content"] == other["content"] and row["drive_id"] == other["drive_id"]
        assert other["source"].startswith("s3://fleet/v1/car00")
    # a rerun reads nothing: the store knows what each object's version holds
    again = calibrate_fleet("s3://fleet/v1/catalog.csv", tmp_path / "remote.db", client=client)
    assert again.calibrated == 0 and again.stored_before == 6
    # the same bytes on disk are the same drives: one row each, not a second history
    moved = calibrate_fleet(fleet.catalog, tmp_path / "remote.db", client=client)
    assert moved.calibrated == 0 and moved.stored_before == 6
    assert len(_by_drive(tmp_path / "remote.db")) == 6


def test_unreadable_objects_are_named_by_row_and_the_others_stored(
        fleet: Any, s3: S3Server, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    root = fleet.catalog.parent
    first = sorted((root / "car000").glob("*.parquet"))[0]
    s3.upload("fleet", "odd/cut.parquet", first.read_bytes()[: first.stat().st_size // 2])
    dead = f"http://127.0.0.1:{free_port()}/car001/x.parquet"
    with http_server(root) as web:
        second = sorted((root / "car001").glob("*.parquet"))[0]
        catalog = tmp_path / "catalog.csv"
        catalog.write_text(
            "vehicle,path,time\n"
            f"car000,s3://fleet/v1/car000/{first.name},2026-03-02T08:00:00Z\n"
            "car000,s3://fleet/v1/car000/missing.parquet,2026-03-03T08:00:00Z\n"
            "car000,s3://fleet/odd/cut.parquet,2026-03-04T08:00:00Z\n"
            f"car001,{dead},2026-03-02T08:00:00Z\n"
            f"car001,{web}/car001/{second.name}?X-Amz-Signature={s3.secret},"
            "2026-03-03T08:00:00Z\n")
        code, out, err = run(capsys, "fleet", "calibrate", str(catalog), "--store",
                             str(tmp_path / "f.db"), "--out", str(tmp_path / "out"),
                             "--workers", "2", "--no-drive-reports", "-v")
    assert code == 1
    lines = [line for line in err.splitlines() if "error: catalog row" in line]
    assert len(lines) == 3, err
    assert "catalog row 2 (car000): drive 's3://fleet/v1/car000/missing.parquet' does not " \
           "exist" in lines[0]
    assert "catalog row 4 (car001): drive '" + dead + "': the server 127.0.0.1:" in lines[1]
    assert "cannot be reached" in lines[1]
    assert "catalog row 3 (car000)" in lines[2] and "cannot be read as PARQUET" in lines[2]
    assert "3 catalog row(s) could not be used" in err
    stored = _by_drive(tmp_path / "f.db")
    assert sorted(r["source"] for r in stored.values()) == [
        f"{web}/car001/{second.name}", f"s3://fleet/v1/car000/{first.name}"]
    assert all(r["success"] for r in stored.values())
    outputs = [out, err, (tmp_path / "f.db").read_bytes().decode("latin-1")]
    outputs += [p.read_bytes().decode("latin-1") for p in (tmp_path / "out").rglob("*")
                if p.is_file()]
    for secret in (s3.secret, s3.key):
        assert not any(secret in text for text in outputs)


def test_wrong_credentials_refuse_the_bucket_rows_only(
        fleet: Any, s3: S3Server, client: Any, tmp_path: Path,
        monkeypatch: pytest.MonkeyPatch) -> None:
    root = fleet.catalog.parent
    drive = sorted((root / "car001").glob("*.parquet"))[1]
    other = sorted((root / "car000").glob("*.parquet"))[1]
    with http_server(root) as web:
        catalog = tmp_path / "catalog.csv"
        catalog.write_text("vehicle,path,time\n"
                           f"car000,s3://fleet/v1/car000/{other.name},2026-03-02T08:00:00Z\n"
                           f"car001,{web}/car001/{drive.name},2026-03-03T08:00:00Z\n")
        monkeypatch.setenv("AWS_SECRET_ACCESS_KEY", "wrong-secret-value")
        run_ = calibrate_fleet(catalog, tmp_path / "f.db", client=client)
    assert run_.calibrated == 1 and len(run_.refused) == 1
    assert run_.refused[0].startswith("catalog row 1 (car000): drive 's3://fleet/v1/car000/")
    assert "access denied" in run_.refused[0] and "wrong-secret-value" not in run_.refused[0]
    with sqlite3.connect(tmp_path / "f.db") as db:
        assert [r[0] for r in db.execute("SELECT vehicle FROM drives")] == ["car001"]


def test_a_bucket_folder_laid_out_by_vehicle_is_a_catalog(fleet: Any) -> None:
    from odocal.fleet.catalog import read_catalog

    on_disk = read_catalog(fleet.catalog.parent)
    listed = read_catalog("s3://fleet/v1/")
    assert [(e.vehicle, e.time, Path(e.path).name) for e in on_disk] == \
        [(e.vehicle, e.time, str(e.path).rsplit("/", 1)[1]) for e in listed]
    assert all(str(e.path).startswith(f"s3://fleet/v1/{e.vehicle}/") for e in listed)


# ---------------------------------------------------------------- issue 40

def test_a_catalog_behind_http_with_pre_signed_and_file_rows(
        fleet: Any, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A catalog served over HTTP whose rows are pre-signed relative entries (one object
    there, one missing) and a ``file://`` row (a file that exists but is no drive): the good
    rows are calibrated; each other one is named by its row; no signature or token appears on
    stdout, stderr, in the store or the report (on main: the entry's query was read as part of
    its path, printed in full, and the file:// row ended the run with nothing stored)."""
    root = fleet.catalog.parent
    drives = sorted((root / "car000").glob("*.parquet"))
    junk = tmp_path / "notes.txt"
    junk.write_text("not a drive\n")
    signed = "?X-Amz-Signature=SIGabc123&X-Amz-Security-Token=TOKENxyz789"
    served = tmp_path / "served"
    served.mkdir()
    (served / "car000").mkdir()
    for d in drives[:2]:
        (served / "car000" / d.name).write_bytes(d.read_bytes())
    (served / "catalog.csv").write_text(
        "vehicle,path,time\n"
        f"car000,car000/{drives[0].name}{signed},2026-03-02T08:00:00Z\n"
        f"car000,car000/missing.parquet{signed},2026-03-03T08:00:00Z\n"
        f"car000,file://{junk},2026-03-04T08:00:00Z\n"
        f"car000,car000/{drives[1].name}{signed},2026-03-05T08:00:00Z\n")
    with http_server(served) as web:
        code, out, err = run(capsys, "fleet", "calibrate", f"{web}/catalog.csv{signed}",
                             "--store", str(tmp_path / "f.db"), "--out", str(tmp_path / "out"),
                             "--workers", "2", "--no-drive-reports", "-v")
    assert code == 1
    lines = [line for line in err.splitlines() if "error: catalog row" in line]
    assert len(lines) == 2, err
    assert lines[0].endswith(f"catalog row 2 (car000): drive '{web}/car000/missing.parquet' "
                             "does not exist")
    assert "catalog row 3 (car000)" in lines[1] and str(junk) in lines[1]
    stored = _by_drive(tmp_path / "f.db")
    assert sorted(r["source"] for r in stored.values()) == [
        f"{web}/car000/{d.name}" for d in drives[:2]]
    outputs = [out, err, (tmp_path / "f.db").read_bytes().decode("latin-1")]
    outputs += [p.read_bytes().decode("latin-1") for p in (tmp_path / "out").rglob("*")
                if p.is_file()]
    assert not any(s in text for text in outputs for s in ("SIGabc123", "TOKENxyz789"))
