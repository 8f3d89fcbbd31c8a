"""The live path on the issue's departures from the model (issue 32, "What to build"): a
reference delay, an a_y offset, a wheel-rate offset at standstill, truncated wheel speeds,
one-sided turning; and a heading error varying with the heading, front wheels logged as the
rear ones. The live path runs the batch default's core on its windows (the lag over a
second either way, the wheel-rate offset with its prior where the rates are encoded, the
identifiability judged jointly) and measures the sensors' departures as batch does, taking out
what it determines (odocal/online/departures.py).

Each test runs several values (none of the issue's) and asserts that no run ends in a confident
wrong number (a parameter reported identified with the truth beyond 3 of its standard
deviations): where the live path cannot be right it must say so (a wider uncertainty, not
identified, or a finding).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

import odocal
from odocal.checks.findings import Check
from odocal.estimators.estimate import Status
from odocal.estimators.windows import WindowSet, builder_for
from odocal.online.departures import recorrected
from odocal.settings import Settings
from odocal.sim import departures
from tests.online import departures as dep
from tests.online.test_live_departures import confidently_wrong, pushed


def _wrong(make: Callable[[int], dep.Departed], seeds: range) -> dict[int, list[str]]:
    runs = {seed: pushed(make(seed)) for seed in seeds}
    return {seed: wrong for seed, run in runs.items() if (wrong := confidently_wrong(run))}


def test_a_late_or_early_reference_is_taken_out_or_named() -> None:
    delays = {20: 0.3, 21: -0.2, 22: 0.45, 23: 0.7}
    assert _wrong(lambda s: dep.reference_delay(s, duration_s=420.0, delay_s=delays[s]),
                  range(20, 24)) == {}


def test_an_offset_lateral_acceleration_is_taken_out() -> None:
    offsets = {24: 0.4, 25: -0.7, 26: 0.25}
    assert _wrong(lambda s: dep.lateral_offset(s, duration_s=420.0, offset_mps2=offsets[s]),
                  range(24, 27)) == {}


def test_wheels_turning_at_standstill_are_taken_out() -> None:
    offsets = {27: 0.04, 28: 0.06, 29: 0.025}
    assert _wrong(lambda s: dep.wheel_offset(s, duration_s=420.0, offset_revps=offsets[s]),
                  range(27, 30)) == {}


def test_wheels_that_read_an_offset_while_moving_only_are_fitted_with_it() -> None:
    """Drives that never stand still long enough to measure the offset at rest: the windows'
    distance residuals show it, as batch's do (c_e was 19-25 standard deviations off)."""
    offsets = {1: 0.05, 73: -0.03, 76: 0.04}
    runs = {s: pushed(dep.wheel_offset(s, duration_s=600.0, offset_revps=o))
            for s, o in offsets.items()}
    assert {s: w for s, run in runs.items() if (w := confidently_wrong(run))} == {}
    for run in runs.values():
        assert run.estimate.identified[0] and not run.alarms
        assert Check.MOVING_OFFSET in {f.check for f in run.estimate.details.findings}


def test_truncated_wheel_speeds_are_taken_out() -> None:
    steps = {30: (1.0, "rpm"), 31: (0.1, "km/h"), 32: (0.5, "rpm")}
    assert _wrong(lambda s: dep.truncated(s, duration_s=420.0, step=steps[s][0],
                                          unit=steps[s][1]), range(30, 33)) == {}


def test_one_sided_turning_leaves_t_r_and_d_not_identified_together() -> None:
    cases = {33: (9.0, "left"), 34: (13.0, "slalom"), 35: (15.0, "left")}
    assert _wrong(lambda s: dep.one_sided(s, duration_s=420.0, speed_mps=cases[s][0],
                                          pattern=cases[s][1]), range(33, 36)) == {}


def test_a_drive_at_one_speed_fits_no_offset_while_moving() -> None:
    """Left turns at 16 m/s: the windows' residual regression put an 'offset' of -8.6 rev/s
    there, and a fit with it free ran away (c_e 1e42, REJECTED); an offset is a scale error at
    one speed, so none is looked for."""
    run = pushed(dep.one_sided(4, duration_s=600.0, speed_mps=16.0, pattern="left"))
    assert run.estimate.status is Status.CONVERGED
    assert Check.MOVING_OFFSET not in {f.check for f in run.estimate.details.findings}
    assert confidently_wrong(run) == []


def _simulated(sim: odocal.SimulatedDrive) -> dep.Departed:
    return dep.Departed({k: np.asarray(v, dtype=np.float64)
                         for k, v in sim.drive.columns().items() if k in dep.COLUMNS},
                        sim.true_parameters)


