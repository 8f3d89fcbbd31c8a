"""The base install (issue 39): what it holds, and what a command whose extra is missing says.

A missing package is made missing for real: a child interpreter whose import system refuses
numba, osqp, dask and distributed (what ``pip install .`` leaves out), running the command
line as a user would.
"""

from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

import odocal
from tests.conftest import ROOT

BASE_ONLY = """
import sys
class NotInstalled:
    def find_spec(self, name, path=None, target=None):
        if name.split('.')[0] in ('numba', 'osqp', 'dask', 'distributed', 'bokeh', 'llvmlite'):
            raise ModuleNotFoundError(f"No module named {name!r}")
        return None
sys.meta_path.insert(0, NotInstalled())
from odocal.cli.main import main
sys.exit(main(sys.argv[1:]))
"""


def _base(*argv: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-c", BASE_ONLY, *argv], cwd=cwd,
                          capture_output=True, text=True, timeout=600)


def test_the_base_install_leaves_numba_dask_and_bokeh_to_extras() -> None:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    base = {d.split(">")[0].split("[")[0] for d in project["dependencies"]}
    assert base == {"numpy", "scipy", "pyarrow", "matplotlib", "tqdm", "rosbags", "pymap3d",
                    "pyyaml"}
    extras = project["optional-dependencies"]
    assert {d.split(">")[0] for d in extras["compensated"]} == {"numba", "osqp"}
    assert {d.split(">")[0] for d in extras["fleet"]} == {"dask[distributed]", "bokeh"}
    for deps in extras.values():                        # every dependency has a lower bound
        assert all(">=" in d or d.startswith("odocal[") for d in deps), deps


@pytest.fixture(scope="module")
def drive(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("base") / "drive.parquet"
    odocal.save_drive(odocal.simulate(duration_s=240, seed=8).drive, path)
    return path


def test_without_numba_the_default_calibrates_and_compensated_names_its_extra(
        drive: Path, tmp_path: Path) -> None:
    done = _base("calibrate", str(drive), "--out", "r", "--no-report", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert "c_e " in done.stdout and (tmp_path / "r" / "calibration.json").is_file()
    done = _base("calibrate", str(drive), "--out", "c", "--method", "compensated",
                 cwd=tmp_path)
    assert done.returncode == 1 and done.stdout == ""
    assert done.stderr.strip() == (
        "odocal calibrate: error: the compensated method (--method compensated) needs numba, "
        "which is not installed: pip install 'odocal[compensated]'")
    assert not (tmp_path / "c").exists()


def test_without_numba_the_demo_compares_what_it_can(tmp_path: Path) -> None:
    done = _base("demo", "--duration", "300", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    row = next(line for line in done.stdout.splitlines() if line.startswith("compensated "))
    assert "pip install 'odocal[compensated]'" in row
    assert any(line.startswith("raw ") and " m " in line for line in done.stdout.splitlines())


def test_without_dask_the_fleet_names_its_extra(tmp_path: Path) -> None:
    for argv in (["fleet", "demo"], ["fleet", "calibrate", "c.csv", "--store", "f.db"]):
        done = _base(*argv, cwd=tmp_path)
        assert done.returncode == 1, done.stderr
        assert done.stderr.strip().endswith("which is not installed: pip install "
                                            "'odocal[fleet]'")
        assert "Traceback" not in done.stderr
    assert list(tmp_path.iterdir()) == []


def test_without_numba_the_fusion_runs_as_plain_python_with_the_same_numbers(
        tmp_path: Path, shared_data: Path) -> None:
    """odocal's GNSS/IMU fusion (comma2k19 with --reference gnss-imu): its kernels uncompiled
    give the compiled kernels' calibration."""
    route = str(shared_data / "comma2k19-example" / "2018-08-02--08-34-47")
    args = ["calibrate", route, "--from", "comma2k19", "--reference", "gnss-imu",
            "--no-report", "-q"]
    done = _base(*args, "--out", "plain", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    compiled = subprocess.run([sys.executable, "-m", "odocal", *args, "--out", "jit"],
                              cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert compiled.returncode == 0, compiled.stderr
    import json

    plain = json.loads((tmp_path / "plain" / "calibration.json").read_text())["theta"]
    jit = json.loads((tmp_path / "jit" / "calibration.json").read_text())["theta"]
    assert plain == pytest.approx(jit, rel=1e-9, abs=1e-12)
