"""Issue 40, "Trust, round three": no secret in any line or file, the same data never counted
twice, and errors that name where."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import odocal
from odocal.io import save_drive
from tests.conftest import run

SECRET = "SIGs3cr3tVALUE"
TOKEN = "TOKt0k3nVALUE"


def _everything(out: str, err: str, *folders: Path) -> str:
    texts = [out, err]
    for folder in folders:
        texts += [p.read_bytes().decode("latin-1") for p in folder.rglob("*") if p.is_file()]
    return "\n".join(texts)


# ---------------------------------------------------------------- secrets

def test_a_query_in_a_local_name_is_in_no_line_or_file(tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]
                                                      ) -> None:
    """A drive saved under a name that carries a pre-signed query (as a download tool leaves
    it): calibrate, replay and validate print and write the name without it."""
    name = tmp_path / f"d.parquet?X-Amz-Signature={SECRET}&X-Amz-Security-Token={TOKEN}"
    save_drive(odocal.simulate(duration_s=300.0, seed=9, noise="white").drive,
               tmp_path / "x.parquet")
    (tmp_path / "x.parquet").rename(name)
    code, out, err = run(capsys, "calibrate", str(name), "--out", str(tmp_path / "c"),
                         "--export", "yaml,tum,autoware")
    assert code == 0, err
    text = _everything(out, err, tmp_path / "c")
    code, out, err = run(capsys, "replay", str(name), "--out", str(tmp_path / "r"))
    assert code == 0, err
    text += _everything(out, err, tmp_path / "r")
    code, out, err = run(capsys, "validate", str(name))
    text += out + err
    code, out, err = run(capsys, "calibrate", str(name) + ".missing", "--out",
                         str(tmp_path / "m"))
    assert code == 1 and "does not exist" in err
    text += out + err
    assert SECRET not in text and TOKEN not in text
    assert "d.parquet" in text


def test_a_token_in_a_urls_user_part_is_in_no_line(tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = run(capsys, "calibrate", f"https://{TOKEN}@127.0.0.1:9/x.parquet"
                         f"?sig={SECRET}#frag", "--out", str(tmp_path / "o"), "-v")
    assert code == 1 and "https://127.0.0.1:9/x.parquet" in err
    assert SECRET not in out + err and TOKEN not in out + err


# ---------------------------------------------------------------- the same drive twice

@pytest.fixture(scope="module")
def drive(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("same") / "drive.parquet"
    save_drive(odocal.simulate(duration_s=420.0, seed=31, noise="realistic").drive, path)
    return path


def _copy_with(drive: Path, target: Path, **change: object) -> Path:
    d = odocal.load_drive(drive)
    cols = {k: np.asarray(v).copy() for k, v in d.columns().items()}
    for key, value in change.items():
        cols[key] = value(cols) if callable(value) else value
    save_drive(odocal.Drive.from_columns(cols, name=target.stem), target)
    return target


def test_the_same_samples_as_parquet_and_csv_are_one_drive(drive: Path, tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]
                                                          ) -> None:
    """Other bytes, the same samples: refused as the same drive, by name (on main: two drives,
    every standard deviation 1.43 times too small)."""
    csv = tmp_path / "drive.csv"
    save_drive(odocal.load_drive(drive), csv)
    code, _, err = run(capsys, "calibrate", str(drive), str(csv), "--out",
                         str(tmp_path / "o"))
    assert code == 1 and len(err.strip().splitlines()) == 1, err
    assert "the same drive" in err and "drive.parquet" in err and "drive.csv" in err
    assert not (tmp_path / "o").exists()


def test_a_copy_with_its_clock_shifted_is_the_same_drive(drive: Path, tmp_path: Path) -> None:
    shifted = _copy_with(drive, tmp_path / "shifted.parquet", t=lambda c: c["t"] + 5000.0)
    with pytest.raises(odocal.DataError, match=r"shifted\.parquet' are the same drive"):
        odocal.calibrate([drive, shifted])


@pytest.mark.parametrize("how", ["cropped", "middle", "noisier", "resampled-start"])
def test_a_near_copy_is_named(drive: Path, tmp_path: Path, how: str) -> None:
    """The same recording cut shorter, with a little noise added, or starting a sample later:
    named as a copy of the other log, with the stretch they share."""
    rng = np.random.default_rng(5)
    if how in ("cropped", "middle"):
        d = odocal.load_drive(drive)
        cut = slice(2000, 12000) if how == "cropped" else slice(5600, 11200)
        cols = {k: np.asarray(v)[cut] for k, v in d.columns().items()}
        near = tmp_path / "near.parquet"
        save_drive(odocal.Drive.from_columns(cols, name="near"), near)
    elif how == "noisier":
        near = _copy_with(drive, tmp_path / "near.parquet",
                          n_rl=lambda c: c["n_rl"] + 0.002 * rng.standard_normal(c["t"].size),
                          n_rr=lambda c: c["n_rr"] + 0.002 * rng.standard_normal(c["t"].size))
    else:
        d = odocal.load_drive(drive)
        cols = {k: np.asarray(v)[1:] for k, v in d.columns().items()}
        cols["t"] = cols["t"] + 100.0
        near = tmp_path / "near.parquet"
        save_drive(odocal.Drive.from_columns(cols, name="near"), near)
    with pytest.raises(odocal.DataError, match=r"near\.parquet.*drive\.parquet|drive\.parquet.*"
                                               r"near\.parquet") as info:
        odocal.calibrate([drive, near])
    assert "copy" in str(info.value) or "same drive" in str(info.value)


def test_one_log_holding_a_run_of_samples_twice_is_named(drive: Path) -> None:
    """Two pieces of one file with the same samples (found by the hostile run: on main one
    file could not be a copy of anything)."""
    d = odocal.load_drive(drive)
    cols = {k: np.asarray(v) for k, v in d.columns().items()}
    n = cols["t"].size
    twice = {k: np.concatenate([v, v + (cols["t"][-1] + 100.0 if k == "t" else 0.0)])
             for k, v in cols.items()}
    twice["piece"] = np.concatenate([np.zeros(n), np.ones(n)])
    with pytest.raises(odocal.DataError, match=r"'twice' holds one run of samples twice \(its "
                                               r"pieces 1 and 2\)"):
        odocal.calibrate(odocal.Drive.from_columns(twice, name="twice"))


def test_two_drives_of_one_car_are_not_copies(tmp_path: Path) -> None:
    """Two drives of the same car on the same kind of roads (the same simulator, other seeds)
    and two drives that both start parked: not copies."""
    a = tmp_path / "a.parquet"
    b = tmp_path / "b.parquet"
    save_drive(odocal.simulate(duration_s=300.0, seed=1, noise="realistic").drive, a)
    save_drive(odocal.simulate(duration_s=300.0, seed=2, noise="realistic").drive, b)
    result = odocal.calibrate([a, b])
    assert len(result.drives) == 2


def test_the_results_say_nothing_of_copies_for_one_drive(drive: Path, tmp_path: Path,
                                                         capsys: pytest.CaptureFixture[str]
                                                         ) -> None:
    code, _, err = run(capsys, "calibrate", str(drive), "--out", str(tmp_path / "o"), "-q",
                       "--no-report")
    assert code == 0, err
    assert json.loads((tmp_path / "o" / "calibration.json").read_text())["theta"]


def test_a_log_with_swapped_wheels_beside_a_good_one_is_named(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Its wheels turn against its reference, the good log's with it: pooled they looked like
    no differential information (on main: c_e alone, exit 0, no log named)."""
    good = tmp_path / "good.parquet"
    save_drive(odocal.simulate(duration_s=600.0, seed=41, noise="realistic").drive, good)
    other = tmp_path / "other.parquet"
    save_drive(odocal.simulate(duration_s=600.0, seed=40, noise="realistic").drive, other)
    d = odocal.load_drive(other)
    swapped = _copy_with(other, tmp_path / "swapped.parquet", n_rl=d.n_rr.copy(),
                         n_rr=d.n_rl.copy())
    code, out, err = run(capsys, "calibrate", str(good), str(swapped), "--out",
                         str(tmp_path / "o"), "--no-report")
    assert code == 3, out + err
    assert "the wheels of '" + str(swapped) + "' imply turns against" in out
    assert "no differential information" not in out
    assert str(good) + "' imply" not in out


