"""METHOD 3: Gauss-Newton identification."""

from __future__ import annotations

import numpy as np
import pytest

import odocal
from odocal.identify import gauss_newton
from odocal.model import Inputs, rollout, wheel_rates_for
from odocal.segments import SegmentBatch, gather, identification_segments
from odocal.settings import IdentifySettings, Settings
from odocal.simulate import SimulatedDrive


def selected_batch(sim: SimulatedDrive) -> SegmentBatch:
    settings = Settings()
    segs = identification_segments([sim.drive], settings.segments)
    return gather([sim.drive], segs.subset(segs.selected))


def test_batch_gauss_newton_recovers_truth_on_noise_free_drive(clean_drive: SimulatedDrive) -> None:
    result = gauss_newton(selected_batch(clean_drive), settings=IdentifySettings())
    truth = clean_drive.true_parameters.as_array()
    np.testing.assert_allclose(result.theta.as_array(), truth, rtol=1e-9)
    assert result.success
    assert all(result.identified)
    assert list(result.cost_history) == sorted(result.cost_history, reverse=True)


def test_pure_gauss_newton_on_one_segment(clean_drive: SimulatedDrive) -> None:
    batch = selected_batch(clean_drive)
    best = int(np.argmax(np.abs(batch.inputs.a_y).max(axis=1)))
    # one segment from the datasheet values takes more than the paper's five iterations
    result = gauss_newton(batch.take(slice(best, best + 1)),
                          settings=IdentifySettings(max_iterations=30))
    np.testing.assert_allclose(result.theta.as_array(), clean_drive.true_parameters.as_array(),
                               rtol=1e-6)
    assert all(result.identified)


def test_unsettled_iteration_does_not_judge_identifiability(clean_drive: SimulatedDrive) -> None:
    batch = selected_batch(clean_drive)
    best = int(np.argmax(np.abs(batch.inputs.a_y).max(axis=1)))
    result = gauss_newton(batch.take(slice(best, best + 1)), settings=IdentifySettings())
    assert result.message.startswith("reached the iteration limit")
    assert all(result.identified)


def test_stops_when_cost_stops_decreasing(clean_drive: SimulatedDrive) -> None:
    result = gauss_newton(selected_batch(clean_drive),
                          settings=IdentifySettings(max_iterations=50))
    assert result.iterations < 50
    assert result.message in ("the cost no longer decreases",
                              "converged (the step is below the tolerance)")


def test_iteration_limit_is_the_papers(clean_drive: SimulatedDrive) -> None:
    result = gauss_newton(selected_batch(clean_drive), settings=IdentifySettings(max_iterations=1))
    assert result.iterations == 1
    assert len(result.cost_history) == 2


def straight_batch(noise: float) -> tuple[SegmentBatch, np.ndarray]:
    """Segments of a straight drive with speed changes: no bends, no lateral acceleration."""
    theta = np.array([1.95, -0.002, 1.53, 0.0008])
    rng = np.random.default_rng(5)
    n, k = 12, 650
    t = np.arange(k) * 0.025
    v = 8 + 3 * np.sin(0.3 * t[None, :] + rng.uniform(0, 6, (n, 1)))
    w = np.zeros((n, k))
    a_y = np.zeros((n, k))
    n_rl, n_rr = wheel_rates_for(theta, v, w, a_y)
    u = Inputs(n_rl=n_rl, n_rr=n_rr, beta=np.zeros((n, k)), a_y=a_y)
    x0 = np.column_stack([rng.uniform(-100, 100, (n, 2)), rng.uniform(-3, 3, n)])
    ref = rollout(theta, u, x0, 0.025)
    ref = ref + noise * rng.standard_normal(ref.shape) * np.array([1, 1, 0.01])
    return SegmentBatch(inputs=u, reference=ref, t_s=0.025), theta


def test_straight_drive_names_the_yaw_parameters_it_cannot_identify() -> None:
    batch, theta = straight_batch(noise=0.0)
    result = gauss_newton(batch, settings=IdentifySettings())
    assert result.identified == (True, True, False, False)
    assert set(result.unidentified) == {"t_r", "d"}
    assert "no information" in result.reasons["t_r"]
    # the identifiable ones are exact, the others stay at the datasheet values
    np.testing.assert_allclose(result.theta.as_array()[:2], theta[:2], rtol=1e-8)
    assert result.theta.t_r == 1.6 and result.theta.d == 0.0
    assert np.all(result.covariance[2:, :] == 0) and np.all(result.covariance[:, 2:] == 0)


def test_weak_parameter_is_reported_statistically(clean_drive: SimulatedDrive) -> None:
    batch, _ = straight_batch(noise=0.05)
    # add a whisper of lateral acceleration: d is then barely (numerically) observable
    u = batch.inputs
    batch = SegmentBatch(inputs=Inputs(u.n_rl, u.n_rr, u.beta, u.a_y + 1e-3),
                         reference=batch.reference, t_s=batch.t_s)
    result = gauss_newton(batch, settings=IdentifySettings())
    assert not result.identified[3]
    assert "d" in result.unidentified


def test_covariance_is_symmetric_positive_semidefinite(noisy_drive: SimulatedDrive) -> None:
    batch = selected_batch(noisy_drive)
    result = gauss_newton(batch.take(slice(0, 40)), settings=IdentifySettings())
    for cov in (result.covariance, result.covariance_naive):
        np.testing.assert_allclose(cov, cov.T, atol=1e-18)
        assert np.linalg.eigvalsh(cov).min() > -1e-15
    assert result.covariance_kind == "cluster-robust"


def test_fixed_parameters_stay_put(clean_drive: SimulatedDrive) -> None:
    result = gauss_newton(selected_batch(clean_drive), settings=IdentifySettings(),
                          fixed={"d": "kept for this test"})
    assert result.theta.d == 0.0
    assert result.reasons["d"] == "kept for this test"


@pytest.mark.parametrize("noise", ["realistic"])
def test_noisy_calibration_is_close(noisy_drive: SimulatedDrive, noise: str) -> None:
    result = odocal.calibrate(noisy_drive.drive, method="raw")
    err = np.abs(result.theta.as_array() - noisy_drive.true_parameters.as_array())
    assert err[0] < 2e-3 and err[1] < 3e-4 and err[2] < 2e-2 and err[3] < 3e-4
    assert result.validation is not None and result.datasheet_validation is not None
    assert result.validation.mean_error_m < 0.5 * result.datasheet_validation.mean_error_m
