"""Inputs that used to crash (exit 4) or hang: one line, exit 1, at once (issue 22)."""

from __future__ import annotations

import os
import socket
import sqlite3
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

import odocal
from tests.conftest import run

BIN = Path(sys.executable).parent


@pytest.fixture()
def drive_file(tmp_path: Path, short_drive: Any) -> Path:
    path = tmp_path / "drive.parquet"
    odocal.save_drive(short_drive.drive, path)
    return path


def _one_line(code: int, err: str) -> str:
    assert code == 1, err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert "internal error" not in err
    return err


@pytest.mark.parametrize(("text", "kind"), [
    ("a = " + "[" * 3000 + "]" * 3000, "toml"),
    ("[a]\nb = " + "{x = " * 3000 + "1" + "}" * 3000, "toml"),
    ('{"theta": ' + "[" * 100000 + "]" * 100000 + "}", "json"),
    ('{"theta": ' + '{"a": ' * 50000 + "1" + "}" * 50000 + "}", "json")])
def test_deeply_nested_settings_or_parameters(tmp_path: Path, drive_file: Path,
                                              capsys: pytest.CaptureFixture[str], text: str,
                                              kind: str) -> None:
    path = tmp_path / f"deep.{kind}"
    path.write_text(text)
    argv = (["calibrate", str(drive_file), "--out", str(tmp_path / "r"), "--config", str(path)]
            if kind == "toml" else ["validate", str(drive_file), "--params", str(path)])
    err = _one_line(*run(capsys, *argv)[::2])
    assert "deep" in err


@pytest.mark.parametrize(("section", "key", "value"), [
    ("uncertainty", "bootstrap_count", "1000000000"), ("minimum", "population", "100000000"),
    ("minimum", "max_generations", "10000000000"),
    ("segments", "validation_distance_m", "1e-300"), ("segments", "validation_distance_m",
                                                      "0.001"),
    ("segments", "validation_distance_m", "1e300")])
def test_settings_that_would_exhaust_memory_or_never_end(tmp_path: Path, drive_file: Path,
                                                         capsys: pytest.CaptureFixture[str],
                                                         section: str, key: str,
                                                         value: str) -> None:
    config = tmp_path / "c.toml"
    config.write_text(f"[{section}]\n{key} = {value}\n")
    err = _one_line(*run(capsys, "calibrate", str(drive_file), "--out", str(tmp_path / "r"),
                         "--config", str(config))[::2])
    assert f"[{section}] {key}" in err and "expected" in err


def _special(tmp_path: Path, kind: str) -> str:
    if kind == "fifo":
        path = tmp_path / "pipe.csv"
        os.mkfifo(path)
        return str(path)
    if kind == "socket":
        path = tmp_path / "sock.csv"
        server = socket.socket(socket.AF_UNIX)
        server.bind(str(path))
        return str(path)
    if kind == "device":
        return "/dev/zero"
    folder = tmp_path / "folder.toml"
    folder.mkdir()
    return str(folder)


@pytest.mark.parametrize("kind", ["fifo", "socket", "device", "folder"])
@pytest.mark.parametrize("role", ["log", "config", "params", "catalog"])
def test_files_that_are_not_files_are_named_without_blocking(tmp_path: Path, drive_file: Path,
                                                             kind: str, role: str) -> None:
    special = _special(tmp_path, kind)
    argv = {"log": ["calibrate", special, "--out", str(tmp_path / "r")],
            "config": ["calibrate", str(drive_file), "--out", str(tmp_path / "r"), "--config",
                       special],
            "params": ["validate", str(drive_file), "--params", special],
            "catalog": ["fleet", "calibrate", special, "--store", str(tmp_path / "s.db")]}[role]
    if role == "catalog" and kind == "folder":
        pytest.skip("a folder is a catalog (VEHICLE/DATE_*.parquet)")
    proc = subprocess.run([str(BIN / "odocal"), *argv], capture_output=True, text=True,
                          timeout=60)
    err = _one_line(proc.returncode, proc.stderr)
    words = {"fifo": "FIFO", "socket": "socket", "device": "character device",
             "folder": "folder"}[kind]
    assert words in err, err


