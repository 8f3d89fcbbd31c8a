"""The live calibration node (``odocal ros2``; the optional ``ros2`` extra).

Owns :class:`~odocal.ros2.node.CalibrationNode`, a lifecycle node: ROS 2 messages in
(``sensor_msgs/JointState``, ``sensor_msgs/Imu``, ``nav_msgs/Odometry`` or
``geometry_msgs/PoseWithCovarianceStamped``, read from their bytes by :mod:`odocal.ros2.cdr`),
each input's stamps checked (:mod:`odocal.ros2.inputs`), the online calibrator and its checks,
the calibrated wheel odometry with the covariance of each message (:mod:`odocal.ros2.twist`),
the estimate, ``/diagnostics``, change alarms and the parameter files of
:mod:`odocal.output.export` (and, :mod:`odocal.ros2.exports`, the IMU's yaw-rate offset of
:mod:`odocal.ros2.gyro`) out, the multipliers to a running controller
(:mod:`odocal.ros2.controller`); its parameters are declared and checked in
:mod:`odocal.ros2.params`. A top layer like
:mod:`odocal.cli`: nothing imports it (the CLI loads it only for ``odocal ros2``), and it may
import every layer below. rclpy and the message packages come from the package index (from a
checkout: ``pip install '.[ros2]'``). Only :mod:`odocal.ros2.node` and
:mod:`odocal.ros2.controller` import rclpy.
"""
