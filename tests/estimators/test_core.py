"""One estimator core for batch and live (issue 24): the same windows, the same fit."""

from __future__ import annotations

import numpy as np
import pytest

import odocal
from odocal.checks.diagnosis import check_drives
from odocal.checks.findings import Check
from odocal.estimators.estimate import Status
from odocal.estimators.inverse import inverse_calibration
from odocal.estimators.windows import WindowBuilder, cluster_steps_for, windows_from_drives
from odocal.online.calibrator import OnlineCalibrator
from odocal.settings import Settings
from odocal.sim.simulate import SimulatedDrive


def pushed(drive: odocal.Drive, step: int, settings: Settings | None = None) -> OnlineCalibrator:
    calibrator = OnlineCalibrator(settings)
    cols = drive.columns()
    for i in range(0, drive.n_samples, step):
        calibrator.push({k: v[i:i + step] for k, v in cols.items()})
    return calibrator


@pytest.mark.parametrize("noise", ["realistic", "quantised-coarse", "slip-heavy", "delay"])
def test_live_with_nothing_folded_is_the_batch_estimate(noise: str) -> None:
    """The online calibrator runs the batch method's core on the same windows: with the whole
    drive in memory, the two answers are one computation."""
    drive = odocal.simulate(duration_s=600, seed=5, noise=noise).drive
    live = pushed(drive, 37).estimate()
    batch = inverse_calibration([drive], settings=Settings())
    assert live.details.windows_in_memory == live.details.windows
    np.testing.assert_allclose(live.theta.as_array(), batch.theta.as_array(), rtol=1e-9,
                               atol=1e-12)
    np.testing.assert_allclose(live.std, batch.std, rtol=1e-6)
    assert live.details.delay_s == pytest.approx(batch.details.delay_s, abs=1e-9)
    assert live.details.coupling == pytest.approx(batch.details.coupling, abs=1e-9)


def test_windows_do_not_depend_on_how_the_samples_came(short_drive: SimulatedDrive) -> None:
    drive = short_drive.drive
    whole, straight = windows_from_drives([drive], Settings())
    builder = WindowBuilder(t_s=drive.t_s, length=whole.length, margin=whole.margin,
                            cluster_steps=cluster_steps_for([drive], Settings()))
    rng = np.random.default_rng(4)
    i = 0
    while i < drive.n_samples:
        j = i + int(rng.integers(1, 200))
        builder.add(drive.t[i:j], drive.n_rl[i:j], drive.n_rr[i:j], drive.a_y[i:j],
                    drive.beta[i:j], drive.x[i:j], drive.y[i:j], drive.psi[i:j])
        i = j
    builder.end_piece()
    chunks = builder.windows()
    np.testing.assert_allclose(chunks.moments, whole.moments, rtol=1e-10, atol=1e-12)
    np.testing.assert_array_equal(chunks.follows, whole.follows)
    np.testing.assert_array_equal(chunks.cluster, whole.cluster)
    np.testing.assert_allclose(builder.straight, straight, rtol=1e-10)


def test_a_noise_free_drive_gives_the_true_parameters(clean_drive: SimulatedDrive) -> None:
    est = inverse_calibration([clean_drive.drive], settings=Settings())
    assert est.status is Status.EXACT
    np.testing.assert_allclose(est.theta.as_array(), clean_drive.true_parameters.as_array(),
                               rtol=1e-8, atol=1e-10)


@pytest.mark.parametrize("degrees", [1.0, -2.0])
def test_a_turned_reference_heading_is_found_with_its_sign_online_and_in_batch(
        noisy_drive: SimulatedDrive, degrees: float) -> None:
    cols = {k: v.copy() for k, v in noisy_drive.drive.columns().items()}
    cols["psi"] = cols["psi"] + np.radians(degrees)
    drive = odocal.Drive.from_columns(cols, name="turned")
    batch = inverse_calibration([drive], settings=Settings())
    # the offset is added to the heading to give the course: the opposite of the turn
    assert batch.details.heading_offset_rad == pytest.approx(-np.radians(degrees), abs=2e-3)
    live = pushed(drive, 40).estimate()
    assert live.details.heading_offset_rad == pytest.approx(batch.details.heading_offset_rad,
                                                            rel=1e-12)
    np.testing.assert_allclose(live.theta.as_array(), batch.theta.as_array(), rtol=1e-9)
    plain = inverse_calibration([noisy_drive.drive], settings=Settings())
    assert abs(batch.theta.c_e - plain.theta.c_e) < 0.2 * plain.std[0]


def test_folded_sums_keep_the_noise_model_of_older_driving() -> None:
    """Windows folded out of memory keep their part of the noise model: a noisy first half and a
    quiet second give the batch answer's noise level, not the last minutes' alone."""
    noisy = odocal.simulate(duration_s=600, seed=6, noise="white-5x").drive
    quiet = odocal.simulate(duration_s=600, seed=7, noise="white").drive
    later = quiet.columns()
    later["t"] = later["t"] + noisy.t[-1] + 60.0
    cols = {k: np.concatenate([v, later[k]]) for k, v in noisy.columns().items()}
    cols["piece"] = np.concatenate([np.zeros(noisy.n_samples), np.ones(quiet.n_samples)])
    both = odocal.Drive.from_columns(cols, name="two halves")
    batch = inverse_calibration([both], settings=Settings())
    settings = Settings().replace(online={"max_windows": 120})
    live = pushed(both, 40, settings).estimate()
    assert live.details.windows_in_memory < live.details.windows / 3
    for channel in (0, 1):
        assert live.details.noise[channel][0] == pytest.approx(batch.details.noise[channel][0],
                                                               rel=0.2)