def test_control_characters_in_names_are_escaped(tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    name = str(tmp_path / "a\x1b[31mred\rb.csv")
    err = _one_line(*run(capsys, "calibrate", name, "--out", str(tmp_path / "r"))[::2])
    assert "\x1b" not in err and "\r" not in err and "\\x1b" in err


@pytest.mark.parametrize("address", ["foo", "tcp://", "tcp://host:notaport", "tcp://h:99999",
                                     "http://h:1", "tcp://h:1 extra"])
def test_a_malformed_scheduler_address(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                       address: str) -> None:
    catalog = tmp_path / "catalog.csv"
    drive = tmp_path / "a.parquet"
    odocal.save_drive(odocal.simulate(duration_s=60, seed=1).drive, drive)
    catalog.write_text("vehicle,path,time\ncar,a.parquet,2026-01-01\n")
    err = _one_line(*run(capsys, "fleet", "calibrate", str(catalog), "--store",
                         str(tmp_path / "s.db"), "--scheduler", address)[::2])
    assert "not a scheduler address" in err
    assert not (tmp_path / "s.db").exists()


def test_a_scheduler_that_never_answers_is_given_up(tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    catalog = tmp_path / "catalog.csv"
    odocal.save_drive(odocal.simulate(duration_s=60, seed=1).drive, tmp_path / "a.parquet")
    catalog.write_text("vehicle,path,time\ncar,a.parquet,2026-01-01\n")
    silent = socket.socket()                   # listens, never speaks Dask
    silent.bind(("127.0.0.1", 0))
    silent.listen()
    port = silent.getsockname()[1]
    err = _one_line(*run(capsys, "fleet", "calibrate", str(catalog), "--store",
                         str(tmp_path / "s.db"), "--scheduler", f"tcp://127.0.0.1:{port}",
                         "--connect-timeout", "2")[::2])
    assert "cannot reach the Dask scheduler" in err
    silent.close()


@pytest.mark.parametrize("content", ["empty", "foreign", "garbage", "missing"])
@pytest.mark.parametrize("command", ["alarms", "history"])
def test_read_only_fleet_commands_change_nothing(tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str],
                                                 content: str, command: str) -> None:
    store = tmp_path / "other.db"
    if content == "empty":
        store.write_bytes(b"")
    elif content == "foreign":
        with sqlite3.connect(store) as db:
            db.execute("CREATE TABLE accounts (id INTEGER)")
    elif content == "garbage":
        store.write_bytes(b"not a database at all" * 100)
    before = store.read_bytes() if store.exists() else None
    argv = ["fleet", command, "--store", str(store)] + (["--vehicle", "x"]
                                                       if command == "history" else [])
    err = _one_line(*run(capsys, *argv)[::2])
    assert "store" in err or "database" in err
    assert (store.read_bytes() if store.exists() else None) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ([] if before is None else
                                                          ["other.db"])
    if content == "foreign":
        with sqlite3.connect(store) as db:
            assert db.execute("PRAGMA journal_mode").fetchone()[0] == "delete"


def test_more_workers_than_cores_start_as_many_as_there_are_cores(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from odocal.fleet.engine import available_cores

    catalog = tmp_path / "catalog.csv"
    odocal.save_drive(odocal.simulate(duration_s=120, seed=1).drive, tmp_path / "a.parquet")
    catalog.write_text("vehicle,path,time\ncar,a.parquet,2026-01-01\n")
    code, _, err = run(capsys, "fleet", "calibrate", str(catalog), "--store",
                       str(tmp_path / "s.db"), "--workers", "1000")
    assert code == 0, err
    assert f"this machine has {available_cores()} cores; starting {available_cores()}" in err


def test_an_input_name_longer_than_the_system_allows(tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    err = _one_line(*run(capsys, "calibrate", str(tmp_path / ("y" * 400 + ".parquet")),
                         "--out", str(tmp_path / "r"))[::2])
    assert "too long" in err and len(err) < 400


@pytest.mark.parametrize(("factor", "words"), [(2 * 3.141592653589793, "rad/s: divide by 2 pi"),
                                               (60.0, "rpm: divide by 60")])
def test_wheel_rates_in_another_unit_are_named_by_that_unit(factor: float, words: str) -> None:
    cols = odocal.simulate(duration_s=300, seed=5).drive.columns()
    cols["n_rl"], cols["n_rr"] = cols["n_rl"] * factor, cols["n_rr"] * factor
    with pytest.raises(odocal.DataError) as err:
        odocal.Drive.from_columns(cols)
    assert words in str(err.value)


def test_the_cause_of_an_error_is_shown_under_verbose_only(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "drive.parquet"
    bad.write_bytes(b"garbage")
    code, _, err = run(capsys, "calibrate", str(bad), "--out", str(tmp_path / "out"))
    line = _one_line(code, err)
    assert "cannot be read as PARQUET" in line and "caused by" not in line
    code, _, err = run(capsys, "calibrate", str(bad), "--out", str(tmp_path / "out"), "-v")
    assert code == 1 and "Traceback" not in err
    causes = [row for row in err.splitlines() if row.startswith("  caused by ")]
    assert causes and causes[0].startswith("  caused by ArrowInvalid: ")    # pyarrow's words
    assert not (tmp_path / "out").exists()
