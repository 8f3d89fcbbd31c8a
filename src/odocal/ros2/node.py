"""``odocal ros2``: the online calibrator as a ROS 2 (lifecycle) node.

Inputs (topic names, message types and wheel joint names are parameters, :mod:`odocal.ros2.params`;
time is each message's header stamp, never its arrival; ``use_sim_time`` is honoured):

* the wheel joints' velocities (rad/s) or, where the driver sends none, positions (rad) from
  ``sensor_msgs/JointState``: the rear wheels; for the four-wheel car (``[vehicle] model =
  "four_wheel"`` in ``settings_file``) the front wheels too, and the steering wheel's angle
  where ``steering_joint`` names its joint in the same message;
* the lateral acceleration and yaw rate from ``sensor_msgs/Imu`` (in the vehicle's axes after
  ``imu_rotation_deg``);
* the reference pose from ``nav_msgs/Odometry`` or ``geometry_msgs/PoseWithCovarianceStamped``
  (and, with ``sideslip_from_reference``, the sideslip from the Odometry's twist).

Each input is read from the bytes DDS carried (``raw=True``, :mod:`odocal.ros2.cdr`): no message
objects are built. A topic's stamps are checked as they come (:class:`odocal.ros2.inputs.
Continuity`): what their continuity says did not arrive, stamps that went back, NaN values: each
counted, refused and named on ``/diagnostics``, never a stop. Times are seconds from the first
message's stamp (exact for a day of driving whatever the clock's epoch); the messages are put onto
the drive's grid (:class:`odocal.online.replay.GridResampler`, aligned to the wheels' first
stamp) and pushed into an :class:`~odocal.OnlineCalibrator` in the blocks of rows ``odocal
replay`` pushes a drive file in; every ``[online] update_s`` of data the estimate is taken, as
replay takes it.

Outputs:

* ``~/odometry`` (``nav_msgs/Odometry``), one per wheel message: the wheel odometry with the
  published calibration (equations (2)-(3) of :mod:`odocal.model.step`; the dead-reckoned
  pose) and the covariance of that message's speed and yaw rate (:mod:`odocal.ros2.twist`);
  from the rear wheels, for the car too (with its rear axle's calibration);
* ``~/estimate`` (``std_msgs/Float64MultiArray``, latched): the published calibration as data,
  a row per parameter (the rear axle's c_e, c_d, t_r, d; the car's ten) of value, std,
  identified (1/0) and the covariance row;
* ``/diagnostics``: OK when every parameter is identified, WARN while something is not (named,
  with why), an input is silent, loses messages or sends what cannot be used, or the latest
  estimate was refused while an earlier one stands; ERROR where the data contradict the model
  (the calibrator halted) or nothing was ever publishable but a refusal;
* ``~/alarms`` (``std_msgs/String``, latched): each change alarm as JSON;
* the parameter files of :mod:`odocal.output.export` into ``export_dir``, on request
  (``~/export``) and at shutdown; ``~/reset`` (``std_srvs/Trigger``) starts the calibration
  over (after a tyre change);
* optionally (``controller_name``), the identified multipliers set on a running
  ``diff_drive_controller`` through its parameter service (the rear axle's only).

A rejected estimate (the checks' or the gate's) never replaces the last publishable one in
anything the node publishes; where the calibrator halts (the data contradict the model) the
odometry falls back to the datasheet values and nothing is exported.
"""

from __future__ import annotations

import json
import math
import signal
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from odocal.errors import ConfigError, MissingDependencyError, OdocalError
from odocal.estimators.estimate import Estimate, NotIdentified, Status
from odocal.estimators.front_axle import rear_axle_of
from odocal.io import joints
from odocal.model import registry
from odocal.model.four_wheel import FOUR_WHEEL_MODEL
from odocal.model.parameters import Parameters
from odocal.model.vehicle import MODEL
from odocal.online.replay import GridResampler, publishable
from odocal.output.export import Calibrated, export, parameters_yaml, targets_for
from odocal.pipeline.odometry import OdometryNoise
from odocal.report.advice import finding_text, reason_text
from odocal.ros2 import cdr, params
from odocal.ros2.calibrating import (
    Beside,
    CalibratorLost,
    Event,
    InThread,
    LeftOut,
    Raised,
    Updated,
    View,
)
from odocal.ros2.exports import imu_corrector, point_ekf_at
from odocal.ros2.gyro import GyroBias
from odocal.ros2.inputs import TWO_PI, Buffer, Continuity, Rates, wheel_joints
from odocal.ros2.twist import UNKNOWN_VARIANCE, TwistVariance
from odocal.settings import Settings, datasheet_theta, load_settings, parse_datasheet

try:
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from geometry_msgs.msg import PoseWithCovarianceStamped
    from nav_msgs.msg import Odometry
    from rcl_interfaces.msg import (
        FloatingPointRange,
        IntegerRange,
        ParameterDescriptor,
        ParameterType,
        SetParametersResult,
    )
    from rclpy.clock import Clock, ClockType
    from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import Imu, JointState
    from std_msgs.msg import Float64MultiArray, MultiArrayDimension, String
    from std_srvs.srv import Trigger

    from odocal.ros2.controller import ControllerPush
except ImportError as err:
    raise MissingDependencyError(
        f"odocal ros2 needs ROS 2's Python packages ({err.name} is missing): "
        "pip install 'odocal[ros2]' (from a checkout: pip install '.[ros2]')") from err

NODE_NAME = "odocal_calibration"
EXPORTS = params.EXPORTS
#: A topic that lost messages is named on /diagnostics for this long (s of its stamps) after.
LOSS_NAMED_S = 60.0
#: At most this many messages of one input are taken in one callback (the executor calls
#: again for the rest: a backlog is not held in memory all at once).
MAX_BATCH = 500
#: Requests to the calibrator beside the node not answered yet (blocks of ``[online] chunk_s``
#: of data) beyond which /diagnostics says it is behind.
BEHIND = 60
_LATCHED = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                      reliability=ReliabilityPolicy.RELIABLE)
_SUCCESS, _FAILURE = TransitionCallbackReturn.SUCCESS, TransitionCallbackReturn.FAILURE
_KINDS = {"bool": ParameterType.PARAMETER_BOOL, "integer": ParameterType.PARAMETER_INTEGER,
          "double": ParameterType.PARAMETER_DOUBLE, "string": ParameterType.PARAMETER_STRING,
          "string_array": ParameterType.PARAMETER_STRING_ARRAY,
          "double_array": ParameterType.PARAMETER_DOUBLE_ARRAY}


def yaw_of(q: Sequence[float]) -> float:
    """The yaw (rad, counter-clockwise about z) of a quaternion (x, y, z, w)."""
    x, y, z, w = q
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def rotation(rpy_deg: Sequence[float]) -> tuple[tuple[float, ...], ...] | None:
    """The rotation taking the IMU's vectors into the vehicle's axes (roll, pitch, yaw in
    degrees, applied about the vehicle's x, y, z: R = Rz Ry Rx); None for none."""
    if not any(rpy_deg):
        return None
    r, p, y = (math.radians(a) for a in rpy_deg)
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), \
        math.cos(y), math.sin(y)
    return ((cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr),
            (sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr),
            (-sp, cp * sr, cp * cr))


