"""``odocal ros2``: the online calibrator as a real ROS 2 node (issue 29, part 2).

Every test starts real nodes in this process on the session's private ROS 2 domain
(:mod:`tests.ros2.rosenv`): a player node publishes a simulated drive's JointState, Imu and
Odometry messages and ``/clock`` faster than real time (as fast as the node takes them) on
simulated time, and the calibration node under test listens through Fast DDS.
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import odocal
from odocal.cli.main import EXIT_OK, main
from odocal.model.parameters import Parameters
from tests.bagwriter import JOINTS, write_bag
from tests.ros2.rosenv import load_declared, require_rclpy, ros_context

require_rclpy()

from builtin_interfaces.msg import Time  # noqa: E402
from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from nav_msgs.msg import Odometry  # noqa: E402
from rclpy.experimental import EventsExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from sensor_msgs.msg import Imu, JointState  # noqa: E402
from std_msgs.msg import String  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402

from odocal.ros2.node import CalibrationNode  # noqa: E402

START_S = 1000.0          # simulated time of the drive's first sample
_counter = iter(range(1_000_000))


@pytest.fixture(scope="module")
def ros() -> Iterator[Any]:
    with ros_context() as context:
        yield context


@pytest.fixture(scope="module")
def drive() -> odocal.Drive:
    """A five-minute realistic city drive as a ROS 2 stack sees it: no sideslip input (a
    JointState, an Imu and an Odometry carry none), so ``beta`` is zero here and in the file
    ``odocal replay`` reads."""
    sim = odocal.simulate(duration_s=300.0, seed=5, noise="realistic")
    return _without_sideslip(sim.drive)


def _without_sideslip(d: odocal.Drive) -> odocal.Drive:
    cols = {k: v for k, v in d.columns().items() if k != "beta"}
    return odocal.Drive.from_columns(cols, name=d.name)


def _stamp(t: float) -> Time:
    sec = int(np.floor(t))
    nsec = round((t - sec) * 1e9)
    if nsec >= 1_000_000_000:
        sec, nsec = sec + 1, nsec - 1_000_000_000
    return Time(sec=sec, nanosec=nsec)


class Player(Node):  # type: ignore[misc]
    """Publishes a drive's messages and /clock; collects what the node under test publishes."""

    def __init__(self, context: Any, ns: str, node_ns: str) -> None:
        super().__init__(f"player_{next(_counter)}", context=context, enable_rosout=False)
        qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        self.clock = self.create_publisher(Clock, "/clock", 10)
        self.wheels = self.create_publisher(JointState, f"{ns}/joint_states", qos)
        self.imu = self.create_publisher(Imu, f"{ns}/imu", qos)
        self.pose = self.create_publisher(Odometry, f"{ns}/pose", qos)
        self.diagnostics: list[Any] = []
        self.odometry: list[Any] = []
        self.alarms: list[str] = []
        self.create_subscription(DiagnosticArray, "/diagnostics",
                                 lambda m: self.diagnostics.append(m), 100)
        self.create_subscription(Odometry, f"{node_ns}/odometry",
                                 lambda m: self.odometry.append(m),
                                 QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE))
        self.create_subscription(String, f"{node_ns}/alarms", lambda m: self.alarms.append(m.data),
                                 QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE,
                                            durability=DurabilityPolicy.TRANSIENT_LOCAL))
        self.export = self.create_client(Trigger, f"{node_ns}/export")

    def statuses(self, name: str) -> list[Any]:
        return [s for m in self.diagnostics for s in m.status if s.name.endswith(name)]


def _messages(d: odocal.Drive, k: int, joints: list[str]) -> tuple[Any, Any, Any]:
    t = START_S + float(d.t[k])
    stamp = _stamp(t)
    joint = JointState(name=joints, position=[0.0] * 4,
                       velocity=[0.0, 0.0, float(d.n_rl[k]) * 2 * np.pi,
                                 float(d.n_rr[k]) * 2 * np.pi])
    joint.header.stamp = stamp
    imu = Imu()
    imu.header.stamp = stamp
    imu.angular_velocity.z = float(d.yaw_rate[k])
    imu.linear_acceleration.y = float(d.a_y[k])
    imu.linear_acceleration.z = 9.81
    pose = Odometry()
    pose.header.stamp = stamp
    pose.pose.pose.position.x, pose.pose.pose.position.y = float(d.x[k]), float(d.y[k])
    pose.pose.pose.orientation.z = float(np.sin(0.5 * d.psi[k]))
    pose.pose.pose.orientation.w = float(np.cos(0.5 * d.psi[k]))
    return joint, imu, pose


