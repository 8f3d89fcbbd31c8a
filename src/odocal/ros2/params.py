"""The node's ROS 2 parameters: each declared once, with its type, range and whether it may
change while the node runs, and every value checked at start with a one-line error.

rclpy itself refuses a value of another type or out of a declared range with an exception and a
stack, and ignores parameters nobody declared (a misspelt ``wheel_topik:=`` changes nothing). So
the node reads the values given to it (``-p``, ``--params-file``, launch files) before it
declares anything and turns every such problem into a :class:`~odocal.errors.ConfigError` that
names the parameter, the value and what would be right; names it does not know are refused.
At run time rclpy enforces the descriptors (read-only, type, range) and the node's own
checks (:func:`check_value`) run before a change is taken.
"""

from __future__ import annotations

import difflib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from odocal.errors import ConfigError
from odocal.output.export import CAR_TARGETS, TARGETS

#: The export targets ``export_targets`` may name (``yaml``: odometry_parameters.yaml;
#: ``ackermann``: the four_wheel model's only, left out for the rear axle's).
EXPORTS = (*TARGETS, *CAR_TARGETS, "yaml")
#: The steering joint's position's units.
STEERING_UNITS = ("rad", "deg")
#: The reference pose's message types.
POSE_TYPES = ("odometry", "pose_with_covariance")
#: Parameters every ROS 2 node has (and the QoS overrides rclpy reads by prefix).
ROS_PARAMETERS = ("use_sim_time", "start_type_description_service")
_ROS_PREFIXES = ("qos_overrides.",)

_TYPE_NAMES = {bool: "a boolean (true or false)", int: "an integer", float: "a double",
               str: "a string", list: "a list"}


@dataclass(frozen=True)
class Spec:
    """One parameter: default, what it is, whether it may change at run time, its range."""

    name: str
    default: Any
    description: str
    writable: bool = False
    low: float | None = None
    high: float | None = None
    choices: tuple[str, ...] = ()
    any_type: bool = False          # a string (comma list) or a list of strings

    @property
    def kind(self) -> str:
        """The value's type: bool, integer, double, string, string_array or double_array."""
        if self.any_type:
            return "string_array"
        d = self.default
        if isinstance(d, bool):
            return "bool"
        if isinstance(d, int):
            return "integer"
        if isinstance(d, float):
            return "double"
        if isinstance(d, str):
            return "string"
        return "double_array" if d and isinstance(d[0], float) else "string_array"


SPECS: tuple[Spec, ...] = (
    Spec("wheel_topic", "/joint_states", "sensor_msgs/JointState with the two wheel joints' "
         "velocities (rad/s) or, where a driver sends none, their positions (rad)"),
    Spec("left_wheel_joint", "", "the left wheel's joint (empty: the one joint named rear or "
         "back and left, else the one left wheel joint that is not a front or steering one)"),
    Spec("right_wheel_joint", "", "the right wheel's joint (as left_wheel_joint)"),
    Spec("front_left_wheel_joint", "", "the four_wheel model's ([vehicle] model in "
         "settings_file) front left wheel joint (empty: the one joint named front and left, "
         "not a steering one)"),
    Spec("front_right_wheel_joint", "", "the front right wheel's joint (as "
         "front_left_wheel_joint)"),
    Spec("steering_joint", "", "the four_wheel model's steering-wheel joint in the same "
         "JointState (its position: the steering wheel's angle; empty: no steering, the "
         "steering ratio and offset are not calibrated); never guessed from the names"),
    Spec("steering_unit", "rad", "the steering joint's position's unit: rad or deg",
         choices=STEERING_UNITS),
    Spec("imu_topic", "/imu/data", "sensor_msgs/Imu: angular_velocity.z and "
         "linear_acceleration.y in the vehicle's axes (imu_rotation_deg); empty: no IMU "
         "(a_y = 0, d not identified)"),
    Spec("imu_rotation_deg", [0.0, 0.0, 0.0], "the IMU's frame against the vehicle's: roll, "
         "pitch, yaw in degrees (rotating the IMU's vectors into base_link)"),
    Spec("pose_topic", "/odometry/filtered", "the reference pose (a localisation stack's)"),
    Spec("pose_type", "odometry", "the reference's message type: odometry "
         "(nav_msgs/Odometry) or pose_with_covariance "
         "(geometry_msgs/PoseWithCovarianceStamped)", choices=POSE_TYPES),
    Spec("sideslip_from_reference", False, "take the sideslip (beta) from the reference "
         "Odometry's twist (atan(vy / vx) in its child frame) as odocal replay takes a drive "
         "file's beta column"),
    Spec("odometry_topic", "~/odometry", "the calibrated wheel odometry (nav_msgs/Odometry)"),
    Spec("frame_id", "odom", "the odometry's frame"),
    Spec("child_frame_id", "base_link", "the odometry's child frame"),
    Spec("settings_file", "", "an odocal settings file (TOML), as --config"),
    Spec("datasheet", "", "the datasheet values, as --datasheet (c_e=1.95,t_r=1.51 or "
         "wheel_radius=0.31,wheel_separation=1.5)"),
    Spec("export_dir", "", "where ~/export and the shutdown write the export files (empty: "
         "nowhere)", writable=True),
    Spec("export_targets", list(EXPORTS), "which export files: any of "
         + ", ".join(EXPORTS) + " (a list, or one string with commas)", writable=True,
         choices=EXPORTS, any_type=True),
    Spec("silence_timeout_s", 2.0, "an input silent this long (s) is named, and nothing is "
         "calibrated until it speaks again", writable=True, low=0.05, high=3600.0),
    Spec("diagnostics_period_s", 1.0, "how often the status goes to /diagnostics (s, on the "
         "node's clock)", writable=True, low=0.1, high=3600.0),
    Spec("qos_depth", 5000, "the input queues' depth (messages that wait while an estimate is "
         "taken)", low=1, high=100000),
    Spec("qos_reliable", False, "reliable input subscriptions (false: best effort, which hears "
         "reliable and best-effort publishers alike)"),
    Spec("controller_name", "", "a running diff_drive_controller to set the identified "
         "multipliers on (e.g. /diff_drive_controller; empty: none)"),
    Spec("calibrator_process", True, "push and estimate in a process of the calibrator's own "
         "beside the node's (the estimates never hold up the messages); false: in the node's "
         "thread"),
    Spec("autostart", True, "configure and activate at once (false: wait for a lifecycle "
         "manager)"),
)
BY_NAME: Mapping[str, Spec] = {s.name: s for s in SPECS}