class _Input:
    """One input topic: its name, role, what its stamps say and what waits for the grid."""

    def __init__(self, name: str, role: str, keys: tuple[str, ...]) -> None:
        self.name, self.role = name, role
        self.buffer = Buffer(name, role, keys)
        self.stamps = Continuity()
        # when it was last seen to speak, on the node's clock (checked when the status is made)
        self.first_receipt_s: float | None = None
        self.last_receipt_s: float | None = None
        self.seen = 0                  # messages taken when it was last checked
        self.undecodable = 0
        self.note = ""                 # why messages were refused (the latest reason)
        self.partial = 0               # taken without a front wheel's or the steering's value

    def taken(self) -> int:
        """Messages taken from the topic, used or refused."""
        return self.stamps.received + self.stamps.back + self.undecodable

    def check_heard(self, now_s: float) -> None:
        """Note ``now_s`` as when it spoke, where messages came since the last check."""
        count = self.taken()
        if count != self.seen:
            self.seen = count
            if self.first_receipt_s is None:
                self.first_receipt_s = now_s
            self.last_receipt_s = now_s

    def problems(self) -> list[str]:
        """What is wrong with what arrived, in words (recent losses, refused messages)."""
        s, out = self.stamps, []
        if s.missing and s.last_t is not None and s.last_missing_t is not None \
                and s.last_t - s.last_missing_t <= LOSS_NAMED_S:
            out.append(f"{self.name}: {s.missing_share * 100:.1f}% of the messages missing by "
                       f"their stamps ({s.missing} of {s.received + s.missing})")
        if s.back:
            out.append(f"{self.name}: {s.back} messages refused, their stamps went back (up to "
                       f"{s.back_max_s:.3g} s)")
        if s.invalid:
            why = self.note or "NaN or infinite values"
            out.append(f"{self.name}: {s.invalid} messages refused, {why}")
        if self.undecodable:
            out.append(f"{self.name}: {self.undecodable} messages that are not "
                       f"{self.role} messages ({self.note})")
        if self.partial:
            out.append(f"{self.name}: {self.partial} messages with a NaN or infinite front "
                       "wheel or steering value: those values left out, the rear wheels kept")
        return out


