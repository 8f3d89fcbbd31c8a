"""The live node as a ROS 2 user runs it (issue 41): each numbered defect of the issue, with a
real calibration node and a real player node (:mod:`tests.ros2.rig`).

1. a rejected live estimate (a tyre change) never replaces the last good one in anything
   published, and every trace marks it;
2. messages lost on the way are counted by the stamps' continuity and named;
3. Ctrl-C or SIGTERM mid-drive: exit 0, the final estimate and the exports, no traceback;
4. parameters declared with their types and ranges, checked at start, refused at run time
   where they cannot change;
5. the twist covariance is that of each message (against the truth's spread);
6. JointState with positions only; NaN values, stamps going back: counted, never a stop;
7. the node says what it does (start, identification changes, the end);
8. wall-clock stamps and the reference's sideslip: replay's estimate.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import odocal
from odocal.cli.main import EXIT_OK, main
from odocal.model.parameters import Parameters
from odocal.model.step import body
from tests.ros2.rig import (
    START_S,
    Script,
    play,
    settle,
    values_of,
    wheel_angles,
    without_sideslip,
)
from tests.ros2.rosenv import load_declared, require_rclpy

require_rclpy()

#: An odometry message counts as the datasheet's where its speed is this close to theirs.
_SAME = 0.005


def _replay(d: odocal.Drive, folder: Path, *extra: str) -> tuple[int, dict[str, Any]]:
    """``odocal replay --no-batch`` on the drive file: exit code and calibration.json."""
    path = folder / "drive.parquet"
    odocal.save_drive(d, path)
    code = main(["replay", str(path), "--out", str(folder / "replay"), "--no-batch",
                 *(extra or ("--no-report", "-q"))])
    return code, json.loads((folder / "replay" / "calibration.json").read_text())


def _theta_std(calibration: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    names = ("c_e", "c_d", "t_r", "d")
    return (np.array([calibration["theta"][n] for n in names]),
            np.array([calibration["std"][n] for n in names]))


# ---------------------------------------------------------------------------------------- 1

def test_a_tyre_change_never_publishes_a_refused_estimate(rig: Any, tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]
                                                          ) -> None:
    """Wheels 2% larger after 300 s, and a plausible range for c_e ([gate] c_e_m) that the new
    wheels leave: every estimate after the change is refused by the gate (as the live checks
    refused them with a front-wheel finding in the issue), while the calibrator goes on. The
    odometry, ~/estimate, the exports and the diagnostics keep the last good calibration;
    replay's trace marks every refused row."""
    true = odocal.TRUE_PARAMETERS
    after = Parameters(true.c_e * 1.02, true.c_d, true.t_r, true.d)
    sim = odocal.simulate(duration_s=600.0, seed=3, noise="realistic", change=(300.0, after))
    d = without_sideslip(sim.drive)
    settings = tmp_path / "settings.toml"
    settings.write_text(f"[gate]\nc_e_m = [{true.c_e * 0.99}, {true.c_e * 1.01}]\n")
    # a datasheet far from the truth: an odometry message on it is told from a calibrated one
    r = rig(datasheet="c_e=2.06,t_r=1.45", settings_file=str(settings))
    statuses: list[str] = []
    play(r.executor, r.player, r.node, d,
         between=lambda b: statuses.append(r.node.estimate.status.name
                                           if r.node.estimate is not None else ""))
    final = r.node.finish()
    settle(r.executor, r.player, r.node)
    refused = [i for i, s in enumerate(statuses) if s == "REJECTED"]
    assert refused and "CONVERGED" in statuses[:refused[0]], statuses     # after a good one
    assert final.status.name == "REJECTED" and not r.node.calibrator.halted
    # the odometry: never the datasheet's once an estimate was published (from 60 s on)
    ds = np.array([2.06, 0.0, 1.45, 0.0])
    on_datasheet = []
    for msg in r.player.odometry:
        k = round((msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec - START_S) / d.t_s)
        v_ds, _, _, _ = body(ds, d.n_rl[k], d.n_rr[k], d.a_y[k])
        if d.t[k] > 60.0 and abs(v_ds) > 1.0:
            on_datasheet.append(abs(msg.twist.twist.linear.x / v_ds - 1.0) < _SAME)
    assert on_datasheet and not any(on_datasheet)
    # ~/estimate: only publishable estimates; the exports at the end are the last of them
    assert r.player.estimates
    last = np.array(r.player.estimates[-1].data).reshape(4, 7)
    assert last[0, 0] < true.c_e * 1.01 < final.theta.c_e
    exported = load_declared(r.folder / "odometry_parameters.yaml", "wheel_odometry",
                             {"effective_wheel_circumference": "DOUBLE",
                              "rear_track_width": "DOUBLE"}, context=r.node.context)
    assert exported["effective_wheel_circumference"] == pytest.approx(last[0, 0], rel=1e-12)
    # /diagnostics: never ERROR; the refusal named with what is published instead
    levels = {s.level for s in r.player.statuses()}
    assert b"\x02" not in levels
    named = [s for s in r.player.statuses() if "refused" in s.message]
    assert named and all(s.level == b"\x01" for s in named)
    assert "publishing the calibration from" in named[-1].message
    assert values_of(named[-1])["latest_status"] == "REJECTED"
    # odocal replay on the same drive: the trace marks every refused estimate, and
    # calibration.json holds the last one that was not
    capsys.readouterr()
    code, calibration = _replay(d, tmp_path, "--config", str(settings),
                                "--datasheet", "c_e=2.06,t_r=1.45")
    assert code == EXIT_OK
    printed = [line for line in capsys.readouterr().out.splitlines() if " km  c_e " in line]
    assert "REJECTED (parameter-range" in printed[-1]
    assert printed[-1].endswith("): not published")
    assert not any("REJECTED" in line for line in printed[:3])
    page = (tmp_path / "replay" / "report.html").read_text()
    said = page.split("<p id='rejected'>")[1].split("</p>")[0]
    assert "updates were rejected by the checks or the gate (" in said
    assert "parameter-range" in said
    assert "the table shows the last estimate that was not" in page
    rows = list(csv.DictReader((tmp_path / "replay" / "trace.csv").open()))
    marked = [row for row in rows if row["status"] == "REJECTED"]
    assert len(marked) >= 3 and all(row["rejected_by"] for row in marked)
    assert all("parameter-range" in row["rejected_by"] for row in marked
               if float(row["c_e"]) > true.c_e * 1.01)
    good = [row for row in rows if row["status"] == "CONVERGED"][-1]
    assert calibration["theta"]["c_e"] == pytest.approx(float(good["c_e"]), rel=1e-12)
    assert rows[-1]["status"] == "REJECTED"