def _spin_until(executor: Any, done: Any, what: str, limit_s: float = 60.0) -> None:
    """Spin until ``done()``; a hang guard (not a speed limit): fail after ``limit_s``."""
    deadline = time.monotonic() + limit_s
    while not done():
        executor.spin_once(timeout_sec=0.01)
        if time.monotonic() > deadline:
            pytest.fail(f"ROS 2 did not deliver {what} within {limit_s:.0f} s")


def play(executor: Any, player: Player, node: CalibrationNode, d: odocal.Drive, *,
         joints: list[str] = JOINTS, imu_until_s: float = np.inf, batch: int = 40) -> None:
    """Publish the drive batch by batch (a second of data at a time), as fast as the node takes
    it: /clock first, then the batch's messages in an order that changes from batch to batch
    (poses first, wheels first), with the IMU's a batch late."""
    sent = {"wheels": 0, "imu": 0, "pose": 0}
    late_imu: list[Any] = []
    for b, start in enumerate(range(0, d.n_samples, batch)):
        ks = range(start, min(start + batch, d.n_samples))
        player.clock.publish(Clock(clock=_stamp(START_S + float(d.t[ks[0]]))))
        triples = [_messages(d, k, joints) for k in ks]
        order = ["pose", "wheels"] if b % 2 else ["wheels", "pose"]
        for role in order:
            for joint, _, pose in triples:
                (player.wheels if role == "wheels" else player.pose).publish(
                    joint if role == "wheels" else pose)
                sent[role] += 1
        for msg in late_imu:
            player.imu.publish(msg)
            sent["imu"] += 1
        late_imu = [imu for k, (_, imu, _) in zip(ks, triples, strict=True)
                    if d.t[k] < imu_until_s]
        expected = dict(sent)
        _spin_until(executor, lambda e=expected: _received(node) == e, "the drive's messages")
    for msg in late_imu:
        player.imu.publish(msg)
        sent["imu"] += 1
    _spin_until(executor, lambda: _received(node) == sent, "the last messages")
    # the clock goes on a little after the drive (a timer tick publishes the diagnostics)
    player.clock.publish(Clock(clock=_stamp(START_S + float(d.t[-1]) + 0.5)))
    executor.spin_once(timeout_sec=0.05)


def settle(executor: Any, player: Player, node: CalibrationNode) -> None:
    """Spin until the player has heard the node's latest estimate on /diagnostics."""
    def heard() -> bool:
        statuses = player.statuses("wheel odometry calibration")
        values = {kv.key: kv.value for kv in statuses[-1].values} if statuses else {}
        return values.get("updates") == str(node.updates)

    _spin_until(executor, heard, "the latest diagnostics")


def _received(node: CalibrationNode) -> dict[str, int]:
    counts = {t.role: t.messages for t in node.topics}
    counts.setdefault("imu", 0)
    return counts


@pytest.fixture()
def rig(ros: Any, tmp_path: Path) -> Iterator[Any]:
    """A function that starts a calibration node (with parameter overrides) and a player on
    topics of their own; both are destroyed after the test."""
    nodes: list[Any] = []
    executor = EventsExecutor(context=ros)

    def start(**params: Any) -> tuple[Any, Player, CalibrationNode]:
        i = next(_counter)
        ns, node_ns = f"/t{i}", f"/t{i}/odocal"
        overrides = {"use_sim_time": True, "wheel_topic": f"{ns}/joint_states",
                     "imu_topic": f"{ns}/imu", "pose_topic": f"{ns}/pose",
                     "export_dir": str(tmp_path / f"exports{i}"), **params}
        node = CalibrationNode(context=ros, namespace=node_ns, node_name="odocal",
                               enable_rosout=False,
                               parameter_overrides=[Parameter(k, value=v)
                                                    for k, v in overrides.items()])
        player = Player(ros, ns, f"{node_ns}/odocal")
        nodes.extend([node, player])
        executor.add_node(node)
        executor.add_node(player)
        # discovery (in this process: immediate) before the first message
        if "wheel_topic" not in params:
            _spin_until(executor, lambda: player.wheels.get_subscription_count() > 0
                        and player.pose.get_subscription_count() > 0, "discovery")
        return executor, player, node

    yield start
    for node in nodes:
        executor.remove_node(node)
        node.destroy_node()
    executor.shutdown()