class CalibrationNode(LifecycleNode):
    """The online calibrator on live topics (see the module's description).

    ``settings`` are the defaults (``odocal ros2 --config --datasheet``); the node's parameters
    ``settings_file`` and ``datasheet`` override them. With ``autostart`` (the default) the node
    configures and activates itself and raises a ConfigError (one line) where it cannot. Other
    keyword arguments go to :class:`rclpy.node.Node` (``context``, ``parameter_overrides``, ...).
    """

    def __init__(self, *, settings: Settings | None = None, node_name: str = NODE_NAME,
                 **node_kwargs: Any) -> None:
        super().__init__(node_name, **node_kwargs)
        try:
            self._defaults = settings or Settings()
            self._entities: list[Any] = []
            self._outputs: list[Any] = []
            self._configured = self._active = self._finished = False
            self._configure_error: str | None = None
            self._declare()
            if self._param("autostart"):
                self.start()
        except Exception:
            self.destroy_node()
            raise

    def destroy_node(self) -> None:
        self._close_calibration()
        super().destroy_node()

    # ------------------------------------------------------------------ parameters

    def _declare(self) -> None:
        """Every parameter with its descriptor, after the values given are checked."""
        given = getattr(self, "_parameter_overrides", {})
        params.check_given({name: p.value for name, p in given.items()})
        for spec in params.SPECS:
            descriptor = ParameterDescriptor(
                name=spec.name, type=_KINDS[spec.kind], description=spec.description,
                read_only=not spec.writable, dynamic_typing=spec.any_type)
            if spec.kind == "double" and spec.low is not None and spec.high is not None:
                descriptor.floating_point_range = [FloatingPointRange(
                    from_value=float(spec.low), to_value=float(spec.high), step=0.0)]
            if spec.kind == "integer" and spec.low is not None and spec.high is not None:
                descriptor.integer_range = [IntegerRange(
                    from_value=int(spec.low), to_value=int(spec.high), step=0)]
            self.declare_parameter(spec.name, spec.default, descriptor)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        self.add_post_set_parameters_callback(self._on_parameters_set)

    def _on_set_parameters(self, changed: Sequence[Any]) -> Any:
        """A change at run time: refused with the reason where the value cannot be used."""
        for p in changed:
            spec = params.BY_NAME.get(p.name)
            problem = params.check_value(spec, p.value) if spec is not None else None
            if problem is not None:
                return SetParametersResult(successful=False, reason=problem)
        return SetParametersResult(successful=True)

    def _on_parameters_set(self, changed: Sequence[Any]) -> None:
        """A change taken: the diagnostics timer follows its period (others are read where
        used)."""
        if self._configured and any(p.name == "diagnostics_period_s" for p in changed):
            self._restart_timer()

    def _param(self, name: str) -> Any:
        return self.get_parameter(name).value

    def _now_s(self) -> float:
        return float(self.get_clock().now().nanoseconds) * 1e-9


    # ------------------------------------------------------------------ lifecycle

    def start(self) -> None:
        """Configure and activate (a ConfigError, one line, where configuring fails)."""
        if self.trigger_configure() != _SUCCESS:
            raise ConfigError(self._configure_error or "the node could not be configured")
        self.trigger_activate()

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        try:
            self._configure()
        except OdocalError as exc:
            self._configure_error = str(exc)
            self.get_logger().error(self._configure_error)
            self._teardown()
            return _FAILURE
        self._configured = True
        return super().on_configure(state)

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        result = super().on_activate(state)
        self._active = True
        self.get_logger().info(self._start_line())
        self.publish_diagnostics()
        return result

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._active = False
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._teardown()
        return super().on_cleanup(state)

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        if self._configured:
            self.finish()
        self._teardown()
        return super().on_shutdown(state)

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._teardown()
        return _SUCCESS

    @property
    def controller_note(self) -> str:
        """What became of the multipliers pushed to ``controller_name`` (empty: nothing)."""
        return self._controller.note if self._controller is not None else ""

    @property
    def finalized(self) -> bool:
        """Whether the lifecycle has shut the node down (it takes nothing more)."""
        return bool(self._state_machine.current_state[1] == "finalized")

    # ------------------------------------------------------------------ configure

    def _configure(self) -> None:
        settings = self._defaults
        p = self._param
        if p("settings_file"):
            settings = load_settings(p("settings_file"))
        if p("datasheet"):
            settings = settings.replace(identify={"theta0": datasheet_theta(
                parse_datasheet(p("datasheet"), what="parameter datasheet"),
                settings.identify.theta0)})
        self.settings = settings
        self._layout = registry.layout(settings.vehicle.model)
        self._car = settings.vehicle.model == FOUR_WHEEL_MODEL.name
        self._check_car()
        self.datasheet = Parameters.from_array(np.asarray(settings.identify.theta0),
                                               layout=self._layout)
        names = {key: self._topic(key) for key in ("wheel_topic", "pose_topic", "imu_topic",
                                                   "odometry_topic")}
        self._rotation = rotation(p("imu_rotation_deg"))
        self._pose_reader = (cdr.odometry if p("pose_type") == "odometry"
                             else cdr.pose_with_covariance)
        self._pose_quick = (cdr.odometry_reader() if p("pose_type") == "odometry"
                            else cdr.pose_reader())
        self._imu_quick = cdr.imu_reader()
        self._beta_wanted = bool(p("sideslip_from_reference"))
        if self._beta_wanted and p("pose_type") != "odometry":
            raise ConfigError("parameter sideslip_from_reference: true needs pose_type "
                              "odometry (a PoseWithCovarianceStamped carries no twist)")
        self._wheel_names = names["wheel_topic"]
        self._imu_name = names["imu_topic"]
        self._pose_name = names["pose_topic"]
        self._fresh()
        self._create_entities(names)
        # the estimate imports scipy.special at its first call (0.9 s here): done now, not
        # under the first estimate, when the inputs' queues would fill meanwhile
        import scipy.special  # noqa: F401

    def _check_car(self) -> None:
        """The car's parameters where the model is the car, and only there (one line)."""
        p = self._param
        car_only = [k for k in ("front_left_wheel_joint", "front_right_wheel_joint",
                                "steering_joint") if p(k)]
        car_only += ["steering_unit"] if p("steering_unit") != "rad" else []
        if not self._car and car_only:
            raise ConfigError(f"parameter {car_only[0]}: the {self.settings.vehicle.model} "
                              "model reads no front wheels or steering; choose the car with "
                              "[vehicle] model = \"four_wheel\" in settings_file")
        if self._car and p("controller_name"):
            raise ConfigError("parameter controller_name: a diff_drive_controller's multipliers "
                              "are the rear axle's; the four_wheel model's calibration goes to "
                              "ackermann_steering_controller by its parameter file (export_dir)")
        self._steered = self._car and bool(p("steering_joint"))
        self._steer_scale = math.pi / 180.0 if p("steering_unit") == "deg" else 1.0

    def _rear(self, theta: Any) -> np.ndarray:
        """The rear axle's parameters of a theta of the node's model (the car's leading four)."""
        theta = np.asarray(theta, dtype=float)
        return FOUR_WHEEL_MODEL.rear_axle(theta) if self._car else theta

    def _topic(self, key: str) -> str:
        """A topic parameter, resolved (a ConfigError naming it where it is no topic name)."""
        value = self._param(key)
        if not value:
            if key == "imu_topic":
                return ""
            raise ConfigError(f"parameter {key}: empty; it takes a topic name")
        try:
            return str(self.resolve_topic_name(value))
        except Exception as exc:   # rclpy's name validation, as it words it
            first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise ConfigError(f"parameter {key}: {value!r} is not a valid topic name "
                              f"({first})") from exc

    def _fresh(self) -> None:
        """Everything calibrated so far forgotten: a new calibrator, grid and inputs."""
        s = self.settings
        self._close_calibration()
        self.calibrator = View()
        self._calibration: Beside | InThread | None = (
            Beside(s) if self._param("calibrator_process") else InThread(s))
        self._lost = ""
        self._grid = GridResampler(t_s=1.0 / s.convert.rate_hz, max_gap_s=s.convert.max_gap_s)
        self._rows_per_push = max(int(s.online.chunk_s * s.convert.rate_hz), 1)
        self._pending: list[dict[str, np.ndarray]] = []
        self._beta: list[tuple[float, float]] = []
        self._wheels = _Input(self._wheel_names, "wheels",
                              ("n_rl", "n_rr", *(("n_fl", "n_fr") if self._car else ()),
                               *(("steer",) if self._steered else ())))
        self._pose = _Input(self._pose_name, "pose", ("x", "y", "psi"))
        self._imu = _Input(self._imu_name, "imu", ("yaw_rate", "a_y")) if self._imu_name \
            else None
        self._joints: tuple[str, str] | None = None
        self._reader = cdr.JointReader(self._pick_joints)
        self._rates = Rates(s.convert.max_gap_s)
        self._mixed = False            # wheel messages with velocities and without, mixed
        self._max_gap_s = s.convert.max_gap_s
        self._config_error: str | None = None
        self._origin: tuple[int, int] | None = None
        self._flushed_t: float | None = None
        self.estimate: Estimate | None = None
        self._good: Estimate | None = None        # the latest estimate that may be published
        self._good_km = 0.0
        self._identified: tuple[bool, ...] = (False,) * self._layout.size
        self._alarms_seen = 0
        self._push_error = ""
        self.updates = 0
        self.twist = TwistVariance(window_s=s.inverse.window_s, max_gap_s=s.convert.max_gap_s)
        self.gyro = GyroBias(s.convert.max_gap_s)
        self._use_theta(self._rear(self.datasheet.as_array()))
        self._a_y = 0.0
        self._odom_t: float | None = None
        self._x = self._y = self._psi = 0.0

    def _create_entities(self, names: dict[str, str]) -> None:
        p = self._param
        depth = int(p("qos_depth"))
        reliability = (ReliabilityPolicy.RELIABLE if p("qos_reliable")
                       else ReliabilityPolicy.BEST_EFFORT)   # best effort hears both kinds
        qos = QoSProfile(depth=depth, reliability=reliability)
        pose_type = Odometry if p("pose_type") == "odometry" else PoseWithCovarianceStamped
        add = self._entities.append
        pub = self._outputs.append
        # each input's callback takes every message waiting behind the one it was handed
        # (one Python call for a backlog, not one per message)
        self._wheel_sub = self.create_subscription(
            JointState, names["wheel_topic"], self._taker("_wheel_sub", self._wheel_batch),
            qos, raw=True)
        self._pose_sub = self.create_subscription(
            pose_type, names["pose_topic"], self._taker("_pose_sub", self._pose_batch), qos,
            raw=True)
        self._imu_sub: Any = None
        if names["imu_topic"]:
            self._imu_sub = self.create_subscription(
                Imu, names["imu_topic"], self._taker("_imu_sub", self._imu_batch), qos,
                raw=True)
        for sub in (self._wheel_sub, self._imu_sub, self._pose_sub):
            if sub is not None:
                add(sub)
        self._odom_pub = self.create_lifecycle_publisher(Odometry, names["odometry_topic"],
                                                         QoSProfile(depth=min(depth, 1000)))
        self._diag_pub = self.create_lifecycle_publisher(DiagnosticArray, "/diagnostics", 10)
        self._alarm_pub = self.create_lifecycle_publisher(
            String, "~/alarms", QoSProfile(depth=50, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                                           reliability=ReliabilityPolicy.RELIABLE))
        self._estimate_pub = self.create_lifecycle_publisher(Float64MultiArray, "~/estimate",
                                                             _LATCHED)
        for publisher in (self._odom_pub, self._diag_pub, self._alarm_pub, self._estimate_pub):
            pub(publisher)
        add(self.create_service(Trigger, "~/export", self._on_export))
        add(self.create_service(Trigger, "~/reset", self._on_reset))
        template = Odometry()
        template.header.frame_id = p("frame_id")
        template.child_frame_id = p("child_frame_id")
        self._writer = cdr.OdometryWriter(serialize_message(template))
        self._writer.covariances(_unknown_covariance(), _unknown_covariance())
        self._status_name = f"{self.get_name()}: wheel odometry calibration"
        self._timer: Any = None
        self._restart_timer()
        # the answers of a calibrator beside the node are read as they come, on the wall's
        # clock (the drive's may have stopped), where no message calls first
        self._steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._answers_timer = self.create_timer(0.02, self._answers_due, clock=self._steady)
        self._controller: ControllerPush | None = None
        if p("controller_name"):
            self._controller = ControllerPush(self, p("controller_name"))
            for client in self._controller.clients:
                add(client)

    def _restart_timer(self) -> None:
        if self._timer is not None:
            self.destroy_timer(self._timer)
        self._timer = self.create_timer(float(self._param("diagnostics_period_s")),
                                        self.publish_diagnostics)

    def _teardown(self) -> None:
        """Every subscription, publisher, service, client and the timer gone."""
        self._active = self._configured = False
        for entity in self._entities:
            (self.destroy_subscription(entity) or self.destroy_service(entity)
             or self.destroy_client(entity))
        for publisher in self._outputs:
            self.destroy_lifecycle_publisher(publisher)
        self._entities, self._outputs = [], []
        for name in ("_timer", "_answers_timer"):
            timer = getattr(self, name, None)
            if timer is not None:
                self.destroy_timer(timer)
                setattr(self, name, None)
        self._close_calibration()

    def _start_line(self) -> str:
        qos = "reliable" if self._param("qos_reliable") else "best effort"
        inputs = [f"{self._wheel_names} (JointState)", f"{self._pose_name} ("
                  + ("Odometry" if self._param("pose_type") == "odometry"
                     else "PoseWithCovarianceStamped") + ")"]
        if self._imu_name:
            inputs.append(f"{self._imu_name} (Imu)")
        return (f"{self.get_fully_qualified_name()}: calibrating the "
                f"{self.settings.vehicle.model} model from {', '.join(inputs)} "
                f"(QoS {qos}, depth {self._param('qos_depth')}); publishing "
                f"{self._odom_pub.topic_name}, {self._estimate_pub.topic_name}, "
                f"{self._alarm_pub.topic_name}, /diagnostics; services "
                f"{self.get_fully_qualified_name()}/export, "
                f"{self.get_fully_qualified_name()}/reset")

    # ------------------------------------------------------------------ inputs

    def _time(self, sec: int, nanosec: int) -> float:
        """A stamp as seconds from the first message's (exact whatever the clock's epoch)."""
        if self._origin is None:
            self._origin = (sec, nanosec)
        return float(sec - self._origin[0]) + 1e-9 * float(nanosec - self._origin[1])

    def stamp_of(self, t: float) -> float:
        """A time of the node's (seconds from its origin) on the messages' clock."""
        if self._origin is None:
            return t
        return t + self._origin[0] + 1e-9 * self._origin[1]

    def _pick_joints(self, names: tuple[str, ...]) -> tuple[tuple[int, ...], int | None]:
        """The wheel joints' indices (rear left, rear right; the car's front left and right
        after them) and the steering joint's (None: none), by :mod:`odocal.io.joints`' rule."""
        p, topic = self._param, self._wheels.name
        left, right = wheel_joints(names, p("left_wheel_joint"), p("right_wheel_joint"), topic)
        if not self._car:
            self._joints = (names[left], names[right])
            self._config_error = None
            return (left, right), None
        front = joints.front_wheel_joints(
            names, (p("front_left_wheel_joint"), p("front_right_wheel_joint")), where=topic,
            setting=lambda side: f"front_{side}_wheel_joint", error=ConfigError)
        if front is None:
            raise ConfigError(f"{topic}: the four_wheel model needs the front wheels, and "
                              f"cannot tell which joints they are among {', '.join(names)}; "
                              "set front_left_wheel_joint and front_right_wheel_joint")
        if set(front) & {left, right}:
            raise ConfigError(f"{topic}: a front wheel is the rear wheel's joint "
                              f"{names[next(iter(set(front) & {left, right}))]!r}; set "
                              "front_left_wheel_joint and front_right_wheel_joint")
        steering = (joints.named_joint(names, p("steering_joint"), where=topic,
                                       setting="steering_joint", error=ConfigError)
                    if self._steered else None)
        if steering in (left, right, *front):
            raise ConfigError(f"{topic}: the steering joint {names[steering]!r} is a wheel's; "
                              "set steering_joint to the steering wheel's joint")
        self._joints = (names[left], names[right])
        self._config_error = None          # (a layout that reads: an earlier one's error gone)
        return (left, right, *front), steering

    def _further(self, more: Sequence[float]) -> tuple[float, ...]:
        """The car's further columns of a quick read's values after the rear wheels' (the front
        ones' velocities, rad/s, and the steering's position): :meth:`_front_row`; () for the
        rear axle."""
        if not more:
            return ()
        return self._front_row((more[0] / TWO_PI, more[1] / TWO_PI),
                               more[2] if len(more) > 2 else None)

    def _front_row(self, rates: Sequence[float], angle: float | None) -> tuple[float, ...]:
        """The car's further wheel columns of a message (the front rates in rev/s, the
        steering in rad); a NaN or infinite one left out (NaN: not measured, as the front fit
        takes it) and counted, the rear wheels' sample kept."""
        row = (*rates, *(() if angle is None else (angle * self._steer_scale,)))
        if all(map(math.isfinite, row)):
            return row
        self._wheels.partial += 1
        return tuple(v if math.isfinite(v) else math.nan for v in row)

    def _taker(self, name: str, handle: Callable[[list[bytes]], None]
               ) -> Callable[[bytes], None]:
        """The callback of the input subscription ``name``: the message handed in and every
        one waiting behind it (at most :data:`MAX_BATCH`), all to ``handle``; then what a
        second of data completes is pushed."""
        def take(first: bytes) -> None:
            if not self._active:
                return                      # (inactive: what came is dropped, as it came)
            sub = getattr(self, name)
            batch = [first]
            more, kind = sub.handle.take_message, sub.msg_type
            with sub.handle:
                while len(batch) < MAX_BATCH:
                    got = more(kind, True)
                    if got is None:
                        break
                    batch.append(got[0])
            handle(batch)
            self._maybe_flush()
            self._answers_due()

        return take

    def _wheel_batch(self, batch: list[bytes]) -> None:
        """The wheel messages of one callback in turn, each as :meth:`_wheel_message` takes
        it. A driver's every message (velocities, of the layout seen last, a stamp after the
        last one, finite values) is read, buffered and its odometry published here with the
        state in local variables (one Python call per message costs as much as its work);
        any other goes through :meth:`_wheel_message`."""
        pub, quick, wheels = self._odom_pub, self._reader.velocities, self._wheels
        handle, check = pub.handle, wheels.stamps.check
        columns = wheels.buffer.columns
        add_t, add_l, add_r = (columns["t"].append, columns["n_rl"].append,
                               columns["n_rr"].append)
        # the car's front wheels and steering, after the rear wheels in what is read
        further, further_of = [columns[k].append for k in wheels.buffer.keys[2:]], self._further
        readings, variances, message = (self.twist.readings.add, self.twist.variances,
                                        self._writer.message)
        # (2a), (2b): the model's body map at the batch's theta and a_y
        a_y = self._a_y
        (v_l, v_r), (w_l, w_r) = self._body_at(a_y)
        max_gap, origin = self._max_gap_s, self._origin
        isfinite, cos, sin = math.isfinite, math.cos, math.sin
        x, y, psi, last = self._x, self._y, self._psi, self._odom_t
        with handle:
            publish = handle.publish_raw if pub.is_activated else None
            mixed = self._mixed
            for data in batch:
                if origin is None or mixed or (got := quick(data)) is None:
                    self._x, self._y, self._psi, self._odom_t = x, y, psi, last
                    self._wheel_message(data)
                    x, y, psi, last = self._x, self._y, self._psi, self._odom_t
                    origin, mixed = self._origin, self._mixed
                    continue
                sec, nsec, left, right, *more = got     # (the car's front and steering after)
                t = float(sec - origin[0]) + 1e-9 * float(nsec - origin[1])
                if not check(t):
                    self._rates.reset()
                    continue
                n_rl, n_rr = left / TWO_PI, right / TWO_PI
                if not (isfinite(n_rl) and isfinite(n_rr)):
                    self._refuse_wheels()
                    continue
                for add, value in zip(further, further_of(more), strict=True):
                    add(value)
                add_t(t)
                add_l(n_rl)
                add_r(n_rr)
                v, w = v_l * n_rl + v_r * n_rr, w_l * n_rl + w_r * n_rr
                if last is not None and 0.0 < t - last <= max_gap:
                    dt = t - last                       # (1) as odocal.model.step.increment
                    h = psi + 0.5 * w * dt
                    x += v * (dt * cos(h))
                    y += v * (dt * sin(h))
                    psi += w * dt
                last = t
                readings(t, v, w)
                var_v, var_w = variances(v, n_rl, n_rr, a_y)
                if publish is not None:
                    half = 0.5 * psi
                    publish(message(sec, nsec, x, y, sin(half), cos(half), v, w, var_v, var_w))
        self._x, self._y, self._psi, self._odom_t = x, y, psi, last

    def _refuse_wheels(self) -> None:
        wheels = self._wheels
        wheels.stamps.refuse_invalid()
        wheels.note = "NaN or infinite wheel values"
        self._rates.reset()

    def _wheel_message(self, data: bytes) -> None:
        wheels = self._wheels
        try:
            sec, nsec, positions, velocities, steering = self._reader.read(data)
        except cdr.CdrError as exc:
            wheels.undecodable += 1
            wheels.note = str(exc)
            return
        except ConfigError as exc:
            # (refused and named: an ERROR until a message of a usable layout comes)
            wheels.undecodable += 1
            wheels.note = str(exc)
            if self._joints is None and self._config_error is None:
                self._config_error = str(exc)
                self.get_logger().error(self._config_error)
                self.publish_diagnostics()
            return
        t = self._time(sec, nsec)
        if not wheels.stamps.check(t):
            self._rates.reset()
            return
        if self._steered and steering is None:
            wheels.stamps.refuse_invalid()
            wheels.note = f"no position for the steering joint {self._param('steering_joint')}"
            return
        angles = () if steering is None else (steering,)
        if velocities is not None:
            t_rate, rates = t, (*(v / TWO_PI for v in velocities), *angles)
            if self._mixed and positions is not None:
                self._rates.add(t, *positions, angles=angles)   # (the next step starts here)
        elif positions is not None:
            since = self._rates.last_t
            got = self._rates.add(t, *positions, angles=angles)
            if since is not None and self._odom_t is not None and since < self._odom_t:
                # velocities came since the angles before: a driver that sends them in some
                # messages and not in others. From now on every message is read here and
                # its angles kept, so that an angles-only message gives the rate over the
                # step from the message before it (this one's step spans a velocity
                # message's instant: not taken)
                self._mixed = True
                return
            if got is None:
                return                               # the first of a piece: no rate yet
            t_rate, rates = got[0], got[1:]
        else:
            wheels.stamps.refuse_invalid()
            wheels.note = "neither velocities nor positions for the wheel joints"
            return
        n_rl, n_rr = rates[:2]
        if not (math.isfinite(n_rl) and math.isfinite(n_rr)):
            self._refuse_wheels()
            return
        row = self._front_row(rates[2:4], rates[4] if len(rates) > 4 else None) \
            if self._car else ()
        wheels.buffer.add(t_rate, (n_rl, n_rr, *row))
        self._publish_odometry(sec, nsec, t, n_rl, n_rr)

    def _imu_batch(self, batch: list[bytes]) -> None:
        """The IMU messages of one callback in turn, each as :meth:`_imu_message` takes it
        (those of the layout seen last read here, any other there)."""
        imu = self._imu
        assert imu is not None
        quick = self._imu_quick.read
        check = imu.stamps.check
        columns = imu.buffer.columns
        add_t, add_w, add_a = (columns["t"].append, columns["yaw_rate"].append,
                               columns["a_y"].append)
        gyro = self.gyro
        isfinite = math.isfinite
        r = self._rotation
        origin = self._origin
        for data in batch:
            if origin is None or (got := quick(data)) is None:
                self._imu_message(data)
                origin = self._origin
                continue
            sec, nsec, rx, ry, rz, ax, ay, az = got
            t = float(sec - origin[0]) + 1e-9 * float(nsec - origin[1])
            if not check(t):
                gyro.reading_gap()
                continue
            if r is None:
                yaw_rate, a_y = rz, ay
            else:
                yaw_rate, a_y = (r[2][0] * rx + r[2][1] * ry + r[2][2] * rz,
                                 r[1][0] * ax + r[1][1] * ay + r[1][2] * az)
            if not (isfinite(yaw_rate) and isfinite(a_y)):
                self._refuse_imu()
                continue
            self._a_y = a_y
            gyro.add_reading(yaw_rate)
            add_t(t)
            add_w(yaw_rate)
            add_a(a_y)

    def _refuse_imu(self) -> None:
        imu = self._imu
        assert imu is not None
        imu.stamps.refuse_invalid()
        imu.note = "NaN or infinite IMU values"
        self.gyro.reading_gap()

    def _imu_message(self, data: bytes) -> None:
        imu = self._imu
        assert imu is not None
        try:
            sec, nsec, rate, accel = cdr.imu(data)
        except cdr.CdrError as exc:
            imu.undecodable += 1
            imu.note = str(exc)
            return
        t = self._time(sec, nsec)
        if not imu.stamps.check(t):
            self.gyro.reading_gap()
            return
        yaw_rate, a_y = self._imu_values(rate, accel)
        if not (math.isfinite(yaw_rate) and math.isfinite(a_y)):
            self._refuse_imu()
            return
        self._a_y = a_y
        self.gyro.add_reading(yaw_rate)
        imu.buffer.add(t, (yaw_rate, a_y))

    def _imu_values(self, rate: Sequence[float], accel: Sequence[float]) -> tuple[float, float]:
        """The yaw rate and the lateral acceleration in the vehicle's axes."""
        r = self._rotation
        if r is None:
            return rate[2], accel[1]
        return (r[2][0] * rate[0] + r[2][1] * rate[1] + r[2][2] * rate[2],
                r[1][0] * accel[0] + r[1][1] * accel[1] + r[1][2] * accel[2])

    def _pose_batch(self, batch: list[bytes]) -> None:
        """The reference messages of one callback in turn, each as :meth:`_pose_message`
        takes it (those of the layout seen last read here, any other there)."""
        pose = self._pose
        quick = self._pose_quick.read
        check = pose.stamps.check
        columns = pose.buffer.columns
        add_t, add_x, add_y, add_psi = (columns["t"].append, columns["x"].append,
                                        columns["y"].append, columns["psi"].append)
        beta_wanted = self._beta_wanted
        isfinite, atan2 = math.isfinite, math.atan2
        origin = self._origin
        for data in batch:
            if origin is None or (got := quick(data)) is None:
                self._pose_message(data)
                origin = self._origin
                continue
            sec, nsec, x, y, qx, qy, qz, qw = got[:8]
            t = float(sec - origin[0]) + 1e-9 * float(nsec - origin[1])
            if not check(t):
                continue
            psi = atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))   # yaw_of
            beta = _sideslip(got[8:10]) if beta_wanted else 0.0
            if not (isfinite(x) and isfinite(y) and isfinite(psi) and isfinite(beta)):
                self._refuse_pose()
                continue
            add_t(t)
            add_x(x)
            add_y(y)
            add_psi(psi)
            if beta_wanted:
                self._beta.append((t, beta))

    def _refuse_pose(self) -> None:
        pose = self._pose
        pose.stamps.refuse_invalid()
        pose.note = "NaN or infinite pose values"

    def _pose_message(self, data: bytes) -> None:
        pose = self._pose
        try:
            m = self._pose_reader(data)
        except cdr.CdrError as exc:
            pose.undecodable += 1
            pose.note = str(exc)
            return
        t = self._time(m.sec, m.nanosec)
        if not pose.stamps.check(t):
            return
        psi = yaw_of(m.orientation)
        beta = _sideslip(m.velocity) if self._beta_wanted else 0.0
        if not (math.isfinite(m.x) and math.isfinite(m.y) and math.isfinite(psi)
                and math.isfinite(beta)):
            self._refuse_pose()
            return
        pose.buffer.add(t, (m.x, m.y, psi))
        if self._beta_wanted:
            self._beta.append((t, beta))

    @property
    def topics(self) -> list[_Input]:
        return [t for t in (self._wheels, self._imu, self._pose) if t is not None]

    def messages(self) -> dict[str, int]:
        """Messages used per input role (refused ones not counted)."""
        return {t.role: t.stamps.received - t.stamps.invalid for t in self.topics}

    def arrived(self) -> dict[str, int]:
        """Messages taken from each input role's topic, used or refused."""
        return {t.role: t.stamps.received + t.stamps.back + t.undecodable for t in self.topics}

    def silent(self) -> list[str]:
        """The input topics that stayed silent longer than ``silence_timeout_s`` (or were never
        heard while another one was), each named with how long (on the node's clock, as seen
        each time the status is made: every ``diagnostics_period_s`` and at each estimate)."""
        now, timeout = self._now_s(), float(self._param("silence_timeout_s"))
        for topic in self.topics:
            topic.check_heard(now)
        heard = [t.first_receipt_s for t in self.topics if t.first_receipt_s is not None]
        if not heard:
            return []
        first = min(heard)
        out = []
        for topic in self.topics:
            if topic.last_receipt_s is None:
                if now - first > timeout:
                    out.append(f"no message on {topic.name} ({topic.role}) yet")
            elif now - topic.last_receipt_s > timeout:
                out.append(f"no message on {topic.name} ({topic.role}) for "
                           f"{now - topic.last_receipt_s:.1f} s")
        return out

    def _lagging(self) -> bool:
        """Whether an input has sent nothing yet, or nothing for ``silence_timeout_s`` of the
        others' stamps (at the end of a drive they all stop together: none lags)."""
        latest = [t.stamps.last_t for t in self.topics]
        if any(t is None for t in latest):
            return True
        newest = max(t for t in latest if t is not None)
        timeout = float(self._param("silence_timeout_s"))
        return any(newest - t > timeout for t in latest if t is not None)

    # ------------------------------------------------------------------ calibrating

    def _maybe_flush(self) -> None:
        newest = self._wheels.buffer.newest()
        if newest is None:
            return
        if self._flushed_t is None:
            self._flushed_t = newest
        elif newest - self._flushed_t >= self.settings.online.chunk_s:
            self._flushed_t = newest
            self.flush()

    def flush(self, *, final: bool = False) -> None:
        """Put what has arrived onto the grid and push it into the calibrator in replay's
        blocks (``final``: the end of the drive, every row); take the estimate every
        ``[online] update_s`` of data; publish an alarm as soon as it is raised."""
        if self._lagging() and not final:
            # an input is missing (not heard yet, or silent): nothing is calibrated from the
            # others alone; what arrived within the silence timeout is kept for when it comes
            newest = max((b for t in self.topics if (b := t.buffer.newest()) is not None),
                         default=None)
            if newest is not None:
                for topic in self.topics:
                    topic.buffer.trim(newest - float(self._param("silence_timeout_s")))
            return
        streams = {t.role: s for t in self.topics if (s := t.buffer.take()) is not None}
        chunk = self._grid.add(streams, final=final) if streams or final else None
        if chunk is not None:
            if self._beta_wanted:
                chunk["beta"] = self._sideslip_at(chunk["t"])
            if "yaw_rate" in chunk:
                self.gyro.add(chunk["t"], chunk["yaw_rate"], chunk["psi"])
            self._pending.append(chunk)
        self._push_pending(final)

    def _sideslip_at(self, t: np.ndarray) -> np.ndarray:
        """The reference's sideslip at grid times ``t`` (kept from the pose messages)."""
        if not self._beta:
            return np.zeros(t.size)
        bt = np.array(self._beta)
        out = np.interp(t, bt[:, 0], bt[:, 1])
        keep = max(int(np.searchsorted(bt[:, 0], t[-1])) - 1, 0)
        self._beta = self._beta[keep:]
        return np.asarray(out, dtype=np.float64)

    def _push_pending(self, final: bool) -> None:
        """The grid's rows to the calibrator, ``rows_per_push`` at a time (the last, shorter
        block only at the end), as odocal replay pushes a drive file."""
        if not self._pending:
            return
        rows = {k: np.concatenate([c[k] for c in self._pending]) for k in self._pending[0]}
        n, step = rows["t"].size, self._rows_per_push
        cut = n if final else (n // step) * step
        blocks = [{k: v[lo:min(lo + step, cut)] for k, v in rows.items()}
                  for lo in range(0, cut, step)]
        self._pending = [{k: v[cut:] for k, v in rows.items()}] if cut < n else []
        if blocks and self._calibration is not None and not self.calibrator.halted:
            self._ask(lambda c: c.push(blocks))

    def _ask(self, request: Callable[[Beside | InThread], None]) -> None:
        """A request to the calibrator; its answers taken where they are ready."""
        calibration = self._calibration
        if calibration is None:
            return
        try:
            request(calibration)
        except CalibratorLost as exc:
            self._calibrator_lost(exc)
            return
        self._take_answers()

    def _answers_due(self) -> None:
        if not self.idle:
            self._take_answers()

    @property
    def idle(self) -> bool:
        """Whether the calibrator has answered every request sent and the answers are
        handled."""
        return self._calibration is None or self._calibration.idle

    def _take_answers(self, *, settle: bool = False) -> None:
        """What the calibrator answered (``settle``: waiting for every answer), in order."""
        calibration = self._calibration
        if calibration is None:
            return
        try:
            events = calibration.settle() if settle else calibration.answers()
        except CalibratorLost as exc:
            self._calibrator_lost(exc)
            return
        for event in events:
            self._handle(event)

    def _handle(self, event: Event) -> None:
        self.calibrator = event.view
        if isinstance(event, LeftOut):   # a block it cannot use: said, and left out
            self._push_error = event.message
            self.get_logger().warning(f"samples at {self.stamp_of(event.t0):.3f} s "
                                      f"left out: {event.message}")
        elif isinstance(event, Raised):
            self._publish_alarms()
        elif isinstance(event, Updated):
            self._updated(event.estimate)

    def _calibrator_lost(self, exc: CalibratorLost) -> None:
        self._lost = str(exc)
        self._close_calibration()               # (its pipe and request thread released)
        self.get_logger().error(self._lost)
        self.publish_diagnostics()

    def _close_calibration(self, *, settled: bool = False) -> None:
        """The calibrator ended: where every answer was taken (``settled``, the drive's end),
        as it reads the end of its requests; else (a reset, a cleanup) at once: what it was
        doing is forgotten."""
        calibration = getattr(self, "_calibration", None)
        if calibration is not None:
            calibration.close(wait=settled)
        self._calibration = None

    def update(self) -> Estimate | None:
        """Take the estimate now (waiting for it), and publish it where it may be (never a
        rejected one over the last publishable one)."""
        self._ask(lambda c: c.estimate())
        self._take_answers(settle=True)
        return self.estimate

    def _updated(self, est: Estimate) -> None:
        """An estimate taken: published where it may be."""
        self.estimate = est
        self.updates += 1
        if publishable(est):
            self._publish_estimate(est)
        elif est.status is Status.REJECTED:
            self._refused(est)
        if len(self.calibrator.alarms) > self._alarms_seen:
            self._publish_alarms()
        self.publish_diagnostics()

    def _publish_estimate(self, est: Estimate) -> None:
        first = self._good is None
        self._good, self._good_km = est, self.calibrator.distance_km
        rear = rear_axle_of(est)
        self._use_theta(rear.theta.as_array())
        self.twist.calibrate(rear)
        self._estimate_pub.publish(estimate_array(est))
        if self._controller is not None:
            self._controller.push(est)
        if first or est.identified != self._identified:
            names = est.theta.layout.names
            gained = [n for n, now, was in zip(names, est.identified, self._identified,
                                               strict=True) if now and not was]
            lost = [n for n, now, was in zip(names, est.identified, self._identified,
                                             strict=True) if was and not now]
            self.get_logger().info(
                f"at {self._good_km:.2f} km: "
                + (f"identified {', '.join(gained)}; " if gained else "")
                + (f"no longer identified: {', '.join(lost)}; " if lost else "")
                + parameters_text(est))
            self._identified = est.identified

    def _refused(self, est: Estimate) -> None:
        """A rejected estimate: where the calibrator halted (the data contradict the model)
        the odometry goes back to the datasheet; otherwise the last publishable one stays."""
        if self.calibrator.halted:
            if self._good is not None or self.updates == 1:
                self.get_logger().error(self._rejection(est))
            self._good = None
            self._use_theta(self._rear(self.datasheet.as_array()))
            self.twist.calibrate(None)
            return
        where = (f"keeping the calibration from {self._good_km:.2f} km"
                 if self._good is not None else "nothing is published yet")
        self.get_logger().warning(f"estimate at {self.calibrator.distance_km:.2f} km refused: "
                                  f"{self._rejection(est)}; {where}")

    def finish(self) -> Estimate | None:
        """The end of the drive (shutdown, or a test's end): push every row the grid can still
        make, take the final estimate, publish it, write the export files (``export_dir``) and
        say what was done. Once: later calls return the same estimate."""
        if self._finished and self.estimate is not None:
            return self.estimate
        self._finished = True
        self.flush(final=True)
        est = self.update()
        self._close_calibration(settled=True)
        log = self.get_logger()
        if est is None:
            log.warning(f"no calibration after {self.calibrator.distance_km:.2f} km: "
                        + (self._lost or "no estimate"))
        elif self._good is not None:
            note = ("" if est is self._good else
                    f" (the final estimate was refused: {self._rejection(est)}; this is the one "
                    f"from {self._good_km:.2f} km)")
            log.info(f"final calibration after {self.calibrator.distance_km:.2f} km: "
                     f"{parameters_text(self._good)}{note}")
        else:
            log.warning(f"no calibration after {self.calibrator.distance_km:.2f} km: "
                        + (self._rejection(est) if est.status is Status.REJECTED
                           else est.message))
        if self._param("export_dir"):
            try:
                written = self.write_exports(Path(self._param("export_dir")))
                log.info("wrote " + ", ".join(str(p) for p in written))
            except OdocalError as exc:
                log.warning(f"no export at shutdown: {exc}")
            except OSError as exc:
                log.error(f"no export at shutdown: cannot write {exc.filename}: "
                          f"{exc.strerror or exc}")
        return est

    def reset(self) -> None:
        """Start the calibration over from the datasheet values (the inputs' counts stay)."""
        kept = (self._wheels, self._imu, self._pose, self._origin, self._odom_t, self._x,
                self._y, self._psi, self._a_y)
        self._fresh()
        (self._wheels, self._imu, self._pose, self._origin, self._odom_t, self._x, self._y,
         self._psi, self._a_y) = kept
        for topic in self.topics:
            topic.buffer = Buffer(topic.name, topic.role, topic.buffer.keys)
        self._writer.covariances(_unknown_covariance(), _unknown_covariance())
        self.get_logger().info("reset: calibrating anew from the datasheet values")
        self.publish_diagnostics()

    def _on_reset(self, request: Any, response: Any) -> Any:
        self.reset()
        response.success, response.message = True, "calibrating anew from the datasheet values"
        return response

    # ------------------------------------------------------------------ outputs

    def _use_theta(self, theta: Any) -> None:
        """Publish odometry with the rear axle's ``theta`` from now on: the model's body map
        as plain floats (a message's speed and yaw rate are four products, :meth:`_body_at`)."""
        self._theta = np.array(theta, dtype=float)
        m0, m1 = MODEL.body_map(self._theta)
        self._body = (tuple(tuple(float(v) for v in row) for row in m0),
                      tuple(tuple(float(v) for v in row) for row in m1))

    def _body_at(self, a_y: float) -> tuple[tuple[float, float], tuple[float, float]]:
        """The wheel rates' (rev/s) weights in the speed and the yaw rate at ``a_y``."""
        (a, b), (c, e) = self._body[0]
        (f, g), (h, k) = self._body[1]
        return (a + a_y * f, b + a_y * g), (c + a_y * h, e + a_y * k)

    def _publish_odometry(self, sec: int, nsec: int, t: float, n_rl: float, n_rr: float) -> None:
        """(2a), (2b) with the published calibration, the pose by (1), and the twist's
        variances (:mod:`odocal.ros2.twist`); as :meth:`_wheel_batch` computes them, in plain
        float arithmetic (the model's body map)."""
        a_y = self._a_y
        (v_l, v_r), (w_l, w_r) = self._body_at(a_y)
        v, w = v_l * n_rl + v_r * n_rr, w_l * n_rl + w_r * n_rr
        last = self._odom_t
        if last is not None and 0.0 < t - last <= self._max_gap_s:
            dt = t - last
            h = self._psi + 0.5 * w * dt
            self._x += v * (dt * math.cos(h))
            self._y += v * (dt * math.sin(h))
            self._psi += w * dt
        self._odom_t = t
        twist = self.twist
        twist.readings.add(t, v, w)
        var_v, var_w = twist.variances(v, n_rl, n_rr, a_y)
        half = 0.5 * self._psi
        self._odom_pub.publish(self._writer.message(
            sec, nsec, self._x, self._y, math.sin(half), math.cos(half), v, w, var_v, var_w))

    def _publish_alarms(self) -> None:
        for alarm in self.calibrator.alarms[self._alarms_seen:]:
            data = alarm.to_dict()
            data["t"], data["detected_t"] = self.stamp_of(alarm.t), self.stamp_of(alarm.detected_t)
            self._alarm_pub.publish(String(data=json.dumps(data)))
            self.get_logger().warning(f"change: {alarm.parameter} moved "
                                      f"{alarm.relative_change * 100:+.3f}% at "
                                      f"{alarm.distance_km:.2f} km (detected at "
                                      f"{alarm.detected_distance_km:.2f} km)")
        self._alarms_seen = len(self.calibrator.alarms)
        self.publish_diagnostics()

    def status(self) -> list[Any]:
        """The node's statuses for ``/diagnostics``: the calibration, and its change alarms."""
        main = DiagnosticStatus(name=self._status_name, hardware_id=self._wheels.name)
        level, message = self._level()
        main.level, main.message = level, message
        values = self._values(level)
        main.values = [KeyValue(key=k, value=v) for k, v in values]
        statuses = [main]
        calibrator = self.calibrator
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

    def _level(self) -> tuple[bytes, str]:
        """The calibration status's level and message: the gravest first."""
        est, good = self.estimate, self._good
        rejected = est is not None and est.status is Status.REJECTED
        if self._config_error is not None:
            return DiagnosticStatus.ERROR, self._config_error
        if self._lost:
            return DiagnosticStatus.ERROR, self._lost
        if self.calibrator.halted or (rejected and good is None):
            return DiagnosticStatus.ERROR, self._rejection(est)
        warnings = [*self.silent(), *(p for t in self.topics for p in t.problems())]
        if self._push_error:
            warnings.append(f"samples left out: {self._push_error}")
        behind = self._calibration.backlog if self._calibration is not None else 0
        if behind > BEHIND:
            warnings.append(f"the calibrator is behind: {behind} blocks of "
                            f"{self.settings.online.chunk_s:g} s of data not answered yet "
                            "(its estimates come late)")
        if rejected:
            warnings.append(f"the latest estimate was refused ({self._rejection(est)}): "
                            f"publishing the calibration from {self._good_km:.2f} km")
        if good is None:
            calibrator = self.calibrator
            warnings.append("not yet identified: " + ", ".join(self._layout.names)
                            + f" ({calibrator.distance_km:.2f} km driven; "
                            + ("no estimate yet)" if est is None else f"{est.message})"))
        else:
            missing = [(n, v) for n, v in zip(good.theta.layout.names, good.verdicts, strict=True)
                       if isinstance(v, NotIdentified)]
            if missing:
                threshold = self.settings.segments.yaw_rate_threshold_radps
                warnings.append("not yet identified: " + "; ".join(
                    f"{n} ({reason_text(n, v, threshold_radps=threshold)})" for n, v in missing))
        if warnings:
            return DiagnosticStatus.WARN, "; ".join(warnings)
        assert good is not None
        return DiagnosticStatus.OK, "identified and within the gate: " + parameters_text(good)

    def _values(self, level: bytes) -> list[tuple[str, str]]:
        calibrator = self.calibrator
        values = [("distance_km", f"{calibrator.distance_km:.4f}"),
                  ("samples", str(calibrator.samples)), ("updates", str(self.updates))]
        for t in self.topics:
            s = t.stamps
            values += [(f"messages {t.name}", str(s.received - s.invalid)),
                       (f"missing {t.name}", str(s.missing)),
                       (f"refused {t.name}", str(s.back + s.invalid + t.undecodable))]
        good = self._good
        if good is not None and level != DiagnosticStatus.ERROR:
            for n, v, s_, ok in zip(good.theta.layout.names, good.theta.as_array(), good.std,
                                    good.identified, strict=True):
                values += [(n, repr(float(v))), (f"{n}_std", repr(float(s_))),
                           (f"{n}_identified", "true" if ok else "false")]
            values += [("status", good.status.name), ("published_from_km", f"{self._good_km:.4f}")]
            if self.estimate is not None and self.estimate is not good:
                values.append(("latest_status", self.estimate.status.name))
        if self._controller is not None and self._controller.note:
            values.append(("controller", self._controller.note))
        return values

    def _rejection(self, est: Estimate | None) -> str:
        findings = (est.details.findings if est is not None and est.details is not None
                    else self.calibrator.findings)
        fatal = [f for f in findings if int(f.severity) == 2]
        if fatal:
            return "the data contradict the model: " + finding_text(fatal[0], self.settings)
        return "calibration rejected: " + (est.message if est is not None else "by the checks")

    def publish_diagnostics(self) -> None:
        if not self._configured:
            return
        msg = DiagnosticArray()
        msg.header.stamp = self.get_clock().now().to_msg()
        msg.status = self.status()
        self._diag_pub.publish(msg)

    # ------------------------------------------------------------------ exports

    def calibrated(self) -> Calibrated:
        """The published calibration as the exports take it (a ConfigError if none)."""
        est = self._good
        if est is None or self.calibrator.halted:
            why = (self._rejection(self.estimate) if self.calibrator.halted
                   or (self.estimate is not None and self.estimate.status is Status.REJECTED)
                   else "nothing is identified yet")
            raise ConfigError(f"no calibration to export: {why}")
        topics = ", ".join(t.name for t in self.topics)
        return Calibrated(theta=est.theta, datasheet=est.datasheet,
                          std=tuple(float(s) for s in est.std),
                          identified=est.identified, method="online (odocal ros2)",
                          noise=self._message_noise(), source=f"ROS 2 topics {topics}",
                          wheel_joints=self._joints,
                          covariance=tuple(tuple(float(v) for v in row)
                                           for row in est.covariance))

    def _message_noise(self) -> OdometryNoise | None:
        """The standard deviations one odometry message states at the drive's mean speed (what
        the exports' twist covariance and velocity standard deviations take)."""
        period = self._wheels.stamps.period_s
        span = self.calibrator.span_s
        if period is None or span is None or span[1] <= span[0]:
            return None
        speed = self.calibrator.distance_km * 1000.0 / (span[1] - span[0])
        n_rl, n_rr = (float(n) for n in MODEL.wheel_rates(self._theta, speed, 0.0, 0.0))
        var_v, var_w = self.twist.variances(speed, n_rl, n_rr, 0.0)
        if var_v >= UNKNOWN_VARIANCE:
            return None
        return OdometryNoise(speed_std_mps=math.sqrt(var_v), yaw_rate_std_radps=math.sqrt(var_w),
                             windows=self.twist.readings.count, window_s=period)

    def write_exports(self, folder: Path) -> list[Path]:
        """The export files of the published calibration into ``folder``."""
        calibrated = self.calibrated()
        targets = params.targets(self._param("export_targets"))
        folder.mkdir(parents=True, exist_ok=True)
        written = export(calibrated, folder,
                         [t for t in targets if t in targets_for(self._layout)])
        if "robot_localization" in targets:
            point_ekf_at(folder / "robot_localization" / "ekf_odometry.yaml",
                         self._odom_pub.topic_name)
        found = self.gyro.result()
        if "autoware" in targets and found is not None and self._imu is not None:
            written.append(imu_corrector(folder / "autoware" / "imu_corrector.param.yaml",
                                         found, self._imu.name,
                                         aligned=self._rotation is None))
        if "yaml" in targets:
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
        if not written:
            response.success = False
            response.message = (f"nothing to write: export_targets names none of the "
                                f"{self.settings.vehicle.model} model's targets ("
                                + ", ".join((*targets_for(self._layout), "yaml")) + ")")
            return response
        response.success = True
        response.message = "wrote " + ", ".join(str(p) for p in written)
        return response

def _sideslip(velocity: tuple[float, float] | None) -> float:
    """The sideslip of a velocity (x, y) in the vehicle's frame: atan(vy / vx), 0 at rest
    (forwards and backwards alike: the direction of travel against the heading's axis)."""
    if velocity is None or velocity[0] == 0.0:
        return 0.0
    return math.atan(velocity[1] / velocity[0])


def _unknown_covariance() -> list[float]:
    """A 6x6 covariance with the unknown variance on its diagonal (what wheels do not see)."""
    cov = [0.0] * 36
    for i in range(0, 36, 7):
        cov[i] = UNKNOWN_VARIANCE
    return cov


def parameters_text(est: Estimate) -> str:
    """The parameters of an estimate in one line: ``c_e 1.95214 +- 0.00031 m, ...``."""
    return ", ".join(f"{n} {v:.6g}" + (f" +- {s:.2g}" if ok else " (datasheet)")
                     for n, v, s, ok in zip(est.theta.layout.names, est.theta.as_array(),
                                            est.std, est.identified, strict=True))


def estimate_columns(names: Sequence[str]) -> tuple[str, ...]:
    """The ``~/estimate`` array's columns (after the rows' parameter) for a model's
    parameters ``names``."""
    return ("value", "std", "identified", *(f"cov_{n}" for n in names))


def estimate_array(est: Estimate) -> Any:
    """``est`` as a ``std_msgs/Float64MultiArray``: a row per parameter (c_e, c_d, t_r, d for
    the rear axle); columns value, std, identified (1.0 or 0.0) and the covariance's row (SI
    units), labels in the layout."""
    names = est.theta.layout.names
    columns = estimate_columns(names)
    cov = np.where(np.isfinite(est.covariance), est.covariance, 0.0)
    data = np.column_stack([est.theta.as_array(), est.std,
                            np.asarray(est.identified, dtype=float), cov])
    msg = Float64MultiArray(data=[float(v) for v in data.ravel()])
    msg.layout.dim = [MultiArrayDimension(label="parameter: " + " ".join(names),
                                          size=len(names), stride=len(names) * len(columns)),
                      MultiArrayDimension(label="column: " + " ".join(columns),
                                          size=len(columns), stride=len(columns))]
    return msg


def run(ros_args: Sequence[str], *, settings: Settings | None = None,
        on_ready: Callable[[CalibrationNode], None] | None = None) -> int:
    """Start the node with ``ros_args`` (``--ros-args ...``) and spin until Ctrl-C or SIGTERM;
    then the final estimate is published and the export files written. Returns 0."""
    from rclpy.executors import ExternalShutdownException
    from rclpy.experimental import EventsExecutor
    from rclpy.signals import SignalHandlerOptions

    try:
        rclpy.init(args=["odocal", *ros_args], signal_handler_options=SignalHandlerOptions.NO)
    except Exception as exc:   # rcl refuses the arguments (a bad -p, a missing params file)
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise ConfigError(f"ROS 2 arguments {' '.join(ros_args)!r}: {first}") from exc
    node: CalibrationNode | None = None
    stop: list[int] = []
    previous = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}

    def on_signal(signum: int, frame: Any) -> None:
        stop.append(signum)            # no exception: the loop below ends between messages

    executor: Any = None
    try:
        for sig in previous:
            signal.signal(sig, on_signal)
        node = CalibrationNode(settings=settings)
        # the events executor's own signal set replaces Python's handlers: ours go back after
        # it (a signal it took would shut the context down under the final estimate)
        executor = EventsExecutor()
        for sig in previous:
            signal.signal(sig, on_signal)
        executor.add_node(node)
        if on_ready is not None:
            on_ready(node)
        try:
            # (one event per spin_once: whether ROS 2 still runs is asked every tenth of a
            # second, not at each message)
            checked = 0.0
            while not stop:
                executor.spin_once(timeout_sec=0.1)
                now = time.monotonic()
                if now - checked >= 0.1:
                    if not rclpy.ok() or node.finalized:
                        break
                    checked = now
        except ExternalShutdownException:
            pass
        if not node.finalized and rclpy.ok():
            node.finish()
        return 0
    finally:
        if executor is not None:
            executor.shutdown()
            executor = None                     # (its signal set restores no handler of ours)
        if node is not None:
            node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