def test_forgetting_follows_a_parameter_that_moved() -> None:
    """With forgetting, older evidence fades: after a step in c_e that the change detector is
    told not to see, the estimate follows the new value; without, it stays between."""
    true = odocal.TRUE_PARAMETERS
    after = odocal.Parameters(true.c_e * 0.997, true.c_d, true.t_r, true.d)
    sim = odocal.simulate(duration_s=2400, seed=3, noise="realistic", change=(1200.0, after))
    blind = {"cusum_h": 1e9}
    keep = pushed(sim.drive, 40, Settings().replace(online=blind)).estimate()
    fade = pushed(sim.drive, 40, Settings().replace(
        online={**blind, "forgetting_s": 300.0})).estimate()
    assert abs(fade.theta.c_e - after.c_e) < 3 * fade.std[0]
    assert abs(fade.theta.c_e - after.c_e) < 0.5 * abs(keep.theta.c_e - after.c_e)
    # on a drive that does not change, forgetting costs precision: less evidence counts
    steady = odocal.simulate(duration_s=1800, seed=3, noise="realistic").drive
    all_of_it = pushed(steady, 40).estimate()
    recent = pushed(steady, 40, Settings().replace(online={"forgetting_s": 300.0})).estimate()
    assert np.all(recent.std > all_of_it.std)
    # c_e and c_d rest on every window: a fifth of the drive's weight widens them by over 1.25
    # (t_r's and d's rest on the bends and the lag, which forgetting touches less)
    assert np.all(recent.std[:2] > 1.25 * all_of_it.std[:2])


@pytest.mark.parametrize("steps", [12, -22, 29])
def test_a_wheel_clock_offset_within_a_second_is_taken_out(noisy_drive: SimulatedDrive,
                                                           steps: int) -> None:
    """The wheels 0.3 s late, 0.55 s early or 0.725 s late: no finding that stops the
    calibration, the lag found and applied, every identified parameter within 3 std."""
    late = {k: v.copy() for k, v in noisy_drive.drive.columns().items()}
    for key in ("n_rl", "n_rr"):
        late[key] = np.roll(late[key], steps)
    # (the samples whose wheels wrapped round from the other end are not the log's)
    keep = slice(max(steps, 0), late["t"].size + min(steps, 0))
    drive = odocal.Drive.from_columns({k: v[keep] for k, v in late.items()}, name="late")
    assert not [f for f in check_drives([drive], Settings()).findings
                if f.check is Check.CLOCK_OFFSET]
    result = odocal.calibrate(drive)
    est = result.estimate
    assert est.success
    # (the clocks' alignment, and the counting window's own 37.5 ms where it holds out as a
    # lag of its own)
    assert est.details.delay_s == pytest.approx(steps * 0.025 + 0.0375, abs=0.03)
    truth = noisy_drive.true_parameters.as_array()
    for j, ok in enumerate(est.identified):
        assert ok
        assert abs(est.theta.as_array()[j] - truth[j]) < 3 * est.std[j]


def test_every_public_name_resolves() -> None:
    """The lazy public API (``odocal.X``) points at where each name lives after the layout."""
    for name in odocal.__all__:
        assert getattr(odocal, name) is not None, name


def test_each_window_knows_the_distance_driven_before_it_across_gaps() -> None:
    """A window's distance (where an alarm places a change, in km driven) is the reference's
    path from the log's first sample to the window's start, piece after piece: the driving
    of an earlier piece counts, the gap adds nothing."""
    d = odocal.simulate(duration_s=150, seed=6, noise="realistic").drive
    cols = d.columns()
    keep = (d.t < 50.0) | (d.t > 56.0) & (d.t < 100.0) | (d.t > 103.0)    # three pieces
    cut = {k: np.asarray(v)[keep] for k, v in cols.items()}
    cut["piece"] = (cut["t"] > 50.0).astype(float) + (cut["t"] > 100.0)
    drive = odocal.Drive.from_columns(cut, name="gaps")
    assert len(drive.pieces) == 3
    step_m = np.hypot(np.diff(drive.x), np.diff(drive.y))
    step_m[[b - 1 for _, b in drive.pieces[:-1]]] = 0.0               # the steps over a gap
    driven_m = np.concatenate([[0.0], np.cumsum(step_m)])
    windows, _ = windows_from_drives([drive], Settings())
    later = windows.t0 > 56.0
    assert later.sum() > 10 and (windows.t0 > 103.0).sum() > 10
    np.testing.assert_allclose(windows.distance_m, np.interp(windows.t0, drive.t, driven_m),
                               rtol=1e-9, atol=1e-6)


def test_the_windows_of_two_drives_never_share_a_cluster(noisy_drive: SimulatedDrive) -> None:
    """Each drive's windows are clusters of their own drive (the cluster's number says which:
    a change is placed in its drive by it; from the mutation sample, where every drive numbered
    as the first survived)."""
    d = noisy_drive.drive
    windows, _ = windows_from_drives([d, d], Settings())
    half = windows.size // 2
    first, second = set(windows.cluster[:half].tolist()), set(windows.cluster[half:].tolist())
    assert first.isdisjoint(second)
    assert all(c // 10**9 == 0 for c in first) and all(c // 10**9 == 1 for c in second)
