"""Parameter files for the localisation stacks users run, from a calibrated estimate.

``autoware``
    ``autoware/vehicle_info.param.yaml`` (``wheel_radius``, ``wheel_tread``: the two keys of
    Autoware's vehicle_info that odometry calibration determines; merge them into the vehicle's
    own file, whose other keys, such as the wheel base and overhangs, no drive can tell) and
    ``autoware/vehicle_velocity_converter.param.yaml``, complete for the current
    ``autoware_vehicle_velocity_converter`` schema (``speed_scale_factor``, ``frame_id``,
    ``velocity_stddev_xx``, ``angular_velocity_stddev_zz``,
    ``enable_online_speed_scale_factor_calibration``, ``acceptable_speed_scale_factor_range``,
    ``stop_speed_threshold``), both as ROS 2 parameter files for any node
    (``/**: ros__parameters``).
``ros2_control``
    ``ros2_control/diff_drive_controller.yaml``: the diff_drive_controller's wheel joint names,
    ``wheel_separation`` and ``wheel_radius`` (datasheet values) with
    ``wheel_separation_multiplier``, ``left_wheel_radius_multiplier`` and
    ``right_wheel_radius_multiplier`` (the calibration), and the pose and twist covariance
    diagonals. Without stated datasheet values the calibrated values go into ``wheel_separation``
    and ``wheel_radius`` and the multipliers carry only the left/right difference.
``robot_localization``
    ``robot_localization/ekf_odometry.yaml``: the wheel-odometry input of an ``ekf_node``
    (``odom0`` fusing forward speed and yaw rate, ``two_d_mode``), with the calibrated twist
    standard deviations in a comment block to set as the odometry message's twist covariance.

A key the data cannot give (the controller's wheel joint names without ``--wheel-joints``, the
speed scale factor without datasheet values) carries one comment line starting ``# FILL IN``
that names it.

Speeds and yaw-rate standard deviations are measured: the calibrated wheel odometry against the
reference motion over 1 s windows (:func:`odometry_noise`); where no drive is at hand the
target's default is kept and the file says so.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from odocal._version import __version__
from odocal.data.drive import Drive
from odocal.errors import ConfigError
from odocal.io.atomic import write_text
from odocal.model.kinematics import inverse_revolutions, motion_increments
from odocal.model.parameters import Parameters
from odocal.settings import datasheet_stated

TARGETS = ("autoware", "ros2_control", "robot_localization")
#: Autoware's vehicle_velocity_converter defaults (used where no noise was measured).
AUTOWARE_VELOCITY_STD, AUTOWARE_YAW_RATE_STD = 0.2, 0.1


@dataclass(frozen=True)
class OdometryNoise:
    """How far the calibrated wheel odometry is from the reference motion, 1 s averages."""

    speed_std_mps: float
    yaw_rate_std_radps: float
    windows: int


@dataclass(frozen=True)
class Calibrated:
    """What an export needs: the estimate, its datasheet start and (optionally) the noise."""

    theta: Parameters
    datasheet: Parameters
    std: tuple[float, ...]
    identified: tuple[bool, ...]
    method: str
    noise: OdometryNoise | None = None
    source: str = ""
    wheel_joints: tuple[str, str] | None = None
    """The left and right wheel joint names of the robot's description (ros2_control)."""

    @property
    def datasheet_stated(self) -> bool:
        """Whether the datasheet values are the user's (not odocal's placeholder car)."""
        return datasheet_stated(self.datasheet)