def test_a_relative_output_folder_is_named_as_it_ends_up(tmp_path: Path, drive: Path,
                                                        monkeypatch: pytest.MonkeyPatch,
                                                        capsys: pytest.CaptureFixture[str]
                                                        ) -> None:
    """'wrote' names the files where they are after the run (on main, with a relative --out:
    'wrote rel/.rel.PID.xxx.part/calibration.json', the temporary folder's path)."""
    monkeypatch.chdir(tmp_path)
    code, out, err = run(capsys, "calibrate", str(drive), "--out", "rel", "--export", "yaml")
    assert code == 0, err
    wrote = [line.removeprefix("wrote ") for line in out.splitlines()
             if line.startswith("wrote ")]
    assert "rel/calibration.json" in wrote and len(wrote) >= 3
    assert all((tmp_path / w).is_file() for w in wrote), wrote


# ---------------------------------------------------------------- errors that name where

@pytest.fixture(scope="module")
def columns() -> dict[str, np.ndarray]:
    """A ten-minute drive's columns, to break."""
    d = odocal.simulate(duration_s=600.0, seed=7, noise="realistic").drive
    return {k: np.asarray(v).copy() for k, v in d.columns().items() if k != "yaw_rate"}


def _write(path: Path, cols: dict[str, np.ndarray], types: dict[str, object] | None = None
           ) -> Path:
    import pyarrow as pa
    import pyarrow.parquet as pq

    pq.write_table(pa.table({k: pa.array(v, type=(types or {}).get(k))
                             for k, v in cols.items()}), path)
    return path


