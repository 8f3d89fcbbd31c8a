"""The node's readers of serialized messages (odocal.ros2.cdr) against rclpy's own serializer
(little endian, as DDS carries them here) and rosbags' (big endian too), for frame names,
joint names and sequences of every length (property-based, derandomized), and what the node
makes of a topic's stamps (odocal.ros2.inputs) and of its readings' noise (odocal.ros2.twist)."""

from __future__ import annotations

import math
import string

import numpy as np
import pytest
from hypothesis import example, given
from hypothesis import strategies as st

from odocal.ros2.inputs import Continuity, Rates, tenth_percentile
from odocal.ros2.twist import ReadingNoise
from tests.ros2.rosenv import require_rclpy

require_rclpy()

from geometry_msgs.msg import PoseWithCovarianceStamped  # noqa: E402
from nav_msgs.msg import Odometry  # noqa: E402
from rclpy.serialization import deserialize_message, serialize_message  # noqa: E402
from sensor_msgs.msg import Imu, JointState  # noqa: E402

from odocal.ros2 import cdr  # noqa: E402

_names = st.text(alphabet=string.ascii_letters + "_/", max_size=9)
_floats = st.floats(allow_nan=False, allow_infinity=False, width=64)


def _pick(names: tuple[str, ...]) -> tuple[tuple[int, ...], int | None]:
    return (names.index("L"), names.index("R")), None


def _pick_car(names: tuple[str, ...]) -> tuple[tuple[int, ...], int | None]:
    """The car's: the rear wheels, then the front ones, and the steering joint."""
    return tuple(names.index(n) for n in ("L", "R", "FL", "FR")), names.index("S")


@given(frame=_names, names=st.lists(_names.filter(lambda n: n not in "LR"), max_size=4),
       where=st.integers(0, 4), positions=st.booleans(), velocities=st.booleans(),
       efforts=st.integers(0, 3), values=st.lists(_floats, min_size=12, max_size=12),
       sec=st.integers(-2**31, 2**31 - 1), nsec=st.integers(0, 999_999_999))
@example(frame="", names=[], where=0, positions=True, velocities=False, efforts=0,
         values=[0.0] * 12, sec=0, nsec=0)
def test_a_joint_state_reads_as_rclpy_serialized_it(frame: str, names: list[str], where: int,
                                                    positions: bool, velocities: bool,
                                                    efforts: int, values: list[float],
                                                    sec: int, nsec: int) -> None:
    joints = list(names)
    joints[min(where, len(joints)):min(where, len(joints))] = ["L", "R"]
    n = len(joints)
    msg = JointState(name=joints, position=values[:n] if positions else [],
                     velocity=values[n:2 * n] if velocities else [],
                     effort=values[:efforts])
    msg.header.frame_id = frame
    msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nsec
    data = serialize_message(msg)
    reader = cdr.JointReader(_pick)
    for _ in range(2):                              # learned, then from the cached layout
        got_sec, got_nsec, pos, vel, steering = reader.read(data)
        i, j = joints.index("L"), joints.index("R")
        assert (got_sec, got_nsec) == (sec, nsec) and steering is None
        assert pos == ((msg.position[i], msg.position[j]) if positions else None)
        assert vel == ((msg.velocity[i], msg.velocity[j]) if velocities else None)
        # the node's loop: the stamp and the velocities by the layout, None without velocities
        assert reader.velocities(data) == ((sec, nsec, msg.velocity[i], msg.velocity[j])
                                           if velocities else None)
    full = cdr.joint_state(data)
    assert full.names == tuple(j.encode() for j in joints)


@given(names=st.lists(_names.filter(lambda n: n not in ("L", "R", "FL", "FR", "S")),
                      max_size=3),
       order=st.permutations(["L", "R", "FL", "FR", "S"]), where=st.integers(0, 3),
       positions=st.booleans(), velocities=st.booleans(),
       values=st.lists(_floats, min_size=16, max_size=16))
@example(names=[], order=["S", "FL", "L", "FR", "R"], where=0, positions=False,
         velocities=True, values=[float(v) for v in range(16)])
def test_a_cars_joint_state_reads_four_wheels_and_the_steering(
        names: list[str], order: list[str], where: int, positions: bool, velocities: bool,
        values: list[float]) -> None:
    """The car's reader: the four wheels' velocities in the order picked and the steering
    joint's position, wherever they lie among other joints; the quick read only where both the
    velocities and the steering's position are in the messages."""
    joints = list(names)
    joints[min(where, len(joints)):min(where, len(joints))] = order
    n = len(joints)
    msg = JointState(name=joints, position=values[:n] if positions else [],
                     velocity=values[n:2 * n] if velocities else [])
    msg.header.stamp.sec, msg.header.stamp.nanosec = 3, 4
    data = serialize_message(msg)
    reader = cdr.JointReader(_pick_car)
    at = [joints.index(k) for k in ("L", "R", "FL", "FR")]
    steer_at = joints.index("S")
    for _ in range(2):
        sec, nsec, pos, vel, steering = reader.read(data)
        assert (sec, nsec) == (3, 4)
        assert pos == (tuple(msg.position[i] for i in at) if positions else None)
        assert vel == (tuple(msg.velocity[i] for i in at) if velocities else None)
        assert steering == (msg.position[steer_at] if positions else None)
        assert reader.velocities(data) == (
            (3, 4, *(msg.velocity[i] for i in at), msg.position[steer_at])
            if positions and velocities else None)


