"""The vehicle model as a value (issue 37, first part): the registry, the protocol, the
setting that chooses it, and the files that carry its name."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import odocal
from odocal.errors import ConfigError, DataError
from odocal.fleet.store import open_store
from odocal.io.json_files import read_parameters
from odocal.model import registry
from odocal.model.kinematics import body_rates, wheel_rates_for
from odocal.model.protocol import VehicleModel
from odocal.model.vehicle import MODEL
from odocal.settings import PER_PARAMETER, Settings, settings_from_dict

THETA = np.array([2.031, -0.0042, 1.512, 0.0011])


def test_the_registry_names_each_model_and_loads_it() -> None:
    assert registry.names() == ("rear_axle", "four_wheel")
    assert registry.model("rear_axle") is MODEL
    assert isinstance(MODEL, VehicleModel)
    assert registry.layout("rear_axle") is MODEL.layout
    assert registry.entry("rear_axle").wheel_inputs == MODEL.wheel_inputs
    with pytest.raises(ConfigError, match=r"unknown vehicle model 'rear_axel' \(did you mean "
                                          r"'rear_axle'\?\); known: rear_axle, four_wheel"):
        registry.model("rear_axel")


def test_the_body_map_is_the_body_rates_and_the_wheel_rates_invert_them() -> None:
    """body_map's two matrices give (2a)-(2b) at any a_y; wheel_rates inverts body_rates;
    both agree with the kinematics' functions they stand for."""
    rng = np.random.default_rng(3)
    rates = rng.uniform(-5.0, 15.0, size=(200, 2))
    a_y = rng.uniform(-6.0, 6.0, size=200)
    v, w = MODEL.body_rates(THETA, rates, a_y)
    v_k, w_k = body_rates(THETA, rates[:, 0], rates[:, 1], a_y)
    np.testing.assert_allclose(v, v_k, rtol=1e-14)
    np.testing.assert_allclose(w, w_k, rtol=1e-14)
    m0, m1 = MODEL.body_map(THETA)
    mapped = np.einsum("kij,kj->ki", m0[None] + a_y[:, None, None] * m1[None], rates)
    np.testing.assert_allclose(mapped[:, 0], v, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(mapped[:, 1], w, rtol=1e-12, atol=1e-12)
    back = MODEL.wheel_rates(THETA, v, w, a_y)
    np.testing.assert_allclose(back, rates, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(back, np.column_stack(wheel_rates_for(THETA, v, w, a_y)),
                               rtol=1e-14)


def test_the_geometry_gains_and_wheel_changes_are_the_rear_axle_s() -> None:
    c_e, c_d, t_r, _ = THETA
    np.testing.assert_allclose(MODEL.circumferences(THETA), [c_e + c_d / 2, c_e - c_d / 2])
    geometry = MODEL.geometry(THETA)
    assert geometry["wheel_radius"] == pytest.approx(c_e / (2 * np.pi), rel=1e-15)
    assert geometry["wheel_separation"] == t_r
    assert geometry["left_wheel_radius"] == pytest.approx((c_e + c_d / 2) / (2 * np.pi))
    assert geometry["right_wheel_radius"] == pytest.approx((c_e - c_d / 2) / (2 * np.pi))
    np.testing.assert_allclose(MODEL.channel_gains(THETA), [c_e, c_e / t_r], rtol=1e-14)
    # the channels of equal wheels: their mean and a zero difference
    np.testing.assert_allclose(MODEL.channel_map @ np.array([3.0, 3.0]), [3.0, 0.0])
    # one tyre 1% smaller: only its circumference moves, and wheel_changes names it
    smaller = MODEL.with_wheel_scaled(THETA, 1, 0.99)
    before, after = MODEL.circumferences(THETA), MODEL.circumferences(smaller)
    assert after[0] == pytest.approx(before[0], rel=1e-15)
    assert after[1] == pytest.approx(0.99 * before[1], rel=1e-15)
    np.testing.assert_allclose(MODEL.wheel_changes(smaller - THETA), after - before,
                               rtol=1e-12, atol=1e-15)
    assert smaller[2] == t_r and smaller[3] == THETA[3]


def test_the_setting_chooses_the_model_and_sizes_every_per_parameter_setting() -> None:
    assert Settings().vehicle.model == "rear_axle"
    assert Settings().layout is MODEL.layout
    with pytest.raises(ConfigError, match="unknown vehicle model 'four'"):
        settings_from_dict({"vehicle": {"model": "four"}})
    for section, key in PER_PARAMETER:
        value = getattr(getattr(Settings(), section), key)
        assert len(value) == MODEL.size, (section, key)
    with pytest.raises(ConfigError,
                       match=r"unknown setting \[vehicle\] 'modle'; known keys: model"):
        settings_from_dict({"vehicle": {"modle": "rear_axle"}})


def test_a_settings_file_naming_an_unknown_model_is_one_line_and_exit_1(tmp_path: Path) -> None:
    config = tmp_path / "odocal.toml"
    config.write_text('[vehicle]\nmodel = "skid_steer"\n')
    done = subprocess.run([sys.executable, "-m", "odocal", "demo", "--duration", "60",
                           "--config", str(config)], capture_output=True, text=True, timeout=300)
    assert done.returncode == 1, done.stderr
    assert done.stderr.strip().count("\n") == 0 and "unknown vehicle model 'skid_steer'" \
        in done.stderr and "Traceback" not in done.stderr


def test_calibration_json_names_its_model_and_another_model_s_is_refused(tmp_path: Path) -> None:
    result = odocal.calibrate(odocal.simulate(duration_s=300, seed=2, noise="white").drive)
    assert result.estimate.model == "rear_axle"
    result.save(tmp_path / "out", report=False)
    path = tmp_path / "out" / "calibration.json"
    data = json.loads(path.read_text())
    assert data["model"] == "rear_axle"
    assert read_parameters(path).as_dict() == pytest.approx(data["theta"], rel=1e-15)
    # a calibration.json from before models were named is the rear axle's
    del data["model"]
    old = tmp_path / "old.json"
    old.write_text(json.dumps(data))
    assert read_parameters(old).as_dict() == pytest.approx(data["theta"], rel=1e-15)
    # another model's, or one this odocal does not know, is refused by name
    other = tmp_path / "other.json"
    with pytest.raises(DataError, match="not of the four_wheel model"):
        registry.check_stated("rear_axle", "four_wheel", "'x.json'")
    other.write_text(json.dumps({**data, "model": "skid_steer"}))
    with pytest.raises(DataError, match="names the vehicle model 'skid_steer', which this "
                                        "odocal does not know"):
        read_parameters(other)


def test_a_fleet_store_holds_one_model_s_parameters(tmp_path: Path) -> None:
    path = tmp_path / "fleet.db"
    with open_store(path, model="rear_axle") as db:
        stored = db.db.execute("SELECT value FROM meta WHERE key = 'model'").fetchone()
    assert stored == ("rear_axle",)
    with open_store(path, model="rear_axle"):
        pass
    import sqlite3

    raw = sqlite3.connect(path)
    raw.execute("UPDATE meta SET value = 'skid_steer' WHERE key = 'model'")
    raw.commit()
    raw.close()
    with pytest.raises(DataError, match="names the vehicle model 'skid_steer'"):
        open_store(path, model="rear_axle")


def test_parameters_are_the_model_s_by_name_whatever_its_layout() -> None:
    """Parameters carry their layout: the rear axle's by default, another model's by its own
    names (a made-up skid-steer layout here), immutable, picklable for Dask's workers."""
    import pickle

    from odocal.model.layout import Layout, ParameterSpec
    from odocal.model.parameters import Parameters

    rear = Parameters(2.0, -0.001, 1.5, d=0.0005)
    assert rear == Parameters(c_e=2.0, c_d=-0.001, t_r=1.5, d=0.0005)
    assert rear.layout is MODEL.layout and rear.t_r == 1.5
    assert rear.replace(t_r=1.6).as_dict() == {"c_e": 2.0, "c_d": -0.001, "t_r": 1.6,
                                               "d": 0.0005}
    assert pickle.loads(pickle.dumps(rear)) == rear and hash(rear) == hash(rear.replace())
    skid = Layout(parameters=(ParameterSpec("c", "m", "circumference", 1.0, "m", 0.6, 0.01),
                              ParameterSpec("b", "m", "effective track", 1.0, "m", 0.5, 0.05)),
                  scale="c", track="b", difference="c", load="c", differential=("b",),
                  bends=("b",), lengths=("c", "b"))
    robot = Parameters.from_array([0.61, 0.52], layout=skid)
    assert robot.b == 0.52 and robot.as_dict() == {"c": 0.61, "b": 0.52}
    assert robot != Parameters(0.61, 0.52, 0.0, 0.0)
    assert pickle.loads(pickle.dumps(robot)).layout == skid
    for bad, message in ((lambda: Parameters(1.0, 2.0, 3.0), "missing d"),
                         (lambda: Parameters(1.0, 2.0, 3.0, 4.0, 5.0), "5 values where"),
                         (lambda: Parameters(1.0, 2.0, 3.0, 4.0, c_e=1.0), "'c_e' given twice"),
                         (lambda: Parameters(0.6, 0.5, layout=skid, t_r=1.0),
                          "'t_r' is not a parameter")):
        with pytest.raises(TypeError, match=message):
            bad()
    with pytest.raises(AttributeError, match="immutable"):
        rear.c_e = 3.0  # type: ignore[misc]
    with pytest.raises(AttributeError, match="no attribute 'wheelbase'"):
        _ = rear.wheelbase


def test_another_model_s_layout_sizes_the_per_parameter_settings(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """The settings check theta0, prior_std, half_width and excess_floor against the chosen
    model's layout (a two-parameter model registered for the test), not the rear axle's."""
    from odocal.model.layout import Layout, ParameterSpec

    two = Layout(parameters=(ParameterSpec("c", "m", "circumference", 1.0, "m", 0.6, 0.01,
                                           (0.05, 50.0), 50.0),
                             ParameterSpec("b", "m", "effective track", 1.0, "m", 0.5, 0.05,
                                           (0.05, 30.0), 30.0)),
                 scale="c", track="b", difference="b", load="b", differential=("b",),
                 bends=("b",), lengths=("c", "b"))
    monkeypatch.setitem(registry._ENTRIES, "skid_steer",
                        registry.Entry("skid_steer", "a test's robot", two, ("n_l", "n_r"),
                                       "odocal.model.vehicle:MODEL"))
    per_model = {"identify": {"theta0": [0.61, 0.52], "prior_std": [0.01, 0.05]},
                 "minimum": {"half_width": [0.05, 0.1]}, "fleet": {"excess_floor": [0.0, 0.0]}}
    settings = settings_from_dict({"vehicle": {"model": "skid_steer"}, **per_model})
    assert settings.layout is two and settings.identify.theta0 == (0.61, 0.52)
    # a per-parameter setting left out is the model's own default (its datasheet uncertainty
    # for the minimum's half width), not the rear axle's four
    unstated = settings_from_dict({"vehicle": {"model": "skid_steer"},
                                   "identify": per_model["identify"], "fleet": per_model["fleet"]})
    assert unstated.minimum.half_width == (0.01, 0.05)
    with pytest.raises(ConfigError, match=r"\[minimum\] half_width = \(0\.1, 0\.02, 0\.3, "
                                          r"0\.01\) is invalid: expected 2 values, one per "
                                          r"parameter of the skid_steer model \(c, b\)"):
        settings_from_dict({"vehicle": {"model": "skid_steer"}, **per_model,
                            "minimum": {"half_width": [0.1, 0.02, 0.3, 0.01]}})
    with pytest.raises(ConfigError, match=r"theta0 = \(0\.61, 70\.0\) is invalid: expected a "
                                          r"wheeled vehicle's values \(b = 70 is not"):
        settings_from_dict({"vehicle": {"model": "skid_steer"}, **per_model,
                            "identify": {"theta0": [0.61, 70.0], "prior_std": [0.01, 0.05]}})
    with pytest.raises(ConfigError, match=r"^setting \[vehicle\] model = 'rear_axel' is "
                                          r"invalid: unknown vehicle model"):
        settings_from_dict({"vehicle": {"model": "rear_axel"}})


def test_the_default_model_leaves_a_fleet_s_settings_hash_as_it_was() -> None:
    """A store made before models were named keeps its drives: the default model does not
    enter the settings hash its task keys carry (f542e10c... at 8b9832e, before [vehicle])."""
    import hashlib

    from odocal.fleet.tasks import settings_hash

    plain = {k: v for k, v in Settings().to_dict().items() if k not in ("fleet", "vehicle")}
    before = hashlib.sha256(json.dumps(plain, sort_keys=True, default=str).encode()).hexdigest()
    assert settings_hash(Settings()) == before
    assert settings_hash(Settings().replace(calibrate={"seed": 3})) != before


def test_validate_refuses_another_model_s_calibration_in_one_line(tmp_path: Path) -> None:
    """``odocal validate --params`` with a calibration.json of a model this run does not use:
    one line, exit 1, no traceback."""
    drive = tmp_path / "d.parquet"
    made = subprocess.run([sys.executable, "-m", "odocal", "simulate", "--out", str(drive),
                           "--duration", "120", "-q"], capture_output=True, text=True,
                          timeout=300)
    assert made.returncode == 0, made.stderr
    other = tmp_path / "other.json"
    other.write_text(json.dumps({"model": "skid_steer", "theta": {
        "c_e": 2.0, "c_d": 0.0, "t_r": 1.5, "d": 0.0}}))
    done = subprocess.run([sys.executable, "-m", "odocal", "validate", str(drive), "--params",
                           str(other)], capture_output=True, text=True, timeout=300)
    assert done.returncode == 1, done.stderr
    assert done.stderr.strip().count("\n") == 0 and "Traceback" not in done.stderr
    assert "names the vehicle model 'skid_steer', which this odocal does not know" \
        in done.stderr
