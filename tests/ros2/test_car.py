"""``odocal ros2`` with the four-wheel car (``[vehicle] model = "four_wheel"`` in the
settings file): four wheel joints and the steering wheel's joint in one JointState, through real
rclpy and Fast DDS (:mod:`tests.ros2.rig`), against ``odocal replay`` of the same drive file,
against the truth, and with mappings it must refuse."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import odocal
from odocal.cli.main import main
from odocal.estimators.estimate import Status
from odocal.model.layout import FOUR_WHEEL
from odocal.model.step import body
from odocal.sim.four_wheel import with_front_axle
from tests.estimators.test_front_axle import ACKERMANN_HUMBLE
from tests.ros2.rig import (
    START_S,
    Script,
    messages,
    play,
    spin_until,
    unique,
    values_of,
    wheel_angles,
)
from tests.ros2.rosenv import load_declared, require_rclpy

require_rclpy()

from diagnostic_msgs.msg import DiagnosticStatus  # noqa: E402

from odocal.ros2.node import CalibrationNode, estimate_columns  # noqa: E402

CAR = '[vehicle]\nmodel = "four_wheel"\n'


@pytest.fixture(scope="module")
def car() -> tuple[odocal.SimulatedDrive, odocal.Drive, np.ndarray]:
    sim, truth = with_front_axle(odocal.simulate(duration_s=300.0, seed=5, noise="realistic"))
    # (the sideslip goes with the drive, as the reference Odometry's twist: without it the
    # steered wheels' kinematics miss it and the wheelbase and the ratio move by stds)
    return sim, sim.drive, truth.as_array()


def car_rig(rig: Any, config: Path, **params: Any) -> Any:
    """The node under test with the car's settings and the reference's sideslip."""
    return rig(settings_file=str(config), sideslip_from_reference=True, **params)


def car_script(**kwargs: Any) -> Script:
    return Script(car=True, sideslip=True, **kwargs)


@pytest.fixture()
def config(tmp_path: Path) -> Path:
    path = tmp_path / "car.toml"
    path.write_text(CAR)
    return path


def _replay(d: odocal.Drive, folder: Path, config: Path) -> dict[str, Any]:
    path = folder / "car.parquet"
    odocal.save_drive(d, path)
    assert main(["replay", str(path), "--config", str(config), "--out", str(folder / "replay"),
                 "--no-batch", "--no-report", "-q"]) == 0
    data: dict[str, Any] = json.loads((folder / "replay" / "calibration.json").read_text())
    return data


def test_the_car_on_ros2_is_replays_car_and_publishes_its_ten_parameters(
        rig: Any, ros: Any, car: Any, config: Path, tmp_path: Path) -> None:
    """The node's final estimate of the car is replay's on the drive file (the same blocks
    pushed into the same calibrator); ~/estimate carries ten rows; the odometry runs on the
    car's rear axle, its stated variance the messages' error against the truth; the
    ackermann_steering_controller file loads in ROS 2 with the car's geometry."""
    sim, d, truth = car
    r = car_rig(rig, config, steering_joint="steering_wheel")
    play(r.executor, r.player, r.node, d, car_script())
    est = r.node.finish()
    calibration = _replay(d, tmp_path, config)
    names = FOUR_WHEEL.names
    assert est.model == calibration["model"] == "four_wheel" and est.names == names
    theta = np.array([calibration["theta"][n] for n in names])
    std = np.array([calibration["std"][n] for n in names])
    diff = (est.theta.as_array() - theta) / std
    print("the node against replay, in replay's stds:", diff.round(4))
    # the rear axle as the rear-axle node's test holds it; the front within the tenth of a std
    # by which the live front's windows follow the rear fit's alignment (online.front's NEAR_*:
    # stamps read to the nanosecond move the rear fit by 1e-7 of itself, and where a window is
    # remade against where it is kept can follow)
    assert np.all(np.abs(diff[:4]) <= 0.02) and np.all(np.abs(diff) <= 0.1), diff
    np.testing.assert_allclose(est.std, std, rtol=0.05)
    assert est.identified["c_f"] and est.identified["ratio"], est.identified
    z = (est.theta.as_array() - truth) / est.std
    assert np.all(np.abs(z[np.array(est.identified)]) < 3.0), dict(zip(names, z.round(2),
                                                                        strict=True))

    # (the final estimate's message, once it has come)
    spin_until(r.executor, lambda: bool(r.player.estimates) and np.array_equal(
        np.array(r.player.estimates[-1].data)[::13], est.theta.as_array()), "the estimate")
    msg = r.player.estimates[-1]
    rows, columns = msg.layout.dim
    assert rows.label == "parameter: " + " ".join(names) and rows.size == 10
    assert columns.label == "column: " + " ".join(estimate_columns(names))
    table = np.array(msg.data).reshape(10, 13)
    assert np.array_equal(table[:, 0], est.theta.as_array())
    assert np.array_equal(table[:, 1], est.std)

    # the odometry: the rear wheels with the car's rear axle, its variance the error's
    true_v, _, _, _ = body(sim.true_parameters.as_array(), sim.true_n_rl, sim.true_n_rr,
                                d.a_y)
    err_v, var_v = [], []
    for m in r.player.odometry:
        k = round((m.header.stamp.sec + 1e-9 * m.header.stamp.nanosec - START_S) / d.t_s)
        if d.t[k] >= 100.0:
            err_v.append(m.twist.twist.linear.x - true_v[k])
            var_v.append(m.twist.covariance[0])
    ratio = np.mean(var_v) / np.mean(np.square(err_v))
    print(f"stated speed variance over the truth's mean squared error: {ratio:.3f}")
    assert 0.7 < ratio < 1.4

    values = load_declared(r.folder / "ackermann" / "ackermann_steering_controller.yaml",
                           "ackermann_steering_controller", ACKERMANN_HUMBLE, context=ros)
    th = est.theta
    assert values["wheelbase"] == pytest.approx(th.L, rel=1e-12)
    assert values["front_wheel_track"] == pytest.approx(th.t_f, rel=1e-12)
    assert values["rear_wheel_track"] == pytest.approx(th.t_r, rel=1e-12)
    assert values["front_wheels_radius"] * 2 * np.pi == pytest.approx(th.c_f)


