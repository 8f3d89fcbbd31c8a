"""The fleet catalog: what a row may say, and what it may not."""

from __future__ import annotations

from pathlib import Path

import pytest

from odocal.errors import DataError
from odocal.fleet.catalog import read_catalog


def _catalog(tmp_path: Path, header: str, row: str) -> Path:
    (tmp_path / "a.parquet").write_bytes(b"")
    path = tmp_path / "catalog.csv"
    path.write_text(f"{header}\n{row}\n")
    return path


@pytest.mark.parametrize(("column", "hint"), [("scene", "convert each"), ("Vehicle ", ""),
                                              ("odometer", ""), ("bad\x1bname", "")])
def test_a_column_odocal_does_not_know_is_refused_by_name(tmp_path: Path, column: str,
                                                          hint: str) -> None:
    path = _catalog(tmp_path, f"vehicle,path,time,{column}", "car1,a.parquet,2026-01-01,x")
    with pytest.raises(DataError) as err:
        read_catalog(path)
    text = str(err.value)
    assert "does not know" in text and "\n" not in text and "\x1b" not in text
    assert column.replace("\x1b", "\\x1b") in text
    assert hint in text


def test_every_documented_column_is_read(tmp_path: Path) -> None:
    path = _catalog(tmp_path, "vehicle,path,time,odometer_km,format,mapping,event",
                    "car1,a.parquet,2026-01-01T08:00:00,120.5,,,tyre change")
    [entry] = read_catalog(path)
    assert entry.vehicle == "car1" and entry.event == "tyre change"