def test_a_heading_error_varying_with_the_heading_is_taken_out() -> None:
    """A magnetometer-like heading error (first or second harmonic): measured on the first
    five minutes of driving, taken out of the windows made so far (they are made again) and of
    every sample after."""
    cases = {36: (4.0, 1, 0.2), 37: (6.0, 2, -1.1)}

    def make(seed: int) -> dep.Departed:
        amplitude, harmonic, phase = cases[seed]
        sim = departures.heading_error(dep.base(seed, 540.0), np.deg2rad(amplitude),
                                       phase_rad=phase, harmonic=harmonic)
        return _simulated(sim)

    runs = {seed: pushed(make(seed)) for seed in cases}
    assert {s: w for s, r in runs.items() if (w := confidently_wrong(r))} == {}
    for run in runs.values():
        assert Check.HEADING_ERROR in {f.check for f in run.estimate.details.findings}
        assert run.estimate.identified[0]


def test_front_wheels_logged_as_the_rear_ones_are_named_not_refused() -> None:
    """The live path's one fit takes the wheels' excess in bends in as batch's does, names it
    with the distance ahead, and publishes the wheels given (a tyre change, a lever arm or a
    smoothed reference never turns into a refusal)."""
    for seed, wheelbase in ((38, 2.9), (39, 2.4)):
        run = pushed(_simulated(departures.front_wheels(dep.base(seed, 420.0), wheelbase)))
        assert run.estimate.status is not Status.REJECTED
        (curve,) = [f for f in run.estimate.details.findings if f.check is Check.CURVE_EXCESS]
        assert np.sqrt(2.0 * curve.value) == pytest.approx(wheelbase, rel=0.25)


def test_windows_corrected_after_the_fact_equal_windows_of_corrected_samples(
        short_drive: odocal.SimulatedDrive) -> None:
    """The wheels' standstill offsets found after windows were made are taken out of them
    exactly: as if the samples had been corrected first (a_y's offset is the fit's own)."""
    cols = {k: v for k, v in short_drive.drive.columns().items() if k in dep.COLUMNS}
    wheels = (0.021, -0.013)

    def windows(c: dict[str, np.ndarray]) -> WindowSet:
        builder = builder_for(Settings(), short_drive.drive.t_s)
        builder.add(*(c[k] for k in dep.COLUMNS))
        return builder.windows()

    fixed = {**cols, "n_rl": cols["n_rl"] - wheels[0], "n_rr": cols["n_rr"] - wheels[1]}
    first, then = windows(fixed), recorrected(windows(cols), wheels_revps=wheels)
    assert then.size == first.size > 20
    np.testing.assert_allclose(then.moments, first.moments, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(then.measured, first.measured, rtol=1e-12, atol=1e-12)


def test_the_live_reference_alignment_is_batchs_chunk_by_chunk() -> None:
    """A late (or early) wheel stream: the reference put on the wheels' clock as the samples
    arrive, in chunks that do not meet the gap, gives the samples batch's shifted_reference
    keeps, once each, with the same poses."""
    from odocal.checks.departures import shifted_reference
    from odocal.online.departures import ReferenceAligner

    d = odocal.simulate(duration_s=90, seed=11, noise="realistic").drive
    cols = d.columns()
    keep = (d.t < 40.0) | (d.t > 43.0)                            # a 3 s gap: two pieces
    cut = {k: np.asarray(v)[keep] for k, v in cols.items()}
    cut["piece"] = (cut["t"] > 43.0).astype(float)
    drive = odocal.Drive.from_columns(cut, name="gap")
    rows = np.column_stack([drive.t, drive.n_rl, drive.n_rr, drive.beta, drive.a_y, drive.x,
                            drive.y, drive.psi])
    for shift_s in (0.34, -0.21):                 # (between samples: interpolated)
        aligner = ReferenceAligner(drive.t_s, shift_s)
        parts = [aligner.add(rows[i:i + 37]) for i in range(0, rows.shape[0], 37)]
        live = np.vstack([*parts, aligner.flush()])
        batch = shifted_reference(drive, shift_s)
        np.testing.assert_allclose(live[:, 0], batch.t, rtol=0, atol=1e-9)
        np.testing.assert_allclose(live[:, 5], batch.x, rtol=0, atol=1e-9)
        np.testing.assert_allclose(live[:, 6], batch.y, rtol=0, atol=1e-9)
        gap = np.remainder(live[:, 7] - batch.psi + np.pi, 2 * np.pi) - np.pi
        assert np.max(np.abs(gap)) < 1e-9
        np.testing.assert_array_equal(live[:, 1], batch.n_rl)
