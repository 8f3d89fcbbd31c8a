"""SIGKILL in the middle of writing: a real ``odocal calibrate --out`` and a real ``odocal fleet
calibrate`` with a store, killed while their outputs are half written. Nothing of the user's,
no input and no stored row is lost, the earlier results stay whole, and no process is left."""

from __future__ import annotations

import hashlib
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

import odocal
from odocal.fleet.simulate import simulate_fleet
from odocal.fleet.store import open_store
from odocal.io import save_drive

BIN = Path(sys.executable).parent


def _tree(root: Path) -> dict[str, str]:
    """Every file under ``root`` (hidden ones included) by its SHA-256."""
    return {p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


def _group(pgid: int) -> list[int]:
    """Running (not zombie) processes of the process group ``pgid``, from /proc."""
    found = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as f:
                    fields = f.read().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[2]) == pgid and fields[0] != "Z":
                found.append(int(entry))
    return found


def _none_left(pgid: int, limit_s: float = 5.0) -> list[int]:
    deadline = time.monotonic() + limit_s
    while _group(pgid) and time.monotonic() < deadline:
        time.sleep(0.05)
    return _group(pgid)


@pytest.fixture(scope="module")
def drive_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("kill") / "drive.parquet"
    save_drive(odocal.simulate(duration_s=900.0, seed=31, noise="realistic").drive, path)
    return path


def _kill_while_part_exists(cmd: list[str], folder: Path, pattern: str) -> subprocess.Popen[Any]:
    """Start ``cmd``; SIGKILL its process group the moment ``folder`` holds ``pattern``."""
    proc = subprocess.Popen(cmd, start_new_session=True, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and proc.poll() is None:
        if any(folder.glob(pattern)):
            os.killpg(proc.pid, signal.SIGKILL)
            break
        time.sleep(0.002)
    proc.wait()
    return proc


def test_calibrate_killed_mid_write_loses_nothing(drive_file: Path, tmp_path: Path) -> None:
    work = tmp_path / "work"
    work.mkdir()
    drive = work / "drive.parquet"
    drive.write_bytes(drive_file.read_bytes())
    notes = work / "notes.txt"
    notes.write_text("the user's notes")
    out = work / "results"
    first = subprocess.run([str(BIN / "odocal"), "calibrate", str(drive), "--out", str(out),
                            "-q"], capture_output=True, text=True, timeout=600)
    assert first.returncode == 0, first.stderr
    before, drive_hash = _tree(out), hashlib.sha256(drive.read_bytes()).hexdigest()
    killed = False
    for _ in range(3):                            # the write can be quicker than the poll
        proc = _kill_while_part_exists(
            [str(BIN / "odocal"), "calibrate", str(drive), "--out", str(out), "-q"],
            work, ".results.*.part")
        if proc.returncode == -signal.SIGKILL:
            killed = True
            break
    assert killed, "never caught the run while it wrote"
    assert _none_left(proc.pid) == [], "a process of the killed run is still running"
    assert _tree(out) == before                   # the earlier results, whole
    assert hashlib.sha256(drive.read_bytes()).hexdigest() == drive_hash
    assert notes.read_text() == "the user's notes"
    assert any(work.glob(".results.*.part"))      # what the killed run left ...
    again = subprocess.run([str(BIN / "odocal"), "calibrate", str(drive), "--out", str(out),
                            "-q"], capture_output=True, text=True, timeout=600)
    assert again.returncode == 0, again.stderr
    left = sorted(p.name for p in work.iterdir())
    assert left == ["drive.parquet", "notes.txt", "results"]   # ... the next run removed


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Any:
    return simulate_fleet(tmp_path_factory.mktemp("kill") / "f", vehicles=2, drives=5,
                          duration_s=240.0, seed=7, plan="none")


def _rows(store: Path) -> dict[str, tuple[Any, ...]]:
    with sqlite3.connect(f"file:{store}?mode=ro", uri=True, timeout=30) as db:
        return {r[0]: r for r in db.execute("SELECT * FROM drives")}


@pytest.mark.parametrize("whom", ["group", "parent"])
def test_fleet_killed_mid_run_loses_no_row_input_or_file(fleet: Any, tmp_path: Path,
                                                         whom: str) -> None:
    """SIGKILL to the whole group (as a shell's kill -9 of a job), or to the parent alone (its
    Dask workers must then end by themselves)."""
    root = fleet.catalog.parent
    notes = root / "notes.txt"
    notes.write_text("the fleet manager's notes")
    inputs = _tree(root)
    store, out = tmp_path / "fleet.db", tmp_path / "report"
    cmd = [str(BIN / "odocal"), "fleet", "calibrate", str(fleet.catalog), "--store", str(store),
           "--out", str(out), "--workers", "2", "-q"]
    proc = subprocess.Popen(cmd, start_new_session=True, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    seen: dict[str, tuple[Any, ...]] = {}
    deadline = time.monotonic() + 300
    try:
        while time.monotonic() < deadline and len(seen) < 3 and proc.poll() is None:
            time.sleep(0.05)
            if store.exists():
                try:
                    seen = _rows(store)
                except sqlite3.Error:
                    seen = {}
        assert proc.poll() is None and len(seen) >= 3, "the run stored too little in time"
        if whom == "group":
            os.killpg(proc.pid, signal.SIGKILL)
        else:
            proc.kill()
        proc.wait()
        assert _none_left(proc.pid) == [], "a process of the killed fleet run is left"
    finally:
        if _group(proc.pid):
            os.killpg(proc.pid, signal.SIGKILL)
    with sqlite3.connect(store) as db:
        assert db.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    after = _rows(store)
    assert all(after[k] == row for k, row in seen.items())   # every row seen is there, as seen
    assert _tree(root) == inputs and notes.read_text() == "the fleet manager's notes"
    rerun = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert rerun.returncode == 0, rerun.stderr
    final = _rows(store)
    assert len(final) == 10 and all(final[k] == row for k, row in after.items())
    with open_store(store, create=False, read_only=True) as db:
        assert len(db.drives()) == 10
    assert not list(tmp_path.rglob("*.part")) and not list(root.rglob("*.part"))
    assert _tree(root) == inputs
