"""What odocal prints is true (issue 39): every file it names exists, every number agrees with
calibration.json, and its words are those of the method that ran."""

from __future__ import annotations

import json
import os
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import odocal
from odocal.cli.main import EXIT_ERROR, EXIT_FAILED, EXIT_OK
from odocal.estimators.estimate import parameter_text, std_text
from odocal.model.parameters import PARAMETER_NAMES
from tests.conftest import run

COMMA = ("comma2k19-example", "2018-08-02--08-34-47")


@pytest.fixture(scope="module")
def drive_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("printed") / "drive.parquet"
    odocal.save_drive(odocal.simulate(duration_s=300, seed=21, noise="realistic").drive, path)
    return path


def _written(out: str) -> list[str]:
    return [line.removeprefix("wrote ") for line in out.splitlines() if line.startswith("wrote ")]


@pytest.mark.parametrize("out", ["res", "out/base", "./deep/er/res/"])
def test_every_wrote_line_names_a_file_that_exists_for_any_out(
        out: str, drive_file: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """A relative --out: each line names the file where it is once the run has ended, never the
    temporary folder it was built in (was ``wrote res/.res.4482.zmx6_rqf.part/...``)."""
    monkeypatch.chdir(tmp_path)
    code, stdout, err = run(capsys, "calibrate", str(drive_file), "--out", out,
                            "--export", "tum,autoware")
    assert code == EXIT_OK, err
    written = _written(stdout)
    assert len(written) >= 10 and not any(".part" in w for w in written)
    for name in written:
        assert (tmp_path / name).is_file(), name
    on_disk = {str(p.relative_to(tmp_path)) for p in (tmp_path / out).rglob("*")
               if p.is_file() and not p.name.startswith(".odocal")}
    assert {os.path.normpath(w) for w in written} == on_disk


def _table(stdout: str) -> dict[str, list[str]]:
    rows = {}
    for line in stdout.splitlines():
        name = line.split(" ", 1)[0]
        if name in (*PARAMETER_NAMES, "scale") and line[10:11] == " ":
            rows[name] = line
    return rows


def test_the_printed_numbers_are_those_of_calibration_json(
        drive_file: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, stdout, err = run(capsys, "calibrate", str(drive_file), "--out", str(tmp_path / "r"),
                            "--datasheet", "c_e=1.95,t_r=1.51", "--no-report")
    assert code == EXIT_OK, err
    saved = json.loads((tmp_path / "r" / "calibration.json").read_text())
    rows = _table(stdout)
    for name in PARAMETER_NAMES:
        assert saved["identified"][name], name
        assert parameter_text(name, saved["datasheet"]["theta"][name]) in rows[name]
        assert parameter_text(name, saved["theta"][name]) in rows[name]
        assert std_text(name, saved["std"][name]) in rows[name]
    val = saved["validation"]
    line = next(x for x in stdout.splitlines() if x.startswith("validation error E_p"))
    assert (f"datasheet {saved['datasheet']['validation']['E_p_m']:.2f} m -> calibrated "
            f"{val['E_p_m']:.2f} m") in line
    assert f"over {val['segments']} segments ({val['distance_m'] / 1000:.2f} km, up to 300 m " \
           "each)" in line
    used = saved["used"]
    assert (f"identified from {used['count']} windows of 2 s, {used['clusters']} clusters, "
            "1 drive") in stdout


def test_the_default_method_speaks_of_windows_not_segments(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], shared_data: Path) -> None:
    """A straight highway: the default fits every 2 s window; the segment methods' count of
    650-sample segments and their selection warning are theirs, not its."""
    route = str(shared_data.joinpath(*COMMA))
    code, stdout, err = run(capsys, "calibrate", route, "--from", "comma2k19", "--out",
                            str(tmp_path / "r"), "--no-report")
    assert code == EXIT_OK, err
    assert "segments of 650 samples" not in stdout and "only 0 of" not in stdout
    assert re.search(r"identified from \d+ windows of 2 s", stdout)
    assert "needs bends: the yaw rate never exceeds 0.15 rad/s" in stdout
    saved = json.loads((tmp_path / "r" / "calibration.json").read_text())
    assert not any("segments have a peak yaw rate" in w for w in saved["status"]["warnings"])
    # the segment methods keep their words
    code, stdout, err = run(capsys, "calibrate", route, "--from", "comma2k19", "--out",
                            str(tmp_path / "raw"), "--no-report", "--method", "raw")
    assert code == EXIT_OK, err
    assert "segments of 650 samples" in stdout and "only 0 of" in stdout


@pytest.mark.parametrize("datasheet", [(), ("--datasheet", "c_e=2.2")])
def test_wheel_speeds_give_the_speed_signals_scale_factor(
        datasheet: tuple[str, ...], tmp_path: Path, capsys: pytest.CaptureFixture[str],
        shared_data: Path) -> None:
    """comma2k19's wheel speeds in m/s: whatever circumference they are turned into rates with,
    the summary, calibration.json, the report and Autoware's file carry one scale factor (c_e
    over that circumference), and say what it is."""
    route = str(shared_data.joinpath(*COMMA))
    out = tmp_path / "r"
    code, stdout, err = run(capsys, "calibrate", route, "--from", "comma2k19", "--out",
                            str(out), "--export", "autoware,json", *datasheet)
    assert code == EXIT_OK, err
    saved = json.loads((out / "calibration.json").read_text())
    speed = saved["speed_scale"]
    assumed = 2.2 if datasheet else 2.0
    assert speed["circumference_m"] == assumed and speed["unit"] == "m/s"
    assert speed["factor"] == pytest.approx(saved["theta"]["c_e"] / assumed, rel=1e-12)
    assert speed["std"] == pytest.approx(saved["std"]["c_e"] / assumed, rel=1e-12)
    assert speed["factor"] == pytest.approx(1.00891, abs=5e-5)        # the car's, not assumed
    scale = _table(stdout)["scale"].split()
    assert scale[2] == f"{speed['factor']:.5f}" and scale[3] == f"+-{speed['std']:.5f}"
    assert "the calibration is a scale factor on the speed signal" in stdout
    assert f"assumed circumference of {assumed:g} m" in stdout
    page = (out / "report.html").read_text()
    assert "id='speed-scale'" in page and f"{speed['factor']:.5f}" in page
    autoware = (out / "autoware" / "vehicle_velocity_converter.param.yaml").read_text()
    factor = float(re.search(r"speed_scale_factor: ([\d.e+-]+)", autoware).group(1))  # type: ignore[union-attr]
    assert factor == pytest.approx(speed["factor"], rel=1e-12)
    exported = json.loads((out / "odometry_parameters.json").read_text())
    assert exported["speed_scale"]["factor"] == pytest.approx(speed["factor"], rel=1e-12)


def test_a_drive_of_wheel_rates_has_no_scale_factor(drive_file: Path, tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    code, stdout, err = run(capsys, "calibrate", str(drive_file), "--out", str(tmp_path / "r"),
                            "--no-report")
    assert code == EXIT_OK, err
    assert "scale" not in _table(stdout) and "speed signal" not in stdout
    assert json.loads((tmp_path / "r" / "calibration.json").read_text())["speed_scale"] is None


def _edited(source: Path, target: Path, **columns: Any) -> Path:
    drive = odocal.load_drive(source)
    data = {**drive.columns(), **{k: v(drive) for k, v in columns.items()}}
    import pyarrow as pa
    import pyarrow.parquet as pq

    pq.write_table(pa.table({k: np.asarray(v) for k, v in data.items()}), target)
    return target


def test_km_h_given_as_rev_s_is_named_as_km_h(drive_file: Path, tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    """Wheel speeds in km/h in the rev/s columns: the units check says km/h, whichever check
    catches them (the loader's range, or the wheels' distance against the reference's)."""
    truth = odocal.TRUE_PARAMETERS.c_e
    kmh = _edited(drive_file, tmp_path / "kmh.parquet",
                  n_rl=lambda d: d.n_rl * truth * 3.6, n_rr=lambda d: d.n_rr * truth * 3.6)
    code, _, err = run(capsys, "calibrate", str(kmh), "--out", str(tmp_path / "a"))
    assert code == EXIT_ERROR and "km/h" in err and len(err.strip().splitlines()) == 1
    # a datasheet wheel that turns that fast: the distance check names the unit instead
    code, stdout, err = run(capsys, "calibrate", str(kmh), "--out", str(tmp_path / "b"),
                            "--datasheet", "c_e=1.0,t_r=1.5", "--no-report")
    assert code == EXIT_FAILED, err
    assert "km/h" in stdout and "rad/s given as rev/s" not in stdout


def test_a_refusal_prints_no_parameter_table(drive_file: Path, tmp_path: Path,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    """Swapped wheels: the checks refuse before any fit; the summary says what was read and
    why it was refused, with no table of datasheet values as if calibrated and no validation."""
    swapped = _edited(drive_file, tmp_path / "swapped.parquet",
                      n_rl=lambda d: d.n_rr, n_rr=lambda d: d.n_rl)
    code, stdout, err = run(capsys, "calibrate", str(swapped), "--out", str(tmp_path / "r"),
                            "--no-report")
    assert code == EXIT_FAILED, err
    lines = stdout.splitlines()
    assert lines[0].startswith("read 1 drive: ")
    assert not any(x.startswith(("parameter ", "validation error", "method: ")) for x in lines)
    assert "swapped" in stdout and "calibration failed: rejected by the checks" in stdout
    assert _written(stdout) == [str(tmp_path / "r" / "calibration.json")]


def test_the_report_says_what_its_maps_show_and_what_to_run_next(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], shared_data: Path) -> None:
    """A straight highway: no "segments that turn most"; a segment's title names its route and
    number (not "40 at 1 s"); the validation in one set of words; a next step with a command."""
    route = str(shared_data.joinpath(*COMMA))
    code, _, err = run(capsys, "calibrate", route, "--from", "comma2k19", "--out",
                       str(tmp_path / "r"))
    assert code == EXIT_OK, err
    page = (tmp_path / "r" / "report.html").read_text()
    assert "that turn most" not in page and "none turns more than 15 degrees" in page
    saved = json.loads((tmp_path / "r" / "calibration.json").read_text())
    n = saved["validation"]["segments"]
    assert f"over {n} segments (" in page and "segments of ~300 m" not in page
    assert re.search(r"<pre id='next-step'>odocal calibrate [^<]+--out results/</pre>", page)
    from odocal.report.html import _drive_label

    assert _drive_label("2018-08-02--08-34-47/40") == "2018-08-02--08-34-47/40"
    assert _drive_label("/data/logs/drive.parquet") == "drive.parquet"


def test_the_banner_says_when_a_validation_segment_got_worse() -> None:
    """E_p falling overall while one segment got worse is said in the verdict (not "fell 16%"
    alone), and the verdict is not the plain green one."""
    import dataclasses

    from odocal.report.data import build

    result = odocal.calibrate(odocal.simulate(duration_s=300, seed=22).drive)
    val, sheet = result.validation, result.datasheet_validation
    assert val is not None and sheet is not None and len(val.segments) >= 2
    good = build(result)
    assert "got worse" not in good.verdict
    # the datasheet better than the calibration on the first segment only
    lower = sheet.errors.mean_m.copy()
    lower[0] = val.errors.mean_m[0] / 2
    worse = dataclasses.replace(result, datasheet_validation=dataclasses.replace(
        sheet, errors=dataclasses.replace(sheet.errors, mean_m=lower)))
    data = build(worse)
    n = len(val.segments)
    assert f", though 1 of the {n} got worse" in data.verdict
    assert data.verdict_level == "partial" and good.verdict_level in ("good", "partial")
