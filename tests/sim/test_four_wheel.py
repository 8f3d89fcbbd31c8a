"""A simulated drive's four-wheel car: the front wheels and the steering on the drive's own
true motion, the rear axle's drive untouched."""

from __future__ import annotations

import numpy as np
import pytest

import odocal
from odocal.model import four_wheel
from odocal.model.vehicle import MODEL
from odocal.sim.four_wheel import TRUE_FOUR_WHEEL, true_motion, with_front_axle


def test_the_front_axle_is_the_model_s_on_the_true_motion() -> None:
    sim = odocal.simulate(duration_s=120, seed=3, noise="none")
    four, truth = with_front_axle(sim)
    # the rear axle's drive is the simulator's, bit for bit
    for key, value in sim.drive.columns().items():
        np.testing.assert_array_equal(four.drive.columns()[key], value)
    assert truth.c_e == sim.true_parameters.c_e and truth.L == TRUE_FOUR_WHEEL.L
    v, w, a_y = true_motion(sim)
    np.testing.assert_allclose(MODEL.wheel_rates(sim.true_parameters.as_array(), v, w, a_y),
                               np.column_stack([sim.true_n_rl, sim.true_n_rr]), rtol=1e-12)
    t_s = sim.drive.t_s
    revs, _ = four_wheel.inverse_step(truth.as_array(), v * t_s, w * t_s, a_y)
    np.testing.assert_allclose(four.drive.inputs["n_fl"], revs[:, 0] / t_s, rtol=1e-12)
    np.testing.assert_allclose(four.drive.inputs["n_fr"], revs[:, 1] / t_s, rtol=1e-12)
    moving = v > 1.0
    bicycle = truth.ratio * np.arctan(truth.L * w / np.where(moving, v, 1.0)) + truth.s_0
    steer = four.drive.inputs["steer"]
    assert np.abs(steer - bicycle)[moving].max() < 6 * 0.0017        # the sensor's noise
    # in a left bend the outer (right) front wheel turns faster than the inner one
    left = moving & (w > 0.1)
    assert np.all(four.drive.inputs["n_fr"][left] > four.drive.inputs["n_fl"][left])


def test_the_front_wheels_carry_the_profile_s_noise_from_their_own_stream() -> None:
    sim = odocal.simulate(duration_s=120, seed=3, noise="realistic")
    a, _ = with_front_axle(sim)
    b, _ = with_front_axle(sim)
    np.testing.assert_array_equal(a.drive.inputs["n_fl"], b.drive.inputs["n_fl"])
    clean, _ = with_front_axle(odocal.simulate(duration_s=120, seed=3, noise="none"))
    error = a.drive.inputs["n_fl"] - clean.drive.inputs["n_fl"]
    rear_error = sim.drive.n_rl - sim.true_n_rl
    assert np.std(error) == pytest.approx(np.std(rear_error), rel=0.5)
    assert abs(np.corrcoef(error, rear_error)[0, 1]) < 0.3


def test_a_drive_with_a_change_has_no_front_axle() -> None:
    after = odocal.simulate(duration_s=60, seed=1, noise="none").true_parameters
    sim = odocal.simulate(duration_s=60, seed=1, noise="none",
                          change=(30.0, after.replace(c_e=after.c_e * 1.01)))
    with pytest.raises(ValueError, match="no one theta"):
        with_front_axle(sim)
