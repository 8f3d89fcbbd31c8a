"""Parameter files for localisation stacks, and the datasheet values they are expressed against."""

from __future__ import annotations

import itertools
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import odocal
from odocal.model.parameters import Parameters
from odocal.output.export import Calibrated, export, parameters_yaml, unstated
from odocal.pipeline.odometry import OdometryNoise
from odocal.settings import DATASHEET_THETA, Settings
from tests.conftest import run
from tests.ros2.rosenv import keys_in_file, load_declared, require_rclpy, ros_context

THETA = Parameters(c_e=1.952, c_d=-0.0021, t_r=1.527, d=0.00076)
STATED = Parameters(1.95, 0.0, 1.5, 0.0)
ROBOT = Parameters(c_e=0.4723, c_d=0.0008, t_r=0.3105, d=0.0)
ROBOT_STATED = Parameters(0.47, 0.0, 0.31, 0.0)

# The parameters each receiving node declares, with the types it declares them with:
# - robot_localization 3.6.0 (src/ros_filter.cpp, RosFilter::loadParams; 3.5.2 for Humble
#   declares these alike), node ekf_filter_node in the file;
# - ros2_controllers 4.42.1 (Jazzy; diff_drive_controller/src/diff_drive_controller_parameter.yaml,
#   the same types in 2.54.0 Humble and 5.17.0 Kilted), plus the ``type`` the controller_manager
#   spawner (2.46.0 / 4.21.0 on) reads from --param-file;
# - autoware_core 1.9.0 autoware_vehicle_velocity_converter
#   (src/vehicle_velocity_converter_node.cpp)
#   and 1.8.0, which also requires frame_id; autoware_vehicle_info_utils (vehicle_info_utils.hpp).
EKF = {"two_d_mode": "BOOL", "odom0": "STRING", "odom0_config": "BOOL_ARRAY",
       "odom0_queue_size": "INTEGER", "odom0_differential": "BOOL", "odom0_relative": "BOOL",
       "odom0_twist_rejection_threshold": "DOUBLE"}
DIFF_DRIVE = {"type": "STRING", "left_wheel_names": "STRING_ARRAY",
              "right_wheel_names": "STRING_ARRAY", "wheel_separation": "DOUBLE",
              "wheel_radius": "DOUBLE", "wheel_separation_multiplier": "DOUBLE",
              "left_wheel_radius_multiplier": "DOUBLE", "right_wheel_radius_multiplier": "DOUBLE",
              "odom_frame_id": "STRING", "base_frame_id": "STRING",
              "pose_covariance_diagonal": "DOUBLE_ARRAY",
              "twist_covariance_diagonal": "DOUBLE_ARRAY"}
CONVERTER_1_9 = {"speed_scale_factor": "DOUBLE", "velocity_stddev_xx": "DOUBLE",
                 "angular_velocity_stddev_zz": "DOUBLE"}
CONVERTER_1_8 = {**CONVERTER_1_9, "frame_id": "STRING"}
VEHICLE_INFO = {"wheel_radius": "DOUBLE", "wheel_tread": "DOUBLE"}
# odocal's own --export yaml schema (no upstream node): what a node reading it declares
OWN = {"effective_wheel_circumference": "DOUBLE", "wheel_radius": "DOUBLE",
       "circumference_difference": "DOUBLE", "rear_track_width": "DOUBLE",
       "load_transfer_coefficient": "DOUBLE", "parameter_names": "STRING_ARRAY",
       "identified": "BOOL_ARRAY", "std": "DOUBLE_ARRAY", "covariance": "DOUBLE_ARRAY"}

#: file -> (the node name it is loaded into, the declarations of each release it is for)
FILES = {
    "robot_localization/ekf_odometry.yaml": ("ekf_filter_node", [EKF]),
    "ros2_control/diff_drive_controller.yaml": ("diff_drive_controller", [DIFF_DRIVE]),
    "autoware/vehicle_velocity_converter.param.yaml": ("vehicle_velocity_converter",
                                                       [CONVERTER_1_9, CONVERTER_1_8]),
    "autoware/vehicle_info.param.yaml": ("vehicle_velocity_converter", [VEHICLE_INFO]),
    "odometry_parameters.yaml": ("wheel_odometry", [OWN]),
}