def _type_of(value: Any) -> str:
    if isinstance(value, list | tuple):
        if not value:
            return "list"
        inner = _type_of(value[0])
        return f"a list of {inner.removeprefix('a ').removeprefix('an ')}s"
    return _TYPE_NAMES.get(type(value), type(value).__name__)


def _fits(spec: Spec, value: Any) -> bool:
    kind = spec.kind
    if kind == "bool":
        return isinstance(value, bool)
    if kind == "integer":
        return isinstance(value, int) and not isinstance(value, bool)
    if kind == "double":
        return isinstance(value, float)
    if kind == "string":
        return isinstance(value, str)
    if kind == "double_array":
        return isinstance(value, list | tuple) and all(isinstance(v, float) for v in value)
    if spec.any_type:
        return isinstance(value, str) or (isinstance(value, list | tuple)
                                          and all(isinstance(v, str) for v in value))
    return isinstance(value, list | tuple) and all(isinstance(v, str) for v in value)


def _wanted(spec: Spec) -> str:
    """What type a parameter takes, in words (with an example where a type is easily
    mistaken: 2.0 for 2)."""
    if spec.any_type:
        return "a list of strings or one string with commas"
    if spec.kind == "double":
        return f"a double (e.g. {float(spec.default)!r})"
    if spec.kind == "double_array":
        return (f"a list of {len(spec.default)} doubles (e.g. "
                f"{[float(v) for v in spec.default]})")
    return {"integer": "an integer", "bool": "a boolean (true or false)", "string": "a string",
            "string_array": "a list of strings"}[spec.kind]


def check_value(spec: Spec, value: Any) -> str | None:
    """What is wrong with ``value`` for ``spec`` (None: nothing), in words that name it."""
    head = f"parameter {spec.name}: {value!r}"
    if not _fits(spec, value):
        return f"{head} is {_type_of(value)}; it takes {_wanted(spec)}"
    if spec.kind in ("integer", "double"):
        if (spec.low is not None and value < spec.low) or \
                (spec.high is not None and value > spec.high):
            return f"{head} is out of range; it takes {spec.low:g} to {spec.high:g}"
    if spec.kind == "double_array" and len(value) != len(spec.default):
        return f"{head} has {len(value)} values; it takes {len(spec.default)}"
    if spec.choices:
        values = targets(value) if spec.any_type else [value]
        bad = [v for v in values if v not in spec.choices]
        if bad:
            return f"{head}: unknown {bad[0]!r}; choose from {', '.join(spec.choices)}"
    return None


def targets(value: str | Sequence[str]) -> list[str]:
    """``export_targets`` as a list: a string is a comma list."""
    items = value.split(",") if isinstance(value, str) else list(value)
    return [t.strip() for t in items if t.strip()]


def check_given(given: Mapping[str, Any]) -> None:
    """The values given to the node at start (name -> value): a ConfigError for the first name
    it does not know or value it cannot take."""
    for name, value in given.items():
        if name in ROS_PARAMETERS or name.startswith(_ROS_PREFIXES):
            continue
        spec = BY_NAME.get(name)
        if spec is None:
            near = difflib.get_close_matches(name, list(BY_NAME), n=1)
            raise ConfigError(f"unknown parameter {name!r}"
                              + (f" (did you mean {near[0]!r}?)" if near else "")
                              + f"; the node's parameters: {', '.join(BY_NAME)}")
        problem = check_value(spec, value)
        if problem is not None:
            raise ConfigError(problem)
