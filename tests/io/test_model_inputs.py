"""The four-wheel model's further inputs (issue 37): nuScenes and comma2k19 read all four wheels
and the steering-wheel angle; the drive carries them through conversion, cutting and its file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from odocal.data.drive import MODEL_INPUTS, Drive
from odocal.errors import DataError
from odocal.io.drivefile import load_drive, save_drive
from odocal.preprocess.convert import convert
from odocal.settings import Settings


def _moving(d: Drive) -> np.ndarray:
    return 0.5 * np.abs(d.n_rl + d.n_rr) > 1.0


def test_nuscenes_reads_the_front_wheels_and_the_steering(shared_data: Path) -> None:
    """The Zoe's front wheels turn as its rear ones within a percent, and its steering-wheel
    angle follows the curvature the reference drives (correlation above 0.8 in every moving
    scene)."""
    drives = [d for d in convert("nuscenes", [shared_data / "nuscenes-can-bus-mini"])
              if _moving(d).sum() > 100]
    assert len(drives) >= 5
    for d in drives:
        assert set(d.inputs) == set(MODEL_INPUTS)
        moving = _moving(d)
        front = d.inputs["n_fl"] + d.inputs["n_fr"]
        assert np.median(front[moving] / (d.n_rl + d.n_rr)[moving]) == pytest.approx(1.0, abs=0.01)
        curvature = d.yaw_rate / np.maximum(0.5 * np.abs(d.n_rl + d.n_rr) * 1.93, 0.5)
        assert np.corrcoef(d.inputs["steer"][moving], curvature[moving])[0, 1] > 0.8, d.name
        # the steering-wheel angle is in radians: a city drive's stays within two turns
        assert np.max(np.abs(d.inputs["steer"])) < 4 * np.pi


def test_comma2k19_reads_the_front_wheels_and_the_steering(shared_data: Path) -> None:
    seg = shared_data / "comma2k19-example" / "2018-08-02--08-34-47" / "40"
    d = convert("comma2k19", [seg], settings=Settings().replace(
        convert={"wheel_circumference_m": 1.0}))[0]
    assert set(d.inputs) == set(MODEL_INPUTS)
    moving = _moving(d)
    front = d.inputs["n_fl"] + d.inputs["n_fr"]
    assert np.median(front[moving] / (d.n_rl + d.n_rr)[moving]) == pytest.approx(1.0, abs=0.01)
    assert 0.01 < np.max(np.abs(d.inputs["steer"])) < 0.2     # a highway's few degrees


def test_the_inputs_follow_the_drive_through_cuts_and_its_file(shared_data: Path,
                                                               tmp_path: Path) -> None:
    d = convert("nuscenes", [shared_data / "nuscenes-can-bus-mini"], scenes=["scene-0061"])[0]
    later = d.since(float(d.t[100]))
    np.testing.assert_array_equal(later.inputs["steer"], d.inputs["steer"][100:])
    kept = d.select(np.arange(d.n_samples) % 2 == 0)
    np.testing.assert_array_equal(kept.inputs["n_fl"], d.inputs["n_fl"][::2])
    path = save_drive(d, tmp_path / "zoe.parquet")
    back = load_drive(path)
    for key in MODEL_INPUTS:
        np.testing.assert_allclose(back.inputs[key], d.inputs[key], rtol=1e-12)
    with pytest.raises(DataError, match="must hold"):
        Drive(**{**_fields(d), "inputs": {"steer": d.inputs["steer"][:-1]}})
    with pytest.raises(DataError, match="not an input odocal knows"):
        Drive(**{**_fields(d), "inputs": {"n_fx": d.inputs["steer"]}})


def test_a_steering_angle_in_degrees_is_named_as_a_unit_mistake_and_left_out() -> None:
    """Beyond any car's steering (15 rad): named as a unit mistake and left out of the drive
    (the rear axle never reads it; the four-wheel model then calibrates without it)."""
    t = np.arange(0.0, 60.0, 0.02)
    cols = {"t": t, "n_rl": np.full(t.size, 5.0), "n_rr": np.full(t.size, 5.0),
            "a_y": np.zeros(t.size), "x": 10.0 * t, "y": np.zeros(t.size),
            "psi": np.zeros(t.size), "steer": 90.0 * np.sin(0.1 * t)}
    degrees = Drive.from_columns(cols, name="degrees")
    assert "steer" not in degrees.inputs
    said = list(degrees.metadata["left_out"])
    assert len(said) == 1 and "column steer reaches 90 rad, beyond any car" in said[0]
    assert "left out" in said[0]
    cols["steer"] = np.deg2rad(cols["steer"])
    assert Drive.from_columns(cols, name="radians").inputs["steer"].max() == pytest.approx(
        np.pi / 2, rel=1e-3)


def _fields(d: Drive) -> dict:
    import dataclasses

    return {f.name: getattr(d, f.name) for f in dataclasses.fields(d)}
