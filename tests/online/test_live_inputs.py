"""What a live stream hands the online calibrator (issue 32): time in any unit or as datetimes,
a sample rate that changes mid-stream, jittered time stamps, and numbers that cannot be fitted:
the calibrator carries on (or halts with a finding); it never raises anything but a DataError
naming a chunk it refuses."""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd
import pytest

import odocal
from odocal.checks.findings import Check
from odocal.errors import DataError
from odocal.estimators import core
from odocal.estimators.estimate import Status
from odocal.online.calibrator import OnlineCalibrator
from odocal.online.samples import SAMPLE, Regrid, time_unit

EPOCH_S = 1.7e9


@pytest.fixture(scope="module")
def live() -> tuple[dict[str, np.ndarray], odocal.Parameters]:
    sim = odocal.simulate(duration_s=300, seed=31, noise="realistic")
    return ({k: v for k, v in sim.drive.columns().items() if k in SAMPLE},
            sim.true_parameters)


def run(cols: Any, chunk: int = 40) -> OnlineCalibrator:
    cal = OnlineCalibrator()
    n = len(cols) if isinstance(cols, pd.DataFrame) else cols["t"].size
    for lo in range(0, n, chunk):
        cal.push(cols.iloc[lo:lo + chunk] if isinstance(cols, pd.DataFrame)
                 else {k: v[lo:lo + chunk] for k, v in cols.items()})
    return cal


@pytest.fixture(scope="module")
def in_seconds(live: tuple[dict[str, np.ndarray], odocal.Parameters]) -> odocal.Estimate:
    cols, _ = live
    return run({**cols, "t": cols["t"] + EPOCH_S}).estimate()


def _stamps(t: np.ndarray) -> np.ndarray:
    return np.datetime64("2023-11-14T22:13:20", "ns") + np.round(t * 1e9).astype(
        "timedelta64[ns]")


@pytest.mark.parametrize("unit", ["ms", "us", "ns", "datetime64", "pandas-utc+1", "datetime"])
def test_time_in_any_unit_or_as_datetimes_gives_the_seconds_estimate(
        live: tuple[dict[str, np.ndarray], odocal.Parameters], in_seconds: odocal.Estimate,
        unit: str) -> None:
    """Epoch time stamps in ms, us or ns (floats or integers) or as datetimes: the same
    estimate as in seconds (was: nothing identifiable, or c_e 1.9e26)."""
    cols, _ = live
    t = cols["t"] + EPOCH_S
    chunk: Any
    if unit in ("ms", "us"):
        chunk = {**cols, "t": t * {"ms": 1e3, "us": 1e6}[unit]}
    elif unit == "ns":
        chunk = {**cols, "t": np.round(t * 1e9).astype(np.int64)}
    elif unit == "datetime64":
        chunk = {**cols, "t": _stamps(cols["t"])}
    elif unit == "pandas-utc+1":
        chunk = pd.DataFrame({**cols, "t": pd.to_datetime(_stamps(cols["t"])).tz_localize(
            "UTC").tz_convert("Etc/GMT-1")})
    else:
        chunk = {**cols, "t": np.array(_stamps(cols["t"]).astype("datetime64[us]").tolist(),
                                       dtype=object)}
    est = run(chunk).estimate()
    assert est.details.time_unit == {"datetime64": "datetime", "pandas-utc+1": "datetime"}.get(
        unit, "datetime" if unit == "datetime" else unit)
    assert est.details.sampling_s == 0.025
    assert est.identified == in_seconds.identified and est.identified[0]
    np.testing.assert_allclose(est.theta.as_array(), in_seconds.theta.as_array(), rtol=1e-9)
    np.testing.assert_allclose(est.std, in_seconds.std, rtol=1e-6)


def test_time_no_unit_makes_a_drive_log_of_is_refused(
        live: tuple[dict[str, np.ndarray], odocal.Parameters]) -> None:
    cols, _ = live
    cal = OnlineCalibrator()
    with pytest.raises(DataError, match=r"advances by 2\.5e-05 per sample: neither seconds"):
        cal.push({k: v[:40] for k, v in {**cols, "t": cols["t"] * 1e-3}.items()})
    assert cal.details_samples() == 0
    cal.push({k: v[:40] for k, v in cols.items()})          # good samples are taken after it
    assert cal.details_samples() == 40
    assert time_unit(25.0) == ("ms", 1e-3) and time_unit(0.5) == ("s", 1.0)
    assert time_unit(10_000_000.0) == ("ns", 1e-9)


