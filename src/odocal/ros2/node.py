"""``odocal ros2``: the online calibrator as a ROS 2 node.

Inputs (topic names and wheel joint names are parameters; time is each message's header stamp,
never its arrival; ``use_sim_time`` is honoured):

* the rear wheels' joint velocities (rad/s) from ``sensor_msgs/JointState``;
* the lateral acceleration (and yaw rate) from ``sensor_msgs/Imu``;
* the reference pose from ``nav_msgs/Odometry`` (what a localisation stack publishes).

The messages are put onto the drive's uniform grid as they arrive, in any interleaving and a
little late (:class:`odocal.online.replay.GridResampler`: a grid time is used once every stream
has samples on both sides of it, as ``odocal replay`` does with a bag), and pushed into an
:class:`~odocal.OnlineCalibrator` every ``[online] chunk_s`` of data. Every ``[online] update_s``
of data the estimate is taken, as ``odocal replay`` takes it, and published.

Outputs:

* ``~/odometry`` (``nav_msgs/Odometry``), one per wheel message: the wheel odometry with the
  current calibration (equations (2)-(3) of :mod:`odocal.model.step`; the dead-reckoned pose),
  its twist covariance from the calibration's measured noise (the error model of the default
  method, for the current speed, over ``[inverse] window_s``);
* ``/diagnostics`` (``diagnostic_msgs/DiagnosticArray``): OK when every parameter is identified
  and the estimate passed the gate, WARN while something is not yet identified (named, with why)
  or an input topic is silent (named), ERROR where the data contradict the model (the checks'
  finding, and never parameters); the parameters, their standard deviations and the distance
  driven as key/values;
* ``~/alarms`` (``std_msgs/String``, latched): each change alarm as JSON as soon as it is raised
  (and a WARN status on ``/diagnostics``);
* the parameter files of :mod:`odocal.output.export` into ``export_dir``, on request
  (``~/export``, ``std_srvs/Trigger``) and at shutdown;
* optionally (``controller_name`` set), the identified multipliers set on a running
  ``diff_drive_controller`` through its parameter service, relative to the nominal
  ``wheel_radius`` and ``wheel_separation`` it reports.
"""

from __future__ import annotations

import json
import math
import re
import signal
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from odocal.errors import ConfigError, MissingDependencyError, OdocalError
from odocal.estimators.estimate import Estimate, NotIdentified, Status
from odocal.io.streams import Stream
from odocal.model.parameters import PARAMETER_NAMES, Parameters
from odocal.model.step import body
from odocal.online.calibrator import OnlineCalibrator
from odocal.online.replay import GridResampler
from odocal.output.export import (
    TARGETS,
    Calibrated,
    OdometryNoise,
    export,
    parameters_yaml,
)
from odocal.report.advice import finding_text, reason_text
from odocal.settings import Settings, datasheet_theta, load_settings, parse_datasheet

try:
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from nav_msgs.msg import Odometry
    from rcl_interfaces.msg import Parameter as ParameterMsg
    from rcl_interfaces.msg import ParameterType, ParameterValue
    from rcl_interfaces.srv import GetParameters, SetParameters
    from rclpy.node import Node
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Imu, JointState
    from std_msgs.msg import String
    from std_srvs.srv import Trigger
except ImportError as err:
    raise MissingDependencyError(
        f"odocal ros2 needs ROS 2's Python packages ({err.name} is missing): "
        "pip install 'odocal[ros2]'") from err

NODE_NAME = "odocal_calibration"
#: The export targets ``export_targets`` may name (``yaml``: odometry_parameters.yaml).
EXPORTS = (*TARGETS, "yaml")
_TWO_PI = 2.0 * math.pi
#: Twist and pose variances for what the wheels do not measure (y, z, roll, pitch; the pose).
_UNKNOWN_VARIANCE = 1.0e6
_REAR = {"left": re.compile(r"(rear|back).*left|left.*(rear|back)|^rl(_|$)", re.IGNORECASE),
         "right": re.compile(r"(rear|back).*right|right.*(rear|back)|^rr(_|$)", re.IGNORECASE)}


