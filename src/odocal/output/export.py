"""Parameter files for the localisation stacks users run, from a calibrated estimate.

Every file is a ROS 2 parameter file written with a YAML library (``yaml.safe_dump``): every
number is a float where the receiving node declares a double (a ``1`` where a double is declared
stops a ROS 2 node at startup), and a string from the user (a log's file name, a fleet's vehicle
name, a wheel joint name) is a quoted value or an escaped comment, never a key. Each file opens
with comment lines saying what made it, from what, which parameters the data did not identify,
and the releases of the receiving node it is written for.

``autoware``
    ``autoware/vehicle_info.param.yaml`` (``wheel_radius``, ``wheel_tread``: the two keys of
    Autoware's vehicle_info that odometry calibration determines; merge them into the vehicle's
    own file, whose other keys, such as the wheel base and overhangs, no drive can tell) and
    ``autoware/vehicle_velocity_converter.param.yaml``: the keys
    ``autoware_vehicle_velocity_converter`` declares (autoware_core 1.0.0-1.9.0:
    ``speed_scale_factor``, ``velocity_stddev_xx``, ``angular_velocity_stddev_zz``, and
    ``frame_id``, which releases up to 1.8.0 require and 1.9.0 no longer declares).
``ros2_control``
    ``ros2_control/diff_drive_controller.yaml``: the controller's ``type`` (so that the spawner's
    ``--param-file`` can load it), the wheel joint names, ``wheel_separation`` and
    ``wheel_radius`` (datasheet values) with ``wheel_separation_multiplier``,
    ``left_wheel_radius_multiplier`` and ``right_wheel_radius_multiplier`` (the calibration),
    and the pose and twist covariance diagonals (ros2_controllers 2.x Humble to 6.x Rolling).
    Without stated datasheet values the calibrated values go into ``wheel_separation`` and
    ``wheel_radius`` and the multipliers carry only the left/right difference.
``ackermann`` (the four-wheel model: ``[vehicle] model = "four_wheel"``)
    ``ackermann/ackermann_steering_controller.yaml``: ros2_controllers'
    ``ackermann_steering_controller`` with the car's geometry: ``wheelbase``, the tracks and
    wheel radii under both releases' names (Humble's ``front_wheel_track``,
    ``rear_wheel_track``, ``front_wheels_radius``, ``rear_wheels_radius``, deprecated in Jazzy;
    Jazzy's and later ``traction_track_width``, ``steering_track_width``,
    ``traction_wheels_radius``: a release reads the names it declares), and the twist
    covariance. The steering's ratio and offset have no key there (the controller commands
    road-wheel angles): they are in ``--export yaml``.
``robot_localization``
    ``robot_localization/ekf_odometry.yaml``: the wheel-odometry input of an ``ekf_node``
    (``odom0`` fusing forward speed and yaw rate, ``two_d_mode``; robot_localization 3.5 Humble,
    3.6 Jazzy and later), with the calibrated twist standard deviations in a comment block to
    set as the odometry message's twist covariance.

A key the data cannot give (the controller's wheel joint names without ``--wheel-joints``, the
speed scale factor without datasheet values or a known speed circumference) carries one comment
line starting ``# FILL IN`` that names it.

Speeds and yaw-rate standard deviations are measured: the calibrated wheel odometry against the
reference motion over 1 s windows (:func:`odocal.pipeline.odometry.odometry_noise`); where
no drive is at hand the
target's default is kept and the file says so.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from odocal._version import __version__
from odocal.errors import ConfigError
from odocal.io.atomic import write_text
from odocal.model.four_wheel import FOUR_WHEEL_MODEL
from odocal.model.layout import Layout
from odocal.model.parameters import Parameters
from odocal.model.vehicle import MODEL
from odocal.pipeline.odometry import OdometryNoise
from odocal.redaction import redact_text
from odocal.settings import datasheet_stated

TARGETS = ("autoware", "ros2_control", "robot_localization")
#: The targets of a model with a wheelbase and a steering (the four-wheel car) besides.
CAR_TARGETS = ("ackermann",)


def is_car(layout: Layout) -> bool:
    """Whether a model of ``layout`` is a car with a wheelbase and a steering."""
    return "L" in layout.names


def targets_for(layout: Layout) -> tuple[str, ...]:
    """Every target a calibration of a model of ``layout`` can be exported to."""
    return (*TARGETS, *CAR_TARGETS) if is_car(layout) else TARGETS
#: Autoware's vehicle_velocity_converter defaults (used where no noise was measured).
AUTOWARE_VELOCITY_STD, AUTOWARE_YAW_RATE_STD = 0.2, 0.1

#: The releases each file is written for (and tested against: tests/output/test_export.py).
RELEASES = {
    "autoware_info": "autoware_core autoware_vehicle_info_utils 1.0.0 and later",
    "autoware": "autoware_core autoware_vehicle_velocity_converter 1.0.0 to 1.9.0",
    "ros2_control": "ros2_controllers diff_drive_controller 2.x (Humble) to 6.x (Rolling); the "
                    "spawner reads 'type' from --param-file from controller_manager 2.46.0 "
                    "(Humble) and 4.21.0 (Jazzy) on",
    "robot_localization": "robot_localization 3.5 (Humble) and 3.6 (Jazzy and later)",
    "ackermann": "ros2_controllers ackermann_steering_controller 2.x (Humble) to 6.x (Rolling)",
    "yaml": "any ROS 2 node that declares these parameters (odocal's own schema)",
}

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
    speed_circumference_m: float | None = None
    """The circumference the vehicle's reported speed was turned into wheel rates with (logs
    whose wheels are speeds in m/s, such as comma2k19): the speed scale factor is relative to
    it."""
    covariance: tuple[tuple[float, ...], ...] | None = None
    """The covariance of theta (``--export yaml``), in theta's order."""
    datasheet_std: tuple[float, ...] | None = None
    """The datasheet values' uncertainty (``[identify] prior_std``), in theta's order: what a
    parameter the drives did not identify is known to (``--export yaml``)."""

    @property
    def datasheet_stated(self) -> bool:
        """Whether the datasheet values are the user's (not odocal's placeholder car)."""
        return datasheet_stated(self.datasheet)