# ---------------------------------------------------------------------------------------- 8

def test_wall_clock_stamps_and_the_references_sideslip_give_replays_estimate(
        rig: Any, tmp_path: Path) -> None:
    """Stamps on the wall clock (1.7e9 s and a fraction) and a drive with sideslip, given to
    the node as the reference Odometry's twist: the node's final estimate is replay's on the
    drive file with its beta column."""
    sim = odocal.simulate(duration_s=300.0, seed=5, noise="realistic")
    d = sim.drive
    assert np.abs(d.beta).max() > 0.02
    start = 1_764_000_000.123456789
    r = rig(sideslip_from_reference=True)
    play(r.executor, r.player, r.node, d, Script(start_s=start, sideslip=True))
    est = r.node.finish()
    _, calibration = _replay(d, tmp_path)
    theta, std = _theta_std(calibration)
    assert all(est.identified)
    print("the node against replay, in replay's standard deviations:",
          (est.theta.as_array() - theta) / std)
    assert np.all(np.abs(est.theta.as_array() - theta) <= 0.01 * std), \
        (est.theta.as_array() - theta) / std
    assert np.allclose(est.std, std, rtol=0.01)


# ---------------------------------------------------------------------------------------- 2

def test_messages_lost_on_the_way_are_counted_by_their_stamps_and_named(
        rig: Any, drive_120: odocal.Drive) -> None:
    """Every tenth wheel message between 40 and 60 s and 25 reference poses in a row never
    arrive: /diagnostics says WARN with the share, the counts are exact."""
    lost_wheels = {k for k in range(1600, 2400) if k % 10 == 3}
    lost_poses = set(range(3000, 3025))

    def skip(role: str, k: int) -> bool:
        return (role == "wheels" and k in lost_wheels) or (role == "pose" and k in lost_poses)

    r = rig()
    play(r.executor, r.player, r.node, drive_120, Script(skip=skip),
         between=lambda b: None)
    settle_diagnostics(r)
    wheels = r.node.get_parameter("wheel_topic").value
    pose = r.node.get_parameter("pose_topic").value
    named = [s for s in r.player.statuses() if "missing by their stamps" in s.message]
    assert named and all(s.level == b"\x01" for s in named)
    values = values_of(r.player.statuses()[-1])
    assert int(values[f"missing {wheels}"]) == len(lost_wheels)
    assert int(values[f"missing {pose}"]) == len(lost_poses)
    share = 100 * len(lost_poses) / drive_120.n_samples
    assert f"{pose}: {share:.1f}% of the messages missing by their stamps (25 of " \
        f"{drive_120.n_samples})" in named[-1].message