def test_a_joint_state_of_another_layout_is_learned_anew() -> None:
    reader = cdr.JointReader(_pick)
    a = JointState(name=["L", "R"], velocity=[1.0, 2.0])
    b = JointState(name=["x", "R", "L"], velocity=[7.0, 8.0, 9.0])   # (same length, swapped)
    assert reader.read(serialize_message(a))[3] == (1.0, 2.0)
    assert reader.velocities(serialize_message(b)) is None           # (not the layout seen)
    assert reader.read(serialize_message(b))[3] == (9.0, 8.0)
    assert reader.velocities(serialize_message(b))[2:] == (9.0, 8.0)  # type: ignore[index]
    assert reader.velocities(serialize_message(a)) is None
    assert reader.read(serialize_message(a))[3] == (1.0, 2.0)


@given(frame=_names, child=_names, values=st.lists(_floats, min_size=10, max_size=10))
def test_imu_odometry_and_pose_read_as_serialized(frame: str, child: str,
                                                  values: list[float]) -> None:
    imu = Imu()
    imu.header.frame_id = frame
    imu.header.stamp.sec, imu.header.stamp.nanosec = 12, 34
    (imu.angular_velocity.x, imu.angular_velocity.y, imu.angular_velocity.z,
     imu.linear_acceleration.x, imu.linear_acceleration.y, imu.linear_acceleration.z) = values[:6]
    assert cdr.imu(serialize_message(imu)) == (12, 34, tuple(values[:3]), tuple(values[3:6]))
    quick = cdr.imu_reader()
    assert quick.read(serialize_message(imu)) == (12, 34, *values[:6])
    imu.header.frame_id = frame + "_x"                  # another layout: learned anew
    assert quick.read(serialize_message(imu)) == (12, 34, *values[:6])
    odom = Odometry()
    odom.header.frame_id, odom.child_frame_id = frame, child
    odom.header.stamp.sec = 5
    odom.pose.pose.position.x, odom.pose.pose.position.y = values[0], values[1]
    q = odom.pose.pose.orientation
    q.x, q.y, q.z, q.w = values[2:6]
    odom.twist.twist.linear.x, odom.twist.twist.linear.y = values[6], values[7]
    got = cdr.odometry(serialize_message(odom))
    assert got == (5, 0, values[0], values[1], tuple(values[2:6]), (values[6], values[7]))
    assert cdr.odometry_reader().read(serialize_message(odom)) == (5, 0, *values[:8])
    pose = PoseWithCovarianceStamped()
    pose.header.frame_id = child
    pose.pose.pose.position.x = values[8]
    pose.pose.pose.orientation.w = values[9]
    got = cdr.pose_with_covariance(serialize_message(pose))
    assert got.x == values[8] and got.orientation == (0.0, 0.0, 0.0, values[9])
    assert got.velocity is None
    assert cdr.pose_reader().read(serialize_message(pose)) == (
        0, 0, values[8], 0.0, 0.0, 0.0, 0.0, values[9])


def test_big_endian_messages_read_as_little_endian_ones() -> None:
    """A big-endian CDR writer (rosbags') as a little-endian one (rclpy's)."""
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    types = store.types
    header = types["std_msgs/msg/Header"](stamp=types["builtin_interfaces/msg/Time"](
        sec=7, nanosec=8), frame_id="odom_frame")
    joint = types["sensor_msgs/msg/JointState"](
        header=header, name=["a", "L", "R"], position=np.array([1.0, 2.0, 3.0]),
        velocity=np.array([4.0, 5.0, 6.0]), effort=np.array([]))
    for little in (True, False):
        data = bytes(store.serialize_cdr(joint, "sensor_msgs/msg/JointState",
                                         little_endian=little))
        assert data[1] == (1 if little else 0)
        assert cdr.JointReader(_pick).read(data) == (7, 8, (2.0, 3.0), (5.0, 6.0), None)


@pytest.mark.parametrize("data", [b"", b"\x00\x01\x00\x00" + b"\x00" * 8,
                                  b"\x00\x0a\x00\x00" + b"\x00" * 40,     # a parameter list
                                  b"\x00\x01\x00\x00" + b"\x00" * 8 + b"\xff\xff\x00\x00"])