def comment(text: str) -> str:
    """``text`` as one comment line: every character that could end the line (or that a YAML
    reader takes for a line break, such as U+2028) or is not printable ASCII is escaped."""
    escaped = "".join(ch if " " <= ch <= "~" else ch.encode("unicode_escape").decode("ascii")
                      for ch in text)
    return f"# {escaped}"


def _float(value: Any) -> float:
    """A finite Python float (YAML writes it with a decimal point or an exponent)."""
    number = float(value)
    if not math.isfinite(number):
        raise ConfigError(f"cannot export the non-finite value {number!r}")
    return number


def parameter_file(header: Sequence[str], node: str, parameters: Mapping[str, Any]) -> str:
    """A ROS 2 parameter file: the comment lines, then ``node: ros__parameters: ...``."""
    body = yaml.safe_dump({node: {"ros__parameters": dict(parameters)}}, sort_keys=False,
                          default_flow_style=None, allow_unicode=False, width=1 << 16)
    return "".join(comment(line) + "\n" for line in header) + body


def _header(c: Calibrated, what: str, release: str) -> list[str]:
    lines = [f"{what}, calibrated by odocal {__version__} (method {c.method})",
             f"for: {RELEASES[release]}"]
    if c.source:
        lines.append(f"from: {redact_text(c.source)}")
    missing = [n for n, ok in zip(c.theta.layout.names, c.identified, strict=True) if not ok]
    if missing:
        lines.append(f"not identified by the data (datasheet values kept; one no datasheet "
                     f"states is a FILL IN line where a key needs it): {', '.join(missing)}")
    if not c.datasheet_stated:
        lines.append("no datasheet values were given (--datasheet): parameters not identified "
                     "hold odocal's placeholder")
    return lines


def unstated(c: Calibrated) -> tuple[str, ...]:
    """The parameters the drives did not identify and no datasheet stated (odocal's
    placeholder kept): a stack's file leaves them out rather than state a guess as the car's."""
    layout = c.theta.layout
    sheet = c.datasheet.as_array()
    return tuple(n for j, (n, ok) in enumerate(zip(layout.names, c.identified, strict=True))
                 if not ok and sheet[j] == layout.placeholder[j])


def _left_out(keys: Mapping[str, str], missing: Sequence[str]) -> tuple[list[str], set[str]]:
    """The header lines for a stack file's ``keys`` (key: the parameter it states) whose
    parameter is ``missing`` (:func:`unstated`), and those keys."""
    gone = {k for k, name in keys.items() if name in missing}
    lines = [f"FILL IN {k}: not written, as {keys[k]} is not identified by these drives and no "
             f"datasheet states it (--datasheet {keys[k]}=...)" for k in keys if k in gone]
    return lines, gone


