"""The joint errors-in-variables estimator."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import odocal
from odocal.cli import EXIT_OK, main
from odocal.estimate import CovarianceKind
from odocal.joint import JointDetails, _gather, _model_terms, joint_calibration
from odocal.settings import Settings
from odocal.simulate import SimulatedDrive


def test_noise_free_drive_gives_the_truth(clean_drive: SimulatedDrive) -> None:
    result = odocal.calibrate(clean_drive.drive, method="joint")
    np.testing.assert_allclose(result.theta.as_array(), clean_drive.true_parameters.as_array(),
                               rtol=1e-9)
    assert result.success and all(result.estimate.identified)


def test_noisy_drive_is_close_and_reports_its_noise(noisy_drive: SimulatedDrive) -> None:
    result = joint_calibration([noisy_drive.drive], settings=Settings())
    err = result.theta.as_array() - noisy_drive.true_parameters.as_array()
    std = result.std
    assert np.all(std > 0)
    assert np.all(np.abs(err) < 5 * std + np.array([2e-4, 2e-5, 2e-3, 2e-5]))
    assert result.covariance_kind is CovarianceKind.JOINT
    details = result.details
    assert isinstance(details, JointDetails)
    assert set(details.estimated) >= {"wheels", "reference_position"}
    # the block mean of the realistic profile's wheel errors is a few thousandths of a rev/s
    assert 3e-4 < details.noise.wheels_revps < 3e-2
    parts = details.cost_parts
    assert set(parts) == {"model", "reference", "wheels"} and all(v > 0 for v in parts.values())
    assert set(details.sensitivity) == {"halved", "doubled"}


def test_given_noise_levels_are_used_as_given(noisy_drive: SimulatedDrive) -> None:
    settings = Settings().replace(joint={
        "wheel_noise_revps": 0.003, "reference_position_m": 0.02, "reference_heading_rad": 0.003,
        "process_position_m": 0.03, "process_heading_rad": 5e-4, "sensitivity": False})
    details = joint_calibration([noisy_drive.drive], settings=settings).details
    assert details.estimated == ()
    assert details.noise.wheels_revps == 0.003
    assert details.sensitivity == {}


def test_gaps_and_several_files_become_pieces(clean_drive: SimulatedDrive) -> None:
    cols = {k: v.copy() for k, v in clean_drive.drive.columns().items()}
    n = cols["t"].size
    cols["t"][n // 2:] += 100.0                                    # a gap
    cols["piece"] = (np.arange(n) >= n // 2).astype(float)
    gapped = odocal.Drive.from_columns(cols, name="gapped")
    other = odocal.simulate(duration_s=300, seed=21, noise="none").drive
    result = joint_calibration([gapped, other], settings=Settings())
    assert result.details.pieces == 3
    np.testing.assert_allclose(result.theta.as_array(),
                               clean_drive.true_parameters.as_array(), rtol=1e-8)


def test_covariance_and_noise_in_calibration_json(noisy_drive: SimulatedDrive,
                                                  tmp_path: Path) -> None:
    path = tmp_path / "drive.parquet"
    odocal.save_drive(noisy_drive.drive, path)
    assert main(["calibrate", str(path), "--out", str(tmp_path / "o"), "--method", "joint",
                 "-q"]) == EXIT_OK
    data = json.loads((tmp_path / "o" / "calibration.json").read_text())
    cov = np.array(data["covariance"])
    assert cov.shape == (4, 4) and np.allclose(cov, cov.T)
    assert np.all(np.linalg.eigvalsh(cov) > 0)
    joint = data["details"]
    assert set(joint["cost_parts"]) == {"model", "reference", "wheels"}
    assert joint["noise"]["wheels_revps"] > 0 and joint["iterations"] > 0
    assert data["method"] == "joint"
    assert (tmp_path / "o" / "report.html").exists()


def test_straight_drive_keeps_the_yaw_parameters() -> None:
    from tests.conftest import straight_drive

    result = odocal.calibrate(straight_drive(), method="joint")
    assert set(result.estimate.unidentified) == {"t_r", "d"}
    assert result.estimate.identified[0]
    assert abs(result.theta.c_e - odocal.TRUE_PARAMETERS.c_e) < 1e-3


@pytest.mark.parametrize("bad", [{"block_s": 0.0}, {"wheel_noise_revps": -1.0},
                                 {"noise_rounds": 0}])
def test_bad_joint_settings(bad: dict[str, float]) -> None:
    with pytest.raises(odocal.ConfigError, match=r"\[joint\]"):
        Settings().replace(joint=bad)


def test_model_terms_jacobian_matches_finite_differences(noisy_drive: SimulatedDrive) -> None:
    """Every block of the joint problem's Jacobian: poses, wheel corrections and theta."""
    data = _gather([noisy_drive.drive], 200)
    rng = np.random.default_rng(3)
    n = data.y.shape[0]
    z = np.concatenate([data.y + rng.normal(0, [0.1, 0.1, 0.002], (n, 3)),
                        rng.normal(0, 0.02, (n, 2))], axis=1)
    theta = np.array([1.95, -0.002, 1.53, 0.0008])
    r, jz, jt, _ = _model_terms(z, theta, data)
    blocks = np.flatnonzero(data.link)[:40:7]
    for a in range(8):                      # [x_b (3), dn_b (2), x_{b+1} (3)]
        node, col = (0, a) if a < 5 else (1, a - 5)
        h = 1e-6
        zp, zm = z.copy(), z.copy()
        zp[blocks + node, col] += h
        zm[blocks + node, col] -= h
        fd = (_model_terms(zp, theta, data)[0][blocks]
              - _model_terms(zm, theta, data)[0][blocks]) / (2 * h)
        np.testing.assert_allclose(jz[blocks, :, a], fd, rtol=1e-6, atol=1e-7)
    for j in range(4):
        h = 1e-7 * max(abs(theta[j]), 1.0)
        tp, tm = theta.copy(), theta.copy()
        tp[j] += h
        tm[j] -= h
        fd = (_model_terms(z, tp, data)[0][blocks] - _model_terms(z, tm, data)[0][blocks]) / (2 * h)
        np.testing.assert_allclose(jt[blocks, :, j], fd, rtol=1e-5, atol=1e-6)
    assert r.shape == (n - 1, 3)
