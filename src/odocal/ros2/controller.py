"""The identified multipliers set on a running ``diff_drive_controller`` (``controller_name``).

Through the controller's own parameter services: its nominal ``wheel_radius`` and
``wheel_separation`` are asked first, then ``left/right_wheel_radius_multiplier`` (where c_e is
identified) and ``wheel_separation_multiplier`` (where t_r is) are set relative to them.
diff_drive_controller (Humble to Kilted) takes them but applies them at its next configure;
Rolling declares them read-only and refuses them. What happened is in :attr:`ControllerPush.note`
(the node's ``/diagnostics`` shows it). Imported by :mod:`odocal.ros2.node` only (rclpy).
"""

from __future__ import annotations

from typing import Any

from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rcl_interfaces.srv import GetParameters, SetParameters

from odocal.estimators.estimate import Estimate
from odocal.model.parameters import PARAMETER_NAMES
from odocal.model.vehicle import MODEL


class ControllerPush:
    """The multipliers of each published estimate, pushed to the controller ``name`` (a
    node's fully qualified name, e.g. ``/diff_drive_controller``) from ``node``."""

    def __init__(self, node: Any, name: str) -> None:
        self.name = name
        self._log = node.get_logger()
        self.get = node.create_client(GetParameters, f"{name}/get_parameters")
        self.set = node.create_client(SetParameters, f"{name}/set_parameters")
        self.note = ""

    @property
    def clients(self) -> tuple[Any, Any]:
        return self.get, self.set

    def push(self, est: Estimate) -> None:
        """Ask the controller's nominal values, then set the multipliers of ``est``."""
        if not self.get.service_is_ready():
            self.note = f"no parameter service {self.name}/get_parameters"
            return
        request = GetParameters.Request(names=["wheel_radius", "wheel_separation"])
        future = self.get.call_async(request)
        future.add_done_callback(lambda f: self._set_multipliers(f, est))

    def _set_multipliers(self, future: Any, est: Estimate) -> None:
        try:
            radius, separation = (v.double_value for v in future.result().values)
        except Exception as exc:  # the service's own failure, as it said it
            self._log.debug(f"reading the controller's parameters: {exc!r}")
            self.note = f"cannot read the controller's nominal values: {exc}"
            return
        if not (radius > 0 and separation > 0):
            self.note = "the controller reports no wheel_radius / wheel_separation"
            return
        wanted = multipliers(est, radius, separation)
        if not wanted:
            return
        msgs = [ParameterMsg(name=k, value=ParameterValue(type=ParameterType.PARAMETER_DOUBLE,
                                                          double_value=float(v)))
                for k, v in wanted.items()]
        done = self.set.call_async(SetParameters.Request(parameters=msgs))
        done.add_done_callback(lambda f: self._answered(f, wanted))

    def _answered(self, future: Any, wanted: dict[str, float]) -> None:
        try:
            results = future.result().results
        except Exception as exc:  # the service's own failure, as it said it
            self._log.debug(f"setting the controller's multipliers: {exc!r}")
            self.note = f"setting the multipliers failed: {exc}"
            return
        refused = [f"{k}: {r.reason}" for k, r in zip(wanted, results, strict=False)
                   if not r.successful]
        self.note = ("refused: " + "; ".join(refused) if refused else
                     "set " + ", ".join(f"{k}={v:.6g}" for k, v in wanted.items())
                     + " (diff_drive_controller applies them at its next configure)")


def multipliers(est: Estimate, radius_m: float, separation_m: float) -> dict[str, float]:
    """diff_drive_controller's multipliers for ``est`` against its nominal wheel radius and
    separation: each wheel's circumference over the nominal one (where c_e is identified), t_r
    over the nominal separation (where t_r is)."""
    geometry = MODEL.geometry(est.theta.as_array())
    nominal = {"wheel_radius": radius_m, "wheel_separation": separation_m}
    ok = dict(zip(PARAMETER_NAMES, est.identified, strict=True))
    wanted: dict[str, float] = {}
    if ok[MODEL.layout.scale]:
        for side in ("left", "right"):
            wanted[f"{side}_wheel_radius_multiplier"] = float(
                geometry[f"{side}_wheel_radius"] / nominal["wheel_radius"])
    if ok[MODEL.layout.track]:
        wanted["wheel_separation_multiplier"] = float(
            geometry["wheel_separation"] / nominal["wheel_separation"])
    return wanted