def _noise(c: Calibrated) -> tuple[float, float, str]:
    if c.noise is not None:
        # (a fleet's pooled calibration keeps the figures, not how many windows gave them)
        over = (f"over {c.noise.windows} windows" if c.noise.windows
                else "in windows")
        return (c.noise.speed_std_mps, c.noise.yaw_rate_std_radps,
                f"measured {over} of {c.noise.window_s:g} s against the reference")
    return AUTOWARE_VELOCITY_STD, AUTOWARE_YAW_RATE_STD, "not measured here: Autoware's defaults"


def autoware(c: Calibrated, out: Path) -> list[Path]:
    th, ds = c.theta, c.datasheet
    car = is_car(th.layout)
    keys = {"wheel_radius": "c_e", "wheel_tread": "t_r", **({"wheel_base": "L"} if car else {})}
    fill, gone = _left_out(keys, unstated(c))
    values = {"wheel_radius": _float(th.c_e / (2.0 * math.pi)), "wheel_tread": _float(th.t_r),
              **({"wheel_base": _float(th.L)} if car else {})}
    info = parameter_file(
        [*_header(c, "Autoware vehicle_info: the keys wheel-odometry calibration sets",
                  "autoware_info"),
         "Merge into the vehicle's vehicle_info.param.yaml (its other keys stay).",
         "wheel_radius: c_e / 2 pi (m); wheel_tread: the rear track width t_r (m)",
         *(["wheel_base: the wheelbase L (m)"] if car else []), *fill],
        "/**", {k: v for k, v in values.items() if k not in gone})
    v_std, w_std, note = _noise(c)
    if c.speed_circumference_m is not None:
        scale = th.c_e / c.speed_circumference_m
        scale_lines = ["speed_scale_factor: the true speed over the speed the vehicle reports: "
                       f"c_e over the {c.speed_circumference_m:.9g} m its reported speed was "
                       "turned into wheel rates with"]
    elif c.datasheet_stated:
        scale = th.c_e / ds.c_e
        scale_lines = ["speed_scale_factor: the true speed over the speed the vehicle reports "
                       "with its datasheet circumference (c_e / c_e datasheet)"]
    else:
        scale = 1.0
        scale_lines = [f"FILL IN speed_scale_factor: {th.c_e:.9g} m (calibrated c_e) over the "
                       "circumference the vehicle computes its speed with (no datasheet given)"]
    conv = parameter_file(
        [*_header(c, "Autoware vehicle_velocity_converter", "autoware"), *scale_lines,
         f"velocity_stddev_xx (m/s), angular_velocity_stddev_zz (rad/s): {note}",
         "frame_id: declared (and required) up to 1.8.0, ignored from 1.9.0 on"],
        "/**", {"speed_scale_factor": _float(scale), "velocity_stddev_xx": _float(v_std),
                "angular_velocity_stddev_zz": _float(w_std), "frame_id": "base_link"})
    a, b = out / "vehicle_info.param.yaml", out / "vehicle_velocity_converter.param.yaml"
    write_text(a, info)
    write_text(b, conv)
    return [a, b]


def _covariance_diagonals(v_std: float, w_std: float) -> dict[str, list[float]]:
    """A ros2_controllers odometry's pose and twist covariance diagonals: the twist's speed
    and yaw-rate variances measured, the planar pose's a small start, the rest out of play."""
    return {"pose_covariance_diagonal": [0.001, 0.001, 1.0e6, 1.0e6, 1.0e6, 1000.0],
            "twist_covariance_diagonal": [_float(v_std**2), 0.001, 1.0e6, 1.0e6, 1.0e6,
                                          _float(w_std**2)]}


def multipliers(geometry: Mapping[str, float],
                nominal: Mapping[str, float]) -> dict[str, float]:
    """diff_drive_controller's multipliers (effective = nominal x multiplier) of a model's
    ``geometry`` against the ``nominal`` one (:meth:`odocal.model.protocol.VehicleModel.geometry`):
    the separation's, and each wheel's radius over the nominal mean wheel's."""
    radius = nominal["wheel_radius"]
    return {"wheel_separation_multiplier":
            geometry["wheel_separation"] / nominal["wheel_separation"],
            "left_wheel_radius_multiplier": geometry["left_wheel_radius"] / radius,
            "right_wheel_radius_multiplier": geometry["right_wheel_radius"] / radius}


