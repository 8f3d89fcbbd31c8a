"""The live calibration node (``odocal ros2``; the optional ``ros2`` extra).

Owns :class:`~odocal.ros2.node.CalibrationNode`, a lifecycle node: ROS 2 messages in
(``sensor_msgs/JointState``, ``sensor_msgs/Imu``, ``nav_msgs/Odometry`` or
``geometry_msgs/PoseWithCovarianceStamped``, read from their bytes by :mod:`odocal.ros2.cdr`),
each input's stamps checked (:mod:`odocal.ros2.inputs`), the online calibrator and its checks,
the calibrated wheel odometry with the covariance of each message (:mod:`odocal.ros2.twist`),
the estimate, ``/diagnostics``, change alarms and the parameter files of
:mod:`odocal.output.export` (and the IMU's yaw-rate offset, :mod:`odocal.ros2.gyro`) out; its
parameters are declared and checked in :mod:`odocal.ros2.params`. A top layer like
:mod:`odocal.cli`: nothing imports it (the CLI loads it only for ``odocal ros2``), and it may
import every layer below. rclpy and the message packages come from the package index (from a
checkout: ``pip install '.[ros2]'``). Only :mod:`odocal.ros2.node` imports rclpy.
"""
