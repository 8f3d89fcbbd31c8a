"""What a ROS 2 user looks for in the live node (issue 41): the estimate as data, a reset after
a tyre change, a PoseWithCovarianceStamped reference, an IMU mounted turned, the gyro's offset
for Autoware's imu_corrector, a lifecycle node, a robot's drive wheels found by their names,
robot_localization pointed at the node's own odometry, and the node's parameter file."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

import odocal
from odocal.errors import ConfigError
from odocal.ros2.inputs import wheel_joints
from tests.ros2.rig import (
    Script,
    call,
    first_seconds,
    play,
    spin_until,
    unique,
    values_of,
    without_sideslip,
)
from tests.ros2.rosenv import keys_in_file, load_declared, require_rclpy

require_rclpy()

from rclpy.node import Node  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from std_msgs.msg import Float64MultiArray  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from odocal.ros2 import params  # noqa: E402
from odocal.ros2.node import CalibrationNode, estimate_columns  # noqa: E402

PARAMS_FILE = Path(params.__file__).with_name("odocal_ros2.params.yaml")


@pytest.fixture(scope="module")
def drive() -> odocal.Drive:
    return without_sideslip(odocal.simulate(duration_s=180.0, seed=5, noise="realistic").drive)


def test_the_estimate_is_latched_data_with_its_labels(rig: Any, drive: odocal.Drive,
                                                      ros: Any) -> None:
    r = rig()
    play(r.executor, r.player, r.node, drive)
    est = r.node.finish()
    # a subscriber that comes late still gets the latest estimate (transient local)
    late = Node(unique("late"), context=ros, enable_rosout=False)
    got: list[Any] = []
    late.create_subscription(Float64MultiArray, f"{r.node.get_fully_qualified_name()}/estimate",
                             got.append, QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                                                    durability=DurabilityPolicy.TRANSIENT_LOCAL))
    r.executor.add_node(late)
    try:
        spin_until(r.executor, lambda: bool(got), "the latched estimate")
    finally:
        r.executor.remove_node(late)
        late.destroy_node()
    msg = got[-1]
    rows, columns = msg.layout.dim
    assert rows.label == "parameter: c_e c_d t_r d" and rows.size == 4
    assert columns.label == "column: " + " ".join(estimate_columns(("c_e", "c_d", "t_r", "d")))
    assert columns.size == 7
    table = np.array(msg.data).reshape(4, 7)
    assert np.array_equal(table[:, 0], est.theta.as_array())
    assert np.array_equal(table[:, 1], est.std)
    assert np.array_equal(table[:, 2], np.asarray(est.identified, dtype=float))
    assert np.allclose(table[:, 3:], est.covariance, rtol=0, atol=0)
    # robot_localization's export takes the node's own odometry (its covariance per message)
    ekf = load_declared(r.folder / "robot_localization" / "ekf_odometry.yaml",
                        "ekf_filter_node", {"odom0": "STRING", "odom0_config": "BOOL_ARRAY"},
                        context=ros)
    assert ekf["odom0"] == f"{r.node.get_fully_qualified_name()}/odometry"


@pytest.mark.parametrize("beside", [False, True], ids=["in its thread", "in a process beside"])
def test_reset_starts_the_calibration_over(rig: Any, drive: odocal.Drive, beside: bool) -> None:
    """~/reset (after a tyre change): everything calibrated before is forgotten; the drive
    goes on and the calibration comes from what follows alone (the calibrator's process, where
    it has one, started anew)."""
    r = rig(calibrator_process=beside)
    first = first_seconds(drive, 90.0)
    play(r.executor, r.player, r.node, first)
    assert r.node.calibrator.distance_km > 0.5
    answer = call(r.executor, r.player.reset, Trigger.Request(), "~/reset")
    assert answer.success and r.node.calibrator.distance_km == 0.0
    spin_until(r.executor, lambda: "not yet identified: c_e, c_d" in
               r.player.statuses()[-1].message, "the status after the reset")
    rest = drive.columns()
    later = odocal.Drive.from_columns({k: v[first.n_samples:] for k, v in rest.items()},
                                      name="later")
    play(r.executor, r.player, r.node, later)         # (its stamps go on from the first part)
    r.node.finish()
    assert r.node.calibrator.distance_km == pytest.approx(
        later.distance_m / 1000, rel=0.05)
    spin_until(r.executor, lambda: len(r.player.odometry) == drive.n_samples,
               "the odometry of every wheel message, before and after the reset")


def test_the_docs_reset_snippet_resets_a_node_of_the_default_name(ros: Any) -> None:
    """docs/ros2.md's few lines of rclpy (a reset without a ROS install), as the page shows
    them, in a process of their own against a node of the default name on this domain."""
    import os
    import re
    import subprocess
    import sys
    import threading

    from rclpy.executors import SingleThreadedExecutor

    from tests.conftest import ROOT

    snippets = re.findall(r"```python\n(.*?)```", (ROOT / "docs" / "ros2.md").read_text(),
                          flags=re.S)
    assert len(snippets) == 1 and "/odocal_calibration/reset" in snippets[0]
    node = CalibrationNode(context=ros, enable_rosout=False)
    executor = SingleThreadedExecutor(context=ros)
    executor.add_node(node)
    stop = threading.Event()

    def spin() -> None:
        while not stop.is_set():
            executor.spin_once(timeout_sec=0.05)

    spinner = threading.Thread(target=spin, daemon=True)
    spinner.start()
    try:
        done = subprocess.run([sys.executable, "-c", snippets[0]], env=os.environ.copy(),
                              capture_output=True, text=True, timeout=90)
    finally:
        stop.set()
        spinner.join(10)
        executor.remove_node(node)
        node.destroy_node()
        executor.shutdown()
    assert done.returncode == 0, done.stdout + done.stderr
    assert done.stdout.strip() == "calibrating anew from the datasheet values"


def test_a_pose_with_covariance_reference_calibrates_as_an_odometry_one(
        rig: Any, drive: odocal.Drive) -> None:
    short = first_seconds(drive, 120.0)
    estimates = []
    for pose_type in ("odometry", "pose_with_covariance"):
        r = rig(pose_type=pose_type)
        play(r.executor, r.player, r.node, short, Script(pose_type=pose_type))
        estimates.append(r.node.finish())
    assert any(estimates[0].identified)
    assert np.array_equal(estimates[0].theta.as_array(), estimates[1].theta.as_array())
    assert np.array_equal(estimates[0].std, estimates[1].std)


def test_an_imu_mounted_turned_is_rotated_into_the_vehicles_axes(
        rig: Any, drive: odocal.Drive) -> None:
    short = first_seconds(drive, 120.0)
    aligned = rig()
    play(aligned.executor, aligned.player, aligned.node, short)
    turned = rig(imu_rotation_deg=[0.0, 0.0, 90.0])
    play(turned.executor, turned.player, turned.node, short, Script(imu_yaw_deg=90.0))
    a, b = aligned.node.finish(), turned.node.finish()
    assert any(a.identified)
    assert np.allclose(a.theta.as_array(), b.theta.as_array(), rtol=1e-9, atol=1e-12)


def test_the_gyros_offset_is_exported_for_imu_corrector(rig: Any, drive: odocal.Drive,
                                                        ros: Any) -> None:
    offset = 0.004                          # rad/s
    r = rig()
    play(r.executor, r.player, r.node, drive, Script(gyro_offset_radps=offset))
    r.node.finish()
    found = r.node.gyro.result()
    assert found is not None
    assert abs(found.offset_radps - offset) <= max(3 * found.std_radps, 2e-4)
    corrector = load_declared(r.folder / "autoware" / "imu_corrector.param.yaml",
                              "imu_corrector",
                              {"angular_velocity_offset_z": "DOUBLE",
                               "angular_velocity_stddev_zz": "DOUBLE",
                               "angular_velocity_offset_x": "DOUBLE"}, context=ros)
    assert corrector["angular_velocity_offset_z"] == pytest.approx(found.offset_radps)
    assert corrector["angular_velocity_offset_x"] == 0.0
    assert 0 < corrector["angular_velocity_stddev_zz"] < 0.1


def test_a_lifecycle_manager_configures_activates_and_deactivates_it(
        rig: Any, drive: odocal.Drive) -> None:
    from lifecycle_msgs.msg import Transition
    from lifecycle_msgs.srv import ChangeState, GetState

    r = rig(autostart=False, discover=False)
    name = r.node.get_fully_qualified_name()
    get = r.player.create_client(GetState, f"{name}/get_state")
    change = r.player.create_client(ChangeState, f"{name}/change_state")
    assert call(r.executor, get, GetState.Request(), "get_state").current_state.label == \
        "unconfigured"
    assert r.player.wheels.get_subscription_count() == 0        # nothing taken unconfigured
    for transition in (Transition.TRANSITION_CONFIGURE, Transition.TRANSITION_ACTIVATE):
        answer = call(r.executor, change,
                      ChangeState.Request(transition=Transition(id=transition)), "change_state")
        assert answer.success
    spin_until(r.executor, lambda: r.player.wheels.get_subscription_count() > 0
               and r.player.pose.get_subscription_count() > 0, "discovery")
    short = first_seconds(drive, 60.0)
    play(r.executor, r.player, r.node, short)
    assert r.node.messages()["wheels"] == short.n_samples
    assert call(r.executor, change, ChangeState.Request(
        transition=Transition(id=Transition.TRANSITION_DEACTIVATE)), "change_state").success
    before = len(r.player.odometry)
    from sensor_msgs.msg import JointState

    r.player.wheels.publish(JointState())                     # not taken while inactive
    for _ in range(20):
        r.executor.spin_once(timeout_sec=0.01)
    assert len(r.player.odometry) == before
    assert call(r.executor, get, GetState.Request(), "get_state").current_state.label == \
        "inactive"
    # cleaned up, configured and activated again: a new calibration from the next messages
    for transition in (Transition.TRANSITION_CLEANUP, Transition.TRANSITION_CONFIGURE,
                       Transition.TRANSITION_ACTIVATE):
        answer = call(r.executor, change,
                      ChangeState.Request(transition=Transition(id=transition)), "change_state")
        assert answer.success
    spin_until(r.executor, lambda: r.player.wheels.get_subscription_count() > 0
               and r.player.pose.get_subscription_count() > 0, "discovery")
    assert r.node.calibrator.samples == 0
    play(r.executor, r.player, r.node, short)
    assert r.node.messages()["wheels"] == short.n_samples


@pytest.mark.parametrize(("names", "found"), [
    (["front_left_wheel", "front_right_wheel", "rear_left_wheel", "rear_right_wheel"], (2, 3)),
    (["left_wheel_joint", "right_wheel_joint"], (0, 1)),
    (["wheel_left_joint", "wheel_right_joint", "caster_back_joint"], (0, 1)),
    (["front_left_steer", "front_right_steer", "left_wheel", "right_wheel"], (2, 3)),
    (["rl", "rr"], (0, 1)),
])
def test_a_robots_drive_wheels_are_found_by_their_names(names: list[str],
                                                       found: tuple[int, int]) -> None:
    assert wheel_joints(names, "", "", "/joint_states") == found


@pytest.mark.parametrize("names", [["left_wheel", "right_wheel", "left_wheel_2"],
                                   ["arm_joint", "gripper_joint"]])
def test_wheels_that_cannot_be_told_are_named_with_the_parameter_to_set(
        names: list[str]) -> None:
    with pytest.raises(ConfigError, match=r"cannot tell which joint is the left wheel among "
                                          r".*; set left_wheel_joint"):
        wheel_joints(names, "", "", "/joint_states")


def test_a_diff_drive_robots_joints_calibrate(rig: Any, drive: odocal.Drive, ros: Any) -> None:
    r = rig()
    play(r.executor, r.player, r.node, first_seconds(drive, 90.0),
         Script(joints=("caster_joint", "wheel_left_joint", "wheel_right_joint")))
    est = r.node.finish()
    assert any(est.identified)
    diff = load_declared(r.folder / "ros2_control" / "diff_drive_controller.yaml",
                         "diff_drive_controller", {"left_wheel_names": "STRING_ARRAY",
                                                   "right_wheel_names": "STRING_ARRAY"},
                         context=ros)
    assert diff["left_wheel_names"] == ["wheel_left_joint"]
    assert diff["right_wheel_names"] == ["wheel_right_joint"]


def test_the_example_parameter_file_is_every_parameter_the_node_takes(ros: Any) -> None:
    """The file docs/ros2.md points to, loaded by rcl as --params-file into a node of the
    default name: every parameter it gives is one the node declares, and every one the node
    declares is in it; the node starts with it."""
    from rosgraph_msgs.msg import Clock  # noqa: F401  (the message package is there)

    given = keys_in_file(PARAMS_FILE, "odocal_calibration", ros)
    assert given == {s.name for s in params.SPECS}
    node = CalibrationNode(context=ros, enable_rosout=False,
                           cli_args=["--ros-args", "--params-file", str(PARAMS_FILE)])
    try:
        for spec in params.SPECS:
            value = node.get_parameter(spec.name).value
            expected = spec.default if spec.name not in ("pose_topic",) else value
            assert value == expected or list(value) == list(expected), spec.name
        status = values_of(node.status()[0])
        assert status["updates"] == "0"
    finally:
        node.destroy_node()