def settle_diagnostics(r: Any) -> None:
    """The node's status published now, and heard by the player (the last one it holds)."""
    from tests.ros2.rig import spin_until

    now = [(s.message, values_of(s)) for s in r.node.status()]
    r.node.publish_diagnostics()

    def heard() -> bool:
        statuses = r.player.diagnostics[-1].status if r.player.diagnostics else []
        return [(s.message, values_of(s)) for s in statuses] == now

    spin_until(r.executor, heard, "the diagnostics")


@pytest.fixture(scope="module")
def drive_120() -> odocal.Drive:
    """Two minutes of a realistic city drive, without sideslip."""
    return without_sideslip(odocal.simulate(duration_s=120.0, seed=5, noise="realistic").drive)


# ---------------------------------------------------------------------------------------- 6

def test_a_joint_state_with_positions_only_is_calibrated(rig: Any, tmp_path: Path) -> None:
    """Many drivers publish the wheels' angles and no velocities: the node differentiates them
    (between messages, at the step's middle) and calibrates as from the rates."""
    sim = odocal.simulate(duration_s=300.0, seed=5, noise="realistic")
    d = without_sideslip(sim.drive)
    r = rig()
    play(r.executor, r.player, r.node, d,
         Script(positions_only=True, extra={"angles": wheel_angles(d)}))
    est = r.node.finish()
    settle(r.executor, r.player, r.node)
    assert not any("no message on" in s.message for s in r.player.statuses())
    assert r.node.messages()["wheels"] == d.n_samples
    _, calibration = _replay(d, tmp_path)
    theta, std = _theta_std(calibration)
    assert all(est.identified)
    # the rates at the steps' middles are the drive's, averaged over a step: within a tenth
    # of a standard deviation of the estimate from the rates themselves
    assert np.all(np.abs(est.theta.as_array() - theta) <= 0.1 * std), \
        (est.theta.as_array() - theta) / std
    assert len(r.player.odometry) == d.n_samples - 1          # (the first has no rate yet)


def test_velocities_in_every_other_message_are_calibrated_as_velocities_alone(
        rig: Any, tmp_path: Path) -> None:
    """A driver whose every message has the wheels' angles and every other one their
    velocities too: the velocities are read where they come, and an angles-only message gives
    the rate over the step from the message before it, at the step's middle. Before, the
    velocity messages' angles were not kept, so an angles-only message gave the rate over two
    steps, stamped at their middle: the velocity message's own time. The buffer held two rows
    at one instant and none at the next, and d moved by 0.96 of replay's std (stop 50's
    hostile run, on a car: up to 1.05). Now the node is as close to the truth as replay is
    (seeds 5-7: the two differ by up to 0.67 std, the grid's averaging of rates at the steps'
    middles, as with angles alone), and its std is within a quarter of replay's."""
    sim = odocal.simulate(duration_s=300.0, seed=5, noise="realistic")
    d = without_sideslip(sim.drive)
    angles = wheel_angles(d)

    def mixed(role: str, k: int, msg: Any) -> None:
        if role == "wheels":
            msg.position = [0.0, 0.0, *(float(v) for v in angles[k])]
            if k % 2:
                msg.velocity = []

    r = rig()
    play(r.executor, r.player, r.node, d, Script(values=mixed))
    est = r.node.finish()
    settle(r.executor, r.player, r.node)
    assert r.node.messages()["wheels"] == d.n_samples
    _, calibration = _replay(d, tmp_path)
    theta, std = _theta_std(calibration)
    assert all(est.identified)
    diff = (est.theta.as_array() - theta) / std
    z = (est.theta.as_array() - sim.true_parameters.as_array()) / est.std
    print("mixed against replay of the rates, in stds:", diff.round(3), "z:", z.round(2))
    assert np.all(np.abs(diff) <= 0.75), diff
    assert np.all(np.abs(z) < 3.0) and np.all(np.asarray(est.std) <= 1.25 * std), z