@pytest.mark.parametrize(("break_", "words"), [
    ("nan", ["column n_rl holds 1 NaN or infinite values", "first at row 5001, t=125"]),
    ("duplicate", ["column t is not strictly increasing", "at row 6001"]),
    ("too fast", ["column n_rl reaches 2621", "first beyond 100 at row 7001, t=175"]),
])
def test_replays_data_errors_name_the_log_the_row_and_the_time(
        columns: dict[str, np.ndarray], tmp_path: Path, capsys: pytest.CaptureFixture[str],
        break_: str, words: list[str]) -> None:
    """As batch names them (on main: "pushed column n_rl holds NaN or infinite values", no
    file, row or time)."""
    cols = {k: v.copy() for k, v in columns.items()}
    if break_ == "nan":
        cols["n_rl"][5000] = np.nan
    elif break_ == "duplicate":
        cols["t"][6000] = cols["t"][5999]
    else:
        cols["n_rl"][7000:7100] = 2621.0
    path = _write(tmp_path / "log.parquet", cols)
    code, _, err = run(capsys, "replay", str(path), "--out", str(tmp_path / "o"), "-q")
    assert code == 1 and len(err.strip().splitlines()) == 1, err
    assert f"'{path}'" in err and "pushed" not in err
    assert all(w in err for w in words), err
    if break_ == "too fast":                     # batch names the burst too (it blamed the sync)
        code, _, err = run(capsys, "calibrate", str(path), "--out", str(tmp_path / "b"), "-q")
        assert code == 1 and "column n_rl reaches 2621 rev/s (first at t=175.000 s" in err


@pytest.mark.parametrize(("break_", "words", "not_words"), [
    ("held 1 Hz", ["columns x, y stay the same", "(it changes every 1 s, 1 Hz)",
                   "held between the updates"], ["pose jumps by"]),
    ("10 then 40 Hz", ["steps 0.1 s (10 Hz) from t=0.000 s to t=39.900 s",
                       "0.025 s (40 Hz) elsewhere", "changes its rate"], ["a gap"]),
    ("epoch float32", ["holds times near 1.7e+09 with 32-bit precision",
                       "steps by 128 s there"], ["sort the log"]),
    ("noisy heading", ["rad per sample", "radians, not degrees", "noisy or jumps"],
     ["in degrees?"]),
    ("10 s", ["holds 401 samples (10.0 s)", "takes 651 samples (16.2 s at 40 Hz"],
     ["K = "]),
])
def test_a_broken_log_is_told_as_what_it_is(columns: dict[str, np.ndarray], tmp_path: Path,
                                            capsys: pytest.CaptureFixture[str], break_: str,
                                            words: list[str], not_words: list[str]) -> None:
    """(on main: a pose jump; a gap of 0.1 s at t=0.000 s; "sort the log or drop duplicate
    stamps"; "is it in degrees?" for radians; "K = 650 steps")"""
    import pyarrow as pa

    cols = {k: v.copy() for k, v in columns.items()}
    types: dict[str, object] = {}
    if break_ == "held 1 Hz":
        held = (np.arange(cols["t"].size) // 40) * 40
        for k in ("x", "y", "psi"):
            cols[k] = cols[k][held]
    elif break_ == "10 then 40 Hz":
        slow = np.arange(400) * 0.1
        fast = slow[-1] + 0.025 * (1 + np.arange(cols["t"].size - 1600))
        t = np.concatenate([slow, fast])
        cols = {k: np.interp(t, columns["t"], v) for k, v in columns.items()}
    elif break_ == "epoch float32":
        cols["t"] = (1.7e9 + cols["t"]).astype(np.float32)
        types["t"] = pa.float32()
    elif break_ == "noisy heading":
        cols["psi"] = cols["psi"] + np.random.default_rng(0).normal(0, 0.2, cols["t"].size)
    else:
        cols = {k: v[:401] for k, v in cols.items()}
    path = _write(tmp_path / "log.parquet", cols, types)
    code, out, err = run(capsys, "calibrate", str(path), "--out", str(tmp_path / "o"))
    said = out + err
    lines = [line for line in err.strip().splitlines() if not line.startswith("[")]
    assert code == 1 and len(lines) == 1, said                   # (progress lines aside)
    assert all(w in said for w in words), said
    assert not any(w in said for w in not_words), said


def test_wheel_rates_with_a_flipped_sign_are_called_so(columns: dict[str, np.ndarray],
                                                      tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]
                                                      ) -> None:
    """(on main: "a wrong wheel-speed unit or scale", and numpy's RuntimeWarning)"""
    import warnings

    cols = {k: v.copy() for k, v in columns.items()}
    cols["n_rl"], cols["n_rr"] = -cols["n_rl"], -cols["n_rr"]
    path = _write(tmp_path / "log.parquet", cols)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        code, out, err = run(capsys, "calibrate", str(path), "--out", str(tmp_path / "o"),
                             "--no-report")
    assert code == 3, out + err
    assert "the wheel rates' sign is flipped" in out and "unit or scale" not in out
    assert "RuntimeWarning" not in err


