"""The online calibrator's parts on their own: its intake, its live checks and the windows'
arrival (issue 38: the calibrator composed of them)."""

from __future__ import annotations

import numpy as np
import pytest

from odocal.errors import DataError
from odocal.online.checking import CHECK_EVERY_S, CHECK_WINDOW_S, LiveChecks
from odocal.online.samples import SAMPLE, Intake


def _driving(t: np.ndarray) -> np.ndarray:
    """Samples (t, n_rl, n_rr, a_y, beta, x, y, psi) of a car going straight at 10 m/s."""
    rows = np.zeros((t.size, len(SAMPLE)))
    rows[:, 0] = t
    rows[:, 1:3] = 10.0 / 1.95
    rows[:, 5] = 10.0 * t
    return rows


def test_the_checks_judge_the_latest_ten_minutes_as_a_drive_named_by_its_stretch() -> None:
    checks = LiveChecks()
    t = np.arange(0.0, 900.0, 0.025)
    for part in np.array_split(_driving(t), 30):
        checks.keep(part, driven=True)
    assert checks.due and checks.unchecked
    latest = checks.latest(0.025, "a log")
    assert isinstance(latest, tuple)
    drive, driving_s = latest
    assert drive.t[0] == pytest.approx(t[-1] - CHECK_WINDOW_S + 0.025, abs=1e-9)
    assert drive.t[-1] == pytest.approx(t[-1])
    assert driving_s == pytest.approx(CHECK_WINDOW_S, abs=0.05)
    assert drive.name == f"a log, t={drive.t[0]:.6g} to {t[-1]:.6g} s"
    assert not checks.due and not checks.unchecked      # (the samples count as checked)
    checks.keep(_driving(t[-1] + np.arange(1, 41) * 0.025), driven=True)
    assert checks.unchecked and not checks.due
    checks.keep(_driving(t[-1] + 1.0 + np.arange(1, 40 * CHECK_EVERY_S) * 0.025), driven=True)
    assert checks.due


def test_parked_samples_after_driving_are_not_kept_and_a_fault_halts() -> None:
    checks = LiveChecks()
    checks.keep(_driving(np.arange(0.0, 10.0, 0.025)), driven=False)
    parked = _driving(np.arange(10.0, 20.0, 0.025))
    parked[:, 1:3] = 0.0
    parked[:, 5] = 100.0
    checks.keep(parked, driven=True)
    latest = checks.latest(0.025, "a log")
    assert isinstance(latest, tuple) and latest[0].t[-1] < 10.0
    checks.failed(np.linalg.LinAlgError("SVD did not converge"))
    assert checks.halted
    assert "the live samples cannot be fitted (SVD did not converge)" in \
        checks.diagnosis.findings[-1].name


def test_the_intake_tells_the_unit_from_the_first_two_samples_and_keeps_time_going() -> None:
    intake = Intake()
    first = {k: np.array([0.0]) for k in SAMPLE}
    first["t"] = np.array([1000.0])                                  # ms
    assert intake.take(first).shape[0] == 0 and intake.t_s is None  # a lone sample waits
    more = {k: np.zeros(3) for k in SAMPLE}
    more["t"] = np.array([1025.0, 1050.0, 1075.0])
    rows = intake.take(more)
    assert intake.unit == "ms" and intake.t_s == pytest.approx(0.025)
    np.testing.assert_allclose(rows[:, 0], [1.0, 1.025, 1.05, 1.075])
    assert intake.samples == 4 and intake.first_t == 1.0 and intake.last_t == 1.075
    again = {k: np.zeros(1) for k in SAMPLE}
    again["t"] = np.array([1075.0])
    with pytest.raises(DataError, match="must increase strictly"):
        intake.take(again)
    assert intake.samples == 4                                       # (nothing taken)