def ros2_control(c: Calibrated, out: Path) -> list[Path]:
    th = c.theta
    # without the user's datasheet the calibrated values are the nominal ones
    ds = c.datasheet if c.datasheet_stated else th
    now, nominal_geometry = MODEL.geometry(th.as_array()), MODEL.geometry(ds.as_array())
    v_std, w_std, note = _noise(c)
    nominal = ("the datasheet values" if c.datasheet_stated
               else "the calibrated values (no datasheet given)")
    header = [*_header(c, "ros2_controllers diff_drive_controller", "ros2_control"),
              f"wheel_separation and wheel_radius are {nominal}; the multipliers carry the",
              "calibration (effective = nominal x multiplier). The top key is the controller's",
              "name in your controller_manager configuration.",
              f"twist_covariance_diagonal: vx and vyaw variances {note}"]
    if c.wheel_joints is not None:
        left, right = c.wheel_joints
    else:
        header.append("FILL IN left_wheel_names and right_wheel_names: the rear wheel joints "
                      "of your robot description (or calibrate with --wheel-joints LEFT,RIGHT)")
        left, right = "rear_left_wheel_joint", "rear_right_wheel_joint"
    params = {
        "type": "diff_drive_controller/DiffDriveController",
        "left_wheel_names": [str(left)], "right_wheel_names": [str(right)],
        "wheel_separation": _float(nominal_geometry["wheel_separation"]),
        "wheel_radius": _float(nominal_geometry["wheel_radius"]),
        **{key: _float(value) for key, value in multipliers(now, nominal_geometry).items()},
        "odom_frame_id": "odom", "base_frame_id": "base_link",
        **_covariance_diagonals(v_std, w_std)}
    path = out / "diff_drive_controller.yaml"
    write_text(path, parameter_file(header, "diff_drive_controller", params))
    return [path]


def ackermann(c: Calibrated, out: Path) -> list[Path]:
    """``ackermann_steering_controller.yaml``: the car's geometry for ros2_controllers'
    ackermann_steering_controller (rear traction wheels, steered front ones), under the names
    of every release (each declares its own; the others are left unread)."""
    th = c.theta
    if not is_car(th.layout):
        raise ConfigError("the ackermann export needs a car's wheelbase and steering: calibrate "
                          "with [vehicle] model = \"four_wheel\"")
    g = FOUR_WHEEL_MODEL.geometry(th.as_array())
    v_std, w_std, note = _noise(c)
    keys = {"wheelbase": "L", "front_wheel_track": "t_f", "rear_wheel_track": "t_r",
            "front_wheels_radius": "c_f", "rear_wheels_radius": "c_e",
            "traction_track_width": "t_r", "steering_track_width": "t_f",
            "traction_wheels_radius": "c_e"}
    fill, gone = _left_out(keys, unstated(c))
    header = [*_header(c, "ros2_controllers ackermann_steering_controller", "ackermann"),
              "wheelbase, tracks and radii: the calibrated car (each axle's mean wheel); "
              "Humble reads front_/rear_ names, Jazzy and later traction_/steering_ ones.",
              "The top key is the controller's name in your controller_manager configuration.",
              f"twist_covariance_diagonal: vx and vyaw variances {note}",
              "FILL IN rear_wheels_names/front_wheels_names (Humble), traction_joints_names/"
              "steering_joints_names (Jazzy and later): your robot description's joints", *fill]
    params = {
        "type": "ackermann_steering_controller/AckermannSteeringController",
        "wheelbase": _float(g["wheelbase"]),
        "front_wheel_track": _float(g["front_wheel_track"]),
        "rear_wheel_track": _float(g["rear_wheel_track"]),
        "front_wheels_radius": _float(g["front_wheels_radius"]),
        "rear_wheels_radius": _float(g["rear_wheels_radius"]),
        "traction_track_width": _float(g["rear_wheel_track"]),
        "steering_track_width": _float(g["front_wheel_track"]),
        "traction_wheels_radius": _float(g["rear_wheels_radius"]),
        "rear_wheels_names": ["rear_left_wheel_joint", "rear_right_wheel_joint"],
        "front_wheels_names": ["front_left_steering_joint", "front_right_steering_joint"],
        "traction_joints_names": ["rear_left_wheel_joint", "rear_right_wheel_joint"],
        "steering_joints_names": ["front_left_steering_joint", "front_right_steering_joint"],
        "odom_frame_id": "odom", "base_frame_id": "base_link",
        **_covariance_diagonals(v_std, w_std)}
    params = {k: v for k, v in params.items() if k not in gone}
    path = out / "ackermann_steering_controller.yaml"
    write_text(path, parameter_file(header, "ackermann_steering_controller", params))
    return [path]