def odometry_noise(drives: Sequence[Drive], theta: Parameters,
                   window_s: float = 1.0) -> OdometryNoise | None:
    """Robust standard deviation of the wheel speed and yaw rate against the reference's."""
    speed_err: list[np.ndarray] = []
    yaw_err: list[np.ndarray] = []
    th = theta.as_array()
    c_l, c_r = theta.c_e + theta.c_d / 2.0, theta.c_e - theta.c_d / 2.0
    for d in drives:
        k = max(1, round(window_s / d.t_s))
        for start, stop in d.pieces:
            if stop - start <= k + 1:
                continue
            sl = slice(start, stop)
            ds, dpsi = motion_increments(d.x[sl], d.y[sl], d.psi[sl], d.beta[sl])
            revs, _ = inverse_revolutions(th, ds, dpsi, d.a_y[start:stop - 1])
            measured = np.column_stack([d.n_rl[start:stop - 1], d.n_rr[start:stop - 1]]) * d.t_s
            err = measured - revs
            n = (len(err) // k) * k
            w = err[:n].reshape(-1, k, 2).sum(axis=1)
            speed_err.append(0.5 * (c_l * w[:, 0] + c_r * w[:, 1]) / (k * d.t_s))
            yaw_err.append((c_r * w[:, 1] - c_l * w[:, 0]) / theta.t_r / (k * d.t_s))
    if not speed_err:
        return None
    sv, sy = np.concatenate(speed_err), np.concatenate(yaw_err)
    if sv.size < 10:
        return None
    mad = 1.4826
    return OdometryNoise(speed_std_mps=float(mad * np.median(np.abs(sv - np.median(sv)))),
                         yaw_rate_std_radps=float(mad * np.median(np.abs(sy - np.median(sy)))),
                         windows=int(sv.size))


def _header(c: Calibrated, what: str) -> list[str]:
    lines = [f"# {what}, calibrated by odocal {__version__} (method {c.method})"]
    if c.source:
        lines.append(f"# from: {c.source}")
    missing = [n for n, ok in zip(("c_e", "c_d", "t_r", "d"), c.identified, strict=True)
               if not ok]
    if missing:
        lines.append(f"# not identified by the data (datasheet values kept): {', '.join(missing)}")
    if not c.datasheet_stated:
        lines.append("# no datasheet values were given (--datasheet): parameters not identified "
                     "hold odocal's placeholder")
    return lines


def _num(value: float) -> str:
    return f"{value:.9g}"


def autoware(c: Calibrated, out: Path) -> list[Path]:
    th, ds = c.theta, c.datasheet
    info = [*_header(c, "Autoware vehicle_info: the keys wheel-odometry calibration sets"),
            "# Merge into the vehicle's vehicle_info.param.yaml (its other keys stay).",
            "/**:", "  ros__parameters:",
            f"    wheel_radius: {_num(th.c_e / (2.0 * math.pi))}  # c_e / 2 pi, m",
            f"    wheel_tread: {_num(th.t_r)}  # rear track width t_r, m"]
    if c.noise is not None:
        v_std, w_std, note = (c.noise.speed_std_mps, c.noise.yaw_rate_std_radps,
                              f"measured over {c.noise.windows} windows of 1 s")
    else:
        v_std, w_std, note = (AUTOWARE_VELOCITY_STD, AUTOWARE_YAW_RATE_STD,
                              "not measured here: Autoware's defaults")
    if c.datasheet_stated:
        scale = th.c_e / ds.c_e
        scale_lines = ["# speed_scale_factor: the true speed over the speed the vehicle reports "
                       "with its", "# datasheet circumference (c_e / c_e datasheet)."]
    else:
        scale = 1.0
        scale_lines = [f"# FILL IN speed_scale_factor: {_num(th.c_e)} m (calibrated c_e) over the "
                       "circumference the vehicle computes its speed with (no datasheet given)"]
    # the range the node's own online estimate may move in; it must hold the factor written
    low, high = min(0.98, round(scale - 0.01, 4)), max(1.02, round(scale + 0.01, 4))  # (not theta)
    conv = [*_header(c, "Autoware vehicle_velocity_converter"), *scale_lines,
            f"# standard deviations {note}",
            "/**:", "  ros__parameters:",
            f"    speed_scale_factor: {_num(scale)}",
            f"    velocity_stddev_xx: {_num(v_std)}  # m/s",
            f"    angular_velocity_stddev_zz: {_num(w_std)}  # rad/s",
            "    frame_id: base_link",
            "    enable_online_speed_scale_factor_calibration: false",
            f"    acceptable_speed_scale_factor_range: [{_num(low)}, {_num(high)}]",
            "    stop_speed_threshold: 0.1  # m/s"]
    a, b = out / "vehicle_info.param.yaml", out / "vehicle_velocity_converter.param.yaml"
    write_text(a, "\n".join(info) + "\n")
    write_text(b, "\n".join(conv) + "\n")
    return [a, b]


def _wheel_names(c: Calibrated) -> list[str]:
    if c.wheel_joints is not None:
        left, right = c.wheel_joints
        return [f"    left_wheel_names: [{_quoted(left)}]",
                f"    right_wheel_names: [{_quoted(right)}]"]
    return ["    # FILL IN left_wheel_names and right_wheel_names: the rear wheel joints of your "
            "robot description (or calibrate with --wheel-joints LEFT,RIGHT)",
            '    left_wheel_names: ["rear_left_wheel_joint"]',
            '    right_wheel_names: ["rear_right_wheel_joint"]']


def _quoted(name: str) -> str:
    return '"' + name.replace("\\", "\\\\").replace('"', '\\"') + '"'


def ros2_control(c: Calibrated, out: Path) -> list[Path]:
    th = c.theta
    # without the user's datasheet the calibrated values are the nominal ones
    ds = c.datasheet if c.datasheet_stated else th
    c_l, c_r = th.c_e + th.c_d / 2.0, th.c_e - th.c_d / 2.0
    v_var = (c.noise.speed_std_mps if c.noise else AUTOWARE_VELOCITY_STD) ** 2
    w_var = (c.noise.yaw_rate_std_radps if c.noise else AUTOWARE_YAW_RATE_STD) ** 2
    nominal = ("the datasheet values" if c.datasheet_stated
               else "the calibrated values (no datasheet given)")
    lines = [*_header(c, "ros2_controllers diff_drive_controller"),
             f"# wheel_separation and wheel_radius are {nominal}; the multipliers",
             "# carry the calibration (effective = nominal x multiplier). The top key is the",
             "# controller's name in your controller_manager configuration.",
             "diff_drive_controller:", "  ros__parameters:",
             *_wheel_names(c),
             "    wheels_per_side: 1",
             f"    wheel_separation: {_num(ds.t_r)}",
             f"    wheel_radius: {_num(ds.c_e / (2.0 * math.pi))}",
             f"    wheel_separation_multiplier: {_num(th.t_r / ds.t_r)}",
             f"    left_wheel_radius_multiplier: {_num(c_l / ds.c_e)}",
             f"    right_wheel_radius_multiplier: {_num(c_r / ds.c_e)}",
             "    odom_frame_id: odom",
             "    base_frame_id: base_link",
             "    pose_covariance_diagonal: [0.001, 0.001, 1000000.0, 1000000.0, 1000000.0, "
             "1000.0]",
             f"    twist_covariance_diagonal: [{_num(v_var)}, 0.001, 1000000.0, 1000000.0, "
             f"1000000.0, {_num(w_var)}]"]
    path = out / "diff_drive_controller.yaml"
    write_text(path, "\n".join(lines) + "\n")
    return [path]


def robot_localization(c: Calibrated, out: Path) -> list[Path]:
    v_std = c.noise.speed_std_mps if c.noise else AUTOWARE_VELOCITY_STD
    w_std = c.noise.yaw_rate_std_radps if c.noise else AUTOWARE_YAW_RATE_STD
    flags = [False] * 15
    flags[6] = flags[11] = True                # vx and vyaw
    lines = [*_header(c, "robot_localization ekf_node: the wheel-odometry input"),
             "# Publish the odometry with this twist covariance (row-major 6x6 diagonal):",
             f"#   vx variance {_num(v_std**2)} (m/s)^2, vyaw variance {_num(w_std**2)} (rad/s)^2",
             "ekf_filter_node:", "  ros__parameters:",
             "    two_d_mode: true",
             "    odom0: /odom",
             "    odom0_config: [" + ", ".join("true" if f else "false" for f in flags) + "]",
             "    odom0_queue_size: 10",
             "    odom0_differential: false",
             "    odom0_relative: false",
             f"    odom0_twist_rejection_threshold: {_num(5.0)}"]
    path = out / "ekf_odometry.yaml"
    write_text(path, "\n".join(lines) + "\n")
    return [path]


_WRITERS = {"autoware": autoware, "ros2_control": ros2_control,
            "robot_localization": robot_localization}


def export(c: Calibrated, out: str | Path, targets: Sequence[str] = TARGETS) -> list[Path]:
    """Write each target's files into ``out/TARGET/`` (created)."""
    written: list[Path] = []
    for target in targets:
        if target not in _WRITERS:
            raise ConfigError(f"unknown export target {target!r}; choose from "
                              f"{', '.join(TARGETS)}")
        folder = Path(out) / target
        folder.mkdir(parents=True, exist_ok=True)
        written += _WRITERS[target](c, folder)
    return written
