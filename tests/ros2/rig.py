"""A player node that publishes a simulated drive as a vehicle's drivers do, and a fixture that
starts the calibration node under test beside it (real rclpy and Fast DDS, in this process, on
the session's private domain: :mod:`tests.ros2.rosenv`).

The player publishes the drive batch by batch (a second of data at a time), as fast as the
node takes it: ``/clock`` first, then the batch's messages in an order that changes from batch
to batch (poses first, wheels first), with the IMU's a batch late; it waits for the node to
have taken every message before the next batch (the node's own counts), so nothing is lost in
the test and what the node does is what the drive says.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import odocal
from tests.bagwriter import BAG_JOINTS, JOINTS
from tests.ros2.rosenv import require_rclpy

require_rclpy()

from builtin_interfaces.msg import Time  # noqa: E402
from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from geometry_msgs.msg import PoseWithCovarianceStamped  # noqa: E402
from nav_msgs.msg import Odometry  # noqa: E402
from rclpy.experimental import EventsExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from sensor_msgs.msg import Imu, JointState  # noqa: E402
from std_msgs.msg import Float64MultiArray, String  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from odocal.ros2.node import CalibrationNode  # noqa: E402

START_S = 1000.0          # simulated time of the drive's first sample
_counter = iter(range(1_000_000))


def unique(prefix: str) -> str:
    return f"{prefix}{next(_counter)}"


def without_sideslip(d: odocal.Drive) -> odocal.Drive:
    cols = {k: v for k, v in d.columns().items() if k != "beta"}
    return odocal.Drive.from_columns(cols, name=d.name)


def first_seconds(d: odocal.Drive, seconds: float) -> odocal.Drive:
    n = int(seconds / d.t_s) + 1
    return odocal.Drive.from_columns({k: v[:n] for k, v in d.columns().items()}, name=d.name)


def stamp(t: float) -> Time:
    sec = int(np.floor(t))
    nsec = round((t - sec) * 1e9)
    if nsec >= 1_000_000_000:
        sec, nsec = sec + 1, nsec - 1_000_000_000
    return Time(sec=sec, nanosec=nsec)


@dataclass
class Script:
    """How the player turns the drive into messages (defaults: as a car's drivers do)."""

    start_s: float = START_S
    joints: Sequence[str] = tuple(JOINTS)
    positions_only: bool = False           # JointState without velocities
    car: bool = False                      # four wheels (the drive's n_fl, n_fr) and, as the
    steering: bool = True                  # ... fifth joint's position, its steer (rad)
    steering_deg: bool = False             # ... or in degrees
    imu_until_s: float = np.inf            # the IMU goes silent after this (s of the drive)
    pose_type: str = "odometry"            # or pose_with_covariance
    sideslip: bool = False                 # the reference's twist carries the drive's beta
    gyro_offset_radps: float = 0.0
    imu_yaw_deg: float = 0.0               # the IMU mounted turned about z
    skip: Callable[[str, int], bool] = lambda role, k: False      # messages never sent
    wheel_t: Callable[[int, float], float] | None = None          # a wheel message's stamp
    values: Callable[[str, int, Any], None] | None = None         # last touch to a message
    extra: dict[str, Any] = field(default_factory=dict)


class Player(Node):  # type: ignore[misc]
    """Publishes a drive's messages and /clock; collects what the node under test publishes."""

    def __init__(self, context: Any, ns: str, node_ns: str, *, pose_type: str = "odometry"
                 ) -> None:
        super().__init__(unique("player_"), context=context, enable_rosout=False)
        qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        latched = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.clock = self.create_publisher(Clock, "/clock", 10)
        self.wheels = self.create_publisher(JointState, f"{ns}/joint_states", qos)
        self.imu = self.create_publisher(Imu, f"{ns}/imu", qos)
        kind = Odometry if pose_type == "odometry" else PoseWithCovarianceStamped
        self.pose = self.create_publisher(kind, f"{ns}/pose", qos)
        self.diagnostics: list[Any] = []
        self.odometry: list[Any] = []
        self.alarms: list[str] = []
        self.estimates: list[Any] = []
        self.create_subscription(DiagnosticArray, "/diagnostics",
                                 lambda m: self.diagnostics.append(m), 100)
        self.create_subscription(Odometry, f"{node_ns}/odometry",
                                 lambda m: self.odometry.append(m),
                                 QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE))
        self.create_subscription(String, f"{node_ns}/alarms",
                                 lambda m: self.alarms.append(m.data), latched)
        self.create_subscription(Float64MultiArray, f"{node_ns}/estimate",
                                 lambda m: self.estimates.append(m), latched)
        self.export = self.create_client(Trigger, f"{node_ns}/export")
        self.reset = self.create_client(Trigger, f"{node_ns}/reset")

    def statuses(self, name: str = "wheel odometry calibration") -> list[Any]:
        return [s for m in self.diagnostics for s in m.status if s.name.endswith(name)]