def test_joint_positions_of_the_car_calibrate_it_as_velocities_do(
        rig: Any, car: Any, config: Path) -> None:
    """A driver that sends the four joints' positions only (and the steering's, in degrees):
    rates from their steps, the steering at each step's middle; the estimate is the velocities'
    within a tenth of its std (the rear axle), a fifth (the front)."""
    _, d, _ = car
    short = d
    by_rates = car_rig(rig, config, steering_joint="steering_wheel")
    play(by_rates.executor, by_rates.player, by_rates.node, short, car_script())
    want = by_rates.node.finish()
    angles = wheel_angles(short, ("n_fl", "n_fr", "n_rl", "n_rr"))
    r = car_rig(rig, config, steering_joint="steering_wheel", steering_unit="deg")
    play(r.executor, r.player, r.node, short,
         car_script(positions_only=True, steering_deg=True, extra={"angles": angles}))
    got = r.node.finish()
    assert got.model == "four_wheel" and got.identified == want.identified
    diff = (got.theta.as_array() - want.theta.as_array()) / want.std
    print("positions against velocities, in stds:", diff.round(4))
    # (the rear axle as the rear-axle node's test holds it; the wheelbase and the ratio, which
    # the drive tells apart only by their correlation, follow the steps' averaging a little
    # further)
    assert np.all(np.abs(diff[:4]) < 0.1) and np.all(np.abs(diff) < 0.2), \
        dict(zip(got.names, diff.round(3), strict=True))


def test_a_car_without_its_steering_joint_calibrates_all_but_the_steering(
        rig: Any, car: Any, config: Path) -> None:
    _, d, _ = car
    r = car_rig(rig, config)
    play(r.executor, r.player, r.node, d, car_script(steering=False))
    est = r.node.finish()
    assert est.identified["c_f"] and est.identified["t_f"]
    assert not est.identified["ratio"] and not est.identified["s_0"]