def stamp_s(msg: Any) -> float:
    """A message's header stamp in seconds."""
    stamp = msg.header.stamp
    return float(stamp.sec) + 1e-9 * float(stamp.nanosec)


def yaw_of(q: Any) -> float:
    """The yaw (rad, counter-clockwise about z) of a ``geometry_msgs/Quaternion``."""
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def wheel_joints(names: Sequence[str], left: str, right: str, topic: str) -> tuple[int, int]:
    """The indices of the left and right rear wheel joints in a JointState's names: those named
    (``left_wheel_joint``, ``right_wheel_joint``), else the one joint whose name says rear (or
    back) and left, and right; a ConfigError naming the joints otherwise."""
    found: list[int] = []
    for side, wanted in (("left", left), ("right", right)):
        if wanted:
            if wanted not in names:
                raise ConfigError(f"{topic}: no joint named {wanted!r} ({side}_wheel_joint); "
                                  f"joints: {', '.join(names) or 'none'}")
            found.append(list(names).index(wanted))
            continue
        matches = [i for i, n in enumerate(names) if _REAR[side].search(n)]
        if len(matches) != 1:
            raise ConfigError(f"{topic}: cannot tell which joint is the rear {side} wheel among "
                              f"{', '.join(names) or 'none'}; set {side}_wheel_joint")
        found.append(matches[0])
    return found[0], found[1]


@dataclass
class _Topic:
    """One input: its name, what has been buffered since the last push, and when it spoke."""

    name: str
    role: str
    keys: tuple[str, ...]
    columns: dict[str, list[float]] = field(default_factory=dict)
    messages: int = 0
    first_receipt_s: float | None = None         # node clock (sim time where used)
    last_receipt_s: float | None = None

    def __post_init__(self) -> None:
        self.columns = {k: [] for k in ("t", *self.keys)}

    def add(self, t: float, values: Sequence[float], now_s: float) -> None:
        self.columns["t"].append(t)
        for key, value in zip(self.keys, values, strict=True):
            self.columns[key].append(value)
        self.messages += 1
        if self.first_receipt_s is None:
            self.first_receipt_s = now_s
        self.last_receipt_s = now_s

    def take(self) -> Stream | None:
        if not self.columns["t"]:
            return None
        arrays = {k: np.asarray(v, dtype=np.float64) for k, v in self.columns.items()}
        self.columns = {k: [] for k in self.columns}
        return Stream(name=self.name, role=self.role, t=arrays.pop("t"), values=arrays)

    def trim(self, keep_after_t: float) -> None:
        t = self.columns["t"]
        cut = next((i for i, v in enumerate(t) if v > keep_after_t), len(t))
        if cut:
            self.columns = {k: v[cut:] for k, v in self.columns.items()}

    def silent_for(self, now_s: float) -> float | None:
        """Seconds since its last message (None: never heard)."""
        return None if self.last_receipt_s is None else now_s - self.last_receipt_s


