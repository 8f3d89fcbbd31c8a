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
    for field in dataclasses.fields(blocked):
        np.testing.assert_array_equal(getattr(blocked, field.name), getattr(whole, field.name))
    np.testing.assert_array_equal(validation.mean_errors(thetas, data), e_whole)
    assert e_whole[0] < e_whole[1]                  # the truth validates better
