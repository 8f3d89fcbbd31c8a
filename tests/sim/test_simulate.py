"""The simulator: believable, deterministic, and exactly consistent with the model."""

from __future__ import annotations

import numpy as np
import pytest

import odocal
from odocal.errors import ConfigError
from odocal.model.kinematics import rollout
from odocal.model.parameters import Inputs
from odocal.sim.noise import NOISE_PROFILES


def test_deterministic_for_a_seed() -> None:
    a = odocal.simulate(duration_s=120, seed=4, noise="realistic")
    b = odocal.simulate(duration_s=120, seed=4, noise="realistic")
    c = odocal.simulate(duration_s=120, seed=5, noise="realistic")
    np.testing.assert_array_equal(a.drive.n_rl, b.drive.n_rl)
    np.testing.assert_array_equal(a.drive.x, b.drive.x)
    assert not np.array_equal(a.drive.x, c.drive.x)


def test_noise_free_drive_is_the_model(clean_drive: odocal.SimulatedDrive) -> None:
    d = clean_drive.drive
    u = Inputs(d.n_rl[:-1], d.n_rr[:-1], d.beta[:-1], d.a_y[:-1])
    poses = rollout(clean_drive.true_parameters.as_array(), u, np.array([d.x[0], d.y[0],
                                                                          d.psi[0]]), d.t_s)
    np.testing.assert_allclose(poses[:, :2], np.column_stack([d.x, d.y]), atol=1e-8)
    np.testing.assert_array_equal(d.n_rl, clean_drive.true_n_rl)


def test_city_drive_is_believable() -> None:
    sim = odocal.simulate(duration_s=1800, seed=2, noise="none")
    d = sim.drive
    speed = np.hypot(np.diff(d.x), np.diff(d.y)) / d.t_s
    assert speed.max() <= 15.0 + 1e-6
    assert 6.0 < speed.mean() < 12.0
    assert (speed < 0.01).mean() > 0.02                   # it stops
    assert np.abs(np.diff(speed)).max() / d.t_s < 3.0     # no jumps in speed
    moving = speed > 1.0
    curvature = np.abs(d.yaw_rate[:-1][moving]) / speed[moving]
    assert curvature.max() <= 1 / 8.0 * 1.05               # tightest turn 8 m
    assert np.abs(np.diff(d.yaw_rate)).max() / d.t_s < 2.0   # clothoids: no yaw-rate jumps
    assert np.abs(d.a_y).max() < 4.0


@pytest.mark.parametrize("profile", sorted(NOISE_PROFILES))
def test_every_profile_runs_and_documents_itself(profile: str) -> None:
    sim = odocal.simulate(duration_s=60, seed=1, noise=profile)
    assert sim.profile.description
    assert np.isfinite(sim.drive.n_rl).all()
    if sim.profile.wheels_exact:
        np.testing.assert_array_equal(sim.drive.n_rl, sim.true_n_rl)
    else:
        assert not np.array_equal(sim.drive.n_rl, sim.true_n_rl)
    p = sim.profile
    reference_exact = not (p.reference_position_m or p.reference_slow_position_m)
    assert np.array_equal(sim.drive.x, sim.true_poses[:, 0]) == reference_exact


def test_unknown_profile() -> None:
    with pytest.raises(ConfigError, match="unknown noise profile 'loud'"):
        odocal.simulate(duration_s=60, noise="loud")


def test_noise_levels_are_what_the_profiles_say() -> None:
    """The simulated errors have the documented size and correlation."""
    sim = odocal.simulate(duration_s=1200, seed=3, noise="white-5x")
    moving = sim.true_n_rl > 0
    err = sim.drive.n_rl[moving] - sim.true_n_rl[moving]
    assert abs(err.std() - 0.10) < 0.005
    markov = odocal.simulate(duration_s=1200, seed=3, noise="markov")
    e = markov.drive.n_rr - markov.true_n_rr
    e = e[markov.true_n_rr > 0]
    assert abs(e.std() - 0.015) < 0.003
    lag = round(0.5 / 0.025)                              # the correlation time: exp(-1)
    assert abs(np.corrcoef(e[:-lag], e[lag:])[0, 1] - np.exp(-1)) < 0.1
    delayed = odocal.simulate(duration_s=600, seed=3, noise="delay")
    t = delayed.drive.t
    lagged = np.interp(t - 0.04, t, delayed.true_n_rl)
    assert np.std(delayed.drive.n_rl - lagged) < 0.006 < np.std(delayed.drive.n_rl
                                                              - delayed.true_n_rl)


@pytest.mark.parametrize(("kwargs", "words"), [
    ({"duration_s": float("inf")}, r"duration inf s is out of range: .* at most 86400 s"),
    ({"duration_s": float("nan")}, r"duration nan s is out of range"),
    ({"duration_s": 1e12}, r"duration 1e\+12 s is out of range"),
    ({"duration_s": -5.0}, r"duration -5 s is out of range: a simulated drive lasts more than"),
    ({"duration_s": "60"}, r"duration '60' is not a number"),
    ({"seed": -1}, r"seed -1 is invalid: a seed is an integer from 0 to 9223372036854775807"),
    ({"seed": 2**63}, r"seed 9223372036854775808 is invalid"),
    ({"seed": 1.5}, r"seed 1.5 is invalid"),
    ({"seed": True}, r"seed True is invalid"),
    ({"noise_seed": -3}, r"noise_seed -3 is invalid"),
    ({"t_s": 1.0}, r"sampling time 1.0 s is out of range: 0.001 to 0.1 s"),
    ({"t_s": 0.0}, r"sampling time 0.0 s is out of range"),
    ({"theta": odocal.Parameters(-1.0, 0.0, 1.5, 0.0)}, r"theta: c_e = -1 is not a wheeled"),
    ({"theta": odocal.Parameters(2.0, 0.0, 1e300, 0.0)}, r"theta: t_r = 1e\+300 is not"),
    ({"change": (100.0, odocal.Parameters(2.0, 3.0, 1.5, 0.0))},
     r"change: c_d = 3 m is not smaller than c_e"),
])
def test_arguments_out_of_range_are_named_before_simulating(kwargs: dict[str, object],
                                                            words: str) -> None:
    with pytest.raises(ConfigError, match=words):
        odocal.simulate(**{"duration_s": 60.0, **kwargs})  # type: ignore[arg-type]


@pytest.mark.parametrize("c_e", [0.2, 0.33, 3.5])
def test_any_wheel_size_simulates_and_reads_back(c_e: float) -> None:
    """A simulated robot's (or truck's) own output is a drive it accepts: rates far beyond a
    car's 40 rev/s are judged with the simulated wheel."""
    theta = odocal.Parameters(c_e=c_e, c_d=0.0, t_r=0.5 if c_e < 1 else 2.0, d=0.0)
    sim = odocal.simulate(duration_s=120, seed=1, noise="none", theta=theta)
    speed = np.hypot(np.diff(sim.drive.x), np.diff(sim.drive.y)) / sim.drive.t_s
    np.testing.assert_allclose(np.max(sim.drive.n_rl) * c_e, np.max(speed), rtol=0.05)
    again = odocal.Drive.from_columns(sim.drive.columns(), circumference_m=c_e)
    np.testing.assert_array_equal(again.n_rl, sim.drive.n_rl)
