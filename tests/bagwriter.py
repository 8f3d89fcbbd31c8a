"""Write a drive as a ROS 1 bag, a ROS 2 bag or an MCAP file with the rosbags writer (tests)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

from odocal.data.drive import Drive

EPOCH = 1_700_000_000.0
JOINTS = ["front_left_wheel", "front_right_wheel", "rear_left_wheel", "rear_right_wheel"]
#: The bag's JointState: the four wheels and the steering wheel (its position: its angle).
BAG_JOINTS = [*JOINTS, "steering_wheel"]


def _messages(drive: Drive, store: object, ros1: bool) -> list[tuple[str, str, float, object]]:
    types = store.types  # type: ignore[attr-defined]
    header_t = types["std_msgs/msg/Header"]
    time_t = types["builtin_interfaces/msg/Time"]
    vec = types["geometry_msgs/msg/Vector3"]
    quat = types["geometry_msgs/msg/Quaternion"]
    point = types["geometry_msgs/msg/Point"]
    out = []
    # the front wheels and the steering wheel as the drive carries them (0 where it does not)
    zeros = np.zeros(drive.n_samples)
    n_fl, n_fr, steer = (drive.inputs.get(k, zeros) for k in ("n_fl", "n_fr", "steer"))
    for k in range(drive.n_samples):
        t = EPOCH + float(drive.t[k])
        sec = int(np.floor(t))
        nsec = round((t - sec) * 1e9)
        if nsec == 1_000_000_000:
            sec, nsec = sec + 1, 0
        stamp = time_t(sec=sec, nanosec=nsec)
        extra = {"seq": k} if ros1 else {}
        header = header_t(stamp=stamp, frame_id="base_link", **extra)
        two_pi = 2 * np.pi
        joint = types["sensor_msgs/msg/JointState"](
            header=header, name=BAG_JOINTS, position=np.array([0.0, 0.0, 0.0, 0.0, steer[k]]),
            velocity=np.array([n_fl[k] * two_pi, n_fr[k] * two_pi, drive.n_rl[k] * two_pi,
                               drive.n_rr[k] * two_pi, 0.0]),
            effort=np.zeros(5))
        imu = types["sensor_msgs/msg/Imu"](
            header=header, orientation=quat(x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=np.zeros(9),
            angular_velocity=vec(x=0.0, y=0.0, z=float(drive.yaw_rate[k])),
            angular_velocity_covariance=np.zeros(9),
            linear_acceleration=vec(x=0.0, y=float(drive.a_y[k]), z=9.81),
            linear_acceleration_covariance=np.zeros(9))
        half = 0.5 * float(drive.psi[k])
        pose = types["geometry_msgs/msg/Pose"](
            position=point(x=float(drive.x[k]), y=float(drive.y[k]), z=0.0),
            orientation=quat(x=0.0, y=0.0, z=np.sin(half), w=np.cos(half)))
        odom = types["nav_msgs/msg/Odometry"](
            header=header, child_frame_id="base_link",
            pose=types["geometry_msgs/msg/PoseWithCovariance"](pose=pose,
                                                               covariance=np.zeros(36)),
            twist=types["geometry_msgs/msg/TwistWithCovariance"](
                twist=types["geometry_msgs/msg/Twist"](linear=vec(x=0.0, y=0.0, z=0.0),
                                                        angular=vec(x=0.0, y=0.0, z=0.0)),
                covariance=np.zeros(36)))
        out += [("/joint_states", "sensor_msgs/msg/JointState", t, joint),
                ("/imu/data", "sensor_msgs/msg/Imu", t, imu),
                ("/odom", "nav_msgs/msg/Odometry", t, odom)]
    return out


def write_bag(drive: Drive, path: Path, kind: str) -> Path:
    """kind: ``ros1`` (path.bag), ``ros2`` (folder, sqlite3) or ``mcap`` (folder with .mcap)."""
    if kind == "ros1":
        store = get_typestore(Stores.ROS1_NOETIC)
        with Writer1(path) as writer:
            conns = {}
            for topic, msgtype, t, msg in _messages(drive, store, ros1=True):
                if topic not in conns:
                    conns[topic] = writer.add_connection(topic, msgtype, typestore=store)
                writer.write(conns[topic], int(t * 1e9), store.serialize_ros1(msg, msgtype))
        return path
    store = get_typestore(Stores.ROS2_HUMBLE)
    plugin = StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3
    with Writer2(path, version=9, storage_plugin=plugin) as writer:
        conns = {}
        for topic, msgtype, t, msg in _messages(drive, store, ros1=False):
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msgtype, typestore=store)
            writer.write(conns[topic], int(t * 1e9), store.serialize_cdr(msg, msgtype))
    return path