def _calibrated(datasheet: Parameters = STATED, theta: Parameters = THETA,
                identified: tuple[bool, bool, bool, bool] = (True, True, True, False),
                **kw: Any) -> Calibrated:
    # what is not identified keeps the datasheet value (as every estimator hands it on)
    values = [t if ok else d for t, d, ok in zip(theta.as_array(), datasheet.as_array(),
                                                  identified, strict=True)]
    # every entry its own value (c_e, c_d, t_r, d of different sizes, one correlation), so a
    # covariance written reversed, transposed or shuffled is seen
    variances = np.array([1e-8, 4e-10, 9e-6, 1e-11]) * np.array(identified, dtype=float)
    cov = np.diag(variances)
    cov[0, 2] = cov[2, 0] = 0.3 * math.sqrt(variances[0] * variances[2])
    return Calibrated(theta=Parameters(*values), datasheet=datasheet,
                      std=tuple(float(v) for v in np.sqrt(np.diag(cov))),  # type: ignore[arg-type]
                      identified=identified, method="inverse",
                      noise=kw.pop("noise", OdometryNoise(0.05, 0.004, 100)),
                      covariance=tuple(tuple(row) for row in cov.tolist()), **kw)


def _write_all(c: Calibrated, out: Path) -> None:
    export(c, out)
    parameters_yaml(c, out / "odometry_parameters.yaml")


def _fill_ins(path: Path) -> list[str]:
    return [line.strip() for line in path.read_text().splitlines()
            if line.strip().startswith("# FILL IN")]


@pytest.fixture(scope="module")
def ros() -> Any:
    require_rclpy()
    with ros_context() as context:
        yield context


def _gone(c: Calibrated | None) -> dict[str, list[str]]:
    """The keys each file leaves out for ``c``: Autoware's wheel_radius and wheel_tread where
    c_e, t_r are neither identified nor stated (odocal's placeholder is no car's)."""
    missing = unstated(c) if c is not None else ()
    return {"autoware/vehicle_info.param.yaml":
            [k for k, n in (("wheel_radius", "c_e"), ("wheel_tread", "t_r")) if n in missing]}


def _load(out: Path, ros: Any, c: Calibrated | None = None) -> dict[str, dict[str, Any]]:
    """Every file in ``out`` loaded in ROS 2 by each release's declarations; the values (a
    key only where ``c``'s file states it: :func:`_gone`)."""
    values: dict[str, dict[str, Any]] = {}
    gone = _gone(c)
    for name, (node, releases) in FILES.items():
        for declarations in releases:
            loaded = load_declared(out / name, node, declarations, context=ros)
            missing = [k for k, v in loaded.items() if v is None]
            assert missing == gone.get(name, []), (name, missing)
            values[name] = loaded
    return values


def _check_values(values: dict[str, dict[str, Any]], c: Calibrated) -> None:
    th, ds = c.theta, (c.datasheet if c.datasheet_stated else c.theta)
    diff = values["ros2_control/diff_drive_controller.yaml"]
    assert diff["type"] == "diff_drive_controller/DiffDriveController"
    assert diff["wheel_separation"] == pytest.approx(ds.t_r, rel=1e-9)
    assert diff["wheel_separation"] * diff["wheel_separation_multiplier"] == \
        pytest.approx(th.t_r, rel=1e-9)
    two_pi_r = diff["wheel_radius"] * 2 * math.pi
    assert two_pi_r * diff["left_wheel_radius_multiplier"] == \
        pytest.approx(th.c_e + th.c_d / 2, rel=1e-9)
    assert two_pi_r * diff["right_wheel_radius_multiplier"] == \
        pytest.approx(th.c_e - th.c_d / 2, rel=1e-9)
    assert diff["twist_covariance_diagonal"][0] == pytest.approx(0.05**2)
    conv = values["autoware/vehicle_velocity_converter.param.yaml"]
    scale = (th.c_e / c.speed_circumference_m if c.speed_circumference_m
             else th.c_e / c.datasheet.c_e if c.datasheet_stated else 1.0)
    assert conv["speed_scale_factor"] == pytest.approx(scale, rel=1e-9)
    assert conv["velocity_stddev_xx"] == pytest.approx(0.05)
    assert conv["frame_id"] == "base_link"
    info = values["autoware/vehicle_info.param.yaml"]
    if "c_e" in unstated(c):
        assert info["wheel_radius"] is None
    else:
        assert info["wheel_radius"] == pytest.approx(th.c_e / (2 * math.pi), rel=1e-9)
    if "t_r" in unstated(c):      # a placeholder is no car's track: left for the user
        assert info["wheel_tread"] is None
    else:
        assert info["wheel_tread"] == pytest.approx(th.t_r, rel=1e-9)
    ekf = values["robot_localization/ekf_odometry.yaml"]
    assert [i for i, f in enumerate(ekf["odom0_config"]) if f] == [6, 11]   # vx, vyaw
    assert ekf["two_d_mode"] is True and ekf["odom0_twist_rejection_threshold"] == 5.0
    own = values["odometry_parameters.yaml"]
    assert own["effective_wheel_circumference"] == pytest.approx(th.c_e, rel=1e-12)
    assert own["load_transfer_coefficient"] == pytest.approx(th.d, rel=1e-12, abs=1e-15)
    assert list(own["identified"]) == list(c.identified)
    assert list(own["parameter_names"]) == ["c_e", "c_d", "t_r", "d"]
    assert len(own["covariance"]) == 16
    # row-major in the order of parameter_names, and the std its diagonal's roots
    np.testing.assert_allclose(own["covariance"], np.asarray(c.covariance).ravel(), rtol=1e-12)
    np.testing.assert_allclose(own["std"], np.sqrt(np.diag(np.asarray(c.covariance))),
                               rtol=1e-12)


