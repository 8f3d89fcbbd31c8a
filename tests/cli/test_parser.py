"""One parser, one rule for exit codes, help on every argument, "did you mean", and the
hints a first run needs (issues 38 and 39)."""

from __future__ import annotations

import argparse
import re
from pathlib import Path
from typing import Any

import pytest

import odocal
from odocal.cli.main import EXIT_ERROR, EXIT_USAGE, build_parser
from tests.conftest import ROOT, run

CLI = ROOT / "src" / "odocal" / "cli"


def _parsers(parser: argparse.ArgumentParser, name: str = "odocal") -> list[tuple[str, Any]]:
    out = [(name, parser)]
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub, p in action.choices.items():
                out += _parsers(p, f"{name} {sub}")
    return out


def test_every_argument_of_every_command_has_help() -> None:
    missing = [f"{name} {a.option_strings or a.dest}"
               for name, p in _parsers(build_parser()) for a in p._actions
               if not a.help and not isinstance(a, argparse._SubParsersAction)]
    assert missing == []


def test_simulate_help_names_the_truth_file_it_writes(capsys: pytest.CaptureFixture[str]
                                                      ) -> None:
    code, out, _ = run(capsys, "simulate", "--help")
    assert code == 0 and "FILE.truth.json" not in out
    assert "NAME.truth.json" in re.sub(r"\s+", " ", out)
    assert "drive.truth.json" in re.sub(r"\s+", " ", out)


@pytest.mark.parametrize(("argv", "meant"), [
    (["calibrate", "x.csv", "--out", "r", "--datashet", "c_e=2"], "--datasheet"),
    (["calibrate", "x.csv", "--out", "r", "--exprot", "tum"], "--export"),
    (["demo", "--no-compre"], "--no-compare"),
    (["fleet", "alarms", "--sotre", "f.db"], "--store"),
    (["calibrte", "x.csv"], "calibrate"),
    (["simulat", "--out", "d.csv"], "simulate"),
])
def test_a_misspelt_option_or_command_gets_did_you_mean(
        argv: list[str], meant: str, capsys: pytest.CaptureFixture[str], tmp_path: Path,
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    code, out, err = run(capsys, *argv)
    assert code == EXIT_USAGE and out == ""
    assert err.strip().splitlines()[-1].endswith(f"(did you mean {meant}?)")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("argv", [
    ["fleet", "calibrate", "c.csv", "--store", "f.db", "--connect-timeout", "-1"],
    ["fleet", "calibrate", "c.csv", "--store", "f.db", "--workers", "-2"],
    ["calibrate", "x.csv", "--out", "r", "--wheel-joints", "only_one"],
    ["calibrate", "x.csv", "--out", "r", "--datasheet", "c_e=100"],
    ["calibrate", "x.csv", "--out", "r", "--scene", "scene-0061"],
    ["replay", "x.csv", "--out", "r", "--datasheet", "t_r=40"],
])
def test_what_is_typed_wrong_exits_2_everywhere(argv: list[str], tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str],
                                                monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    code, out, err = run(capsys, *argv)
    assert code == EXIT_USAGE and out == "" and "Traceback" not in err
    assert re.search(r"error: argument [-\w]+: ", err.strip().splitlines()[-1])
    assert list(tmp_path.iterdir()) == []


def test_the_command_modules_read_their_arguments_and_never_change_them() -> None:
    """No ``getattr(args, ...)`` (each command reads its own arguments; helpers take values),
    no ``args.x = ...``, and one module per command family beside one parser module."""
    sources = {p.name: p.read_text() for p in CLI.glob("*.py")}
    assert {"parser.py", "main.py", "common.py", "arguments.py", "simulation.py",
            "calibration.py", "checking.py", "online.py", "fleet.py"} <= set(sources)
    for name, text in sources.items():
        assert "getattr(args" not in text, name
        assert not re.search(r"\bargs\.\w+\s*=[^=]", text), name
        assert len(text.splitlines()) < 400, name
    assert "add_subparsers" in sources["parser.py"] and "def main(" in sources["main.py"]


def test_a_raw_log_folder_without_from_is_named_with_its_format(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], shared_data: Path) -> None:
    for folder, fmt in (("nuscenes-can-bus-mini", "nuscenes"),
                        ("comma2k19-example/2018-08-02--08-34-47", "comma2k19"),
                        ("comma2k19-example", "comma2k19")):
        code, _, err = run(capsys, "calibrate", str(shared_data / folder), "--out",
                           str(tmp_path / "r"))
        assert code == EXIT_ERROR and len(err.strip().splitlines()) == 1
        assert f"it looks like a {fmt} log, read with --from {fmt}" in err
    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information: {}\n")
    code, _, err = run(capsys, "calibrate", str(bag), "--out", str(tmp_path / "r"))
    assert code == EXIT_ERROR and "read with --from rosbag" in err
    empty = tmp_path / "empty"
    empty.mkdir()
    code, _, err = run(capsys, "calibrate", str(empty), "--out", str(tmp_path / "r"))
    assert code == EXIT_ERROR and "raw logs are read with --from FORMAT" in err


def test_a_table_of_other_columns_points_to_a_mapping(tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]
                                                      ) -> None:
    table = tmp_path / "log.csv"
    table.write_text("time,left,right,gz\n0,1,1,0\n0.025,1,1,0\n")
    code, _, err = run(capsys, "calibrate", str(table), "--out", str(tmp_path / "r"))
    assert code == EXIT_ERROR and len(err.strip().splitlines()) == 1
    assert "it has other columns (time, left, right, gz)" in err
    assert "--from table --mapping MAP.toml" in err


def test_a_mapping_without_a_pose_names_its_sections(tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]
                                                     ) -> None:
    """Not "--reference gnss-imu", an option the user never typed: the mapping's sections."""
    from tests.preprocess.test_convert import MAPPING, write_tables

    write_tables(odocal.simulate(duration_s=60, seed=3).drive, tmp_path)
    (tmp_path / "map.toml").write_text(MAPPING[:MAPPING.index("[pose]")])
    code, _, err = run(capsys, "calibrate", str(tmp_path / "wheels.csv"),
                       str(tmp_path / "imu.csv"), "--from", "table", "--mapping",
                       str(tmp_path / "map.toml"), "--out", str(tmp_path / "r"))
    assert code == EXIT_ERROR and "--reference" not in err
    assert "has no reference pose" in err and "[pose] section" in err and "[gnss]" in err
