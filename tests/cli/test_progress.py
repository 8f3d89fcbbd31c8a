"""No silent waits: long commands say what they do (issue 25)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import odocal

BIN = Path(sys.executable).parent


def _odocal(*argv: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(BIN / "odocal"), *argv], capture_output=True, text=True,
                          timeout=600, env={**os.environ, **(env or {})})


def test_the_first_run_of_a_segment_method_says_it_compiles(tmp_path: Path,
                                                            short_drive: Any) -> None:
    drive = tmp_path / "d.parquet"
    odocal.save_drive(short_drive.drive, drive)
    cold = {"NUMBA_CACHE_DIR": str(tmp_path / "numba")}
    first = _odocal("calibrate", str(drive), "--out", str(tmp_path / "a"), "--method", "raw",
                    "--no-report", env=cold)
    assert first.returncode == 0, first.stderr
    assert "compiling the numerical kernels" in first.stderr
    again = _odocal("calibrate", str(drive), "--out", str(tmp_path / "b"), "--method", "raw",
                    "--no-report", env=cold)
    assert "compiling" not in again.stderr                    # cached now
    default = _odocal("calibrate", str(drive), "--out", str(tmp_path / "c"), "--no-report",
                      env={"NUMBA_CACHE_DIR": str(tmp_path / "other")})
    assert "compiling" not in default.stderr                  # the default compiles nothing


def test_minimum_shows_its_generations(tmp_path: Path, short_drive: Any) -> None:
    drive = tmp_path / "d.parquet"
    odocal.save_drive(short_drive.drive, drive)
    config = tmp_path / "quick.toml"
    config.write_text("[minimum]\nmax_generations = 5\npopulation = 5\n")
    run = _odocal("minimum", str(drive), "--config", str(config))
    assert run.returncode == 0, run.stderr
    assert "reachable minimum: differential evolution, generation" in run.stderr
    assert "minimum E_p" in run.stdout