def test_nan_values_and_stamps_going_back_are_refused_counted_and_named(
        rig: Any, drive_120: odocal.Drive) -> None:
    """800 wheel messages with NaN velocities (20 s), 44 whose stamps jump back 5 s, one NaN
    pose and one NaN IMU value: each refused and named; the node goes on and calibrates."""
    nan_wheels = set(range(800, 1600))
    back = set(range(3200, 3244))

    def values(role: str, k: int, msg: Any) -> None:
        if role == "wheels" and k in nan_wheels:
            msg.velocity = [0.0, 0.0, float("nan"), float("nan")]
        if role == "pose" and k == 2000:
            msg.pose.pose.position.x = float("nan")
        if role == "imu" and k == 2100:
            msg.linear_acceleration.y = float("nan")

    def wheel_t(k: int, t: float) -> float:
        return t - 5.0 if k in back else t

    r = rig()
    play(r.executor, r.player, r.node, drive_120, Script(values=values, wheel_t=wheel_t))
    est = r.node.finish()
    settle_diagnostics(r)
    assert est.success and any(est.identified)
    text = " | ".join(s.message for s in r.player.statuses())
    wheels = r.node.get_parameter("wheel_topic").value
    assert f"{wheels}: 800 messages refused, NaN or infinite wheel values" in text
    # (the first of them 4.975 s behind the last one taken)
    assert f"{wheels}: 44 messages refused, their stamps went back (up to 4.97 s)" in text
    assert "missing by their stamps" not in text             # refused is not lost
    assert f"{r.node.get_parameter('pose_topic').value}: 1 messages refused, NaN" in text
    assert f"{r.node.get_parameter('imu_topic').value}: 1 messages refused, NaN" in text
    assert all(s.level != b"\x02" for s in r.player.statuses())


# ---------------------------------------------------------------------------------------- 3

class _NoAnswer(Exception):
    """The node's process never answered the first batch (what it said is the message)."""


@pytest.mark.parametrize(("signum", "after"), [("SIGINT", 400), ("SIGINT", 2500),
                                               ("SIGTERM", 400), ("SIGTERM", 2500)])
def test_ctrl_c_or_sigterm_mid_drive_ends_cleanly(ros: Any, tmp_path: Path, signum: str,
                                                  after: int) -> None:
    """``odocal ros2`` as a process, a player publishing as fast as it can: the signal lands
    while messages flow (``after`` messages into the drive's second part, once the node has
    published estimates). Exit 0, the final calibration said and exported, no traceback.
    (Reliable inputs here: a best-effort reader drops what a writer sends before the reader
    has matched it, and the player cannot see when that is.)

    In full test runs the first of these, on a test worker that has run many ROS 2 tests
    before, used to never hear the node's odometry: the node started, said so, and then
    nothing arrived for minutes. The first batch was sent again until the node answered, and
    a batch that arrives twice is refused, so where the node had taken the first batch but
    its odometry of it was lost (sent before its writer had matched the player's reader)
    nothing new ever came. The player now goes on to the next batch instead. A start that
    hears nothing for 45 s is still tried once more with a new node and player and two
    minutes, saying so; the signal's handling is what is judged."""
    for attempt, resend_s in ((1, 45.0), (2, 120.0)):
        try:
            _signal_mid_drive(ros, tmp_path / f"exports-{attempt}", signum, after, resend_s)
            return
        except _NoAnswer as stall:
            print(f"start {attempt}: odocal ros2 never answered the first batch; it said:\n"
                  f"{stall}")
    pytest.fail("odocal ros2 never answered the first batch, in two starts (printed above)")


def _latest_s(player: Any) -> float:
    """The stamp (s) of the latest odometry the player heard."""
    last = player.odometry[-1].header.stamp
    return float(last.sec) + 1e-9 * float(last.nanosec)


