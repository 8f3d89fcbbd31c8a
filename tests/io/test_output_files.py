"""Single output files follow the results folder's rule (issue 32): odocal replaces only what it
wrote. Each file it writes for a command's ``--out`` is listed, with the SHA-256 of its content,
in the folder's ``.odocal-outputs`` (``sha256sum``'s format); a file not listed there, or changed
since, is the user's and stops the run before anything is computed."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path
from typing import Any

import pytest

import odocal
from odocal.cli.main import EXIT_ERROR, EXIT_OK
from odocal.errors import OutputError
from odocal.io.atomic import (
    OUTPUTS_MANIFEST,
    _manifest_line,
    _read_manifest,
    check_output_file,
    write_text,
)
from tests.conftest import run

USER = "the user's own file\n"


@pytest.fixture(scope="module")
def drive_file(tmp_path_factory: pytest.TempPathFactory, short_drive: Any) -> Path:
    path = tmp_path_factory.mktemp("inputs") / "drive.parquet"
    odocal.save_drive(short_drive.drive, path)
    return path


def _refused(code: int, out: str, err: str, name: str) -> None:
    assert code == EXIT_ERROR and len(err.strip().splitlines()) == 1, err
    assert f"'{name}' exists and odocal did not write it" in err.replace(str(Path.cwd()), "")
    assert "odocal replaces only files it wrote" in err


@pytest.mark.parametrize(("argv", "user_file"), [
    (["simulate", "--out", "real.csv", "--duration", "60"], "real.csv"),
    (["simulate", "--out", "real.parquet", "--duration", "60"], "real.parquet"),
    (["simulate", "--out", "run.csv", "--duration", "60"], "run.truth.json"),
    (["simulate", "--out", "folder", "--duration", "60"], "folder/drive.parquet"),
    (["simulate", "--out", "folder/", "--duration", "60"], "folder/drive.truth.json"),
    (["minimum", "{drive}", "--out", "min.json"], "min.json"),
    (["minimum", "{drive}", "--out", "folder"], "folder/minimum.json"),
    (["reproduce", "--out", "paper.json"], "paper.json"),
    (["reproduce", "--out", "folder"], "folder/reproduce.json"),
    (["convert", "--from", "rosbag", "{bag}", "--out", "converted.parquet"], "converted.parquet"),
])
def test_a_users_file_of_that_name_stops_the_command_before_computing(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
        drive_file: Path, argv: list[str], user_file: str) -> None:
    monkeypatch.chdir(tmp_path)
    (tmp_path / "folder").mkdir()
    (tmp_path / user_file).write_text(USER)
    bag = tmp_path / "log.bag"
    bag.write_bytes(b"not read: the output is checked first")
    argv = [a.format(drive=drive_file, bag=bag) for a in argv]
    code, out, err = run(capsys, *argv)
    _refused(code, out, err, user_file)
    assert (tmp_path / user_file).read_text() == USER
    assert out == ""                                          # nothing computed, nothing said
    assert not (tmp_path / OUTPUTS_MANIFEST).exists()


def test_convert_into_a_folder_refuses_a_users_file_named_like_a_log(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str],
        short_drive: Any) -> None:
    from tests.bagwriter import write_bag

    (tmp_path / "in").mkdir()
    bag = write_bag(short_drive.drive, tmp_path / "in" / "trip.bag", "ros1")
    out = tmp_path / "out"
    out.mkdir()
    monkeypatch.chdir(out)
    code, _, _ = run(capsys, "convert", "--from", "rosbag", str(bag), "--out", ".", "-q")
    assert code == EXIT_OK
    written = sorted(p.name for p in out.iterdir())
    assert written == [OUTPUTS_MANIFEST, "trip.parquet"]
    # a rerun replaces odocal's own file
    assert run(capsys, "convert", "--from", "rosbag", str(bag), "--out", ".", "-q")[0] == EXIT_OK
    # the user's file of that name is not replaced
    (out / "trip.parquet").write_text(USER)
    code, _, err = run(capsys, "convert", "--from", "rosbag", str(bag), "--out", ".")
    assert code == EXIT_ERROR and "'trip.parquet' exists and changed since odocal wrote it" in err
    assert (out / "trip.parquet").read_text() == USER


def test_odocal_replaces_its_own_files_and_lists_them_for_sha256sum(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.chdir(tmp_path)
    for seed in ("1", "2"):                                   # the second run replaces the first
        code, _, err = run(capsys, "simulate", "--out", "sim.csv", "--duration", "30", "--seed",
                           seed, "-q")
        assert code == EXIT_OK, err
    first = odocal.simulate(duration_s=30, seed=2).drive
    assert odocal.load_drive(tmp_path / "sim.csv").n_samples == first.n_samples
    listed = _read_manifest(tmp_path)
    assert sorted(listed) == ["sim.csv", "sim.truth.json"]
    if shutil.which("sha256sum"):
        check = subprocess.run(["sha256sum", "-c", OUTPUTS_MANIFEST], cwd=tmp_path,
                               capture_output=True, text=True)
        assert check.returncode == 0 and check.stdout.count(": OK") == 2, check.stdout
    # a file odocal wrote and the user then edited is the user's
    with open(tmp_path / "sim.csv", "a") as handle:
        handle.write("# my note\n")
    code, _, err = run(capsys, "simulate", "--out", "sim.csv", "--duration", "30")
    assert code == EXIT_ERROR and "changed since odocal wrote it" in err
    # and one it wrote that is gone may be written again (its line is dropped then)
    (tmp_path / "sim.csv").unlink()
    (tmp_path / "sim.truth.json").unlink()
    assert run(capsys, "simulate", "--out", "sim.parquet", "--duration", "30", "-q")[0] == 0
    assert sorted(_read_manifest(tmp_path)) == ["sim.parquet", "sim.truth.json"]


def test_an_output_link_is_followed_and_stays_a_link(tmp_path: Path) -> None:
    target = tmp_path / "data" / "result.json"
    target.parent.mkdir()
    link = tmp_path / "result.json"
    link.symlink_to(target)
    write_text(link, "{}\n", owned=True)                      # through a dangling link
    write_text(link, "{\"a\": 1}\n", owned=True)              # and over odocal's own file
    assert link.is_symlink() and target.read_text() == "{\"a\": 1}\n"
    assert "result.json" in _read_manifest(target.parent)
    assert not (tmp_path / OUTPUTS_MANIFEST).exists()
    target.write_text(USER)
    with pytest.raises(OutputError, match=r"'.*result\.json' exists and changed since"):
        check_output_file(link)


@pytest.mark.parametrize("name", ["plain.json", "two  spaces.json", "back\\slash.json",
                                  "new\nline.json", "ünïcode.json"])
def test_any_name_round_trips_through_the_manifest(tmp_path: Path, name: str) -> None:
    write_text(tmp_path / name, "odocal's\n", owned=True)
    check_output_file(tmp_path / name)                        # odocal's own: replaceable
    assert list(_read_manifest(tmp_path)) == [name]
    line = _manifest_line("0" * 64, name)
    assert line.count("\n") == 1 and line.endswith("\n")
    if shutil.which("sha256sum"):
        check = subprocess.run(["sha256sum", "-c", OUTPUTS_MANIFEST], cwd=tmp_path,
                               capture_output=True)
        assert check.returncode == 0, check.stdout


def test_a_folder_or_a_device_as_an_output_file_is_named(tmp_path: Path) -> None:
    (tmp_path / "dir.json").mkdir()
    with pytest.raises(OutputError, match="is a folder: name a file in it"):
        check_output_file(tmp_path / "dir.json")
    with pytest.raises(OutputError, match="exists and is not a regular file"):
        check_output_file("/dev/null")


@pytest.mark.parametrize("runs", [1, 2, 3])
def test_a_linked_results_folder_stays_a_link_with_nothing_left_beside_it(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], drive_file: Path, runs: int) -> None:
    real = tmp_path / "storage" / "results"
    real.mkdir(parents=True)
    link = tmp_path / "results"
    link.symlink_to(real)
    for _ in range(runs):
        code, _, err = run(capsys, "calibrate", str(drive_file), "--out", str(link), "-q",
                           "--no-report")
        assert code == EXIT_OK, err
    assert link.is_symlink() and link.resolve() == real.resolve()
    assert (real / "calibration.json").is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["results", "storage"]
    assert sorted(p.name for p in real.parent.iterdir()) == ["results"]   # no .old, no .part