class CalibrationNode(Node):
    """The online calibrator on live topics (see the module's description).

    ``settings`` are the defaults (``odocal ros2 --config --datasheet``); the node's parameters
    ``settings_file`` and ``datasheet`` override them. Other keyword arguments go to
    :class:`rclpy.node.Node` (``context``, ``cli_args``, ``parameter_overrides``, ...).
    """

    def __init__(self, *, settings: Settings | None = None, node_name: str = NODE_NAME,
                 **node_kwargs: Any) -> None:
        super().__init__(node_name, **node_kwargs)
        try:
            self._setup(settings)
        except Exception:
            self.destroy_node()
            raise

    def _setup(self, settings: Settings | None) -> None:
        self._declare()
        p = self._param
        settings = settings or Settings()
        if p("settings_file"):
            settings = load_settings(p("settings_file"))
        if p("datasheet"):
            settings = settings.replace(identify={"theta0": datasheet_theta(
                parse_datasheet(p("datasheet"), what="parameter datasheet"),
                settings.identify.theta0)})
        targets = [t for t in p("export_targets") if t]
        unknown = [t for t in targets if t not in EXPORTS]
        if unknown:
            raise ConfigError(f"parameter export_targets: unknown target {unknown[0]!r}; "
                              f"choose from {', '.join(EXPORTS)}")
        self.settings = settings
        self.calibrator = OnlineCalibrator(settings)
        self.datasheet = Parameters.from_array(np.asarray(settings.identify.theta0))
        self._targets = targets
        self._grid = GridResampler(t_s=1.0 / settings.convert.rate_hz,
                                   max_gap_s=settings.convert.max_gap_s)
        self._wheels = _Topic(p("wheel_topic"), "wheels", ("n_rl", "n_rr"))
        self._pose = _Topic(p("pose_topic"), "pose", ("x", "y", "psi"))
        self._imu = _Topic(p("imu_topic"), "imu", ("yaw_rate", "a_y")) if p("imu_topic") \
            else None
        self._joints: tuple[int, int] | None = None
        self._joint_names: tuple[str, str] | None = None
        self._config_error: str | None = None
        # what has been pushed, when the estimate is next taken (as odocal replay takes it)
        self._first_t: float | None = None
        self._last_t: float | None = None
        self._next_update: float | None = None
        self._flushed_t: float | None = None
        self.estimate: Estimate | None = None
        self._good: Estimate | None = None        # the latest estimate that may be published
        self._alarms_seen = 0
        self.updates = 0
        # the odometry published per wheel message
        self._theta = self.datasheet.as_array()
        self._a_y = 0.0
        self._odom_t: float | None = None
        self._x = self._y = self._psi = 0.0
        self._noise = np.full((2, 2), np.nan)     # no measured noise before an estimate

        depth = int(p("qos_depth"))
        reliability = (ReliabilityPolicy.RELIABLE if p("qos_reliable")
                       else ReliabilityPolicy.BEST_EFFORT)   # best effort hears both kinds
        qos = QoSProfile(depth=depth, reliability=reliability)
        self.create_subscription(JointState, self._wheels.name, self._on_wheels, qos)
        self.create_subscription(Odometry, self._pose.name, self._on_pose, qos)
        if self._imu is not None:
            self.create_subscription(Imu, self._imu.name, self._on_imu, qos)
        self._odom_pub = self.create_publisher(Odometry, p("odometry_topic"), depth)
        self._diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        latched = QoSProfile(depth=50, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                             reliability=ReliabilityPolicy.RELIABLE)
        self._alarm_pub = self.create_publisher(String, "~/alarms", latched)
        self.create_service(Trigger, "~/export", self._on_export)
        self._odom = Odometry()
        self._odom.header.frame_id = p("frame_id")
        self._odom.child_frame_id = p("child_frame_id")
        self._status_name = f"{self.get_name()}: wheel odometry calibration"
        self.create_timer(float(p("diagnostics_period_s")), self.publish_diagnostics)
        self._controller = p("controller_name")
        if self._controller:
            self._get_client: Any = self.create_client(GetParameters,
                                                  f"{self._controller}/get_parameters")
            self._set_client: Any = self.create_client(SetParameters,
                                                  f"{self._controller}/set_parameters")
        self.controller_note = ""

    # ------------------------------------------------------------------ parameters

    def _declare(self) -> None:
        defaults: dict[str, Any] = {
            "wheel_topic": "/joint_states", "imu_topic": "/imu/data",
            "pose_topic": "/odometry/filtered", "left_wheel_joint": "", "right_wheel_joint": "",
            "odometry_topic": "~/odometry", "frame_id": "odom", "child_frame_id": "base_link",
            "settings_file": "", "datasheet": "", "export_dir": "",
            "export_targets": list(EXPORTS), "silence_timeout_s": 2.0,
            "diagnostics_period_s": 1.0, "qos_depth": 1000, "qos_reliable": False,
            "controller_name": ""}
        for name, value in defaults.items():
            self.declare_parameter(name, value)

    def _param(self, name: str) -> Any:
        return self.get_parameter(name).value

    def _now_s(self) -> float:
        return float(self.get_clock().now().nanoseconds) * 1e-9

    # ------------------------------------------------------------------ inputs

    def _on_wheels(self, msg: Any) -> None:
        if self._joints is None:
            try:
                self._joints = wheel_joints(list(msg.name), self._param("left_wheel_joint"),
                                            self._param("right_wheel_joint"), self._wheels.name)
            except ConfigError as exc:
                if self._config_error is None:
                    self._config_error = str(exc)
                    self.get_logger().error(self._config_error)
                    self.publish_diagnostics()
                return
            self._joint_names = (msg.name[self._joints[0]], msg.name[self._joints[1]])
        left, right = self._joints
        try:
            n_rl = float(msg.velocity[left]) / _TWO_PI
            n_rr = float(msg.velocity[right]) / _TWO_PI
        except IndexError:
            return                               # a message without velocities for them
        t = stamp_s(msg)
        if not (math.isfinite(n_rl) and math.isfinite(n_rr)):
            return
        self._wheels.add(t, (n_rl, n_rr), self._now_s())
        self._publish_odometry(msg, t, n_rl, n_rr)
        if self._flushed_t is None:
            self._flushed_t = t
        elif t - self._flushed_t >= self.settings.online.chunk_s:
            self._flushed_t = t
            self.flush()

    def _on_imu(self, msg: Any) -> None:
        assert self._imu is not None
        a_y = float(msg.linear_acceleration.y)
        self._a_y = a_y
        self._imu.add(stamp_s(msg), (float(msg.angular_velocity.z), a_y), self._now_s())

    def _on_pose(self, msg: Any) -> None:
        pose = msg.pose.pose
        self._pose.add(stamp_s(msg), (float(pose.position.x), float(pose.position.y),
                                      yaw_of(pose.orientation)), self._now_s())

    @property
    def topics(self) -> list[_Topic]:
        return [t for t in (self._wheels, self._imu, self._pose) if t is not None]

    def silent(self) -> list[str]:
        """The input topics that stayed silent longer than ``silence_timeout_s`` (or were never
        heard while another one was), each named with how long."""
        now, timeout = self._now_s(), float(self._param("silence_timeout_s"))
        heard = [t.first_receipt_s for t in self.topics if t.first_receipt_s is not None]
        if not heard:
            return []
        first = min(heard)
        out = []
        for topic in self.topics:
            quiet = topic.silent_for(now)
            if quiet is None:
                if now - first > timeout:
                    out.append(f"no message on {topic.name} ({topic.role}) yet")
            elif quiet > timeout:
                out.append(f"no message on {topic.name} ({topic.role}) for {quiet:.1f} s")
        return out

    def _lagging(self) -> bool:
        """Whether an input has not been heard yet, or not for ``silence_timeout_s`` while
        another one was (at the end of a drive they all stop together: none lags)."""
        receipts = [t.last_receipt_s for t in self.topics]
        if any(r is None for r in receipts):
            return True
        newest = max(r for r in receipts if r is not None)
        timeout = float(self._param("silence_timeout_s"))
        return any(newest - r > timeout for r in receipts if r is not None)

    def flush(self) -> None:
        """Push what has arrived into the calibrator (on the drive's grid); take the estimate
        every ``[online] update_s`` of data, publish an alarm as soon as it is raised."""
        if self._lagging():
            # an input is missing (not heard yet, or silent): nothing is calibrated from the
            # others alone; what arrived within the silence timeout is kept for when it comes
            newest = max((c.columns["t"][-1] for c in self.topics if c.columns["t"]),
                         default=None)
            if newest is not None:
                for topic in self.topics:
                    topic.trim(newest - float(self._param("silence_timeout_s")))
            return
        streams = {t.role: s for t in self.topics if (s := t.take()) is not None}
        if not streams:
            return
        chunk = self._grid.add(streams)
        if chunk is None or chunk["t"].size == 0:
            return
        if self.calibrator.halted:
            return
        self.calibrator.push(chunk)
        self._last_t = float(chunk["t"][-1])
        if self._first_t is None:
            self._first_t = float(chunk["t"][0])
            self._next_update = self._first_t + self.settings.online.update_s
        if self.calibrator.halted:
            self.update()
            return
        if len(self.calibrator.alarms) > self._alarms_seen:
            self._publish_alarms()
        assert self._next_update is not None
        if self._last_t >= self._next_update:
            self.update()
            self._next_update = self._last_t + self.settings.online.update_s

    def update(self) -> Estimate:
        """Take the estimate now and publish it on ``/diagnostics``."""
        est = self.calibrator.estimate()
        self.estimate = est
        self.updates += 1
        if publishable(est):
            self._good = est
            self._theta = est.theta.as_array()
            self._noise = np.asarray(est.details.noise if est.details is not None
                                     else np.full((2, 2), np.nan), dtype=np.float64)
            if self._controller:
                self._push_to_controller(est)
        elif est.status is Status.REJECTED:
            self._good = None
            self._theta = self.datasheet.as_array()    # never a contradicted estimate
            self._noise = np.full((2, 2), np.nan)
        if len(self.calibrator.alarms) > self._alarms_seen:
            self._publish_alarms()
        self.publish_diagnostics()
        return est

    def finish(self) -> Estimate:
        """The end of the drive (shutdown, or a test's end): push what the grid can still use,
        take the final estimate, publish it and write the export files (``export_dir``)."""
        self.flush()
        est = self.update()
        if self._param("export_dir"):
            try:
                self.write_exports(Path(self._param("export_dir")))
            except OdocalError as exc:
                self.get_logger().warning(f"no export at shutdown: {exc}")
        return est

    # ------------------------------------------------------------------ outputs

    def _publish_odometry(self, msg: Any, t: float, n_rl: float, n_rr: float) -> None:
        """(2a), (2b) with the current calibration, the pose by (1), and the twist variance from
        the error model: ``s0^2 + (f rev)^2`` per channel over ``[inverse] window_s``."""
        th = self._theta
        v, w, _, _ = body(th, n_rl, n_rr, self._a_y)
        if self._odom_t is not None and 0.0 < t - self._odom_t <= self.settings.convert.max_gap_s:
            dt = t - self._odom_t
            heading = self._psi + 0.5 * w * dt
            self._x += v * dt * math.cos(heading)
            self._y += v * dt * math.sin(heading)
            self._psi += w * dt
        self._odom_t = t
        odom = self._odom
        odom.header.stamp = msg.header.stamp
        pose = odom.pose.pose
        pose.position.x, pose.position.y = self._x, self._y
        pose.orientation.z, pose.orientation.w = math.sin(0.5 * self._psi), \
            math.cos(0.5 * self._psi)
        odom.twist.twist.linear.x, odom.twist.twist.angular.z = float(v), float(w)
        var_v, var_w = self._twist_variances(abs(float(v)))
        cov = [0.0] * 36
        for i in (0, 7, 14, 21, 28, 35):
            cov[i] = _UNKNOWN_VARIANCE
        odom.pose.covariance = cov
        twist = list(cov)
        twist[0], twist[35] = var_v, var_w
        odom.twist.covariance = twist
        self._odom_pub.publish(odom)

    def _twist_variances(self, speed_mps: float) -> tuple[float, float]:
        """Speed and yaw-rate variances over ``[inverse] window_s`` from the error model of
        the latest estimate (unknown, a large variance, before one)."""
        noise = self._noise
        if not np.all(np.isfinite(noise)):
            return _UNKNOWN_VARIANCE, _UNKNOWN_VARIANCE
        c_e, t_r = float(self._theta[0]), float(self._theta[2])
        window = self.settings.inverse.window_s
        rev = speed_mps * window / c_e
        var = noise[:, 0] ** 2 + (noise[:, 1] * rev) ** 2         # revolutions^2 per window
        return (float(var[0] * (c_e / window) ** 2),
                float(var[1] * (c_e / (t_r * window)) ** 2))

    def _publish_alarms(self) -> None:
        for alarm in self.calibrator.alarms[self._alarms_seen:]:
            self._alarm_pub.publish(String(data=json.dumps(alarm.to_dict())))
            self.get_logger().warning(f"change: {alarm.parameter} moved "
                                      f"{alarm.relative_change * 100:+.3f}% at "
                                      f"{alarm.distance_km:.2f} km")
        self._alarms_seen = len(self.calibrator.alarms)
        self.publish_diagnostics()

    def status(self) -> list[Any]:
        """The node's statuses for ``/diagnostics``: the calibration, and its change alarms."""
        main = DiagnosticStatus(name=self._status_name, hardware_id=self._wheels.name)
        values: list[tuple[str, str]] = []
        est = self.estimate
        calibrator = self.calibrator
        values += [("distance_km", f"{calibrator.distance_km:.4f}"),
                   ("samples", str(calibrator.details_samples())),
                   ("updates", str(self.updates))]
        values += [(f"messages {t.name}", str(t.messages)) for t in self.topics]
        silent = self.silent()
        rejected = calibrator.halted or (est is not None and est.status is Status.REJECTED)
        if self._config_error is not None:
            main.level, main.message = DiagnosticStatus.ERROR, self._config_error
        elif rejected:
            main.level = DiagnosticStatus.ERROR
            main.message = self._rejection(est)
        elif silent:
            main.level, main.message = DiagnosticStatus.WARN, "; ".join(silent)
        elif self._good is None:
            main.level = DiagnosticStatus.WARN
            main.message = ("not yet identified: " + ", ".join(PARAMETER_NAMES)
                            + f" ({calibrator.distance_km:.2f} km driven; "
                            + ("no estimate yet)" if est is None else f"{est.message})"))
        else:
            missing = [(n, v) for n, v in zip(PARAMETER_NAMES, self._good.verdicts, strict=True)
                       if isinstance(v, NotIdentified)]
            if missing:
                threshold = self.settings.segments.yaw_rate_threshold_radps
                main.level = DiagnosticStatus.WARN
                main.message = "not yet identified: " + "; ".join(
                    f"{n} ({reason_text(n, v, threshold_radps=threshold)})" for n, v in missing)
            else:
                main.level = DiagnosticStatus.OK
                main.message = ("identified and within the gate: " + ", ".join(
                    f"{n} {v:.6g}" for n, v in self._good.theta.as_dict().items()))
        if self._good is not None and not rejected and self._config_error is None:
            good = self._good
            for n, v, s, ok in zip(PARAMETER_NAMES, good.theta.as_array(), good.std,
                                   good.identified, strict=True):
                values += [(n, repr(float(v))), (f"{n}_std", repr(float(s))),
                           (f"{n}_identified", "true" if ok else "false")]
            values.append(("status", good.status.name))
        if self._controller and self.controller_note:
            values.append(("controller", self.controller_note))
        main.values = [KeyValue(key=k, value=v) for k, v in values]
        statuses = [main]
        if calibrator.alarms:
            last = calibrator.alarms[-1]
            statuses.append(DiagnosticStatus(
                level=DiagnosticStatus.WARN, name=f"{self.get_name()}: change alarm",
                hardware_id=self._wheels.name,
                message=(f"{last.parameter} moved {last.relative_change * 100:+.3f}% at "
                         f"{last.distance_km:.2f} km (detected at "
                         f"{last.detected_distance_km:.2f} km): recalibrate"),
                values=[KeyValue(key=k, value=str(v)) for k, v in last.to_dict().items()]
                + [KeyValue(key="alarms", value=str(len(calibrator.alarms)))]))
        return statuses

    def _rejection(self, est: Estimate | None) -> str:
        findings = (est.details.findings if est is not None and est.details is not None
                    else self.calibrator.diagnosis.findings)
        fatal = [f for f in findings if int(f.severity) == 2]
        if fatal:
            return "the data contradict the model: " + finding_text(fatal[0], self.settings)
        return "calibration rejected: " + (est.message if est is not None else "by the checks")

    def publish_diagnostics(self) -> None:
        msg = DiagnosticArray()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.status = self.status()
        self._diag_pub.publish(msg)

    # ------------------------------------------------------------------ exports

    def calibrated(self) -> Calibrated:
        """The latest publishable estimate as the exports take it (a ConfigError if none)."""
        est = self._good
        if est is None or self.calibrator.halted:
            why = (self._rejection(self.estimate) if self.calibrator.halted
                   else "nothing is identified yet")
            raise ConfigError(f"no calibration to export: {why}")
        details = est.details
        noise = None
        if details is not None:
            windows = max(details.windows, 1)
            c_e = est.theta.c_e
            mean_rev = details.distance_km * 1000.0 / windows / c_e
            window = self.settings.inverse.window_s
            n = np.asarray(details.noise)
            var = n[:, 0] ** 2 + (n[:, 1] * mean_rev) ** 2
            noise = OdometryNoise(speed_std_mps=float(math.sqrt(var[0]) * c_e / window),
                                  yaw_rate_std_radps=float(math.sqrt(var[1]) * c_e
                                                           / (est.theta.t_r * window)),
                                  windows=int(details.windows), window_s=window)
        topics = ", ".join(t.name for t in self.topics)
        return Calibrated(theta=est.theta, datasheet=est.datasheet,
                          std=tuple(float(s) for s in est.std),
                          identified=est.identified, method="online (odocal ros2)",
                          noise=noise, source=f"ROS 2 topics {topics}",
                          wheel_joints=self._joint_names,
                          covariance=tuple(tuple(float(v) for v in row)
                                           for row in est.covariance))

    def write_exports(self, folder: Path) -> list[Path]:
        """The export files of the latest publishable estimate into ``folder``."""
        calibrated = self.calibrated()
        folder.mkdir(parents=True, exist_ok=True)
        written = export(calibrated, folder, [t for t in self._targets if t in TARGETS])
        if "yaml" in self._targets:
            written.append(parameters_yaml(calibrated, folder / "odometry_parameters.yaml"))
        return written

    def _on_export(self, request: Any, response: Any) -> Any:
        folder = self._param("export_dir")
        if not folder:
            response.success, response.message = False, "set the parameter export_dir first"
            return response
        try:
            written = self.write_exports(Path(folder))
        except (OdocalError, OSError) as exc:
            response.success, response.message = False, str(exc)
            return response
        response.success = True
        response.message = "wrote " + ", ".join(str(p) for p in written)
        return response

    # ------------------------------------------------------------------ controller

    def _push_to_controller(self, est: Estimate) -> None:
        """Set the identified multipliers on the controller, relative to its own nominal
        ``wheel_radius`` and ``wheel_separation`` (asked first)."""
        if not self._get_client.service_is_ready():
            self.controller_note = f"no parameter service {self._controller}/get_parameters"
            return
        request = GetParameters.Request(names=["wheel_radius", "wheel_separation"])
        future = self._get_client.call_async(request)
        future.add_done_callback(lambda f: self._set_multipliers(f, est))

    def _set_multipliers(self, future: Any, est: Estimate) -> None:
        try:
            radius, separation = (v.double_value for v in future.result().values)
        except Exception as exc:  # the service's own failure, as it said it
            self.get_logger().debug(f"reading the controller's parameters: {exc!r}")
            self.controller_note = f"cannot read the controller's nominal values: {exc}"
            return
        if not (radius > 0 and separation > 0):
            self.controller_note = "the controller reports no wheel_radius / wheel_separation"
            return
        th = est.theta
        c_e, c_d, t_r, _ = th.as_array()
        nominal_c = _TWO_PI * radius
        wanted = {"left_wheel_radius_multiplier": (c_e + c_d / 2) / nominal_c,
                  "right_wheel_radius_multiplier": (c_e - c_d / 2) / nominal_c,
                  "wheel_separation_multiplier": t_r / separation}
        ok = dict(zip(PARAMETER_NAMES, est.identified, strict=True))
        if not ok["c_e"]:
            wanted.pop("left_wheel_radius_multiplier")
            wanted.pop("right_wheel_radius_multiplier")
        if not ok["t_r"]:
            wanted.pop("wheel_separation_multiplier")
        if not wanted:
            return
        params = [ParameterMsg(name=k, value=ParameterValue(type=ParameterType.PARAMETER_DOUBLE,
                                                            double_value=float(v)))
                  for k, v in wanted.items()]
        done = self._set_client.call_async(SetParameters.Request(parameters=params))
        done.add_done_callback(lambda f: self._controller_set(f, wanted))

    def _controller_set(self, future: Any, wanted: dict[str, float]) -> None:
        try:
            results = future.result().results
        except Exception as exc:  # the service's own failure, as it said it
            self.get_logger().debug(f"setting the controller's multipliers: {exc!r}")
            self.controller_note = f"setting the multipliers failed: {exc}"
            return
        refused = [f"{k}: {r.reason}" for k, r in zip(wanted, results, strict=False)
                   if not r.successful]
        self.controller_note = ("refused: " + "; ".join(refused) if refused else
                                "set " + ", ".join(f"{k}={v:.6g}" for k, v in wanted.items()))