def _signal_mid_drive(ros: Any, folder: Path, signum: str, after: int,
                      resend_s: float) -> None:
    import os
    import signal
    import subprocess
    import sys
    import time

    from rclpy.experimental import EventsExecutor
    from rosgraph_msgs.msg import Clock

    from tests.ros2.rig import Player, messages, spin_until, stamp, unique
    from tests.ros2.rosenv import isolate

    isolate()
    name, ns = unique("sig"), f"/{unique('s')}"
    proc = subprocess.Popen(
        [sys.executable, "-m", "odocal", "ros2", "--ros-args", "-r", f"__node:={name}",
         "-p", "use_sim_time:=true", "-p", f"wheel_topic:={ns}/joint_states",
         "-p", f"imu_topic:={ns}/imu", "-p", f"pose_topic:={ns}/pose",
         "-p", f"export_dir:={folder}", "-p", "qos_reliable:=true",
         "--disable-external-lib-logs"],
        env=os.environ.copy(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        start_new_session=True)
    player = Player(ros, ns, f"/{name}")
    executor = EventsExecutor(context=ros)
    executor.add_node(player)
    d = without_sideslip(odocal.simulate(duration_s=150.0, seed=5, noise="realistic").drive)
    script = Script()
    waited_s = float("nan")
    try:
        spin_until(executor, lambda: player.wheels.get_subscription_count() > 0
                   and player.pose.get_subscription_count() > 0
                   and player.imu.get_subscription_count() > 0
                   and all(sub.get_publisher_count() > 0 for sub in player.subscriptions
                           if sub.topic_name.startswith(f"/{name}/")),
                   "discovery", limit_s=90)
        sent = 0
        unanswered_since = time.monotonic()
        for k in range(d.n_samples):
            msgs = messages(d, k, script)
            if k % 40 == 0:
                player.clock.publish(Clock(clock=stamp(START_S + float(d.t[k]))))
            for role in ("wheels", "imu", "pose"):
                getattr(player, role).publish(msgs[role])
            if k < 100 * 40 and k % 40 == 39:      # the first 100 s at the node's pace
                if not player.odometry:
                    # What a reader gets before it has matched the writer is lost on the way,
                    # both ways: the first batches, or the node's odometry of them. Until the
                    # node answers, each batch waits up to 5 s for it and the next one goes
                    # out (a batch sent again is refused as arriving twice: before, a start
                    # whose first odometry was lost never heard an answer); a start that
                    # hears none for resend_s is given up.
                    deadline = time.monotonic() + 5.0
                    while not player.odometry and time.monotonic() < deadline:
                        executor.spin_once(timeout_sec=0.01)
                    if not player.odometry:
                        if time.monotonic() - unanswered_since > resend_s:
                            os.killpg(proc.pid, signal.SIGKILL)
                            raise _NoAnswer(proc.communicate(timeout=30)[1][-4000:])
                        continue
                # (by stamps: odometry lost before the node's writer matched is not waited for)
                spin_until(executor, lambda t=START_S + float(d.t[k]): _latest_s(player) > t - 1e-3,
                           "the node's odometry", limit_s=90)
            if k == 100 * 40:                      # the node has published estimates
                spin_until(executor, lambda: len(player.estimates) >= 1, "the node's estimates",
                           limit_s=90)
            if k > 100 * 40:
                sent += 3
                if sent >= after:
                    os.killpg(proc.pid, getattr(signal, signum))
                    signalled = time.monotonic()
                    break
        try:
            _, err = proc.communicate(timeout=60)
            waited_s = time.monotonic() - signalled
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            pytest.fail(f"{signum} did not stop odocal ros2")
    except pytest.fail.Exception:
        # what the node said, for a wait that failed
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        said = proc.communicate(timeout=30)[1] if proc.stderr is not None else ""
        print(f"odocal ros2 said:\n{said[-6000:]}")
        print(f"player: odometry {len(player.odometry)}, estimates {len(player.estimates)}")
        raise
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
        executor.remove_node(player)
        player.destroy_node()
        executor.shutdown()
    print(f"{signum} after {after} messages: exit {proc.returncode} after {waited_s:.2f} s")
    assert proc.returncode == 0, err
    for bad in ("Traceback", "FATAL", "Exception", "internal error"):
        assert bad not in err, err
    assert "final calibration after" in err and "wrote " in err, err
    assert (folder / "odometry_parameters.yaml").is_file()


# ---------------------------------------------------------------------------------------- 4

@pytest.mark.parametrize(("given", "said"), [
    ({"silence_timeout_s": -1.0}, "parameter silence_timeout_s: -1.0 is out of range; it "
                                  "takes 0.05 to 3600"),
    ({"diagnostics_period_s": 0.0}, "parameter diagnostics_period_s: 0.0 is out of range; it "
                                    "takes 0.1 to 3600"),
    ({"diagnostics_period_s": -1.0}, "diagnostics_period_s: -1.0 is out of range"),
    ({"qos_depth": -5}, "parameter qos_depth: -5 is out of range; it takes 1 to 100000"),
    ({"qos_depth": "abc"}, "parameter qos_depth: 'abc' is a string; it takes an integer"),
    ({"silence_timeout_s": 2}, "parameter silence_timeout_s: 2 is an integer; it takes a "
                               "double \\(e.g. 2.0\\)"),
    ({"export_targets": ["autoware", "ros3"]}, "export_targets: .* unknown 'ros3'; choose "
                                               "from autoware, "),
    ({"wheel_topic": "bad topic!"}, "parameter wheel_topic: 'bad topic!' is not a valid "
                                    "topic name"),
    ({"wheel_topik": "/x"}, "unknown parameter 'wheel_topik' \\(did you mean 'wheel_topic'"),
    ({"pose_type": "pose"}, "parameter pose_type: 'pose': unknown 'pose'; choose from "
                            "odometry, pose_with_covariance"),
    ({"imu_rotation_deg": [0, 0, 90]}, "imu_rotation_deg: \\[0, 0, 90\\] is a list of "
                                       "integers; it takes a list of 3 doubles"),
    ({"datasheet": "c_e=x"}, "parameter datasheet"),
])
def test_bad_parameters_are_refused_at_start_in_one_line(ros: Any, given: dict[str, Any],
                                                         said: str) -> None:
    from rclpy.parameter import Parameter

    from odocal.ros2.node import CalibrationNode
    from tests.ros2.rig import unique

    with pytest.raises(odocal.ConfigError, match=said) as caught:
        CalibrationNode(context=ros, node_name=unique("bad"), enable_rosout=False,
                        parameter_overrides=[Parameter(k, value=v) for k, v in given.items()])
    assert len(str(caught.value).splitlines()) == 1


def test_a_bad_parameter_on_the_command_line_is_exit_1(capsys: pytest.CaptureFixture[str]
                                                      ) -> None:
    from tests.ros2.rosenv import isolate

    isolate()
    for words, said in ((["-p", "qos_depth:=abc"], "qos_depth: 'abc' is a string"),
                        (["-p", "silence_timeout_s:=2"], "silence_timeout_s: 2 is an integer"),
                        (["-p", "wheel_topik:=/x"], "unknown parameter 'wheel_topik'")):
        code = main(["ros2", "--ros-args", *words, "--disable-external-lib-logs"])
        err = capsys.readouterr().err
        assert code == 1, err
        assert said in err and len(err.strip().splitlines()) == 1, err


def test_export_targets_take_one_string_with_commas(ros: Any) -> None:
    from rclpy.parameter import Parameter

    from odocal.ros2.node import CalibrationNode
    from odocal.ros2.params import targets
    from tests.ros2.rig import unique

    node = CalibrationNode(context=ros, node_name=unique("one"), enable_rosout=False,
                           parameter_overrides=[Parameter("export_targets",
                                                          value="autoware, yaml")])
    try:
        assert targets(node.get_parameter("export_targets").value) == ["autoware", "yaml"]
    finally:
        node.destroy_node()


def test_parameters_change_at_run_time_or_are_refused_with_the_reason(
        rig: Any, drive_120: odocal.Drive, tmp_path: Path) -> None:
    from rclpy.parameter import Parameter
    from rclpy.parameter_client import AsyncParameterClient
    from std_srvs.srv import Trigger

    from tests.ros2.rig import call, spin_until

    r = rig()
    play(r.executor, r.player, r.node, drive_120)
    client = AsyncParameterClient(r.player, r.node.get_fully_qualified_name())
    spin_until(r.executor, lambda: client.services_are_ready(), "the parameter services")

    def set_one(name: str, value: Any) -> Any:
        future = client.set_parameters([Parameter(name, value=value)])
        spin_until(r.executor, future.done, "set_parameters")
        return future.result().results[0]

    refused = set_one("wheel_topic", "/elsewhere")
    assert not refused.successful and "read-only" in refused.reason
    assert r.node.get_parameter("wheel_topic").value != "/elsewhere"
    refused = set_one("silence_timeout_s", -1.0)
    assert not refused.successful
    refused = set_one("export_targets", ["autoware", "ros3"])
    assert not refused.successful and "unknown 'ros3'" in refused.reason
    taken = set_one("diagnostics_period_s", 0.5)
    assert taken.successful and r.node._timer.timer_period_ns == 500_000_000
    elsewhere = tmp_path / "elsewhere"
    assert set_one("export_dir", str(elsewhere)).successful
    assert set_one("export_targets", "yaml").successful
    answer = call(r.executor, r.player.export, Trigger.Request(), "~/export")
    assert answer.success, answer.message
    assert sorted(p.name for p in elsewhere.iterdir()) == ["odometry_parameters.yaml"]


# ---------------------------------------------------------------------------------------- 5

def test_the_twist_covariance_is_each_messages_error(rig: Any, ros: Any) -> None:
    """Against the simulation's truth: the variance each odometry message states is the mean
    squared error of the messages (speed and yaw rate), not that of a two-second mean; the
    exports carry the same."""
    sim = odocal.simulate(duration_s=300.0, seed=5, noise="realistic")
    d = without_sideslip(sim.drive)
    r = rig()
    play(r.executor, r.player, r.node, d)
    est = r.node.finish()
    true_v, true_w, _, _ = body(sim.true_parameters.as_array(), sim.true_n_rl, sim.true_n_rr,
                                d.a_y)
    err_v, err_w, var_v, var_w = [], [], [], []
    for msg in r.player.odometry:
        k = round((msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec - START_S) / d.t_s)
        if d.t[k] < 100.0:                          # the noise measured from the first estimate
            continue
        err_v.append(msg.twist.twist.linear.x - true_v[k])
        err_w.append(msg.twist.twist.angular.z - true_w[k])
        var_v.append(msg.twist.covariance[0])
        var_w.append(msg.twist.covariance[35])
    ratio_v = np.mean(var_v) / np.mean(np.square(err_v))
    ratio_w = np.mean(var_w) / np.mean(np.square(err_w))
    print(f"stated over the truth's mean squared error: speed {ratio_v:.3f} (std "
          f"{np.sqrt(np.mean(var_v)):.4f} against {np.sqrt(np.mean(np.square(err_v))):.4f} m/s), "
          f"yaw rate {ratio_w:.3f} (std {np.sqrt(np.mean(var_w)):.4f} against "
          f"{np.sqrt(np.mean(np.square(err_w))):.4f} rad/s)")
    assert 0.7 < ratio_v < 1.4 and 0.7 < ratio_w < 1.4, (ratio_v, ratio_w)
    assert est.success
    diff = load_declared(r.folder / "ros2_control" / "diff_drive_controller.yaml",
                         "diff_drive_controller", {"twist_covariance_diagonal": "DOUBLE_ARRAY"},
                         context=ros)
    stated = diff["twist_covariance_diagonal"]
    assert 0.5 < stated[0] / np.mean(np.square(err_v)) < 2.0
    assert 0.5 < stated[5] / np.mean(np.square(err_w)) < 2.0


# ---------------------------------------------------------------------------------------- 7

def test_the_node_says_what_it_does(rig: Any, drive_120: odocal.Drive) -> None:
    """On /rosout (and the console): a start line with the node, its topics and QoS; a line at
    each identification change; the final calibration and the files written."""
    from rcl_interfaces.msg import Log
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    r = rig(rosout=True)
    logger = r.node.get_logger().name
    lines: list[str] = []
    r.player.create_subscription(
        Log, "/rosout", lambda m: lines.append(m.msg) if m.name == logger else None,
        QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE,
                   durability=DurabilityPolicy.TRANSIENT_LOCAL))
    play(r.executor, r.player, r.node, drive_120)
    r.node.finish()
    from tests.ros2.rig import spin_until

    spin_until(r.executor, lambda: any(line.startswith("wrote ") for line in lines),
               "the node's last lines")
    name = r.node.get_fully_qualified_name()
    start = lines[0]
    assert start.startswith(f"{name}: calibrating the rear_axle model from ")
    assert "QoS best effort" in start
    for key in ("wheel_topic", "pose_topic", "imu_topic"):
        assert r.node.get_parameter(key).value in start
    assert f"{name}/odometry" in start and "/diagnostics" in start
    changes = [line for line in lines if " km: identified " in line]
    assert changes and "c_e" in changes[0]
    assert any(line.startswith("final calibration after ") for line in lines)
    assert str(r.folder / "odometry_parameters.yaml") in lines[-1]