def test_a_car_with_front_and_rear_exchanged_is_named_never_published(
        rig: Any, car: Any, config: Path) -> None:
    """Front and rear exchanged by their names: the fit names the front wheels mapped as rear
    and the calibrator halts; an ERROR on /diagnostics that says so, nothing to export, the
    odometry back on the datasheet."""
    _, d, _ = car
    r = car_rig(rig, config, steering_joint="steering_wheel")
    play(r.executor, r.player, r.node, d, car_script(joints=(
        "rear_left_wheel", "rear_right_wheel", "front_left_wheel", "front_right_wheel",
        "steering_wheel")))
    est = r.node.finish()
    assert est is not None and est.status is Status.REJECTED
    status = r.node.status()[0]
    assert status.level == DiagnosticStatus.ERROR, status.message
    assert "the data contradict the model" in status.message and "front" in status.message
    with pytest.raises(odocal.ConfigError, match="no calibration to export"):
        r.node.calibrated()
    assert not (r.folder / "ackermann").exists()


def test_joints_that_name_no_front_wheels_are_an_error_naming_the_parameters(
        rig: Any, car: Any, config: Path) -> None:
    _, d, _ = car
    r = car_rig(rig, config)
    joints = ("wheel_a", "wheel_b", "rear_left_wheel", "rear_right_wheel", "steering_wheel")
    r.player.wheels.publish(messages(d, 0, car_script(joints=joints))["wheels"])
    spin_until(r.executor, lambda: r.node.status()[0].level == DiagnosticStatus.ERROR,
               "the error on /diagnostics")
    said = r.node.status()[0].message
    assert "the four_wheel model needs the front wheels" in said
    assert "set front_left_wheel_joint and front_right_wheel_joint" in said
    assert len(said.splitlines()) == 1


@pytest.mark.parametrize(("given", "said"), [
    ({"steering_joint": "steering_wheel"},
     "parameter steering_joint: the rear_axle model reads no front wheels or steering"),
    ({"front_left_wheel_joint": "fl"}, "parameter front_left_wheel_joint: the rear_axle"),
    ({"steering_unit": "grad"}, "parameter steering_unit: 'grad': unknown"),
])
def test_the_cars_parameters_on_a_rear_axle_are_refused_in_one_line(
        ros: Any, given: dict[str, Any], said: str) -> None:
    from rclpy.parameter import Parameter

    with pytest.raises(odocal.ConfigError, match=said) as caught:
        CalibrationNode(context=ros, node_name=unique("rear"), enable_rosout=False,
                        parameter_overrides=[Parameter(k, value=v) for k, v in given.items()])
    assert len(str(caught.value).splitlines()) == 1


def test_a_controller_to_push_to_is_refused_for_the_car(ros: Any, config: Path) -> None:
    from rclpy.parameter import Parameter

    with pytest.raises(odocal.ConfigError, match="parameter controller_name: a "
                                                 "diff_drive_controller's multipliers") as caught:
        CalibrationNode(context=ros, node_name=unique("car"), enable_rosout=False,
                        parameter_overrides=[Parameter("settings_file", value=str(config)),
                                             Parameter("controller_name",
                                                       value="/diff_drive_controller")])
    assert len(str(caught.value).splitlines()) == 1


def test_a_steering_joint_that_is_a_wheel_is_an_error_never_a_crash(
        rig: Any, car: Any, config: Path) -> None:
    _, d, _ = car
    r = car_rig(rig, config, steering_joint="front_left_wheel")
    for k in range(3):
        r.player.wheels.publish(messages(d, k, car_script())["wheels"])
    spin_until(r.executor, lambda: r.node.status()[0].level == DiagnosticStatus.ERROR,
               "the error on /diagnostics")
    said = r.node.status()[0].message
    assert "the steering joint 'front_left_wheel' is a wheel's; set steering_joint" in said
    spin_until(r.executor, lambda: r.node.arrived()["wheels"] == 3, "the messages counted")


