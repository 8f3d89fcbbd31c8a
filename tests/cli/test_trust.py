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


@pytest.mark.parametrize("how", ["cropped", "noisier", "resampled-start"])
def test_a_near_copy_is_named(drive: Path, tmp_path: Path, how: str) -> None:
    """The same recording cut shorter, with a little noise added, or starting a sample later:
    named as a copy of the other log, with the stretch they share."""
    rng = np.random.default_rng(5)
    if how == "cropped":
        d = odocal.load_drive(drive)
        cols = {k: np.asarray(v)[2000:12000] for k, v in d.columns().items()}
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
