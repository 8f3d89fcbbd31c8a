"""Real set-ups that used to be refused or misread (issue 32): a GNSS that gives positions only,
wheel tick counters that wrap, and a wheel clock offset found where the yaw rates do not agree."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
import pymap3d
import pytest

import odocal
from odocal.cli.main import EXIT_OK
from odocal.errors import ConfigError
from odocal.io.streams import Stream
from odocal.io.units import counter_modulus, wheel_rate_revps
from odocal.preprocess.align import estimate_wheel_offset
from odocal.preprocess.fusion import fuse
from odocal.settings import FusionSettings
from odocal.sim.simulate import SimulatedDrive
from tests.conftest import run

ORIGIN = (47.5, 19.0, 100.0)

GNSS_MAPPING = """
[wheels]
file = "wheels.csv"
time = "t"
rear_left = "rl"
rear_right = "rr"

[imu]
file = "imu.csv"
time = "t"
yaw_rate = "gz"
lateral_accel = "ay"

[gnss]
file = "gnss.csv"
time = "t"
latitude = "lat"
longitude = "lon"
"""


def write_navsatfix_setup(sim: SimulatedDrive, folder: Path, *, seed: int) -> list[Path]:
    """Wheels at 40 Hz, a biased noisy IMU at 100 Hz and a NavSatFix at 10 Hz (latitude and
    longitude with 0.5 m noise, no speed, no course), as three CSV files and a mapping."""
    rng = np.random.default_rng(seed)
    d, truth = sim.drive, sim.true_poses
    pacsv.write_csv(pa.table({"t": d.t, "rl": d.n_rl, "rr": d.n_rr}), folder / "wheels.csv")
    t_imu = np.arange(d.t[0], d.t[-1], 0.01)
    yaw = np.gradient(np.unwrap(truth[:, 2]), d.t_s)
    pacsv.write_csv(pa.table({
        "t": t_imu, "gz": np.interp(t_imu, d.t, yaw) + 0.003 + 0.01 * rng.standard_normal(
            t_imu.size),
        "ay": np.interp(t_imu, d.t, d.a_y)}), folder / "imu.csv")
    every = 4
    east = truth[::every, 0] + 0.5 * rng.standard_normal(truth[::every].shape[0])
    north = truth[::every, 1] + 0.5 * rng.standard_normal(truth[::every].shape[0])
    lat, lon, _ = pymap3d.enu2geodetic(east, north, np.zeros_like(east), *ORIGIN)
    pacsv.write_csv(pa.table({"t": d.t[::every], "lat": lat, "lon": lon}), folder / "gnss.csv")
    (folder / "map.toml").write_text(GNSS_MAPPING)
    return [folder / "wheels.csv", folder / "imu.csv", folder / "gnss.csv"]


def wrapped_heading_error(psi: np.ndarray, truth: np.ndarray) -> np.ndarray:
    return np.remainder(psi - truth + np.pi, 2 * np.pi) - np.pi


@pytest.mark.parametrize("seed", [4, 6])
def test_gnss_positions_only_with_imu_and_wheels_calibrate(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], seed: int) -> None:
    # each seed starts the route towards another heading (uniform in +-pi)
    sim = odocal.simulate(duration_s=420, seed=seed, noise="realistic")
    files = write_navsatfix_setup(sim, tmp_path, seed=seed)
    drive = odocal.convert("table", files, mapping=tmp_path / "map.toml")[0]
    truth = np.interp(drive.t, sim.drive.t, np.unwrap(sim.true_poses[:, 2]))
    error = wrapped_heading_error(drive.psi, truth)
    assert np.degrees(np.sqrt(np.mean(error**2))) < 1.0          # not 180 degrees off
    assert drive.metadata["conversion"]["reference"] == "gnss-imu"
    code, out, _ = run(capsys, "calibrate", "--from", "table", *map(str, files), "--mapping",
                       str(tmp_path / "map.toml"), "--datasheet", "c_e=1.95,t_r=1.5",
                       "--out", str(tmp_path / "r"), "--no-report", "-q")
    assert code == EXIT_OK, out
    result = odocal.io.json_files.read_json(tmp_path / "r" / "calibration.json")
    true = sim.true_parameters.as_dict()
    for name in ("c_e", "c_d", "t_r"):
        assert result["identified"][name]
        error_ = abs(result["theta"][name] - true[name])
        assert error_ < 4.0 * result["std"][name], (name, result["theta"][name], true[name])
    assert abs(result["theta"]["c_e"] - true["c_e"]) < 0.002
    assert abs(result["theta"]["t_r"] - true["t_r"]) < 0.02


def test_positions_only_starting_in_reverse_are_not_mirrored() -> None:
    """Leaving a parking space backwards: the first displacement points against the heading;
    the filter's mirror image (speed negative all drive long) is turned back."""
    dt, heading0 = 0.025, 0.7
    t = np.arange(0.0, 120.0, dt)
    speed = np.where(t < 5.0, -2.0, np.minimum(12.0, 2.0 * (t - 5.0)))
    yaw_rate = np.where((t > 30.0) & (t < 40.0), 0.15, 0.0) - np.where(
        (t > 60.0) & (t < 75.0), 0.1, 0.0)
    psi = heading0 + np.concatenate([[0.0], np.cumsum(yaw_rate[:-1]) * dt])
    x = np.concatenate([[0.0], np.cumsum(speed[:-1] * np.cos(psi[:-1])) * dt])
    y = np.concatenate([[0.0], np.cumsum(speed[:-1] * np.sin(psi[:-1])) * dt])
    rng = np.random.default_rng(3)
    fixes = np.arange(0, t.size, 4)
    fused = fuse(t, yaw_rate + 0.002, gnss_t=t[fixes],
                 east=x[fixes] + 0.3 * rng.standard_normal(fixes.size),
                 north=y[fixes] + 0.3 * rng.standard_normal(fixes.size), gnss_speed=None,
                 gnss_course=None, gnss_std=None, heading_t=None, heading=None,
                 settings=FusionSettings(), name="reverse")
    moving = t > 10.0
    error = wrapped_heading_error(fused.psi, psi)
    assert np.degrees(np.sqrt(np.mean(error[moving] ** 2))) < 1.0
    assert np.median(fused.speed[t < 4.0]) < -1.0                 # it did reverse first
    assert np.median(fused.speed[moving]) > 5.0


