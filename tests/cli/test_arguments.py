"""Arguments that used to crash (exit 4), run out of memory or write a wrong truth (issue 32):
each is one line naming the argument and its range, before anything is computed."""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

import pytest

import odocal
from odocal.cli.main import EXIT_ERROR, EXIT_USAGE
from odocal.errors import ConfigError
from tests.conftest import run


@pytest.fixture(scope="module")
def drive_file(tmp_path_factory: pytest.TempPathFactory, short_drive: Any) -> Path:
    path = tmp_path_factory.mktemp("arguments") / "drive.parquet"
    odocal.save_drive(short_drive.drive, path)
    return path


def _usage_error(code: int, err: str, argument: str, *words: str) -> None:
    assert code == EXIT_USAGE, err
    last = err.strip().splitlines()[-1]
    assert f"argument {argument}: " in last and "Traceback" not in err
    for word in words:
        assert word in last, last


@pytest.mark.parametrize(("argv", "argument", "words"), [
    (["simulate", "--duration", "inf"], "--duration", ("at most 86400 s",)),
    (["simulate", "--duration", "1e12"], "--duration", ("1e12 is out of range",)),
    (["simulate", "--duration", "nan"], "--duration", ("out of range",)),
    (["simulate", "--duration", "-60"], "--duration", ("above 1",)),
    (["simulate", "--duration", "ten"], "--duration", ("'ten' is not a number",)),
    (["simulate", "--seed", "-1"], "--seed", ("an integer from 0 to 9223372036854775807",)),
    (["simulate", "--seed", "1.5"], "--seed", ("'1.5' is not an integer",)),
    (["demo", "--duration", "inf"], "--duration", ("at most 86400 s",)),
    (["demo", "--seed", "-7"], "--seed", ("from 0",)),
    (["reproduce", "--distance-km", "inf"], "--distance-km", ("from 0.5 to 500 km",)),
    (["reproduce", "--distance-km", "-1"], "--distance-km", ("from 0.5 to 500 km",)),
    (["reproduce", "--seed", "-1"], "--seed", ("from 0",)),
    (["minimum", "x.csv", "--seed", "-2"], "--seed", ("from 0",)),
    (["calibrate", "x.csv", "--out", "r", "--seed", "-1"], "--seed", ("from 0",)),
    (["calibrate", "x.csv", "--out", "r", "--workers", "-3"], "--workers", ("from 0 to 1024",)),
    (["calibrate", "x.csv", "--out", "r", "--from", "table", "--circumference", "0"],
     "--circumference", ("from 0.05 to 50 m",)),
    (["calibrate", "x.csv", "--out", "r", "--from", "table", "--circumference", "inf"],
     "--circumference", ("from 0.05 to 50 m",)),
    (["simulate-fleet", "--out", "f", "--size", "5"], "--size", ("from 0 to 0.05",)),
    (["simulate-fleet", "--out", "f", "--size", "-0.01"], "--size", ("from 0 to 0.05",)),
    (["simulate-fleet", "--out", "f", "--size", "nan"], "--size", ("from 0 to 0.05",)),
    (["simulate-fleet", "--out", "f", "--wear", "0.5"], "--wear", ("from 0 to 0.05",)),
    (["simulate-fleet", "--out", "f", "--vehicles", "0"], "--vehicles", ("from 1 to 1000",)),
    (["simulate-fleet", "--out", "f", "--drives", "1"], "--drives", ("from 2 to 1000",)),
    (["simulate-fleet", "--out", "f", "--duration", "inf"], "--duration", ("at most 86400",)),
    (["fleet", "demo", "--drives", "100000"], "--drives", ("from 2 to 1000",)),
])
def test_numbers_out_of_range_are_usage_errors(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                               capsys: pytest.CaptureFixture[str],
                                               argv: list[str], argument: str,
                                               words: tuple[str, ...]) -> None:
    monkeypatch.chdir(tmp_path)
    code, out, err = run(capsys, *argv)
    _usage_error(code, err, argument, *words)
    assert out == "" and list(tmp_path.iterdir()) == []            # nothing written


@pytest.mark.parametrize("kwargs", [{"size": 5.0}, {"size": -0.1}, {"wear": float("nan")},
                                    {"vehicles": 0}, {"drives": 1},
                                    {"duration_s": float("inf")}, {"seed": -1}])
