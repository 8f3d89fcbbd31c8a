"""Drive files as real loggers write them (issue 32): time in other units or as date-times,
stamps that jitter, logs too slow for the model, and wheels smaller than a car's."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
import pyarrow.parquet as pq
import pytest

import odocal
from odocal.cli.main import EXIT_ERROR, EXIT_FAILED, EXIT_OK
from odocal.model.parameters import Parameters
from odocal.sim.simulate import SimulatedDrive
from tests.conftest import run

EPOCH_S = 1_754_000_000.0          # 2025-07-31


@pytest.fixture(scope="module")
def white_drive() -> SimulatedDrive:
    return odocal.simulate(duration_s=300, seed=7, noise="white")


@pytest.mark.parametrize(("unit", "factor", "divisor"), [
    ("milliseconds", 1e3, "1000"), ("microseconds", 1e6, "1e6"), ("nanoseconds", 1e9, "1e9")])
@pytest.mark.parametrize("rate_hz", [40, 100])
def test_time_in_another_unit_is_named_with_its_divisor(unit: str, factor: float, divisor: str,
                                                        rate_hz: int) -> None:
    cols = odocal.simulate(duration_s=60, seed=1, noise="white", t_s=1 / rate_hz).drive.columns()
    cols["t"] = cols["t"] * factor
    with pytest.raises(odocal.DataError) as err:
        odocal.Drive.from_columns(cols, name="log.csv")
    text = str(err.value)
    assert f"it looks like {unit} at {rate_hz} Hz: divide t by {divisor}" in text
    assert "unknown unit" not in text


@pytest.mark.parametrize("rate_hz", [0.5, 1.0, 2.0, 5.0])
def test_a_log_too_slow_for_the_model_is_named_by_its_rate(white_drive: SimulatedDrive,
                                                           rate_hz: float) -> None:
    cols = white_drive.drive.columns()
    every = round(1 / (rate_hz * white_drive.drive.t_s))
    cols = {k: v[::every] for k, v in cols.items()}
    with pytest.raises(odocal.DataError) as err:
        odocal.Drive.from_columns(cols, name="slow.csv")
    text = str(err.value)
    assert f"sampled at {rate_hz:g} Hz" in text and "needs 10 Hz or more" in text
    assert "longer logs" not in text
    if rate_hz < 1.0:                       # a step of 2 might be milliseconds at 500 Hz too
        assert "it looks like milliseconds at 500 Hz" in text


def test_ten_hertz_is_enough_and_a_step_of_no_unit_is_named(white_drive: SimulatedDrive) -> None:
    cols = {k: v[::4] for k, v in white_drive.drive.columns().items()}
    assert odocal.Drive.from_columns(cols).t_s == pytest.approx(0.1)
    cols["t"] = cols["t"] * 1500.0                              # a step of 150
    with pytest.raises(odocal.DataError, match="in no unit is that the step of a drive log"):
        odocal.Drive.from_columns(cols)


def _iso(seconds: np.ndarray, zone: str) -> list[str]:
    shift = {"": 0.0, "Z": 0.0, "+05:00": 5 * 3600.0, "-08:00": -8 * 3600.0}[zone]
    stamps = np.datetime64("1970-01-01T00:00:00", "us") + np.round(
        (seconds + shift) * 1e6).astype("timedelta64[us]")
    return [str(s).replace("T", " " if zone == "-08:00" else "T") + zone for s in stamps]


@pytest.mark.parametrize("zone", ["", "Z", "+05:00", "-08:00"])
def test_iso_date_times_in_a_csv_are_seconds(tmp_path: Path, white_drive: SimulatedDrive,
                                             zone: str) -> None:
    cols = dict(white_drive.drive.columns())
    seconds = EPOCH_S + cols["t"]
    table = {**cols, "t": pa.array(_iso(seconds, zone))}
    pacsv.write_csv(pa.table(table), tmp_path / "d.csv")
    drive = odocal.load_drive(tmp_path / "d.csv")
    np.testing.assert_allclose(drive.t, seconds, atol=2e-6, rtol=0)
    assert drive.t_s == pytest.approx(white_drive.drive.t_s, rel=1e-6)
    # the same calibration as the drive on that clock in seconds
    est = odocal.calibrate(drive).estimate
    same = odocal.calibrate(odocal.Drive.from_columns({**cols, "t": seconds})).estimate
    assert np.all(np.abs(est.theta.as_array() - same.theta.as_array()) < 0.01 * same.std)


@pytest.mark.parametrize("unit", ["ms", "us", "ns"])
def test_parquet_timestamps_are_seconds(tmp_path: Path, white_drive: SimulatedDrive,
                                        unit: str) -> None:
    cols = dict(white_drive.drive.columns())
    per_s = {"ms": 1e3, "us": 1e6, "ns": 1e9}[unit]
    ticks = np.round((EPOCH_S + cols["t"]) * per_s).astype(np.int64)
    stamps = pa.array(ticks, type=pa.timestamp(unit, tz="UTC" if unit == "us" else None))
    pq.write_table(pa.table({**cols, "t": stamps}), tmp_path / "d.parquet")
    drive = odocal.load_drive(tmp_path / "d.parquet")
    np.testing.assert_allclose(drive.t, EPOCH_S + cols["t"], atol=2e-6, rtol=0)
    # and a duration column (time since the start) too
    pq.write_table(pa.table({**cols, "t": pa.array(np.round(cols["t"] * per_s).astype(
        np.int64), type=pa.duration(unit))}), tmp_path / "rel.parquet")
    np.testing.assert_allclose(odocal.load_drive(tmp_path / "rel.parquet").t, cols["t"],
                               atol=1e-9)


@pytest.mark.parametrize(("jitter_s", "t_s"), [(0.0005, 0.025), (0.002, 0.025), (0.005, 0.025),
                                               (0.001, 0.01)])
def test_stamps_that_jitter_are_resampled_not_called_gaps(jitter_s: float, t_s: float) -> None:
    sim = odocal.simulate(duration_s=300, seed=7, noise="white", t_s=t_s)
    cols = dict(sim.drive.columns())
    rng = np.random.default_rng(int(jitter_s * 1e4))
    cols["t"] = cols["t"] + rng.uniform(-jitter_s, jitter_s, cols["t"].size)
    drive = odocal.Drive.from_columns(cols, name="jitter.csv")
    resampled = drive.metadata["resampled"]
    assert drive.t_s == pytest.approx(t_s, rel=1e-3)
    assert jitter_s * 0.9 < resampled["max_jitter_s"] < 2.5 * jitter_s
    np.testing.assert_allclose(np.diff(drive.t), drive.t_s, rtol=1e-6)
    est = odocal.calibrate(drive).estimate
    error = est.theta.as_array() - sim.true_parameters.as_array()
    assert all(est.identified)
    assert np.all(np.abs(error) < 4.0 * est.std), (error, est.std)
    assert abs(error[0]) < 0.001 and abs(error[2]) < 0.02


def test_a_missing_sample_is_still_a_gap_and_stamps_that_drift_are_named(
        white_drive: SimulatedDrive) -> None:
    cols = dict(white_drive.drive.columns())
    rng = np.random.default_rng(1)
    jittered = {**cols, "t": cols["t"] + rng.uniform(-0.002, 0.002, cols["t"].size)}
    dropped = {k: np.delete(v, 300) for k, v in jittered.items()}
    with pytest.raises(odocal.DataError, match=r"column t has a gap of 0\.0[45]\d* s at t=7\.4"):
        odocal.Drive.from_columns(dropped)
    burst = dict(cols)
    burst["t"] = cols["t"].copy()
    burst["t"][301:] -= 0.015                                  # one step of 10 ms
    with pytest.raises(odocal.DataError, match=r"column t has an irregular step of 0\.01 s"):
        odocal.Drive.from_columns(burst)
    # a logger whose step wanders by 3% over minutes: no uniform grid fits its stamps
    drifting = dict(cols)
    steps = 0.025 * (1.0 + 0.03 * np.sin(np.arange(cols["t"].size - 1) / 2000.0))
    drifting["t"] = np.concatenate([[0.0], np.cumsum(steps)])
    with pytest.raises(odocal.DataError,
                       match=r"column t drifts \d+\.\d+ s from a uniform step of 0\.025 s"):
        odocal.Drive.from_columns(drifting)


@pytest.mark.parametrize("c_e", [0.2, 0.33, 0.5])
def test_small_wheels_are_judged_with_their_stated_circumference(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], c_e: float) -> None:
    truth = Parameters(c_e=c_e, c_d=-0.001 * c_e, t_r=0.45, d=0.0001)
    sim = odocal.simulate(duration_s=300, seed=3, noise="white", theta=truth)
    path = tmp_path / "robot.parquet"
    odocal.save_drive(sim.drive, path)
    if np.percentile(sim.drive.n_rl, 99) > 40.0:                 # beyond a car's wheel
        with pytest.raises(odocal.DataError, match="a smaller wheel: state its circumference"):
            odocal.load_drive(path)
    assert odocal.load_drive(path, circumference_m=c_e).n_samples == sim.drive.n_samples
    stated = f"c_e={c_e * 1.02:.4f},t_r=0.47"
    code, out, err = run(capsys, "calibrate", str(path), "--datasheet", stated, "--out",
                         str(tmp_path / "r"), "--no-report", "-q")
    assert code == EXIT_OK, err
    result = odocal.io.json_files.read_json(tmp_path / "r" / "calibration.json")
    for name in ("c_e", "c_d", "t_r", "d"):
        error = abs(result["theta"][name] - truth.as_dict()[name])
        assert error < 4.0 * result["std"][name], (name, result["theta"][name])
    assert abs(result["theta"]["c_e"] / c_e - 1.0) < 1e-4
    # rad/s for rev/s is still a unit mistake for a wheel of that size
    radians = {**sim.drive.columns()}
    radians["n_rl"], radians["n_rr"] = radians["n_rl"] * 2 * np.pi, radians["n_rr"] * 2 * np.pi
    with pytest.raises(odocal.DataError, match=rf"looks like rad/s.*a wheel of {c_e:g} m"):
        odocal.Drive.from_columns(radians, circumference_m=c_e)
    # without a datasheet the drive is refused with the way out, in one line: on reading it
    # (rates no car's wheel turns at) or by the checks (the wheels' distance against the
    # reference's, judged with the placeholder car's wheel)
    code, out, err = run(capsys, "calibrate", str(path), "--out", str(tmp_path / "r2"), "-q")
    if np.percentile(sim.drive.n_rl, 99) > 40.0:
        assert code == EXIT_ERROR and "--datasheet c_e=" in err and len(err.splitlines()) == 1
    else:
        assert code == EXIT_FAILED and "--datasheet" in out and len(out.splitlines()) == 1


def test_a_datasheet_in_the_drives_metadata_states_the_wheel(white_drive: SimulatedDrive) -> None:
    cols = dict(white_drive.drive.columns())
    cols["n_rl"], cols["n_rr"] = cols["n_rl"] * 6.0, cols["n_rr"] * 6.0    # a 6x smaller wheel
    with pytest.raises(odocal.DataError, match="a car's wheel turns at most 40 rev/s"):
        odocal.Drive.from_columns(cols)
    drive = odocal.Drive.from_columns(cols, metadata={"datasheet": {"c_e": 0.33, "t_r": 1.5}})
    assert drive.metadata["datasheet"]["c_e"] == 0.33