def test_bytes_that_are_not_the_message_are_a_cdr_error(data: bytes) -> None:
    with pytest.raises(cdr.CdrError):
        cdr.JointReader(_pick).read(data)
    with pytest.raises(cdr.CdrError):
        cdr.imu(data)
    assert cdr.imu_reader().read(data) is None
    assert cdr.odometry_reader().read(data) is None
    assert cdr.JointReader(_pick).velocities(data) is None


def test_the_odometry_writer_fills_what_rclpy_reads_back() -> None:
    template = Odometry()
    template.header.frame_id, template.child_frame_id = "odom", "base_link"
    writer = cdr.OdometryWriter(serialize_message(template))
    writer.covariances([float(i) for i in range(36)], [-float(i) for i in range(36)])
    msg = deserialize_message(writer.message(3, 4, 1.5, -2.5, 0.6, 0.8, 9.5, 0.25, 0.01, 0.02),
                              Odometry)
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (3, 4)
    assert msg.header.frame_id == "odom" and msg.child_frame_id == "base_link"
    assert (msg.pose.pose.position.x, msg.pose.pose.position.y) == (1.5, -2.5)
    assert (msg.pose.pose.orientation.z, msg.pose.pose.orientation.w) == (0.6, 0.8)
    assert (msg.twist.twist.linear.x, msg.twist.twist.angular.z) == (9.5, 0.25)
    assert msg.twist.covariance[0] == 0.01 and msg.twist.covariance[35] == 0.02
    assert list(msg.pose.covariance) == [float(i) for i in range(36)]
    assert list(msg.twist.covariance[1:35]) == [-float(i) for i in range(1, 35)]


# ------------------------------------------------------------------- stamps, rates, noise

def test_continuity_counts_what_the_stamps_call_for() -> None:
    stamps = Continuity()
    t = [0.01 * k for k in range(200)]
    lost = {50, 51, 52, 120}
    for k, v in enumerate(t):
        if k not in lost:
            assert stamps.check(v)
    assert stamps.missing == 4 and stamps.received == 196
    assert stamps.missing_share == pytest.approx(4 / 200)
    assert not stamps.check(1.0) and stamps.back == 1 and stamps.back_max_s == pytest.approx(0.99)
    # the next one a step later than the one in between: that one came, its stamp gone back
    assert stamps.check(1.99 + 0.02) and stamps.missing == 4
    assert stamps.check(2.05) and stamps.missing == 7          # 2.02, 2.03, 2.04


@given(st.lists(st.floats(min_value=0.0, max_value=2.0), min_size=1, max_size=70))
@example([0.01] * 64)
def test_the_period_is_numpys_tenth_percentile(steps: list[float]) -> None:
    assert tenth_percentile(steps) == float(np.percentile(steps, 10))


def test_rates_from_positions_are_the_step_over_its_time_at_its_middle() -> None:
    rates = Rates(max_gap_s=0.5)
    assert rates.add(1.0, 0.0, 0.0) is None
    t, left, right = rates.add(1.1, 2 * math.pi, -math.pi)       # type: ignore[misc]
    assert t == pytest.approx(1.05) and left == pytest.approx(10.0) and right == pytest.approx(-5.0)
    assert rates.add(2.0, 0.0, 0.0) is None                       # a gap: a new piece
    # four joints and a steering angle beside them (its mean over the step)
    # (other joints than the step before: a new piece)
    assert rates.add(2.1, 0.0, 0.0, 0.0, 0.0, angles=(0.2,)) is None
    t, *got = rates.add(2.3, math.pi, 0.0, -math.pi, 4 * math.pi,  # type: ignore[misc]
                        angles=(0.4,))
    assert t == pytest.approx(2.2)
    assert got == pytest.approx([2.5, 0.0, -2.5, 10.0, 0.3])


def test_reading_noise_is_the_variance_of_white_readings() -> None:
    """Readings of a smooth motion with white errors of 0.05 m/s (and 0.03 rad/s) plus 1% of
    the speed: the fit gives back both parts."""
    rng = np.random.default_rng(1)
    noise = ReadingNoise(max_gap_s=0.5)
    t = np.arange(40000) * 0.025
    speed = 10.0 + 8.0 * np.sin(t / 20.0)
    v = speed + rng.normal(0, 1, t.size) * np.sqrt(0.05**2 + (0.01 * speed) ** 2)
    w = 0.1 * np.sin(t / 7.0) + rng.normal(0, 0.03, t.size)
    for k in range(t.size):
        noise.add(float(t[k]), float(v[k]), float(w[k]))
    coefficients = noise.coefficients()
    assert coefficients is not None
    (a_v, b_v), (a_w, b_w) = coefficients
    assert a_v == pytest.approx(0.05**2, rel=0.15) and b_v == pytest.approx(0.01**2, rel=0.15)
    assert a_w + b_w * 100 == pytest.approx(0.03**2, rel=0.05)
