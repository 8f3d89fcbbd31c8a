"""``--export tum``: trajectories that evo itself reads and compares."""

from __future__ import annotations

import os
import subprocess
import sys
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import odocal
from odocal.pipeline.odometry import dead_reckoned
from tests.conftest import run

BIN = Path(sys.executable).parent


def _evo(*argv: str) -> subprocess.CompletedProcess[str]:
    tool = BIN / argv[0]
    if not tool.exists():
        pytest.skip(f"{argv[0]} not installed (pip install -e '.[test]')")
    env = {**os.environ, "MPLBACKEND": "Agg", "HOME": os.environ.get("HOME", "/tmp")}
    return subprocess.run([str(tool), *argv[1:]], capture_output=True, text=True, timeout=300,
                          env=env)


def _rpe_mean(folder: Path, estimate: str, tmp: Path) -> float:
    """evo_rpe's mean translation error per 100 m, as evo saves and reloads it."""
    from evo.tools import file_interface

    result = tmp / f"{estimate}.zip"
    proc = _evo("evo_rpe", "tum", str(folder / "reference.tum"), str(folder / estimate),
                "--delta", "100", "--delta_unit", "m", "--save_results", str(result),
                "--no_warnings")
    assert proc.returncode == 0, proc.stderr + proc.stdout
    assert zipfile.is_zipfile(result)
    return float(file_interface.load_res_file(str(result)).stats["mean"])


def test_evo_reads_the_trajectories_and_sees_the_gain(tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str],
                                                      noisy_drive: Any) -> None:
    drive = tmp_path / "drive.parquet"
    odocal.save_drive(noisy_drive.drive, drive)
    out = tmp_path / "res"
    code, stdout, _ = run(capsys, "calibrate", str(drive), "--out", str(out), "--no-report",
                          "--export", "tum", "--datasheet", "c_e=2.0,t_r=1.6,c_d=0.0001")
    assert code == 0
    folder = out / "trajectories"
    for name in ("reference.tum", "odometry.tum", "odometry_datasheet.tum"):
        assert f"wrote {folder / name}" in stdout
    calibrated = _rpe_mean(folder, "odometry.tum", tmp_path)
    datasheet = _rpe_mean(folder, "odometry_datasheet.tum", tmp_path)
    assert calibrated < 0.5 * datasheet, (calibrated, datasheet)
    # evo_traj reads all three with the log's own timestamps, one pose per sample
    proc = _evo("evo_traj", "tum", *(str(p) for p in sorted(folder.glob("*.tum"))),
                "--no_warnings")
    assert proc.returncode == 0, proc.stderr
    n = noisy_drive.drive.n_samples
    assert proc.stdout.count(f"{n} poses") == 3, proc.stdout
    from evo.tools import file_interface

    ref = file_interface.read_tum_trajectory_file(str(folder / "reference.tum"))
    d = noisy_drive.drive
    np.testing.assert_allclose(ref.timestamps, d.t, atol=1e-6)
    np.testing.assert_allclose(ref.positions_xyz[:, 0], d.x, atol=1e-6)
    np.testing.assert_allclose(ref.positions_xyz[:, 1], d.y, atol=1e-6)
    # the heading evo reads from the quaternion is the drive's psi (yaw about z, x forward)
    from evo.core import transformations

    yaw = np.array([transformations.euler_from_matrix(pose, "szyx")[0]
                    for pose in ref.poses_se3])
    gap = np.remainder(yaw - d.psi + np.pi, 2.0 * np.pi) - np.pi
    assert np.max(np.abs(gap)) < 1e-6
    # and the odometry's heading is the calibrated wheels' dead-reckoned yaw, starting at psi
    odo = file_interface.read_tum_trajectory_file(str(folder / "odometry.tum"))
    first = transformations.euler_from_matrix(odo.poses_se3[0], "szyx")[0]
    assert abs(np.remainder(first - d.psi[0] + np.pi, 2.0 * np.pi) - np.pi) < 1e-6


def test_one_folder_per_log_and_a_restart_at_every_gap(tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str],
                                                       short_drive: Any) -> None:
    d = short_drive.drive
    cols = d.columns()
    keep = (d.t < 40) | (d.t > 45)                  # a 5 s gap: two pieces
    gapped_cols = {k: np.asarray(v)[keep] for k, v in cols.items()}
    gapped_cols["piece"] = (gapped_cols["t"] > 45).astype(float)
    gapped = odocal.Drive.from_columns(gapped_cols, name="car/1")
    assert len(gapped.pieces) == 2
    poses = dead_reckoned(gapped, short_drive.true_parameters)
    second = gapped.pieces[1][0]
    np.testing.assert_allclose(poses[second], [gapped.x[second], gapped.y[second],
                                               gapped.psi[second]])
    paths = []
    # another drive (the same samples twice are one drive, refused since issue 40)
    other = odocal.simulate(duration_s=float(d.t[-1] - d.t[0]), seed=77, noise="realistic")
    for i, drive in enumerate((gapped, odocal.Drive.from_columns(other.drive.columns(),
                                                                   name="car_1"))):
        paths.append(tmp_path / f"d{i}.parquet")
        odocal.save_drive(drive, paths[-1])
    out = tmp_path / "res"
    run(capsys, "calibrate", *map(str, paths), "--out", str(out), "--no-report", "--export",
        "tum", "-q")
    folders = sorted(p.name for p in (out / "trajectories").iterdir())
    assert len(folders) == 2 and len(set(folders)) == 2        # names that clean alike differ
    for f in folders:
        proc = _evo("evo_traj", "tum", str(out / "trajectories" / f / "odometry.tum"),
                    "--no_warnings")
        assert proc.returncode == 0, proc.stderr
