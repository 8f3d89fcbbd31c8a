"""The command line: outputs, exit codes and one-line errors."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from odocal.cli.main import EXIT_ERROR, EXIT_OK, EXIT_USAGE, main
from odocal.io import save_drive
from odocal.sim.simulate import SimulatedDrive
from tests.conftest import run


@pytest.fixture(scope="module")
def drive_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("logs") / "drive.csv"
    assert main(["simulate", "--out", str(path), "--duration", "600", "--seed", "3", "-q"]) == 0
    return path


def test_simulate_writes_drive_and_truth(drive_file: Path) -> None:
    truth = json.loads(drive_file.with_name("drive.truth.json").read_text())
    assert set(truth["theta"]) == {"c_e", "c_d", "t_r", "d"}
    assert len(truth["n_rl"]) == 600 * 40 + 1
    assert truth["noise_profile"]["name"] == "realistic"


def test_calibrate_writes_calibration_json(drive_file: Path, tmp_path: Path,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "results"
    code, stdout, _ = run(capsys, "calibrate", str(drive_file), "--out", str(out),
                          "--method", "raw")
    assert code == EXIT_OK
    data = json.loads((out / "calibration.json").read_text())
    assert set(data["theta"]) == {"c_e", "c_d", "t_r", "d"}
    assert data["method"] == "raw"
    assert data["segments_used"] > 50
    assert data["validation"]["E_p_m"] > 0 and data["validation"]["segments"] > 5
    assert np.array(data["covariance"]).shape == (4, 4)
    assert data["inputs"][0]["sha256"] and data["settings"]["segments"]["length"] == 650
    assert "validation error E_p" in stdout and "calibrated" in stdout

    code, stdout, _ = run(capsys, "validate", str(drive_file), "--params",
                          str(out / "calibration.json"))
    assert code == EXIT_OK
    assert f"E_p = {data['validation']['E_p_m']:.3f} m" in stdout


def test_several_logs_of_one_vehicle(drive_file: Path, tmp_path: Path,
                                     capsys: pytest.CaptureFixture[str]) -> None:
    second = tmp_path / "second.parquet"
    assert main(["simulate", "--out", str(second), "--duration", "400", "--seed", "9", "-q"]) == 0
    out = tmp_path / "r"
    code, _, _ = run(capsys, "calibrate", str(drive_file), str(second), "--out", str(out),
                     "--method", "raw", "-q")
    assert code == EXIT_OK
    data = json.loads((out / "calibration.json").read_text())
    assert [Path(d["name"]).name for d in data["inputs"]] == ["drive.csv", "second.parquet"]


def test_demo_prints_truth_and_estimates(capsys: pytest.CaptureFixture[str]) -> None:
    code, stdout, _ = run(capsys, "demo", "--duration", "600", "--method", "raw")
    assert code == EXIT_OK
    assert "true" in stdout and "datasheet" in stdout and "true parameters:" in stdout
    assert "best std" not in stdout        # the default profile counts ticks: no bound
    code, stdout, _ = run(capsys, "demo", "--duration", "300", "--noise", "white",
                          "--no-compare")
    assert code == EXIT_OK and "best std" in stdout and "Cramér-Rao" in stdout


def test_demo_without_counted_wheel_errors_shows_no_bound(
        capsys: pytest.CaptureFixture[str]) -> None:
    code, stdout, _ = run(capsys, "demo", "--duration", "300", "--noise", "reference",
                          "--no-compare")
    assert code == EXIT_OK
    assert "best std" not in stdout


def bad_drive(tmp_path: Path, sim: SimulatedDrive, name: str, change: object) -> Path:
    cols = {k: v.copy() for k, v in sim.drive.columns().items()}
    change(cols)  # type: ignore[operator]
    import pyarrow as pa
    import pyarrow.csv as pacsv

    path = tmp_path / name
    pacsv.write_csv(pa.table(cols), path)
    return path


@pytest.mark.parametrize(("change", "message"), [
    (lambda c: c.pop("psi"), "lacks column psi"),
    (lambda c: c["n_rr"].__setitem__(7, np.nan), "column n_rr contains 1 NaN"),
    (lambda c: c["t"].__setitem__(slice(200, None), c["t"][200:] + 3.0), "column t has a gap"),
    (lambda c: c["t"].__setitem__(10, 0.0), "not strictly increasing"),
    (lambda c: (c["n_rl"].__imul__(60), c["n_rr"].__imul__(60)), "looks like rpm"),
    (lambda c: c["psi"].__imul__(57.29), "psi must be in radians"),
])
def test_bad_input_exits_with_one_line(tmp_path: Path, clean_drive: SimulatedDrive,
                                       capsys: pytest.CaptureFixture[str], change: object,
                                       message: str) -> None:
    path = bad_drive(tmp_path, clean_drive, "bad.csv", change)
    code, _, err = run(capsys, "calibrate", str(path), "--out", str(tmp_path / "out"))
    assert code == EXIT_ERROR
    assert err.count("\n") == 1 and "Traceback" not in err
    assert err.startswith("odocal calibrate: error: ") and message in err
    assert not (tmp_path / "out" / "calibration.json").exists()


def test_empty_file_and_missing_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    empty = tmp_path / "empty.csv"
    empty.write_text("")
    code, _, err = run(capsys, "calibrate", str(empty), "--out", str(tmp_path / "o"))
    assert code == EXIT_ERROR and "is empty" in err and err.count("\n") == 1
    code, _, err = run(capsys, "validate", str(tmp_path / "nope.csv"))
    assert code == EXIT_ERROR and "does not exist" in err


def test_unknown_setting_is_an_error(drive_file: Path, tmp_path: Path,
                                     capsys: pytest.CaptureFixture[str]) -> None:
    config = tmp_path / "odocal.toml"
    config.write_text("[identify]\nmax_iteration = 3\n")
    code, _, err = run(capsys, "calibrate", str(drive_file), "--out", str(tmp_path / "o"),
                       "--config", str(config))
    assert code == EXIT_ERROR and "unknown setting [identify] 'max_iteration'" in err


def test_output_never_overwrites_an_input(drive_file: Path, capsys: pytest.CaptureFixture[str],
                                          tmp_path: Path) -> None:
    before = drive_file.read_bytes()
    code, _, err = run(capsys, "calibrate", str(drive_file), "--out", str(drive_file))
    assert code == EXIT_ERROR and "would overwrite the input" in err
    assert drive_file.read_bytes() == before


def test_short_drive_says_what_is_needed(tmp_path: Path,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "short.csv"
    assert main(["simulate", "--out", str(path), "--duration", "10", "-q"]) == 0
    code, _, err = run(capsys, "calibrate", str(path), "--out", str(tmp_path / "o"))
    # (in the drive's own seconds and samples: "K = 650 steps" said nothing of them)
    assert code == EXIT_ERROR and "holds 401 samples (10.0 s)" in err and "651 samples" in err


def test_bad_params_file(drive_file: Path, tmp_path: Path,
                         capsys: pytest.CaptureFixture[str]) -> None:
    params = tmp_path / "p.json"
    params.write_text(json.dumps({"theta": {"c_e": 1.9, "c_d": 0, "t_r": "wide", "d": 0}}))
    code, _, err = run(capsys, "validate", str(drive_file), "--params", str(params))
    assert code == EXIT_ERROR and "theta.t_r = 'wide' is not a finite number" in err


def test_usage_errors(capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(capsys, "calibrate")
    assert code == EXIT_USAGE and "usage" in err
    code, _, _ = run(capsys, "simulate", "--out", "x.csv", "--noise", "loud")
    assert code == EXIT_USAGE


def test_parquet_logs_calibrate_too(clean_drive: SimulatedDrive, tmp_path: Path,
                                    capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "clean.parquet"
    save_drive(clean_drive.drive, path)
    code, _, _ = run(capsys, "calibrate", str(path), "--out", str(tmp_path / "o"), "--method",
                     "raw", "-q")
    assert code == EXIT_OK
    data = json.loads((tmp_path / "o" / "calibration.json").read_text())
    truth = clean_drive.true_parameters.as_dict()
    for name, value in data["theta"].items():
        assert value == pytest.approx(truth[name], rel=1e-6)


def test_help_and_version_load_nothing_heavy() -> None:
    """--help and --version answer without numpy, scipy, numba or matplotlib."""
    import subprocess
    import sys

    code = ("import sys; import odocal.cli.main as c; c.build_parser().format_help(); "
            "heavy = [m for m in ('numpy', 'scipy', 'numba', 'matplotlib', 'pyarrow') "
            "if m in sys.modules]; print(heavy); assert not heavy")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stdout + done.stderr


def test_every_method_name_has_an_estimator() -> None:
    from odocal.estimators import DEFAULT_METHOD, METHOD_NAMES
    from odocal.pipeline.calibrate import METHODS

    assert tuple(METHODS) == METHOD_NAMES and DEFAULT_METHOD in METHOD_NAMES