def messages(d: odocal.Drive, k: int, script: Script, sim: Any = None) -> dict[str, Any]:
    """The wheel, IMU and reference messages of sample ``k``."""
    t = script.start_s + float(d.t[k])
    t_wheel = script.wheel_t(k, t) if script.wheel_t is not None else t
    rates = [float(d.n_rl[k]) * 2 * np.pi, float(d.n_rr[k]) * 2 * np.pi]
    joints = list(script.joints)
    joint = JointState(name=joints)
    if script.car:
        _car_joints(joint, d, k, script)
    elif script.positions_only:
        # the wheels' angles: the rates summed over the steps before (trapezoidal)
        joint.position = [0.0] * (len(joints) - 2) + [float(v) for v in script.extra["angles"][k]]
    else:
        joint.position = [0.0] * len(joints)
        joint.velocity = [0.0] * (len(joints) - 2) + rates
    joint.header.stamp = stamp(t_wheel)
    imu = Imu()
    imu.header.stamp = stamp(t)
    yaw_rate = float(d.yaw_rate[k]) + script.gyro_offset_radps
    turn = math.radians(script.imu_yaw_deg)
    # a vector of the vehicle's (a_x = 0, a_y) in an IMU turned by `turn` about z
    imu.angular_velocity.z = yaw_rate
    imu.linear_acceleration.x = float(d.a_y[k]) * math.sin(turn)
    imu.linear_acceleration.y = float(d.a_y[k]) * math.cos(turn)
    imu.linear_acceleration.z = 9.81
    pose: Any = Odometry() if script.pose_type == "odometry" else PoseWithCovarianceStamped()
    pose.header.stamp = stamp(t)
    pose.pose.pose.position.x, pose.pose.pose.position.y = float(d.x[k]), float(d.y[k])
    pose.pose.pose.orientation.z = float(np.sin(0.5 * d.psi[k]))
    pose.pose.pose.orientation.w = float(np.cos(0.5 * d.psi[k]))
    if script.sideslip:
        beta = float(d.beta[k])
        pose.twist.twist.linear.x, pose.twist.twist.linear.y = math.cos(beta), math.sin(beta)
    out = {"wheels": joint, "imu": imu, "pose": pose}
    if script.values is not None:
        for role, msg in out.items():
            script.values(role, k, msg)
    return out


def _car_joints(joint: JointState, d: odocal.Drive, k: int, script: Script) -> None:
    """A car's JointState (:data:`BAG_JOINTS`, or ``script.joints`` where it names five): the
    four wheels in that order, then the steering wheel (its position the drive's steer)."""
    joint.name = list(script.joints) if len(script.joints) == 5 else list(BAG_JOINTS)
    steer = float(d.inputs["steer"][k]) if script.steering else 0.0
    steer = math.degrees(steer) if script.steering_deg else steer
    if script.positions_only:
        joint.position = [float(v) for v in script.extra["angles"][k]] + [steer]
    else:
        joint.position = [0.0] * 4 + [steer]
        joint.velocity = [float(d.inputs[c][k]) * 2 * np.pi for c in ("n_fl", "n_fr")] + [
            float(d.n_rl[k]) * 2 * np.pi, float(d.n_rr[k]) * 2 * np.pi, 0.0]


def wheel_angles(d: odocal.Drive, columns: Sequence[str] = ("n_rl", "n_rr")) -> np.ndarray:
    """The wheels' joint angles (rad) whose steps over the drive's samples give its rates
    (``columns``: the drive's wheel columns, in the joints' order)."""
    rates = np.column_stack([d.columns()[c] for c in columns]) * 2 * np.pi
    steps = 0.5 * (rates[1:] + rates[:-1]) * np.diff(d.t)[:, None]
    return np.vstack([np.zeros((1, len(columns))), np.cumsum(steps, axis=0)])


def spin_until(executor: Any, done: Callable[[], bool], what: str, limit_s: float = 60.0) -> None:
    """Spin until ``done()``; a hang guard (not a speed limit): fail after ``limit_s``."""
    deadline = time.monotonic() + limit_s
    while not done():
        executor.spin_once(timeout_sec=0.01)
        if time.monotonic() > deadline:
            pytest.fail(f"ROS 2 did not deliver {what} within {limit_s:.0f} s")