def test_simulate_fleet_refuses_a_truth_no_vehicle_has(tmp_path: Path,
                                                       kwargs: dict[str, Any]) -> None:
    from odocal.fleet.simulate import simulate_fleet

    with pytest.raises(ConfigError, match=r"out of range|invalid"):
        simulate_fleet(tmp_path / "fleet", **kwargs)
    assert not (tmp_path / "fleet").exists()


@pytest.mark.parametrize(("datasheet", "words"), [
    (["c_e=1e308"], "c_e = 1e+308 is not a wheeled vehicle's effective wheel circumference "
                    "(0.05 to 50 m)"),
    (["c_e=100"], "c_e = 100 is not a wheeled vehicle's effective wheel circumference"),
    (["c_e=1.9,t_r=1e308"], "t_r = 1e+308 is not a wheeled vehicle's rear track width"),
    (["c_e=-1.9"], "c_e = -1.9 is not"),
    (["t_r=inf"], "t_r = inf is not"),
    (["d=1e308"], "d = 1e+308 is not"),
    (["c_e=1.9,c_e=1.9"], "the datasheet gives c_e twice (1.9 and 1.9): give each value once"),
    (["c_e=1.9,t_r=1.5,c_e=2.1"], "the datasheet gives c_e twice (1.9 and 2.1)"),
    # a second --datasheet is merged with the first, and a name in both is refused
    (["c_e=1.9", "c_e=2.1"], "the datasheet gives c_e twice (1.9 and 2.1)"),
    (["t_r=1.5", "wheel_separation=1.6"], "the datasheet gives t_r twice (1.5 and 1.6)"),
    # millimetres given as metres: a circumference difference no axle has
    (["c_d=0.5"], "c_d = 0.5 m is 25% of c_e = 2 m, where two tyres of one axle differ by a "
                  "few millimetres; c_d is in metres (0.5 mm is c_d=0.0005)"),
    (["c_e=1.95", "c_d=0.3"], "c_d = 0.3 m is 15% of c_e = 1.95 m"),
])
def test_a_datasheet_no_vehicle_has_is_a_usage_error_without_warnings(
        tmp_path: Path, drive_file: Path, capsys: pytest.CaptureFixture[str],
        datasheet: list[str], words: str) -> None:
    flags = [w for value in datasheet for w in ("--datasheet", value)]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        code, out, err = run(capsys, "calibrate", str(drive_file), "--out", str(tmp_path / "r"),
                             *flags)
    _usage_error(code, err, "--datasheet", words)
    assert out == "" and "Traceback" not in err
    assert [str(w.message) for w in caught] == []                 # no RuntimeWarning flood
    assert not (tmp_path / "r").exists()


def test_two_datasheets_are_merged(tmp_path: Path, drive_file: Path,
                                   capsys: pytest.CaptureFixture[str]) -> None:
    """--datasheet c_e=.. --datasheet t_r=..: both values stated, neither replaced."""
    import json

    code, _, err = run(capsys, "calibrate", str(drive_file), "--out", str(tmp_path / "r"),
                       "--datasheet", "c_e=1.95", "--datasheet", "t_r=1.51,c_d=0.001",
                       "--no-report", "-q")
    assert code == 0, err
    sheet = json.loads((tmp_path / "r" / "calibration.json").read_text())["datasheet"]["theta"]
    assert sheet == {"c_e": 1.95, "c_d": 0.001, "t_r": 1.51, "d": 0.0}


@pytest.mark.parametrize("prior", ["[1e300, 0.01, 0.1, 0.005]", "[0.05, 0.01, 1e300, 0.005]",
                                   "[0.05, 0.01, 0.1, 1e300]", "[0.05, 0.01, 0.1, 0]"])
def test_a_prior_std_no_fit_can_carry_is_named_before_computing(
        tmp_path: Path, drive_file: Path, capsys: pytest.CaptureFixture[str],
        prior: str) -> None:
    config = tmp_path / "c.toml"
    config.write_text(f"[identify]\nprior_std = {prior}\n")
    code, out, err = run(capsys, "calibrate", str(drive_file), "--out", str(tmp_path / "r"),
                         "--config", str(config))
    assert code == EXIT_ERROR and len(err.strip().splitlines()) == 1, err
    assert "[identify] prior_std" in err and "up to c_e 50, c_d 50, t_r 30, d 1" in err
    assert out == "" and not (tmp_path / "r").exists()