def test_a_steering_joint_gone_from_the_messages_is_counted_and_named(
        rig: Any, car: Any, config: Path) -> None:
    """Messages of a layout without the named steering joint, after messages that had it: each
    one refused, counted and named (not silence); one such message first, then the drive: the
    error clears once a usable layout comes."""
    _, d, _ = car
    short = odocal.Drive.from_columns({k: v[:2401] for k, v in d.columns().items()},
                                      name=d.name)
    r = car_rig(rig, config, steering_joint="steering_wheel")
    wheels_only = ("front_left_wheel", "front_right_wheel", "rear_left_wheel",
                   "rear_right_wheel", "spare")
    gone = lambda role, k: role == "wheels" and k >= 1200  # noqa: E731
    play(r.executor, r.player, r.node, short, car_script(skip=gone))
    for k in range(1200, 1210):
        r.player.wheels.publish(messages(short, k, car_script(joints=wheels_only))["wheels"])
    spin_until(r.executor, lambda: r.node.arrived()["wheels"] == 1210, "the messages counted")
    status = r.node.status()[0]
    assert status.level == DiagnosticStatus.WARN
    assert "no joint named 'steering_wheel' (steering_joint)" in status.message
    assert values_of(status)[f"refused {r.node.topics[0].name}"] == "10"
    assert "no message on" not in status.message

    first = car_rig(rig, config, steering_joint="steering_wheel")
    first.player.wheels.publish(messages(short, 0, car_script(joints=wheels_only))["wheels"])
    spin_until(first.executor,
               lambda: first.node.status()[0].level == DiagnosticStatus.ERROR, "the error")
    play(first.executor, first.player, first.node, short, car_script())
    assert first.node.finish() is not None
    assert first.node.status()[0].level != DiagnosticStatus.ERROR


def test_what_a_rear_axle_node_cannot_export_or_read_is_said(rig: Any, ros: Any) -> None:
    from rclpy.parameter import Parameter
    from std_srvs.srv import Trigger

    from tests.ros2.rig import call

    with pytest.raises(odocal.ConfigError, match="parameter steering_unit: the rear_axle"):
        CalibrationNode(context=ros, node_name=unique("rear"), enable_rosout=False,
                        parameter_overrides=[Parameter("steering_unit", value="deg")])
    sim = odocal.simulate(duration_s=90.0, seed=5, noise="realistic")
    r = rig(export_targets=["ackermann"])
    play(r.executor, r.player, r.node, sim.drive)
    r.node.update()
    answer = call(r.executor, r.player.export, Trigger.Request(), "~/export")
    assert not answer.success
    assert answer.message.startswith("nothing to write: export_targets names none of the "
                                     "rear_axle model's targets (autoware")


def test_a_nan_steering_or_front_wheel_leaves_that_value_out_not_the_rear_wheels(
        rig: Any, car: Any, config: Path) -> None:
    """400 messages with a NaN steering angle and 100 with a NaN front wheel: each message's
    rear wheels are taken and their odometry published; those values are left out (counted
    and named), and the car is calibrated (before, the whole message was refused: 10 s of it
    cost the wheelbase)."""
    _, d, truth = car

    def spoiled(role: str, k: int, msg: Any) -> None:
        if role == "wheels" and 2000 <= k < 2400:
            msg.position[4] = float("nan")
        if role == "wheels" and 3000 <= k < 3100:
            msg.velocity[0] = float("nan")

    r = car_rig(rig, config, steering_joint="steering_wheel")
    play(r.executor, r.player, r.node, d, car_script(values=spoiled))
    est = r.node.finish()
    assert r.node.messages()["wheels"] == d.n_samples
    spin_until(r.executor, lambda: len(r.player.odometry) == d.n_samples, "the odometry")
    assert "500 messages with a NaN or infinite front wheel or steering value: those values " \
           "left out, the rear wheels kept" in r.node.status()[0].message
    assert all(est.identified)
    z = (est.theta.as_array() - truth) / est.std
    assert np.all(np.abs(z) < 3.0), dict(zip(est.names, z.round(2), strict=True))