def test_the_node_calibrates_as_replay_does(rig: Any, drive: odocal.Drive,
                                            tmp_path: Path, ros: Any) -> None:
    # a stand-in for a running diff_drive_controller: a real ROS 2 parameter service with the
    # parameters the controller declares (ros2_controllers 4.42.1), not the controller itself
    # (no ros2_control on the package index)
    name = f"ctl{next(_counter)}"
    controller = Node("diff_drive_controller", namespace=f"/{name}", context=ros,
                      enable_rosout=False)
    for key, value in (("wheel_radius", 0.31), ("wheel_separation", 1.5),
                       ("wheel_separation_multiplier", 1.0),
                       ("left_wheel_radius_multiplier", 1.0),
                       ("right_wheel_radius_multiplier", 1.0)):
        controller.declare_parameter(key, value)
    executor, player, node = rig(controller_name=f"/{name}/diff_drive_controller")
    executor.add_node(controller)
    play(executor, player, node, drive)
    est = node.finish()
    settle(executor, player, node)
    def pushed() -> bool:       # the final estimate's multipliers (after earlier ones)
        value = controller.get_parameter("wheel_separation_multiplier").value
        return bool(abs(value * 1.5 - est.theta.t_r) < 1e-12)

    _spin_until(executor, pushed, "the final multipliers to the controller")
    assert node.controller_note.startswith("set wheel_separation_multiplier=") or \
        node.controller_note.startswith("set left_wheel_radius_multiplier=")
    left = controller.get_parameter("left_wheel_radius_multiplier").value
    assert left * 2 * np.pi * 0.31 == pytest.approx(est.theta.c_e + est.theta.c_d / 2, rel=1e-9)
    executor.remove_node(controller)
    controller.destroy_node()
    # odocal replay --no-batch on the same drive
    path = tmp_path / "drive.parquet"
    odocal.save_drive(drive, path)
    assert main(["replay", str(path), "--out", str(tmp_path / "replay"), "--no-batch",
                 "--no-report", "-q"]) == EXIT_OK
    replayed = json.loads((tmp_path / "replay" / "calibration.json").read_text())
    theta = np.array([replayed["theta"][n] for n in ("c_e", "c_d", "t_r", "d")])
    std = np.array([replayed["std"][n] for n in ("c_e", "c_d", "t_r", "d")])
    assert all(est.identified) and np.all(std > 0)
    assert np.all(np.abs(est.theta.as_array() - theta) <= 0.01 * std), \
        (est.theta.as_array() - theta) / std
    assert np.allclose(est.std, std, rtol=0.01)
    # /diagnostics: OK, with the parameters, their std and the distance as key/values
    [*_, last] = player.statuses("wheel odometry calibration")
    assert last.level == b"\x00", last.message
    values = {kv.key: kv.value for kv in last.values}
    assert float(values["c_e"]) == pytest.approx(est.theta.c_e, rel=1e-9)
    assert float(values["t_r_std"]) == pytest.approx(est.std[2], rel=1e-2)
    assert float(values["distance_km"]) == pytest.approx(drive.distance_m / 1000, rel=0.02)
    assert values["d_identified"] == "true" and not player.alarms
    # the calibrated wheel odometry: one message per wheel message, the twist from the
    # calibration, its covariance from the measured noise once there is an estimate
    assert len(player.odometry) == drive.n_samples
    final = player.odometry[-1]
    c_rl = est.theta.c_e + est.theta.c_d / 2 + est.theta.d * drive.a_y[-1]
    c_rr = est.theta.c_e - est.theta.c_d / 2 - est.theta.d * drive.a_y[-1]
    v = 0.5 * (drive.n_rl[-1] * c_rl + drive.n_rr[-1] * c_rr)
    assert final.twist.twist.linear.x == pytest.approx(v, rel=1e-3)
    assert final.header.stamp.sec == int(START_S + drive.t[-1])
    assert 0 < final.twist.covariance[0] < 0.1 and 0 < final.twist.covariance[35] < 0.1
    assert player.odometry[0].twist.covariance[0] == 1e6     # before any estimate: unknown
    # the export files on request, loaded as ROS 2 loads them
    assert player.export.wait_for_service(timeout_sec=10)
    future = player.export.call_async(Trigger.Request())
    _spin_until(executor, future.done, "the export service's answer")
    assert future.result().success, future.result().message
    folder = Path(node.get_parameter("export_dir").value)
    diff = load_declared(folder / "ros2_control" / "diff_drive_controller.yaml",
                         "diff_drive_controller",
                         {"left_wheel_names": "STRING_ARRAY", "wheel_separation": "DOUBLE",
                          "wheel_separation_multiplier": "DOUBLE"}, context=ros)
    assert diff["left_wheel_names"] == ["rear_left_wheel"]           # the joint it used
    assert diff["wheel_separation"] * diff["wheel_separation_multiplier"] == \
        pytest.approx(est.theta.t_r)
    assert (folder / "odometry_parameters.yaml").is_file()


