"""What the node adds to the export files of :mod:`odocal.output.export`.

* :func:`imu_corrector`: Autoware's imu_corrector parameters from the IMU's yaw-rate offset the
  node measured (:mod:`odocal.ros2.gyro`), as Autoware's deviation_estimator writes them;
* :func:`point_ekf_at`: robot_localization's input (written as ``/odom``) pointed at the node's
  own calibrated odometry, which states the covariance of each message.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

from odocal.io.atomic import write_text
from odocal.output.export import parameter_file
from odocal.ros2.gyro import GyroOffset

#: imu_corrector's own default for the rates a planar calibration does not see (rad/s).
IMU_CORRECTOR_STDDEV = 0.03


def imu_corrector(path: Path, found: GyroOffset, imu_topic: str, *, aligned: bool) -> Path:
    """``imu_corrector.param.yaml``: the yaw-rate offset (what imu_corrector subtracts) and one
    message's yaw-rate noise; roll and pitch rates at imu_corrector's defaults, said so. Where
    the IMU is mounted turned (``aligned`` false) the offset about the vehicle's z axis is not
    the IMU's: a FILL IN line says so and the file keeps 0."""
    noise = found.noise_radps if math.isfinite(found.noise_radps) else IMU_CORRECTOR_STDDEV
    header = [f"Autoware imu_corrector: the yaw-rate offset against the reference heading, "
              f"measured by odocal ros2 over {found.seconds:.0f} s on {imu_topic}: "
              f"{found.offset_radps:.6g} +- {found.std_radps:.2g} rad/s "
              "(imu_corrector subtracts it)",
              "angular_velocity_stddev_zz: one message's yaw-rate noise, measured; x and y: "
              "not seen by a planar calibration (imu_corrector's defaults)"]
    if not aligned:
        header.append("FILL IN angular_velocity_offset_*: the offset is about the vehicle's z "
                      "axis, and this IMU is mounted turned (imu_rotation_deg); turn it into "
                      "the IMU's axes")
    values = {"angular_velocity_offset_x": 0.0, "angular_velocity_offset_y": 0.0,
              "angular_velocity_offset_z": float(found.offset_radps) if aligned else 0.0,
              "angular_velocity_stddev_xx": IMU_CORRECTOR_STDDEV,
              "angular_velocity_stddev_yy": IMU_CORRECTOR_STDDEV,
              "angular_velocity_stddev_zz": float(noise)}
    write_text(path, parameter_file(header, "/**", values))
    return path


def point_ekf_at(path: Path, topic: str) -> None:
    """robot_localization's ``odom0`` (written as ``/odom``) set to ``topic``, the node's own
    calibrated odometry (a file that is not there: nothing to do)."""
    if not path.is_file():
        return
    import yaml

    text = path.read_text()
    scalar = yaml.safe_dump(topic, default_style=None).splitlines()[0]
    text = re.sub(r"^(\s*odom0: ).*$", lambda m: m.group(1) + scalar, text, count=1,
                  flags=re.MULTILINE)
    write_text(path, text)
