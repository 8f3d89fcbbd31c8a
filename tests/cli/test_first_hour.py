"""A user's first hour: commands that check before they compute and take what users give."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

import odocal
from tests.conftest import run


def test_compare_on_a_short_drive_refuses_before_fitting(tmp_path: Path,
                                                         capsys: pytest.CaptureFixture[str]
                                                         ) -> None:
    path = tmp_path / "short.parquet"
    odocal.save_drive(odocal.simulate(duration_s=30, seed=4, noise="realistic").drive, path)
    code, out, err = run(capsys, "calibrate", str(path), "--out", str(tmp_path / "r"),
                         "--compare")
    assert code == 1 and "--compare" in err and "too short" in err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert "inverse: fit" not in err and "parameter" not in out       # nothing was fitted
    assert not (tmp_path / "r").exists()


def test_one_file_commands_take_a_folder_as_out(tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str],
                                                short_drive: Any) -> None:
    folder = tmp_path / "work"
    folder.mkdir()
    code, _, err = run(capsys, "simulate", "--out", str(folder), "--duration", "60", "-q")
    assert code == 0, err
    assert (folder / "drive.parquet").is_file() and (folder / "drive.truth.json").is_file()
    new = tmp_path / "new"
    code, _, err = run(capsys, "simulate", "--out", f"{new}/", "--duration", "60", "-q")
    assert code == 0 and (new / "drive.parquet").is_file(), err
    code, _, err = run(capsys, "minimum", str(folder / "drive.parquet"), "--out", str(folder),
                       "-q")
    assert code == 0 and (folder / "minimum.json").is_file(), err


def test_validate_and_minimum_read_raw_logs(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                            shared_data: Path) -> None:
    logs = str(shared_data / "nuscenes-can-bus-mini")
    args = ["--from", "nuscenes", "--scene", "scene-1077", "--scene", "scene-0796"]
    config = tmp_path / "short.toml"
    config.write_text("[segments]\nvalidation_distance_m = 80.0\n")
    code, out, err = run(capsys, "validate", logs, *args, "--config", str(config))
    assert code == 0, err
    assert "converted scene-1077" in out and "validation error E_p" in out
    code, _, err = run(capsys, "validate", logs, "--scene", "scene-1077")
    assert code == 2 and "--from nuscenes" in err            # a usage error (exit 2)


def test_a_comma2k19_route_folder_reads_its_segments(tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str],
                                                     shared_data: Path) -> None:
    from odocal.io.comma2k19 import segment_folders

    root = shared_data / "comma2k19-example"
    route = root / "2018-08-02--08-34-47"
    assert segment_folders(root) == [route / "40"] == segment_folders(route)
    assert segment_folders(route / "40") == [route / "40"]
    code, out, err = run(capsys, "calibrate", str(route), "--from", "comma2k19", "--out",
                         str(tmp_path / "r"), "--no-report")
    assert code == 0, err
    assert "converted 2018-08-02--08-34-47/40" in out
    code, _, err = run(capsys, "calibrate", str(tmp_path), "--from", "comma2k19", "--out",
                       str(tmp_path / "s"))
    assert code == 1 and "not a comma2k19 segment folder" in err and "ROUTE/40/" in err