def test_swapped_wheel_joints_give_an_error_and_no_parameters(rig: Any,
                                                              drive: odocal.Drive) -> None:
    executor, player, node = rig(left_wheel_joint="rear_right_wheel",
                                 right_wheel_joint="rear_left_wheel")
    play(executor, player, node, _first_seconds(drive, 160.0))
    est = node.finish()
    settle(executor, player, node)
    assert node.calibrator.halted and not est.success
    [*_, last] = player.statuses("wheel odometry calibration")
    assert last.level == b"\x02"
    assert "swapped" in last.message
    keys = {kv.key for kv in last.values}
    assert not keys & {"c_e", "c_d", "t_r", "d", "c_e_std"}
    assert not any(s.level == b"\x00" for s in player.statuses("wheel odometry calibration"))
    future = player.export.call_async(Trigger.Request())
    _spin_until(executor, future.done, "the export service's answer")
    assert not future.result().success and "contradict" in future.result().message
    assert not Path(node.get_parameter("export_dir").value).exists()


def test_a_two_percent_step_in_c_e_raises_an_alarm(rig: Any) -> None:
    true = odocal.TRUE_PARAMETERS
    after = Parameters(true.c_e * 0.98, true.c_d, true.t_r, true.d)
    sim = odocal.simulate(duration_s=360.0, seed=7, noise="realistic", change=(200.0, after))
    executor, player, node = rig()
    play(executor, player, node, _without_sideslip(sim.drive))
    node.finish()
    settle(executor, player, node)
    assert player.alarms, "no alarm on ~/alarms"
    alarm = json.loads(player.alarms[0])
    assert alarm["parameter"] == "c_e" and alarm["relative_change"] < 0
    assert alarm["detected_t"] > START_S + 200.0
    [status, *_] = player.statuses("change alarm")
    assert status.level == b"\x01" and "c_e moved" in status.message


def test_a_silent_imu_topic_is_named(rig: Any, drive: odocal.Drive) -> None:
    executor, player, node = rig(silence_timeout_s=2.0)
    twenty = _first_seconds(drive, 20.0)
    play(executor, player, node, twenty, imu_until_s=8.0)
    statuses = player.statuses("wheel odometry calibration")
    named = [s for s in statuses if "no message on" in s.message]
    assert named and all(s.level == b"\x01" for s in named)
    assert f"{node.get_parameter('imu_topic').value} (imu) for" in named[-1].message
    assert "/joint_states" not in named[-1].message and "/pose" not in named[-1].message
    # nothing was calibrated from the wheels and the pose alone while it was silent
    assert node.calibrator.details_samples() < 9.0 * 40


def _first_seconds(d: odocal.Drive, seconds: float) -> odocal.Drive:
    n = int(seconds / d.t_s) + 1
    cols = {k: v[:n] for k, v in d.columns().items()}
    return odocal.Drive.from_columns(cols, name=d.name)