def robot_localization(c: Calibrated, out: Path) -> list[Path]:
    v_std, w_std, note = _noise(c)
    flags = [False] * 15
    flags[6] = flags[11] = True                # vx and vyaw
    header = [*_header(c, "robot_localization ekf_node: the wheel-odometry input",
                       "robot_localization"),
              f"Publish the odometry with this twist covariance (row-major 6x6 diagonal; {note}):",
              f"  vx variance {v_std**2:.9g} (m/s)^2, vyaw variance {w_std**2:.9g} (rad/s)^2"]
    params = {"two_d_mode": True, "odom0": "/odom", "odom0_config": flags,
              "odom0_queue_size": 10, "odom0_differential": False, "odom0_relative": False,
              "odom0_twist_rejection_threshold": 5.0}
    path = out / "ekf_odometry.yaml"
    write_text(path, parameter_file(header, "ekf_filter_node", params))
    return [path]


def parameters_yaml(c: Calibrated, path: Path) -> Path:
    """``odometry_parameters.yaml`` (``--export yaml``): theta, the derived wheel radius, which
    parameters the drive identified and their covariance, as a ROS 2 parameter file."""
    th = c.theta
    names, units = th.layout.names, th.layout.units
    n = len(names)
    cov = (np.zeros((n, n)) if c.covariance is None
           else np.asarray(c.covariance, dtype=float))
    header = [*_header(c, "Wheel-odometry parameters", "yaml"),
              "Parameters a drive did not identify keep their datasheet values (identified: "
              "false): their std and covariance are 0 (not fitted), their uncertainty is the "
              "datasheet's (datasheet_std).",
              "Units: " + ", ".join(f"{n} {u}" for n, u in zip(names, units, strict=True))
              + "; wheel_radius = c_e / (2 pi), m; c_d is left minus right.",
              f"covariance: row-major {n}x{n} in the order of parameter_names, SI units"]
    speed: dict[str, Any] = {}
    if c.speed_circumference_m is not None:
        # the wheels were speeds turned into rates with an assumed circumference: c_e is that
        # assumption times the speed signal's scale factor, which is what a stack can use
        header.append(f"The wheels were logged as speeds and turned into rates with "
                      f"{c.speed_circumference_m:.9g} m: c_e is that circumference times "
                      "speed_scale_factor (the true speed over the reported one), c_d "
                      "relative to it alike.")
        speed = {"speed_scale_factor": _float(th.c_e / c.speed_circumference_m),
                 "speed_scale_factor_std": _float(c.std[0] / c.speed_circumference_m),
                 "assumed_wheel_circumference": _float(c.speed_circumference_m)}
    params = {"effective_wheel_circumference": _float(th.c_e),
              "wheel_radius": _float(th.c_e / (2.0 * math.pi)),
              "circumference_difference": _float(th.c_d),
              "rear_track_width": _float(th.t_r),
              "load_transfer_coefficient": _float(th.d),
              **({"front_wheel_circumference": _float(th.c_f),
                  "front_circumference_difference": _float(th.c_fd),
                  "front_track_width": _float(th.t_f), "wheelbase": _float(th.L),
                  "steering_ratio": _float(th.ratio), "steering_offset": _float(th.s_0)}
                 if is_car(th.layout) else {}),
              "parameter_names": list(names),
              "identified": [bool(ok) for ok in c.identified],
              "std": [_float(s) for s in c.std],
              **({"datasheet_std": [_float(s) for s in c.datasheet_std]}
                 if c.datasheet_std is not None else {}),
              "covariance": [_float(v) for v in cov.ravel()], **speed}
    write_text(path, parameter_file(header, "wheel_odometry", params))
    return path


_WRITERS = {"autoware": autoware, "ros2_control": ros2_control,
            "robot_localization": robot_localization, "ackermann": ackermann}


def export(c: Calibrated, out: str | Path, targets: Sequence[str] = TARGETS) -> list[Path]:
    """Write each target's files into ``out/TARGET/`` (created)."""
    written: list[Path] = []
    for target in targets:
        if target not in _WRITERS:
            raise ConfigError(f"unknown export target {target!r}; choose from "
                              f"{', '.join((*TARGETS, *CAR_TARGETS))}")
        folder = Path(out) / target
        folder.mkdir(parents=True, exist_ok=True)
        written += _WRITERS[target](c, folder)
    return written
