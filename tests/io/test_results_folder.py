"""What odocal may replace: only what it wrote itself (issue 22)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

import odocal
from odocal.errors import OutputError
from odocal.io.atomic import (
    RESULTS_MARKER,
    check_replaceable,
    file_name,
    remove_leftovers,
    results_folder,
)
from tests.conftest import run


@pytest.fixture()
def drive_file(tmp_path: Path, short_drive: Any) -> Path:
    path = tmp_path / "drive.parquet"
    odocal.save_drive(short_drive.drive, path)
    return path


@pytest.mark.parametrize("foreign", ["notes.txt", "figures/mine.png", "trajectories/x.tum",
                                     "deep/er/file", "evil\x1bname"])
def test_a_file_the_user_put_into_a_results_folder_stops_the_run(
        tmp_path: Path, drive_file: Path, capsys: pytest.CaptureFixture[str],
        foreign: str) -> None:
    out = tmp_path / "results"
    code, _, _ = run(capsys, "calibrate", str(drive_file), "--out", str(out), "--export", "tum")
    assert code == 0 and (out / RESULTS_MARKER).is_file()
    user = out / foreign
    user.parent.mkdir(parents=True, exist_ok=True)
    user.write_text("mine")
    before = sorted(p.relative_to(out).as_posix() for p in out.rglob("*"))
    code, out_text, err = run(capsys, "calibrate", str(drive_file), "--out", str(out))
    assert code == 1 and len(err.strip().splitlines()) == 1
    assert "which odocal did not write" in err and "\x1b" not in err
    assert foreign.split("/")[0].replace("\x1b", "") in err.replace("\\x1b", "")
    assert "parameter" not in out_text                       # refused before computing
    assert user.read_text() == "mine"
    assert sorted(p.relative_to(out).as_posix() for p in out.rglob("*")) == before


def test_odocal_replaces_its_own_folder_whole(tmp_path: Path, drive_file: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "results"
    assert run(capsys, "calibrate", str(drive_file), "--out", str(out), "--export", "tum",
               "--no-report")[0] == 0
    assert (out / "trajectories").is_dir()
    assert run(capsys, "calibrate", str(drive_file), "--out", str(out), "--no-report")[0] == 0
    assert not (out / "trajectories").exists()               # nothing of the earlier run stays
    assert sorted(p.name for p in tmp_path.iterdir()) == ["drive.parquet", "results"]


def test_a_folder_without_the_marker_is_replaced_only_if_it_holds_odocals_names(
        tmp_path: Path) -> None:
    old = tmp_path / "old"
    old.mkdir()
    (old / "calibration.json").write_text("{}")
    check_replaceable(old)                                   # an older odocal's folder
    (old / "data.csv").write_text("x")
    with pytest.raises(OutputError, match=r"data\.csv"):
        check_replaceable(old)
    afile = tmp_path / "file"
    afile.write_text("x")
    with pytest.raises(OutputError, match="not a folder"):
        check_replaceable(afile)


def test_a_failed_run_leaves_no_temporary_folder_and_the_old_results(tmp_path: Path) -> None:
    out = tmp_path / "results"
    with results_folder(out) as tmp:
        (tmp / "calibration.json").write_text("first")
    with pytest.raises(RuntimeError), results_folder(out) as tmp:
        (tmp / "calibration.json").write_text("second")
        raise RuntimeError("the computation failed")
    assert (out / "calibration.json").read_text() == "first"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["results"]


def test_a_dead_runs_leftovers_are_removed_and_a_live_runs_kept(tmp_path: Path) -> None:
    target = tmp_path / "results"
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)
    pid = int(dead.stdout)
    (tmp_path / f".results.{pid}.abc.part").mkdir()
    (tmp_path / f".results.{pid}.abc.old").mkdir()
    (tmp_path / f".results.{pid}.xyz.part").write_text("a file")
    live = tmp_path / f".results.{os.getpid()}.def.part"
    live.mkdir()
    unrelated = tmp_path / ".results.notes"
    unrelated.write_text("mine")
    remove_leftovers(target)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([live.name, unrelated.name])


def test_names_that_clean_alike_stay_apart() -> None:
    names = ["car/1", "car_1", "car 1", "car:1", "", ".hidden", "ü", "a" * 300]
    cleaned = [file_name(n) for n in names]
    assert len(set(cleaned)) == len(names)
    assert file_name("car_1") == "car_1"                     # a clean name stays as it is
    assert all(len(c.encode()) < 120 and "/" not in c and not c.startswith(".")
               for c in cleaned)


@pytest.mark.parametrize("make", ["long", "under_file"])
def test_an_output_that_cannot_be_written_is_named_before_computing(
        tmp_path: Path, drive_file: Path, capsys: pytest.CaptureFixture[str], make: str) -> None:
    target = (tmp_path / ("x" * 300) if make == "long" else drive_file / "sub")
    code, out, err = run(capsys, "calibrate", str(drive_file), "--out", str(target))
    assert code == 1 and "cannot write" in err and len(err.strip().splitlines()) == 1
    assert "parameter" not in out


# ---------------------------------------------------------------- issue 40: hashes, not names

@pytest.mark.parametrize("edited", ["calibration.json", "figures/map.png",
                                    "trajectories/reference.tum"])
def test_a_results_file_the_user_edited_stops_the_run(
        tmp_path: Path, drive_file: Path, capsys: pytest.CaptureFixture[str],
        edited: str) -> None:
    """The marker holds each file's SHA-256: a file edited by hand is the user's now, and the
    folder is refused like a foreign one (on main the edit was replaced without a word)."""
    out = tmp_path / "results"
    assert run(capsys, "calibrate", str(drive_file), "--out", str(out), "--export",
               "tum")[0] == 0
    path = out / edited
    path.write_bytes(path.read_bytes() + b"\n my note")
    mine = path.read_bytes()
    code, _, err = run(capsys, "calibrate", str(drive_file), "--out", str(out))
    assert code == 1 and len(err.strip().splitlines()) == 1
    assert f"holds '{edited}', changed since odocal wrote it" in err
    assert path.read_bytes() == mine


def test_the_marker_lists_every_file_with_its_sha256(tmp_path: Path, drive_file: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    import hashlib

    out = tmp_path / "results"
    assert run(capsys, "calibrate", str(drive_file), "--out", str(out), "--export",
               "tum,yaml")[0] == 0
    lines = (out / RESULTS_MARKER).read_text().splitlines()
    listed = dict(reversed(line.split("  ", 1)) for line in lines[1:])
    files = sorted(p.relative_to(out).as_posix() for p in out.rglob("*")
                   if p.is_file() and p.name != RESULTS_MARKER)
    assert sorted(listed) == files and len(files) >= 5
    assert all(hashlib.sha256((out / f).read_bytes()).hexdigest() == listed[f] for f in files)
    check_replaceable(out)


def test_what_odocal_simulate_wrote_is_odocals(tmp_path: Path, drive_file: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    """A folder holding a drive and truth odocal simulate wrote (its manifest says so, their
    content unchanged) is odocal's: calibrate replaces it (on main: "which odocal did not
    write"); once the drive is edited, it is the user's."""
    folder = tmp_path / "sim"
    assert run(capsys, "simulate", "--out", str(folder) + "/", "--duration", "120", "-q")[0] == 0
    assert sorted(p.name for p in folder.iterdir()) == [".odocal-outputs", "drive.parquet",
                                                        "drive.truth.json"]
    check_replaceable(folder)
    truth = folder / "drive.truth.json"
    truth.write_text(truth.read_text() + " ")
    with pytest.raises(OutputError, match=r"holds 'drive\.truth\.json', changed since odocal"):
        check_replaceable(folder)
    truth.write_text(truth.read_text()[:-1])
    code, _, err = run(capsys, "calibrate", str(drive_file), "--out", str(folder), "-q")
    assert code == 0, err
    assert (folder / "calibration.json").is_file() and not (folder / "drive.parquet").exists()


def test_an_older_marker_of_names_is_still_read(tmp_path: Path) -> None:
    old = tmp_path / "old"
    (old / "figures").mkdir(parents=True)
    (old / "calibration.json").write_text("{}")
    (old / "figures" / "map.png").write_bytes(b"png")
    (old / RESULTS_MARKER).write_text("written by odocal as a whole; replaced as a whole. It "
                                      "wrote:\n- calibration.json\n- figures\n- figures/map.png\n")
    check_replaceable(old)
    (old / "figures" / "mine.png").write_bytes(b"png")
    with pytest.raises(OutputError, match=r"figures/mine\.png"):
        check_replaceable(old)