COMBINATIONS = [(vehicle, stated, identified)
                for vehicle in ("car", "robot") for stated in (True, False)
                for identified in itertools.product((True, False), repeat=4)]


def test_every_export_loads_in_ros2_as_the_upstream_nodes_declare_it(
        tmp_path: Path, ros: Any) -> None:
    """Car and robot, datasheet stated or not, each parameter identified or not: every file
    loads in rcl with each parameter of the type the receiving node declares."""
    for i, (vehicle, stated, identified) in enumerate(COMBINATIONS):
        theta, datasheet = (THETA, STATED) if vehicle == "car" else (ROBOT, ROBOT_STATED)
        c = _calibrated(datasheet if stated else Parameters(*DATASHEET_THETA), theta,
                        identified)
        out = tmp_path / str(i)
        _write_all(c, out)
        _check_values(_load(out, ros, c), c)
    # and the other inputs that change a file: no noise measured (the targets' defaults), a
    # speed circumference (wheel speeds in m/s), the wheel joints named
    c = _calibrated(noise=None, speed_circumference_m=1.96, wheel_joints=("l", "r"))
    _write_all(c, tmp_path / "other")
    values = _load(tmp_path / "other", ros)
    assert values["autoware/vehicle_velocity_converter.param.yaml"]["speed_scale_factor"] == \
        pytest.approx(THETA.c_e / 1.96)
    # odocal's own file says the same (the true speed over the reported one), as ROS 2 loads it
    speed = {"speed_scale_factor": "DOUBLE", "speed_scale_factor_std": "DOUBLE",
             "assumed_wheel_circumference": "DOUBLE"}
    own = load_declared(tmp_path / "other" / "odometry_parameters.yaml", "wheel_odometry",
                        {**OWN, **speed}, context=ros)
    assert own["speed_scale_factor"] == pytest.approx(THETA.c_e / 1.96)
    assert own["assumed_wheel_circumference"] == 1.96
    assert values["autoware/vehicle_velocity_converter.param.yaml"]["velocity_stddev_xx"] == 0.2
    assert values["ros2_control/diff_drive_controller.yaml"]["left_wheel_names"] == ["l"]


def test_the_files_load_as_a_nodes_global_params_file(tmp_path: Path) -> None:
    """``rclpy.init(args=["--ros-args", "--params-file", F])``, as ``ros2 run ... --ros-args
    --params-file F`` starts a node, for the case that broke each file (nothing identified but
    c_e, no datasheet)."""
    require_rclpy()
    c = _calibrated(Parameters(*DATASHEET_THETA), identified=(True, False, False, False))
    _write_all(c, tmp_path)
    gone = _gone(c)
    assert gone["autoware/vehicle_info.param.yaml"] == ["wheel_tread"]
    assert "# FILL IN wheel_tread: not written, as t_r is not identified by these drives and " \
        "no datasheet states it (--datasheet t_r=...)" in \
        (tmp_path / "autoware" / "vehicle_info.param.yaml").read_text()
    for name, (node, releases) in FILES.items():
        for declarations in releases:
            values = load_declared(tmp_path / name, node, declarations)
            assert [k for k, v in values.items() if v is None] == gone.get(name, []), name


def test_a_later_export_into_the_same_folder_replaces_the_earlier(tmp_path: Path,
                                                                   ros: Any) -> None:
    """The live node's export service (and a fleet report run again) writes each newer
    estimate into the folder of the last: the files then hold the newer values."""
    _write_all(_calibrated(), tmp_path)
    newer = _calibrated(theta=Parameters(c_e=1.948, c_d=-0.0018, t_r=1.531, d=0.0007))
    _write_all(newer, tmp_path)
    _check_values(_load(tmp_path, ros, newer), newer)