def counters(turns: np.ndarray, *, ticks_per_rev: int, bits: int, signed: bool,
             start: int) -> np.ndarray:
    """A ``bits``-wide tick counter of ``turns`` revolutions, as the unit reports it."""
    modulus = 2**bits
    count = np.mod(np.floor(turns * ticks_per_rev) + start, modulus)
    return np.where(count >= modulus // 2, count - modulus, count) if signed else count


@pytest.mark.parametrize("bits", [12, 16, 32])
@pytest.mark.parametrize("signed", [False, True])
def test_a_wrapping_tick_counter_is_unwrapped(bits: int, signed: bool) -> None:
    t = np.arange(0.0, 60.0, 0.01)
    rate = 8.0 + 4.0 * np.sin(0.2 * t)                           # rev/s
    turns = np.concatenate([[0.0], np.cumsum(rate[:-1]) * 0.01])
    top = 2 ** (bits - 1) if signed else 2**bits              # where it wraps
    ticks = counters(turns, ticks_per_rev=1024, bits=bits, signed=signed, start=top - 3000)
    assert np.any(np.abs(np.diff(ticks)) > 2 ** (bits - 1))      # it wrapped
    assert counter_modulus(ticks) == 2.0**bits
    got = wheel_rate_revps(ticks, "ticks", stream="w", t=t, ticks_per_rev=1024)
    # one tick of quantisation over a 10 ms step
    np.testing.assert_allclose(got[1:], rate[:-1], atol=1.0 / (1024 * 0.01) + 1e-9)


def test_counter_widths_that_are_not_recognised_are_stated() -> None:
    t = np.arange(0.0, 30.0, 0.02)
    turns = 5.0 * t
    ticks = counters(turns, ticks_per_rev=96, bits=10, signed=False, start=0)
    assert counter_modulus(ticks) is None or counter_modulus(ticks) != 2.0**10
    got = wheel_rate_revps(ticks, "ticks", stream="w", t=t, ticks_per_rev=96, counter_bits=10)
    np.testing.assert_allclose(np.mean(got[1:]), 5.0, rtol=0.002)
    assert np.max(np.abs(got)) < 10.0                             # no wrap left
    # a counter that never wraps is left alone, whatever its range
    for start in (0, 2**20, -(2**14)):
        plain = np.floor(turns[:200] * 96) + start
        assert counter_modulus(plain) is None


def test_a_bad_counter_width_is_named(tmp_path: Path) -> None:
    from odocal.io.mapping import check_mapping

    for bad in (0, 1, 64, 16.0, "16", True):
        with pytest.raises(ConfigError, match=r"counter_bits = .* integer from 2 to 52"):
            check_mapping({"wheels": {"file": "w.csv", "counter_bits": bad}})


TICK_MAPPING = """
[wheels]
file = "wheels.csv"
time = "t"
rear_left = "rl"
rear_right = "rr"
unit = "ticks"
ticks_per_rev = 96

[imu]
file = "imu.csv"
time = "t"
yaw_rate = "gz"
lateral_accel = "ay"

[pose]
file = "pose.csv"
time = "t"
x = "x"
y = "y"
heading = "yaw"
"""


@pytest.fixture(scope="module")
def reference_drive() -> SimulatedDrive:
    return odocal.simulate(duration_s=420, seed=3, noise="reference")


@pytest.mark.parametrize(("bits", "signed"), [(16, False), (16, True), (12, True)])
def test_wrapping_counters_calibrate_from_a_table(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], reference_drive: SimulatedDrive,
        bits: int, signed: bool) -> None:
    sim, d = reference_drive, reference_drive.drive
    turns = [np.concatenate([[0.0], np.cumsum(n[:-1]) * d.t_s])
             for n in (sim.true_n_rl, sim.true_n_rr)]
    pacsv.write_csv(pa.table({
        "t": d.t,
        "rl": counters(turns[0], ticks_per_rev=96, bits=bits, signed=signed,
                       start=2 ** (bits - 1) - 77),
        "rr": counters(turns[1], ticks_per_rev=96, bits=bits, signed=signed, start=1234)}),
        tmp_path / "wheels.csv")
    pacsv.write_csv(pa.table({"t": d.t, "gz": d.yaw_rate, "ay": d.a_y}), tmp_path / "imu.csv")
    pacsv.write_csv(pa.table({"t": d.t, "x": d.x, "y": d.y, "yaw": d.psi}), tmp_path / "pose.csv")
    (tmp_path / "map.toml").write_text(TICK_MAPPING)
    files = [str(tmp_path / f) for f in ("wheels.csv", "imu.csv", "pose.csv")]
    code, out, _ = run(capsys, "inspect", "--from", "table", *files, "--mapping",
                       str(tmp_path / "map.toml"))
    wraps = int(turns[0][-1] * 96 // 2**bits)
    assert code == EXIT_OK and f"{bits}-bit counter" in out
    assert f"{wraps} wraps undone" in out or f"{wraps + 1} wraps undone" in out
    drive = odocal.convert("table", files, mapping=tmp_path / "map.toml")[0]
    offset = drive.metadata["conversion"]["wheel_offset"]
    assert abs(offset["offset_s"]) < 0.03                          # no -174 ms shift
    code, out, _ = run(capsys, "calibrate", "--from", "table", *files, "--mapping",
                       str(tmp_path / "map.toml"), "--datasheet", "c_e=1.95,t_r=1.5",
                       "--out", str(tmp_path / "r"), "--no-report", "-q")
    assert code == EXIT_OK, out
    result = odocal.io.json_files.read_json(tmp_path / "r" / "calibration.json")
    true = sim.true_parameters.as_dict()
    assert abs(result["theta"]["c_e"] - true["c_e"]) < 0.001
    assert abs(result["theta"]["c_d"] - true["c_d"]) < 0.0002
    assert abs(result["theta"]["t_r"] - true["t_r"]) < 0.01


@pytest.mark.parametrize("corrupt", ["noise", "spikes", "another drive"])
def test_no_wheel_clock_offset_from_yaw_rates_that_do_not_agree(
        reference_drive: SimulatedDrive, corrupt: str) -> None:
    d = reference_drive.drive
    rng = np.random.default_rng(5)
    if corrupt == "noise":
        rl, rr = d.n_rl + rng.standard_normal(d.n_samples), d.n_rr + rng.standard_normal(
            d.n_samples)
    elif corrupt == "spikes":                  # what an unwrapped counter turns into
        rl, rr = d.n_rl.copy(), d.n_rr.copy()
        rl[rng.choice(d.n_samples, 40, replace=False)] -= 6000.0
    else:
        other = odocal.simulate(duration_s=420, seed=9, noise="none").drive
        rl, rr = other.n_rl, other.n_rr
    wheels = Stream("wheels", "wheels", d.t.copy(), {"n_rl": rl, "n_rr": rr})
    imu = Stream("imu", "imu", d.t.copy(), {"yaw_rate": d.yaw_rate, "a_y": d.a_y})
    found = estimate_wheel_offset(wheels, imu, theta=(2.0, 0.0, 1.6, 0.0),
                                  max_offset_s=0.5)
    assert not found.estimated and found.offset_s == 0.0
    assert found.correlation < 0.3 and "no offset applied" in found.message
    # the clean wheels give their offset (half a sample: rates act over the step)
    clean = Stream("wheels", "wheels", d.t.copy(), {"n_rl": d.n_rl, "n_rr": d.n_rr})
    good = estimate_wheel_offset(clean, imu, theta=(2.0, 0.0, 1.6, 0.0),
                                 max_offset_s=0.5)
    assert good.estimated and good.correlation > 0.9
    assert good.offset_s == pytest.approx(d.t_s / 2, abs=0.005)


@pytest.mark.parametrize("time_unit", [None, "datetime", "s"])
def test_table_streams_stamped_with_date_times(tmp_path: Path, short_drive: SimulatedDrive,
                                               time_unit: str | None) -> None:
    d = short_drive.drive
    epoch_us = np.round((1_754_000_000.0 + d.t) * 1e6).astype(np.int64)
    iso = [str(s) + "Z" for s in epoch_us.astype("datetime64[us]")]
    pacsv.write_csv(pa.table({"stamp": iso, "rl": d.n_rl, "rr": d.n_rr}), tmp_path / "w.csv")
    import pyarrow.parquet as pq

    pq.write_table(pa.table({"t": pa.array(epoch_us * 1000, type=pa.timestamp("ns")),
                             "gz": d.yaw_rate, "ay": d.a_y}), tmp_path / "imu.parquet")
    pacsv.write_csv(pa.table({"t": 1_754_000_000.0 + d.t, "x": d.x, "y": d.y, "yaw": d.psi}),
                    tmp_path / "pose.csv")
    unit = "" if time_unit is None else f'time_unit = "{time_unit}"\n'
    mapping = {"wheels": {"file": "w.csv", "time": "stamp", "rear_left": "rl",
                          "rear_right": "rr"},
               "imu": {"file": "imu.parquet", "time": "t", "yaw_rate": "gz",
                       "lateral_accel": "ay"},
               "pose": {"file": "pose.csv", "time": "t", "x": "x", "y": "y", "heading": "yaw"}}
    text = "\n".join(f"[{role}]\n" + "".join(f'{k} = "{v}"\n' for k, v in keys.items())
                     + (unit if role != "pose" else "") for role, keys in mapping.items())
    (tmp_path / "map.toml").write_text(text)
    files = [tmp_path / "w.csv", tmp_path / "imu.parquet", tmp_path / "pose.csv"]
    settings = odocal.Settings().replace(convert={"wheel_offset": "off"})
    back = odocal.convert("table", files, mapping=tmp_path / "map.toml", settings=settings)[0]
    np.testing.assert_allclose(back.t - 1_754_000_000.0, d.t[:back.n_samples], atol=1e-5)
    np.testing.assert_allclose(back.n_rl, d.n_rl[:back.n_samples], atol=1e-4)
    np.testing.assert_allclose(back.a_y, d.a_y[:back.n_samples], atol=1e-4)
    # a unit stated for a date-time column is a mistake, named
    (tmp_path / "map.toml").write_text(text.replace(unit, "").replace(
        'time = "stamp"\n', 'time = "stamp"\ntime_unit = "ns"\n'))
    with pytest.raises(ConfigError, match=r"\[wheels\] time column 'stamp' of 'w.csv' holds "
                                          r"date-times.*drop time_unit = 'ns'"):
        odocal.convert("table", files, mapping=tmp_path / "map.toml")
