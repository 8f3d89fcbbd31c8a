"""The live calibration node (``odocal ros2``; the optional ``ros2`` extra).

Owns :class:`~odocal.ros2.node.CalibrationNode`: ROS 2 messages in (``sensor_msgs/JointState``,
``sensor_msgs/Imu``, ``nav_msgs/Odometry``), the online calibrator and its checks, the calibrated
wheel odometry, ``/diagnostics``, change alarms and the parameter files of
:mod:`odocal.output.export` out. A top layer like :mod:`odocal.cli`: nothing imports it (the CLI
loads it only for ``odocal ros2``), and it may import every layer below. rclpy and the message
packages come from the package index (``pip install 'odocal[ros2]'``).
"""