def test_a_ros2_bag_played_through_the_node(rig: Any, ros: Any, tmp_path: Path) -> None:
    """A ROS 2 bag (tests/bagwriter.py, sqlite3) replayed by publishing its serialized messages
    on their topics with the bag's clock: the node's estimate is odocal replay's on the bag."""
    from rosbags.highlevel import AnyReader

    sim = odocal.simulate(duration_s=150.0, seed=2, noise="realistic")
    bag = write_bag(_without_sideslip(sim.drive), tmp_path / "drive_bag", "ros2")
    expected = odocal.replay(bag, fmt="rosbag").estimate
    executor, player, node = rig(pose_topic="/bag/odom", wheel_topic="/bag/joint_states",
                                 imu_topic="/bag/imu/data")
    kinds = {"/joint_states": JointState, "/imu/data": Imu, "/odom": Odometry}
    qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
    pubs = {topic: player.create_publisher(kind, f"/bag{topic}", qos)
            for topic, kind in kinds.items()}
    _spin_until(executor, lambda: all(p.get_subscription_count() for p in pubs.values()),
                "discovery")
    sent = 0
    with AnyReader([bag]) as reader:
        for i, (conn, receive_ns, raw) in enumerate(reader.messages()):
            if i % 120 == 0:
                player.clock.publish(Clock(clock=_stamp(receive_ns * 1e-9)))
            pubs[conn.topic].publish(bytes(raw))           # the bag's CDR bytes as they are
            sent += 1
            if sent % 120 == 0:
                _spin_until(executor, lambda s=sent: sum(_received(node).values()) == s,
                            "the bag's messages")
    _spin_until(executor, lambda: sum(_received(node).values()) == sent, "the bag's messages")
    est = node.finish()
    assert sent == 3 * sim.drive.n_samples
    assert any(est.identified)
    for ours, theirs, s, ok in zip(est.theta.as_array(), expected.theta.as_array(),
                                   expected.std, expected.identified, strict=True):
        if ok:
            assert abs(ours - theirs) <= 0.01 * s


def test_without_rclpy_the_command_says_what_to_install(monkeypatch: pytest.MonkeyPatch,
                                                       capsys: pytest.CaptureFixture[str]
                                                       ) -> None:
    import sys

    monkeypatch.setitem(sys.modules, "rclpy", None)
    monkeypatch.delitem(sys.modules, "odocal.ros2.node", raising=False)
    code = main(["ros2"])
    err = capsys.readouterr().err
    assert code == 1 and "pip install 'odocal[ros2]'" in err and len(err.splitlines()) == 1


def test_bad_ros_arguments_are_one_line_errors(capsys: pytest.CaptureFixture[str],
                                               tmp_path: Path) -> None:
    code = main(["ros2", "--ros-args", "--params-file", str(tmp_path / "none.yaml")])
    err = capsys.readouterr().err
    assert code == 1 and "ROS 2 arguments" in err and len(err.strip().splitlines()) == 1


def test_bad_node_parameters_are_one_line_errors(ros: Any) -> None:
    with pytest.raises(odocal.ConfigError, match="export_targets: unknown target 'ros3'"):
        CalibrationNode(context=ros, node_name=f"bad{next(_counter)}", enable_rosout=False,
                        parameter_overrides=[Parameter("export_targets",
                                                       value=["autoware", "ros3"])])
    with pytest.raises(odocal.ConfigError, match="parameter datasheet"):
        CalibrationNode(context=ros, node_name=f"bad{next(_counter)}", enable_rosout=False,
                        parameter_overrides=[Parameter("datasheet", value="c_e=x")])


def test_odocal_ros2_starts_the_node_and_stops_on_ctrl_c(ros: Any, tmp_path: Path) -> None:
    """The README's one line, as a process: it publishes its status, and Ctrl-C ends it with
    exit 0 (nothing to export without data: said, not an error)."""
    import os
    import signal
    import subprocess
    import sys

    from tests.ros2.rosenv import isolate

    isolate()
    name = f"cli{next(_counter)}"
    proc = subprocess.Popen(
        [sys.executable, "-m", "odocal", "ros2", "--datasheet", "c_e=1.95,t_r=1.51",
         "--ros-args", "-r", f"__node:={name}", "-p", f"export_dir:={tmp_path / 'x'}",
         "--disable-external-lib-logs"],
        env=os.environ.copy(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        start_new_session=True)
    listener = Node(f"listener{next(_counter)}", context=ros, enable_rosout=False)
    heard: list[Any] = []
    listener.create_subscription(DiagnosticArray, "/diagnostics",
                                 lambda m: heard.extend(s for s in m.status
                                                        if s.name.startswith(name)), 10)
    executor = EventsExecutor(context=ros)
    executor.add_node(listener)
    try:
        _spin_until(executor, lambda: bool(heard), "the node's first status", limit_s=90)
    finally:
        os.killpg(proc.pid, signal.SIGINT)
        try:
            _, err = proc.communicate(timeout=60)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            pytest.fail("Ctrl-C did not stop odocal ros2")
        executor.remove_node(listener)
        listener.destroy_node()
        executor.shutdown()
    assert heard[0].level == b"\x01" and "not yet identified" in heard[0].message
    assert proc.returncode == 0, err
    assert "no calibration to export" in err