def test_an_hour_parked_with_a_jittering_pose_adds_no_distance(
        columns: dict[str, np.ndarray], tmp_path: Path) -> None:
    """An hour parked, 2 cm of pose noise at 40 Hz, then the drive: the distance is the
    drive's (on main: 11.34 km for 6.24 km)."""
    drive = odocal.Drive.from_columns(columns)
    parked = int(3600 / drive.t_s)
    rng = np.random.default_rng(1)
    cols = {"t": np.concatenate([np.arange(parked) * drive.t_s,
                                 parked * drive.t_s + columns["t"]])}
    for k in ("n_rl", "n_rr", "a_y", "beta"):
        cols[k] = np.concatenate([np.zeros(parked), columns[k]])
    for k in ("x", "y"):
        cols[k] = np.concatenate([columns[k][0] + 0.02 * rng.standard_normal(parked),
                                  columns[k]])
    cols["psi"] = np.concatenate([np.full(parked, columns["psi"][0]), columns["psi"]])
    with_parking = odocal.Drive.from_columns(cols)
    assert with_parking.distance_m == pytest.approx(drive.distance_m, rel=0.002)
    assert drive.distance_m == pytest.approx(5560.0, rel=0.01)


def test_c_d_drift_is_told_in_mm_with_its_share_of_c_e() -> None:
    """(on main: "c_d fell 4.00% (78.20 mm)", the 4% a share of c_e)"""
    import datetime as dt

    from odocal.fleet.drift import analyse
    from odocal.settings import FleetSettings

    rng = np.random.default_rng(0)
    rows = []
    t0 = dt.datetime(2026, 1, 1, tzinfo=dt.UTC)
    for i in range(30):
        c_d = rng.normal(0.0, 2e-4) - (0.0782 if i >= 17 else 0.0)
        row: dict[str, object] = {"task_key": f"k{i:04d}", "vehicle": "v",
                                  "time": (t0 + dt.timedelta(days=i)).isoformat(),
                                  "odometer_km": None, "distance_km": 20.0, "success": 1,
                                  "event": None}
        for n, value in (("c_e", 1.955), ("c_d", c_d), ("t_r", 1.5), ("d", 0.0)):
            row[n], row[f"{n}_std"], row[f"{n}_identified"] = value, 2e-4, 1
        rows.append(row)
    alarms = [a for a in analyse(rows, FleetSettings()).alarms if a.parameter == "c_d"]
    assert len(alarms) == 1
    assert "c_d fell 78.1" in alarms[0].message and "% of c_e)" in alarms[0].message


def test_wheels_that_read_nothing_while_the_reference_drives_are_named(
        columns: dict[str, np.ndarray], tmp_path: Path,
        capsys: pytest.CaptureFixture[str]) -> None:
    """Both wheel columns zero, the reference driving 5.5 km (found by the hostile run: on main
    "the vehicle does not move ... nothing to calibrate", exit 0)."""
    cols = {k: v.copy() for k, v in columns.items()}
    cols["n_rl"] = np.zeros_like(cols["n_rl"])
    cols["n_rr"] = np.zeros_like(cols["n_rr"])
    path = _write(tmp_path / "log.parquet", cols)
    code, out, _ = run(capsys, "calibrate", str(path), "--out", str(tmp_path / "o"),
                       "--no-report")
    assert code == 3 and "the wheels read no motion while the reference travels (5.5" in out
    assert "does not move" not in out
