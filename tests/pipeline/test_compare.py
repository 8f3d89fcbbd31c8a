"""--compare: every method on held-out time blocks of the user's drive."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from odocal.cli.main import main
from odocal.estimators import METHOD_NAMES
from odocal.io import save_drive
from odocal.pipeline.compare import compare, folds
from odocal.sim.simulate import SimulatedDrive


def test_folds_are_disjoint_alternate_blocks(noisy_drive: SimulatedDrive) -> None:
    d = noisy_drive.drive
    a, b = folds([d], 120.0)
    ta, tb = a[0].t, b[0].t
    assert len(ta) + len(tb) == d.n_samples and not set(ta) & set(tb)
    assert np.all((np.floor(ta / 120.0) % 2) == 0) and np.all((np.floor(tb / 120.0) % 2) == 1)
    assert len(a[0].pieces) == 4 and len(b[0].pieces) == 4      # 900 s in 120 s blocks


def test_every_method_is_scored_and_the_truth_shows_which_is_right(
        noisy_drive: SimulatedDrive) -> None:
    c = compare([noisy_drive.drive], truth=noisy_drive.true_parameters)
    assert [s.method for s in c.scores] == list(METHOD_NAMES)
    for s in c.scores:
        assert s.held_out_e_p_m is not None and 0 < s.held_out_e_p_m < c.datasheet_e_p_m
        assert s.truth_error is not None and abs(s.truth_error["c_e"]) < 2e-3
    assert c.favoured and c.favoured[0] in METHOD_NAMES
    assert c.favoured[0] in c.verdict


def test_calibrate_compare_writes_the_table(noisy_drive: SimulatedDrive, tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str]) -> None:
    drive = tmp_path / "d.parquet"
    save_drive(noisy_drive.drive, drive)
    assert main(["calibrate", str(drive), "--out", str(tmp_path / "o"), "--compare"]) == 0
    out = capsys.readouterr().out
    assert "held-out E_p" in out and "comparing the methods" in out
    data = json.loads((tmp_path / "o" / "calibration.json").read_text())
    assert [m["method"] for m in data["comparison"]["methods"]] == list(METHOD_NAMES)
    html = (tmp_path / "o" / "report.html").read_text()
    assert "id='compare'" in html and "The methods compared" in html