def test_the_odometry_noise_is_the_wheels_error_through_their_own_circumferences() -> None:
    """The twist covariance written for the EKF: a right wheel reading 0.2 rev/s too much for
    one second and too little the next, on a noise-free drive, is a speed error of
    +-0.1 C_rr m/s and a yaw-rate error of +-0.2 C_rr / t_r rad/s: their median absolute
    deviations, times 1.4826 (the normal's std from the MAD)."""
    from odocal.pipeline.odometry import odometry_noise

    sim = odocal.simulate(duration_s=120.0, seed=11, noise="none")
    d, theta = sim.drive, sim.true_parameters
    per_second = round(1.0 / d.t_s)
    sign = np.where((np.arange(d.n_samples) // per_second) % 2 == 0, 1.0, -1.0)
    drive = odocal.Drive.from_columns({**d.columns(), "n_rr": d.n_rr + 0.2 * sign},
                                      name="right wheel off")
    noise = odometry_noise([drive], theta)
    assert noise is not None and noise.windows == d.n_samples // per_second
    c_rr = theta.c_e - theta.c_d / 2.0
    assert noise.speed_std_mps == pytest.approx(1.4826 * 0.1 * c_rr, rel=1e-4)
    assert noise.yaw_rate_std_radps == pytest.approx(1.4826 * 0.2 * c_rr / theta.t_r, rel=1e-4)


HOSTILE = ["drive\nodom0_config: [true]\n.parquet", "a\rb: 1", "x\u2028wheel_radius: 9",
           "x\x85y: 1", "# not a comment", "'quoted\"", "\u00e9t\u00e9 \U0001F697", "k: v"]


@pytest.mark.parametrize("name", HOSTILE)
def test_no_user_string_adds_a_key(name: str, tmp_path: Path, ros: Any) -> None:
    """A log's name (or a fleet's vehicle name) in the provenance line, and wheel joint names,
    stay a comment and values: rcl reads exactly the keys odocal writes."""
    c = _calibrated(source=name, wheel_joints=(name, "true"))
    _write_all(c, tmp_path)
    for rel, (node, releases) in FILES.items():
        path = tmp_path / rel
        assert keys_in_file(path, node, ros) == set().union(*releases), rel
        header = [line for line in path.read_text().splitlines() if "from:" in line]
        assert len(header) == 1 and header[0].startswith("# from: ")
    diff = load_declared(tmp_path / "ros2_control/diff_drive_controller.yaml",
                         "diff_drive_controller", DIFF_DRIVE, context=ros)
    assert diff["left_wheel_names"] == [name] and diff["right_wheel_names"] == ["true"]


def test_what_the_data_cannot_give_is_named_in_one_fill_in_line(tmp_path: Path) -> None:
    export(_calibrated(datasheet=Parameters(*DATASHEET_THETA)), tmp_path)
    diff_path = tmp_path / "ros2_control" / "diff_drive_controller.yaml"
    [line] = _fill_ins(diff_path)
    assert "left_wheel_names and right_wheel_names" in line
    conv_path = tmp_path / "autoware" / "vehicle_velocity_converter.param.yaml"
    [line] = _fill_ins(conv_path)
    assert line.startswith("# FILL IN speed_scale_factor") and "1.952" in line
    for path in tmp_path.rglob("*.yaml"):
        assert "no datasheet values were given" in path.read_text()
        assert "# for: " in path.read_text()                      # the releases it is for
    # stated, with joints: complete, nothing to fill in
    export(_calibrated(wheel_joints=("l", "r")), tmp_path / "complete")
    for path in (tmp_path / "complete").rglob("*.yaml"):
        assert _fill_ins(path) == [], path
    text = (tmp_path / "complete" / "autoware" / "vehicle_info.param.yaml").read_text()
    assert "not identified by the data (datasheet values kept; one no datasheet states is a " \
        "FILL IN line where a key needs it): d" in text


def test_wheel_joint_names_and_export_lists_from_the_command_line(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], noisy_drive: Any, ros: Any) -> None:
    drive = tmp_path / "d.parquet"
    odocal.save_drive(noisy_drive.drive, drive)
    code, out, _ = run(capsys, "calibrate", str(drive), "--out", str(tmp_path / "o"),
                       "--no-report", "--export", "ros2_control,autoware", "--export", "yaml",
                       "--wheel-joints", 'wheel_"l", wheel_r',
                       "--datasheet", "wheel_radius=0.31,wheel_separation=1.5")
    assert code == 0
    for rel in ("ros2_control/diff_drive_controller.yaml", "autoware/vehicle_info.param.yaml",
                "autoware/vehicle_velocity_converter.param.yaml", "odometry_parameters.yaml"):
        assert f"wrote {tmp_path / 'o' / rel}" in out
    diff = load_declared(tmp_path / "o" / "ros2_control" / "diff_drive_controller.yaml",
                         "diff_drive_controller", DIFF_DRIVE, context=ros)
    assert diff["left_wheel_names"] == ['wheel_"l"'] and diff["right_wheel_names"] == ["wheel_r"]
    # a robot's datasheet in its stack's names: wheel_radius 0.31 m is c_e = 2 pi 0.31
    assert diff["wheel_radius"] == pytest.approx(0.31)
    assert diff["wheel_separation"] == pytest.approx(1.5)
    data = json.loads((tmp_path / "o" / "calibration.json").read_text())
    assert data["datasheet"]["theta"]["c_e"] == pytest.approx(2 * math.pi * 0.31)
    code, _, err = run(capsys, "calibrate", str(drive), "--out", str(tmp_path / "p"),
                       "--wheel-joints", "only_one")
    assert code == 2 and "--wheel-joints" in err and "left and the right" in err
    code, _, err = run(capsys, "calibrate", str(drive), "--out", str(tmp_path / "p"),
                       "--export", "autoware,ros3")
    assert code == 2 and "unknown target 'ros3'" in err and not (tmp_path / "p").exists()


@pytest.mark.parametrize("bad", ["c_e", "c_e=x", "c_e=1.9;t_r=1.5", "w=1.9", "c_e=-1",
                                 "t_r=0", "c_e=nan", "c_e=inf", "c_e=1.9,wheel_radius=0.3",
                                 "t_r=1.5,t_r=1.6", "wheel_radius=-0.1"])
def test_a_bad_datasheet_flag_is_one_line(bad: str, tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str],
                                          noisy_drive: Any) -> None:
    drive = tmp_path / "d.parquet"
    odocal.save_drive(noisy_drive.drive, drive)
    code, _, err = run(capsys, "calibrate", str(drive), "--out", str(tmp_path / "o"),
                       "--datasheet", bad)
    # what was typed on the command line: a usage error (exit 2), its last line naming it
    assert code == 2 and "argument --datasheet: " in err.strip().splitlines()[-1]
    assert "Traceback" not in err and not (tmp_path / "o").exists()


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
    # (another drive: the same samples twice would be refused as one drive given twice)
    other = dataclasses.replace(odocal.simulate(duration_s=300.0, seed=91).drive, name="other",
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


@pytest.mark.realdata
def test_the_issues_real_logs_export_files_that_load(shared_data: Path, tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str],
                                                     ros: Any) -> None:
    """The cases that stopped the receiving nodes (issue 29): a straight scene with a datasheet
    (t_r not identified) and the comma2k19 segment without one (its wheel speeds were turned into
    rates with a known circumference: the speed scale factor is relative to it)."""
    code, _, err = run(capsys, "calibrate", "--from", "nuscenes",
                       str(shared_data / "nuscenes-can-bus-mini"), "--scene", "scene-0796",
                       "--datasheet", "c_e=1.95,t_r=1.51", "--out", str(tmp_path / "zoe"),
                       "-q", "--no-report",
                       "--export", "autoware,ros2_control,robot_localization,yaml")
    assert code == 0, err
    own = load_declared(tmp_path / "zoe" / "odometry_parameters.yaml", "wheel_odometry", OWN,
                        context=ros)
    assert own["identified"][2] is False                   # t_r: not identified
    diff = load_declared(tmp_path / "zoe" / "ros2_control" / "diff_drive_controller.yaml",
                         "diff_drive_controller", DIFF_DRIVE, context=ros)
    assert diff["wheel_separation_multiplier"] == 1.0
    segment = shared_data / "comma2k19-example" / "2018-08-02--08-34-47" / "40"
    code, _, err = run(capsys, "calibrate", "--from", "comma2k19", str(segment), "-q",
                       "--no-report", "--out", str(tmp_path / "comma"),
                       "--export", "autoware,yaml")
    assert code == 0, err
    conv_path = tmp_path / "comma" / "autoware" / "vehicle_velocity_converter.param.yaml"
    conv = load_declared(conv_path, "vehicle_velocity_converter", CONVERTER_1_8, context=ros)
    theta = json.loads((tmp_path / "comma" / "calibration.json").read_text())["theta"]
    assert conv["speed_scale_factor"] == pytest.approx(theta["c_e"] / DATASHEET_THETA[0])
    assert _fill_ins(conv_path) == []
