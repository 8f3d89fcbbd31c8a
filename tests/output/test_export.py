"""Parameter files for localisation stacks, and the datasheet values they are expressed against."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import pytest
import yaml

import odocal
from odocal.model.parameters import Parameters
from odocal.output.export import Calibrated, OdometryNoise, export
from odocal.settings import DATASHEET_THETA, Settings
from tests.conftest import run

THETA = Parameters(c_e=1.952, c_d=-0.0021, t_r=1.527, d=0.00076)
STATED = Parameters(1.95, 0.0, 1.5, 0.0)

# The keys the current upstream schemas require (autoware_vehicle_velocity_converter's
# schema/vehicle_velocity_converter.json; ros2_controllers' diff_drive_controller parameters,
# whose wheel name lists must not be empty for the controller to configure).
AUTOWARE_CONVERTER_REQUIRED = {
    "velocity_stddev_xx": float, "frame_id": str, "angular_velocity_stddev_zz": float,
    "speed_scale_factor": float, "enable_online_speed_scale_factor_calibration": bool,
    "acceptable_speed_scale_factor_range": list, "stop_speed_threshold": float}
DIFF_DRIVE_REQUIRED = {"left_wheel_names": list, "right_wheel_names": list,
                       "wheel_separation": float, "wheel_radius": float}


def _ros_params(path: Path, node: str) -> dict[str, Any]:
    data = yaml.safe_load(path.read_text())
    assert list(data) == [node] and list(data[node]) == ["ros__parameters"]
    return dict(data[node]["ros__parameters"])


def _calibrated(datasheet: Parameters = STATED, **kw: Any) -> Calibrated:
    return Calibrated(theta=THETA, datasheet=datasheet, std=(1e-4, 1e-4, 1e-3, 1e-5),
                      identified=(True, True, True, False), method="inverse",
                      noise=OdometryNoise(0.05, 0.004, 100), **kw)


def _fill_ins(path: Path) -> list[str]:
    return [line.strip() for line in path.read_text().splitlines()
            if line.strip().startswith("# FILL IN")]


def test_exports_carry_each_targets_documented_keys(tmp_path: Path) -> None:
    export(_calibrated(wheel_joints=("rear_left", "rear_right")), tmp_path)
    info = _ros_params(tmp_path / "autoware" / "vehicle_info.param.yaml", "/**")
    assert set(info) == {"wheel_radius", "wheel_tread"}
    assert info["wheel_radius"] == pytest.approx(1.952 / (2 * math.pi))
    assert info["wheel_tread"] == pytest.approx(1.527)
    conv = _ros_params(tmp_path / "autoware" / "vehicle_velocity_converter.param.yaml", "/**")
    assert set(conv) == set(AUTOWARE_CONVERTER_REQUIRED)
    for key, kind in AUTOWARE_CONVERTER_REQUIRED.items():
        assert isinstance(conv[key], kind), key
    assert conv["speed_scale_factor"] == pytest.approx(1.952 / 1.95)
    low, high = conv["acceptable_speed_scale_factor_range"]
    assert low <= conv["speed_scale_factor"] <= high
    assert conv["velocity_stddev_xx"] == pytest.approx(0.05)
    diff = _ros_params(tmp_path / "ros2_control" / "diff_drive_controller.yaml",
                       "diff_drive_controller")
    for key, kind in DIFF_DRIVE_REQUIRED.items():
        assert isinstance(diff[key], kind), key
    assert diff["left_wheel_names"] == ["rear_left"]
    assert diff["right_wheel_names"] == ["rear_right"]
    assert diff["wheel_separation"] == pytest.approx(1.5)          # the datasheet's
    assert diff["wheel_separation"] * diff["wheel_separation_multiplier"] == pytest.approx(1.527)
    left = diff["wheel_radius"] * diff["left_wheel_radius_multiplier"] * 2 * math.pi
    assert left == pytest.approx(1.952 - 0.0021 / 2)
    assert len(diff["twist_covariance_diagonal"]) == 6
    assert diff["twist_covariance_diagonal"][0] == pytest.approx(0.05**2)
    ekf = _ros_params(tmp_path / "robot_localization" / "ekf_odometry.yaml", "ekf_filter_node")
    assert ekf["two_d_mode"] is True and len(ekf["odom0_config"]) == 15
    assert [i for i, f in enumerate(ekf["odom0_config"]) if f] == [6, 11]   # vx, vyaw
    text = (tmp_path / "autoware" / "vehicle_info.param.yaml").read_text()
    assert "not identified by the data (datasheet values kept): d" in text
    for path in tmp_path.rglob("*.yaml"):               # complete: nothing to fill in
        assert _fill_ins(path) == [], path


def test_what_the_data_cannot_give_is_named_in_one_fill_in_line(tmp_path: Path) -> None:
    export(_calibrated(datasheet=Parameters(*DATASHEET_THETA)), tmp_path)
    diff_path = tmp_path / "ros2_control" / "diff_drive_controller.yaml"
    [line] = _fill_ins(diff_path)
    assert "left_wheel_names and right_wheel_names" in line
    diff = _ros_params(diff_path, "diff_drive_controller")
    assert diff["left_wheel_names"] and diff["right_wheel_names"]      # loads and configures
    # no datasheet: the nominal values are the calibrated ones, never a placeholder car's
    assert diff["wheel_separation"] == pytest.approx(1.527)
    assert diff["wheel_separation_multiplier"] == 1
    assert diff["wheel_radius"] * 2 * math.pi == pytest.approx(1.952)
    conv_path = tmp_path / "autoware" / "vehicle_velocity_converter.param.yaml"
    [line] = _fill_ins(conv_path)
    assert line.startswith("# FILL IN speed_scale_factor") and "1.952" in line
    assert _ros_params(conv_path, "/**")["speed_scale_factor"] == 1.0
    for path in tmp_path.rglob("*.yaml"):
        assert "no datasheet values were given" in path.read_text()


def test_wheel_joint_names_from_the_command_line(tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str],
                                                 noisy_drive: Any) -> None:
    drive = tmp_path / "d.parquet"
    odocal.save_drive(noisy_drive.drive, drive)
    code, _, _ = run(capsys, "calibrate", str(drive), "--out", str(tmp_path / "o"), "-q",
                     "--no-report", "--export", "ros2_control", "--wheel-joints",
                     'wheel_"l", wheel_r', "--datasheet", "c_e=1.95,t_r=1.5")
    assert code == 0
    diff = _ros_params(tmp_path / "o" / "ros2_control" / "diff_drive_controller.yaml",
                       "diff_drive_controller")
    assert diff["left_wheel_names"] == ['wheel_"l"'] and diff["right_wheel_names"] == ["wheel_r"]
    code, _, err = run(capsys, "calibrate", str(drive), "--out", str(tmp_path / "p"),
                       "--wheel-joints", "only_one")
    assert code == 1 and "--wheel-joints" in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize("bad", ["c_e", "c_e=x", "c_e=1.9;t_r=1.5", "w=1.9", "c_e=-1",
                                 "t_r=0", "c_e=nan", "c_e=inf"])
def test_a_bad_datasheet_flag_is_one_line(bad: str, tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str],
                                          noisy_drive: Any) -> None:
    drive = tmp_path / "d.parquet"
    odocal.save_drive(noisy_drive.drive, drive)
    code, _, err = run(capsys, "calibrate", str(drive), "--out", str(tmp_path / "o"),
                       "--datasheet", bad)
    assert code == 1 and "datasheet" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()


def test_results_say_what_the_datasheet_is(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                           noisy_drive: Any) -> None:
    drive = tmp_path / "d.parquet"
    odocal.save_drive(noisy_drive.drive, drive)
    code, out, _ = run(capsys, "calibrate", str(drive), "--out", str(tmp_path / "a"),
                       "--no-report")
    assert code == 0 and "no datasheet values given" in out and "placeholder" in out
    code, out, _ = run(capsys, "calibrate", str(drive), "--out", str(tmp_path / "b"),
                       "--no-report", "--datasheet", "c_e=1.94,t_r=1.51,c_d=0.001")
    assert code == 0 and "placeholder" not in out
    assert "1.94000 m" in out and "1.51000 m" in out
    data = json.loads((tmp_path / "b" / "calibration.json").read_text())
    assert json.dumps(data).count("1.94") >= 1


def test_a_drive_file_carries_its_datasheet(tmp_path: Path, noisy_drive: Any) -> None:
    import dataclasses

    from odocal.errors import DataError

    stated = dataclasses.replace(noisy_drive.drive,
                                 metadata={"datasheet": {"c_e": 1.93, "t_r": 1.55}})
    result = odocal.calibrate(stated)
    assert result.estimate.datasheet.c_e == pytest.approx(1.93)
    assert result.estimate.datasheet.t_r == pytest.approx(1.55)
    # the settings (a --datasheet or a config's theta0) win over the metadata
    own = Settings().replace(identify={"theta0": (1.96, 0.0, 1.52, 0.0)})
    assert odocal.calibrate(stated, settings=own).estimate.datasheet.c_e == pytest.approx(1.96)
    other = dataclasses.replace(noisy_drive.drive, name="other",
                                metadata={"datasheet": {"c_e": 1.80, "t_r": 1.55}})
    with pytest.raises(DataError, match="different datasheet values"):
        odocal.calibrate([stated, other])


def test_a_small_robot_is_judged_against_its_own_datasheet(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    robot = odocal.simulate(duration_s=600, seed=3, noise="realistic",
                            theta=Parameters(0.472, 0.0008, 0.31, 0.0))
    path = tmp_path / "robot.parquet"
    odocal.save_drive(robot.drive, path)
    code, out, _ = run(capsys, "calibrate", str(path), "--out", str(tmp_path / "a"),
                       "--no-report", "--datasheet", "c_e=0.44,t_r=0.30")
    assert code == 0, out
    assert "0.47" in out
    # a fixed range that excludes it is named, with where it comes from
    config = tmp_path / "robot.toml"
    config.write_text("[gate]\nc_e_m = [0.5, 5.0]\n")
    code, out, err = run(capsys, "calibrate", str(path), "--out", str(tmp_path / "b"),
                         "--no-report", "--datasheet", "c_e=0.44,t_r=0.30", "--config",
                         str(config))
    assert code == 3
    assert "c_e = 0.472 m lies outside the range 0.5 m .. 5 m set in [gate] c_e_m" in out + err
    assert "contradict" not in out + err
    # without its datasheet the placeholder car's scale does not fit: named, never a fit
    code, out, err = run(capsys, "calibrate", str(path), "--out", str(tmp_path / "c"),
                         "--no-report")
    assert code == 3 and "--datasheet" in out + err
