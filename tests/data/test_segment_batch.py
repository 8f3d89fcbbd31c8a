"""A batch gathered lazily holds the same segments as one gathered at once (issue 30)."""

from __future__ import annotations

import numpy as np

from odocal.data.segments import SegmentBatch, gather, gather_lazily, identification_segments
from odocal.settings import Settings
from odocal.sim.simulate import SimulatedDrive


def test_a_lazy_batch_gives_the_segments_a_gathered_one_holds(
        short_drive: SimulatedDrive) -> None:
    drives = [short_drive.drive, short_drive.drive.since(30.0)]
    segs = identification_segments(drives, Settings().segments)
    used = segs.subset(np.flatnonzero(segs.selected | (np.arange(len(segs)) % 3 == 0)))
    eager, lazy = gather(drives, used), gather_lazily(drives, used)
    assert lazy.lazy and not eager.lazy
    assert len(lazy) == len(eager) > 4 and lazy.steps == eager.steps and lazy.t_s == eager.t_s

    def same(a: SegmentBatch, b: SegmentBatch) -> None:
        for f in ("n_rl", "n_rr", "beta", "a_y"):
            np.testing.assert_array_equal(getattr(a.inputs, f), getattr(b.inputs, f))
        np.testing.assert_array_equal(a.reference, b.reference)

    same(lazy, eager)
    same(lazy.part(1, 4), eager.take(slice(1, 4)))
    assert [len(p) for p in lazy.parts(3)] == [3] * (len(lazy) // 3) + (
        [len(lazy) % 3] if len(lazy) % 3 else [])
    pick = np.array([4, 0, 4, 2])                     # a bootstrap draw repeats segments
    same(lazy.take(pick), eager.take(pick))
    same(lazy.subset(pick), eager.take(pick))
    assert lazy.subset(pick).lazy and not lazy.take(pick).lazy
    for name in ("n_rl", "n_rr", "beta", "a_y"):
        np.testing.assert_array_equal(lazy.input_rows(name, 2, 5),
                                      getattr(eager.inputs, name)[2:5])
    rates = np.arange(len(eager) * eager.steps, dtype=float).reshape(len(eager), -1)
    same(lazy.with_wheel_rates(rates, -rates), eager.with_wheel_rates(rates, -rates))
    same(lazy.with_wheel_rates(rates, -rates).subset(pick).part(1, 3),
         eager.with_wheel_rates(rates, -rates).take(pick[1:3]))
    np.testing.assert_array_equal(lazy.with_wheel_rates(rates, -rates).input_rows("n_rr", 1, 3),
                                  -rates[1:3])