@pytest.mark.parametrize("rate_hz", [20.0, 100.0, 12.5])
def test_a_sample_rate_change_mid_stream_carries_on(
        live: tuple[dict[str, np.ndarray], odocal.Parameters], in_seconds: odocal.Estimate,
        rate_hz: float) -> None:
    """The logger switches from 40 Hz to another rate half-way: the later samples are put onto
    the first ones' grid (was: every step a gap, then the checks halted it for good)."""
    cols, truth = live
    t = cols["t"]
    later = np.arange(150.0, t[-1], 1.0 / rate_hz)
    psi = np.unwrap(cols["psi"])
    switched = {k: np.concatenate([v[t < 150.0], np.interp(later, t, psi if k == "psi" else v)])
                for k, v in cols.items()}
    switched["t"] = np.concatenate([t[t < 150.0], later])
    cal = run(switched)
    est = cal.estimate()
    assert not cal.halted and est.status is Status.CONVERGED
    assert est.details.sampling_s == 0.025
    assert est.details.windows >= 0.9 * in_seconds.details.windows      # the later half too
    assert est.identified[0]
    assert abs(est.theta.c_e - truth.c_e) < 3 * est.std[0]
    assert abs(est.theta.c_e - in_seconds.theta.c_e) < in_seconds.std[0]


def test_jittered_time_stamps_are_put_on_the_grid(
        live: tuple[dict[str, np.ndarray], odocal.Parameters],
        in_seconds: odocal.Estimate) -> None:
    cols, _ = live
    rng = np.random.default_rng(3)
    jittered = {**cols, "t": cols["t"] + rng.uniform(-0.003, 0.003, cols["t"].size)}
    cal = run(jittered)
    est = cal.estimate()
    assert not cal.halted and est.identified == in_seconds.identified
    assert np.all(np.abs(est.theta.as_array() - in_seconds.theta.as_array())
                  < in_seconds.std + 1e-12)


def test_samples_on_the_grid_pass_as_they_are_and_others_are_interpolated() -> None:
    grid = Regrid(0.1)
    t = np.arange(20) * 0.1 + 5.0
    rows = np.column_stack([t] + [np.sin(t + k) for k in range(6)]
                           + [np.full(t.size, 3.1)])
    rows[10:, 7] = -3.1                             # the heading wraps past pi
    out = np.vstack([grid.add(rows[:7]), grid.add(rows[7:])])
    assert np.array_equal(out, rows)                # bit for bit
    # a slower stream after it: once its rate is the stream's own (the first few steps are
    # gaps until then), the grid times between its samples are interpolated, the heading the
    # short way round
    slow_t = t[-1] + 0.25 * np.arange(1, 41)
    slow = np.column_stack([slow_t] + [np.cos(slow_t + k) for k in range(6)]
                           + [np.where(np.arange(40) % 2 == 0, 3.1, -3.1)])
    out = grid.add(slow)
    settled = out[out[:, 0] > slow_t[12]]
    assert settled.shape[0] > 60 and np.allclose(np.diff(settled[:, 0]), 0.1)
    g = settled[5]
    j = int(np.searchsorted(slow_t, g[0]))
    frac = (g[0] - slow_t[j - 1]) / 0.25
    np.testing.assert_allclose(g[1:7], slow[j - 1, 1:7] + frac * (slow[j, 1:7] - slow[j - 1, 1:7]))
    assert np.all(np.abs(np.abs(settled[:, 7]) - 3.1) < 0.09)   # never through 0 between +-3.1
    # a gap is a gap: the grid restarts at the first sample after it
    after = grid.add(np.column_stack([[slow_t[-1] + 5.0]] + [[0.0]] * 7))
    assert after.shape == (1, 8) and after[0, 0] == slow_t[-1] + 5.0


def test_numbers_that_cannot_be_fitted_halt_it_with_a_finding(
        live: tuple[dict[str, np.ndarray], odocal.Parameters],
        monkeypatch: pytest.MonkeyPatch) -> None:
    """No exception ever from push: a solver that does not converge on degenerate samples (the
    fuzz test's 'SVD did not converge') halts the calibrator with that finding."""
    cols, _ = live

    def diverges(*args: Any, **kwargs: Any) -> Any:
        raise np.linalg.LinAlgError("SVD did not converge")

    monkeypatch.setattr(core, "solve", diverges)
    cal = run(cols)                                   # (raises nothing)
    est = cal.estimate()
    assert cal.halted and est.status is Status.REJECTED and not any(est.identified)
    (finding,) = [f for f in est.details.findings if f.check is Check.INVALID_INPUT]
    assert "cannot be fitted (SVD did not converge)" in finding.name
