"""The drive type and the drive format: every bad input gets a clear DataError."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from odocal.data.drive import Drive
from odocal.errors import DataError, InputFileError
from odocal.io import load_drive, save_drive
from odocal.sim.simulate import SimulatedDrive


@pytest.fixture()
def columns(clean_drive: SimulatedDrive) -> dict[str, np.ndarray]:
    return {k: v.copy() for k, v in clean_drive.drive.columns().items()}


def test_round_trip_keeps_everything(clean_drive: SimulatedDrive, tmp_path: Path) -> None:
    for suffix in (".csv", ".parquet"):
        path = tmp_path / f"drive{suffix}"
        save_drive(clean_drive.drive, path)
        back = load_drive(path)
        for key, values in clean_drive.drive.columns().items():
            np.testing.assert_array_equal(back.columns()[key], values, err_msg=key)
        assert back.t_s == clean_drive.drive.t_s
        assert len(back.metadata["sha256"]) == 64


def test_optional_columns_default(columns: dict[str, np.ndarray]) -> None:
    del columns["beta"], columns["yaw_rate"]
    drive = Drive.from_columns(columns, name="x")
    assert np.all(drive.beta == 0.0)
    np.testing.assert_allclose(drive.yaw_rate, np.gradient(drive.psi, drive.t_s))


def test_wrapped_heading_is_unwrapped(columns: dict[str, np.ndarray]) -> None:
    columns["psi"] = np.remainder(columns["psi"] + np.pi, 2 * np.pi) - np.pi
    drive = Drive.from_columns(columns)
    assert np.abs(np.diff(drive.psi)).max() < 0.1


def test_arrays_are_read_only(clean_drive: SimulatedDrive) -> None:
    with pytest.raises(ValueError):
        clean_drive.drive.n_rl[0] = 1.0


@pytest.mark.parametrize(("change", "message"), [
    (lambda c: c.pop("n_rr"), r"'bad' lacks column n_rr"),
    (lambda c: (c.pop("x"), c.pop("y")), r"lacks columns x, y"),
    (lambda c: c["n_rl"].__setitem__(slice(100, 112), np.nan),
     r"column n_rl contains 12 NaN or infinite values \(first at t=2.500 s\)"),
    (lambda c: c["a_y"].__setitem__(5, np.inf), r"column a_y contains 1 NaN"),
    (lambda c: c["t"].__setitem__(50, c["t"][48]), r"column t is not strictly increasing"),
    (lambda c: c["t"].__setitem__(slice(300, None), c["t"][300:] + 0.5),
     r"column t has a gap of 0.525 s at t=7.475 s"),
    (lambda c: c["t"].__setitem__(slice(None), c["t"] * 1000), r"t must be in seconds .*milli"),
    (lambda c: (c["n_rl"].__imul__(60), c["n_rr"].__imul__(60)),
     r"n_rl reaches .*rev/s \(it looks like rpm"),
    (lambda c: c["psi"].__imul__(180 / np.pi), r"psi must be in radians"),
    (lambda c: c["yaw_rate"].__imul__(180 / np.pi), r"yaw_rate must be in rad/s"),
    (lambda c: (c["x"].__imul__(1e-5), c["y"].__imul__(1e-5)),
     r"x and y must be metres in a local planar frame"),
])
def test_bad_columns_are_named(columns: dict[str, np.ndarray], change: object,
                               message: str) -> None:
    change(columns)  # type: ignore[operator]
    with pytest.raises(DataError, match=message):
        Drive.from_columns(columns, name="bad")


def test_empty_and_short_inputs(tmp_path: Path) -> None:
    empty = tmp_path / "empty.csv"
    empty.write_text("")
    with pytest.raises(DataError, match=r"'.*empty.csv' is empty"):
        load_drive(empty)
    header = tmp_path / "header.csv"
    header.write_text("t,n_rl,n_rr,a_y,x,y,psi\n")
    with pytest.raises(DataError, match="has no rows"):
        load_drive(header)
    with pytest.raises(InputFileError, match="does not exist"):
        load_drive(tmp_path / "missing.csv")
    wrong = tmp_path / "drive.txt"
    wrong.write_text("t\n1\n")
    with pytest.raises(DataError, match=r"unknown file type '\.txt'"):
        load_drive(wrong)


def test_non_numeric_and_corrupt_files(tmp_path: Path, clean_drive: SimulatedDrive) -> None:
    path = tmp_path / "d.csv"
    save_drive(clean_drive.drive, path)
    text = path.read_text().splitlines()
    fields = text[5].split(",")
    fields[1] = "fast"
    text[5] = ",".join(fields)
    path.write_text("\n".join(text) + "\n")
    with pytest.raises(DataError, match="column n_rl holds a non-numeric value 'fast'"):
        load_drive(path)
    corrupt = tmp_path / "d.parquet"
    corrupt.write_bytes(b"PAR1 this is not parquet")
    with pytest.raises(DataError, match="cannot be read as PARQUET"):
        load_drive(corrupt)


def test_piece_column_allows_gaps(columns: dict[str, np.ndarray]) -> None:
    columns["t"][5000:] += 12.0
    columns["piece"] = (np.arange(columns["t"].size) >= 5000).astype(float)
    drive = Drive.from_columns(columns)
    assert drive.pieces == ((0, 5000), (5000, columns["t"].size))
    assert drive.duration_s == pytest.approx((columns["t"].size - 2) * 0.025)


def test_save_refuses_unknown_suffix(clean_drive: SimulatedDrive, tmp_path: Path) -> None:
    with pytest.raises(DataError, match="unknown file type"):
        save_drive(clean_drive.drive, tmp_path / "drive.xlsx")
