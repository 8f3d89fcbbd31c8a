"""Real drives, held out (issue 23): what each log identifies, two cars never averaged."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import odocal
from odocal.checks.findings import Check
from odocal.cli.main import EXIT_FAILED, main
from odocal.data.segments import gather_ragged, identification_segments
from odocal.estimators.estimate import Status
from odocal.estimators.validation import segment_errors
from odocal.preprocess.convert import convert
from odocal.settings import SegmentSettings, Settings

SINGAPORE = ("scene-0061", "scene-0796", "scene-0916", "scene-1077", "scene-1100")
BOSTON = ("scene-0103", "scene-0655")
#: 20 s scenes: validation segments of 80 m fit in them (the validation decides the gate only)
SHORT = Settings().replace(segments={"validation_distance_m": 80.0})


@pytest.fixture(scope="module")
def scenes(shared_data: Path) -> dict[str, odocal.Drive]:
    return {d.name: d for d in convert("nuscenes", [shared_data / "nuscenes-can-bus-mini"])}


def held_out(drive: odocal.Drive, theta: np.ndarray) -> float:
    """Dead reckoning over 650-sample windows of ``drive`` (every 100 samples)."""
    segs = identification_segments([drive], SegmentSettings(yaw_rate_threshold_radps=0.0))
    return float(segment_errors(theta, gather_ragged([drive], segs)).mean_m.mean())


@pytest.mark.realdata
def test_two_cars_are_refused_by_name_not_averaged(scenes: dict[str, odocal.Drive],
                                                   tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    """The Boston car's rear wheels differ by 1.9% more than the Singapore car's: one
    calibration of both would average two vehicles."""
    for boston in BOSTON:
        for singapore in ("scene-0061", "scene-0796"):
            result = odocal.calibrate([scenes[boston], scenes[singapore]], settings=SHORT)
            assert result.estimate.status is Status.REJECTED
            (finding,) = result.diagnosis.fatal_findings
            assert finding.check is Check.VEHICLES_DIFFER
            assert set(finding.name.split("|")) == {boston, singapore}
            assert 0.015 < finding.value < 0.025
    # each car's own scenes together are one vehicle
    for car in (SINGAPORE, BOSTON):
        result = odocal.calibrate([scenes[s] for s in car], settings=SHORT)
        assert Check.VEHICLES_DIFFER not in {f.check for f in result.diagnosis.findings}
    # and the command line says so in one line, exit 3
    paths = []
    for name in ("scene-0103", "scene-0061"):
        paths.append(tmp_path / f"{name}.parquet")
        odocal.save_drive(scenes[name], paths[-1])
    code = main(["calibrate", *map(str, paths), "--out", str(tmp_path / "o"), "-q"])
    out = capsys.readouterr().out
    assert code == EXIT_FAILED and out.count("\n") == 1
    assert "disagree on the vehicle" in out and "scene-0103" in out


@pytest.mark.realdata
@pytest.mark.parametrize("train", BOSTON)
def test_one_short_scene_identifies_what_it_holds(scenes: dict[str, odocal.Drive],
                                                  train: str) -> None:
    """A 20 s straight scene holds the distance scale and the wheels' difference: the default
    identifies both (its windows form clusters enough to judge them), and dead reckoning on the
    car's other scene is far better than with the datasheet values."""
    result = odocal.calibrate(scenes[train], settings=SHORT)
    est = result.estimate
    assert est.identified[:2] == (True, True)
    assert set(est.unidentified) == {"t_r", "d"}               # no bends to see them
    assert result.used_data["unit"] == "windows" and result.used_data["clusters"] >= 4
    other = scenes[next(s for s in BOSTON if s != train)]
    assert held_out(other, est.theta.as_array()) < 0.1 * held_out(other, est.datasheet
                                                                    .as_array())


@pytest.mark.realdata
def test_what_each_method_used_is_reported(scenes: dict[str, odocal.Drive],
                                           tmp_path: Path) -> None:
    paths = []
    for name in SINGAPORE[:4]:
        paths.append(tmp_path / f"{name}.parquet")
        odocal.save_drive(scenes[name], paths[-1])
    config = tmp_path / "short.toml"
    config.write_text("[segments]\nvalidation_distance_m = 80.0\n")
    for method, unit in (("inverse", "windows"), ("raw", "segments")):
        out = tmp_path / method
        main(["calibrate", *map(str, paths), "--out", str(out), "--method", method, "-q",
              "--no-report", "--config", str(config)])
        used = json.loads((out / "calibration.json").read_text())["used"]
        assert used["unit"] == unit and used["drives"] == 4
        if unit == "windows":                   # every window of every scene, straight or not
            # (each scene loses the lag scan's margin, 0.25 s and two steps, at either end)
            t_s = scenes[SINGAPORE[0]].t_s
            margin = round(odocal.Settings().inverse.lag_scan_s / t_s) + 2
            expected = sum((scenes[n].n_samples - 1 - 2 * margin) // round(2.0 / t_s)
                           for n in SINGAPORE[:4])
            assert used["count"] == expected and used["length_s"] == pytest.approx(2.0, rel=1e-3)


@pytest.mark.realdata
def test_the_default_holds_out_at_least_as_well_as_a_plain_fit_over_the_singapore_car(
        scenes: dict[str, odocal.Drive]) -> None:
    """Leave one scene out, judged by dead reckoning on it: summed over the folds, the default
    is within 10% of raw Gauss-Newton (benchmarks/bench_realdata.py prints every method)."""
    logs = [scenes[s] for s in SINGAPORE]
    totals = {"inverse": 0.0, "raw": 0.0}
    for held in logs:
        train = [d for d in logs if d is not held]
        for method in totals:
            theta = odocal.calibrate(train, method=method, settings=SHORT).theta.as_array()
            totals[method] += held_out(held, theta)
    assert totals["inverse"] <= 1.1 * totals["raw"]


@pytest.mark.realdata
def test_the_live_car_takes_the_singapore_scenes_played_in_a_row(
        scenes: dict[str, odocal.Drive]) -> None:
    """The five scenes pushed into the live car one after another, 100 s apart: the checks
    of the latest ten minutes see them as one drive with gaps, and a gap's jump is no bend
    (the axles' check refused them, 0.72 against 0.8, while it differenced across the gaps).
    The live car is the batch one of the same scenes within 1.5 of batch's stds."""
    from odocal.online.calibrator import OnlineCalibrator

    car = Settings().replace(vehicle={"model": "four_wheel"})
    calibrator = OnlineCalibrator(car)
    start = 0.0
    for name in SINGAPORE:
        columns = scenes[name].columns()
        t = columns["t"] - columns["t"][0] + start
        start = float(t[-1]) + 100.0
        for i in range(0, t.size, 40):
            calibrator.push({k: (t if k == "t" else v)[i:i + 40] for k, v in columns.items()})
    live = calibrator.estimate()
    assert live.status is Status.CONVERGED, [f.name for f in live.details.findings]
    batch = odocal.calibrate([scenes[n] for n in SINGAPORE], settings=car).model_estimate
    both = np.array(live.identified) & np.array(batch.identified)
    assert both[:4].all() and both.sum() >= 8, (live.identified, batch.identified)
    with np.errstate(divide="ignore", invalid="ignore"):       # (a std of 0: not identified)
        diff = (live.theta.as_array() - batch.theta.as_array()) / batch.std
    assert np.all(np.abs(diff[both]) < 1.5), dict(zip(live.names, diff.round(2), strict=True))
