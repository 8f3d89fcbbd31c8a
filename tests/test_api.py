"""The Python API (issue 39): named access, short reprs with the terminal's table,
``result.save`` with the command line's rules, and a complete ``__all__``."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import odocal
from odocal.report.summary import summary_lines
from odocal.sim.simulate import SimulatedDrive


@pytest.fixture(scope="module")
def sim() -> SimulatedDrive:
    return odocal.simulate(duration_s=300, seed=31, noise="realistic")


@pytest.fixture(scope="module")
def result(sim: SimulatedDrive) -> odocal.CalibrationResult:
    return odocal.calibrate(sim.drive)


def test_std_and_identified_read_by_name_and_by_order(result: odocal.CalibrationResult
                                                      ) -> None:
    est = result.estimate
    std = np.sqrt(np.diag(est.covariance))
    for j, name in enumerate(("c_e", "c_d", "t_r", "d")):
        assert est.std[name] == est.std[j] == std[j]
        assert est.identified[name] is est.identified[j] is True
    assert est.std.as_dict() == dict(zip(("c_e", "c_d", "t_r", "d"), std.tolist(), strict=True))
    assert est.identified == (True, True, True, True)          # still a tuple of flags
    assert est.identified.as_dict()["t_r"] is True
    with pytest.raises(KeyError, match=r"'t_f' is not a parameter; the parameters are c_e, "
                                       r"c_d, t_r, d"):
        est.std["t_f"]
    with pytest.raises(KeyError, match="'x' is not a parameter"):
        est.identified["x"]
    # arithmetic and slices are plain arrays: names belong to the four values only
    assert type(est.std * 2) is np.ndarray and type(est.std[:2]) is np.ndarray
    assert float((est.std * 2)[0]) == 2 * std[0]
    assert type(np.asarray(est.std)) is np.ndarray
    assert repr(est.std).startswith("ByName(c_e=") and repr(est.identified).startswith("Flags(")


def test_reprs_are_the_terminals_table(result: odocal.CalibrationResult,
                                       sim: SimulatedDrive) -> None:
    text = repr(result)
    assert len(text) < 1500 and text.startswith("CalibrationResult(method='inverse', "
                                                "status=converged, drives=1")
    table = [line for line in summary_lines(result) if line.startswith(
        ("parameter ", "c_e ", "c_d ", "t_r ", "d "))]
    assert len(table) == 5 and all(line in text.splitlines() for line in table)
    assert f"calibrated {result.validation.mean_error_m:.2f} m" in text  # type: ignore[union-attr]
    est = repr(result.estimate)
    assert est.splitlines()[1:] == table and len(est) < 800
    online = odocal.OnlineCalibrator()
    online.push(sim.drive.columns())
    running = online.estimate()
    shown = repr(online)
    assert shown.startswith(f"OnlineCalibrator({sim.drive.n_samples} samples, "
                            f"{online.distance_km:.2f} km") and len(shown) < 800
    assert f"{running.theta.c_e:.5f} m" in shown


def test_save_writes_what_the_command_line_writes(result: odocal.CalibrationResult,
                                                  tmp_path: Path) -> None:
    written = result.save(tmp_path / "out", exports=("autoware", "json"))
    assert written.folder == tmp_path / "out"
    assert all(f.is_file() for f in written.files) and len(written.files) >= 9
    assert {p.as_posix() for p in written.paths} >= {
        "calibration.json", "report.html", "autoware/vehicle_info.param.yaml",
        "odometry_parameters.json"}
    saved = json.loads((tmp_path / "out" / "calibration.json").read_text())
    assert saved["theta"] == result.theta.as_dict() and "report" in saved
    # its own folder is replaced whole, atomically: nothing of the earlier run stays
    again = result.save(tmp_path / "out", report=False)
    assert [p.as_posix() for p in again.paths] == ["calibration.json"]
    assert not (tmp_path / "out" / "report.html").exists()
    assert not list(tmp_path.glob(".out*"))                   # no temporary folder left


def test_save_refuses_a_folder_it_did_not_write_and_one_that_holds_an_input(
        sim: SimulatedDrive, tmp_path: Path) -> None:
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep me")
    drive = tmp_path / "logs" / "drive.parquet"
    drive.parent.mkdir()
    odocal.save_drive(sim.drive, drive)
    result = odocal.calibrate(str(drive))
    with pytest.raises(odocal.OutputError, match=r"holds 'notes\.txt'.*which odocal did not "
                                                 r"write"):
        result.save(mine, report=False)
    assert (mine / "notes.txt").read_text() == "keep me" and len(list(mine.iterdir())) == 1
    with pytest.raises(odocal.OutputError, match="holds the input"):
        result.save(tmp_path / "logs", report=False)
    assert drive.is_file() and len(list(drive.parent.iterdir())) == 1


def test_all_names_every_public_name_and_each_resolves() -> None:
    from odocal import _LAZY

    errors = {"ConfigError", "DataError", "InputFileError", "MissingDependencyError",
              "OdocalError", "OutputError", "SolverError"}
    assert len(odocal.__all__) == len(set(odocal.__all__))
    assert set(odocal.__all__) == {*errors, "__version__", *_LAZY}
    for name in odocal.__all__:
        assert getattr(odocal, name) is not None, name
    assert set(odocal.__all__) <= set(dir(odocal))


def test_import_odocal_stays_light() -> None:
    """``import odocal`` loads none of numpy, scipy, numba, pyarrow or matplotlib."""
    code = ("import sys, odocal; heavy = [m for m in ('numpy', 'scipy', 'numba', 'pyarrow', "
            "'matplotlib', 'dask') if m in sys.modules]; print(heavy); assert not heavy")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stdout + done.stderr
