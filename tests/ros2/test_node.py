"""``odocal ros2``: the online calibrator as a real ROS 2 node (issues 29 and 41).

Every test starts real nodes in this process on the session's private ROS 2 domain
(:mod:`tests.ros2.rosenv`): a player node publishes a simulated drive's JointState, Imu and
Odometry messages and ``/clock`` faster than real time (as fast as the node takes them) on
simulated time, and the calibration node under test listens through Fast DDS
(:mod:`tests.ros2.rig`).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import odocal
from odocal.cli.main import EXIT_OK, main
from odocal.model.parameters import Parameters
from tests.bagwriter import write_bag
from tests.ros2.rig import (
    START_S,
    Script,
    call,
    first_seconds,
    messages,
    play,
    settle,
    spin_until,
    stamp,
    unique,
    values_of,
    wheel_angles,
    without_sideslip,
)
from tests.ros2.rosenv import load_declared, require_rclpy

require_rclpy()

from diagnostic_msgs.msg import DiagnosticArray  # noqa: E402
from nav_msgs.msg import Odometry  # noqa: E402
from rclpy.experimental import EventsExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from sensor_msgs.msg import Imu, JointState  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402


@pytest.fixture(scope="module")
def drive() -> odocal.Drive:
    """A five-minute realistic city drive as a ROS 2 stack sees it: no sideslip input (a
    JointState, an Imu and an Odometry carry none), so ``beta`` is zero here and in the file
    ``odocal replay`` reads."""
    return without_sideslip(odocal.simulate(duration_s=300.0, seed=5, noise="realistic").drive)


def replayed(d: odocal.Drive, folder: Path) -> dict[str, Any]:
    """``odocal replay --no-batch`` on the drive: its calibration.json."""
    path = folder / "drive.parquet"
    odocal.save_drive(d, path)
    assert main(["replay", str(path), "--out", str(folder / "replay"), "--no-batch",
                 "--no-report", "-q"]) == EXIT_OK
    return json.loads((folder / "replay" / "calibration.json").read_text())


def theta_std(calibration: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    names = ("c_e", "c_d", "t_r", "d")
    return (np.array([calibration["theta"][n] for n in names]),
            np.array([calibration["std"][n] for n in names]))


@pytest.mark.parametrize("beside", [False, True], ids=["in its thread", "in a process beside"])
def test_the_node_calibrates_as_replay_does(rig: Any, drive: odocal.Drive,
                                            tmp_path: Path, ros: Any, beside: bool) -> None:
    # a stand-in for a running diff_drive_controller: a real ROS 2 parameter service with the
    # parameters the controller declares (ros2_controllers 4.42.1), not the controller itself
    # (no ros2_control on the package index)
    name = unique("ctl")
    controller = Node("diff_drive_controller", namespace=f"/{name}", context=ros,
                      enable_rosout=False)
    for key, value in (("wheel_radius", 0.31), ("wheel_separation", 1.5),
                       ("wheel_separation_multiplier", 1.0),
                       ("left_wheel_radius_multiplier", 1.0),
                       ("right_wheel_radius_multiplier", 1.0)):
        controller.declare_parameter(key, value)
    r = rig(controller_name=f"/{name}/diff_drive_controller", calibrator_process=beside)
    executor, player, node = r.executor, r.player, r.node
    executor.add_node(controller)
    play(executor, player, node, drive)
    est = node.finish()
    # every [online] update_s (30 s) of data from the first block's end, and the final one
    assert node.updates == (drive.duration_s - 1.0) // 30.0 + 1
    settle(executor, player, node)

    def pushed() -> bool:       # the final estimate's multipliers (after earlier ones)
        value = controller.get_parameter("wheel_separation_multiplier").value
        return bool(abs(value * 1.5 - est.theta.t_r) < 1e-12)

    spin_until(executor, pushed, "the final multipliers to the controller")
    assert node.controller_note.startswith("set ")
    assert "applies them at its next configure" in node.controller_note
    left = controller.get_parameter("left_wheel_radius_multiplier").value
    assert left * 2 * np.pi * 0.31 == pytest.approx(est.theta.c_e + est.theta.c_d / 2, rel=1e-9)
    executor.remove_node(controller)
    controller.destroy_node()
    # odocal replay --no-batch on the same drive
    theta, std = theta_std(replayed(drive, tmp_path))
    assert all(est.identified) and np.all(std > 0)
    assert np.all(np.abs(est.theta.as_array() - theta) <= 0.01 * std), \
        (est.theta.as_array() - theta) / std
    assert np.allclose(est.std, std, rtol=0.01)
    # /diagnostics: OK, with the parameters, their std and the distance as key/values
    [*_, last] = player.statuses()
    assert last.level == b"\x00", last.message
    values = values_of(last)
    assert float(values["c_e"]) == pytest.approx(est.theta.c_e, rel=1e-9)
    assert float(values["t_r_std"]) == pytest.approx(est.std[2], rel=1e-2)
    assert float(values["distance_km"]) == pytest.approx(drive.distance_m / 1000, rel=0.02)
    assert values["d_identified"] == "true" and not player.alarms
    assert values[f"missing {node.get_parameter('wheel_topic').value}"] == "0"
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
    answer = call(executor, player.export, Trigger.Request(), "~/export")
    assert answer.success, answer.message
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
    r = rig(left_wheel_joint="rear_right_wheel", right_wheel_joint="rear_left_wheel")
    play(r.executor, r.player, r.node, first_seconds(drive, 160.0))
    est = r.node.finish()
    settle(r.executor, r.player, r.node)
    assert r.node.calibrator.halted and not est.success
    [*_, last] = r.player.statuses()
    assert last.level == b"\x02"
    assert "swapped" in last.message
    assert not set(values_of(last)) & {"c_e", "c_d", "t_r", "d", "c_e_std"}
    assert not any(s.level == b"\x00" for s in r.player.statuses())
    answer = call(r.executor, r.player.export, Trigger.Request(), "~/export")
    assert not answer.success and "contradict" in answer.message
    assert not r.folder.exists()


def test_a_two_percent_step_in_c_e_raises_an_alarm(rig: Any) -> None:
    true = odocal.TRUE_PARAMETERS
    after = Parameters(true.c_e * 0.98, true.c_d, true.t_r, true.d)
    sim = odocal.simulate(duration_s=360.0, seed=7, noise="realistic", change=(200.0, after))
    r = rig()
    play(r.executor, r.player, r.node, without_sideslip(sim.drive))
    r.node.finish()
    settle(r.executor, r.player, r.node)
    assert r.player.alarms, "no alarm on ~/alarms"
    alarm = json.loads(r.player.alarms[0])
    assert alarm["parameter"] == "c_e" and alarm["relative_change"] < 0
    assert START_S + 200.0 < alarm["detected_t"] < START_S + 360.0     # on the log's clock
    [status, *_] = r.player.statuses("change alarm")
    assert status.level == b"\x01" and "c_e moved" in status.message


def test_a_silent_imu_topic_is_named(rig: Any, drive: odocal.Drive) -> None:
    r = rig(silence_timeout_s=2.0)
    play(r.executor, r.player, r.node, first_seconds(drive, 20.0), Script(imu_until_s=8.0))
    named = [s for s in r.player.statuses() if "no message on" in s.message]
    assert named and all(s.level == b"\x01" for s in named)
    assert f"{r.node.get_parameter('imu_topic').value} (imu) for" in named[-1].message
    assert "/joint_states" not in named[-1].message and "/pose" not in named[-1].message
    # nothing was calibrated from the wheels and the pose alone while it was silent
    assert r.node.calibrator.samples < 9.0 * 40


def test_a_ros2_bag_played_through_the_node(rig: Any, tmp_path: Path) -> None:
    """A ROS 2 bag (tests/bagwriter.py, sqlite3) replayed by publishing its serialized messages
    on their topics with the bag's clock: the node's estimate is odocal replay's on the bag."""
    from rosbags.highlevel import AnyReader

    sim = odocal.simulate(duration_s=150.0, seed=2, noise="realistic")
    bag = write_bag(without_sideslip(sim.drive), tmp_path / "drive_bag", "ros2")
    expected = odocal.replay(bag, fmt="rosbag").estimate
    r = rig(pose_topic="/bag/odom", wheel_topic="/bag/joint_states", imu_topic="/bag/imu/data",
            discover=False)
    kinds = {"/joint_states": JointState, "/imu/data": Imu, "/odom": Odometry}
    qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
    pubs = {topic: r.player.create_publisher(kind, f"/bag{topic}", qos)
            for topic, kind in kinds.items()}
    spin_until(r.executor, lambda: all(p.get_subscription_count() for p in pubs.values()),
               "discovery")
    sent = 0

    def taken() -> int:
        return sum(r.node.arrived().values())

    with AnyReader([bag]) as reader:
        for i, (conn, receive_ns, raw) in enumerate(reader.messages()):
            if i % 120 == 0:
                r.player.clock.publish(Clock(clock=stamp(receive_ns * 1e-9)))
            pubs[conn.topic].publish(bytes(raw))           # the bag's CDR bytes as they are
            sent += 1
            if sent % 120 == 0:
                spin_until(r.executor, lambda s=sent: taken() == s, "the bag's messages")
    spin_until(r.executor, lambda: taken() == sent, "the bag's messages")
    est = r.node.finish()
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
    assert "pip install '.[ros2]'" in err                      # from a checkout


