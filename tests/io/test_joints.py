"""One rule for which joints are the wheels, for the bag reader and the live node (issue 38: the
bag took ``robot_front_left_wheel_joint`` as a rear wheel and read names the node refused)."""

from __future__ import annotations

from typing import Any

import pytest

from odocal.errors import ConfigError, DataError
from odocal.io.rosbag import _joints
from odocal.ros2.inputs import wheel_joints


def _rear(found: Any) -> tuple[int, int]:
    return found.velocities["rear_left"], found.velocities["rear_right"]

FOUND = [
    (["front_left_wheel", "front_right_wheel", "rear_left_wheel", "rear_right_wheel"], (2, 3)),
    (["left_wheel_joint", "right_wheel_joint"], (0, 1)),
    (["wheel_left_joint", "wheel_right_joint", "caster_back_joint"], (0, 1)),
    (["front_left_steer", "front_right_steer", "left_wheel", "right_wheel"], (2, 3)),
    (["rl", "rr"], (0, 1)),
    (["rl.wheel", "rr.wheel"], (0, 1)),
    (["rl-wheel", "rr-wheel"], (0, 1)),
    (["r_left_wheel_joint", "r_right_wheel_joint"], (0, 1)),
    (["wheel_back_right", "wheel_back_left"], (1, 0)),
    # a robot's front wheels beside its rear ones: the front ones are never taken
    (["robot_front_left_wheel_joint", "robot_front_right_wheel_joint",
      "robot_rear_left_wheel_joint", "robot_rear_right_wheel_joint"], (2, 3)),
]


@pytest.mark.parametrize(("names", "found"), FOUND)
def test_the_bag_and_the_node_find_the_same_wheels(names: list[str],
                                                   found: tuple[int, int]) -> None:
    assert wheel_joints(names, "", "", "/joint_states") == found
    assert _rear(_joints(names, {}, "/joint_states")) == found


@pytest.mark.parametrize("names", [
    ["robot_front_left_wheel_joint", "robot_front_right_wheel_joint"],   # front wheels only
    ["left_wheel", "right_wheel", "left_wheel_2"],
    ["arm_joint", "gripper_joint"],
])
def test_joints_the_rule_cannot_tell_are_refused_by_both_naming_the_setting(
        names: list[str]) -> None:
    with pytest.raises(ConfigError, match=r"cannot tell which joint is the left wheel among "
                                          r".*; set left_wheel_joint"):
        wheel_joints(names, "", "", "/joint_states")
    with pytest.raises(DataError, match=r"cannot tell which joint is the left wheel among "
                                        r".*; set the mapping's \[wheels\] rear_left"):
        _joints(names, {}, "/joint_states")


def test_named_joints_win_and_a_missing_name_is_refused() -> None:
    names = ["a", "b", "rear_left_wheel", "rear_right_wheel"]
    assert wheel_joints(names, "b", "a", "/j") == (1, 0)
    assert _rear(_joints(names, {"rear_left": "b", "rear_right": "a"}, "/j")) == (1, 0)
    with pytest.raises(DataError, match=r"no joint named 'c' \(the mapping's \[wheels\] "
                                        r"rear_left\); joints: a, b"):
        _joints(names, {"rear_left": "c"}, "/j")


@pytest.mark.parametrize(("names", "front"), [
    (["front_left_wheel", "front_right_wheel", "rear_left_wheel", "rear_right_wheel"], (0, 1)),
    (["robot_front_left_wheel_joint", "robot_front_right_wheel_joint",
      "robot_rear_left_wheel_joint", "robot_rear_right_wheel_joint"], (0, 1)),
    (["rl", "rr", "fl", "fr"], (2, 3)),
    (["wheel_rear_left", "wheel_rear_right", "wheel_front_right", "wheel_front_left"], (3, 2)),
    # steering joints and casters turn a wheel about its vertical axis: never a front wheel
    (["front_left_steer", "front_right_steer", "left_wheel", "right_wheel"], None),
    (["left_wheel_joint", "right_wheel_joint", "front_caster_left", "front_caster_right"],
     None),
    (["left_wheel_joint", "right_wheel_joint"], None),
])
def test_a_cars_front_wheels_are_read_beside_the_rear_ones(
        names: list[str], front: tuple[int, int] | None) -> None:
    found = _joints(names, {}, "/joint_states")
    if front is None:
        assert set(found.velocities) == {"rear_left", "rear_right"}
    else:
        assert (found.velocities["front_left"], found.velocities["front_right"]) == front
    assert found.steering is None


def test_front_wheels_the_names_do_not_pair_are_left_out_and_named_ones_must_pair() -> None:
    # found by their names: one on each side, or the log is read as it read before (rear only)
    for names in (["rear_left", "rear_right", "front_left_wheel"],
                  ["rear_left", "rear_right", "front_left_a", "front_left_b", "front_right"]):
        assert set(_joints(names, {}, "/j").velocities) == {"rear_left", "rear_right"}
    # named by the user: both, and there
    with pytest.raises(DataError, match=r"a front wheel joint is named without the other; "
                                        r"set the mapping's \[wheels\] front_right too"):
        _joints(["rear_left", "rear_right", "x"], {"front_left": "x"}, "/j")
    with pytest.raises(DataError, match=r"no joint named 'y' \(the mapping's \[wheels\] "
                                        r"front_right\)"):
        _joints(["rear_left", "rear_right", "x"], {"front_left": "x", "front_right": "y"},
                "/j")
    with pytest.raises(DataError, match=r"the same joint is taken for a rear and a front wheel "
                                        r"\(rear_left\)"):
        _joints(["rear_left", "rear_right", "x"], {"front_left": "rear_left",
                                                   "front_right": "x"}, "/j")


def test_the_steering_joint_is_the_one_the_mapping_names() -> None:
    names = ["rear_left", "rear_right", "steering_wheel"]
    assert _joints(names, {}, "/j").steering is None            # never guessed
    assert _joints(names, {"steering": "steering_wheel"}, "/j").steering == 2
    with pytest.raises(DataError, match=r"no joint named 'steer' \(the mapping's \[wheels\] "
                                        r"steering\)"):
        _joints(names, {"steering": "steer"}, "/j")


def test_a_joint_without_its_velocity_or_the_steering_joint_without_a_position_is_one_line(
        ) -> None:
    """A JointState whose arrays are shorter than its names (a driver that publishes positions
    only, or no positions): the bag reader names the joint and what it lacks, in one line."""
    from types import SimpleNamespace

    from odocal.io.rosbag import _extract

    section = {"_type": "sensor_msgs/msg/JointState", "steering": "steering_wheel"}
    names = ["rear_left", "rear_right", "steering_wheel"]
    no_velocity = SimpleNamespace(name=names, velocity=[], position=[0.0, 0.0, 0.1])
    with pytest.raises(DataError, match=r"^topic /j: the joint 'rear_left' \(rear_left\) has "
                                        r"no velocity \(0 velocities for 3 joints\)$"):
        _extract("wheels", section, no_velocity, {}, "/j")
    no_position = SimpleNamespace(name=names, velocity=[1.0, 1.0, 0.0], position=[])
    with pytest.raises(DataError, match=r"^topic /j: the steering joint 'steering_wheel' has "
                                        r"no position \(0 positions for 3 joints\)$"):
        _extract("wheels", section, no_position, {}, "/j")
    fine = SimpleNamespace(name=names, velocity=[6.0, 6.2, 0.0], position=[0.0, 0.0, 0.1])
    assert _extract("wheels", section, fine, {}, "/j") == {
        "rear_left": 6.0, "rear_right": 6.2, "steering": 0.1}