def publishable(est: Estimate) -> bool:
    """Whether an estimate may be published: converged (or exact), identified something and
    not refused by the checks or the gate."""
    return est.status in (Status.CONVERGED, Status.EXACT) and any(est.identified)


def run(ros_args: Sequence[str], *, settings: Settings | None = None,
        on_ready: Callable[[CalibrationNode], None] | None = None) -> int:
    """Start the node with ``ros_args`` (``--ros-args ...``) and spin until Ctrl-C or SIGTERM;
    then the final estimate is published and the export files written. Returns an exit code."""
    # the events executor takes 5x the messages per second of the SingleThreadedExecutor
    from rclpy.executors import ExternalShutdownException
    from rclpy.experimental import EventsExecutor
    from rclpy.signals import SignalHandlerOptions

    try:
        rclpy.init(args=["odocal", *ros_args], signal_handler_options=SignalHandlerOptions.NO)
    except Exception as exc:   # rcl refuses the arguments (a bad -p, a missing params file)
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise ConfigError(f"ROS 2 arguments {' '.join(ros_args)!r}: {first}") from exc
    node: CalibrationNode | None = None
    previous = signal.getsignal(signal.SIGTERM)

    def stop(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, stop)
    try:
        node = CalibrationNode(settings=settings)
        if on_ready is not None:
            on_ready(node)
        executor = EventsExecutor()
        executor.add_node(node)
        try:
            # spin_once in a Python loop: Ctrl-C and SIGTERM reach Python between calls (the
            # events executor's own spin() does not return to Python for a signal)
            while rclpy.ok():
                executor.spin_once(timeout_sec=0.1)
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
        node.finish()
        return 0
    finally:
        signal.signal(signal.SIGTERM, previous)
        if node is not None:
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