def play(executor: Any, player: Player, node: CalibrationNode, d: odocal.Drive,
         script: Script | None = None, *, batch: int = 40,
         between: Callable[[int], None] | None = None) -> dict[str, int]:
    """Publish the drive (see the module); returns the messages sent per role."""
    script = script or Script()
    before = arrived(node)                  # (what the node took before: a drive goes on)
    sent = dict(before)
    late_imu: list[Any] = []
    pubs = {"wheels": player.wheels, "pose": player.pose}
    for b, start in enumerate(range(0, d.n_samples, batch)):
        ks = range(start, min(start + batch, d.n_samples))
        player.clock.publish(Clock(clock=stamp(script.start_s + float(d.t[ks[0]]))))
        batch_msgs = [(k, messages(d, k, script)) for k in ks]
        for role in (["pose", "wheels"] if b % 2 else ["wheels", "pose"]):
            for k, msgs in batch_msgs:
                if not script.skip(role, k):
                    pubs[role].publish(msgs[role])
                    sent[role] += 1
        for msg in late_imu:
            player.imu.publish(msg)
            sent["imu"] += 1
        late_imu = [msgs["imu"] for k, msgs in batch_msgs
                    if d.t[k] < script.imu_until_s and not script.skip("imu", k)]
        expected = dict(sent)
        # (and the calibrator's answers, where it runs beside the node: as in its thread, each
        # estimate is published before the next batch)
        spin_until(executor, lambda e=expected: arrived(node) == e and node.idle,
                   "the drive's messages")
        if between is not None:
            between(b)
    for msg in late_imu:
        player.imu.publish(msg)
        sent["imu"] += 1
    spin_until(executor, lambda: arrived(node) == sent and node.idle, "the last messages")
    # the clock goes on a little after the drive (a timer tick publishes the diagnostics)
    player.clock.publish(Clock(clock=stamp(script.start_s + float(d.t[-1]) + 0.5)))
    executor.spin_once(timeout_sec=0.05)
    return {role: sent[role] - before[role] for role in sent}


def arrived(node: CalibrationNode) -> dict[str, int]:
    counts = node.arrived()
    counts.setdefault("imu", 0)
    return counts


def settle(executor: Any, player: Player, node: CalibrationNode) -> None:
    """Spin until the player has heard the node's latest estimate on /diagnostics."""
    def heard() -> bool:
        statuses = player.statuses()
        values = {kv.key: kv.value for kv in statuses[-1].values} if statuses else {}
        return values.get("updates") == str(node.updates)

    spin_until(executor, heard, "the latest diagnostics")


def call(executor: Any, client: Any, request: Any, what: str) -> Any:
    """A service's answer (the service found first)."""
    spin_until(executor, client.service_is_ready, f"the service {what}")
    future = client.call_async(request)
    spin_until(executor, future.done, f"the answer of {what}")
    return future.result()


def values_of(status: Any) -> dict[str, str]:
    return {kv.key: kv.value for kv in status.values}


@dataclass
class Rig:
    """What ``rig(...)`` starts: the executor, the player and the node under test."""

    executor: Any
    player: Player
    node: CalibrationNode
    folder: Path


def start_rig(ros: Any, tmp_path: Path, nodes: list[Any], executor: Any, *,
              pose_type: str = "odometry", discover: bool = True, rosout: bool = False,
              **params: Any) -> Rig:
    i = next(_counter)
    ns, node_ns = f"/t{i}", f"/t{i}/odocal"
    folder = tmp_path / f"exports{i}"
    overrides = {"use_sim_time": True, "wheel_topic": f"{ns}/joint_states",
                 "imu_topic": f"{ns}/imu", "pose_topic": f"{ns}/pose",
                 "export_dir": str(folder), "pose_type": pose_type,
                 # (the calibrator in the node's thread: each estimate published before the next
                 # message, as the tests' checks expect; the process beside it has tests of its own)
                 "calibrator_process": False, **params}
    node = CalibrationNode(context=ros, namespace=node_ns, node_name="odocal",
                           enable_rosout=rosout,
                           parameter_overrides=[Parameter(k, value=v)
                                                for k, v in overrides.items()])
    player = Player(ros, ns, f"{node_ns}/odocal", pose_type=pose_type)
    nodes.extend([node, player])
    executor.add_node(node)
    executor.add_node(player)
    if discover and node.get_parameter("autostart").value:
        spin_until(executor, lambda: player.wheels.get_subscription_count() > 0
                   and player.pose.get_subscription_count() > 0
                   and (player.imu.get_subscription_count() > 0
                        or not node.get_parameter("imu_topic").value), "discovery")
    return Rig(executor, player, node, folder)


def rig_fixture(ros: Any, tmp_path: Path) -> Iterator[Callable[..., Rig]]:
    """The body of the ``rig`` fixture (tests/ros2/conftest.py)."""
    nodes: list[Any] = []
    executor = EventsExecutor(context=ros)

    def start(**params: Any) -> Rig:
        return start_rig(ros, tmp_path, nodes, executor, **params)

    yield start
    for node in nodes:
        executor.remove_node(node)
        node.destroy_node()
    executor.shutdown()
