"""Data that contradict the model: diagnosed before the fit, gated after it (issue 10)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

import odocal
from odocal.checks.diagnosis import check_drives
from odocal.checks.findings import Check, Severity
from odocal.checks.gate import gate
from odocal.cli.main import EXIT_FAILED, EXIT_OK, main
from odocal.estimators.estimate import Reason, Status
from odocal.settings import Settings
from odocal.sim.simulate import SimulatedDrive


def altered(sim: SimulatedDrive, **changes: Any) -> odocal.Drive:
    """The drive with some columns replaced (values or functions of the old columns)."""
    old = {k: v.copy() for k, v in sim.drive.columns().items()}
    new = {key: value(old) if callable(value) else value for key, value in changes.items()}
    return odocal.Drive.from_columns({**old, **new}, name=f"altered-{'-'.join(changes)}")


def checks(drive: odocal.Drive) -> dict[Check, Severity]:
    return {f.check: f.severity for f in check_drives([drive], Settings()).findings}


def test_a_good_drive_passes_every_check(noisy_drive: SimulatedDrive) -> None:
    assert checks(noisy_drive.drive) == {}


@pytest.mark.parametrize("method", ["inverse", "raw"])
def test_swapped_wheels_are_refused_without_a_fit(noisy_drive: SimulatedDrive,
                                                  method: str) -> None:
    drive = altered(noisy_drive, n_rl=lambda c: c["n_rr"], n_rr=lambda c: c["n_rl"])
    result = odocal.calibrate(drive, method=method)
    assert result.estimate.status is Status.REJECTED and not result.success
    assert [f.check for f in result.diagnosis.findings] == [Check.WHEELS_SWAPPED]
    assert result.diagnosis.findings[0].value < -0.9
    assert result.theta == result.estimate.datasheet           # nothing calibrated
    assert all(v.reason is Reason.REJECTED for v in result.estimate.verdicts)  # type: ignore


def test_mirrored_heading_reads_as_swapped(noisy_drive: SimulatedDrive) -> None:
    drive = altered(noisy_drive, y=lambda c: -c["y"], psi=lambda c: -c["psi"],
                    a_y=lambda c: -c["a_y"], beta=lambda c: -c["beta"])
    assert checks(drive) == {Check.WHEELS_SWAPPED: Severity.FATAL}


def test_copied_column_calibrates_c_e_alone(noisy_drive: SimulatedDrive) -> None:
    drive = altered(noisy_drive, n_rr=lambda c: c["n_rl"])
    result = odocal.calibrate(drive)
    assert [f.check for f in result.diagnosis.findings] == [Check.WHEELS_IDENTICAL]
    assert result.success and result.estimate.identified == (True, False, False, False)
    for name in ("c_d", "t_r", "d"):
        assert result.estimate.verdict(name).reason is Reason.NO_DIFFERENTIAL  # type: ignore
    # the left wheel's own circumference: c_e + c_d/2 + d a_y (a_y averages out)
    left = odocal.TRUE_PARAMETERS.c_e + odocal.TRUE_PARAMETERS.c_d / 2
    assert abs(result.theta.c_e - left) < 3 * result.estimate.std[0] + 2e-4


def test_locked_axle_or_one_speed_signal_calibrates_c_e_alone(
        noisy_drive: SimulatedDrive) -> None:
    mean = 0.5 * (noisy_drive.drive.n_rl + noisy_drive.drive.n_rr)
    result = odocal.calibrate(altered(noisy_drive, n_rl=mean, n_rr=mean), method="raw")
    assert [f.check for f in result.diagnosis.findings] == [Check.WHEELS_IDENTICAL]
    assert result.estimate.identified == (True, False, False, False)
    assert abs(result.theta.c_e - odocal.TRUE_PARAMETERS.c_e) < 1e-3
    assert result.validation is not None and result.datasheet_validation is not None
    assert result.validation.mean_distance_error_m < \
        result.datasheet_validation.mean_distance_error_m


def test_a_wheel_that_does_not_follow_the_turns(noisy_drive: SimulatedDrive) -> None:
    rng = np.random.default_rng(2)
    mean = 0.5 * (noisy_drive.drive.n_rl + noisy_drive.drive.n_rr)
    noisy = mean + 0.01 * rng.standard_normal(mean.size) * (mean > 0)
    assert checks(altered(noisy_drive, n_rl=mean, n_rr=noisy)) == {
        Check.NO_DIFFERENTIAL: Severity.FALLBACK}


def test_wheel_unit_mistake_is_named(noisy_drive: SimulatedDrive) -> None:
    # scaled by 3.6 (a km/h-for-m/s mix-up upstream) passes the column's plausibility limit
    # but not the distance check
    scaled = altered(noisy_drive, n_rl=lambda c: c["n_rl"] * 3.6,
                     n_rr=lambda c: c["n_rr"] * 3.6)
    result = odocal.calibrate(scaled)
    (finding,) = result.diagnosis.findings
    assert finding.check is Check.SPEED_SCALE and finding.severity is Severity.FATAL
    assert finding.value == pytest.approx(3.6 * 2.0 / odocal.TRUE_PARAMETERS.c_e, rel=0.01)
    from odocal.report.advice import finding_text

    assert "km/h given as m/s" in finding_text(finding, result.settings)
    # wheel speeds in m/s given as rev/s: the factor is the circumference, a note, not a failure
    speeds = altered(noisy_drive, n_rl=lambda c: c["n_rl"] * 1.95, n_rr=lambda c: c["n_rr"] * 1.95)
    (note,) = check_drives([speeds], Settings()).findings
    assert note.check is Check.SPEED_SCALE and note.severity is Severity.NOTE
    assert "m/s given as rev/s" in finding_text(note, Settings())


def test_lateral_acceleration_sign_and_unit(noisy_drive: SimulatedDrive) -> None:
    assert checks(altered(noisy_drive, a_y=lambda c: -c["a_y"])) == {
        Check.LATERAL_SIGN: Severity.FATAL}
    in_g = altered(noisy_drive, a_y=lambda c: c["a_y"] / 9.81)
    found = check_drives([in_g], Settings()).findings
    assert [f.check for f in found] == [Check.LATERAL_SCALE]
    assert found[0].value == pytest.approx(1 / 9.81, rel=0.1)


@pytest.mark.parametrize("seconds", [1.3, -1.6])
def test_clock_offset_beyond_what_the_calibration_corrects(noisy_drive: SimulatedDrive,
                                                           seconds: float) -> None:
    shift = round(seconds * 40)                           # beyond [inverse] max_delay_s (1 s)
    late = altered(noisy_drive, n_rl=lambda c: np.roll(c["n_rl"], shift),
                   n_rr=lambda c: np.roll(c["n_rr"], shift))
    found = check_drives([late], Settings()).findings
    assert [f.check for f in found] == [Check.CLOCK_OFFSET]
    assert found[0].severity is Severity.FATAL
    assert found[0].value == pytest.approx(seconds, abs=0.05)
    # the same lag within what the lag search is told to reach is no finding
    wider = Settings().replace(inverse={"max_delay_s": 2.0}, gate={"max_clock_offset_s": 2.0})
    assert check_drives([late], wider).findings == ()


@pytest.mark.parametrize("noise", [0.0, 0.05])
def test_standing_still_is_not_an_error(noise: float, tmp_path: Path,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    n = 24001                                             # ten minutes at 40 Hz
    rng = np.random.default_rng(3)
    pose = noise * rng.standard_normal((n, 2))
    drive = odocal.Drive.from_columns(
        {"t": np.arange(n) * 0.025, "n_rl": np.zeros(n), "n_rr": np.zeros(n),
         "a_y": np.zeros(n), "x": 10 + pose[:, 0], "y": -4 + pose[:, 1],
         "psi": np.full(n, 0.3) + 0.01 * noise * rng.standard_normal(n)}, name="parked")
    path = tmp_path / "parked.parquet"
    odocal.save_drive(drive, path)
    code = main(["calibrate", str(path), "--out", str(tmp_path / "o"), "-q"])
    assert code == EXIT_OK
    result = odocal.calibrate(drive)
    assert result.diagnosis.standstill and not any(result.estimate.identified)
    assert result.estimate.status is Status.NOTHING_IDENTIFIABLE
    main(["calibrate", str(path), "--out", str(tmp_path / "o2")])
    assert "the vehicle does not move" in capsys.readouterr().out


def test_gate_rejects_implausible_parameters_and_bad_fits() -> None:
    settings = Settings()
    good = np.array([1.95, -0.002, 1.53, 0.0008])
    assert gate(good, settings, error_m=1.0, datasheet_error_m=10.0, segment_m=300.0) == []
    far = gate(np.array([7.0, 0.5, 0.1, 0.1]), settings, error_m=None, datasheet_error_m=None,
               segment_m=None)
    assert {f.name for f in far} == {"c_e", "c_d", "t_r", "d"}
    worse = gate(good, settings, error_m=11.0, datasheet_error_m=10.0, segment_m=300.0)
    assert [f.check for f in worse] == [Check.WORSE_THAN_DATASHEET]
    large = gate(good, settings, error_m=40.0, datasheet_error_m=80.0, segment_m=300.0)
    assert [f.check for f in large] == [Check.LARGE_ERROR]


def test_rejected_calibration_exits_3_with_one_line_reason(
        noisy_drive: SimulatedDrive, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    drive = altered(noisy_drive, n_rl=lambda c: c["n_rr"], n_rr=lambda c: c["n_rl"])
    path = tmp_path / "swapped.parquet"
    odocal.save_drive(drive, path)
    code = main(["calibrate", str(path), "--out", str(tmp_path / "o"), "--export", "json"])
    out = capsys.readouterr().out
    assert code == EXIT_FAILED
    assert "error: the yaw rate the wheels imply turns against the reference's" in out
    assert "left and right wheel columns are swapped" in out
    assert not (tmp_path / "o" / "odometry_parameters.json").exists()
    page = (tmp_path / "o" / "report.html").read_text()
    assert "Do not use: the yaw rate the wheels imply" in page


def test_a_reference_heading_offset_does_not_decide_the_validation(
        noisy_drive: SimulatedDrive) -> None:
    """A fused pose whose heading is turned by a mounting yaw (1 degree): validation starts from
    the corrected heading, so the true parameters validate as well as without the offset, and
    the default method (which estimates the offset) is unmoved; raw Gauss-Newton, which fits the
    turned heading, bends c_d to follow it and validates worse."""
    turned = altered(noisy_drive, psi=lambda c: c["psi"] + np.radians(1.0))
    truth = noisy_drive.true_parameters
    assert odocal.validate(turned, truth).mean_error_m == pytest.approx(
        odocal.validate(noisy_drive.drive, truth).mean_error_m, rel=0.02)
    plain, off = odocal.calibrate(noisy_drive.drive), odocal.calibrate(turned)
    assert off.validation is not None and plain.validation is not None
    assert off.validation.mean_error_m == pytest.approx(plain.validation.mean_error_m, rel=0.02)
    assert off.theta.c_d == pytest.approx(plain.theta.c_d, abs=1e-5)
    raw = odocal.calibrate(turned, method="raw")
    assert raw.validation is not None and raw.validation.mean_error_m > off.validation.mean_error_m


def test_repaired_samples_are_noted_by_drive_and_column(noisy_drive: SimulatedDrive) -> None:
    """What an importer repaired (its metadata's ``repaired``) is a note per column (from the
    mutation sample: a mutant that read no metadata survived)."""
    d = noisy_drive.drive
    drive = odocal.Drive.from_columns(d.columns(), name="logged",
                                      metadata={**d.metadata, "repaired": {"t": 3, "n_rl": 1}})
    found = [f for f in check_drives([drive], Settings()).findings
             if f.check is Check.DATA_REPAIRED]
    assert sorted((f.name, f.value, f.severity) for f in found) == [
        ("logged:n_rl", 1.0, Severity.NOTE), ("logged:t", 3.0, Severity.NOTE)]


def test_a_scale_mistake_is_named_with_the_ratio_and_the_one_it_should_be_near(
        noisy_drive: SimulatedDrive) -> None:
    """Wheel rates three times what they are (beyond ``[gate] max_scale``): the distance
    check's finding carries the ratio of the wheels' distance to the reference's (3) and the
    1 it should be near, which the words are made from."""
    sim = noisy_drive
    drive = altered(sim, n_rl=sim.drive.n_rl * 3.0, n_rr=sim.drive.n_rr * 3.0)
    (finding,) = [f for f in check_drives([drive], Settings()).findings
                  if f.check is Check.SPEED_SCALE]
    assert finding.severity is Severity.FATAL
    assert finding.value == pytest.approx(3.0, rel=0.03)
    assert finding.reference == 1.0


def test_wheels_that_read_nothing_while_the_reference_drives_are_a_scale_fault_with_its_distance(
        noisy_drive: SimulatedDrive) -> None:
    """Both wheel columns at zero (an unmapped signal) under a reference that drives: the
    finding is the scale check's, with the ratio 0 and the reference's distance (m), not a
    vehicle standing still."""
    sim = noisy_drive
    drive = altered(sim, n_rl=np.zeros(sim.drive.n_samples), n_rr=np.zeros(sim.drive.n_samples))
    (finding,) = [f for f in check_drives([drive], Settings()).findings
                  if f.check is Check.SPEED_SCALE]
    assert finding.severity is Severity.FATAL and finding.value == 0.0
    travelled = float(np.sum(np.hypot(np.diff(sim.drive.x), np.diff(sim.drive.y))))
    assert finding.reference == pytest.approx(travelled, rel=0.02)
