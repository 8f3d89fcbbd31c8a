"""Sensor and reference faults that look like data: named by the same checks on every path
(batch ``calibrate``, the online calibrator, ``replay``), never calibrated into a confident
number (issue 22)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import odocal
from odocal.checks.diagnosis import check_drives
from odocal.checks.findings import Check, Severity
from odocal.cli.main import EXIT_FAILED, main
from odocal.estimators.estimate import Identified, Reason, Status
from odocal.model.kinematics import rollout, wheel_rates_for
from odocal.model.parameters import Inputs
from odocal.online.calibrator import OnlineCalibrator
from odocal.settings import Settings
from odocal.sim.simulate import SimulatedDrive

Columns = dict[str, np.ndarray]


def faulty(sim: SimulatedDrive, change: Callable[[Columns], Columns]) -> odocal.Drive:
    columns = {k: v.copy() for k, v in sim.drive.columns().items()}
    return odocal.Drive.from_columns(change(columns), name="faulty")


def online(drive: odocal.Drive, chunk: int = 40) -> OnlineCalibrator:
    calibrator = OnlineCalibrator()
    cols = drive.columns()
    for i in range(0, drive.n_samples, chunk):
        calibrator.push({k: v[i:i + chunk] for k, v in cols.items()
                         if k in ("t", "n_rl", "n_rr", "a_y", "beta", "x", "y", "psi")})
    return calibrator


def found(drive: odocal.Drive) -> dict[Check, Any]:
    return {f.check: f for f in check_drives([drive], Settings()).findings}


def refused_everywhere(drive: odocal.Drive, check: Check) -> None:
    """Batch refuses without fitting, and the live path halts with the same finding."""
    result = odocal.calibrate(drive)
    assert result.estimate.status is Status.REJECTED, result.diagnosis
    assert check in {f.check for f in result.diagnosis.fatal_findings}
    assert result.theta == result.estimate.datasheet            # nothing calibrated
    calibrator = online(drive)
    estimate = calibrator.estimate()
    assert calibrator.halted and estimate.status is Status.REJECTED
    assert check in {f.check for f in estimate.details.findings if f.severity is Severity.FATAL}
    assert not any(estimate.identified)


# ------------------------------------------------------------------------- a dead wheel sensor

@pytest.mark.parametrize("wheel", ["n_rl", "n_rr"])
def test_a_dead_wheel_sensor_is_named_not_calibrated(noisy_drive: SimulatedDrive,
                                                    wheel: str) -> None:
    drive = faulty(noisy_drive, lambda c: {**c, wheel: np.zeros_like(c[wheel])})
    assert found(drive)[Check.WHEEL_DEAD].name == wheel
    refused_everywhere(drive, Check.WHEEL_DEAD)


def test_a_wheel_sensor_that_dies_half_way(noisy_drive: SimulatedDrive) -> None:
    def die(c: Columns) -> Columns:
        n_rl = c["n_rl"].copy()
        n_rl[n_rl.size // 2:] = 0.0
        return {**c, "n_rl": n_rl}

    drive = faulty(noisy_drive, die)
    finding = found(drive)[Check.WHEEL_DEAD]
    assert 0.3 < finding.value < 0.7
    assert odocal.calibrate(drive).estimate.status is Status.REJECTED


def test_wheels_that_stop_together_are_not_a_dead_sensor(noisy_drive: SimulatedDrive) -> None:
    # the simulated city drive stops at junctions: both wheels read 0 then, which is no fault
    assert Check.WHEEL_DEAD not in found(noisy_drive.drive)


# ------------------------------------------------------------------- lateral acceleration faults

@pytest.mark.parametrize("value", [0.0, 0.3, -0.5])
def test_a_constant_lateral_acceleration_leaves_d_unidentified_and_widens_t_r(
        noisy_drive: SimulatedDrive, value: float) -> None:
    """a_y stuck at a constant (unplugged, a missing mapping): d is not identified (not 'exactly
    0 with std 0'), and t_r either is not identified or its uncertainty covers the truth."""
    drive = faulty(noisy_drive, lambda c: {**c, "a_y": np.full_like(c["a_y"], value)})
    missing = found(drive)[Check.LATERAL_MISSING]
    assert missing.severity is Severity.FALLBACK and missing.name == "a_y"
    # what it says: a_y's share of speed times yaw rate (none varies) against the least share
    assert missing.reference == odocal.Settings().checks.lateral_min_share
    assert missing.value == pytest.approx(0.0, abs=1e-9)
    truth = noisy_drive.true_parameters.as_array()
    for estimate in (odocal.calibrate(drive).estimate, online(drive).estimate()):
        assert estimate.success
        assert estimate.verdict("d").reason is Reason.NO_LATERAL  # type: ignore[union-attr]
        for j, name in enumerate(("c_e", "c_d", "t_r")):
            verdict = estimate.verdict(name)
            if isinstance(verdict, Identified):
                assert abs(estimate.theta.as_array()[j] - truth[j]) < 3 * verdict.std, name
        assert estimate.widening[2] > 1.0 or not estimate.identified[2]


@pytest.mark.parametrize("delay", [15, 40])
def test_a_lateral_acceleration_late_against_the_motion_is_named(
        noisy_drive: SimulatedDrive, delay: int) -> None:
    drive = faulty(noisy_drive, lambda c: {**c, "a_y": np.concatenate(
        [np.zeros(delay), c["a_y"][:-delay]])})
    finding = found(drive)[Check.LATERAL_DELAY]
    assert finding.value == pytest.approx(delay * 0.025, abs=0.03)
    assert Check.LATERAL_DELAY in {f.check for f in online(drive).estimate().details.findings}
    # the batch calibration aligns a_y before the fit: d is right within its uncertainty
    result = odocal.calibrate(drive)
    assert result.departures is not None
    assert result.departures.lateral_lag_s == pytest.approx(delay * 0.025, abs=0.01)
    est, truth = result.estimate, noisy_drive.true_parameters.as_array()
    for j, ok in enumerate(est.identified):
        if ok:
            assert abs(est.theta.as_array()[j] - truth[j]) < 3 * est.std[j]


@pytest.mark.parametrize("scale", [-1.0, -1 / 9.81])
def test_a_flipped_lateral_acceleration_is_refused_everywhere(noisy_drive: SimulatedDrive,
                                                              scale: float) -> None:
    drive = faulty(noisy_drive, lambda c: {**c, "a_y": scale * c["a_y"]})
    refused_everywhere(drive, Check.LATERAL_SIGN)


# ------------------------------------------------------------------------ the reference pose

@pytest.mark.parametrize("seconds", [30, -100])
def test_a_reference_out_of_step_with_the_wheels_is_named(noisy_drive: SimulatedDrive,
                                                          seconds: int) -> None:
    """The pose stream ``seconds`` late (negative: early) against the wheels: beyond the clock
    check's two seconds, the reference's speed still says by how much."""
    shift = abs(seconds) * 40
    wheels, pose = (slice(shift, None), slice(None, -shift)) if seconds > 0 \
        else (slice(None, -shift), slice(shift, None))

    def out_of_step(c: Columns) -> Columns:
        out = {k: c[k][wheels] for k in ("n_rl", "n_rr", "a_y")}
        out.update({k: c[k][pose] for k in ("x", "y", "psi", "beta")})
        return {**out, "t": c["t"][:-shift]}

    drive = faulty(noisy_drive, out_of_step)
    finding = found(drive)[Check.REFERENCE_SYNC]
    assert finding.value == pytest.approx(seconds, abs=1.5)
    refused_everywhere(drive, Check.REFERENCE_SYNC)


@pytest.mark.parametrize("frame", ["xy-swapped", "compass"])
def test_a_reference_heading_in_another_frame_is_refused(noisy_drive: SimulatedDrive,
                                                         frame: str) -> None:
    def turn(c: Columns) -> Columns:
        if frame == "xy-swapped":
            return {**c, "x": c["y"], "y": c["x"]}
        return {**c, "psi": np.pi / 2 - c["psi"]}               # clockwise from north

    drive = faulty(noisy_drive, turn)
    refused_everywhere(drive, Check.REFERENCE_HEADING)
    # its gaps spread between along and against the heading: not a car backing up on wheels
    # without a sign (those go either way), which the words then do not suggest
    assert found(drive)[Check.REFERENCE_HEADING].reference == 0.0


def _backwards(c: Columns) -> Columns:
    """The drive backed along its own path: every column in reverse order on the same clock,
    the wheels turning backwards (a_y, speed times yaw rate, is the same)."""
    out = {k: v[::-1].copy() for k, v in c.items()}
    out["t"] = c["t"]
    for k in ("n_rl", "n_rr"):
        out[k] = -out[k]
    if "yaw_rate" in out:
        out["yaw_rate"] = -out["yaw_rate"]
    return out


@pytest.mark.parametrize("share", [1.0, 0.5])
def test_a_vehicle_backing_up_is_no_heading_in_another_frame(noisy_drive: SimulatedDrive,
                                                              share: float) -> None:
    """A drive backed along its path (whole, or its second half: shunting) moves against its
    heading while its wheels turn backwards: calibrated, within 3 std of the truth (on main
    it was refused as a heading 180 or 90 degrees off the course, "another frame?"). With
    the wheels' sign dropped, backing up whole is refused, and the words say it may be that."""
    def backed(c: Columns) -> Columns:
        if share == 1.0:
            return _backwards(c)
        half = c["t"].size // 2
        first = {k: v[:half + 1] for k, v in c.items()}
        back = _backwards(first)
        out = {k: np.concatenate([first[k], back[k][1:]]) for k in c}
        out["t"] = c["t"][0] + np.arange(out["t"].size) * (c["t"][1] - c["t"][0])
        return out

    drive = faulty(noisy_drive, backed)
    result = odocal.calibrate(drive)
    assert result.success, result.diagnosis
    truth = noisy_drive.true_parameters.as_array()
    est = result.estimate
    for j, name in enumerate(est.names):
        if est.identified[name]:
            assert abs(est.theta.as_array()[j] - truth[j]) <= 3.0 * float(est.std[j]), name
    # with the wheels' sign dropped: refused, and the words say it may be that (shunting, the
    # median gap is 90 degrees: the share against the heading says it, hostile L3)
    unsigned = faulty(noisy_drive, lambda c: {**(b := backed(c)), "n_rl": np.abs(b["n_rl"]),
                                               "n_rr": np.abs(b["n_rr"])})
    refused = odocal.calibrate(unsigned)
    [heading] = [f for f in refused.diagnosis.fatal_findings
                 if f.check is Check.REFERENCE_HEADING]
    assert heading.reference == pytest.approx(share, abs=0.1)
    from odocal.report.summary import summary_lines

    words = "\n".join(summary_lines(refused))
    assert "wheel speeds without a sign on a vehicle backing up" in words
    assert f"as on {heading.reference:.0%} of them the reference moves against its heading" \
        in words


def test_wheels_counting_backwards_on_a_drive_forwards_are_a_sign_not_a_heading(
        noisy_drive: SimulatedDrive) -> None:
    """Both rear wheels negated while the car drives forwards along its heading: the wheels'
    sign is named (the heading check, which takes a car backing up, must not claim it: the
    heading is right whichever way the wheels say)."""
    drive = faulty(noisy_drive, lambda c: {**c, "n_rl": -c["n_rl"], "n_rr": -c["n_rr"]})
    result = odocal.calibrate(drive)
    fatal = {f.check for f in result.diagnosis.fatal_findings}
    assert Check.SPEED_SCALE in fatal and Check.REFERENCE_HEADING not in fatal


@pytest.mark.parametrize("jump", [1000.0, 40.0])
def test_a_jump_in_the_reference_pose_is_named_with_where(noisy_drive: SimulatedDrive,
                                                          jump: float) -> None:
    def jumped(c: Columns) -> Columns:
        x = c["x"].copy()
        x[x.size // 3:] += jump
        return {**c, "x": x}

    drive = faulty(noisy_drive, jumped)
    finding = found(drive)[Check.POSE_JUMP]
    assert finding.value == pytest.approx(jump, abs=2.0)
    assert finding.reference == pytest.approx(drive.t[drive.n_samples // 3], abs=0.1)
    refused_everywhere(drive, Check.POSE_JUMP)


def test_a_small_reference_glitch_is_no_jump(noisy_drive: SimulatedDrive) -> None:
    def glitch(c: Columns) -> Columns:
        x = c["x"].copy()
        x[x.size // 3:] += 1.5                                   # a GNSS-size correction
        return {**c, "x": x}

    assert Check.POSE_JUMP not in found(faulty(noisy_drive, glitch))


# --------------------------------------------------------- a constant-radius circle is no fault

def circle(rate_radps: float, seconds: float = 600.0) -> odocal.Drive:
    theta = odocal.TRUE_PARAMETERS.as_array()
    t = np.arange(int(seconds * 40) + 1) * 0.025
    v, w = np.full(t.size, 8.0), np.full(t.size, rate_radps)
    a = v * w
    n_rl, n_rr = wheel_rates_for(theta, v, w, a)
    rng = np.random.default_rng(1)
    poses = rollout(theta, Inputs(n_rl[:-1], n_rr[:-1], np.zeros(t.size - 1), a[:-1]),
                    np.zeros(3), 0.025)
    return odocal.Drive.from_columns(
        {"t": t, "n_rl": n_rl + 0.01 * rng.standard_normal(t.size),
         "n_rr": n_rr + 0.01 * rng.standard_normal(t.size), "a_y": a, "x": poses[:, 0],
         "y": poses[:, 1], "psi": poses[:, 2]}, name="circle")


@pytest.mark.parametrize("rate", [0.2, -0.3])
def test_a_constant_radius_circle_is_not_a_locked_axle(rate: float) -> None:
    """One turning rate cannot tell t_r from c_d and d, but the wheels plainly follow the turn:
    c_e is calibrated, the rest named, and the gate never passes a worse E_p than it had."""
    drive = circle(rate)
    assert not {Check.NO_DIFFERENTIAL, Check.WHEELS_SWAPPED} & set(found(drive))
    result = odocal.calibrate(drive)
    est = result.estimate
    assert est.identified[0] and not any(est.identified[1:])
    assert abs(est.theta.c_e - odocal.TRUE_PARAMETERS.c_e) < 3 * est.std[0]
    assert result.validation is not None and result.datasheet_validation is not None
    if result.validation.mean_error_m > 1.02 * result.datasheet_validation.mean_error_m:
        assert est.status is Status.REJECTED
        assert Check.WORSE_THAN_DATASHEET in {f.check for f in result.diagnosis.findings}


# ----------------------------------------------------------------------- the replay command

@pytest.mark.parametrize("fault", ["swapped", "dead", "radians"])
def test_replay_refuses_what_calibrate_refuses(short_drive: SimulatedDrive, tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str],
                                               fault: str) -> None:
    def change(c: Columns) -> Columns:
        if fault == "swapped":
            return {**c, "n_rl": c["n_rr"], "n_rr": c["n_rl"]}
        if fault == "dead":
            return {**c, "n_rr": np.zeros_like(c["n_rr"])}
        # rad/s for rev/s on a slow drive: within the column's plausibility limit
        return {**c, "n_rl": c["n_rl"] * np.pi, "n_rr": c["n_rr"] * np.pi}

    drive = faulty(short_drive, change)
    path = tmp_path / f"{fault}.parquet"
    odocal.save_drive(drive, path)
    code = main(["replay", str(path), "--out", str(tmp_path / "live"), "-q"])
    out = capsys.readouterr().out
    assert code == EXIT_FAILED
    assert out.count("\n") == 1 and out.startswith("error: ")
    code = main(["calibrate", str(path), "--out", str(tmp_path / "batch"), "-q"])
    assert code == EXIT_FAILED