def test_bad_ros_arguments_are_one_line_errors(capsys: pytest.CaptureFixture[str],
                                               tmp_path: Path) -> None:
    code = main(["ros2", "--ros-args", "--params-file", str(tmp_path / "none.yaml")])
    err = capsys.readouterr().err
    assert code == 1 and "ROS 2 arguments" in err and len(err.strip().splitlines()) == 1


def test_odocal_ros2_starts_the_node_and_stops_on_ctrl_c(ros: Any, tmp_path: Path) -> None:
    """docs/ros2.md's first line, as a process: it publishes its status, and Ctrl-C ends it with
    exit 0 (nothing to export without data: said, not an error)."""
    import os
    import signal
    import subprocess
    import sys

    from tests.ros2.rosenv import isolate

    isolate()
    name = unique("cli")
    proc = subprocess.Popen(
        [sys.executable, "-m", "odocal", "ros2", "--datasheet", "c_e=1.95,t_r=1.51",
         "--ros-args", "-r", f"__node:={name}", "-p", f"export_dir:={tmp_path / 'x'}",
         "--disable-external-lib-logs"],
        env=os.environ.copy(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        start_new_session=True)
    listener = Node(unique("listener"), context=ros, enable_rosout=False)
    heard: list[Any] = []
    listener.create_subscription(DiagnosticArray, "/diagnostics",
                                 lambda m: heard.extend(s for s in m.status
                                                        if s.name.startswith(name)), 10)
    executor = EventsExecutor(context=ros)
    executor.add_node(listener)
    try:
        spin_until(executor, lambda: bool(heard), "the node's first status", limit_s=90)
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
    assert "Traceback" not in err


class _Captured:
    """A lifecycle publisher whose serialized messages are kept (both ways the node hands
    them over: ``publish`` and the handle's ``publish_raw``)."""

    def __init__(self, publisher: Any, out: list[bytes]) -> None:
        self._publisher, self._out = publisher, out
        self.is_activated = publisher.is_activated
        self.topic_name = publisher.topic_name
        self.handle = self

    def __enter__(self) -> _Captured:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def publish(self, data: bytes) -> None:
        assert isinstance(data, bytes)
        self._out.append(data)

    publish_raw = publish


def test_a_callbacks_batch_is_taken_as_its_messages_one_by_one(rig: Any,
                                                              drive: odocal.Drive) -> None:
    """The inputs' batch handlers (a driver's messages read and published in one loop, as the
    node takes them) against the same messages handed in one at a time: the same odometry,
    byte for byte, the same counts and the same calibration; with messages that leave the
    loop's path among them (a NaN wheel rate, stamps that go back, another IMU frame name, a
    wheel message with positions only, then a stretch whose every other wheel message has the
    angles alone: from there on every message goes the one-by-one path)."""
    from rclpy.serialization import serialize_message

    d = first_seconds(drive, 100.0)
    angles = wheel_angles(d)
    script = Script()
    batches: list[list[tuple[str, bytes]]] = []
    for start in range(0, d.n_samples, 25):
        batch = []
        for k in range(start, min(start + 25, d.n_samples)):
            msgs = messages(d, k, script)
            if k == 700:
                msgs["wheels"].velocity[-1] = float("nan")
            if k == 900:
                msgs["imu"].header.frame_id = "imu_link"
            if k == 1100:
                msgs["wheels"].velocity = []
            if k in (1300, 1301):                  # a second back, then on again
                for m in msgs.values():
                    m.header.stamp = stamp(START_S + float(d.t[k]) - 1.0)
            if k >= 2000:                              # the angles, velocities every other
                msgs["wheels"].position = [0.0, 0.0, *(float(a) for a in angles[k])]
                if k % 2:
                    msgs["wheels"].velocity = []
            batch += [(role, serialize_message(msgs[role])) for role in ("imu", "pose", "wheels")]
        batches.append(batch)
    nodes = [rig(discover=False).node for _ in range(2)]
    outputs: list[list[bytes]] = [[], []]
    for node, out in zip(nodes, outputs, strict=True):
        node._odom_pub = _Captured(node._odom_pub, out)
    for batch in batches:
        for role, name in (("imu", "imu"), ("pose", "pose"), ("wheels", "wheel")):
            group = [data for r, data in batch if r == role]
            getattr(nodes[0], f"_{name}_batch")(group)
            for data in group:
                getattr(nodes[1], f"_{name}_message")(data)
            for node in nodes:
                node._maybe_flush()
    ests = [node.finish() for node in nodes]
    assert nodes[0]._mixed and nodes[1]._mixed
    assert len(outputs[0]) > 0.9 * d.n_samples and outputs[0] == outputs[1]
    assert nodes[0].arrived() == nodes[1].arrived() and nodes[0].updates == nodes[1].updates > 2
    assert [t.stamps for t in nodes[0].topics] == [t.stamps for t in nodes[1].topics]
    assert np.array_equal(ests[0].theta.as_array(), ests[1].theta.as_array())
