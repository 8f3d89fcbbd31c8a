"""METHOD 6: validation errors, rolled out a block of segments at a time (issue 30)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from odocal.data.segments import gather_ragged, validation_segments
from odocal.estimators import validation
from odocal.settings import Settings
from odocal.sim.simulate import SimulatedDrive


def test_blocks_of_segments_give_the_errors_of_one_pass(noisy_drive: SimulatedDrive,
                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    drive = noisy_drive.drive
    data = gather_ragged([drive], validation_segments([drive], Settings().segments))
    thetas = np.array([noisy_drive.true_parameters.as_array(), [2.0, 0.0, 1.6, 0.0]])
    whole = validation.segment_errors(thetas[0], data)
    e_whole = validation.mean_errors(thetas, data)
    monkeypatch.setattr(validation, "BLOCK_SAMPLES", int(data.steps.max()) * 2 + 5)
    assert 3 <= len(validation._blocks(data)) < len(data)
    blocked = validation.segment_errors(thetas[0], data)
    # the same to rounding (a rollout's running sums restart with each block)
    for field in dataclasses.fields(blocked):
        np.testing.assert_allclose(getattr(blocked, field.name), getattr(whole, field.name),
                                   rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(validation.mean_errors(thetas, data), e_whole, rtol=1e-9)
    assert e_whole[0] < e_whole[1]                  # the truth validates better
