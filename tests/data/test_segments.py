"""METHOD 2: identification and validation segments."""

from __future__ import annotations

import numpy as np

from odocal.data.drive import Drive
from odocal.data.segments import (
    gather,
    gather_ragged,
    identification_segments,
    validation_segments,
)
from odocal.settings import SegmentSettings
from odocal.sim.simulate import SimulatedDrive


def test_identification_segments_follow_the_paper(clean_drive: SimulatedDrive) -> None:
    settings = SegmentSettings()
    drive = clean_drive.drive
    segs = identification_segments([drive], settings)
    assert np.all(segs.steps == 650)
    assert np.all(np.diff(segs.start) == 100)
    assert segs.start[-1] + 650 <= drive.n_samples - 1
    assert len(segs) == (drive.n_samples - 1 - 650) // 100 + 1
    peak = np.array([np.abs(drive.yaw_rate[s:s + 651]).max() for s in segs.start])
    np.testing.assert_allclose(segs.peak_yaw_rate_radps, peak)
    np.testing.assert_array_equal(segs.selected, peak > 0.15)


def test_segments_never_cross_pieces(clean_drive: SimulatedDrive) -> None:
    d = clean_drive.drive
    cols = d.columns()
    t = cols["t"].copy()
    t[9000:] += 30.0                                       # a 30 s gap after sample 9000
    cols["t"] = t
    cols["piece"] = (np.arange(d.n_samples) >= 9000).astype(float)
    gapped = Drive.from_columns(cols, name="gapped")
    assert gapped.pieces == ((0, 9000), (9000, d.n_samples))
    for segs in (identification_segments([gapped], SegmentSettings()),
                 validation_segments([gapped], SegmentSettings())):
        end = segs.start + segs.steps
        assert not np.any((segs.start < 9000) & (end >= 9000))


def test_validation_segments_cover_about_300_m(clean_drive: SimulatedDrive) -> None:
    settings = SegmentSettings()
    segs = validation_segments([clean_drive.drive], settings)
    assert segs.start[0] == settings.validation_offset
    np.testing.assert_array_equal(segs.start[1:], segs.start[:-1] + segs.steps[:-1])
    assert np.all(segs.distance_m[:-1] >= 300.0)
    assert np.all(segs.distance_m < 300.0 + 15 * 0.025 + 1e-9)   # one step at most 15 m/s
    assert segs.distance_m[-1] >= 150.0                          # a trailing rest of >= half
    assert segs.selected.all()


def test_gather_copies_the_right_samples(clean_drive: SimulatedDrive) -> None:
    d = clean_drive.drive
    segs = identification_segments([d], SegmentSettings()).subset(np.array([0, 3, 7]))
    batch = gather([d], segs)
    s = int(segs.start[1])
    np.testing.assert_array_equal(batch.inputs.n_rl[1], d.n_rl[s:s + 650])
    np.testing.assert_array_equal(batch.reference[1, :, 2], d.psi[s:s + 651])
    vsegs = validation_segments([d], SegmentSettings())
    ragged = gather_ragged([d], vsegs)
    assert ragged.reference.shape[0] == int(ragged.steps.sum())
    first = int(vsegs.start[1])
    np.testing.assert_array_equal(ragged.initial[1], [d.x[first], d.y[first], d.psi[first]])
    row = int(ragged.steps[0])                            # first row of segment 1
    np.testing.assert_array_equal(ragged.reference[row], [d.x[first + 1], d.y[first + 1],
                                                          d.psi[first + 1]])


def test_segments_from_several_drives(clean_drive: SimulatedDrive,
                                      noisy_drive: SimulatedDrive) -> None:
    drives = [clean_drive.drive, noisy_drive.drive]
    segs = identification_segments(drives, SegmentSettings())
    assert set(segs.drive.tolist()) == {0, 1}
    for i, d in enumerate(drives):
        assert (segs.start[segs.drive == i] + 650 <= d.n_samples - 1).all()
